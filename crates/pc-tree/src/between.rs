//! Visibility between two surface points, past the roughness of the surfaces themselves
//! (docs/vmap.md, "Rough surfaces").
//!
//! A scanned wall is flat, but its splats are not: range noise moves each centre off the
//! surface and the normals fitted to noisy neighbours tilt each disk, so disks stand a fraction
//! of their radius proud of their neighbours. A ray leaving such a surface at a shallow angle
//! meets those neighbours and reads the scanner's noise as an occluder: on a 1M-point virtual
//! scan half the V-map's rays were blocked, two thirds of them by a disk facing like the end it
//! left, 88 % of those within half a radius of that end's tangent plane and 99 % within one,
//! against 1 blocked ray in 50 on the smooth Cornell box (`examples/blockers.rs` in pc-vmap
//! measures it).
//!
//! The rule: along a ray from a splat of normal `n` and radius `r`, the point at distance `t`
//! stands `t · cos θ` above the splat's tangent plane (θ between the ray and `n`). Up to the
//! distance where that height passes `h + `[`OWN_SLOPE`]` · t`, with `h = `[`OWN_HEIGHT`]` · r +
//! `[`OWN_ROUGH`]` · σ` (σ the roughness of the splat's octree leaf, [`leaf_roughness`]), and at
//! most [`OWN_REACH`]` · h`, the ray is within the surface's own roughness, its *own zone*, where
//! hits on splats of the end's material facing like `n` (cosine above
//! [`OWN_COS`]) are the surface itself and are ignored. Any other surface
//! there still blocks: the wall at a room's corner, a ball resting on the floor. `OWN_SLOPE`
//! allows for the end's own normal being off by about 6°, which tilts its tangent plane away
//! from the surface's.
//!
//! Why the material: at a splat's resolution a separate surface a fraction of a radius above
//! another, facing the same way, looks exactly like roughness. The scene tells them apart where
//! it can: an emitter panel hung 1 cm under a ceiling (the Cornell box's light, half a ceiling
//! radius at 100k splats), a rug on a floor, a painting on a wall are other materials and keep
//! blocking; a scan, one material, is one rough surface.
//!
//! A [`Between`] is cast as one any-hit walk that passes over the hits [`Between::ignores`]:
//! the CPU's [`crate::accel::Accel::visible_between`] and its WGSL twin `trace_between` in
//! shaders/common/traverse.wgsl (driven by [`crate::caster::GpuCaster`]).

use glam::Vec3;
use pc_artifact::octree::{node, Splat};
use rayon::prelude::*;

use crate::ray::Ray;
use crate::OctreeView;

/// An end's own zone reaches until the ray stands this many of the end's radii above the end's
/// tangent plane (plus [`OWN_SLOPE`] of the distance): the scan's noise stood within half a
/// radius for 88 % of the blocked rays, within one for 99 %.
pub const OWN_HEIGHT: f32 = 1.0;

/// The tangent plane's allowance per unit of distance (about 6°: an end's fitted normal is off
/// the surface's by that much on a noisy scan).
pub const OWN_SLOPE: f32 = 0.1;

/// And this many times the roughness of its octree leaf: the noise is the scanner's, a few
/// millimetres whatever the spacing, so at 20M points of the hall scan (3.7 mm splats) it stood
/// more than a radius proud and a tolerance in radii alone passed over too little of it. Five,
/// not three: a shallow ray passes over hundreds of splats in its zone, and at three standard
/// deviations one of them pokes through often enough that at 20M a quarter of the blocks came
/// just past a zone's end (docs/vmap.md, "What blocks at 20M").
pub const OWN_ROUGH: f32 = 5.0;

/// A splat is an end's own surface only where its normal is within about 30° of the end's:
/// noise tilts two splats of one wall apart by up to about 15°, while splats fitted across an
/// edge blend its two faces (45° from each), and a wall's top splats then counted the
/// ceiling's edge as their own and let a low sun through it (the hall scan at 300k).
pub const OWN_COS: f32 = 0.85;

/// An own zone reaches at most this many times its height tolerance, however shallow the ray.
pub const OWN_REACH: f32 = 32.0;

/// Where a first-hit ray leaving a splat starts, in the splat's radii: past the rounding of its
/// own plane. Other surfaces count from there (the floor under a glass ball resting on it), the
/// origin's own past its own zone ([`Between::leaving`]). Used by the final gather and the
/// photon tracer; WGSL twin `LEAVE_EPS` in shaders/common/traverse.wgsl. (The renderer's
/// bounces off mirrors and glass keep the plain Δ: docs/caustics.md, "Not done yet".)
pub const LEAVE_EPS: f32 = 1e-3;

