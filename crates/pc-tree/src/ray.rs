//! Ray traversal through the octree and ray-splat intersection (seed §8.5.6, §8.5.8, §8.5.11).
//!
//! The walk is the seed's: enter the root box, find the cell containing the current point by a
//! descent from the root (§8.5.11), test the ray against every splat the leaf references (own and
//! overlapping, §8.5.13), and if nothing is hit inside the cell, move to the next cell along the
//! ray. The seed moves by stepping Δ past the exit plane; here the step is exact instead: in
//! normalised root coordinates every cell face is a dyadic number `k / 2^depth`, exactly
//! representable in f32, so the next point is the exit point with its exit coordinate set to the
//! face itself (leaving in +) or to the float just below it (leaving in −), and its other
//! coordinates clamped into the face. The next descent therefore lands in the face neighbour, no
//! cell is skipped however small, and no Δ needs tuning. Δ survives only as the self-hit rule
//! (hits closer than `t_min` to the origin are ignored, Fig. 17(b)).
//!
//! A hit is accepted only if it lies inside the current cell's ray interval: a referenced splat
//! may be hit beyond the cell, and a nearer surface may lie in the next cell. Because a splat is
//! referenced by every cell its disk reaches, its hit point lies in a cell the walk visits, where
//! it is accepted. Hence the nearest hit is exact (tested against brute force).

use glam::Vec3;
use pc_artifact::octree::{node, Splat};

use crate::between::Between;
use crate::OctreeView;

/// A ray with its valid parameter interval.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
    /// Hits closer than this are ignored (self-hit distance Δ, §8.5.6).
    pub t_min: f32,
    pub t_max: f32,
}

impl Ray {
    pub fn new(origin: Vec3, dir: Vec3) -> Ray {
        Ray {
            origin,
            dir,
            t_min: 0.0,
            t_max: f32::INFINITY,
        }
    }
}

/// The nearest hit of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    /// Data-pool index of the splat hit.
    pub splat: u32,
    /// Node word of the leaf in which the hit was found (its references hold every disk that
    /// covers the hit point).
    pub leaf: u32,
}

/// The slab `lo ≤ axis · x ≤ hi` that holds every disk listed in a leaf or below a node, padded
/// far above the rounding of a hit point: a ray that stays outside it can hit none of them.
/// `axis` zero with an infinite interval where the normals cancel.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Slab {
    pub axis: [f32; 3],
    pub lo: f32,
    pub hi: f32,
}

impl Slab {
    /// Holds everything.
    pub const WHOLE: Slab = Slab {
        axis: [0.0; 3],
        lo: f32::NEG_INFINITY,
        hi: f32::INFINITY,
    };

    /// `[axis x, y, z, lo, hi]`, as an artifact's leaf record holds it.
    #[inline(always)]
    pub fn to_array(self) -> [f32; 5] {
        let [x, y, z] = self.axis;
        [x, y, z, self.lo, self.hi]
    }

    /// The inverse of [`Slab::to_array`].
    #[inline(always)]
    pub fn from_array([x, y, z, lo, hi]: [f32; 5]) -> Slab {
        Slab {
            axis: [x, y, z],
            lo,
            hi,
        }
    }

    /// Whether the ray's stretch `[ray.t_min, limit]` stays outside the slab.
    #[inline(always)]
    pub fn misses(&self, ray: &Ray, limit: f32) -> bool {
        self.entry(ray, limit).is_none()
    }

    /// Where the ray's stretch `[ray.t_min, limit]` enters the slab (`ray.t_min` where it
    /// starts inside); `None` where it [misses](Slab::misses) it.
    #[inline(always)]
    pub fn entry(&self, ray: &Ray, limit: f32) -> Option<f32> {
        let ([ox, oy, oz], [dx, dy, dz]) = (ray.origin.to_array(), ray.dir.to_array());
        let [ax, ay, az] = self.axis;
        let (s0, ds) = (ax * ox + ay * oy + az * oz, ax * dx + ay * dy + az * dz);
        let (ta, tb) = ((self.lo - s0) / ds, (self.hi - s0) / ds);
        let (enter, leave) = (ta.min(tb).max(ray.t_min), ta.max(tb).min(limit));
        (enter <= leave || enter.is_nan() || leave.is_nan()).then_some(enter)
    }
}

/// Work counters of traversals, for benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TraversalStats {
    pub cells: u64,
    pub splat_tests: u64,
}

