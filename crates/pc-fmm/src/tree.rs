//! The octree as the FMM sees it: per node-pool slot its own-splat range, expansion centre,
//! radius, normal cone and source area, and the splats in the octree's normalised frame
//! (positions in the unit root cube, areas over size²: form factors are scale-free, and the
//! expansions stay well inside f32 range whatever the scan's units).

use glam::Vec3;
use pc_artifact::octree::{class, node, MaterialRecord};
use pc_tree::OctreeView;
use rayon::prelude::*;

pub const NONE: u32 = u32::MAX;

/// Splats in the normalised frame.
#[derive(Clone, Debug, Default)]
pub struct Points {
    pub pos: Vec<[f32; 3]>,
    pub normal: Vec<[f32; 3]>,
    /// Splat area over size².
    pub area: Vec<f32>,
    /// Diffuse and emitting splats take part in the solve; specular ones neither send nor
    /// receive (§8.5.15).
    pub active: Vec<bool>,
    /// Node-pool slot of the leaf that owns each splat.
    pub leaf: Vec<u32>,
}

/// Per node-pool slot geometry and the level structure of the passes.
#[derive(Clone, Debug, Default)]
pub struct Tree {
    pub slots: usize,
    /// Own-splat range `[lo, hi)` of the subtree (empty: lo == hi).
    pub lo: Vec<u32>,
    pub hi: Vec<u32>,
    /// First child slot of an internal node, `NONE` for leaves and empty slots.
    pub first_child: Vec<u32>,
    pub parent: Vec<u32>,
    /// Expansion centre (the node's area-weighted centroid).
    pub center: Vec<[f32; 3]>,
    /// Largest distance of a splat centre from `center`.
    pub radius: Vec<f32>,
    /// Largest area-equivalent disk radius `sqrt(A/π)` of the subtree's active splats.
    pub disk: Vec<f32>,
    /// Bounding box of the splat centres: min and max corners.
    pub bmin: Vec<[f32; 3]>,
    pub bmax: Vec<[f32; 3]>,
    /// Normal cone: axis and cosine of the half-angle (-1: any direction).
    pub axis: Vec<[f32; 3]>,
    pub cone_cos: Vec<f32>,
    /// Area of the active splats (the sources) in the subtree.
    pub area: Vec<f32>,
    /// Number of active splats (the receivers) in the subtree.
    pub active: Vec<u32>,
    /// Compact expansion index per slot (`NONE` for empty slots), and back.
    pub compact: Vec<u32>,
    pub nodes: Vec<u32>,
    /// Slots per depth, root first.
    pub levels: Vec<Vec<u32>>,
    /// Leaf slots that own splats.
    pub leaves: Vec<u32>,
    /// Compact leaf index per slot (`NONE` elsewhere).
    pub leaf_index: Vec<u32>,
}

impl Tree {
    #[inline]
    pub fn is_leaf(&self, slot: u32) -> bool {
        self.first_child[slot as usize] == NONE
    }

    #[inline]
    pub fn count(&self, slot: u32) -> u32 {
        self.hi[slot as usize] - self.lo[slot as usize]
    }

    /// Non-empty children of an internal node.
    pub fn children(&self, slot: u32) -> impl Iterator<Item = u32> + '_ {
        let first = self.first_child[slot as usize];
        let n = if first == NONE { 0 } else { 8 };
        (0..n)
            .map(move |k| first + k)
            .filter(move |&c| self.hi[c as usize] > self.lo[c as usize])
    }
}

/// Whether a material class takes part in the radiosity solve.
pub fn is_active(materials: &[MaterialRecord], material: u32) -> bool {
    materials
        .get(material as usize)
        .is_some_and(|m| m.class == class::DIFFUSE || m.class == class::EMITTER)
}

/// Build the FMM's view of an octree.
pub fn build(view: &OctreeView, materials: &[MaterialRecord]) -> (Tree, Points) {
    let pts = points(view, materials);
    let mut t = Tree::empty(view.nodes.len());
    let depth = t.link(view);
    // Ranges and normal cones as every stage computes them.
    let ranges = pc_tree::nodes::subtree_ranges(view);
    let cones = pc_tree::nodes::normal_cones(view, &ranges);
    for (slot, &[lo, hi]) in ranges.iter().enumerate() {
        t.lo[slot] = lo;
        t.hi[slot] = hi;
    }
    t.set_centres(view, &ranges, &cones);
    t.finish(&pts, &depth);
    (t, pts)
}

