//! Shaft culling: a proof that no disk blocks any of a bundle of segments (pc-fmm's emitters'
//! shadow rays, docs/fmm.md, "Direct light of the emitters"; the V-map's rays between two
//! nodes, docs/vmap.md, "Empty shafts").
//!
//! Every shadow ray of a group of receivers (one octree leaf's) runs from a receiver's centre,
//! inside the receivers' box `A`, to an emitter's centre, inside the emitters' box `B`, and
//! counts a hit only between `t_min` (`self_hit` receiver radii) and `t_max` (`self_hit`
//! emitter radii short of the end). Such a segment, with `s = t / len`, lies in the *shaft*
//! `⋃_{s ∈ [s0, s1]} (1 − s) A + s B` with `s0 = min t_min / max len` and
//! `s1 = 1 − min (self_hit r_e) / max len` (the convex hull of `A ∪ B` for `[0, 1]`, Haines and
//! Wallace's shaft). When no splat's disk reaches into the shaft, no ray of the group can be
//! blocked: all of its samples see the emitters, exactly as casting every ray would say, and
//! none is cast. The surfaces at the two ends (the receivers' own plane, the emitters' plane)
//! stay out of the shaft because `s0 > 0` and `s1 < 1` lift it off them.
//!
//! The test descends the octree with each node's box of its splats' disks (tight per normal:
//! a disk of radius r and normal n reaches `r √(1 − n_k²)` along axis k) and collects the
//! leaves whose box meets the shaft; the group's rays are then tested against those leaves'
//! disks alone (pc-fmm's `lanes::blocked`, the octree walk's ray-disk test, eight at a time),
//! a leaf's disks only when the ray's stretch in its box reaches the slab of its disks
//! ([`Slab`]). No leaf: every ray is open without a test.

use crate::OctreeView;
use glam::Vec3;
use pc_artifact::octree::node;
use rayon::prelude::*;

/// Axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    pub fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// The box of a disk (centre `c`, normal `n`, radius `r`), widened against rounding in
    /// the ray-disk test. Along axis k the disk reaches `r √(n_i² + n_j²) / |n|` (the other
    /// two components: no cancellation when `n` is nearly along the axis); the margin is
    /// relative to the radius and absolute to the coordinates' precision.
    pub fn of_disk(c: Vec3, n: Vec3, r: f32) -> Aabb {
        let n2 = n * n;
        let len = n.length().max(f32::MIN_POSITIVE);
        let side = Vec3::new(n2.y + n2.z, n2.x + n2.z, n2.x + n2.y).powf(0.5) / len;
        let reach = side.min(Vec3::ONE) * r * (1.0 + 1e-4)
            + Vec3::splat(1e-6 * r + 4.0 * f32::EPSILON * r)
            + c.abs() * (4.0 * f32::EPSILON);
        Aabb {
            min: c - reach,
            max: c + reach,
        }
    }
}

/// The shaft between a receivers' box and an emitters' box for `s ∈ [s0, s1]`.
#[derive(Clone, Copy, Debug)]
pub struct Shaft {
    a: Aabb,
    b: Aabb,
    s0: f32,
    s1: f32,
}

impl Shaft {
    /// The shaft of rays from points in `a` (hits counted from `t_min` on) to points in `b`
    /// (hits counted until `end` short of the target), or `None` when the margins leave no
    /// room (`s0 ≥ s1`) or a box is empty.
    pub fn new(a: Aabb, b: Aabb, t_min: f32, end: f32) -> Option<Shaft> {
        if a.is_empty() || b.is_empty() {
            return None;
        }
        let far = (b.max - a.min).abs().max((a.max - b.min).abs()).length();
        if far <= 0.0 || !far.is_finite() {
            return None;
        }
        // Half the margins: the ray test's rounding stays well inside.
        let s0 = 0.5 * t_min / far;
        let s1 = 1.0 - 0.5 * end / far;
        // The float rays drift from the exact segments by a few units in the last place of
        // their coordinates and length: widen both ends by that much.
        let scale = a
            .min
            .abs()
            .max(a.max.abs())
            .max(b.min.abs().max(b.max.abs()));
        let eps = Vec3::splat(8.0 * f32::EPSILON * (scale.max_element() + far));
        let grow = |x: Aabb| Aabb {
            min: x.min - eps,
            max: x.max + eps,
        };
        (s0 < s1).then_some(Shaft {
            a: grow(a),
            b: grow(b),
            s0,
            s1,
        })
    }

