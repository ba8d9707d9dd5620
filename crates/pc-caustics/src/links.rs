//! The specular links (docs/caustics.md "Specular links"): how the light that diffuse splats
//! reflect reaches other diffuse splats through mirrors and glass (paths D S⁺ D), which the
//! seed's two-pass split (§8.1) leaves out. They depend on the geometry alone, not on the
//! lights, so pc-fmm applies them in every product of the solve and a moved light reuses them.
//!
//! 1. **Aims** ([`aims`]): the budget of paths is shared among the V-map's links from a node's
//!    diffuse splats `X` to another's specular splats `Y` in proportion to their flux factor
//!    `A_X cos θ_X · A_Y |cos θ_Y| / d²` (from the parts' centroids and mean normals, bounded
//!    near contact), rounded stochastically. Each link's paths follow two strategies: by area
//!    (a source and an aim point drawn by area on the two parts) and by direction (a source by
//!    area, a direction by cosine, kept if it first meets the link's specular part). Every path
//!    carries the balance heuristic's weight of its own points' geometry ([`aims`]): an unbiased
//!    estimate of the flux wherever the centroids misjudge it (a curved surface, a near pair),
//!    and bounded where the parts touch (the glass ball on the floor). The
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
use pc_tree::accel::Accel;
use pc_tree::between::surface;
use pc_tree::rng::rand;
use pc_tree::{cosine_dir, disk_point, Between, OctreeView, Ray, TraversalStats};
use rayon::prelude::*;

use crate::emit::{self, Aim, Leaves, Sampling, Source};
use crate::stage::Traced;
use crate::trace::LEAVE_EPS;

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

/// The share of a link's paths that draw their direction by cosine rather than their aim point
/// by area: half on near-field links (parts that may touch), and on far links in proportion
/// to the parts' estimated form factor `F̂`, up to half at [`DIRECTION_FULL_AT`].
fn direction_share(near: bool, form_factor: f64) -> f64 {
    if near {
        0.5
    } else {
        0.5 * (form_factor / DIRECTION_FULL_AT).min(1.0)
    }
}

/// The estimated form factor from which a far link draws half its paths by direction.
const DIRECTION_FULL_AT: f64 = 0.2;

/// The most a near link's path may weigh, in multiples of the mean path's weight: a near link
/// draws at least `π A_X / (MAX_WEIGHT · mean)` paths by direction, which bounds its paths'
/// weights by `π A_X / n_D`.
const MAX_WEIGHT: f64 = 64.0;

/// Rays of a near link's pilot estimate.
const PILOT_RAYS: u32 = 16;

/// The share of `PILOT_RAYS` cosine-distributed rays from points of the link's diffuse part
/// (drawn by area) whose first hit is a specular splat of its target node: an estimate of the
/// form factor from `X` to `Y`'s specular part, visibility included.
fn pilot_form_factor(
    scene: Scene,
    leaves: &Leaves,
    diffuse: &Prefix,
    l: &LinkPlan,
    seed: u32,
    link: u32,
) -> f64 {
    let Scene { view, accel, rough } = scene;
    let mut stats = TraversalStats::default();
    let mut hits = 0;
    for k in 0..PILOT_RAYS {
        let u = |d: u32| rand(seed, 0x5bec_0003, link.wrapping_mul(PILOT_RAYS) + k, d);
        let leaf = diffuse.pick(&l.x, u(0) as f64);
        let j = leaves.pick(view, leaf, u(1));
        let s = &view.splats[j as usize];
        let ray = Ray {
            origin: disk_point(s, u(2), u(3)),
            dir: cosine_dir(s.normal, u(4), u(5)),
            t_min: LEAVE_EPS * s.radius,
            t_max: f32::INFINITY,
        };
        if !crate::trace::may_meet(view, l.y_node, &ray) {
            continue; // its first hit cannot be the node's
        }
        let seg = Between::leaving(ray, pc_tree::between::surface(view, rough, j));
        if let Some(hit) = accel.intersect_between(view, &seg, &mut stats) {
            let within = (l.y_splats[0]..l.y_splats[1]).contains(&hit.splat);
            let specular = class::is_specular(leaves.leaves[leaves.leaf_of(hit.splat)].class);
            hits += (within && specular) as u32;
        }
    }
    hits as f64 / PILOT_RAYS as f64
}

