//! The final gather (docs/fmm.md, "Final gather"): where a V-map leaf's links cannot stand for
//! every splat in it (an occluder close to the leaf, as under a ball resting on a floor, makes
//! visibility change from splat to splat), the splats of that leaf gather the solved light
//! themselves, by ray casting, instead of taking the FMM's `T` at the leaf's shared fractions.
//!
//! Which leaves: candidates are those where pc-vmap's `smear` section (crates/pc-vmap/src/smear.rs)
//! says some node's visible transfer differs from what its links give it by more than
//! `gather_error` of it, beyond [`Z`] standard deviations of the V-map's sampling, or that at
//! least `gather_contact` of the leaf's probes found another surface close over it
//! ([`candidates`]). A pilot of a few rays per splat measures how far off the light of each
//! group of [`GROUP`] neighbouring splats in them is; the groups off by more than
//! `gather_error` are gathered, the worst first, at most `gather_share` of the active splats
//! ([`run`]).
//!
//! How: each splat casts a stratified grid of cosine-distributed rays from its centre, each
//! passing over its own rough surface as the V-map's rays do (its own zone,
//! [`pc_tree::Between::leaving`]), and averages the reflected radiance `L − Lₑ` of the splats
//! they hit from the front ([`gather_splat`]): an unbiased estimate of `(T (L − Lₑ))_i`, the light
//! the FMM's `T` would bring, with visibility per ray. The gathered splats within a splat's disk
//! pool their rays for it ([`crate::pool`]), so each casts its share of `gather_rays`. Specular
//! splats (whose light reaches diffuse ones through `S`), back faces and the sky give nothing. The CPU twin of
//! `shaders/fmm/gather.wgsl` ([`GpuGather`]): the same rays from the same random numbers.

use glam::Vec3;
use pc_artifact::octree::{node, Splat};
use pc_artifact::vmap::VmapView;
use pc_gpu::{grid, Binding, GpuContext, GpuError, Kernel};
use pc_tree::accel::Accel;
use pc_tree::between::LEAVE_EPS;
use pc_tree::gpu::{GpuOctree, OctreeParts};
use pc_tree::rng::rand;
use pc_tree::{Between, OctreeView, Ray, TraversalStats};
use rayon::prelude::*;

use crate::pool::Footprints;

/// Standard deviations of the V-map's sampling noise a misstatement must stand out by.
pub const Z: f32 = 3.0;

/// The seed of the gather's random numbers (fixed: a rerun gives the same light).
const SEED: u32 = 0x6761_7468;

/// Which V-map leaves the final gather considers and how many splats it may gather
/// ([`candidates`], [`run`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Selection {
    /// A candidate: some node in the leaf whose light the links misstate by more than this
    /// share of it ([`pc_artifact::vmap::Smear::exceeds`], beyond [`Z`] deviations); gathered
    /// when the pilot finds its light off by more than this share, too.
    pub error: f32,
    /// A candidate, too: at least this share of the leaf's probes blocked by a surface close
    /// over it.
    pub contact: f32,
    /// At most this share of the active splats is gathered in all, the groups the pilot finds
    /// most off first.
    pub share: f32,
}

impl Selection {
    /// The selection the parameters `p` ask for.
    pub fn of(p: &pc_artifact::params::FmmParams) -> Selection {
        Selection {
            error: p.gather_error,
            contact: p.gather_contact,
            share: p.gather_share,
        }
    }
}

/// Rays per splat of the pilot gather that ranks the candidates (a 4 × 4 grid).
pub const PILOT_RAYS: u32 = 16;

/// The pilot visits at most this many times the splats the gather may take (`gather_share`):
/// the candidates the V-map suspects most, where many are (a scan's rough surfaces).
const PILOT_BUDGET: usize = 4;

/// The unit the gather takes or leaves: splats of a candidate leaf consecutive in Morton order
/// (so close together), whose pilot differences are summed before their magnitude is taken
/// (the error under a ball changes sign across a leaf, and the pilot's noise mostly cancels
/// within a group). Smaller than a V-map leaf, which holds up to 1,280 splats at 20M.
const GROUP: usize = 8;