    /// Whether the box `n` meets the shaft: some `s ∈ [s0, s1]` with `n` overlapping
    /// `(1 − s) a + s b` on every axis (each axis bounds `s` by two linear inequalities).
    pub fn meets(&self, n: &Aabb) -> bool {
        let (mut lo, mut hi) = (self.s0, self.s1);
        for k in 0..3 {
            // n.min ≤ a.max + s (b.max − a.max)  and  n.max ≥ a.min + s (b.min − a.min).
            for (alpha, beta) in [
                (self.a.max[k] - n.min[k], self.b.max[k] - self.a.max[k]),
                (n.max[k] - self.a.min[k], self.a.min[k] - self.b.min[k]),
            ] {
                // alpha + s beta ≥ 0
                if beta > 0.0 {
                    lo = lo.max(-alpha / beta);
                } else if beta < 0.0 {
                    hi = hi.min(alpha / -beta);
                } else if alpha < 0.0 {
                    return false;
                }
            }
            if lo > hi {
                return false;
            }
        }
        lo <= hi
    }
}

/// The slab `lo ≤ n · x ≤ hi` that holds every disk of a leaf, `n` the leaf's mean normal: a
/// flat leaf's is as thin as its disks' rounding, where its box (a tilted face's) may be deep.
/// A ray whose stretch inside the leaf's box stays on one side of it meets none of its disks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Slab {
    pub n: Vec3,
    pub lo: f32,
    pub hi: f32,
}

impl Slab {
    /// No bound (a leaf whose normals cancel).
    pub const ALL: Slab = Slab {
        n: Vec3::ZERO,
        lo: f32::NEG_INFINITY,
        hi: f32::INFINITY,
    };

    /// The slab of disks (centre, normal, radius) along their mean normal, widened by
    /// `margin`, and relative to each radius against rounding in the ray-disk test.
    pub fn of_disks(disks: impl Iterator<Item = (Vec3, Vec3, f32)> + Clone, margin: f32) -> Slab {
        let sum: Vec3 = disks.clone().map(|(_, m, _)| m.normalize_or_zero()).sum();
        let Some(n) = sum.try_normalize() else {
            return Slab::ALL;
        };
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for (c, m, r) in disks {
            // A disk of normal m reaches r |n × m| along n (no cancellation near parallel).
            let reach =
                r * n.cross(m.normalize_or_zero()).length().min(1.0) * (1.0 + 1e-4) + 1e-4 * r;
            let d = n.dot(c);
            lo = lo.min(d - reach);
            hi = hi.max(d + reach);
        }
        Slab {
            n,
            lo: lo - margin,
            hi: hi + margin,
        }
    }
}

/// Per node-pool slot, the box of the disks of the splats under it (the leaves' own splats:
/// every splat once), and per leaf the slab of its disks.
pub struct DiskBoxes {
    boxes: Vec<Aabb>,
    slabs: Vec<Slab>,
    /// Per slot, the splat range of its subtree (the leaves' own splats are contiguous in the
    /// pool's order, and so are a subtree's).
    ranges: Vec<(u32, u32)>,
}