/// What a piece of a segment ignores: hits on splats of `material` facing like `normal`
/// (cosine above [`OWN_COS`]). [`Own::NONE`] ignores nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Own {
    pub normal: Vec3,
    pub material: u32,
}

impl Own {
    /// The surface of splat `s`.
    pub fn of(s: &Splat) -> Own {
        Own {
            normal: s.normal.into(),
            material: s.material,
        }
    }

    pub const NONE: Own = Own {
        normal: Vec3::ZERO,
        material: u32::MAX,
    };

    /// Whether a splat of normal `n` and material `m` is this surface.
    #[inline(always)]
    pub fn is(&self, n: [f32; 3], m: u32) -> bool {
        n[0] * self.normal.x + n[1] * self.normal.y + n[2] * self.normal.z > OWN_COS
            && m == self.material
    }
}

/// Splat `i` of `view` with its octree leaf's roughness (`rough`, [`leaf_roughness`]): the end
/// of a segment that leaves it ([`Between::leaving`], [`Between::splats`]).
#[inline]
pub fn surface<'v>(view: &OctreeView<'v>, rough: &[f32], i: u32) -> (&'v Splat, f32) {
    let i = i as usize;
    (&view.splats[i], rough[view.splat_leaf[i] as usize])
}

/// How far along a ray leaving a splat of radius `radius`, on a leaf of roughness `rough`
/// ([`leaf_roughness`]), at cosine `cos` to its normal the splat's own zone reaches.
pub fn own_zone(radius: f32, rough: f32, cos: f32) -> f32 {
    let h = OWN_HEIGHT * radius + OWN_ROUGH * rough;
    let reach = OWN_REACH * h;
    let rise = cos - OWN_SLOPE;
    if rise * reach <= h {
        reach
    } else {
        h / rise
    }
}

/// The roughness of every octree leaf, per node-pool slot (zero elsewhere): the RMS height of
/// a surface's splat centres above their plane, about its mean normal. Range noise and the tilt
/// of fitted normals show here. A leaf whose normals spread ([`ROUGH_SPREAD`]: an edge) gets
/// zero.
///
/// Measured over the smallest node from the leaf up that spans its own noise: a cube of edge
/// `L` holds a slab of the surface at most `L` deep, so a leaf smaller than the noise is deep
/// (a dense scan's: the 20M hall scan's leaves are 5-10 mm, its ceiling's noise 2.5 mm, with
/// centres 3.5 mm about their plane at a station's zenith) reads only the noise it cuts off,
/// 1.3 mm there, a leaf of a few splats reads less still (one splat: zero), and a surface on a
/// cube face splits its noise between two cubes. So a node is read with its column, its two
/// neighbours of its depth along the axis nearest its normal; from the leaf up, the first
/// node at least [`ROUGH_SPAN`] of its column's roughness wide, the column holding at least
/// [`ROUGH_COUNT`] splats, gives the leaf's, at most [`ROUGH_CLIMB`] levels up and while the
/// nodes stay flat; a smooth surface's leaf is its own. docs/vmap.md, "Roughness wider than a
/// leaf".
pub fn leaf_roughness(view: &OctreeView) -> Vec<f32> {
    let n = view.nodes.len();
    // Per node: its subtree's own splats' count, Σ p, Σ p pᵀ (upper triangle) and Σ n, about
    // the root cube's centre (f64: the variance is millimetres² under metres²).
    let c = (Vec3::from(view.frame.origin) + 0.5 * view.frame.size).as_dvec3();
    // Each node's parent and depth, top-down (children follow their parent in the pool).
    let mut parent = vec![u32::MAX; n];
    let mut depth = vec![0u8; n];
    for slot in 0..n {
        let w = view.nodes[slot];
        if !node::is_leaf(w) && !node::is_empty(w) {
            let first = node::ptr(w) as usize;
            for ch in first..first + 8 {
                parent[ch] = slot as u32;
                depth[ch] = depth[slot] + 1;
            }
        }
    }
    let m = moments(view, c, &parent, &depth);
    // Per node: whether its normals agree (an edge's do not).
    let flat: Vec<bool> = m
        .par_iter()
        .zip(view.node_info)
        .map(|(m, info)| m.flat(Vec3::from(info.normal)))
        .collect();
    let edge = |at: usize| view.frame.size / (1u64 << depth[at]) as f32;
    // A node's column: itself and its two neighbours of its depth along the axis its normal
    // is nearest (a surface lying on a cube face splits its noise between two cubes).
    let column = |at: usize| -> (f32, u32) {
        let axis = Vec3::from(view.node_info[at].normal);
        let k = axis.abs().max_position();
        let mean = m[at].p / m[at].count.max(1) as f64 + c;
        let mut sum = m[at];
        for side in [-1.0, 1.0] {
            let mut q = mean;
            q[k] += side * edge(at) as f64;
            let q = q.as_vec3().to_array();
            if let Some(nb) = view
                .normalized(q)
                .and_then(|q| at_depth(view.nodes, q, depth[at]))
            {
                sum.merge(&m[nb as usize]);
            }
        }
        (sum.rough(axis), sum.count)
    };
    (0..n)
        .into_par_iter()
        .map(|slot| {
            if !node::is_leaf(view.nodes[slot]) || !flat[slot] {
                return 0.0;
            }
            let mut at = slot;
            let mut read = 0.0;
            for _ in 0..=ROUGH_CLIMB {
                let (sigma, count) = column(at);
                read = sigma;
                if count >= ROUGH_COUNT && edge(at) >= ROUGH_SPAN * sigma {
                    break;
                }
                match parent[at] {
                    p if p != u32::MAX && flat[p as usize] => at = p as usize,
                    _ => break,
                }
            }
            read
        })
        .collect()
}