/// What the solve gave each splat (per splat, RGB).
#[derive(Clone, Copy)]
pub struct Solved<'a> {
    pub radiance: &'a [[f32; 3]],
    /// The source term: the light that reaches a splat other than through `T` and `S`.
    pub source: &'a [[f32; 3]],
    pub albedo: &'a [[f32; 3]],
    pub active: &'a [bool],
}

impl Solved<'_> {
    /// The active splats and the mean luminance (`r + g + b`) of their radiance.
    fn active_mean(&self) -> (usize, f64) {
        let active = (0..self.active.len()).filter(|&i| self.active[i]);
        let count = active.clone().count();
        let sum: f64 = active.map(|i| lum(self.radiance[i].into())).sum();
        (count, sum / count.max(1) as f64)
    }
}

/// The luminance the gather ranks by: `r + g + b`.
fn lum(c: Vec3) -> f64 {
    (c.x + c.y + c.z) as f64
}

/// A V-map leaf the final gather considers ([`candidates`]), with how strongly the V-map
/// suspects its links: its contact share, or the worst relative misstatement of a node in it
/// (at most 1), whichever is larger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    pub slot: u32,
    pub suspicion: f32,
}

/// The V-map leaves whose links may misstate their splats' light (pc-vmap's `smear` section):
/// a node in the leaf misstated beyond `how.error` (significant at [`Z`]), or a contact share
/// of at least `how.contact`. Ascending node-pool slots.
pub fn candidates(view: &OctreeView, vmap: &VmapView, how: Selection) -> Vec<Candidate> {
    let mut leaves = Vec::new();
    let mut stack: Vec<u32> = if view.nodes.is_empty() {
        vec![]
    } else {
        vec![0]
    };
    while let Some(slot) = stack.pop() {
        if vmap.vnode[slot as usize] != 0 {
            let contact = vmap.smear[slot as usize].contact;
            let contact = (contact >= how.contact).then_some(contact);
            let misstated = misstatement(view, vmap, slot, how.error);
            if let Some(suspicion) = contact.into_iter().chain(misstated).reduce(f32::max) {
                leaves.push(Candidate { slot, suspicion });
            }
            continue;
        }
        stack.extend(children(view, slot));
    }
    leaves.sort_unstable_by_key(|c| c.slot);
    leaves
}

/// What the final gather did ([`run`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gathered {
    /// The gathered splats (ascending data-pool indices) and their new radiance.
    pub splats: Vec<u32>,
    pub radiance: Vec<[f32; 3]>,
    /// The active splats of the candidate leaves, and those the pilot visited.
    pub candidates: u64,
    pub piloted: u64,
    /// Rays cast, the pilot's and the gather's.
    pub rays: u64,
}

/// What the specular links bring each of a list of splats (`S (L − Lₑ)`), or `None` without
/// links.
pub type SpecularAt<'a> = &'a dyn Fn(&[u32]) -> Option<Vec<[f32; 3]>>;