impl DiskBoxes {
    pub fn new(view: &OctreeView) -> DiskBoxes {
        let slots = view.nodes.len();
        let mut boxes = vec![Aabb::EMPTY; slots];
        let mut slabs = vec![Slab::ALL; slots];
        let mut ranges = vec![(u32::MAX, 0u32); slots];
        // Rounding of a ray's points along a slab's normal: a few units in the last place of the
        // scene's largest coordinate (rays run inside the scene, a few of its sizes long).
        // (A maximum, in any order the same.)
        let scale = view
            .splats
            .par_iter()
            .map(|s| Vec3::from(s.position).abs().max_element() + s.radius)
            .reduce(|| 0.0f32, f32::max);
        let margin = 64.0 * f32::EPSILON * scale;
        // The leaves, each from its own disks, in parallel.
        boxes
            .par_iter_mut()
            .zip(slabs.par_iter_mut())
            .zip(ranges.par_iter_mut())
            .enumerate()
            .for_each(|(slot, ((bx, slab), range_of))| {
                let w = view.nodes[slot];
                if !node::is_leaf(w) || node::is_empty(w) {
                    return;
                }
                let range = view.leaf(w).0;
                let disks = range.clone().map(|i| {
                    let s = &view.splats[i as usize];
                    (Vec3::from(s.position), Vec3::from(s.normal), s.radius)
                });
                for (c, n, r) in disks.clone() {
                    *bx = bx.union(Aabb::of_disk(c, n, r));
                }
                *slab = Slab::of_disks(disks, margin);
                if !range.is_empty() {
                    *range_of = (range.start, range.end);
                }
            });
        // The internal nodes from their children's: bottom-up is reverse slot order (children
        // follow their parent in the pool).
        for slot in (0..slots).rev() {
            let w = view.nodes[slot];
            if node::is_empty(w) || node::is_leaf(w) {
                continue;
            }
            let c = node::ptr(w) as usize;
            let mut bx = Aabb::EMPTY;
            for b in &boxes[c..c + 8] {
                bx = bx.union(*b);
            }
            let r = ranges[c..c + 8]
                .iter()
                .fold((u32::MAX, 0), |a, r| (a.0.min(r.0), a.1.max(r.1)));
            ranges[slot] = r;
            boxes[slot] = bx;
        }
        DiskBoxes {
            boxes,
            slabs,
            ranges,
        }
    }