/// The splats in the root cube's normalised frame (positions in [0, 1)³, areas over size²).
fn points(view: &OctreeView, materials: &[MaterialRecord]) -> Points {
    let f = &view.frame;
    let origin = Vec3::from(f.origin);
    let inv = f.inv_size;
    let splats = view.splats.par_iter();
    Points {
        pos: splats
            .clone()
            .map(|s| ((Vec3::from(s.position) - origin) * inv).into())
            .collect(),
        normal: splats.clone().map(|s| s.normal).collect(),
        area: view.splat_area.par_iter().map(|&a| a * inv * inv).collect(),
        active: splats.map(|s| is_active(materials, s.material)).collect(),
        leaf: view.splat_leaf.par_iter().copied().collect(),
    }
}

impl Tree {
    /// A tree of `slots` slots with nothing filled in.
    fn empty(slots: usize) -> Tree {
        Tree {
            slots,
            lo: vec![0; slots],
            hi: vec![0; slots],
            first_child: vec![NONE; slots],
            parent: vec![NONE; slots],
            center: vec![[0.0; 3]; slots],
            radius: vec![0.0; slots],
            disk: vec![0.0; slots],
            bmin: vec![[0.0; 3]; slots],
            bmax: vec![[0.0; 3]; slots],
            axis: vec![[0.0; 3]; slots],
            cone_cos: vec![-1.0; slots],
            area: vec![0.0; slots],
            active: vec![0; slots],
            compact: vec![NONE; slots],
            ..Default::default()
        }
    }

    /// Children and parents from the node pool, top-down (children always follow their parent
    /// in the pool). Returns each slot's depth.
    pub(crate) fn link(&mut self, view: &OctreeView) -> Vec<u32> {
        let mut depth = vec![0u32; self.slots];
        for slot in 0..self.slots {
            let w = view.nodes[slot];
            if !node::is_leaf(w) && !node::is_empty(w) {
                let c = node::ptr(w);
                self.first_child[slot] = c;
                for k in 0..8 {
                    self.parent[(c + k) as usize] = slot as u32;
                    depth[(c + k) as usize] = depth[slot] + 1;
                }
            }
        }
        depth
    }

    /// Everything that follows from the ranges, links, centres and cones: active area and
    /// count, bounds, compact indices and levels (`depth`: each slot's depth).
    pub(crate) fn finish(&mut self, pts: &Points, depth: &[u32]) {
        self.sum_active(pts);
        self.bound(pts);
        self.index(depth);
    }

    /// Active area and count: each leaf's from its splats (in parallel), then the internal
    /// nodes' bottom-up (children always follow their parent in the pool).
    fn sum_active(&mut self, pts: &Points) {
        let leaf_sums: Vec<(f32, u32)> = (0..self.slots)
            .into_par_iter()
            .map(|slot| {
                let (lo, hi) = (self.lo[slot], self.hi[slot]);
                let mut sum = (0.0f32, 0u32);
                if lo < hi && self.first_child[slot] == NONE {
                    for i in lo as usize..hi as usize {
                        if pts.active[i] {
                            sum.0 += pts.area[i];
                            sum.1 += 1;
                        }
                    }
                }
                sum
            })
            .collect();
        for slot in (0..self.slots).rev() {
            let (lo, hi) = (self.lo[slot], self.hi[slot]);
            (self.area[slot], self.active[slot]) = (0.0, 0);
            if lo >= hi {
                continue;
            }
            if self.first_child[slot] == NONE {
                (self.area[slot], self.active[slot]) = leaf_sums[slot];
            } else {
                let c = self.first_child[slot] as usize;
                for k in c..c + 8 {
                    if self.hi[k] > self.lo[k] {
                        self.area[slot] += self.area[k];
                        self.active[slot] += self.active[k];
                    }
                }
            }
        }
    }

