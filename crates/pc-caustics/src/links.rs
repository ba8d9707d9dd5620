//! The specular links (docs/caustics.md "Specular links"): how the light that diffuse splats
//! reflect reaches other diffuse splats through mirrors and glass (paths D S⁺ D), which the
//! seed's two-pass split (§8.1) leaves out. They depend on the geometry alone, not on the
//! lights, so pc-fmm applies them in every product of the solve and a moved light reuses them.
//!
//! 1. **Aims** ([`aims`]): the budget of paths is shared among the V-map's links from a node's
//!    diffuse splats `X` to another's specular splats `Y` in proportion to their flux factor
//!    `A_X cos θ_X · A_Y |cos θ_Y| / d²` (from the parts' centroids and mean normals, bounded
//!    near contact), rounded stochastically; each path draws its source and target leaves by
//!    area. A path from point `x` toward point `y` carries
//!    `A_X A_Y cos θ_x |cos θ_y| / (|x − y|² + 0.1 r_y²) / n` for the `n` paths the link
//!    expects (`r_y` the aimed splat's radius): an unbiased estimate of the flux wherever the
//!    centroids misjudge it (a curved surface, a near pair), with a floor at contact. The
//!    albedo is left out of the share: the links then do not depend on the diffuse colours,
//!    and recolouring a wall reuses them. (Pairing every leaf under a link, as the emitters'
//!    photons do, made 253M pairs on a 1M-splat scene.)
//! 2. **Paths**: each is a photon of the caustic tracer ([`crate::trace`] or its GPU twin) from
//!    a point of `D` toward a point of `S`; it is kept where it first lands on the front of a
//!    diffuse splat after ≥ 1 specular bounce, its weight tinted by the bounces (Fresnel, the
//!    mirror's reflectance). A path whose aim point is hidden is dropped: the surface in front
//!    has its own aims.
//! 3. **Bins and flux** ([`build`]): the receiving octree leaf of each kept path is its bin; the
//!    bin's flux row sums the weights per sender, the splat the path left, so that
//!    `Φ_b = Σ w ⊙ L_s`.
//! 4. **Smooth**: every bin estimates its irradiance from the bins of its own surface (normals
//!    within 45°, centroids near its plane) within a radius `h`: the kernel `K = 1 − d²/h²`
//!    over the bins' centroids, and the ratio estimator `E = Σ K Φ / Σ K A` (flux over area,
//!    both kernel-weighted: no loss at a surface's border). `h` is the radius that holds
//!    `caustics.specular_gather` paths, at least twice the bin's extent. Stored as
//!    `g = K / (π Σ K A)`, so `E_b / π = Σ g Φ_b'`, the operator's units.
//! 5. **Gather**: every diffuse splat interpolates the bins of its surface within twice its own
//!    bin's extent (weights `K`, normalised), so the estimate has no steps at bin borders.

use std::num::NonZeroUsize;

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use pc_artifact::octree::class;
use pc_artifact::specular::{FluxLink, GatherLink, SpecularView};
use pc_artifact::vmap::VmapView;
use pc_tree::rng::rand;
use pc_tree::OctreeView;
use rayon::prelude::*;

use crate::emit::{self, Aim, Leaves, Source};
use crate::stage::Traced;

/// Prefix sums over the leaves (in data-pool order) of one class group: area, and area times
/// centroid and normal, so that any node's part of that group is summed in O(1).
struct Prefix {
    area: Vec<f64>,
    centroid: Vec<[f64; 3]>,
    normal: Vec<[f64; 3]>,
}

impl Prefix {
    fn new(leaves: &Leaves, member: &dyn Fn(&emit::Leaf) -> bool) -> Prefix {
        let n = leaves.leaves.len();
        let mut p = Prefix {
            area: vec![0.0; n + 1],
            centroid: vec![[0.0; 3]; n + 1],
            normal: vec![[0.0; 3]; n + 1],
        };
        for (i, l) in leaves.leaves.iter().enumerate() {
            let a = if member(l) { l.area as f64 } else { 0.0 };
            p.area[i + 1] = p.area[i] + a;
            for k in 0..3 {
                p.centroid[i + 1][k] = p.centroid[i][k] + a * l.centroid[k] as f64;
                p.normal[i + 1][k] = p.normal[i][k] + a * l.normal[k] as f64;
            }
        }
        p
    }

