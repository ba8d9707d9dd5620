//! Schema of the `photons` artifact written by pc-caustics (docs/caustics.md, seed §8.5.2 to
//! §8.5.7): the caustic photon map.
//!
//! | section    | element       | what                                                          |
//! |------------|---------------|---------------------------------------------------------------|
//! | `photons`  | [`Photon`]    | every stored photon (LS⁺D: first diffuse hit after ≥ 1 specular bounce) |
//! | `kdtree`   | `u8`          | a kiddo [`PhotonTree`] over the photon positions, item = index into `photons`, archived with rkyv 0.8 so pc-raytrace queries it in place ([`archived_tree`]) |
//! | `deposit`  | `[f32; 3]`    | per data-pool splat: the caustic power (W, RGB) its photons carry, which pc-fmm adds to its sources |
//!
//! The kd-tree is validated by rkyv's bytecheck before it is used ([`archived_tree`]): a
//! corrupt or foreign section is an error, never undefined behaviour.

use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

use std::path::Path;

use crate::light::PointLight;
use crate::octree::OctreeId;
use crate::params::CausticsParams;
use crate::reader::Checked;
use crate::{Artifact, ArtifactError, ArtifactKind};

pub mod sections {
    pub const PHOTONS: &str = "photons";
    pub const KDTREE: &str = "kdtree";
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

/// The photon kd-tree: kiddo's immutable tree over `f32` positions, items are photon indices.
pub type PhotonTree = kiddo::ImmutableKdTree<f32, 3>;

/// The archived (zero-copy) form of [`PhotonTree`], as it lies in the `kdtree` section.
pub type ArchivedPhotonTree = kiddo::kd_tree::ArchivedKdTree<
    f32,
    u32,
    kiddo::Eytzinger,
    kiddo::VecOfArenas<f32, u32, 3, 32>,
    3,
    32,
>;

/// Alignment the archived tree needs (kiddo's leaf arenas are aligned to 128 bytes); the
/// section is written with [`crate::ArtifactWriter::section_aligned`].
pub const TREE_ALIGN: u64 = 128;

/// Serializes a photon tree for the `kdtree` section.
pub fn tree_bytes(tree: &PhotonTree) -> Result<Vec<u8>, rkyv::rancor::Error> {
    rkyv::to_bytes::<rkyv::rancor::Error>(tree).map(|b| b.to_vec())
}

/// The `kdtree` section of `a`, validated (bytecheck) and borrowed in place from the mapping.
pub fn archived_tree(a: &Artifact) -> Result<&ArchivedPhotonTree, ArtifactError> {
    let bytes = a.section_aligned(sections::KDTREE, TREE_ALIGN as usize)?;
    rkyv::access::<ArchivedPhotonTree, rkyv::rancor::Error>(bytes).map_err(|e| {
        ArtifactError::Cast {
            path: a.path().to_path_buf(),
            section: sections::KDTREE.to_owned(),
            msg: format!("not a valid archived photon kd-tree: {e}"),
        }
    })
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
}

/// The sections of a photon map, checked ([`PhotonsFile`]).
#[derive(Clone, Copy)]
pub struct PhotonsView<'a> {
    pub photons: &'a [Photon],
    /// Per data-pool splat: the caustic power its photons carry (W, RGB).
    pub deposit: &'a [[f32; 3]],
    pub tree: &'a ArchivedPhotonTree,
}

impl<'a> PhotonsView<'a> {
    fn sections(a: &'a Artifact) -> Result<PhotonsView<'a>, ArtifactError> {
        Ok(PhotonsView {
            photons: a.section(sections::PHOTONS)?,
            deposit: a.section(sections::DEPOSIT)?,
            tree: archived_tree(a)?,
        })
    }

    /// Photons on splats of the deposit's data pool with finite values, a kd-tree over exactly
    /// those photons, a finite deposit that is the photons' power summed per splat.
    fn check(&self) -> Result<(), String> {
        let splats = self.deposit.len();
        if self.tree.size() as usize != self.photons.len() {
            return Err(format!(
                "the kd-tree holds {} photons but the map {}",
                self.tree.size(),
                self.photons.len()
            ));
        }
        let mut sum = vec![[0f64; 3]; splats];
        for (i, p) in self.photons.iter().enumerate() {
            let finite = p.position.iter().chain(&p.dir).chain(&p.power);
            if p.splat as usize >= splats || !finite.clone().all(|x| x.is_finite()) {
                return Err(format!(
                    "photon {i}: splat out of range or values not finite"
                ));
            }
            for k in 0..3 {
                sum[p.splat as usize][k] += p.power[k] as f64;
            }
        }
        if let Some(j) = (0..splats).find(|&j| {
            (0..3).any(|k| {
                let d = self.deposit[j][k] as f64;
                !d.is_finite() || (d - sum[j][k]).abs() > 1e-3 * sum[j][k].abs().max(1e-12)
            })
        }) {
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
        let stale = |why: String| f.art.stale(why, "pc-caustics");
        if f.meta.octree_key != octree.key.to_string() {
            return Err(stale(format!(
                "it was traced on another octree than {}",
                octree.path.display()
            )));
        }
        let deposits = f.view().deposit.len();
        if deposits != octree.splats {
            return Err(stale(format!(
                "its deposit holds {deposits} splats, the octree {} has {}",
                octree.path.display(),
                octree.splats
            )));
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn photon_layout_is_48_bytes() {
        assert_eq!(std::mem::size_of::<Photon>(), 48);
        assert_eq!(std::mem::offset_of!(Photon, dir), 16);
        assert_eq!(std::mem::offset_of!(Photon, power), 32);
    }

    #[test]
    fn the_tree_round_trips_through_its_archive() {
        let pts: Vec<[f32; 3]> = (0..200_000)
            .map(|i| {
                let t = i as f32 * 0.37;
                [t.sin(), t.cos(), (t * 0.1).fract()]
            })
            .collect();
        let tree = PhotonTree::new_from_slice(&pts).unwrap();
        let bytes = tree_bytes(&tree).unwrap();
        // rkyv needs the archive aligned as the section payload is.
        let mut aligned = rkyv::util::AlignedVec::<{ TREE_ALIGN as usize }>::new();
        aligned.extend_from_slice(&bytes);
        let arch = rkyv::access::<ArchivedPhotonTree, rkyv::rancor::Error>(&aligned).unwrap();
        let q = [0.2f32, 0.5, 0.3];
        let a = tree
            .query(&q)
            .nearest_one::<kiddo::SquaredEuclidean<f32>>()
            .execute();
        let b = arch
            .query(&q)
            .nearest_one::<kiddo::SquaredEuclidean<f32>>()
            .execute();
        assert_eq!(a.item, b.item);
        // A corrupt archive is an error, not undefined behaviour.
        let n = aligned.len();
        for b in &mut aligned[n - 64..] {
            *b = 0xFF;
        }
        assert!(rkyv::access::<ArchivedPhotonTree, rkyv::rancor::Error>(&aligned).is_err());
    }
}
