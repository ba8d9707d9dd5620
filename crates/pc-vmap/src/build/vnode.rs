//! The V-map's nodes ([`VNode`]: what it needs of each node-pool slot) and the tests of a
//! pair of them that need no ray: facing, well separated.

use glam::Vec3;
use pc_artifact::octree::node;
use pc_tree::OctreeView;
use rayon::prelude::*;

/// What the V-map needs per node-pool slot.
#[derive(Clone, Copy, Debug, Default)]
pub struct VNode {
    /// Own splats of the subtree, `[lo, hi)` in the data pool.
    pub lo: u32,
    pub hi: u32,
    pub center: Vec3,
    pub radius: f32,
    pub axis: Vec3,
    /// Cosine of the normal cone's half-angle; -1 when the normals span every direction.
    pub cone_cos: f32,
    /// No pair goes below a V-map leaf.
    pub vleaf: bool,
    /// The summed areas of its splats (in data-pool order, as f64).
    pub area: f64,
    /// For an octree leaf, its roughness (`pc_tree::between::leaf_roughness`), which sets its
    /// splats' own zones; zero elsewhere.
    pub rough: f32,
}

impl VNode {
    pub fn count(&self) -> u32 {
        self.hi - self.lo
    }
}

/// Subtree ranges, normal cones ([`pc_tree::nodes`]) and V-map leaves of every node-pool slot.
pub fn vnodes(view: &OctreeView, leaf_splats: u32) -> Vec<VNode> {
    let ranges = pc_tree::nodes::subtree_ranges(view);
    let cones = pc_tree::nodes::normal_cones(view, &ranges);
    let rough = pc_tree::between::leaf_roughness(view);
    ranges
        .par_iter()
        .zip(&cones)
        .zip(&rough)
        .enumerate()
        .map(|(slot, ((&[lo, hi], &cone_cos), &rough))| {
            if lo >= hi {
                return VNode {
                    cone_cos: -1.0,
                    ..Default::default()
                };
            }
            let info = &view.node_info[slot];
            VNode {
                lo,
                hi,
                center: Vec3::from(info.centroid),
                radius: info.disk_radius,
                axis: Vec3::from(info.normal),
                cone_cos,
                // A V-map leaf's fraction applies to all its splats alike: never mix classes (a
                // light and the ceiling just behind it are not equally visible).
                vleaf: node::is_leaf(view.nodes[slot])
                    || (hi - lo <= leaf_splats && info.class != pc_artifact::octree::class::MIXED),
                area: view.splat_area[lo as usize..hi as usize]
                    .iter()
                    .map(|&a| a as f64)
                    .sum(),
                rough,
            }
        })
        .collect()
}

/// The roughness of the octree leaf that owns splat `i` (its own zone's tolerance).
pub(crate) fn end_rough(view: &OctreeView, vn: &[VNode], i: u32) -> f32 {
    vn[view.splat_leaf[i as usize] as usize].rough
}

/// Non-empty children of an internal node.
pub fn children<'v>(
    view: &OctreeView,
    vn: &'v [VNode],
    slot: u32,
) -> impl Iterator<Item = u32> + 'v {
    let w = view.nodes[slot as usize];
    let first = if node::is_leaf(w) || node::is_empty(w) {
        0
    } else {
        node::ptr(w)
    };
    let count = if first == 0 { 0 } else { 8 };
    (first..first + count).filter(move |&c| vn[c as usize].count() > 0)
}

/// Whether some normal of `a`'s cone can face a direction within `spread` of `dir`.
#[inline]
pub(super) fn faces(a: &VNode, dir: Vec3, spread: f32) -> bool {
    if a.cone_cos <= -1.0 {
        return true;
    }
    let angle = a.axis.dot(dir).clamp(-1.0, 1.0).acos();
    angle < std::f32::consts::FRAC_PI_2 + a.cone_cos.clamp(-1.0, 1.0).acos() + spread + 1e-4
}

/// Conservative normal-cone test: can any splat of `a` face any splat of `b` and vice versa?
pub fn may_face(a: &VNode, b: &VNode) -> bool {
    let d = b.center - a.center;
    let dist = d.length();
    if dist <= 1e-12 {
        return true;
    }
    let dir = d / dist;
    let spread = ((a.radius + b.radius) / dist).min(1.0).asin();
    faces(a, dir, spread) && faces(b, -dir, spread)
}

/// Opening criterion of the FMM: (R_a + R_b) / distance < theta.
#[inline]
pub fn well_separated(a: &VNode, b: &VNode, theta: f32) -> bool {
    (a.radius + b.radius) < theta * (b.center - a.center).length()
}