    /// Expansion centres (the nodes' centroids in the normalised frame) and the normal cones.
    fn set_centres(&mut self, view: &OctreeView, ranges: &[[u32; 2]], cones: &[f32]) {
        let origin = Vec3::from(view.frame.origin);
        let inv = view.frame.inv_size;
        let geo: Vec<([f32; 3], [f32; 3], f32)> = (0..self.slots)
            .into_par_iter()
            .map(|slot| {
                if ranges[slot][0] >= ranges[slot][1] {
                    return ([0.0; 3], [0.0; 3], -1.0);
                }
                let info = &view.node_info[slot];
                let c = (Vec3::from(info.centroid) - origin) * inv;
                (c.into(), info.normal, cones[slot])
            })
            .collect();
        for (slot, (c, a, k)) in geo.into_iter().enumerate() {
            self.center[slot] = c;
            self.axis[slot] = a;
            self.cone_cos[slot] = k;
        }
    }

    /// Bounds, bottom-up: boxes exact; radii about the centres exact at leaves and bounded
    /// through the children above; the largest active disk radius. The leaves from their
    /// splats in parallel, then the internal nodes from their children.
    fn bound(&mut self, pts: &Points) {
        let (los, his, first_child, center) = (&self.lo, &self.hi, &self.first_child, &self.center);
        self.bmin
            .par_iter_mut()
            .zip(self.bmax.par_iter_mut())
            .zip(self.disk.par_iter_mut())
            .zip(self.radius.par_iter_mut())
            .enumerate()
            .for_each(|(slot, (((bmin_of, bmax_of), disk_of), radius_of))| {
                let (lo, hi) = (los[slot] as usize, his[slot] as usize);
                if lo >= hi || first_child[slot] != NONE {
                    return;
                }
                let (mut bmin, mut bmax) =
                    (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
                let mut disk = 0.0f32;
                for i in lo..hi {
                    bmin = bmin.min(Vec3::from(pts.pos[i]));
                    bmax = bmax.max(Vec3::from(pts.pos[i]));
                    if pts.active[i] {
                        disk = disk.max((pts.area[i] * std::f32::consts::FRAC_1_PI).sqrt());
                    }
                }
                let c = Vec3::from(center[slot]);
                (*bmin_of, *bmax_of, *disk_of) = (bmin.into(), bmax.into(), disk);
                *radius_of = pts.pos[lo..hi]
                    .iter()
                    .map(|&p| (Vec3::from(p) - c).length())
                    .fold(0.0f32, f32::max);
            });
        for slot in (0..self.slots).rev() {
            let (lo, hi) = (self.lo[slot], self.hi[slot]);
            if lo >= hi || self.first_child[slot] == NONE {
                continue;
            }
            let (mut bmin, mut bmax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            let mut disk = 0.0f32;
            let c = Vec3::from(self.center[slot]);
            let mut radius = 0.0f32;
            for k in self.children(slot as u32).map(|k| k as usize) {
                bmin = bmin.min(Vec3::from(self.bmin[k]));
                bmax = bmax.max(Vec3::from(self.bmax[k]));
                disk = disk.max(self.disk[k]);
                radius = radius.max((Vec3::from(self.center[k]) - c).length() + self.radius[k]);
            }
            self.disk[slot] = disk;
            self.bmin[slot] = bmin.into();
            self.bmax[slot] = bmax.into();
            self.radius[slot] = radius;
        }
    }

    /// Compact indices of the non-empty slots, the levels and the leaves.
    fn index(&mut self, depth: &[u32]) {
        self.nodes.clear();
        self.leaves.clear();
        self.compact = vec![NONE; self.slots];
        let max_depth = depth.iter().copied().max().unwrap_or(0) as usize;
        self.levels = vec![Vec::new(); max_depth + 1];
        self.leaf_index = vec![NONE; self.slots];
        for (slot, &d) in depth.iter().enumerate().take(self.slots) {
            if self.hi[slot] > self.lo[slot] {
                self.compact[slot] = self.nodes.len() as u32;
                self.nodes.push(slot as u32);
                self.levels[d as usize].push(slot as u32);
                if self.first_child[slot] == NONE {
                    self.leaf_index[slot] = self.leaves.len() as u32;
                    self.leaves.push(slot as u32);
                }
            }
        }
        while self.levels.last().is_some_and(|l| l.is_empty()) {
            self.levels.pop();
        }
    }
}