    /// Area, centroid and mean normal of the group's leaves `r`.
    fn part(&self, r: &std::ops::Range<usize>) -> (f64, Vec3, Vec3) {
        let a = self.area[r.end] - self.area[r.start];
        if a <= 0.0 {
            return (0.0, Vec3::ZERO, Vec3::ZERO);
        }
        let d = |t: &[[f64; 3]]| {
            Vec3::new(
                (t[r.end][0] - t[r.start][0]) as f32,
                (t[r.end][1] - t[r.start][1]) as f32,
                (t[r.end][2] - t[r.start][2]) as f32,
            )
        };
        (
            a,
            d(&self.centroid) / a as f32,
            d(&self.normal).normalize_or_zero(),
        )
    }

    /// The leaf of `r` at area fraction `u` ∈ [0, 1) of the group's area there.
    fn pick(&self, r: &std::ops::Range<usize>, u: f64) -> u32 {
        let t = self.area[r.start] + u * (self.area[r.end] - self.area[r.start]);
        let i = self.area[r.start + 1..=r.end].partition_point(|&c| c <= t);
        (r.start + i.min(r.len() - 1)) as u32
    }
}

/// The smallest cosine a node pair's share counts with: a node whose mean normal turns away
/// may still hold leaves that face the other (a curved or noisy surface).
const MIN_SHARE_COS: f32 = 0.05;

/// Paths from diffuse leaves to the specular leaves they see, `budget` of them in expectation.
///
/// The budget is shared among the V-map's links (node `X`, node `Y`) with diffuse splats in
/// `X` and specular ones in `Y`, in proportion to `A_X A_Y cos θ_X |cos θ_Y| / (d² + (A_X +
/// A_Y) / π)` between the two parts' centroids and mean normals (cosines at least
/// [`MIN_SHARE_COS`]), rounded stochastically. Each path then draws its source leaf in `X` and
/// its target leaf in `Y` by area and carries `A_X A_Y / n` (`n` the link's expected paths)
/// times its own points' geometry ([`Aim::sample_geometry`]): unbiased for every leaf pair.
pub fn aims(leaves: &Leaves, v: &VmapView, budget: u32, seed: u32) -> Vec<Aim> {
    let diffuse = Prefix::new(leaves, &|l| !class::is_specular(l.class));
    let specular = Prefix::new(leaves, &|l| class::is_specular(l.class));
    // (X's leaves, Y's leaves, areas, share) of every diffuse → specular link.
    let mut shares: Vec<(std::ops::Range<usize>, std::ops::Range<usize>, f64, f64)> = Vec::new();
    for x in 0..v.node_range.len() {
        let row = v.links_of(x);
        if row.is_empty() {
            continue;
        }
        let [xlo, xhi] = v.node_range[x];
        let xr = leaves.within(xlo, xhi);
        let (ax, cx, nx) = diffuse.part(&xr);
        if ax <= 0.0 {
            continue;
        }
        for link in row.iter().filter(|k| k.fraction > 0.0) {
            let [ylo, yhi] = v.node_range[link.slot() as usize];
            let yr = leaves.within(ylo, yhi);
            let (ay, cy, ny) = specular.part(&yr);
            if ay <= 0.0 {
                continue;
            }
            let d = cy - cx;
            let r2 = d.length_squared() as f64;
            let dir = d.normalize_or_zero();
            let cos_x = nx.dot(dir).max(MIN_SHARE_COS) as f64;
            let cos_y = ny.dot(dir).abs().max(MIN_SHARE_COS) as f64;
            let share = ax * ay * cos_x * cos_y / (r2 + (ax + ay) / std::f64::consts::PI);
            shares.push((xr.clone(), yr, ax * ay, share));
        }
    }
    let total: f64 = shares.iter().map(|s| s.3).sum();
    if total <= 0.0 || budget == 0 {
        return Vec::new();
    }
    let mut out: Vec<Aim> = Vec::new();
    let mut id = 0u32;
    for (i, (xr, yr, area, share)) in shares.iter().enumerate() {
        let n = budget as f64 * share / total;
        let u = rand(seed, 0x5bec_0001, i as u32, 0) as f64;
        let count = (n.floor() + (u < n.fract()) as u32 as f64) as u32;
        let power = [(area / n) as f32; 3];
        for _ in 0..count {
            let source = diffuse.pick(xr, rand(seed, 0x5bec_0002, id, 0) as f64);
            let target = specular.pick(yr, rand(seed, 0x5bec_0002, id, 1) as f64);
            id = id.wrapping_add(1);
            match out.last_mut() {
                Some(a)
                    if a.source == Source::Area(source)
                        && a.target == target
                        && a.power == power =>
                {
                    a.photons += 1
                }
                _ => out.push(Aim {
                    source: Source::Area(source),
                    target,
                    photons: 1,
                    power,
                    sample_geometry: true,
                }),
            }
        }
    }
    out
}

