//! The solve's unknowns on a large scan: clusters of splats instead of splats
//! (docs/fmm.md, "Scale").
//!
//! The interaction plan holds tens of tasks per unknown, and on a noisy scan their number per
//! unknown grows with the scan (normal cones straddle, so pairs refine to single splats): a
//! 1M-splat scan's plan peaked at 11 GB. Above `fmm.max_elements` active splats, the splats of
//! the smallest octree nodes are merged into **elements**: the *cut* is the highest node on
//! every root-to-leaf path that lies within a V-map leaf (no link points below a V-map leaf)
//! and is an octree leaf or holds at most `m` splats of one material class (the V-map's own
//! purity rule), `m` the smallest size that leaves at most `max_elements` cut nodes. Within a
//! cut node, splats whose normals lie within `ELEMENT_COS` of a cluster's first normal form one
//! element (a node across a corner gives one element per face): its area is the sum of their
//! areas, its position and normal their area-weighted means, its albedo, emission and source
//! their area-weighted means, so the element's equation is the area-weighted sum of its splats'.
//!
//! The FMM then runs unchanged on the elements; its leaves are the highest nodes within V-map
//! leaves that hold at most [`LEAF_ELEMENTS`] elements (or the cut nodes, if larger). What a splat
//! keeps of its own: the source term (emission, every light's direct light with its own shadow
//! rays, caustic photons) stays per splat; only the gathered light `T (L − Lₑ)` of the later
//! bounces, which varies slowly, is its element's: `L_i = E_i + ρ_i G_e(i)`.

use glam::Vec3;
use pc_artifact::octree::class;
use pc_tree::OctreeView;
use rayon::prelude::*;

use crate::error::FmmError;
use crate::solve::{Operator, Solution};
use crate::system::System;
use crate::tree::{Points, Tree, NONE};

/// Splats whose normal is within this cosine (about 25°) of a cluster's first normal join it.
pub const ELEMENT_COS: f32 = 0.9;

/// Where the cut lies on a slot: above it, on it (an element-tree leaf), or below (gone).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Cut {
    Above,
    On,
    Below,
}

/// The elements and the FMM's tree over them.
pub struct Clustering {
    /// Element of every splat (`NONE` for inactive splats).
    pub of: Vec<u32>,
    /// The elements as points (normalised frame, like the splats).
    pub points: Points,
    /// The tree over the elements ([`LEAF_ELEMENTS`]), with element ranges.
    pub tree: Tree,
    /// Largest splat count of a cut node that is not an octree leaf (`m`).
    pub node_splats: u32,
}

impl Clustering {
    /// The clustering of a scan with more than `max_elements` active splats, `None` for one
    /// solved splat by splat. `vleaf`: the V-map's per-slot leaf flags.
    pub fn new(
        view: &OctreeView,
        tree: &Tree,
        pts: &Points,
        vleaf: &[u32],
        max_elements: u64,
    ) -> Option<Clustering> {
        let active = pts.active.iter().filter(|&&a| a).count() as u64;
        if active <= max_elements || tree.slots == 0 {
            return None;
        }
        let in_vleaf = within_vleaf(tree, vleaf);
        // The smallest m whose cut has at most max_elements nodes (fewer as m grows).
        let (mut lo, mut hi) = (1u32, 1u32 << 20);
        while lo < hi {
            let m = lo + (hi - lo) / 2;
            match cut_nodes(view, tree, &in_vleaf, m).0 <= max_elements {
                true => hi = m,
                false => lo = m + 1,
            }
        }
        let (_, cut) = cut_nodes(view, tree, &in_vleaf, lo);
        let (of, mut points, ranges) = elements(tree, pts, &cut);
        let tree = element_tree(tree, &cut, &ranges, &mut points, &in_vleaf);
        Some(Clustering {
            of,
            points,
            tree,
            node_splats: lo,
        })
    }

    /// The elements' system: area-weighted means of their splats' source, emission and albedo.
    pub fn system(&self, sys: &System, pts: &Points) -> System {
        let n = self.points.pos.len();
        let mut e = System::zeros(n);
        for (i, &el) in self.of.iter().enumerate() {
            if el == NONE {
                continue;
            }
            let (k, a) = (el as usize, pts.area[i]);
            for c in 0..3 {
                e.source[k][c] += a * sys.source[i][c];
                e.emission[k][c] += a * sys.emission[i][c];
                e.albedo[k][c] += a * sys.albedo[i][c];
            }
        }
        for (k, &a) in self.points.area.iter().enumerate() {
            let w = if a > 0.0 { 1.0 / a } else { 0.0 };
            for v in [&mut e.source[k], &mut e.emission[k], &mut e.albedo[k]] {
                *v = (Vec3::from(*v) * w).into();
            }
        }
        e
    }

