//! The solve's unknowns on a large scan: clusters of splats instead of splats
//! (docs/fmm.md, "Scale").
//!
//! The interaction plan holds tens of tasks per unknown, and on a noisy scan their number per
//! unknown grows with the scan (normal cones straddle, so pairs refine to single splats): a
//! 1M-splat scan's plan peaked at 11 GB. Above `fmm.max_elements` active splats, the splats of
//! the smallest octree nodes are merged into **elements**: the *cut* is the highest node on
//! every root-to-leaf path that lies within a V-map leaf (no link points below a V-map leaf)
//! and is an octree leaf or holds at most `m` splats of one material class (the V-map's own
//! purity rule), `m` a small size (bisection) whose cut nodes make at most `max_elements` elements.
//! Within a cut node, splats of like normal form one element (a node across a corner gives one
//! element per face; noisy normals of one face give one element, [`groups`]): its area is the
//! sum of their areas, its position and normal their area-weighted means, its albedo, emission
//! and source their area-weighted means, so the element's equation is the area-weighted sum of
//! its splats'.
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

/// The largest cut-node size the search tries (a node this large is above every V-map leaf).
const MAX_NODE_SPLATS: u32 = 1 << 20;

/// Splats whose normal is within this cosine (about 25°) of a group's seed normal join it.
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
        let sizes = CutSizes::new(view, tree, &in_vleaf);
        // A small m whose cut makes at most max_elements elements, by bisection (elements fall
        // as m grows, not strictly: a merged node's mean seed may split a face its children
        // kept whole). A cut node holds at least one element: first the smallest m with few
        // enough nodes (cheap), then the elements counted from there. Where even the largest m
        // does not fit (the V-map's leaves alone make more), the largest: `Clustering::points`
        // tells how many it made.
        let smallest = |lo: u32, fits: &dyn Fn(u32) -> bool| {
            let (mut lo, mut hi) = (lo, MAX_NODE_SPLATS);
            while lo < hi {
                let m = lo + (hi - lo) / 2;
                match fits(m) {
                    true => hi = m,
                    false => lo = m + 1,
                }
            }
            lo
        };
        let nodes = smallest(1, &|m| cut_nodes(tree, &sizes, m).0 <= max_elements);
        let m = smallest(nodes, &|m| {
            let (_, cut) = cut_nodes(tree, &sizes, m);
            element_count(tree, pts, &cut) <= max_elements
        });
        let (_, cut) = cut_nodes(tree, &sizes, m);
        let (of, mut points, ranges) = elements(tree, pts, &cut);
        let tree = element_tree(tree, &cut, &ranges, &mut points, &in_vleaf);
        Some(Clustering {
            of,
            points,
            tree,
            node_splats: m,
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

/// For each slot, the node sizes `m` whose cut lies on it ([`cut_nodes`]): from `own`, the
/// least `m` at which it may be cut (a leaf always; a node inside a V-map leaf whose splats
/// are of one class, from its splat count on; any other node never), up to, not including,
/// `above`, the least `own` of its ancestors (from there on an ancestor is cut instead).
struct CutSizes {
    own: Vec<u64>,
    above: Vec<u64>,
}

impl CutSizes {
    const NEVER: u64 = u64::MAX;

    fn new(view: &OctreeView, tree: &Tree, in_vleaf: &[bool]) -> CutSizes {
        let own: Vec<u64> = (0..tree.slots)
            .into_par_iter()
            .map(|slot| {
                let n = tree.count(slot as u32);
                let pure = view.node_info[slot].class != class::MIXED;
                match tree.first_child[slot] == NONE {
                    true => 0,
                    false if n > 0 && in_vleaf[slot] && pure => n as u64,
                    false => Self::NEVER,
                }
            })
            .collect();
        // Parents come before their children in the pool.
        let mut above = vec![Self::NEVER; tree.slots];
        for slot in 0..tree.slots {
            let p = tree.parent[slot];
            if p != NONE {
                above[slot] = above[p as usize].min(own[p as usize]);
            }
        }
        CutSizes { own, above }
    }
}

/// The cut for node size `m`: how many cut nodes own active splats, and each slot's place.
/// (Top-down: a slot is cut where it may be and no ancestor was, and lies below a cut one;
/// [`CutSizes`] holds the bounds of `m` for each, so every `m` the bisection tries is one
/// parallel pass.)
fn cut_nodes(tree: &Tree, sizes: &CutSizes, m: u32) -> (u64, Vec<Cut>) {
    let m = m as u64;
    let cut: Vec<Cut> = sizes
        .own
        .par_iter()
        .zip(&sizes.above)
        .map(|(&own, &above)| match (above <= m, own <= m) {
            (true, _) => Cut::Below,
            (false, true) => Cut::On,
            (false, false) => Cut::Above,
        })
        .collect();
    let count = cut
        .par_iter()
        .enumerate()
        .filter(|&(s, &c)| c == Cut::On && tree.count(s as u32) > 0 && tree.active[s] > 0)
        .count() as u64;
    (count, cut)
}

/// A cut node's share of area below which a normal group joins the group of the nearest normal
/// (see [`groups`]).
pub const MINOR_SHARE: f32 = 0.125;

/// A minor group joins a major one within this cosine (60°) of its normal...
pub const MERGE_COS: f32 = 0.5;

/// ...or whatever its normal when it lies within this many of its splats' mean disk radii of
/// the major group's plane (a scan's flipped normals; on the 20M hall one radius left 77M
/// point-to-point tasks and two 45M, no limit 38M).
pub const PLANE_RADII: f32 = 2.0;

/// One normal group of a cut node: its splats' count, area, area × position and area ×
/// normal, the seed normal that gathered them, and the first of them.
#[derive(Clone, Copy)]
struct Group {
    count: u32,
    area: f32,
    pos: Vec3,
    normal: Vec3,
    seed: Vec3,
    first: u32,
}

impl Group {
    fn new(seed: Vec3) -> Group {
        Group {
            count: 0,
            area: 0.0,
            pos: Vec3::ZERO,
            normal: Vec3::ZERO,
            seed,
            first: NONE,
        }
    }

    /// Splat `i` with its normal `n` (zero for a splat without a usable one).
    fn add(&mut self, pts: &Points, i: u32, n: Vec3) {
        let a = pts.area[i as usize];
        self.count += 1;
        self.area += a;
        self.pos += a * Vec3::from(pts.pos[i as usize]);
        self.normal += a * n;
        self.first = self.first.min(i);
    }

    fn merge(&mut self, o: &Group) {
        self.count += o.count;
        self.area += o.area;
        self.pos += o.pos;
        self.normal += o.normal;
        self.first = self.first.min(o.first);
    }

    /// The area-weighted mean normal (the seed for splats of zero area).
    fn direction(&self) -> Vec3 {
        self.normal.try_normalize().unwrap_or(self.seed)
    }

    /// The area-weighted mean position (infinitely far for splats of zero area: in no plane).
    fn centre(&self) -> Vec3 {
        match self.area > 0.0 {
            true => self.pos / self.area,
            false => Vec3::INFINITY,
        }
    }

    /// The area-equivalent disk radius of its mean splat.
    fn disk_radius(&self) -> f32 {
        (self.area / (self.count.max(1) as f32 * std::f32::consts::PI)).sqrt()
    }
}

/// The normal groups of the active splats `lo..hi` (one cut node): each splat joins the first
/// group whose seed lies within [`ELEMENT_COS`] of its normal, the first seed being the splats'
/// area-weighted mean normal (the first splat's normal made the grouping hang on one noisy
/// normal), later seeds the first normal no group took. Then each group of less than
/// [`MINOR_SHARE`] of the area joins the major group of the nearest normal if that lies within
/// [`MERGE_COS`], or, whatever its normal, the major group in whose plane it lies (within
/// [`PLANE_RADII`] of its splats' mean disk radius: a scan's flipped normals). A scan's noisy and flipped normals
/// otherwise make elements of one or two splats whose odd normals widen every normal cone above
/// them (docs/fmm.md, "Scale"), while the back of a thin slab or a small face at a corner stays
/// an element of its own. A splat without a usable normal joins the first group. `of[i - lo]`
/// gets each active splat's group.
fn groups(pts: &Points, lo: u32, hi: u32, of: &mut [u32]) -> Vec<Group> {
    let active = (lo..hi).filter(|&i| pts.active[i as usize]);
    let normal = |i: u32| {
        let n = Vec3::from(pts.normal[i as usize]);
        (n.is_finite() && n.length_squared() > 0.25).then_some(n)
    };
    let mean: Vec3 = active
        .clone()
        .filter_map(|i| Some(pts.area[i as usize] * normal(i)?))
        .sum();
    let mut g: Vec<Group> = mean.try_normalize().map(Group::new).into_iter().collect();
    for i in active.clone() {
        let n = normal(i);
        let k = match n.and_then(|n| g.iter().position(|s| s.seed.dot(n) >= ELEMENT_COS)) {
            Some(k) => k,
            None if n.is_none() && !g.is_empty() => 0,
            None => {
                g.push(Group::new(n.unwrap_or(Vec3::Z)));
                g.len() - 1
            }
        };
        g[k].add(pts, i, n.unwrap_or(Vec3::ZERO));
        of[(i - lo) as usize] = k as u32;
    }
    // The major groups first, then each minor group merged into the nearest major one within
    // MERGE_COS, or kept (every group when none is major: a node of many small faces).
    let total: f32 = g.iter().map(|s| s.area).sum();
    let major = |s: &Group| s.count > 0 && s.area > 0.0 && s.area >= MINOR_SHARE * total;
    let mut to = vec![NONE; g.len()];
    let mut kept: Vec<Group> = Vec::new();
    for (k, s) in g.iter().enumerate().filter(|(_, s)| major(s)) {
        to[k] = kept.len() as u32;
        kept.push(*s);
    }
    let majors: Vec<(Vec3, Vec3)> = kept.iter().map(|s| (s.direction(), s.centre())).collect();
    let minor = g
        .iter()
        .enumerate()
        .filter(|(_, s)| s.count > 0 && !major(s));
    for (k, s) in minor {
        let n = s.direction();
        let nearest = (0..majors.len())
            .map(|x| (x, majors[x].0.dot(n)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .filter(|&(_, c)| c >= MERGE_COS);
        // Flipped normals (a scan orients some normals wrongly) lie in a major group's plane:
        // they join it whatever their normal.
        let in_plane = || {
            let (c, r) = (s.centre(), s.disk_radius());
            (0..majors.len())
                .map(|x| (x, majors[x].0.dot(c - majors[x].1).abs()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .filter(|&(_, d)| d <= PLANE_RADII * r)
        };
        match nearest.or_else(in_plane) {
            Some((x, _)) => {
                to[k] = x as u32;
                kept[x].merge(s);
            }
            None => {
                to[k] = kept.len() as u32;
                kept.push(*s);
            }
        }
    }
    for i in active {
        let o = &mut of[(i - lo) as usize];
        *o = to[*o as usize];
    }
    kept
}

/// How many elements the cut nodes make.
fn element_count(tree: &Tree, pts: &Points, cut: &[Cut]) -> u64 {
    (0..tree.slots as u32)
        .into_par_iter()
        .filter(|&s| cut[s as usize] == Cut::On && tree.count(s) > 0)
        .map_init(Vec::new, |of, s| {
            let (lo, hi) = (tree.lo[s as usize], tree.hi[s as usize]);
            of.resize((hi - lo) as usize, 0);
            groups(pts, lo, hi, of).len() as u64
        })
        .sum()
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
    for &slot in &on {
        let first = e.pos.len() as u32;
        let (lo, hi) = (tree.lo[slot as usize], tree.hi[slot as usize]);
        let local = &mut of[lo as usize..hi as usize];
        let g = groups(pts, lo, hi, local);
        for (i, o) in (lo..hi).zip(local.iter_mut()) {
            *o = match pts.active[i as usize] {
                true => first + *o,
                false => NONE,
            };
        }
        for s in &g {
            // Splats of zero area (none in a built octree) leave the element at its first.
            let pos = match s.area > 0.0 {
                true => s.pos / s.area,
                false => Vec3::from(pts.pos[s.first as usize]),
            };
            e.pos.push(pos.into());
            e.normal.push(s.direction().into());
            e.area.push(s.area);
            e.active.push(true);
            e.leaf.push(slot);
        }
        // A cut node whose splats are all inactive has no element (and an empty range).
        if g.is_empty() {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Splats of area 1 at the origin with the given normals.
    fn splats(normals: &[Vec3]) -> Points {
        let n = normals.len();
        Points {
            pos: vec![[0.0; 3]; n],
            normal: normals.iter().map(|v| v.normalize().into()).collect(),
            area: vec![1.0; n],
            active: vec![true; n],
            leaf: vec![0; n],
        }
    }

    /// A normal tilted from +z by `deg` degrees towards the azimuth `az` (radians).
    fn tilted(deg: f32, az: f32) -> Vec3 {
        let t = deg.to_radians();
        Vec3::new(t.sin() * az.cos(), t.sin() * az.sin(), t.cos())
    }

    #[test]
    fn noisy_normals_of_one_face_make_one_element() {
        // 64 normals within 20° of +z, and three outliers at 30-40° that the first-normal rule
        // made into elements of their own.
        let mut normals: Vec<Vec3> = (0..64)
            .map(|k| tilted((k % 5) as f32 * 5.0, k as f32 * 2.4))
            .collect();
        normals.extend([tilted(30.0, 0.3), tilted(35.0, 2.0), tilted(40.0, 4.0)]);
        let pts = splats(&normals);
        let mut of = vec![0; normals.len()];
        let g = groups(&pts, 0, normals.len() as u32, &mut of);
        assert_eq!(g.len(), 1);
        assert!(of.iter().all(|&k| k == 0));
        assert_eq!(g[0].count, normals.len() as u32);
        assert!((g[0].area - normals.len() as f32).abs() < 1e-3);
    }

    #[test]
    fn a_corner_keeps_one_element_per_face_and_slivers_join_the_nearest() {
        // Floor (+z) 40 splats, wall (+x) 24, 2 splats 40° off the wall towards +y, and 2 facing
        // down (the back of a thin slab): each sliver is under an eighth of the area; the first
        // joins the wall, the nearer normal, the second is within 60° of no face and stays.
        let mut normals = vec![Vec3::Z; 40];
        normals.extend(vec![Vec3::X; 24]);
        let off = Vec3::new(40f32.to_radians().cos(), 40f32.to_radians().sin(), 0.0);
        normals.extend([off, off, -Vec3::Z, -Vec3::Z]);
        let mut pts = splats(&normals);
        // The floor in z = 0, the wall in x = 0, the slab's back 3 from both planes (the splats'
        // disk radius is 0.56).
        for k in 0..40 {
            pts.pos[k] = [0.5 + (k % 8) as f32 * 0.5, 0.5 + (k / 8) as f32 * 0.5, 0.0];
        }
        for k in 40..64 {
            pts.pos[k] = [0.0, 0.5 + (k % 6) as f32 * 0.5, 0.5 + (k / 6) as f32 * 0.1];
        }
        pts.pos[66] = [3.0, 3.0, -3.0];
        pts.pos[67] = [3.0, 3.0, -3.0];
        let mut of = vec![0; normals.len()];
        let g = groups(&pts, 0, normals.len() as u32, &mut of);
        assert_eq!(g.len(), 3);
        assert_eq!(g.iter().map(|s| s.count).sum::<u32>(), 68);
        let (floor, wall, back) = (of[0] as usize, of[40] as usize, of[66] as usize);
        assert_eq!(g[floor].count, 40);
        assert_eq!(
            g[wall].count, 26,
            "the sliver joins the wall, the nearer normal"
        );
        assert_eq!((of[64], of[65]), (wall as u32, wall as u32));
        assert_eq!(g[back].count, 2, "the slab's back stays its own element");
        assert!(g[back].direction().dot(-Vec3::Z) > 0.999);
    }

    #[test]
    fn flipped_normals_in_a_faces_plane_join_it() {
        // A floor of 40 splats at z = 0 and 3 of them with the normal flipped: they lie in the
        // floor's plane and join it, though their normal is opposite.
        let mut normals = vec![Vec3::Z; 40];
        normals.extend([-Vec3::Z; 3]);
        let mut pts = splats(&normals);
        for (k, p) in pts.pos.iter_mut().enumerate() {
            *p = [k as f32 * 0.3, (k % 7) as f32 * 0.2, 0.01 * (k % 3) as f32];
        }
        let mut of = vec![0; normals.len()];
        let g = groups(&pts, 0, normals.len() as u32, &mut of);
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].count, 43);
    }

    #[test]
    fn a_splat_without_a_usable_normal_joins_the_first_group() {
        let mut normals = vec![Vec3::Z; 8];
        normals.push(Vec3::X);
        let mut pts = splats(&normals);
        pts.normal.push([f32::NAN, 0.0, 0.0]);
        pts.normal.push([0.0; 3]);
        pts.pos.extend([[0.0; 3]; 2]);
        pts.area.extend([1.0, 1.0]);
        pts.active.extend([true, true]);
        pts.leaf.extend([0, 0]);
        let mut of = vec![0; 11];
        let g = groups(&pts, 0, 11, &mut of);
        assert_eq!((of[9], of[10]), (of[0], of[0]));
        assert!(g
            .iter()
            .all(|s| s.normal.is_finite() && s.direction().is_finite()));
        assert_eq!(g.iter().map(|s| s.count).sum::<u32>(), 11);
    }

    #[test]
    fn a_node_of_many_small_faces_keeps_them_all() {
        // Ten faces 36° apart around a cone, none a major share: every one stays an element.
        let normals: Vec<Vec3> = (0..10)
            .flat_map(|k| vec![tilted(60.0, k as f32 * std::f32::consts::TAU / 10.0); 3])
            .collect();
        let pts = splats(&normals);
        let mut of = vec![0; normals.len()];
        let g = groups(&pts, 0, normals.len() as u32, &mut of);
        assert_eq!(g.len(), 10);
        assert!(g.iter().all(|s| s.count == 3));
    }
}