/// The octree, its packed walk (with its leaves' surfaces,
/// [`pc_tree::accel::Accel::with_own_surfaces`]) and each leaf's roughness
/// ([`pc_tree::between::leaf_roughness`]): what a ray leaving a splat past its own zone needs.
#[derive(Clone, Copy)]
pub struct Scene<'a> {
    pub view: &'a OctreeView<'a>,
    pub accel: &'a Accel<'a>,
    pub rough: &'a [f32],
}

/// One diffuse → specular link: its parts' leaves and areas, and its paths by each strategy.
struct LinkPlan {
    x: std::ops::Range<usize>,
    y: std::ops::Range<usize>,
    /// The target node's data-pool range, and its node-pool slot.
    y_splats: [u32; 2],
    y_node: u32,
    ax: f64,
    ay: f64,
    share: f64,
    near: bool,
    /// The share of its paths drawn by direction.
    direction: f64,
}

/// Paths from diffuse leaves to the specular leaves they see, `budget` of them in expectation.
///
/// The budget is shared among the V-map's links (node `X`, node `Y`) with diffuse splats in
/// `X` and specular ones in `Y`, in proportion to `A_X A_Y cos θ_X |cos θ_Y| / (d² + (A_X +
/// A_Y) / π)` between the two parts' centroids and mean normals (cosines at least
/// [`MIN_SHARE_COS`]), rounded stochastically. A link's `n` paths follow two strategies
/// (docs/caustics.md "Specular links"):
/// * by area, `n_A` of them: a source leaf in `X` and a target leaf in `Y` drawn by area, the
///   aim point on the target (density `1 / (A_X A_Y)` over the point pair);
/// * by direction, `n_D = β n` of them ([`direction_share`]): a source leaf by area, then a
///   direction by cosine about the source splat, kept if its first hit is a specular splat of
///   `Y` (density `cos θ_x cos θ_y / (π A_X d²)`).
///
/// Every path carries the balance heuristic's weight `f / (n_A p_A + n_D p_D)` of the point
/// pair's geometry `f = cos θ_x cos θ_y / d²`, which is `A_X A_Y / n_A ·`
/// [`link_weight`](emit::link_weight)`(cos θ_x, cos θ_y, d, k)` with `k = n_D A_Y / (π n_A)`: unbiased for every
/// point pair, and bounded by `π A_X / n_D` where the parts touch (a ball on a floor), where the
/// area strategy alone has no bound.
pub fn aims(scene: Scene, leaves: &Leaves, v: &VmapView, budget: u32, seed: u32) -> Vec<Aim> {
    let diffuse = Prefix::new(leaves, &|l| !class::is_specular(l.class));
    let specular = Prefix::new(leaves, &|l| class::is_specular(l.class));
    if specular.part(&(0..leaves.leaves.len())).0 <= 0.0 {
        return Vec::new(); // no specular surface: no path to plan
    }
    let plans = link_plans(scene, leaves, v, (&diffuse, &specular), seed);
    let Some(counts) = path_counts(&plans, budget) else {
        return Vec::new();
    };
    let rounded = rounded_counts(&counts, seed);
    // The id of each link's first path: ids run over the links in order, as one loop would
    // number them.
    let mut id = 0u32;
    let first_path: Vec<u32> = rounded
        .iter()
        .map(|&[a, d]| {
            let first = id;
            id = id.wrapping_add(a).wrapping_add(d);
            first
        })
        .collect();
    // The links' aims, made in parallel over blocks of links (the paths of one link that draw
    // the same source and target leaves are one aim).
    let blocks: Vec<Vec<Aim>> = (0..plans.len())
        .into_par_iter()
        .step_by(AIM_BLOCK)
        .map(|lo| {
            let mut out = Vec::new();
            for i in lo..(lo + AIM_BLOCK).min(plans.len()) {
                let (l, [n_area, n_dir]) = (&plans[i], rounded[i]);
                let (area, dir) = counts[i];
                link_aims(
                    l,
                    (n_area, n_dir),
                    (area, dir),
                    first_path[i],
                    seed,
                    &diffuse,
                    &specular,
                    &mut out,
                );
            }
            out
        })
        .collect();
    crate::stage::concat(&blocks)
}

