//! The specular links (docs/caustics.md "Specular links"): how the light that diffuse splats
//! reflect reaches other diffuse splats through mirrors and glass (paths D S⁺ D), which the
//! seed's two-pass split (§8.1) leaves out. They depend on the geometry alone, not on the
//! lights, so pc-fmm applies them in every product of the solve and a moved light reuses them.
//!
//! 1. **Aims** ([`aims`]): every (diffuse leaf `D`, specular leaf `S`) pair that meets under a
//!    V-map link ([`emit::leaf_pairs`]) has the flux per unit radiance of `D`,
//!    `G = A_D cos θ_D · A_S |cos θ_S| / d²`. The budget of paths is shared in proportion to
//!    `G`, rounded stochastically. A path from point `x` toward point `y` carries
//!    `A_D A_S cos θ_x |cos θ_y| / (|x − y|² + r_y²) / n` for the `n` paths the pair expects
//!    (`r_y` the aimed splat's radius, the near-contact limit of a disk): an unbiased estimate
//!    of the pair's flux wherever the centroids misjudge it (a curved surface, a near pair).
//!    The albedo is left out of the share: the links then do not depend on the diffuse
//!    colours, and recolouring a wall reuses them.
//! 2. **Paths**: each is a photon of the caustic tracer ([`crate::trace`] or its GPU twin) from
//!    a point of `D` toward a point of `S`; it is kept where it first lands on the front of a
//!    diffuse splat after ≥ 1 specular bounce, its weight tinted by the bounces (Fresnel, the
//!    mirror's reflectance). A path whose aim point is hidden is dropped: the surface in front
//!    has its own aims.
//! 3. **Bins and flux** ([`build`]): the receiving octree leaf of each kept path is its bin; the
//!    bin's flux row sums the weights per sender leaf, so that `Φ_b = Σ w ⊙ L̄_D`.
//! 4. **Gather**: every diffuse splat estimates its irradiance from the bins of its own surface
//!    (normals within 45°, centroids near its plane) within a radius `h`: the kernel
//!    `K = 1 − d²/h²` over the bins' centroids, and the ratio estimator `E = Σ K Φ / Σ K A`
//!    (flux over area, both kernel-weighted: no loss at a surface's border). `h` is the
//!    radius around the splat's bin that holds `caustics.specular_gather` paths, at least
//!    twice the bin's extent. Stored per splat as `g = K / (π Σ K A)`, so `T_i = Σ g Φ_b` is
//!    the irradiance over π, the operator's units.

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

/// Paths from diffuse leaves to the specular leaves they see, `budget` of them in expectation.
pub fn aims(leaves: &Leaves, v: &VmapView, budget: u32, seed: u32) -> Vec<Aim> {
    let diffuse = |l: &emit::Leaf| !class::is_specular(l.class);
    let pairs = emit::leaf_pairs(leaves, v, &diffuse);
    let total: f64 = pairs.iter().map(|p| p.2 as f64).sum();
    let area = |l: u32| leaves.leaves[l as usize].area;
    if total <= 0.0 || budget == 0 {
        return Vec::new();
    }
    pairs
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let n = budget as f64 * p.2 as f64 / total;
            let u = rand(seed, 0x5bec_0001, i as u32, 0) as f64;
            let count = (n.floor() + (u < n.fract()) as u32 as f64) as u32;
            (count > 0).then(|| Aim {
                source: Source::Area(p.0),
                target: p.1,
                photons: count,
                power: [(area(p.0) as f64 * area(p.1) as f64 / n) as f32; 3],
                sample_geometry: true,
            })
        })
        .collect()
}

/// The links' tables, as the artifact stores them ([`pc_artifact::specular`]).
#[derive(Clone, Debug, Default)]
pub struct Links {
    pub senders: Vec<[u32; 2]>,
    pub flux_offsets: Vec<u32>,
    pub flux: Vec<FluxLink>,
    pub gather_offsets: Vec<u32>,
    pub gather: Vec<GatherLink>,
}