    /// Every splat's radiance from the elements' solution `sol` of `elements` (their
    /// [`Clustering::system`]): its own source in `splats` plus its albedo times its element's
    /// gathered light `T (L − Lₑ)`, one more product of `op`.
    pub fn radiance(
        &self,
        op: &mut dyn Operator,
        sol: &Solution,
        elements: &System,
        splats: &System,
    ) -> Result<Vec<[f32; 3]>, FmmError> {
        let reflected: Vec<[f32; 3]> = sol
            .radiance
            .iter()
            .zip(&elements.emission)
            .map(|(l, e)| std::array::from_fn(|c| l[c] - e[c]))
            .collect();
        let mut gathered = vec![[0.0f32; 3]; reflected.len()];
        op.apply(&reflected, &mut gathered)?;
        Ok(self.spread(splats, &gathered))
    }

    /// Every splat's source plus its albedo times its element's `gathered` light.
    fn spread(&self, sys: &System, gathered: &[[f32; 3]]) -> Vec<[f32; 3]> {
        self.of
            .iter()
            .enumerate()
            .map(|(i, &el)| match el {
                NONE => sys.source[i],
                _ => (Vec3::from(sys.source[i])
                    + Vec3::from(sys.albedo[i]) * Vec3::from(gathered[el as usize]))
                .into(),
            })
            .collect()
    }
}

/// Whether each slot is a V-map leaf (`vleaf`: the V-map's per-slot flags) or lies below one.
fn within_vleaf(tree: &Tree, vleaf: &[u32]) -> Vec<bool> {
    let mut within = vec![false; tree.slots];
    // Parents come before their children in the pool.
    for slot in 0..tree.slots {
        let parent = tree.parent[slot];
        within[slot] =
            (parent != NONE && within[parent as usize]) || vleaf.get(slot).is_some_and(|&v| v != 0);
    }
    within
}

/// The cut for node size `m`: how many cut nodes own active splats, and each slot's place.
fn cut_nodes(view: &OctreeView, tree: &Tree, in_vleaf: &[bool], m: u32) -> (u64, Vec<Cut>) {
    let mut cut = vec![Cut::Above; tree.slots];
    let mut count = 0u64;
    // Parents come before their children in the pool.
    for slot in 0..tree.slots {
        let parent = tree.parent[slot];
        if parent != NONE && cut[parent as usize] != Cut::Above {
            cut[slot] = Cut::Below;
            continue;
        }
        let n = tree.count(slot as u32);
        let leaf = tree.first_child[slot] == NONE;
        let pure = view.node_info[slot].class != class::MIXED;
        if n > 0 && in_vleaf[slot] && (leaf || (n <= m && pure)) {
            cut[slot] = Cut::On;
            count += (tree.active[slot] > 0) as u64;
        } else if leaf {
            // An empty slot, or a leaf outside every V-map leaf (no splat there is linked).
            cut[slot] = Cut::On;
            count += (n > 0 && tree.active[slot] > 0) as u64;
        }
    }
    (count, cut)
}

/// The elements of the cut nodes, in splat order: each splat's element, the elements as points
/// and each slot's element range (`[0, 0)` off the cut).
#[allow(clippy::type_complexity)]
fn elements(tree: &Tree, pts: &Points, cut: &[Cut]) -> (Vec<u32>, Points, Vec<[u32; 2]>) {
    let mut on: Vec<u32> = (0..tree.slots as u32)
        .filter(|&s| cut[s as usize] == Cut::On && tree.count(s) > 0)
        .collect();
    on.sort_unstable_by_key(|&s| tree.lo[s as usize]);
    let mut of = vec![NONE; pts.pos.len()];
    let mut e = Points::default();
    let mut ranges = vec![[0u32; 2]; tree.slots];
    // Per element being built: area, area × position, area × normal, first normal, first splat.
    let mut sums: Vec<(f32, Vec3, Vec3, Vec3, u32)> = Vec::new();
    for &slot in &on {
        let first = e.pos.len() as u32;
        sums.clear();
        for i in tree.lo[slot as usize]..tree.hi[slot as usize] {
            let iu = i as usize;
            if !pts.active[iu] {
                continue;
            }
            let n = Vec3::from(pts.normal[iu]);
            let k = match sums.iter().position(|s| s.3.dot(n) >= ELEMENT_COS) {
                Some(k) => k,
                None => {
                    sums.push((0.0, Vec3::ZERO, Vec3::ZERO, n, i));
                    sums.len() - 1
                }
            };
            let a = pts.area[iu];
            let s = &mut sums[k];
            s.0 += a;
            s.1 += a * Vec3::from(pts.pos[iu]);
            s.2 += a * n;
            of[iu] = first + k as u32;
        }
        for &(a, ap, an, n0, i0) in &sums {
            // Splats of zero area (none in a built octree) leave the element at its first.
            let pos = if a > 0.0 {
                ap / a
            } else {
                Vec3::from(pts.pos[i0 as usize])
            };
            e.pos.push(pos.into());
            e.normal.push(an.try_normalize().unwrap_or(n0).into());
            e.area.push(a);
            e.active.push(true);
            e.leaf.push(slot);
        }
        // A cut node whose splats are all inactive has no element (and an empty range).
        if sums.is_empty() {
            continue;
        }
        ranges[slot as usize] = [first, e.pos.len() as u32];
    }
    (of, e, ranges)
}

