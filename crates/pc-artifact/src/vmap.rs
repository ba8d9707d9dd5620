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

use bytemuck::{Pod, Zeroable};

/// Section names of a vmap artifact.
pub mod sections {
    pub const LINK_OFFSETS: &str = "link_offsets";
    pub const LINKS: &str = "links";
    pub const LIGHT_OFFSETS: &str = "light_offsets";
    pub const LIGHT_LINKS: &str = "light_links";
    pub const NODE_RANGE: &str = "node_range";
    pub const NODE_CONE: &str = "node_cone";
    pub const VNODE: &str = "vnode";
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

/// Parameters that shape the links (they are part of the links key).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct VmapParams {
    /// Opening criterion: two nodes are well separated when (R_a + R_b) / distance < theta.
    pub theta: f32,
    /// Visibility rays per far-field node pair.
    pub rays: u32,
    /// Near-field pairs: every splat pair up to this many, else this many samples.
    pub near_rays: u32,
    /// Nodes with at most this many splats are V-map leaves.
    pub leaf_splats: u32,
    /// Self-hit distance in radii (§8.5.6).
    pub self_hit: f32,
    /// Partly visible pairs whose form factor (either way) is below this keep a partial link
    /// instead of being refined; 0 refines every partial pair down to V-map leaves.
    pub refine_form_factor: f32,
    /// Far pairs whose form factor (either way, from the sample weights) is at least
    /// `heavy_form_factor` get `heavy_rays` rays instead of `rays` (0 or ≤ `rays`: off).
    #[serde(default)]
    pub heavy_rays: u32,
    #[serde(default)]
    pub heavy_form_factor: f32,
    pub seed: u32,
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
    /// The point lights the light lists were computed for: position then intensity.
    pub lights: Vec<[f32; 6]>,
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

/// The tables of a vmap artifact, checked against the octree they are used with.
pub struct Tables<'a> {
    pub meta: VmapMeta,
    pub link_offsets: &'a [u32],
    pub links: &'a [Link],
    pub light_offsets: &'a [u32],
    pub light_links: &'a [Link],
    pub node_range: &'a [[u32; 2]],
}

impl<'a> Tables<'a> {
    /// Open the tables of `vm`, made for the octree with key `octree_key` and `nodes` node-pool
    /// slots and for the point lights `lights`. A V-map of another octree or other lights, or
    /// tables that do not fit the octree, are errors that name the file and say what to rerun.
    pub fn open(
        vm: &'a crate::Artifact,
        octree_key: &crate::Key,
        nodes: usize,
        splats: usize,
        lights: &[[f32; 6]],
    ) -> Result<Tables<'a>, String> {
        let path = vm.path().display();
        let meta: VmapMeta = vm.metadata().map_err(|e| e.to_string())?;
        if meta.octree_key != octree_key.to_string() {
            return Err(format!(
                "{path}: stale V-map: it was computed for another octree: rerun pc-vmap"
            ));
        }
        if meta.lights != lights {
            return Err(format!(
                "{path}: stale V-map: its light lists are for other point lights than the \
                 config defines: rerun pc-vmap (it reuses the links)"
            ));
        }
        let e = |x: crate::ArtifactError| x.to_string();
        let t = Tables {
            link_offsets: vm.section(sections::LINK_OFFSETS).map_err(e)?,
            links: vm.section(sections::LINKS).map_err(e)?,
            light_offsets: vm.section(sections::LIGHT_OFFSETS).map_err(e)?,
            light_links: vm.section(sections::LIGHT_LINKS).map_err(e)?,
            node_range: vm.section(sections::NODE_RANGE).map_err(e)?,
            meta,
        };
        if t.link_offsets.len() != nodes + 1
            || *t.link_offsets.last().unwrap_or(&0) as usize != t.links.len()
            || t.light_offsets.len() != lights.len() + 1
            || *t.light_offsets.last().unwrap_or(&0) as usize != t.light_links.len()
            || t.node_range.len() != nodes
            || t.node_range
                .iter()
                .any(|r| r[0] > r[1] || r[1] as usize > splats)
            || t.links
                .iter()
                .chain(t.light_links)
                .any(|l| l.slot() as usize >= nodes)
            || t.link_offsets.windows(2).any(|w| w[0] > w[1])
            || t.light_offsets.windows(2).any(|w| w[0] > w[1])
        {
            return Err(format!(
                "{path}: the link tables do not fit the octree: rerun pc-vmap"
            ));
        }
        Ok(t)
    }

    /// The light list of point light `l`.
    pub fn light_list(&self, l: usize) -> &'a [Link] {
        &self.light_links[self.light_offsets[l] as usize..self.light_offsets[l + 1] as usize]
    }
}