/// Per node: its subtree's splats' [`Moments`] about `c`, given each node's `parent` and
/// `depth`. Each leaf's own splats (a run of the data pool) are summed in pool order, and each
/// node's children into it from the last to the first, level by level from the deepest, in
/// parallel: the same sums, to the bit, as one loop over the pool and one over the nodes in
/// reverse, each merged into its parent (children follow their parent in the pool).
fn moments(view: &OctreeView, c: glam::DVec3, parent: &[u32], depth: &[u8]) -> Vec<Moments> {
    let n = view.nodes.len();
    // Each leaf's own splats, in pool order: those of its range that name it their owner (the
    // reader checks that every splat lies in its owner's range).
    let mut m: Vec<Moments> = (0..n)
        .into_par_iter()
        .map(|slot| {
            let w = view.nodes[slot];
            let mut sum = Moments::default();
            if node::is_leaf(w) && !node::is_empty(w) {
                for i in view.leaf(w).0 {
                    if view.splat_leaf[i as usize] == slot as u32 {
                        let s = &view.splats[i as usize];
                        sum.add(Vec3::from(s.position).as_dvec3() - c, Vec3::from(s.normal));
                    }
                }
            }
            sum
        })
        .collect();
    let mut by_depth: Vec<Vec<u32>> = vec![Vec::new(); 256];
    for slot in 0..n {
        let w = view.nodes[slot];
        if !node::is_leaf(w) && !node::is_empty(w) {
            by_depth[depth[slot] as usize].push(slot as u32);
        }
    }
    for level in by_depth.iter().rev().filter(|l| !l.is_empty()) {
        let sums: Vec<Moments> = level
            .par_iter()
            .map(|&p| {
                let first = node::ptr(view.nodes[p as usize]) as usize;
                let mut sum = m[p as usize];
                for ch in (first..first + 8).rev().filter(|&ch| parent[ch] == p) {
                    sum.merge(&m[ch]);
                }
                sum
            })
            .collect();
        for (&p, sum) in level.iter().zip(sums) {
            m[p as usize] = sum;
        }
    }
    m
}

/// The node of depth `target` that holds the normalised point `q`, `None` where the descent
/// ends in a leaf or an empty node above it.
fn at_depth(nodes: &[u32], q: [f32; 3], target: u8) -> Option<u32> {
    let at = pc_artifact::octree::descend_normalized(nodes, q, target as u32);
    (at.depth == target as u32).then_some(at.slot)
}

/// A leaf counts as one rough surface only where its splats' normals agree, their mean
/// `1 − n·n̄` below this (about 20°): a leaf across an edge (a wall meeting the ceiling) has
/// heights about its mean plane as large as itself, which are geometry, not noise, and its
/// splats' fitted normals blend the two faces; its own zones stay a radius high. So does a
/// node above a rough leaf: its roughness is read no higher than its normals agree.
const ROUGH_SPREAD: f32 = 0.06;

/// A node's column spans its noise where the node is this many times as wide as the column's
/// roughness: the column, three nodes deep, holds the noise to well past three standard
/// deviations either side of the node's middle.
const ROUGH_SPAN: f32 = 6.0;

/// Fewer splats than this read no roughness worth the name (one reads zero).
const ROUGH_COUNT: u32 = 8;

/// At most this many levels above a leaf (16 times its width): farther up, a curved
/// surface's bend would read as noise.
const ROUGH_CLIMB: usize = 4;