/// Every V-map link from a node with diffuse splats to one with specular splats, in node order
/// (rayon keeps it), with its share of the paths and its strategies' mix ([`aims`]).
fn link_plans(
    scene: Scene,
    leaves: &Leaves,
    v: &VmapView,
    (diffuse, specular): (&Prefix, &Prefix),
    seed: u32,
) -> Vec<LinkPlan> {
    let mut plans: Vec<LinkPlan> = (0..v.node_range.len())
        .into_par_iter()
        .flat_map_iter(|x| {
            let row = v.links_of(x);
            let [xlo, xhi] = v.node_range[x];
            let xr = leaves.within(xlo, xhi);
            let (ax, cx, nx) = match row.is_empty() {
                true => (0.0, Vec3::ZERO, Vec3::ZERO),
                false => diffuse.part(&xr),
            };
            let links = row.iter().filter(move |k| ax > 0.0 && k.fraction > 0.0);
            links.filter_map(move |link| {
                let y_splats = v.node_range[link.slot() as usize];
                let yr = leaves.within(y_splats[0], y_splats[1]);
                let (ay, cy, ny) = specular.part(&yr);
                if ay <= 0.0 {
                    return None;
                }
                let d = cy - cx;
                let r2 = d.length_squared() as f64;
                let dir = d.normalize_or_zero();
                let cos_x = nx.dot(dir).max(MIN_SHARE_COS) as f64;
                let cos_y = ny.dot(dir).abs().max(MIN_SHARE_COS) as f64;
                let bounded = r2 + (ax + ay) / std::f64::consts::PI;
                let share = ax * ay * cos_x * cos_y / bounded;
                Some(LinkPlan {
                    x: xr.clone(),
                    y: yr,
                    y_splats,
                    y_node: link.slot(),
                    ax,
                    ay,
                    share,
                    near: link.is_near(),
                    direction: 0.0,
                })
            })
        })
        .collect();
    // Near links: the centroids say little about parts that touch (from the floor beside a
    // ball's contact, the ball's centroid lies at a grazing angle, yet it fills most of the
    // sky). Their share and strategy mix follow a pilot estimate of the form factor instead.
    plans.par_iter_mut().enumerate().for_each(|(i, l)| {
        let mut form_factor = l.share / (std::f64::consts::PI * l.ax);
        if l.near {
            let pilot = pilot_form_factor(scene, leaves, diffuse, l, seed, i as u32);
            form_factor = form_factor.max(pilot);
            l.share = l.share.max(std::f64::consts::PI * l.ax * pilot);
        }
        l.direction = direction_share(l.near, form_factor);
    });
    plans
}

/// Each link's expected paths by area and by direction out of `budget`; `None` where no link
/// has a share or the budget is 0. A near link draws at least enough paths by direction that
/// none of its paths weighs more than [`MAX_WEIGHT`] times the mean; the counts are then
/// scaled back to the budget.
fn path_counts(plans: &[LinkPlan], budget: u32) -> Option<Vec<(f64, f64)>> {
    let total: f64 = plans.iter().map(|s| s.share).sum();
    if total <= 0.0 || budget == 0 {
        return None;
    }
    let mean = total / budget as f64;
    let mut counts: Vec<(f64, f64)> = plans
        .iter()
        .map(|l| {
            let n = budget as f64 * l.share / total;
            let mut n_dir = l.direction * n;
            if l.near {
                n_dir = n_dir.max(std::f64::consts::PI * l.ax / (MAX_WEIGHT * mean));
            }
            ((1.0 - l.direction) * n, n_dir)
        })
        .collect();
    let drawn: f64 = counts.iter().map(|c| c.0 + c.1).sum();
    for c in &mut counts {
        *c = (c.0 * budget as f64 / drawn, c.1 * budget as f64 / drawn);
    }
    Some(counts)
}

