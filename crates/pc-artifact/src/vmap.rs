//! V-map artifact schema (seed §7.2, §7.3): visibility links between octree nodes, in CSR form,
//! and the nodes each point light sees.
//!
//! Sections of a `vmap` artifact (node indices are node-pool slots of the octree it was made
//! from; its key is in the metadata):
//!
//! | name            | element       | meaning |
//! |-----------------|---------------|---------|
//! | `link_offsets`  | `u32`         | CSR row starts, one per node-pool slot plus one |
//! | `links`         | [`Link`]      | for each node, the nodes it exchanges light with; every link is stored in both rows |
//! | `light_offsets` | `u32`         | CSR row starts, one per point light plus one |
//! | `light_links`   | [`Link`]      | for each point light, the nodes it sees and the visible fraction |
//! | `node_range`    | `[u32; 2]`    | per node-pool slot: its subtree's own splats `[begin, end)` in the data pool |
//! | `node_cone`     | `f32`         | per node-pool slot: cosine of the half-angle of its normal cone (−1: no cone) |
//! | `vnode`         | `u32`         | per node-pool slot: 1 when the node is a V-map leaf (no link goes below it) |
//! | `smear`         | [`Smear`]     | per node-pool slot: what its links' shared fractions misstate of its splats' visible transfer |

use std::path::Path;

use bytemuck::{Pod, Zeroable};

use crate::light::PointLight;
use crate::octree::OctreeId;
use crate::params::VmapParams;
use crate::reader::{any_where, Checked};
use crate::{Artifact, ArtifactError, ArtifactKind};

/// Section names of a vmap artifact.
pub mod sections {
    pub const LINK_OFFSETS: &str = "link_offsets";
    pub const LINKS: &str = "links";
    pub const LIGHT_OFFSETS: &str = "light_offsets";
    pub const LIGHT_LINKS: &str = "light_links";
    pub const NODE_RANGE: &str = "node_range";
    pub const NODE_CONE: &str = "node_cone";
    pub const VNODE: &str = "vnode";
    pub const SMEAR: &str = "smear";
}

/// What the fractions of the links that reach a node's splats misstate of the light they see,
/// summed over the node's subtree from the rays the links were decided on (docs/vmap.md,
/// "Visibility within a V-map leaf"). Area-weighted form factors, in the octree's normalised
/// frame: `error` is the visible transfer the rays found minus the one the links give
/// (`transfer`, ≥ 0), `variance` (≥ 0) the sampling variance of `error`. `contact`, for a
/// V-map leaf, is the share of its probes that another surface close over it blocks (a ball
/// resting on it: visibility changes from splat to splat), in [0, 1].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Smear {
    pub error: f32,
    pub transfer: f32,
    pub variance: f32,
    pub contact: f32,
}

impl Smear {
    /// Whether the links misstate the node's light by more than `share` of it, beyond `z`
    /// standard deviations of the sampling noise.
    pub fn exceeds(&self, share: f32, z: f32) -> bool {
        let e = self.error.abs();
        e > share * self.transfer && e * e > z * z * self.variance
    }
}

/// One visibility link: the other node and the fraction of the light between the two that is
/// not occluded. `node` carries [`Link::NEAR`] for near-field pairs (V-map leaves too close for a
/// far-field expansion: the FMM computes them point to point).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Link {
    pub node: u32,
    pub fraction: f32,
}

impl Link {
    /// Flag bit of near-field links.
    pub const NEAR: u32 = 1 << 31;

    pub fn far(node: u32, fraction: f32) -> Link {
        Link { node, fraction }
    }
    pub fn near(node: u32, fraction: f32) -> Link {
        Link {
            node: node | Self::NEAR,
            fraction,
        }
    }
    /// The node-pool slot.
    pub fn slot(&self) -> u32 {
        self.node & !Self::NEAR
    }
    pub fn is_near(&self) -> bool {
        self.node & Self::NEAR != 0
    }
}

