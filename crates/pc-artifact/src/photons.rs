//! Schema of the `photons` artifact written by pc-caustics (docs/caustics.md, seed §8.5.2 to
//! §8.5.7): the caustic photon map.
//!
//! | section    | element       | what                                                          |
//! |------------|---------------|---------------------------------------------------------------|
//! | `photons`  | [`Photon`]    | every stored photon (LS⁺D: first diffuse hit after ≥ 1 specular bounce) |
//! | `deposit`  | `[f32; 3]`    | per data-pool splat: the caustic power (W, RGB) its photons carry, which pc-fmm adds to its sources |
//! | `spec_*`   |               | the specular links (light-independent; [`crate::specular`]) |
//!
//! No search structure is stored: the renderer builds its kd-tree over the positions when it
//! opens the map (pc-raytrace `caustic.rs`, 50 ms for 750k photons on two cores). An archived
//! kiddo tree, queried in place, was stored up to November 2026; kiddo's queries trust the
//! archive's internal offsets, so a section that passed rkyv's bytecheck but was edited read
//! outside the mapping (found by pc-fuzz). Files that still carry a `kdtree` section are read
//! as before; the section is ignored.

use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

use std::path::Path;

use crate::light::PointLight;
use crate::octree::OctreeId;
use crate::params::CausticsParams;
use crate::reader::{first_where, Checked};
use crate::specular::{SpecularMeta, SpecularView};
use crate::{Artifact, ArtifactError, ArtifactKind};

pub mod sections {
    pub const PHOTONS: &str = "photons";
    pub const DEPOSIT: &str = "deposit";
}

/// One stored photon: 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Photon {
    /// Where it landed (on the diffuse splat's plane).
    pub position: [f32; 3],
    /// Data-pool index of the diffuse splat it landed on.
    pub splat: u32,
    /// Unit direction of travel when it arrived (pointing into the surface).
    pub dir: [f32; 3],
    /// Specular bounces on its path (≥ 1).
    pub bounces: u32,
    /// Power it carries (W, linear RGB).
    pub power: [f32; 3],
    pub _pad: u32,
}

/// Metadata of a photons artifact.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct PhotonsMeta {
    /// Keys of the octree and V-map artifacts the photons were traced on.
    pub octree_key: String,
    pub vmap_key: String,
    pub params: CausticsParams,
    /// The point lights.
    pub lights: Vec<PointLight>,
    /// Total emitted power of every light (W, RGB), point lights and emitting splats.
    pub emitted_power: [f64; 3],
    /// Power aimed at the specular leaves the lights see (W, RGB).
    pub aimed_power: [f64; 3],
    /// Photons traced (aimed at specular leaves).
    pub traced: u64,
    /// Photons stored on diffuse splats.
    pub stored: u64,
    /// Photons whose aimed point was hidden behind something else.
    pub occluded: u64,
    /// Photons dropped at the bounce limit or leaving the scene.
    pub lost: u64,
    pub device: String,
    pub timings: Vec<(String, f64)>,
    /// The specular links (none in artifacts written before they existed).
    #[serde(default)]
    pub specular: SpecularMeta,
}

/// The sections of a photon map, checked ([`PhotonsFile`]).
#[derive(Clone, Copy)]
pub struct PhotonsView<'a> {
    pub photons: &'a [Photon],
    /// Per data-pool splat: the caustic power its photons carry (W, RGB).
    pub deposit: &'a [[f32; 3]],
    /// The specular links (diffuse → specular → diffuse).
    pub specular: SpecularView<'a>,
}

impl<'a> PhotonsView<'a> {
    fn sections(a: &'a Artifact) -> Result<PhotonsView<'a>, ArtifactError> {
        let map = PhotonMapView::sections(a)?;
        Ok(PhotonsView {
            photons: map.photons,
            deposit: map.deposit,
            specular: SpecularView::sections(a)?,
        })
    }

    /// The photons and the deposit alone, as the renderer reads them.
    pub fn map(&self) -> PhotonMapView<'a> {
        PhotonMapView {
            photons: self.photons,
            deposit: self.deposit,
        }
    }

    /// The photons' checks ([`PhotonMapView::check`]) and the specular links'.
    fn check(&self) -> Result<(), String> {
        self.map().check()?;
        self.specular.check(self.deposit.len())
    }
}

/// The photons of a photon map without its specular links, checked ([`PhotonMapFile`]).
#[derive(Clone, Copy)]
pub struct PhotonMapView<'a> {
    pub photons: &'a [Photon],
    /// Per data-pool splat: the caustic power its photons carry (W, RGB).
    pub deposit: &'a [[f32; 3]],
}