/// The links' tables, as the artifact stores them ([`pc_artifact::specular`]).
#[derive(Clone, Debug, Default)]
pub struct Links {
    pub flux_offsets: Vec<u32>,
    pub flux: Vec<FluxLink>,
    pub smooth_offsets: Vec<u32>,
    pub smooth: Vec<GatherLink>,
    pub gather_offsets: Vec<u32>,
    pub gather: Vec<GatherLink>,
}

impl Links {
    /// The tables as the artifact's reader gives them.
    pub fn view(&self) -> SpecularView<'_> {
        SpecularView {
            flux_offsets: &self.flux_offsets,
            flux: &self.flux,
            smooth_offsets: &self.smooth_offsets,
            smooth: &self.smooth,
            gather_offsets: &self.gather_offsets,
            gather: &self.gather,
        }
    }
}

/// A receiving octree leaf: its diffuse splats' area, centroid, mean normal and extent.
#[derive(Clone, Copy, Debug, Default)]
struct Bin {
    area: f32,
    centroid: Vec3,
    normal: Vec3,
    extent: f32,
    /// Kept paths that landed in it.
    paths: u32,
}

/// The tables from the traced paths of `aims`.
pub fn build(
    view: &OctreeView,
    materials: &[pc_artifact::octree::MaterialRecord],
    leaves: &Leaves,
    aims: &[Aim],
    traced: &Traced,
    gather: u32,
    seed: u32,
) -> Links {
    if traced.photons.is_empty() {
        return Links::default();
    }
    let diffuse = |j: usize| !class::is_specular(materials[view.splats[j].material as usize].class);
    let mut bins = bins(view, leaves, &diffuse);
    let leaf_of = |splat: u32| leaves.leaves.partition_point(|l| l.lo <= splat) - 1;
    // The splat each kept path left: the tracer's own draw (`Tracer::photon`, random number 0 of
    // its id), so that the sender's radiance is the splat's, not its leaf's mean (a ball lens
    // images a bright spot on the floor; a leaf's mean would spread it first).
    let mut first = Vec::with_capacity(aims.len() + 1);
    let mut total = 0u64;
    for a in aims {
        first.push(total);
        total += a.photons as u64;
    }
    // Flux rows: (bin, sender splat, weight), merged per pair.
    let mut rows: Vec<(u32, u32, Vec3)> = traced
        .photons
        .iter()
        .zip(&traced.id)
        .filter_map(|(p, &id)| {
            let a = first.partition_point(|&f| f <= id as u64) - 1;
            match aims[a].source {
                Source::Area(d) => {
                    let j = leaves.pick(view, d, rand(seed, id, 0, 0));
                    Some((leaf_of(p.splat) as u32, j, Vec3::from(p.power)))
                }
                Source::Point(_) => None,
            }
        })
        .collect();
    for r in &rows {
        bins[r.0 as usize].paths += 1;
    }
    rows.sort_unstable_by_key(|r| (r.0, r.1));
    let mut merged: Vec<(u32, u32, Vec3)> = Vec::with_capacity(rows.len());
    for r in rows {
        match merged.last_mut() {
            Some(m) if (m.0, m.1) == (r.0, r.1) => m.2 += r.2,
            _ => merged.push(r),
        }
    }
    let mut out = Links {
        flux_offsets: vec![0; bins.len() + 1],
        ..Default::default()
    };
    for r in &merged {
        out.flux_offsets[r.0 as usize + 1] += 1;
        out.flux.push(FluxLink {
            sender: r.1,
            weight: r.2.into(),
        });
    }
    for b in 0..bins.len() {
        out.flux_offsets[b + 1] += out.flux_offsets[b];
    }
    let [smooth, interpolate] = gather_links(view, &bins, &diffuse, &leaf_of, gather);
    (out.smooth_offsets, out.smooth) = smooth;
    (out.gather_offsets, out.gather) = interpolate;
    out
}