/// Which of 96 cells of a cube map (6 faces of 4 × 4) a direction falls in. Incoherent rays
/// cast in the order of this cell, and within it of their origins along the space-filling
/// curve, walk the cells the rays before them brought into the cache: the CPU's final gather
/// (pc-fmm) orders its rays so. (Not the V-map's: a node pair's rays, cast one after another,
/// are more alike than rays of one cell; ordered by cell the 4M scan's V-map took 25-30 % longer.)
pub fn direction_cell(d: Vec3) -> u32 {
    let a = d.abs();
    let (face, u, v, m) = if a.x >= a.y && a.x >= a.z {
        ((d.x < 0.0) as u32, d.y, d.z, a.x)
    } else if a.y >= a.z {
        (2 + (d.y < 0.0) as u32, d.x, d.z, a.y)
    } else {
        (4 + (d.z < 0.0) as u32, d.x, d.y, a.z)
    };
    let cell = |x: f32| (((x / m.max(1e-30) + 1.0) * 2.0) as u32).min(3);
    face * 16 + cell(u) * 4 + cell(v)
}

/// Ray parameter at which the ray crosses the splat's plane inside its disk and on the kept
/// side of its border clip (`Splat::clip`), if any. Rays parallel to the plane miss.
#[inline]
pub fn intersect_splat(origin: Vec3, dir: Vec3, s: &Splat) -> Option<f32> {
    let n = Vec3::from(s.normal);
    let denom = dir.dot(n);
    if denom.abs() < 1e-8 {
        return None;
    }
    let c = Vec3::from(s.position);
    let t = (c - origin).dot(n) / denom;
    let x = origin + dir * t;
    ((x - c).length_squared() <= s.radius * s.radius && s.within_clip(x.into())).then_some(t)
}

/// Entry and exit parameters of the ray in the box `[lo, hi]`, if it meets it.
#[inline]
pub fn ray_box(origin: Vec3, inv_dir: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, f32)> {
    let a = (lo - origin) * inv_dir;
    let b = (hi - origin) * inv_dir;
    let t0 = a.min(b).max_element();
    let t1 = a.max(b).min_element();
    (t0 <= t1 && !t0.is_nan() && !t1.is_nan()).then_some((t0, t1))
}

/// Levels of the octree (Morton bits per axis).
const MAX_LEVELS: usize = 21;
/// 2²¹, the number of deepest cells along the root's edge.
const ROOT: u32 = 1 << MAX_LEVELS;
/// Edge of a deepest cell in normalised coordinates, 2⁻²¹ (exact).
const CELL: f32 = 1.0 / ROOT as f32;

/// Integer coordinates of a normalised point in [0, 1)³ at the deepest level.
#[inline]
fn quantize(q: Vec3) -> [u32; 3] {
    [q.x, q.y, q.z].map(|c| ((c * ROOT as f32) as u32).min(ROOT - 1))
}

/// The integer coordinate (deepest cells) of the normalised coordinate `x`, clamped into the
/// cell `lo .. lo + size` along its axis (a point the rounding put just outside it).
#[inline(always)]
fn coord_in(x: f32, lo: u32, size: u32) -> u32 {
    ((x.max(0.0) * ROOT as f32) as u32)
        .min(ROOT - 1)
        .clamp(lo, lo + size - 1)
}

/// The float just below `x` (x > 0).
#[inline]
fn below(x: f32) -> f32 {
    f32::from_bits(x.to_bits() - 1)
}

/// The nearest splat hit in `[ray.t_min, ray.t_max]`.
pub fn intersect(view: &OctreeView, ray: &Ray, stats: &mut TraversalStats) -> Option<Hit> {
    walk(view, ray, stats, false, None)
}

/// Whether any splat is hit in `[ray.t_min, ray.t_max]` (shadow rays).
pub fn occluded(view: &OctreeView, ray: &Ray, stats: &mut TraversalStats) -> bool {
    walk(view, ray, stats, true, None).is_some()
}

/// Whether a splat blocks the segment, passing over the hits [`Between::ignores`]
/// (the unaccelerated twin of [`crate::accel::Accel::occluded_between`]).
pub fn occluded_between(view: &OctreeView, seg: &Between, stats: &mut TraversalStats) -> bool {
    walk(view, &seg.ray, stats, true, Some(seg)).is_some()
}

fn walk(
    view: &OctreeView,
    ray: &Ray,
    stats: &mut TraversalStats,
    any: bool,
    between: Option<&Between>,
) -> Option<Hit> {
    walk_with(
        view,
        view.nodes,
        ray,
        stats,
        |_| None,
        |w, limit, stats| {
            let (range, refs) = view.leaf(w);
            let mut best: Option<Hit> = None;
            stats.splat_tests += (range.end - range.start) as u64 + refs.len() as u64;
            for i in range.chain(refs.iter().copied()) {
                let s = &view.splats[i as usize];
                if let Some(th) = intersect_splat(ray.origin, ray.dir, s) {
                    if th >= ray.t_min
                        && th <= limit
                        && best.is_none_or(|b| th < b.t)
                        && !between.is_some_and(|b| b.ignores(th, s.normal, s.material))
                    {
                        best = Some(Hit {
                            t: th,
                            splat: i,
                            leaf: w,
                        });
                        if any {
                            return best;
                        }
                    }
                }
            }
            best
        },
    )
}

