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

use crate::{Artifact, ArtifactError};

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
pub fn tree_bytes(tree: &PhotonTree) -> Result<Vec<u8>, String> {
    rkyv::to_bytes::<rkyv::rancor::Error>(tree)
        .map(|b| b.to_vec())
        .map_err(|e| format!("archiving the photon kd-tree: {e}"))
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

/// Parameters of the photon pass (part of the artifact key).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct CausticsParams {
    /// Photon budget n_e over the whole sphere of every light: a photon carries P / n_e, and
    /// only those aimed at specular leaves are traced (§8.5.3).
    pub photons: u32,
    /// Most specular bounces a photon makes before it is dropped.
    pub max_bounces: u32,
    /// Δ of §8.5.6 in radii of the splat a photon leaves.
    pub self_hit: f32,
    pub seed: u32,
}

/// Metadata of a photons artifact.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct PhotonsMeta {
    /// Keys of the octree and V-map artifacts the photons were traced on.
    pub octree_key: String,
    pub vmap_key: String,
    pub params: CausticsParams,
    /// The point lights: position then intensity.
    pub lights: Vec<[f32; 6]>,
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
