//! Per node-pool slot: the data-pool range its subtree owns and its normal cone, computed once
//! for every stage that reasons about whole nodes (pc-vmap stores both in its artifact; pc-fmm
//! builds its tree from them).

use glam::Vec3;
use pc_artifact::octree::node;
use rayon::prelude::*;

use crate::OctreeView;

/// The data-pool range `[lo, hi)` of the splats each node's subtree owns (contiguous, the data
/// pool being in Morton order); `[0, 0)` for nodes without splats.
pub fn subtree_ranges(view: &OctreeView) -> Vec<[u32; 2]> {
    let n = view.nodes.len();
    let mut range = vec![[0u32; 2]; n];
    // Bottom-up: children always follow their parent in the pool.
    for slot in (0..n).rev() {
        let w = view.nodes[slot];
        if node::is_empty(w) {
            continue;
        }
        if node::is_leaf(w) {
            let (r, _) = view.leaf(w);
            if r.end > r.start {
                range[slot] = [r.start, r.end];
            }
        } else {
            let c = node::ptr(w) as usize;
            let (mut lo, mut hi) = (u32::MAX, 0u32);
            for &[a, b] in &range[c..c + 8] {
                if a < b {
                    lo = lo.min(a);
                    hi = hi.max(b);
                }
            }
            if lo < hi {
                range[slot] = [lo, hi];
            }
        }
    }
    range
}

/// Each node's normal cone about its average normal (`NodeInfo::normal`): the cosine of its
/// half-angle, the smallest `axis · n` over the subtree's splats; −1 (any direction) for nodes
/// without splats or whose normals cancel out.
pub fn normal_cones(view: &OctreeView, ranges: &[[u32; 2]]) -> Vec<f32> {
    ranges
        .par_iter()
        .zip(view.node_info)
        .map(|(&[lo, hi], info)| {
            let axis = Vec3::from(info.normal);
            if lo >= hi || axis == Vec3::ZERO {
                return -1.0;
            }
            view.splats[lo as usize..hi as usize]
                .iter()
                .map(|s| axis.dot(Vec3::from(s.normal)))
                .fold(1.0f32, f32::min)
                // A node of one normal rounds to just above 1 (the 20M scan had one).
                .clamp(-1.0, 1.0)
        })
        .collect()
}