/// The walk over `nodes` (the view's node pool, or [`crate::accel::Accel`]'s copy of it whose
/// leaf and internal words point elsewhere), with the test of one leaf's splats supplied by the
/// caller (`test(node word, t limit, stats)` returns the nearest hit in `[ray.t_min, limit]`),
/// so the packed layout shares the same traversal. `slab(internal word)` may give a slab that
/// holds every disk listed below the node: where the ray's stretch `[ray.t_min, limit]` (the
/// limit being where it leaves the node's cell) misses it, the node is skipped whole, as if it
/// were empty, since none of its leaves could accept a hit; where it meets it, the walk jumps
/// to the cell where the ray enters the slab, for the same reason (docs/raytrace.md, "A jump
/// to the slab's entry"). The artifact's walk has no slabs.
#[inline(always)]
pub(crate) fn walk_with(
    view: &OctreeView,
    nodes: &[u32],
    ray: &Ray,
    stats: &mut TraversalStats,
    slab: impl Fn(u32) -> Option<Slab>,
    mut test: impl FnMut(u32, f32, &mut TraversalStats) -> Option<Hit>,
) -> Option<Hit> {
    // Normalised root coordinates: the root is [0,1)³ and t is the same parameter.
    let origin = Vec3::from(view.frame.origin);
    let qo = (ray.origin - origin) * view.frame.inv_size;
    // Adding +0 turns -0 into +0, so a zero component never picks the wrong exit face.
    let qd = ray.dir * view.frame.inv_size + Vec3::ZERO;
    let inv = qd.recip();
    let (t0, t1) = ray_box(qo, inv, Vec3::ZERO, Vec3::ONE)?;
    let t = t0.max(ray.t_min).max(0.0);
    let t_end = t1.min(ray.t_max);
    if t > t_end {
        return None;
    }
    // Where the ray leaves the cell of depth `depth` around the integer point `qi`: the cell's
    // corner, its size and the exit parameter of each axis.
    let exit = |qi: [u32; 3], depth: usize| {
        let shift = (MAX_LEVELS - depth) as u32;
        let lo_i = qi.map(|c| (c >> shift) << shift);
        let size_i = 1u32 << shift;
        let lo = Vec3::from_array(lo_i.map(|c| c as f32 * CELL));
        let hi = Vec3::from_array(lo_i.map(|c| (c + size_i) as f32 * CELL));
        let far = Vec3::select(qd.cmpge(Vec3::ZERO), hi, lo);
        (lo_i, size_i, (far - qo) * inv)
    };
    // The current point as 21-bit integer cell coordinates (exact: q·2²¹ is a scaling by a
    // power of two and the floor reads its bits), and the path of node words from the root.
    let q = (qo + qd * t).clamp(Vec3::ZERO, Vec3::splat(below(1.0)));
    let mut qi = quantize(q);
    let mut path = [0u32; MAX_LEVELS + 1];
    path[0] = nodes[0];
    // The deepest valid entry of `path` for qi.
    let mut depth = 0usize;
    // The ray's parameter at qi: where it entered qi's cell, or the slab it jumped to.
    let mut t_at = t;
    loop {
        stats.cells += 1;
        // Descend from the deepest ancestor that still contains qi (§8.5.11, resumed).
        let mut w = path[depth];
        while w & (node::LEAF | node::EMPTY) == 0 && depth < MAX_LEVELS {
            if let Some(s) = slab(w) {
                let (lo_i, size_i, ta) = exit(qi, depth);
                let Some(t_in) = s.entry(ray, ta.min_element().min(t_end)) else {
                    break;
                };
                // No disk listed below the node lies before its slab, so none of the cells the
                // ray crosses in the node before it enters the slab could accept a hit: go
                // straight to the cell where it enters (the slab's padding is far above the
                // rounding of that point, and qi stays in the node's cell).
                if t_in > t_at {
                    let q = qo + qd * t_in;
                    qi = std::array::from_fn(|a| coord_in(q[a], lo_i[a], size_i));
                    t_at = t_in;
                }
            }
            let shift = (MAX_LEVELS - 1 - depth) as u32;
            let child = ((qi[0] >> shift) & 1)
                | (((qi[1] >> shift) & 1) << 1)
                | (((qi[2] >> shift) & 1) << 2);
            w = nodes[(node::ptr(w) + child) as usize];
            depth += 1;
            path[depth] = w;
        }
        let (lo_i, size_i, ta) = exit(qi, depth);
        let t_exit = ta.min_element();
        if node::is_leaf(w) {
            let hit = test(w, t_exit.min(t_end), stats);
            if hit.is_some() {
                return hit;
            }
        }
        if t_exit >= t_end {
            return None;
        }
        // Exact step into the face neighbour(s): the exit coordinate becomes the face (+) or
        // the last cell below it (−); the others are the exit point clamped into the face.
        let next = qo + qd * t_exit;
        let mut ni = [0u32; 3];
        for axis in 0..3 {
            if ta[axis] <= t_exit {
                if qd[axis] >= 0.0 {
                    if lo_i[axis] + size_i >= ROOT {
                        return None; // leaves the root
                    }
                    ni[axis] = lo_i[axis] + size_i;
                } else {
                    if lo_i[axis] == 0 {
                        return None;
                    }
                    ni[axis] = lo_i[axis] - 1;
                }
            } else {
                ni[axis] = coord_in(next[axis], lo_i[axis], size_i);
            }
        }
        // The deepest common ancestor of the old and new points: their top equal bits.
        let diff = (qi[0] ^ ni[0]) | (qi[1] ^ ni[1]) | (qi[2] ^ ni[2]);
        let common = (diff.leading_zeros() as usize).saturating_sub(32 - MAX_LEVELS);
        depth = depth.min(common);
        qi = ni;
        // Not below a jump's parameter: a jump can land one cell short of its point (rounding),
        // and must not be taken again from there.
        t_at = t_at.max(t_exit);
    }
}