/// A node's splat moments for [`leaf_roughness`].
#[derive(Clone, Copy, Default)]
struct Moments {
    count: u32,
    p: glam::DVec3,
    pp: [f64; 6],
    n: Vec3,
}

impl Moments {
    fn add(&mut self, p: glam::DVec3, n: Vec3) {
        self.count += 1;
        self.p += p;
        let pp = [
            p.x * p.x,
            p.x * p.y,
            p.x * p.z,
            p.y * p.y,
            p.y * p.z,
            p.z * p.z,
        ];
        for (a, b) in self.pp.iter_mut().zip(pp) {
            *a += b;
        }
        self.n += n;
    }

    fn merge(&mut self, o: &Moments) {
        self.count += o.count;
        self.p += o.p;
        for (a, b) in self.pp.iter_mut().zip(o.pp) {
            *a += b;
        }
        self.n += o.n;
    }

    /// Whether the normals agree with `axis` ([`ROUGH_SPREAD`]); not without splats or an
    /// axis.
    fn flat(&self, axis: Vec3) -> bool {
        self.count > 0
            && axis != Vec3::ZERO
            && 1.0 - self.n.dot(axis) / (self.count as f32) < ROUGH_SPREAD
    }

    /// The RMS height of the centres about their centroid's plane of normal `axis`; zero
    /// without splats.
    fn rough(&self, axis: Vec3) -> f32 {
        if self.count == 0 {
            return 0.0;
        }
        let k = self.count as f64;
        let a = axis.as_dvec3();
        let mean = self.p / k;
        let [xx, xy, xz, yy, yz, zz] = self.pp.map(|v| v / k);
        // aᵀ (E[p pᵀ] − mean meanᵀ) a
        let second = a.x * a.x * xx
            + a.y * a.y * yy
            + a.z * a.z * zz
            + 2.0 * (a.x * a.y * xy + a.x * a.z * xz + a.y * a.z * yz);
        let var = (second - a.dot(mean).powi(2)).max(0.0);
        var.sqrt() as f32
    }
}

/// Each octree leaf's roughness ([`leaf_roughness`]), computed at its first use and shared by
/// every later one (a stage whose several passes may each need it, or none).
pub struct LazyRoughness<'v> {
    view: &'v OctreeView<'v>,
    rough: std::sync::OnceLock<Vec<f32>>,
}

impl std::fmt::Debug for LazyRoughness<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LazyRoughness")
            .field("computed", &self.rough.get().is_some())
            .finish()
    }
}

impl<'v> LazyRoughness<'v> {
    pub fn new(view: &'v OctreeView<'v>) -> LazyRoughness<'v> {
        LazyRoughness {
            view,
            rough: std::sync::OnceLock::new(),
        }
    }

    /// Per node-pool slot, as [`leaf_roughness`] gives it.
    pub fn get(&self) -> &[f32] {
        self.rough.get_or_init(|| leaf_roughness(self.view))
    }
}

/// A visibility segment between two surface points: `ray` from the first end (at `t = 0`)
/// toward the second, whose own zones end at `t = zones[0]` (hits before it on the surface
/// `ends[0]` are ignored) and begin at `t = zones[1]` (after it, on `ends[1]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Between {
    pub ray: Ray,
    pub ends: [Own; 2],
    pub zones: [f32; 2],
}

impl Between {
    /// The segment from the splat `a` to the splat `b` (each with its leaf's roughness),
    /// `len` apart along `dir`, both ends' own zones set by the rule above, and `t_min`,
    /// `t_max` the ray's interval.
    pub fn splats(
        (a, rough_a): (&Splat, f32),
        (b, rough_b): (&Splat, f32),
        dir: Vec3,
        len: f32,
        t_min: f32,
        t_max: f32,
    ) -> Between {
        let (na, nb) = (Vec3::from(a.normal), Vec3::from(b.normal));
        let (ca, cb) = (na.dot(dir), -nb.dot(dir));
        Between {
            ray: Ray {
                origin: a.position.into(),
                dir,
                t_min,
                t_max,
            },
            ends: [Own::of(a), Own::of(b)],
            zones: [
                own_zone(a.radius, rough_a, ca),
                len - own_zone(b.radius, rough_b, cb),
            ],
        }
    }

    /// A plain ray: no end ignores anything.
    pub fn plain(ray: Ray) -> Between {
        Between {
            ray,
            ends: [Own::NONE; 2],
            zones: [f32::NEG_INFINITY, f32::INFINITY],
        }
    }

