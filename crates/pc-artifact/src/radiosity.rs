//! Schema of the `radiosity` artifact written by pc-fmm (docs/fmm.md, docs/artifacts.md).
//!
//! | section     | element     | what                                                        |
//! |-------------|-------------|-------------------------------------------------------------|
//! | `radiance`  | `[f32; 3]`  | per data-pool splat: outgoing diffuse radiance, linear RGB   |
//! | `source`    | `[f32; 3]`  | per splat: the solve's source term E (emission + direct)     |
//! | `residuals` | `f64`       | relative residual after each iteration                       |
//!
//! `radiance` holds emission plus every LD⁺ bounce and the LDD bounces fed by caustic energy,
//! but not the caustic energy's own first diffuse bounce: the renderer adds that from the
//! photon map (seed §8.1, §8.5.15). Specular splats hold zero.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::octree::OctreeId;
use crate::params::FmmParams;
use crate::reader::{first_where, Checked};
use crate::{Artifact, ArtifactError, ArtifactKind};

pub mod sections {
    pub const RADIANCE: &str = "radiance";
    pub const SOURCE: &str = "source";
    pub const RESIDUALS: &str = "residuals";
}

/// Metadata of a radiosity artifact.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RadiosityMeta {
    /// Keys of the octree and V-map artifacts the solve used.
    pub octree_key: String,
    pub vmap_key: String,
    /// Key of the caustics artifact whose energy fed the solve, if any.
    pub photons_key: Option<String>,
    pub params: FmmParams,
    pub iterations: u32,
    pub converged: bool,
    pub residuals: Vec<f64>,
    /// Expansion order of each iteration's product (empty in artifacts made before relaxed
    /// products: all at `params.order`).
    #[serde(default)]
    pub orders: Vec<u32>,
    /// Splats that take part (diffuse and emitting).
    pub active_splats: u64,
    /// The solve's unknowns when they were clusters of splats (`fmm.max_elements`), 0 when
    /// every active splat was its own.
    #[serde(default)]
    pub elements: u64,
    pub m2l: u64,
    pub p2l: u64,
    pub m2p: u64,
    pub p2p: u64,
    pub p2p_pairs: u64,
    /// Emitter samples taken over all receivers, the shadow rays they cast, and the samples
    /// settled by shaft culling, without a walk through the octree (the probes' verdict
    /// settled the others).
    #[serde(default)]
    pub emitter_samples: u64,
    #[serde(default)]
    pub emitter_rays: u64,
    #[serde(default)]
    pub emitter_settled: u64,
    /// The final gather (docs/fmm.md, "Final gather"): the splats of its candidate leaves, of
    /// those the ones its pilot visited, the splats whose light it took from rays of their own,
    /// and every ray it cast.
    #[serde(default)]
    pub gather_candidates: u64,
    #[serde(default)]
    pub gather_piloted: u64,
    #[serde(default)]
    pub gathered_splats: u64,
    #[serde(default)]
    pub gather_rays_cast: u64,
    pub device: String,
    pub timings: Vec<(String, f64)>,
}

/// The sections of a radiosity artifact, checked ([`RadiosityFile`]).
#[derive(Clone, Copy, Debug)]
pub struct RadiosityView<'a> {
    /// Per data-pool splat: outgoing diffuse radiance, linear RGB.
    pub radiance: &'a [[f32; 3]],
    /// Per splat: the solve's source term.
    pub source: &'a [[f32; 3]],
    pub residuals: &'a [f64],
}

impl<'a> RadiosityView<'a> {
    fn sections(a: &'a Artifact) -> Result<RadiosityView<'a>, ArtifactError> {
        Ok(RadiosityView {
            radiance: a.section(sections::RADIANCE)?,
            source: a.section(sections::SOURCE)?,
            residuals: a.section(sections::RESIDUALS)?,
        })
    }

    /// One source term per splat, every radiance and source finite and non-negative, the
    /// residuals those of the metadata.
    fn check(&self, meta: &RadiosityMeta) -> Result<(), String> {
        if self.source.len() != self.radiance.len() {
            return Err(format!(
                "{} source terms for {} splats",
                self.source.len(),
                self.radiance.len()
            ));
        }
        let bad = |c: &[f32; 3]| c.iter().any(|x| !x.is_finite() || *x < 0.0);
        let first_bad = |v: &[[f32; 3]]| first_where(v, |_, c| bad(c));
        if let Some(i) = first_bad(self.radiance).or_else(|| first_bad(self.source)) {
            return Err(format!("splat {i}: negative or non-finite radiance"));
        }
        if self.residuals != meta.residuals.as_slice() {
            return Err("the residuals section and the metadata disagree".into());
        }
        Ok(())
    }
}

/// An opened radiosity artifact, checked once: its kind, its structure and (with
/// [`RadiosityFile::open`]) that it was solved on the octree it is used with.
pub type RadiosityFile = Checked<RadiosityMeta>;

impl Checked<RadiosityMeta> {
    /// Open the radiosity at `path` for the octree `octree`: solved on another octree, or of
    /// another size, is [`ArtifactError::Stale`] (rerun pc-vmap and pc-fmm).
    pub fn open(path: impl AsRef<Path>, octree: &OctreeId) -> Result<RadiosityFile, ArtifactError> {
        let f = RadiosityFile::from_artifact(Artifact::open_input(path, ArtifactKind::Radiosity)?)?;
        let stale = |why: String, rerun: &str| f.art.stale(why, rerun);
        if f.meta.octree_key != octree.key.to_string() {
            return Err(stale(
                format!(
                    "it was solved for another octree than {}",
                    octree.path.display()
                ),
                "pc-vmap and pc-fmm",
            ));
        }
        let n = f.view().radiance.len();
        if n != octree.splats {
            return Err(stale(
                format!(
                    "it holds {n} splats, the octree {} has {}",
                    octree.path.display(),
                    octree.splats
                ),
                "pc-fmm",
            ));
        }
        Ok(f)
    }

    /// Open the radiosity at `path` on its own (pc-inspect): kind and structure.
    pub fn open_alone(path: impl AsRef<Path>) -> Result<RadiosityFile, ArtifactError> {
        RadiosityFile::from_artifact(Artifact::open_kind(path, ArtifactKind::Radiosity)?)
    }

    /// [`RadiosityFile::open_alone`] for an artifact opened already (another kind is
    /// [`ArtifactError::WrongKind`]).
    pub fn from_artifact(art: Artifact) -> Result<RadiosityFile, ArtifactError> {
        art.ensure_kind(ArtifactKind::Radiosity)?;
        let meta: RadiosityMeta = art.metadata()?;
        RadiosityView::sections(&art)?
            .check(&meta)
            .map_err(|m| art.invalid(m))?;
        Ok(RadiosityFile { art, meta })
    }

    /// The checked sections.
    pub fn view(&self) -> RadiosityView<'_> {
        RadiosityView::sections(&self.art)
            .expect("the sections were checked when the file was opened")
    }
}