/// Metadata of a vmap artifact.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct VmapMeta {
    /// Key of the octree artifact the links were computed on.
    pub octree_key: String,
    /// Key of the links alone: the octree key, the stage version and `params`. Lights do not
    /// enter it, so a rerun after moving a light reuses the links.
    pub links_key: String,
    pub params: VmapParams,
    /// The V-map leaf size used: `params.leaf_splats`, or more on a large octree
    /// ([`VmapParams::leaf_splats_for`]).
    #[serde(default)]
    pub leaf_splats_used: u32,
    /// The point lights the light lists were computed for.
    pub lights: Vec<PointLight>,
    pub far_links: u64,
    pub near_links: u64,
    pub pairs_tested: u64,
    pub rays_cast: u64,
    /// Whether the links were reused from the previous artifact.
    pub links_reused: bool,
    pub device: String,
    pub timings: Vec<(String, f64)>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn link_flags() {
        let l = Link::near(42, 0.5);
        assert!(l.is_near() && l.slot() == 42);
        let f = Link::far(7, 1.0);
        assert!(!f.is_near() && f.slot() == 7);
        assert_eq!(std::mem::size_of::<Link>(), 8);
    }
}

/// The sections of a V-map, checked ([`VmapFile`]).
#[derive(Clone, Copy, Debug)]
pub struct VmapView<'a> {
    pub link_offsets: &'a [u32],
    pub links: &'a [Link],
    pub light_offsets: &'a [u32],
    pub light_links: &'a [Link],
    pub node_range: &'a [[u32; 2]],
    pub node_cone: &'a [f32],
    pub vnode: &'a [u32],
    pub smear: &'a [Smear],
}

impl<'a> VmapView<'a> {
    fn sections(a: &'a Artifact) -> Result<VmapView<'a>, ArtifactError> {
        Ok(VmapView {
            link_offsets: a.section(sections::LINK_OFFSETS)?,
            links: a.section(sections::LINKS)?,
            light_offsets: a.section(sections::LIGHT_OFFSETS)?,
            light_links: a.section(sections::LIGHT_LINKS)?,
            node_range: a.section(sections::NODE_RANGE)?,
            node_cone: a.section(sections::NODE_CONE)?,
            vnode: a.section(sections::VNODE)?,
            smear: a.section(sections::SMEAR).map_err(|e| match e {
                ArtifactError::MissingSection { .. } => a.stale(
                    "it was made by a pc-vmap from before the `smear` section (November 2026)",
                    "pc-vmap",
                ),
                e => e,
            })?,
        })
    }

    /// The links of node-pool slot `slot`.
    pub fn links_of(&self, slot: usize) -> &'a [Link] {
        &self.links[self.link_offsets[slot] as usize..self.link_offsets[slot + 1] as usize]
    }

    /// The light list of point light `l`.
    pub fn light_list(&self, l: usize) -> &'a [Link] {
        &self.light_links[self.light_offsets[l] as usize..self.light_offsets[l + 1] as usize]
    }

    /// The structure every reader relies on: CSR indices over the links and the light links,
    /// per-node tables of one entry per node, links to nodes that exist with fractions in
    /// (0, 1], splat ranges within `splats` (when known).
    fn check(&self, lights: usize, splats: Option<usize>) -> Result<(), String> {
        let nodes = self.node_range.len();
        let csr = crate::reader::is_csr;
        if !csr(self.link_offsets, nodes, self.links.len()) {
            return Err("link offsets are not a CSR index over the links".into());
        }
        if !csr(self.light_offsets, lights, self.light_links.len()) {
            return Err(format!(
                "light offsets are not a CSR index over the light links of {lights} lights"
            ));
        }
        if self.node_cone.len() != nodes || self.vnode.len() != nodes || self.smear.len() != nodes {
            return Err(format!(
                "{} node cones, {} V-map leaf flags and {} smear records for {nodes} nodes",
                self.node_cone.len(),
                self.vnode.len(),
                self.smear.len()
            ));
        }
        if any_where(self.smear, |s| {
            let sums = [s.transfer, s.variance];
            !(s.error.is_finite()
                && sums.iter().all(|x| x.is_finite() && *x >= 0.0)
                && (0.0..=1.0).contains(&s.contact))
        }) {
            return Err("a node's smear record is not finite or has a negative sum".into());
        }
        let bad_link =
            |l: &Link| l.slot() as usize >= nodes || !(l.fraction > 0.0 && l.fraction <= 1.0);
        if any_where(self.links, bad_link) || any_where(self.light_links, bad_link) {
            return Err(
                "a link names a node outside the octree or has a fraction outside (0, 1]".into(),
            );
        }
        let splats = splats.unwrap_or(u32::MAX as usize);
        if any_where(self.node_range, |r| r[0] > r[1] || r[1] as usize > splats) {
            return Err("a node's splat range lies outside the octree's data pool".into());
        }
        if any_where(self.node_cone, |c| !(-1.0..=1.0).contains(c)) {
            return Err("a node cone's cosine lies outside [-1, 1]".into());
        }
        Ok(())
    }
}