impl Links {
    /// The tables as the artifact's reader gives them.
    pub fn view(&self) -> SpecularView<'_> {
        SpecularView {
            senders: &self.senders,
            flux_offsets: &self.flux_offsets,
            flux: &self.flux,
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
) -> Links {
    if traced.photons.is_empty() {
        return Links::default();
    }
    let diffuse = |j: usize| !class::is_specular(materials[view.splats[j].material as usize].class);
    let mut bins = bins(view, leaves, &diffuse);
    let leaf_of = |splat: u32| leaves.leaves.partition_point(|l| l.lo <= splat) - 1;
    // Flux rows: (bin, sender leaf, weight), merged per pair.
    let mut rows: Vec<(u32, u32, Vec3)> = traced
        .photons
        .iter()
        .zip(&traced.aim)
        .filter_map(|(p, &a)| match aims[a as usize].source {
            Source::Area(d) => Some((leaf_of(p.splat) as u32, d, Vec3::from(p.power))),
            Source::Point(_) => None,
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
    // Senders: the leaves that send, numbered in order.
    let mut sender_leaves: Vec<u32> = merged.iter().map(|r| r.1).collect();
    sender_leaves.sort_unstable();
    sender_leaves.dedup();
    let sender_of = |leaf: u32| sender_leaves.binary_search(&leaf).unwrap() as u32;
    let mut out = Links {
        senders: sender_leaves
            .iter()
            .map(|&l| [leaves.leaves[l as usize].lo, leaves.leaves[l as usize].hi])
            .collect(),
        flux_offsets: vec![0; bins.len() + 1],
        ..Default::default()
    };
    for r in &merged {
        out.flux_offsets[r.0 as usize + 1] += 1;
        out.flux.push(FluxLink {
            sender: sender_of(r.1),
            weight: r.2.into(),
        });
    }
    for b in 0..bins.len() {
        out.flux_offsets[b + 1] += out.flux_offsets[b];
    }
    let (offsets, g) = gather_links(view, &bins, &diffuse, &leaf_of, gather);
    out.gather_offsets = offsets;
    out.gather = g;
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

/// The gather rows of every splat (CSR over the data pool).
fn gather_links(
    view: &OctreeView,
    bins: &[Bin],
    diffuse: &(dyn Fn(usize) -> bool + Sync),
    leaf_of: &(dyn Fn(u32) -> usize + Sync),
    gather: u32,
) -> (Vec<u32>, Vec<GatherLink>) {
    let used: Vec<u32> = (0..bins.len() as u32)
        .filter(|&b| bins[b as usize].area > 0.0)
        .collect();
    let points: Vec<[f32; 3]> = used
        .iter()
        .map(|&b| bins[b as usize].centroid.into())
        .collect();
    let tree: ImmutableKdTree<f32, 3> =
        ImmutableKdTree::new_from_slice(&points).expect("kd-tree over at most u32::MAX bins");
    // The kernel radius of each bin: the distance that holds `gather` paths of its surface.
    let radius: Vec<f32> = bins
        .par_iter()
        .map(|b| {
            if b.area <= 0.0 {
                return 0.0;
            }
            let k = NonZeroUsize::new(RADIUS_CANDIDATES.min(used.len())).unwrap();
            let q: [f32; 3] = b.centroid.into();
            let mut found = tree
                .query(&q)
                .nearest_n::<SquaredEuclidean<f32>>(k)
                .execute();
            found.sort_by(|a, b| a.distance.total_cmp(&b.distance));
            let mut paths = 0u32;
            let mut reach = 0.0f32;
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
            reach.max(2.0 * b.extent)
        })
        .collect();
    let rows: Vec<Vec<GatherLink>> = (0..view.splats.len())
        .into_par_iter()
        .map(|i| {
            if !diffuse(i) {
                return Vec::new();
            }
            let s = &view.splats[i];
            let (x, n) = (Vec3::from(s.position), Vec3::from(s.normal));
            let h = radius[leaf_of(i as u32)];
            if h <= 0.0 {
                return Vec::new();
            }
            let q: [f32; 3] = x.into();
            let mut norm = 0.0f64;
            let mut row = Vec::new();
            tree.query(&q)
                .within::<SquaredEuclidean<f32>>(h * h)
                .unsorted()
                .visit(|f| {
                    let b = used[f.item as usize];
                    let c = &bins[b as usize];
                    let k = 1.0 - f.distance / (h * h);
                    if k <= 0.0 || !same_surface(x, n, c, h) {
                        return;
                    }
                    norm += (k * c.area) as f64;
                    if c.paths > 0 {
                        row.push(GatherLink { bin: b, weight: k });
                    }
                });
            if norm <= 0.0 {
                return Vec::new();
            }
            let scale = (1.0 / (std::f64::consts::PI * norm)) as f32;
            row.sort_unstable_by_key(|g| g.bin);
            for g in &mut row {
                g.weight *= scale;
            }
            row
        })
        .collect();
    let mut offsets = Vec::with_capacity(rows.len() + 1);
    offsets.push(0u32);
    let mut all = Vec::with_capacity(rows.iter().map(Vec::len).sum());
    for r in rows {
        all.extend(r);
        offsets.push(all.len() as u32);
    }
    (offsets, all)
}