/// The final gather over the candidate `leaves` ([`candidates`]) of the octree `view`: a pilot
/// of [`PILOT_RAYS`] rays per splat measures how far off the light of each group of [`GROUP`]
/// neighbouring splats is ([`rank`]); the groups off by more than `how.error` are gathered,
/// the most off first, at most `how.share` of the active splats, with `rays` for each splat's
/// footprint ([`Footprints`]: the gathered splats within its disk share theirs). Each gathered
/// splat's radiance becomes its source plus its albedo times its gathered light and what
/// `specular` brings it through mirrors and glass.
#[allow(clippy::too_many_arguments)]
pub fn run(
    view: &OctreeView,
    vmap: &VmapView,
    candidates: &[Candidate],
    solved: Solved,
    how: Selection,
    rays: GatherRays,
    gatherer: &Gatherer,
    specular: SpecularAt,
) -> Result<Gathered, GpuError> {
    let active = solved.active;
    let own = |slot: u32| {
        let [lo, hi] = vmap.node_range[slot as usize];
        (lo..hi).filter(move |&i| active[i as usize])
    };
    let (count, mean) = solved.active_mean();
    let budget = (how.share as f64 * count as f64) as usize;
    let leaves = piloted(vmap, candidates, solved, mean, PILOT_BUDGET * budget);
    let pilot_splats: Vec<u32> = leaves.iter().flat_map(|&l| own(l)).collect();
    let mut out = Gathered {
        candidates: candidates.iter().map(|c| own(c.slot).count() as u64).sum(),
        piloted: pilot_splats.len() as u64,
        ..Default::default()
    };
    if rays.strata == 0 || pilot_splats.is_empty() {
        return Ok(out);
    }
    let pilot = GatherRays {
        strata: PILOT_RAYS.isqrt(),
    };
    let g = gatherer.gather(pilot, &pilot_splats)?;
    let through = specular(&pilot_splats);
    out.rays += pilot_splats.len() as u64 * PILOT_RAYS as u64;
    let pilot = Pilot {
        splats: &pilot_splats,
        gathered: &g,
        specular: through.as_deref(),
    };
    // Pilot index of each gathered splat, for what the specular links bring it.
    let mut taken: Vec<usize> = Vec::new();
    for (_, group) in rank(vmap, &leaves, pilot, solved, mean, how.error) {
        if taken.len() + group.len() <= budget {
            taken.extend(group);
        }
    }
    taken.sort_unstable_by_key(|&k| pilot_splats[k]);
    out.splats = taken.iter().map(|&k| pilot_splats[k]).collect();
    if out.splats.is_empty() {
        return Ok(out);
    }
    // The rays are pooled over each splat's footprint (crate::pool).
    let feet = Footprints::new(view, &out.splats);
    let strata = feet.strata(rays);
    let light = feet.pool(&gather_grids(gatherer, &out.splats, &strata)?, &strata);
    out.rays += strata.iter().map(|&s| (s * s) as u64).sum::<u64>();
    out.radiance = taken
        .iter()
        .zip(&light)
        .map(|(&k, l)| {
            let s = pilot.specular.map_or(Vec3::ZERO, |s| Vec3::from(s[k]));
            radiance_with(solved, pilot_splats[k] as usize, Vec3::from(*l) + s).into()
        })
        .collect();
    Ok(out)
}

/// Each of `splats` gathered with its own grid of `strata × strata` rays, one call of the
/// gatherer per grid.
fn gather_grids(
    gatherer: &Gatherer,
    splats: &[u32],
    strata: &[u32],
) -> Result<Vec<[f32; 3]>, GpuError> {
    let mut grids = strata.to_vec();
    grids.sort_unstable();
    grids.dedup();
    let mut light = vec![[0.0; 3]; splats.len()];
    for grid in grids {
        let ks: Vec<usize> = (0..splats.len()).filter(|&k| strata[k] == grid).collect();
        let these: Vec<u32> = ks.iter().map(|&k| splats[k]).collect();
        let found = gatherer.gather(GatherRays { strata: grid }, &these)?;
        for (k, l) in ks.into_iter().zip(found) {
            light[k] = l;
        }
    }
    Ok(light)
}

/// The candidates the pilot visits (ascending slots): the most suspect first ([`Candidate`]),
/// times the share of their light that came through the solve's transport (what the gather
/// replaces: a leaf lit mostly directly, or hidden and dark, has little to gain), while their
/// splats fit `splats`.
fn piloted(
    vmap: &VmapView,
    candidates: &[Candidate],
    solved: Solved,
    mean: f64,
    splats: usize,
) -> Vec<u32> {
    let active = solved.active;
    let mut ranked: Vec<(f64, u32, usize)> = candidates
        .iter()
        .map(|c| {
            let [lo, hi] = vmap.node_range[c.slot as usize];
            let (mut transported, mut light, mut n) = (0.0f64, 0.0f64, 0);
            for i in (lo..hi).map(|i| i as usize).filter(|&i| active[i]) {
                let (l, e) = (solved.radiance[i].into(), solved.source[i].into());
                transported += (lum(l) - lum(e)).max(0.0);
                light += lum(l).max(0.0) + 0.01 * mean;
                n += 1;
            }
            let share = if light > 0.0 {
                transported / light
            } else {
                0.0
            };
            (c.suspicion as f64 * share, c.slot, n)
        })
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let (mut taken, mut leaves) = (0usize, Vec::new());
    for (_, slot, n) in ranked {
        if taken + n <= splats {
            taken += n;
            leaves.push(slot);
        }
    }
    leaves.sort_unstable();
    leaves
}

/// Splat `i`'s radiance with `transported` light (`G + S`): its source plus its albedo times it.
fn radiance_with(solved: Solved, i: usize, transported: Vec3) -> Vec3 {
    Vec3::from(solved.source[i]) + Vec3::from(solved.albedo[i]) * transported
}