/// Each link's paths by area and by direction: its expected counts rounded stochastically
/// (unbiased), the random numbers keyed by the link's place.
fn rounded_counts(counts: &[(f64, f64)], seed: u32) -> Vec<[u32; 2]> {
    counts
        .par_iter()
        .enumerate()
        .map(|(i, &(n_area, n_dir))| {
            let round = |m: f64, d: u32| {
                let u = rand(seed, 0x5bec_0001, i as u32, d) as f64;
                (m.floor() + (u < m.fract()) as u32 as f64) as u32
            };
            [round(n_area, 0), round(n_dir, 1)]
        })
        .collect()
}

/// Links whose aims [`aims`] makes in one task.
const AIM_BLOCK: usize = 256;

/// The aims of one link's `n_area` paths by area and `n_dir` by direction (their expected
/// counts `area` and `dir` set the power and the strategies' mix), the first numbered `id`,
/// appended to `out`; consecutive paths that draw the same leaves are one aim.
#[allow(clippy::too_many_arguments)] // (one link's plan, counts, ids and the two prefixes)
fn link_aims(
    l: &LinkPlan,
    (n_area, n_dir): (u32, u32),
    (area, dir): (f64, f64),
    mut id: u32,
    seed: u32,
    diffuse: &Prefix,
    specular: &Prefix,
    out: &mut Vec<Aim>,
) {
    let start = out.len();
    let mut push = |aim: Aim| match out[start..].last_mut() {
        Some(a)
            if Aim {
                photons: a.photons,
                ..aim
            } == *a =>
        {
            a.photons += 1
        }
        _ => out.push(aim),
    };
    let power = [(l.ax * l.ay / area) as f32; 3];
    let k = (dir * l.ay / (std::f64::consts::PI * area)) as f32;
    for _ in 0..n_area {
        let source = diffuse.pick(&l.x, rand(seed, 0x5bec_0002, id, 0) as f64);
        let target = specular.pick(&l.y, rand(seed, 0x5bec_0002, id, 1) as f64);
        id = id.wrapping_add(1);
        push(Aim {
            source: Source::Area(source),
            target,
            photons: 1,
            power,
            sampling: Sampling::Area { k },
        });
    }
    for _ in 0..n_dir {
        let source = diffuse.pick(&l.x, rand(seed, 0x5bec_0002, id, 0) as f64);
        id = id.wrapping_add(1);
        push(Aim {
            source: Source::Area(source),
            target: l.y.start as u32,
            photons: 1,
            power,
            sampling: Sampling::Direction {
                k,
                lo: l.y_splats[0],
                hi: l.y_splats[1],
                node: l.y_node,
            },
        });
    }
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
    /// Back along its paths' directions of travel, each weighted by its weight's channel sum:
    /// where its light comes from (unit; zero where they cancel), and the [`cube_cell`] of
    /// that ([`Shade`]).
    back: Vec3,
    back_cell: u32,
    /// The diffuse splat nearest its centroid: where a [`Shade`] ray leaves it.
    origin: u32,
}