/// Largest element count of an element-tree leaf above a cut node: leaves of one or two
/// elements made the plan a task per element pair (a 300k-splat scan's 42k elements gave 31M
/// point-to-point tasks of 9 pairs each).
pub const LEAF_ELEMENTS: u32 = 32;

/// The tree over the elements: the full tree cut at the highest node within a V-map leaf that
/// holds at most [`LEAF_ELEMENTS`] elements (or at the cut node), element ranges bottom-up,
/// then bounds, active sums and levels recomputed from the elements, whose `leaf` it sets.
fn element_tree(
    full: &Tree,
    cut: &[Cut],
    ranges: &[[u32; 2]],
    pts: &mut Points,
    in_vleaf: &[bool],
) -> Tree {
    let mut t = full.clone();
    // Element ranges of every slot above or on the cut, bottom-up.
    for slot in (0..t.slots).rev() {
        (t.lo[slot], t.hi[slot]) = match cut[slot] {
            Cut::Below => (0, 0),
            Cut::On => (ranges[slot][0], ranges[slot][1]),
            Cut::Above => {
                let c = t.first_child[slot] as usize;
                let kids = (c..c + 8).filter(|&k| t.hi[k] > t.lo[k]);
                let lo = kids.clone().map(|k| t.lo[k]).min();
                let hi = kids.map(|k| t.hi[k]).max();
                (lo.unwrap_or(0), hi.unwrap_or(0))
            }
        };
    }
    // The leaves, top-down: the first node within a V-map leaf small enough, or the cut node.
    let mut depth = vec![0u32; t.slots];
    let mut gone = vec![false; t.slots];
    for slot in 0..t.slots {
        let parent = t.parent[slot];
        if parent != NONE {
            let p = parent as usize;
            depth[slot] = depth[p] + 1;
            gone[slot] = gone[p] || t.first_child[p] == NONE;
        }
        if gone[slot] {
            (t.lo[slot], t.hi[slot]) = (0, 0);
            t.first_child[slot] = NONE;
        } else if cut[slot] == Cut::On
            || (in_vleaf[slot] && t.hi[slot] - t.lo[slot] <= LEAF_ELEMENTS)
        {
            t.first_child[slot] = NONE;
            for k in t.lo[slot]..t.hi[slot] {
                pts.leaf[k as usize] = slot as u32;
            }
        }
    }
    cones(&mut t, pts);
    t.finish(pts, &depth);
    t
}

/// Normal cones of the elements' normals, about their area-weighted mean: tighter than the
/// splats' cones, since a scan's noisy normals average out within an element, so fewer pairs
/// straddle a cosine clamp and refine (4M-splat hall: see docs/fmm.md, "Scale").
fn cones(t: &mut Tree, pts: &Points) {
    let cones: Vec<Option<(Vec3, f32)>> = (0..t.slots)
        .into_par_iter()
        .map(|slot| {
            let (lo, hi) = (t.lo[slot] as usize, t.hi[slot] as usize);
            let normal = |k: usize| Vec3::from(pts.normal[k]);
            let sum: Vec3 = (lo..hi).map(|k| pts.area[k] * normal(k)).sum();
            let axis = sum.try_normalize()?;
            let cos = (lo..hi).map(|k| axis.dot(normal(k))).fold(1.0f32, f32::min);
            let cos = cos.clamp(-1.0, 1.0);
            Some((axis, cos))
        })
        .collect();
    for (slot, cone) in cones.into_iter().enumerate() {
        match cone {
            Some((axis, cos)) => {
                t.axis[slot] = axis.into();
                t.cone_cos[slot] = cos;
            }
            None => t.cone_cos[slot] = -1.0,
        }
    }
}