/// An opened V-map artifact, checked once: its kind, its structure, and (with
/// [`VmapFile::open`]) that it was made for the octree and the point lights it is used with.
pub type VmapFile = Checked<VmapMeta>;

impl Checked<VmapMeta> {
    /// Open the V-map at `path` for the octree `octree` and the point lights `lights`. A V-map
    /// of another octree or other lights, or tables that do not fit the octree, are
    /// [`ArtifactError::Stale`] (rerun pc-vmap); a missing file is
    /// [`ArtifactError::MissingInput`].
    pub fn open(
        path: impl AsRef<Path>,
        octree: &OctreeId,
        lights: &[PointLight],
    ) -> Result<VmapFile, ArtifactError> {
        let art = Artifact::open_input(path, ArtifactKind::Vmap)?;
        let meta: VmapMeta = art.metadata()?;
        let stale = |why: String, rerun: &str| art.stale(why, rerun);
        if meta.octree_key != octree.key.to_string() {
            return Err(stale(
                format!(
                    "it was computed for another octree than {}",
                    octree.path.display()
                ),
                "pc-vmap",
            ));
        }
        if meta.lights != lights {
            return Err(stale(
                "its light lists are for other point lights than the config defines".into(),
                "pc-vmap (it reuses the links)",
            ));
        }
        let v = VmapView::sections(&art)?;
        if v.node_range.len() != octree.nodes {
            return Err(stale(
                format!(
                    "its tables hold {} nodes, the octree {} has {}",
                    v.node_range.len(),
                    octree.path.display(),
                    octree.nodes
                ),
                "pc-vmap",
            ));
        }
        v.check(lights.len(), Some(octree.splats))
            .map_err(|m| art.invalid(format!("{m}: rerun pc-vmap")))?;
        Ok(VmapFile { art, meta })
    }

    /// Open the V-map at `path` on its own (pc-inspect, the reuse of a previous run's links):
    /// the kind and the structure are checked, not what it was made from.
    pub fn open_alone(path: impl AsRef<Path>) -> Result<VmapFile, ArtifactError> {
        VmapFile::from_artifact(Artifact::open_kind(path, ArtifactKind::Vmap)?)
    }

    /// [`VmapFile::open_alone`] for an artifact opened already (another kind is
    /// [`ArtifactError::WrongKind`]).
    pub fn from_artifact(art: Artifact) -> Result<VmapFile, ArtifactError> {
        art.ensure_kind(ArtifactKind::Vmap)?;
        let meta: VmapMeta = art.metadata()?;
        VmapView::sections(&art)?
            .check(meta.lights.len(), None)
            .map_err(|m| art.invalid(m))?;
        Ok(VmapFile { art, meta })
    }

    /// The checked sections.
    pub fn view(&self) -> VmapView<'_> {
        VmapView::sections(&self.art).expect("the sections were checked when the file was opened")
    }
}