    /// The splat ranges of the highest subtrees of at most `max` splats (or single leaves),
    /// in splat order: they cover every splat once.
    pub fn subtrees(&self, view: &OctreeView, max: u32) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        let mut stack = if self.ranges.is_empty() {
            Vec::new()
        } else {
            vec![0u32]
        };
        while let Some(slot) = stack.pop() {
            let (lo, hi) = self.ranges[slot as usize];
            if lo >= hi {
                continue;
            }
            let w = view.nodes[slot as usize];
            if node::is_leaf(w) || hi - lo <= max {
                out.push((lo, hi));
            } else {
                let c = node::ptr(w);
                stack.extend(c..c + 8);
            }
        }
        out.sort_unstable();
        out
    }

    /// Whether some disk's box meets the shaft: the first leaf of [`Self::leaves`] with a
    /// splat, without collecting the others. `false` proves that no ray of the shaft's
    /// segments meets a disk.
    pub fn any_meets(&self, view: &OctreeView, shaft: &Shaft, stack: &mut Vec<u32>) -> bool {
        !self.each_leaf(view, shaft, stack, |_, r| r.is_empty())
    }

    /// The octree leaves whose disks' box meets the shaft, as (splat range, box, slab), into
    /// `out`: `false` (and `out` incomplete) once their splats number more than `limit`.
    pub fn leaves(
        &self,
        view: &OctreeView,
        shaft: &Shaft,
        limit: usize,
        stack: &mut Vec<u32>,
        out: &mut Vec<((u32, u32), Aabb, Slab)>,
    ) -> bool {
        out.clear();
        let mut splats = 0usize;
        self.each_leaf(view, shaft, stack, |slot, r| {
            splats += r.len();
            let s = slot as usize;
            out.push(((r.start, r.end), self.boxes[s], self.slabs[s]));
            splats <= limit
        })
    }

    /// Each leaf whose disks' box meets the shaft, depth first, handed to `visit` with its
    /// slot and splat range until `visit` says to stop (then `false`).
    fn each_leaf(
        &self,
        view: &OctreeView,
        shaft: &Shaft,
        stack: &mut Vec<u32>,
        mut visit: impl FnMut(u32, std::ops::Range<u32>) -> bool,
    ) -> bool {
        stack.clear();
        stack.push(0);
        while let Some(slot) = stack.pop() {
            let bx = &self.boxes[slot as usize];
            if bx.is_empty() || !shaft.meets(bx) {
                continue;
            }
            let w = view.nodes[slot as usize];
            if node::is_leaf(w) {
                if !visit(slot, view.leaf(w).0) {
                    return false;
                }
            } else {
                let c = node::ptr(w);
                stack.extend(c..c + 8);
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bx(min: [f32; 3], max: [f32; 3]) -> Aabb {
        Aabb {
            min: min.into(),
            max: max.into(),
        }
    }

    #[test]
    fn the_shaft_holds_every_segment_and_leaves_out_what_is_beside_it() {
        // Floor patch under a ceiling light.
        let a = bx([0.4, 0.0, 0.4], [0.5, 0.0, 0.5]);
        let b = bx([0.45, 1.0, 0.45], [0.55, 1.0, 0.55]);
        let s = Shaft::new(a, b, 0.01, 0.01).unwrap();
        // Points on segments between the boxes, inside [s0, s1].
        for (x, y, t) in [
            ([0.4, 0.0, 0.4], [0.55, 1.0, 0.55], 0.5),
            ([0.5, 0.0, 0.45], [0.45, 1.0, 0.5], 0.1),
            ([0.42, 0.0, 0.5], [0.5, 1.0, 0.45], 0.9),
        ] {
            let p = Vec3::from(x).lerp(Vec3::from(y), t);
            assert!(s.meets(&bx(p.into(), p.into())), "{p}");
        }
        // Beside the shaft, and the two end planes.
        assert!(!s.meets(&bx([0.7, 0.4, 0.7], [0.8, 0.6, 0.8])));
        assert!(!s.meets(&bx([0.0, 0.0, 0.0], [1.0, 0.0, 1.0])));
        assert!(!s.meets(&bx([0.0, 1.0, 0.0], [1.0, 1.0, 1.0])));
        // A slab across the middle.
        assert!(s.meets(&bx([0.0, 0.5, 0.0], [1.0, 0.5, 1.0])));
        // A disk tilted a hair off an axis keeps its thickness (1 − n_y² would round to 0).
        let n = Vec3::new(2e-4, 1.0, 0.0).normalize();
        let t = Aabb::of_disk(Vec3::ZERO, n, 1.0);
        assert!(t.max.y >= 1.9e-4 && t.min.y <= -1.9e-4, "{t:?}");
        // A floor disk's box is flat.
        let d = Aabb::of_disk(Vec3::new(0.45, 0.0, 0.45), Vec3::Y, 0.05);
        assert!(d.max.y - d.min.y < 1e-6 && !s.meets(&d));
    }

    #[test]
    fn a_slab_holds_its_disks_and_a_flat_leafs_is_thin() {
        // Disks on a plane tilted off every axis (a rotated box's face): their box is deep,
        // their slab as thin as the margins.
        let m = Vec3::new(0.3, 0.2, 0.9).normalize();
        let (u, v) = m.any_orthonormal_pair();
        let disks: Vec<(Vec3, Vec3, f32)> = (0..12)
            .map(|k| {
                let (a, b) = ((k % 4) as f32 * 0.01, (k / 4) as f32 * 0.01);
                (Vec3::new(0.4, 0.7, 0.2) + a * u + b * v, m, 0.006)
            })
            .collect();
        let rim = |d: &[(Vec3, Vec3, f32)], slab: &Slab| {
            for &(c, n, r) in d {
                let (p, q) = n.any_orthonormal_pair();
                for k in 0..16 {
                    let t = k as f32 * std::f32::consts::TAU / 16.0;
                    let x = c + r * (t.cos() * p + t.sin() * q);
                    let y = slab.n.dot(x);
                    assert!(slab.lo <= y && y <= slab.hi, "{x} at {y} outside {slab:?}");
                }
            }
        };
        let flat = Slab::of_disks(disks.iter().copied(), 1e-6);
        rim(&disks, &flat);
        assert!(flat.hi - flat.lo < 1e-5, "{flat:?}");
        let bx = disks
            .iter()
            .fold(Aabb::EMPTY, |b, &(c, n, r)| b.union(Aabb::of_disk(c, n, r)));
        assert!((bx.max - bx.min).min_element() > 0.01, "{bx:?}");
        // A corner leaf (two faces): the slab widens to hold both.
        let mut corner = disks.clone();
        corner.extend(disks.iter().map(|&(c, _, r)| (c + 0.01 * m, u, r)));
        let wide = Slab::of_disks(corner.iter().copied(), 1e-6);
        rim(&corner, &wide);
        assert!(wide.hi - wide.lo > 0.01);
        // Normals that cancel bound nothing.
        let both = [(Vec3::ZERO, Vec3::X, 1.0), (Vec3::ZERO, -Vec3::X, 1.0)];
        assert_eq!(Slab::of_disks(both.into_iter(), 0.0), Slab::ALL);
    }
}