/// The tables from the traced paths of `aims`.
pub fn build(
    scene: Scene,
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
    let view = scene.view;
    let diffuse = |j: usize| !class::is_specular(materials[view.splats[j].material as usize].class);
    let mut bins = bins(view, leaves, &diffuse);
    // The splat each kept path left: the tracer's own draw (`Tracer::start`, random number 0 of
    // its id), so that the sender's radiance is the splat's, not its leaf's mean (a ball lens
    // images a bright spot on the floor; a leaf's mean would spread it first).
    let first = emit::first_ids(aims);
    // Flux rows: (bin, sender splat, weight), merged per pair (made in parallel, in the paths'
    // order; two binary searches and a walk over a leaf's splats each), and each path's
    // direction of travel where it landed.
    let (mut rows, arrivals): (Vec<(u32, u32, Vec3)>, Vec<Vec3>) = traced
        .photons
        .par_iter()
        .zip(&traced.id)
        .filter_map(|(p, &id)| {
            let a = first.partition_point(|&f| f <= id as u64) - 1;
            match aims[a].source {
                Source::Area(d) => {
                    let j = leaves.pick(view, d, rand(seed, id, 0, 0));
                    let row = (leaves.leaf_of(p.splat) as u32, j, Vec3::from(p.power));
                    Some((row, Vec3::from(p.dir)))
                }
                Source::Point(_) => None,
            }
        })
        .unzip();
    for (r, dir) in rows.iter().zip(&arrivals) {
        let b = &mut bins[r.0 as usize];
        b.paths += 1;
        b.back -= r.2.element_sum() * *dir;
    }
    for b in &mut bins {
        b.back = b.back.normalize_or_zero();
        b.back_cell = cube_cell(b.back);
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
    let shade = Shade {
        scene,
        materials,
        bins: &bins,
    };
    let [smooth, interpolate] = gather_links(
        view,
        &bins,
        &diffuse,
        &|j| leaves.leaf_of(j),
        (gather, &shade),
    );
    (out.smooth_offsets, out.smooth) = smooth;
    (out.gather_offsets, out.gather) = interpolate;
    out
}

/// Every octree leaf's diffuse splats as a bin.
fn bins(view: &OctreeView, leaves: &Leaves, diffuse: &(dyn Fn(usize) -> bool + Sync)) -> Vec<Bin> {
    leaves
        .leaves
        .par_iter()
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
                let mut nearest = f32::INFINITY;
                for j in l.lo as usize..l.hi as usize {
                    if diffuse(j) {
                        let s = &view.splats[j];
                        let d = (Vec3::from(s.position) - b.centroid).length();
                        b.extent = b.extent.max(d + s.radius);
                        if d < nearest {
                            (nearest, b.origin) = (d, j as u32);
                        }
                    }
                }
            }
            b
        })
        .collect()
}

/// Shadows within a density estimate's reach: whether the light that another bin of its
/// surface receives through mirrors and glass would reach a bin. A ray from the bin back along
/// the way the other's light arrives (its paths' mean direction, weighted) that first meets a
/// diffuse or emitting splat within the smoothing radius says no; a mirror or a glass met first
/// may be where that light comes from. The other bin is then left out of the bin's estimate and
/// of its splats' interpolation, where its light would spread into the shadow: the ceiling above
/// a lamp hanging 1 cm under it, which a mirror ball lights all around (docs/caustics.md,
/// "Shadows in the smoothing"). The bins around one bin whose light arrives within one cell of
/// a cube map ([`cube_cell`]) share one ray: their paths mostly come the same way, off the
/// same mirror (at 1M splats a ray for every pair took 0.65 s more).
struct Shade<'a> {
    scene: Scene<'a>,
    materials: &'a [pc_artifact::octree::MaterialRecord],
    bins: &'a [Bin],
}

impl Shade<'_> {
    /// Whether the light arriving at bin `from` is blocked within `reach` in front of bin `at`;
    /// `seen` holds the answers for `at` so far, by direction cell.
    fn hides(&self, (at, from): (u32, u32), reach: f32, seen: &mut Vec<(u32, bool)>) -> bool {
        if at == from {
            return false;
        }
        let (b, c) = (&self.bins[at as usize], &self.bins[from as usize]);
        if c.back == Vec3::ZERO {
            return false;
        }
        if let Some(&(_, hidden)) = seen.iter().find(|s| s.0 == c.back_cell) {
            return hidden;
        }
        let hidden = self.blocked(b, c.back, reach);
        seen.push((c.back_cell, hidden));
        hidden
    }

    /// Whether a ray from bin `b` along `back` first meets a splat that is not specular
    /// within `reach`.
    fn blocked(&self, b: &Bin, back: Vec3, reach: f32) -> bool {
        let view = self.scene.view;
        let (s, rough) = surface(view, self.scene.rough, b.origin);
        if Vec3::from(s.normal).dot(back) <= 0.0 {
            return false;
        }
        let ray = Ray {
            origin: s.position.into(),
            dir: back,
            t_min: LEAVE_EPS * s.radius,
            t_max: reach,
        };
        let seg = Between::leaving(ray, (s, rough));
        let mut stats = TraversalStats::default();
        self.scene
            .accel
            .intersect_between(view, &seg, &mut stats)
            .is_some_and(|hit| {
                let m = view.splats[hit.splat as usize].material;
                !class::is_specular(self.materials[m as usize].class)
            })
    }
}

/// Cells along a cube-map face's edge in [`cube_cell`]: 5.6° at a face's centre.
const DIRECTION_CELLS: u32 = 16;