    /// A ray leaving the splat `a` (on a leaf of roughness `rough`: [`surface`]), the far end no
    /// surface (a point light, a probe's reach, a first hit).
    pub fn leaving(ray: Ray, (a, rough): (&Splat, f32)) -> Between {
        Between {
            ray,
            ends: [Own::of(a), Own::NONE],
            zones: [
                own_zone(a.radius, rough, Vec3::from(a.normal).dot(ray.dir)),
                f32::INFINITY,
            ],
        }
    }

    /// Whether a hit at `t` on a splat of normal `n` and material `m` is an end's own surface:
    /// within that end's zone, and that surface ([`Own::is`]). Where the zones overlap, either
    /// end's surface is its own.
    #[inline(always)]
    pub fn ignores(&self, t: f32, n: [f32; 3], m: u32) -> bool {
        self.ignores_with(t, n, || m)
    }

    /// [`Self::ignores`] with the material read only for a hit within an end's zone (the
    /// splat's record, a cache miss, is not read for the hits between the zones).
    #[inline(always)]
    pub fn ignores_with(&self, t: f32, n: [f32; 3], material: impl Fn() -> u32) -> bool {
        (t < self.zones[0] && self.ends[0].is(n, material()))
            || (t > self.zones[1] && self.ends[1].is(n, material()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_own_zone_shrinks_as_the_ray_rises() {
        // Straight up: the height, and a little for the slope.
        let up = own_zone(1.0, 0.0, 1.0);
        assert!((up - OWN_HEIGHT / (1.0 - OWN_SLOPE)).abs() < 1e-6);
        // Along the surface, or rising no faster than the allowance: the whole reach.
        assert_eq!(own_zone(2.0, 0.0, 0.0), 2.0 * OWN_REACH);
        assert_eq!(own_zone(2.0, 0.0, OWN_SLOPE), 2.0 * OWN_REACH);
        // In between, where the rise meets the allowance.
        let t = own_zone(1.0, 0.0, 0.5);
        assert!(t > up && t < OWN_REACH);
        assert!((t * 0.5 - (OWN_HEIGHT + OWN_SLOPE * t)).abs() < 1e-5);
        // A rough leaf raises the tolerance, and the reach with it.
        let h = OWN_HEIGHT + OWN_ROUGH * 0.5;
        assert!((own_zone(1.0, 0.5, 1.0) - h / (1.0 - OWN_SLOPE)).abs() < 1e-5);
        assert_eq!(own_zone(1.0, 0.5, 0.0), OWN_REACH * h);
    }

    fn splat(p: Vec3, n: Vec3, r: f32) -> Splat {
        Splat {
            position: p.into(),
            radius: r,
            normal: n.into(),
            material: 0,
            albedo: [1.0; 3],
            source: 0,
            clip: [0.0; 4],
        }
    }

    #[test]
    fn an_end_ignores_its_own_surface_within_its_zone_only() {
        let (a, b) = (Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0));
        let up = [0.0, 1.0, 0.0];
        let s = Between::splats(
            (&splat(a, Vec3::Y, 0.1), 0.0),
            (&splat(b, -Vec3::Y, 0.1), 0.0),
            b.normalize(),
            b.length(),
            0.05,
            0.97,
        );
        let za = own_zone(0.1, 0.0, Vec3::Y.dot(b.normalize()));
        assert!(s.ignores(0.9 * za, up, 0));
        assert!(!s.ignores(1.1 * za, up, 0), "past the zone");
        assert!(!s.ignores(0.9 * za, up, 1), "another material");
        assert!(
            !s.ignores(0.9 * za, [0.0, -1.0, 0.0], 0),
            "the other end's side"
        );
        assert!(s.ignores(b.length() - 0.9 * za, [0.0, -1.0, 0.0], 0));
        // A ray leaving a splat: no far end.
        let r = Between::leaving(s.ray, (&splat(a, Vec3::Y, 0.1), 0.0));
        assert!(r.ignores(0.9 * za, up, 0) && !r.ignores(1e30, [0.0, -1.0, 0.0], u32::MAX));
    }

    #[test]
    fn only_the_ends_material_facing_its_way_is_its_own() {
        let own = Own {
            normal: Vec3::Y,
            material: 3,
        };
        assert!(own.is([0.0, 1.0, 0.0], 3));
        assert!(own.is([0.45, 0.89, 0.0], 3));
        assert!(!own.is([0.6, 0.8, 0.0], 3), "an edge's blended normal");
        assert!(!own.is([0.0, 1.0, 0.0], 2), "another material");
        assert!(!own.is([1.0, 0.0, 0.0], 3), "another orientation");
        assert!(!Own::NONE.is([0.0, 1.0, 0.0], u32::MAX));
    }
}