/// The pilot's gather of the candidate leaves' splats (in leaf order) and what the specular
/// links bring each of them.
#[derive(Clone, Copy)]
struct Pilot<'a> {
    splats: &'a [u32],
    gathered: &'a [[f32; 3]],
    specular: Option<&'a [[f32; 3]]>,
}

/// The groups of [`GROUP`] splats of the candidate `leaves` (ranges of the pilot's splats)
/// whose light the pilot finds off by more than `error`, the most off first, with that
/// relative error: the difference of their radiance with the pilot's light from the solve's,
/// summed before the magnitude is taken, over `Σ |L| + 1 %` of the scene's mean (the terms of
/// the per-pixel relative error).
fn rank(
    vmap: &VmapView,
    leaves: &[u32],
    pilot: Pilot,
    solved: Solved,
    mean: f64,
    error: f32,
) -> Vec<(f64, std::ops::Range<usize>)> {
    let active = solved.active;
    // Splat k of the pilot: its radiance with the pilot's light against the solve's, and the
    // solve's with the margin.
    let off = |k: usize| {
        let i = pilot.splats[k] as usize;
        let through = pilot.specular.map_or(Vec3::ZERO, |s| Vec3::from(s[k]));
        let want = radiance_with(solved, i, Vec3::from(pilot.gathered[k]) + through);
        lum(want) - lum(solved.radiance[i].into())
    };
    let light =
        |k: usize| lum(solved.radiance[pilot.splats[k] as usize].into()).max(0.0) + 0.01 * mean;
    let mut ranked = Vec::new();
    let mut at = 0;
    for &leaf in leaves {
        let [lo, hi] = vmap.node_range[leaf as usize];
        let n = (lo..hi).filter(|&i| active[i as usize]).count();
        let ks: Vec<usize> = (at..at + n).collect();
        at += n;
        for g in ks.chunks(GROUP) {
            let diff = g.iter().map(|&k| off(k)).sum::<f64>().abs();
            let light: f64 = g.iter().map(|&k| light(k)).sum();
            let rel = if light > 0.0 { diff / light } else { 0.0 };
            if rel > error as f64 {
                ranked.push((rel, g[0], g.len()));
            }
        }
    }
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    ranked.into_iter().map(|(r, k, n)| (r, k..k + n)).collect()
}

/// The worst relative misstatement (at most 1) of a node in the subtree of `slot` misstated by
/// more than `error` of its transfer beyond [`Z`] deviations; `None` where none is.
fn misstatement(view: &OctreeView, vmap: &VmapView, slot: u32, error: f32) -> Option<f32> {
    let mut worst = None;
    let mut stack = vec![slot];
    while let Some(s) = stack.pop() {
        let m = &vmap.smear[s as usize];
        if m.exceeds(error, Z) {
            let rel = (m.error.abs() / m.transfer.max(f32::MIN_POSITIVE)).min(1.0);
            worst = Some(worst.map_or(rel, |w: f32| w.max(rel)));
        }
        stack.extend(children(view, s));
    }
    worst
}

/// The non-empty children of `slot`.
fn children<'v>(view: &'v OctreeView<'v>, slot: u32) -> impl Iterator<Item = u32> + 'v {
    let w = view.nodes[slot as usize];
    let first = match node::is_leaf(w) || node::is_empty(w) {
        true => 0,
        false => node::ptr(w),
    };
    let count = if first == 0 { 0 } else { 8 };
    (first..first + count).filter(move |&c| !node::is_empty(view.nodes[c as usize]))
}

/// How the gather casts its rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GatherRays {
    /// The rays of a splat form a `strata × strata` grid over the cosine-weighted hemisphere.
    pub strata: u32,
}

impl GatherRays {
    /// `rays` per splat, rounded down to a square.
    pub fn new(rays: u32) -> GatherRays {
        GatherRays {
            strata: (rays as f64).sqrt().floor() as u32,
        }
    }