/// Which of `6 × DIRECTION_CELLS²` cells of a cube map the unit direction `d` falls in.
fn cube_cell(d: Vec3) -> u32 {
    let a = d.abs();
    let (face, u, v, m) = if a.x >= a.y && a.x >= a.z {
        (u32::from(d.x < 0.0), d.y, d.z, a.x)
    } else if a.y >= a.z {
        (2 + u32::from(d.y < 0.0), d.x, d.z, a.y)
    } else {
        (4 + u32::from(d.z < 0.0), d.x, d.y, a.z)
    };
    let n = DIRECTION_CELLS;
    let q = |t: f32| (((t / m + 1.0) * 0.5 * n as f32) as u32).min(n - 1);
    (face * n + q(u)) * n + q(v)
}

/// Bins farther than this from a splat's plane, in kernel radii, lie on another surface.
const PLANE_TOLERANCE: f32 = 0.25;
/// Bins whose normal differs by more than 45° lie on another surface.
const SAME_SURFACE_COS: f32 = std::f32::consts::FRAC_1_SQRT_2;
/// Bins looked at to find the radius that holds the gather count.
const RADIUS_CANDIDATES: usize = 256;
/// Bins looked at first ([`gather_links`]).
const RADIUS_FIRST: usize = 32;

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
    (gather, shade): (u32, &Shade),
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
    // The density estimate of each bin: the radius that holds `gather` paths of its surface,
    // without the bins whose light a surface in front of it hides within that radius
    // ([`Shade`]); and those bins.
    let (smooth, hidden): (Vec<Vec<GatherLink>>, Vec<Vec<u32>>) = bins
        .par_iter()
        .enumerate()
        .map(|(at, b)| {
            if b.area <= 0.0 {
                return (Vec::new(), Vec::new());
            }
            let q: [f32; 3] = b.centroid.into();
            // The paths of the surface's bins among the `want` nearest, nearest first, until
            // they hold the gather count, and the reach of the last one taken.
            let gathered = |want: usize| {
                let k = NonZeroUsize::new(want.min(used.len())).unwrap();
                let mut found = tree
                    .query(&q)
                    .nearest_n::<SquaredEuclidean<f32>>(k)
                    .unsorted()
                    .execute();
                // Sorted here, ties by bin: kiddo's own sorted output went through a binary
                // heap (0.2 s of the 1M bench box's 6.7 s stage, the links the same).
                found.sort_unstable_by(|a, b| {
                    (a.distance.total_cmp(&b.distance)).then(a.item.cmp(&b.item))
                });
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
                (paths, reach, k.get() < want)
            };
            // The nearest few first, and a query for all the candidates (a heap of
            // RADIUS_CANDIDATES) only where they do not hold the gather count and more bins
            // exist. (On the 1M bench box 60 % of the bins need the second query; a middle
            // query of 96 bins gave the same links and no time, 2026-11-28.)
            let (paths, reach, all) = gathered(RADIUS_FIRST);
            let reach = if paths >= gather || all {
                reach
            } else {
                gathered(RADIUS_CANDIDATES).1
            };
            let h = reach.max(2.0 * b.extent);
            let (mut norm, mut row, mut hidden, mut seen) =
                (0.0f64, Vec::new(), Vec::new(), Vec::new());
            around(b.centroid, b.normal, h, &mut |i, c, k| {
                if c.paths > 0 && shade.hides((at as u32, i), h, &mut seen) {
                    hidden.push(i);
                    return;
                }
                norm += (k * c.area) as f64;
                if c.paths > 0 {
                    row.push(GatherLink { bin: i, weight: k });
                }
            });
            hidden.sort_unstable();
            if norm <= 0.0 {
                return (Vec::new(), hidden);
            }
            let scale = (1.0 / (std::f64::consts::PI * norm)) as f32;
            row.sort_unstable_by_key(|g| g.bin);
            row.iter_mut().for_each(|g| g.weight *= scale);
            (row, hidden)
        })
        .unzip();
    // Each splat between the bins of its surface within twice its own bin's extent, but for
    // those its own bin's estimate left out.
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
                if hidden[own].binary_search(&b).is_ok() {
                    return;
                }
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