impl<'a> PhotonMapView<'a> {
    /// The sections it reads.
    const SECTIONS: [&'static str; 2] = [sections::PHOTONS, sections::DEPOSIT];

    fn sections(a: &'a Artifact) -> Result<PhotonMapView<'a>, ArtifactError> {
        Ok(PhotonMapView {
            photons: a.section(sections::PHOTONS)?,
            deposit: a.section(sections::DEPOSIT)?,
        })
    }

    /// At most `u32::MAX` photons (the renderer's kd-tree names them by `u32`), on splats of
    /// the deposit's data pool, with finite values; a finite deposit that is the photons' power
    /// summed per splat.
    fn check(&self) -> Result<(), String> {
        let splats = self.deposit.len();
        if u32::try_from(self.photons.len()).is_err() {
            return Err(format!("{} photons, more than 2³² − 1", self.photons.len()));
        }
        let bad_photon = |_: usize, p: &Photon| {
            let finite = p.position.iter().chain(&p.dir).chain(&p.power);
            p.splat as usize >= splats || !finite.clone().all(|x| x.is_finite())
        };
        if let Some(i) = first_where(self.photons, bad_photon) {
            return Err(format!(
                "photon {i}: splat out of range or values not finite"
            ));
        }
        let mut sum = vec![[0f64; 3]; splats];
        for p in self.photons {
            for (s, &w) in sum[p.splat as usize].iter_mut().zip(&p.power) {
                *s += w as f64;
            }
        }
        let bad_deposit = |j: usize, d: &[f32; 3]| {
            (0..3).any(|k| {
                let d = d[k] as f64;
                !d.is_finite() || (d - sum[j][k]).abs() > 1e-3 * sum[j][k].abs().max(1e-12)
            })
        };
        if let Some(j) = first_where(self.deposit, bad_deposit) {
            return Err(format!(
                "splat {j}: deposit {:?} is not the power of its photons {:?}",
                self.deposit[j], sum[j]
            ));
        }
        Ok(())
    }
}

/// An opened photon map, checked once: its kind, its structure and (with
/// [`PhotonsFile::open`]) that it was traced on the octree it is used with.
pub type PhotonsFile = Checked<PhotonsMeta>;

impl Checked<PhotonsMeta> {
    /// Open the photon map at `path` for the octree `octree`: traced on another octree, or a
    /// deposit of another size, is [`ArtifactError::Stale`] (rerun pc-caustics).
    pub fn open(path: impl AsRef<Path>, octree: &OctreeId) -> Result<PhotonsFile, ArtifactError> {
        let f = PhotonsFile::from_artifact(Artifact::open_input(path, ArtifactKind::Photons)?)?;
        fresh_for(&f.art, &f.meta, f.view().deposit.len(), octree)?;
        Ok(f)
    }

    /// Open the photon map at `path` on its own (pc-inspect): kind and structure.
    pub fn open_alone(path: impl AsRef<Path>) -> Result<PhotonsFile, ArtifactError> {
        PhotonsFile::from_artifact(Artifact::open_kind(path, ArtifactKind::Photons)?)
    }

    /// [`PhotonsFile::open_alone`] for an artifact opened already (another kind is
    /// [`ArtifactError::WrongKind`]).
    pub fn from_artifact(art: Artifact) -> Result<PhotonsFile, ArtifactError> {
        art.ensure_kind(ArtifactKind::Photons)?;
        let meta: PhotonsMeta = art.metadata()?;
        PhotonsView::sections(&art)?
            .check()
            .map_err(|m| art.invalid(m))?;
        Ok(PhotonsFile { art, meta })
    }

    /// The checked sections.
    pub fn view(&self) -> PhotonsView<'_> {
        PhotonsView::sections(&self.art)
            .expect("the sections were checked when the file was opened")
    }
}

/// The checks of every reader against the octree: traced on another octree, or a deposit of
/// another size than its splats, is [`ArtifactError::Stale`] (rerun pc-caustics).
fn fresh_for(
    art: &Artifact,
    meta: &PhotonsMeta,
    deposits: usize,
    octree: &OctreeId,
) -> Result<(), ArtifactError> {
    let stale = |why: String| art.stale(why, "pc-caustics");
    if meta.octree_key != octree.key.to_string() {
        return Err(stale(format!(
            "it was traced on another octree than {}",
            octree.path.display()
        )));
    }
    if deposits != octree.splats {
        return Err(stale(format!(
            "its deposit holds {deposits} splats, the octree {} has {}",
            octree.path.display(),
            octree.splats
        )));
    }
    Ok(())
}

/// A photon map opened for its photons alone (the renderer, pc-bake): the photon and deposit
/// sections are checked as [`PhotonsFile`] checks them and handed out; the specular links
/// (which only pc-fmm reads, 85 % of the file at 1M splats) are neither checked nor readable.
pub struct PhotonMapFile {
    art: Artifact,
    meta: PhotonsMeta,
}

impl PhotonMapFile {
    /// Open the photons of the photon map at `path` for the octree `octree` (stale as
    /// [`PhotonsFile::open`] says).
    pub fn open(path: impl AsRef<Path>, octree: &OctreeId) -> Result<PhotonMapFile, ArtifactError> {
        let art =
            Artifact::open_input_sections(path, ArtifactKind::Photons, &PhotonMapView::SECTIONS)?;
        let meta: PhotonsMeta = art.metadata()?;
        let view = PhotonMapView::sections(&art)?;
        view.check().map_err(|m| art.invalid(m))?;
        fresh_for(&art, &meta, view.deposit.len(), octree)?;
        Ok(PhotonMapFile { art, meta })
    }

    /// The checked photons.
    pub fn view(&self) -> PhotonMapView<'_> {
        PhotonMapView::sections(&self.art)
            .expect("the sections were checked when the file was opened")
    }

    /// The decoded metadata.
    pub fn meta(&self) -> &PhotonsMeta {
        &self.meta
    }

    /// The key in the header.
    pub fn key(&self) -> crate::Key {
        self.art.key()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn photon_layout_is_48_bytes() {
        assert_eq!(std::mem::size_of::<Photon>(), 48);
        assert_eq!(std::mem::offset_of!(Photon, dir), 16);
        assert_eq!(std::mem::offset_of!(Photon, power), 32);
    }
}