/// Every octree leaf's diffuse splats as a bin.
fn bins(view: &OctreeView, leaves: &Leaves, diffuse: &dyn Fn(usize) -> bool) -> Vec<Bin> {
    leaves
        .leaves
        .iter()
        .map(|l| {
            let mut b = Bin::default();
            for j in l.lo as usize..l.hi as usize {
                if diffuse(j) {
                    let (s, a) = (&view.splats[j], view.splat_area[j]);
                    b.area += a;
                    b.centroid += a * Vec3::from(s.position);
                    b.normal += a * Vec3::from(s.normal);
                }
            }
            if b.area > 0.0 {
                b.centroid /= b.area;
                b.normal = b.normal.normalize_or_zero();
                for j in l.lo as usize..l.hi as usize {
                    if diffuse(j) {
                        let s = &view.splats[j];
                        let d = (Vec3::from(s.position) - b.centroid).length() + s.radius;
                        b.extent = b.extent.max(d);
                    }
                }
            }
            b
        })
        .collect()
}

/// Bins farther than this from a splat's plane, in kernel radii, lie on another surface.
const PLANE_TOLERANCE: f32 = 0.25;
/// Bins whose normal differs by more than 45° lie on another surface.
const SAME_SURFACE_COS: f32 = std::f32::consts::FRAC_1_SQRT_2;
/// Bins looked at to find the radius that holds the gather count.
const RADIUS_CANDIDATES: usize = 256;

/// Whether a bin `c` lies on the surface of a point `x` with normal `n`, within radius `h`.
fn same_surface(x: Vec3, n: Vec3, c: &Bin, h: f32) -> bool {
    c.area > 0.0
        && n.dot(c.normal) >= SAME_SURFACE_COS
        && n.dot(c.centroid - x).abs() <= PLANE_TOLERANCE * h
}

/// CSR rows from per-row lists.
fn csr(rows: Vec<Vec<GatherLink>>) -> (Vec<u32>, Vec<GatherLink>) {
    let mut offsets = Vec::with_capacity(rows.len() + 1);
    offsets.push(0u32);
    let mut all = Vec::with_capacity(rows.iter().map(Vec::len).sum());
    for r in rows {
        all.extend(r);
        offsets.push(all.len() as u32);
    }
    (offsets, all)
}