    /// The `k`-th ray of splat `i` (grid cell `k / strata`, `k % strata`, jittered).
    fn ray(&self, view: &OctreeView, i: u32, k: u32) -> Ray {
        let s = &view.splats[i as usize];
        let m = self.strata as f32;
        let u1 = ((k / self.strata) as f32 + rand(SEED, i, k, 0)) / m;
        let u2 = ((k % self.strata) as f32 + rand(SEED, i, k, 1)) / m;
        Ray {
            origin: Vec3::from(s.position),
            dir: pc_tree::cosine_dir(s.normal, u1, u2),
            t_min: LEAVE_EPS * s.radius,
            t_max: f32::INFINITY,
        }
    }
}

/// The mean reflected radiance that splat `i`'s rays find (`reflected`: `L − Lₑ` of every splat,
/// zero where a splat takes no part): its gathered `T (L − Lₑ)`. Each ray passes over its own
/// rough surface within its own zone (`rough`: each octree leaf's roughness,
/// [`pc_tree::between::leaf_roughness`]), as the V-map's rays do: on the 20M hall scan the
/// Δ rule alone (hits on splats facing like the origin ignored within half a radius) let 61 % of
/// the rays end on the back of the surface's own noise and bring nothing, 1.1 % with the own
/// zone. WGSL twin: `gather` in shaders/fmm/gather.wgsl.
pub fn gather_splat(
    (view, accel, rough): (&OctreeView, &Accel, &[f32]),
    reflected: &[[f32; 3]],
    rays: GatherRays,
    i: u32,
    stats: &mut TraversalStats,
) -> [f32; 3] {
    let own = pc_tree::between::surface(view, rough, i);
    let count = rays.strata * rays.strata;
    let mut sum = Vec3::ZERO;
    for k in 0..count {
        sum += gather_ray((view, accel), reflected, rays.ray(view, i, k), own, stats);
    }
    (sum / count.max(1) as f32).into()
}

/// What one gather ray brings: the reflected radiance of the splat it hits from the front.
fn gather_ray(
    (view, accel): (&OctreeView, &Accel),
    reflected: &[[f32; 3]],
    ray: Ray,
    own: (&Splat, f32),
    stats: &mut TraversalStats,
) -> Vec3 {
    let seg = Between::leaving(ray, own);
    match accel.intersect_between(view, &seg, stats) {
        Some(h) if Vec3::from(view.splats[h.splat as usize].normal).dot(seg.ray.dir) < 0.0 => {
            Vec3::from(reflected[h.splat as usize])
        }
        _ => Vec3::ZERO,
    }
}

/// Rays cast per sorted batch of the CPU gather ([`gather_cpu`]).
const SORTED_BATCH: usize = 1 << 21;

/// [`gather_splat`] for each of `splats`, in batches of about [`SORTED_BATCH`] rays cast in the
/// order of their direction (one of 96 cells of a cube map), then of their splat: rays in one
/// direction from splats near one another (ascending indices follow the octree's space-filling
/// curve) walk the cells the rays before them brought into the cache. Each splat's rays are
/// summed in its own order afterwards: the same light to the bit as one splat at a time.
pub fn gather_cpu(
    (view, accel, rough): (&OctreeView, &Accel, &[f32]),
    reflected: &[[f32; 3]],
    rays: GatherRays,
    splats: &[u32],
) -> Vec<[f32; 3]> {
    let count = (rays.strata * rays.strata) as usize;
    if count == 0 {
        return vec![[0.0; 3]; splats.len()];
    }
    let per_batch = (SORTED_BATCH / count).max(1);
    let mut out = Vec::with_capacity(splats.len());
    for batch in splats.chunks(per_batch) {
        // Every ray of the batch, splat-major, made once; then their order by direction cell.
        let made: Vec<Ray> = (0..batch.len() * count)
            .into_par_iter()
            .map(|r| rays.ray(view, batch[r / count], (r % count) as u32))
            .collect();
        let mut order: Vec<(u32, u32)> = made
            .par_iter()
            .enumerate()
            .map(|(r, ray)| (pc_tree::ray::direction_cell(ray.dir), r as u32))
            .collect();
        order.par_sort_unstable();
        let cast: Vec<Vec3> = order
            .par_iter()
            .map_init(TraversalStats::default, |st, &(_, r)| {
                let own = pc_tree::between::surface(view, rough, batch[r as usize / count]);
                gather_ray((view, accel), reflected, made[r as usize], own, st)
            })
            .collect();
        let mut found = vec![Vec3::ZERO; made.len()];
        for (&(_, r), l) in order.iter().zip(cast) {
            found[r as usize] = l;
        }
        // Each splat's rays in its own order, as gather_splat sums them.
        out.par_extend(found.par_chunks(count).map(|rs| {
            let sum = rs.iter().fold(Vec3::ZERO, |s, &l| s + l);
            <[f32; 3]>::from(sum / count as f32)
        }));
    }
    out
}