/// The least cosine between a covering splat's normal and the hit's for the two to blend
/// ([`covering`]; WGSL twin `BLEND_MIN_COS` in shaders/raytrace/render.wgsl): one surface's
/// splats, as pc-octree's area pass counts them (60°). It was "facing the same way" (> 0), and
/// two walls meeting at a right angle passed on the rounding of their normals (10⁻⁸), so a hit
/// within `thickness` radii of a corner took the other wall's light: the reference Cornell
/// box's corner lines held 15 % of its squared per-pixel error (0.0482 → 0.0445).
pub const BLEND_MIN_COS: f32 = 0.5;

/// Every splat of the leaf `leaf` (own and referenced) whose disk covers the point `x` of a
/// surface with normal `n`: within its radius in its plane and inside its border clip,
/// within `thickness · radius` of its plane, its normal within 60° of `n` ([`BLEND_MIN_COS`]).
/// Used to blend overlapping splats at a hit (§8.5.8's open issue). Returns (data-pool index,
/// weight) with the weight `(1 − (ρ/r)²)²` of the in-plane distance ρ, which falls smoothly to
/// zero at the rim.
pub fn covering(
    view: &OctreeView,
    leaf: u32,
    x: Vec3,
    n: Vec3,
    thickness: f32,
    out: &mut Vec<(u32, f32)>,
) {
    out.clear();
    let (range, refs) = view.leaf(leaf);
    for i in range.chain(refs.iter().copied()) {
        let s = &view.splats[i as usize];
        let sn = Vec3::from(s.normal);
        if sn.dot(n) <= BLEND_MIN_COS {
            continue;
        }
        let d = x - Vec3::from(s.position);
        let h = d.dot(sn);
        let rho2 = d.length_squared() - h * h;
        let r2 = s.radius * s.radius;
        if h.abs() <= thickness * s.radius && rho2 < r2 && s.within_clip((x - sn * h).into()) {
            let u = 1.0 - rho2 / r2;
            out.push((i, u * u));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every direction falls in one of the 96 cells, every cell holds some directions, and
    /// opposite directions never share one.
    #[test]
    fn directions_fall_in_96_cube_map_cells() {
        let mut seen = [0u32; 96];
        let n = 200;
        for a in 0..n {
            for b in 0..n {
                let (u1, u2) = ((a as f32 + 0.5) / n as f32, (b as f32 + 0.5) / n as f32);
                let z = 1.0 - 2.0 * u1;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = std::f32::consts::TAU * u2;
                let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                let c = direction_cell(d);
                assert!(c < 96, "{d:?} in cell {c}");
                assert_ne!(
                    c,
                    direction_cell(-d),
                    "{d:?} shares a cell with its opposite"
                );
                seen[c as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&k| k > 0), "cells never hit: {seen:?}");
        // The axes and the zero vector land somewhere valid.
        for d in [
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::ZERO,
        ] {
            assert!(direction_cell(d) < 96);
        }
    }
}