/// The density estimate of every bin (the smoothing rows: `E_b = Σ g Φ_b'`, irradiance over π)
/// and every splat's interpolation between the bins of its surface around it (the gather
/// rows: `T_i = Σ w E_b`, weights summing to one). Two sparse maps rather than one kernel per
/// splat: on a 1M-splat scene the kernel held about 90 bins per splat.
fn gather_links(
    view: &OctreeView,
    bins: &[Bin],
    diffuse: &(dyn Fn(usize) -> bool + Sync),
    leaf_of: &(dyn Fn(u32) -> usize + Sync),
    gather: u32,
) -> [(Vec<u32>, Vec<GatherLink>); 2] {
    let used: Vec<u32> = (0..bins.len() as u32)
        .filter(|&b| bins[b as usize].area > 0.0)
        .collect();
    let points: Vec<[f32; 3]> = used
        .iter()
        .map(|&b| bins[b as usize].centroid.into())
        .collect();
    let tree: ImmutableKdTree<f32, 3> =
        ImmutableKdTree::new_from_slice(&points).expect("kd-tree over at most u32::MAX bins");
    // Kernel-weighted visit of the bins of the surface at (x, n) within h.
    let around = |x: Vec3, n: Vec3, h: f32, f: &mut dyn FnMut(u32, &Bin, f32)| {
        let q: [f32; 3] = x.into();
        tree.query(&q)
            .within::<SquaredEuclidean<f32>>(h * h)
            .unsorted()
            .visit(|it| {
                let b = used[it.item as usize];
                let c = &bins[b as usize];
                let k = 1.0 - it.distance / (h * h);
                if k > 0.0 && same_surface(x, n, c, h) {
                    f(b, c, k);
                }
            });
    };
    // The density estimate of each bin: the radius that holds `gather` paths of its surface.
    let smooth: Vec<Vec<GatherLink>> = bins
        .par_iter()
        .map(|b| {
            if b.area <= 0.0 {
                return Vec::new();
            }
            let k = NonZeroUsize::new(RADIUS_CANDIDATES.min(used.len())).unwrap();
            let q: [f32; 3] = b.centroid.into();
            let mut found = tree
                .query(&q)
                .nearest_n::<SquaredEuclidean<f32>>(k)
                .execute();
            found.sort_by(|a, b| a.distance.total_cmp(&b.distance));
            let (mut paths, mut reach) = (0u32, 0.0f32);
            for f in &found {
                let c = &bins[used[f.item as usize] as usize];
                let d = f.distance.sqrt();
                if !same_surface(b.centroid, b.normal, c, 4.0 * d.max(b.extent)) {
                    continue;
                }
                paths += c.paths;
                reach = d + c.extent;
                if paths >= gather {
                    break;
                }
            }
            let h = reach.max(2.0 * b.extent);
            let (mut norm, mut row) = (0.0f64, Vec::new());
            around(b.centroid, b.normal, h, &mut |i, c, k| {
                norm += (k * c.area) as f64;
                if c.paths > 0 {
                    row.push(GatherLink { bin: i, weight: k });
                }
            });
            if norm <= 0.0 {
                return Vec::new();
            }
            let scale = (1.0 / (std::f64::consts::PI * norm)) as f32;
            row.sort_unstable_by_key(|g| g.bin);
            row.iter_mut().for_each(|g| g.weight *= scale);
            row
        })
        .collect();
    // Each splat between the bins of its surface within twice its own bin's extent.
    let interpolate: Vec<Vec<GatherLink>> = (0..view.splats.len())
        .into_par_iter()
        .map(|i| {
            if !diffuse(i) {
                return Vec::new();
            }
            let s = &view.splats[i];
            let own = leaf_of(i as u32);
            let h = 2.0 * bins[own].extent;
            if h <= 0.0 {
                return Vec::new();
            }
            let (mut norm, mut row) = (0.0f32, Vec::new());
            around(s.position.into(), s.normal.into(), h, &mut |b, _, k| {
                norm += k;
                if !smooth[b as usize].is_empty() {
                    row.push(GatherLink { bin: b, weight: k });
                }
            });
            if norm <= 0.0 {
                return Vec::new();
            }
            row.sort_unstable_by_key(|g| g.bin);
            row.iter_mut().for_each(|g| g.weight /= norm);
            row
        })
        .collect();
    [csr(smooth), csr(interpolate)]
}