/// The gather on the device it was made for, of one solution's reflected radiance.
pub enum Gatherer<'a> {
    Cpu {
        view: &'a OctreeView<'a>,
        /// The walk, passing over own surfaces ([`Accel::with_own_surfaces`]).
        accel: &'a Accel<'a>,
        /// Each octree leaf's roughness ([`pc_tree::between::leaf_roughness`]).
        rough: &'a [f32],
        /// `L − Lₑ` of every splat, zero where a splat takes no part ([`reflected`]).
        reflected: Vec<[f32; 3]>,
    },
    Gpu(Box<GpuGather>),
}

impl<'a> Gatherer<'a> {
    /// The CPU gather of `reflected` (per splat, [`reflected`]) through `accel` (the stage's
    /// walk, with its own surfaces: [`Accel::with_own_surfaces`]), each leaf of roughness
    /// `rough`.
    pub fn cpu(
        (view, accel): (&'a OctreeView<'a>, &'a Accel<'a>),
        rough: &'a [f32],
        reflected: Vec<[f32; 3]>,
    ) -> Gatherer<'a> {
        Gatherer::Cpu {
            view,
            accel,
            rough,
            reflected,
        }
    }

    /// [`gather_cpu`] or [`GpuGather::gather`].
    pub fn gather(&self, rays: GatherRays, splats: &[u32]) -> Result<Vec<[f32; 3]>, GpuError> {
        match self {
            Gatherer::Cpu {
                view,
                accel,
                rough,
                reflected,
            } => Ok(gather_cpu((view, accel, rough), reflected, rays, splats)),
            Gatherer::Gpu(g) => g.gather(rays, splats),
        }
    }

    /// What runs it, for reports.
    pub fn device(&self) -> String {
        match self {
            Gatherer::Cpu { .. } => format!("CPU ({} threads)", rayon::current_num_threads()),
            Gatherer::Gpu(g) => g.device(),
        }
    }
}

/// Every splat's reflected radiance `L − Lₑ` (`radiance` and `emission` per splat), zero where
/// a splat takes no part (`active`).
pub fn reflected(radiance: &[[f32; 3]], emission: &[[f32; 3]], active: &[bool]) -> Vec<[f32; 3]> {
    radiance
        .iter()
        .zip(emission)
        .zip(active)
        .map(|((l, e), &a)| match a {
            true => std::array::from_fn(|c| l[c] - e[c]),
            false => [0.0; 3],
        })
        .collect()
}

/// WGSL `GatherParams`: the dispatch casts rays `first .. first + rays` of each splat's
/// `strata²`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuParams {
    strata: u32,
    count: u32,
    first: u32,
    rays: u32,
}

/// WGSL `GatherSlot`: the splat to gather (in) and its gathered light (out).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuSlot {
    value: [f32; 3],
    splat: u32,
}

/// Splats per dispatch (a dispatch must stay short: drivers reset devices whose work runs for
/// seconds).
const SPLATS_PER_DISPATCH: usize = 1 << 14;

/// Rays of each splat one dispatch casts on a software adapter. llvmpipe ends a shader's loops
/// after 65535 iterations per invocation group, all loops together (Mesa's
/// `LP_MAX_TGSI_LOOP_ITERATIONS`), silently: with the default 256 rays in one dispatch the
/// box test scene's gathered light came out wrong at 1801 of 1844 splats (relative L2 0.44),
/// some of them black. A hardware GPU casts them all in one dispatch.
const SOFTWARE_RAYS: u32 = 8;

/// The kernel's source (`shaders/fmm/gather.wgsl` with the files it requires).
pub fn gpu_source() -> Result<String, GpuError> {
    pc_gpu::shaders::source("fmm/gather.wgsl")
}

/// The final gather on the GPU: `shaders/fmm/gather.wgsl`, twin of [`gather_cpu`].
pub struct GpuGather {
    ctx: GpuContext,
    kernel: Kernel,
    octree: GpuOctree,
    /// `L − Lₑ` of every splat, padded to `vec4`.
    reflected: pc_gpu::Buffer,
    /// Each octree leaf's roughness.
    rough: pc_gpu::Buffer,
}

impl GpuGather {
    /// Upload the octree (its shading parts too: the shared `optics.wgsl` declares them) and
    /// the reflected radiance to gather, `reflected` ([`reflected`]), with each leaf's
    /// roughness `rough`.
    pub fn new(
        ctx: GpuContext,
        view: &OctreeView,
        rough: &[f32],
        reflected: &[[f32; 3]],
    ) -> Result<GpuGather, GpuError> {
        let mut b = vec![Binding::Uniform];
        b.extend([Binding::ReadOnly; 7]);
        b.push(Binding::Uniform);
        b.push(Binding::ReadWrite);
        b.push(Binding::ReadOnly);
        let kernel = ctx.kernel("fmm/gather", &gpu_source()?, "main", &b)?;
        let octree = GpuOctree::upload(&ctx, view, OctreeParts::Shade)?;
        let padded: Vec<[f32; 4]> = reflected.iter().map(|r| [r[0], r[1], r[2], 0.0]).collect();
        let reflected = ctx.storage("reflected", bytemuck::cast_slice(&padded))?;
        let rough = ctx.storage("leaf_rough", bytemuck::cast_slice(rough))?;
        Ok(GpuGather {
            ctx,
            kernel,
            octree,
            reflected,
            rough,
        })
    }

    /// What the GPU runs on, for reports.
    pub fn device(&self) -> String {
        self.ctx.describe()
    }

    /// [`gather_cpu`] on the GPU: each chunk of splats in one dispatch, or on a software adapter
    /// in dispatches of [`SOFTWARE_RAYS`] rays each, every one adding to the sums the one before
    /// left (the CPU's order of addition).
    pub fn gather(&self, rays: GatherRays, splats: &[u32]) -> Result<Vec<[f32; 3]>, GpuError> {
        let ctx = &self.ctx;
        let rb = &self.reflected;
        let total = rays.strata * rays.strata;
        let per_dispatch = match ctx.is_software() {
            true => SOFTWARE_RAYS,
            false => total.max(1),
        };
        let mut out = Vec::with_capacity(splats.len());
        for chunk in splats.chunks(SPLATS_PER_DISPATCH) {
            let slots: Vec<GpuSlot> = chunk
                .iter()
                .map(|&splat| GpuSlot {
                    splat,
                    ..Default::default()
                })
                .collect();
            let sb = ctx.storage("gather_slots", bytemuck::cast_slice(&slots))?;
            let mut first = 0;
            loop {
                let params = GpuParams {
                    strata: rays.strata,
                    count: chunk.len() as u32,
                    first,
                    rays: per_dispatch,
                };
                let pb = ctx.uniform("gather_params", bytemuck::bytes_of(&params));
                let binds: Vec<&pc_gpu::Buffer> = self
                    .octree
                    .buffers()
                    .chain([rb, &pb, &sb, &self.rough])
                    .collect();
                self.kernel.run(ctx, &binds, grid(chunk.len() as u32, 64))?;
                first += per_dispatch;
                if first >= total {
                    break;
                }
            }
            let size = std::mem::size_of_val(slots.as_slice()) as u64;
            let bytes = ctx.read(&sb, size)?;
            let back: &[GpuSlot] = bytemuck::cast_slice(&bytes);
            out.extend(back.iter().map(|s| s.value));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wgsl_records_match_rust_layouts() {
        let module = pc_gpu::validate_wgsl(&gpu_source().unwrap()).unwrap();
        for (name, size) in [
            ("GatherParams", std::mem::size_of::<GpuParams>()),
            ("GatherSlot", std::mem::size_of::<GpuSlot>()),
        ] {
            let (got, _) = pc_gpu::wgsl_struct_layout(&module, name).unwrap();
            assert_eq!(got as usize, size, "{name}");
        }
    }

    #[test]
    fn rays_round_down_to_a_square() {
        assert_eq!(GatherRays::new(256).strata, 16);
        assert_eq!(GatherRays::new(255).strata, 15);
        assert_eq!(GatherRays::new(0).strata, 0);
    }
}
