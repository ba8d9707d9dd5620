//! The radiosity solve, by restarted GMRES ([`solve_gmres`], the default) or Jacobi
//! ([`solve`]); docs/fmm.md "Solver".
//!
//! Jacobi iteration `L ← E + ρ ∘ T (L − Lₑ)` runs until the relative residual
//! `‖L_{k+1} − L_k‖_A / ‖L_{k+1} − Lₑ‖_A` (area-weighted L2 over RGB) falls below the
//! tolerance. The norm leaves out the emitters' own radiance `Lₑ`: a light 100 times brighter
//! than the room would otherwise make the residual look converged long before the
//! inter-reflections are.
//!
//! Jacobi with an FMM product: every iteration is one application of the operator `T`, which is
//! what the FMM makes O(N). The error left after stopping is about `r λ / (1 − λ)` with `λ`
//! the convergence rate (`r_k / r_{k−1}`), which [`Solution::error_estimate`] reports.

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_artifact::vmap::Link;
use pc_tree::caster::Caster;
use pc_tree::{OctreeView, Ray};

use crate::lanes;
use crate::shaft::{Aabb, DiskBoxes, Shaft};
use crate::tree::Points;

/// Anything that applies the transport operator `out_i = Σ_j f K(i, j) A_j L_j`.
pub trait Operator {
    /// One application at the configured order.
    fn apply(&mut self, radiance: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), String> {
        self.apply_relaxed(radiance, out, 1.0).map(|_| ())
    }
    /// An application whose error may be up to `relax` (≥ 1) times [`Operator::apply`]'s: an
    /// operator with cheaper, coarser forms takes the cheapest within it (relaxed products of
    /// inexact Krylov methods, docs/fmm.md). Returns the expansion order used.
    fn apply_relaxed(
        &mut self,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        relax: f64,
    ) -> Result<u32, String>;
    /// The expansion order of [`Operator::apply`].
    fn order(&self) -> u32;
    /// What runs it, for reports.
    fn device(&self) -> String;
}

/// The per-splat terms of the equation `L = E + ρ ∘ T (L − Lₑ)`.
///
/// `E = Lₑ + D`: the emitted radiance and the reflected direct light `D` of the point lights
/// and of the emitting splats (shadow rays), and of caustic photons when given. The operator
/// transports only the reflected part `L − Lₑ`: the first bounce off the emitters is already
/// in `D`, resolved per splat by rays rather than by the V-map's node-level fractions. With
/// `D = ρ T Lₑ` exactly, this is `L = Lₑ + ρ T L`.
#[derive(Clone, Debug, Default)]
pub struct System {
    /// Source term E.
    pub source: Vec<[f32; 3]>,
    /// Emitted radiance Lₑ.
    pub emission: Vec<[f32; 3]>,
    /// Diffuse reflectance ρ per splat (zero for specular splats).
    pub albedo: Vec<[f32; 3]>,
}

/// A point light: position (world) and intensity (W/sr per channel).
#[derive(Clone, Copy, Debug)]
pub struct PointLight {
    pub position: Vec3,
    pub intensity: Vec3,
}

/// Build the system: albedo from the materials, E from emission and point lights.
///
/// `light_lists[l]` is the V-map's list of light `l`: `(slot, fraction)` for each V-map leaf
/// that sees the light; `ranges[slot]` its splat range. A splat outside every listed node is in
/// shadow; one in a node seen whole is lit; one in a partly seen node casts its own shadow ray
/// (from its centre, ignoring hits within `self_hit` radii).
#[allow(clippy::too_many_arguments)]
pub fn system(
    view: &OctreeView,
    materials: &[MaterialRecord],
    pts: &Points,
    lights: &[PointLight],
    light_lists: &[&[Link]],
    ranges: &dyn Fn(u32) -> (u32, u32),
    self_hit: f32,
    tester: &dyn Caster,
) -> Result<System, String> {
    let n = view.splats.len();
    let mut sys = System {
        source: vec![[0.0; 3]; n],
        emission: vec![[0.0; 3]; n],
        albedo: vec![[0.0; 3]; n],
    };
    for (i, s) in view.splats.iter().enumerate() {
        if !pts.active[i] {
            continue;
        }
        let m = &materials[s.material as usize];
        let rho = Vec3::from(m.color) * Vec3::from(s.albedo);
        sys.albedo[i] = rho.into();
        if m.class == class::EMITTER {
            sys.source[i] = m.radiance;
            sys.emission[i] = m.radiance;
        }
    }
    for (l, light) in lights.iter().enumerate() {
        let list = light_lists.get(l).copied().unwrap_or(&[]);
        let mut partial: Vec<u32> = Vec::new();
        let mut lit: Vec<u32> = Vec::new();
        for link in list {
            let (lo, hi) = ranges(link.slot());
            if link.fraction >= 1.0 {
                lit.extend(lo..hi);
            } else if link.fraction > 0.0 {
                partial.extend(lo..hi);
            }
        }
        let mut rays = Vec::with_capacity(partial.len());
        let mut who = Vec::with_capacity(partial.len());
        for &i in &partial {
            let s = &view.splats[i as usize];
            let x = Vec3::from(s.position);
            let d = light.position - x;
            let len = d.length();
            if len <= 0.0 || !pts.active[i as usize] || Vec3::from(s.normal).dot(d) <= 0.0 {
                continue;
            }
            rays.push(Ray {
                origin: x,
                dir: d / len,
                t_min: self_hit * s.radius,
                t_max: len * (1.0 - 1e-4),
            });
            who.push(i);
        }
        let vis = tester.visible(&rays)?;
        lit.extend(who.iter().zip(&vis).filter(|(_, &v)| v).map(|(&i, _)| i));
        for i in lit {
            let iu = i as usize;
            if !pts.active[iu] {
                continue;
            }
            let s = &view.splats[iu];
            let d = light.position - Vec3::from(s.position);
            let r2 = d.length_squared();
            let cos = Vec3::from(s.normal).dot(d) / r2.sqrt();
            if cos <= 0.0 || r2 <= 0.0 {
                continue;
            }
            // Reflected radiance ρ E / π with irradiance E = I cos / r².
            let e = light.intensity * (cos / r2) * std::f32::consts::FRAC_1_PI;
            let add = Vec3::from(sys.albedo[iu]) * e;
            sys.source[iu] = (Vec3::from(sys.source[iu]) + add).into();
        }
    }
    Ok(sys)
}

/// A leaf whose shaft to the emitters holds the leaves of at most this many disks tests its
/// rays against them alone instead of walking the octree; past it the probes decide.
pub const SHAFT_CANDIDATES: usize = 65536;

/// Leaves under one octree node of at most this many splats first try one shaft together
/// ([`emitter_direct`]).
pub const SHAFT_FAMILY: u32 = 256;

/// How [`emitter_direct`] samples the emitters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmitterSampling {
    /// Stratified samples per receiving splat.
    pub samples: u32,
    /// Samples per splat that probe visibility first (0: every sample casts its ray).
    pub probes: u32,
    /// Shadow rays ignore hits within this many radii of either end.
    pub self_hit: f32,
    /// Settle leaves whose shaft to the emitters is empty without rays ([`crate::shaft`]).
    pub shafts: bool,
}

/// What [`emitter_direct`] did: shadow rays cast, samples taken, and samples settled by shaft
/// culling without a ray.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EmitterRays {
    pub cast: u64,
    pub samples: u64,
    pub settled: u64,
}

/// Reflected direct light of the emitting splats, `D_i = ρ_i/π ∫ Lₑ cos θ_i cos θ_j / r² V dA`,
/// by `samples` stratified samples per receiving splat of the emitting splats, drawn in
/// proportion to their area (over the area CDF). Near pairs use the disk form factor
/// (docs/fmm.md). Added to `sys.source`.
///
/// Visibility (docs/fmm.md, "Direct light of the emitters"): first, an octree leaf whose shaft
/// to the emitters no splat's disk enters sees them from every sample, without a ray
/// ([`crate::shaft`], exact). Elsewhere it is tested adaptively: `probes` of
/// the samples, spread over the strata (and offset by receiver, so that a leaf's receivers
/// together probe every stratum), cast their shadow rays first; in an octree leaf where
/// every probe of every receiver agrees (all open, or all blocked) the other samples take that
/// answer, and only leaves where the probes disagree (a shadow edge) cast the rest.
/// `probes` 0 (or at least `samples`) casts every sample the shafts leave.
pub fn emitter_direct(
    view: &OctreeView,
    pts: &Points,
    sys: &mut System,
    how: EmitterSampling,
    tester: &dyn Caster,
) -> Result<EmitterRays, String> {
    let EmitterSampling {
        samples,
        probes,
        self_hit,
        shafts,
    } = how;
    use rayon::prelude::*;
    let emitters: Vec<u32> = (0..view.splats.len() as u32)
        .filter(|&j| sys.emission[j as usize] != [0.0; 3] && pts.active[j as usize])
        .collect();
    if emitters.is_empty() || samples == 0 {
        return Ok(EmitterRays::default());
    }
    let mut cdf = Vec::with_capacity(emitters.len());
    let mut total = 0.0f64;
    for &j in &emitters {
        total += view.splat_area[j as usize] as f64;
        cdf.push(total);
    }
    // Every `every`-th sample is a probe (all of them without probing).
    let every = if probes == 0 || probes >= samples {
        1
    } else {
        samples / probes
    };
    // Receivers grouped by the leaf that owns them (a leaf's splats are contiguous).
    let receivers: Vec<u32> = (0..view.splats.len() as u32)
        .filter(|&i| pts.active[i as usize] && sys.albedo[i as usize] != [0.0; 3])
        .collect();
    let mut groups: Vec<&[u32]> = Vec::new();
    let mut start = 0;
    for k in 1..=receivers.len() {
        if k == receivers.len()
            || pts.leaf[receivers[k] as usize] != pts.leaf[receivers[start] as usize]
        {
            groups.push(&receivers[start..k]);
            start = k;
        }
    }
    let (mut cast, mut taken, mut settled) = (0u64, 0u64, 0u64);
    // Shaft culling: the emitters' box and their smallest radius.
    let disks = DiskBoxes::new(view);
    let disk_lanes = lanes::DiskLanes::new(view.splats);
    let mut emitter_box = Aabb::EMPTY;
    let mut emitter_r_min = f32::INFINITY;
    for &j in &emitters {
        let sj = &view.splats[j as usize];
        emitter_box.grow(sj.position.into());
        emitter_r_min = emitter_r_min.min(sj.radius);
    }
    // Eight slices per emitter: the scan after the guide is nearly always empty (a branch that
    // is predicted).
    let slices = 8 * emitters.len().max(1);
    let sampler = Sampler {
        view,
        emitters: &emitters,
        points: emitters
            .iter()
            .map(|&j| {
                let sj = &view.splats[j as usize];
                EmitterPoint {
                    position: sj.position.into(),
                    normal: sj.normal.into(),
                    area: view.splat_area[j as usize],
                    radius: sj.radius,
                }
            })
            .collect(),
        cdf: &cdf,
        guide: guide(&cdf, total, slices),
        total,
        samples,
        every,
        self_hit,
    };
    // The light a receiver takes from its samples, given their visibility.
    let gather = |smp: &[Sample], seen: &mut dyn FnMut(usize) -> bool| -> Vec3 {
        let mut e = Vec3::ZERO;
        for (k, &(_, j, w, _)) in smp.iter().enumerate() {
            if seen(k) {
                e += Vec3::from(sys.emission[j as usize]) * w;
            }
        }
        e
    };
    let end = self_hit * emitter_r_min;
    // A leaf's receivers: the box of their centres, their smallest radius, and whether any
    // faces some point of the emitters' box.
    let leaf_box = |group: &[u32]| -> (Aabb, f32, bool) {
        let mut a = Aabb::EMPTY;
        let mut r_min = f32::INFINITY;
        let mut faces = false;
        for &i in group {
            let si = &view.splats[i as usize];
            let (x, n) = (Vec3::from(si.position), Vec3::from(si.normal));
            a.grow(x);
            r_min = r_min.min(si.radius);
            // Some point of the emitters' box in front of the receiver?
            let c = (emitter_box.min + emitter_box.max) * 0.5;
            let h = (emitter_box.max - emitter_box.min) * 0.5;
            // (With a rounding margin: a sample's own cosine test decides.)
            let slack = 1e-5 * (n.abs().dot(h) + (c - x).length());
            faces |= n.dot(c - x) + n.abs().dot(h) > -slack;
        }
        (a, r_min, faces)
    };
    // A culled leaf's light: the samples summed as they are drawn, each ray tested against the
    // disks of the shaft's leaves (`open`: none, all open).
    let culled_light = |group: &[u32], open: bool, leaf_lanes: &lanes::LeafLanes| -> LeafLight {
        let mut samples = 0;
        let light = group
            .iter()
            .map(|&i| {
                let mut e = Vec3::ZERO;
                sampler.each(i, |(ray, j, w, _)| {
                    samples += 1;
                    if open || !lanes::blocked(leaf_lanes, &disk_lanes, &ray) {
                        e += Vec3::from(sys.emission[j as usize]) * w;
                    }
                });
                (i, e)
            })
            .collect();
        LeafLight::Done { light, samples }
    };
    // Leaves in families: those under the highest octree nodes of at most `SHAFT_FAMILY`
    // splats. A family's leaves first share one shaft (of their boxes together): when it
    // holds few enough disks, one descent and one box tree serve them all, where each leaf's
    // own would cost as much (the leaves in a shaft grow with N, the leaves that ask too).
    // Otherwise each leaf takes its own shaft.
    let families = families(&groups, &disks.subtrees(view, SHAFT_FAMILY));
    // Bounded batches of families (the samples of leaves left to the probes are kept).
    let batch = ((1usize << 22) / samples as usize).max(1);
    let family_len =
        |f: &std::ops::Range<usize>| -> usize { groups[f.clone()].iter().map(|g| g.len()).sum() };
    let mut f0 = 0;
    while f0 < families.len() {
        let mut f1 = f0;
        let mut n = 0;
        while f1 < families.len() && (n == 0 || n + family_len(&families[f1]) <= batch) {
            n += family_len(&families[f1]);
            f1 += 1;
        }
        let fams = &families[f0..f1];
        let chunk = &groups[fams[0].start..fams[fams.len() - 1].end];
        f0 = f1;
        // Per leaf: its samples, and shaft culling (every sample of a leaf whose shaft to the
        // emitters no disk enters is open; where disks enter, its rays are tested against
        // them alone). A culled leaf's light is summed at once; the others wait for the
        // probes.
        let per_family: Vec<Vec<LeafLight>> = fams
            .par_iter()
            .map_init(
                || (Vec::new(), Vec::new(), lanes::LeafLanes::default()),
                |(stack, cands, leaf_lanes), fam| {
                    let members = &groups[fam.clone()];
                    let boxes: Vec<(Aabb, f32, bool)> =
                        members.iter().map(|g| leaf_box(g)).collect();
                    let none = || LeafLight::Done {
                        light: Vec::new(),
                        samples: 0,
                    };
                    // The family's shaft, of the leaves that face the emitters.
                    let (mut a, mut r_min) = (Aabb::EMPTY, f32::INFINITY);
                    for &(b, r, faces) in &boxes {
                        if faces {
                            a = a.union(b);
                            r_min = r_min.min(r);
                        }
                    }
                    let shared = shafts
                        && members.len() > 1
                        && Shaft::new(a, emitter_box, self_hit * r_min, end).is_some_and(|shaft| {
                            disks.leaves(view, &shaft, SHAFT_CANDIDATES, stack, cands)
                        });
                    if shared {
                        let open = cands.is_empty();
                        if !open {
                            leaf_lanes.load(cands);
                        }
                        return members
                            .iter()
                            .zip(&boxes)
                            .map(|(g, &(_, _, faces))| {
                                if faces {
                                    culled_light(g, open, leaf_lanes)
                                } else {
                                    none()
                                }
                            })
                            .collect();
                    }
                    members
                        .iter()
                        .zip(&boxes)
                        .map(|(group, &(a, r_min, faces))| {
                            if !faces {
                                // Every sample would face away: none is taken.
                                return none();
                            }
                            let culled = shafts
                                && Shaft::new(a, emitter_box, self_hit * r_min, end).is_some_and(
                                    |shaft| {
                                        disks.leaves(view, &shaft, SHAFT_CANDIDATES, stack, cands)
                                    },
                                );
                            if !culled {
                                let mut smp = Vec::new();
                                let mut ends = Vec::with_capacity(group.len());
                                for &i in group.iter() {
                                    sampler.each(i, |x| smp.push(x));
                                    ends.push(smp.len());
                                }
                                return LeafLight::Pending { smp, ends };
                            }
                            let open = cands.is_empty();
                            if !open {
                                leaf_lanes.load(cands);
                            }
                            culled_light(group, open, leaf_lanes)
                        })
                        .collect()
                },
            )
            .collect();
        let leaves: Vec<LeafLight> = per_family.into_iter().flatten().collect();
        let mut light: Vec<(u32, Vec3)> = Vec::new();
        let mut pending: Vec<(&[u32], &[Sample], &[usize])> = Vec::new();
        for (group, leaf) in chunk.iter().zip(&leaves) {
            match leaf {
                LeafLight::Done { light: l, samples } => {
                    light.extend_from_slice(l);
                    settled += *samples as u64;
                    taken += *samples as u64;
                }
                LeafLight::Pending { smp, ends } => {
                    pending.push((group, smp, ends));
                    taken += smp.len() as u64;
                }
            }
        }
        // Probes for the leaves culling left: their shadow rays first; a leaf whose probes all
        // agree gives the rest their answer, the others cast every ray.
        let probe_rays: Vec<Ray> = pending
            .iter()
            .flat_map(|(_, smp, _)| smp.iter().filter(|s| s.3).map(|s| s.0))
            .collect();
        let probe_vis = tester.visible(&probe_rays)?;
        let mut at = 0;
        let verdicts: Vec<Option<bool>> = pending
            .iter()
            .map(|(_, smp, _)| {
                let n = smp.iter().filter(|s| s.3).count();
                let v = &probe_vis[at..at + n];
                at += n;
                if v.is_empty() {
                    None // no probe faced the light: nothing to go by, cast them all
                } else if v.iter().all(|&x| x) {
                    Some(true)
                } else if v.iter().all(|&x| !x) {
                    Some(false)
                } else {
                    None
                }
            })
            .collect();
        let rest_rays: Vec<Ray> = pending
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| v.is_none())
            .flat_map(|((_, smp, _), _)| smp.iter().filter(|s| !s.3).map(|s| s.0))
            .collect();
        let rest_vis = tester.visible(&rest_rays)?;
        cast += (probe_rays.len() + rest_rays.len()) as u64;
        let (mut pa, mut ra) = (0, 0);
        for ((group, smp, ends), verdict) in pending.iter().zip(&verdicts) {
            let mut start = 0;
            for (&i, &end) in group.iter().zip(ends.iter()) {
                let own = &smp[start..end];
                start = end;
                let e = gather(own, &mut |k| {
                    if own[k].3 {
                        pa += 1;
                        probe_vis[pa - 1]
                    } else if let Some(v) = verdict {
                        *v
                    } else {
                        ra += 1;
                        rest_vis[ra - 1]
                    }
                });
                light.push((i, e));
            }
        }
        for (i, e) in light {
            let iu = i as usize;
            let add = Vec3::from(sys.albedo[iu]) * e;
            sys.source[iu] = (Vec3::from(sys.source[iu]) + add).into();
        }
    }
    Ok(EmitterRays {
        cast,
        samples: taken,
        settled,
    })
}

/// The leaf groups (receivers, in splat order) in families: per subtree range `[lo, hi)` (in
/// splat order, covering every splat), the range of groups whose receivers lie in it; empty
/// ones left out.
fn families(groups: &[&[u32]], subtrees: &[(u32, u32)]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut g = 0;
    for &(_, hi) in subtrees {
        let start = g;
        while g < groups.len() && groups[g][0] < hi {
            g += 1;
        }
        if g > start {
            out.push(start..g);
        }
    }
    // (Subtrees cover every splat: nothing is left; kept whole if not.)
    if g < groups.len() {
        out.push(g..groups.len());
    }
    out
}

/// One emitter sample of a receiver: its shadow ray, the emitter splat, the estimator's weight
/// and whether it is a probe.
type Sample = (Ray, u32, f32, bool);

/// A leaf's direct light: summed (culled), or its samples for the probes.
enum LeafLight {
    Done {
        light: Vec<(u32, Vec3)>,
        samples: usize,
    },
    Pending {
        smp: Vec<Sample>,
        /// Per receiver, the end of its samples.
        ends: Vec<usize>,
    },
}

/// The guide table of a CDF (last value `total`): per slice `b` of `slices` equal slices of
/// the total, the first index whose value reaches the slice's start.
fn guide(cdf: &[f64], total: f64, slices: usize) -> Vec<u32> {
    (0..slices)
        .map(|b| {
            let start = b as f64 / slices as f64 * total;
            cdf.partition_point(|&c| c < start).min(cdf.len() - 1) as u32
        })
        .collect()
}

/// The first index whose CDF value reaches `target` (clamped to the last): the binary search's
/// answer, from the guide table's slice and a short scan.
#[inline]
fn draw(cdf: &[f64], guide: &[u32], total: f64, target: f64) -> usize {
    let (n, g) = (cdf.len(), guide.len());
    let b = ((target / total * g as f64) as usize).min(g - 1);
    let mut e = guide[b] as usize;
    while e > 0 && cdf[e - 1] >= target {
        e -= 1;
    }
    while e < n - 1 && cdf[e] < target {
        e += 1;
    }
    e
}

/// An emitter splat as a sample reads it.
#[derive(Clone, Copy)]
struct EmitterPoint {
    position: Vec3,
    normal: Vec3,
    area: f32,
    radius: f32,
}

/// Stratified samples of the emitters over their area CDF.
struct Sampler<'a> {
    view: &'a OctreeView<'a>,
    emitters: &'a [u32],
    /// What a sample reads of each emitter, in one place (not the whole splat and its area).
    points: Vec<EmitterPoint>,
    cdf: &'a [f64],
    /// Per slice `b` of `guide.len()` equal slices of the total: the first emitter whose CDF
    /// value reaches its start.
    guide: Vec<u32>,
    total: f64,
    samples: u32,
    every: u32,
    self_hit: f32,
}

impl Sampler<'_> {
    #[inline]
    fn draw(&self, target: f64) -> usize {
        draw(self.cdf, &self.guide, self.total, target)
    }

    /// The samples of receiver `i`, each handed to `f`. Samples that face away (or draw `i`
    /// itself) are left out.
    #[inline]
    fn each(&self, i: u32, mut f: impl FnMut(Sample)) {
        let view = self.view;
        let si = &view.splats[i as usize];
        let (xi, ni) = (Vec3::from(si.position), Vec3::from(si.normal));
        let (samples, total) = (self.samples, self.total);
        for k in 0..samples {
            let u = (k as f64 + pc_tree::rng::rand(0x6d1, i, k, 0) as f64) / samples as f64;
            let e = self.draw(u * total);
            let j = self.emitters[e];
            if j == i {
                continue;
            }
            let sj = &self.points[e];
            let d = sj.position - xi;
            let r2 = d.length_squared();
            let len = r2.sqrt();
            if len <= 0.0 {
                continue;
            }
            let (ci, cj) = (ni.dot(d) / len, -sj.normal.dot(d) / len);
            if ci <= 0.0 || cj <= 0.0 {
                continue;
            }
            // Estimator of ∫ ... dA with pdf A_j / A_total per drawn splat.
            let aj = sj.area;
            let w = ci * cj / (std::f32::consts::PI * r2 + aj) * total as f32 / samples as f32;
            let t_min = self.self_hit * si.radius;
            f((
                Ray {
                    origin: xi,
                    dir: d / len,
                    t_min,
                    t_max: (len - self.self_hit * sj.radius).max(t_min),
                },
                j,
                w,
                (k + i).is_multiple_of(self.every),
            ));
        }
    }
}

/// Result of a solve.
#[derive(Clone, Debug, Default)]
pub struct Solution {
    pub radiance: Vec<[f32; 3]>,
    /// Relative residual after each iteration.
    pub residuals: Vec<f64>,
    /// Expansion order of each iteration's product.
    pub orders: Vec<u32>,
    pub converged: bool,
}

impl Solution {
    /// Estimated relative error left: `r λ / (1 − λ)` with `λ` the last residual ratio.
    pub fn error_estimate(&self) -> f64 {
        let n = self.residuals.len();
        if n < 2 {
            return self.residuals.last().copied().unwrap_or(0.0);
        }
        let (a, b) = (self.residuals[n - 2], self.residuals[n - 1]);
        let lambda = (b / a.max(1e-300)).min(0.99);
        b * lambda / (1.0 - lambda)
    }
}

/// Jacobi iteration. `progress(iteration, residual)` is called after each iteration.
pub fn solve(
    op: &mut dyn Operator,
    sys: &System,
    pts: &Points,
    tolerance: f64,
    max_iterations: u32,
    progress: &mut dyn FnMut(u32, f64),
) -> Result<Solution, String> {
    let n = sys.source.len();
    let mut l = sys.source.clone();
    let mut t = vec![[0.0f32; 3]; n];
    let mut reflected = vec![[0.0f32; 3]; n];
    let mut sol = Solution::default();
    for it in 1..=max_iterations {
        for i in 0..n {
            for c in 0..3 {
                reflected[i][c] = l[i][c] - sys.emission.get(i).map_or(0.0, |e| e[c]);
            }
        }
        op.apply(&reflected, &mut t)?;
        sol.orders.push(op.order());
        let (mut dn, mut nn) = (0.0f64, 0.0f64);
        for i in 0..n {
            if !pts.active[i] {
                continue;
            }
            let a = pts.area[i] as f64;
            let mut new = [0.0f32; 3];
            for c in 0..3 {
                new[c] = sys.source[i][c] + sys.albedo[i][c] * t[i][c];
                let d = (new[c] - l[i][c]) as f64;
                let lit = (new[c] - sys.emission.get(i).map_or(0.0, |e| e[c])) as f64;
                dn += a * d * d;
                nn += a * lit * lit;
            }
            l[i] = new;
        }
        let r = if nn > 0.0 { (dn / nn).sqrt() } else { 0.0 };
        sol.residuals.push(r);
        progress(it, r);
        if r < tolerance {
            sol.converged = true;
            break;
        }
    }
    sol.radiance = l;
    Ok(sol)
}

/// Krylov vectors kept before GMRES restarts (each N RGB doubles: 24 MB per million splats).
pub const GMRES_RESTART: usize = 16;

/// Restarted GMRES on the same equation, written for the reflected part `x = L − Lₑ`:
/// `(I − ρ ∘ T) x = E − Lₑ`, one Krylov process per color channel, the three in lockstep so
/// that each step costs one application of `T` (the FMM product) for all three. Inner products
/// are area-weighted over the active splats, so the residual it reports,
/// `‖b − (I − ρT) x‖_A / ‖b‖_A` over RGB, is the norm Jacobi reports (Jacobi's update
/// `L_{k+1} − L_k` is exactly the residual of `L_k`), relative to the source instead of the
/// solution, which is stricter. Radiosity's operator has a spectrum clustered near 0 with a
/// few eigenvalues out to the scene's mean albedo, where Krylov methods converge much faster
/// than Jacobi's fixed rate (docs/fmm.md). `restart` bounds the stored basis (`restart` + 1
/// vectors of N RGB doubles).
///
/// `relaxed`: the product of Arnoldi step k may be `1 / ‖r_{k−1}‖` times less accurate than the
/// configured order's (‖r‖ the largest channel's relative residual so far in the cycle): an
/// error in that product moves the answer by about its size times `‖r_{k−1}‖`, so late products
/// at a lower order add no more error than each full one carries (Bouras & Frayssé 2005,
/// Simoncini & Szyld 2003; docs/fmm.md, "Relaxed products"). A restart's residual is always
/// computed at the full order.
#[allow(clippy::too_many_arguments)]
pub fn solve_gmres(
    op: &mut dyn Operator,
    sys: &System,
    pts: &Points,
    tolerance: f64,
    max_iterations: u32,
    restart: usize,
    relaxed: bool,
    progress: &mut dyn FnMut(u32, f64),
) -> Result<Solution, String> {
    let n = sys.source.len();
    let m = restart.max(1);
    let emit = |i: usize, c: usize| sys.emission.get(i).map_or(0.0, |e| e[c]) as f64;
    let weight: Vec<f64> = (0..n)
        .map(|i| {
            if pts.active[i] {
                pts.area[i] as f64
            } else {
                0.0
            }
        })
        .collect();
    let b: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            if weight[i] == 0.0 {
                return [0.0; 3];
            }
            std::array::from_fn(|c| sys.source[i][c] as f64 - emit(i, c))
        })
        .collect();
    let dot = |u: &[[f64; 3]], v: &[[f64; 3]], c: usize| -> f64 {
        (0..n).map(|i| weight[i] * u[i][c] * v[i][c]).sum()
    };
    // y = (I − ρT) v on the active splats.
    let mut v32 = vec![[0.0f32; 3]; n];
    let mut t = vec![[0.0f32; 3]; n];
    let mut apply = |v: &[[f64; 3]], out: &mut Vec<[f64; 3]>, relax: f64| -> Result<u32, String> {
        for i in 0..n {
            v32[i] = v[i].map(|x| x as f32);
        }
        // (At 1, every operator's configured order.)
        let order = op.apply_relaxed(&v32, &mut t, relax)?;
        out.clear();
        out.extend((0..n).map(|i| {
            if weight[i] == 0.0 {
                [0.0; 3]
            } else {
                std::array::from_fn(|c| v[i][c] - sys.albedo[i][c] as f64 * t[i][c] as f64)
            }
        }));
        Ok(order)
    };
    let b_norm = (0..3).map(|c| dot(&b, &b, c)).sum::<f64>().sqrt();
    let b_channel: [f64; 3] = std::array::from_fn(|c| dot(&b, &b, c).sqrt());
    // x0 = 0, so the first cycle starts from r0 = b without a product; a restart costs one
    // product more (not counted as an iteration: it adds no Krylov vector).
    let mut x = vec![[0.0f64; 3]; n];
    let mut sol = Solution::default();
    let mut w = Vec::with_capacity(n);
    let mut it = 0u32;
    'outer: while it < max_iterations && b_norm > 0.0 {
        let r0: Vec<[f64; 3]> = if it == 0 {
            b.clone()
        } else {
            apply(&x, &mut w, 1.0)?;
            (0..n)
                .map(|i| std::array::from_fn(|c| b[i][c] - w[i][c]))
                .collect()
        };
        let mut basis: Vec<Vec<[f64; 3]>> = Vec::with_capacity(m + 1);
        let beta: [f64; 3] = std::array::from_fn(|c| dot(&r0, &r0, c).sqrt());
        let scale = beta.map(|s| if s > 0.0 { 1.0 / s } else { 0.0 });
        basis.push(
            r0.iter()
                .map(|r| std::array::from_fn(|c| r[c] * scale[c]))
                .collect(),
        );
        // Per channel: Hessenberg columns (rotated), Givens rotations, the rotated rhs g.
        let mut h: Vec<[Vec<f64>; 3]> = vec![std::array::from_fn(|_| vec![0.0f64; m + 1]); m];
        let mut rot = vec![[(1.0f64, 0.0f64); 3]; m];
        let mut g: Vec<[f64; 3]> = vec![[0.0; 3]; m + 1];
        g[0] = beta;
        let mut k = 0;
        while k < m && it < max_iterations {
            // The largest channel's relative residual before this step.
            let r_prev = (0..3)
                .filter(|&c| b_channel[c] > 0.0)
                .map(|c| g[k][c].abs() / b_channel[c])
                .fold(0.0f64, f64::max);
            let relax = if relaxed && r_prev > 0.0 {
                (1.0 / r_prev).max(1.0)
            } else {
                1.0
            };
            sol.orders.push(apply(&basis[k], &mut w, relax)?);
            it += 1;
            for c in 0..3 {
                // Modified Gram-Schmidt.
                for (j, v) in basis.iter().enumerate() {
                    let hj = dot(&w, v, c);
                    h[k][c][j] = hj;
                    for i in 0..n {
                        w[i][c] -= hj * v[i][c];
                    }
                }
                h[k][c][k + 1] = dot(&w, &w, c).sqrt();
            }
            let next: Vec<[f64; 3]> = w
                .iter()
                .map(|x| {
                    std::array::from_fn(|c| {
                        let s = h[k][c][k + 1];
                        if s > 0.0 {
                            x[c] / s
                        } else {
                            0.0
                        }
                    })
                })
                .collect();
            for c in 0..3 {
                let col = &mut h[k][c];
                for (j, r) in rot.iter().enumerate().take(k) {
                    let (cs, sn) = r[c];
                    let (a, bb) = (col[j], col[j + 1]);
                    col[j] = cs * a + sn * bb;
                    col[j + 1] = -sn * a + cs * bb;
                }
                let (a, bb) = (col[k], col[k + 1]);
                let d = a.hypot(bb);
                let (cs, sn) = if d > 0.0 { (a / d, bb / d) } else { (1.0, 0.0) };
                rot[k][c] = (cs, sn);
                col[k] = d;
                col[k + 1] = 0.0;
                g[k + 1][c] = -sn * g[k][c];
                g[k][c] *= cs;
            }
            basis.push(next);
            k += 1;
            let r = (0..3).map(|c| g[k][c] * g[k][c]).sum::<f64>().sqrt() / b_norm;
            sol.residuals.push(r);
            progress(it, r);
            if r < tolerance {
                sol.converged = true;
            }
            if sol.converged || it == max_iterations {
                update(&mut x, &basis, &h, &g, k);
                break 'outer;
            }
        }
        update(&mut x, &basis, &h, &g, k);
    }
    if b_norm == 0.0 {
        sol.converged = true;
    }
    sol.radiance = (0..n)
        .map(|i| {
            if weight[i] == 0.0 {
                sys.source[i]
            } else {
                std::array::from_fn(|c| (x[i][c] + emit(i, c)) as f32)
            }
        })
        .collect();
    Ok(sol)
}

/// `x += V y` with `y` solving the `k`×`k` upper triangular system `H y = g`, per channel.
fn update(
    x: &mut [[f64; 3]],
    basis: &[Vec<[f64; 3]>],
    h: &[[Vec<f64>; 3]],
    g: &[[f64; 3]],
    k: usize,
) {
    for c in 0..3 {
        let mut y = vec![0.0f64; k];
        for j in (0..k).rev() {
            let mut s = g[j][c];
            for l in j + 1..k {
                s -= h[l][c][j] * y[l];
            }
            y[j] = if h[j][c][j] != 0.0 {
                s / h[j][c][j]
            } else {
                0.0
            };
        }
        for (j, yj) in y.iter().enumerate() {
            for (xi, v) in x.iter_mut().zip(&basis[j]) {
                xi[c] += yj * v[c];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn families_gather_the_leaves_of_each_subtree_in_order() {
        // Receivers of five leaves (splats 0..40), subtrees [0, 16), [16, 24), [24, 40).
        let leaves: Vec<Vec<u32>> = vec![
            vec![0, 3, 7],
            vec![9, 12],
            vec![17],
            vec![25, 26],
            vec![33, 39],
        ];
        let groups: Vec<&[u32]> = leaves.iter().map(|v| v.as_slice()).collect();
        let f = families(&groups, &[(0, 16), (16, 24), (24, 40)]);
        assert_eq!(f, vec![0..2, 2..3, 3..5]);
        // A subtree without receivers is left out; receivers past the last subtree (none
        // should be) stay together rather than being lost.
        let f = families(&groups, &[(0, 8), (8, 16), (16, 20), (20, 24)]);
        assert_eq!(f, vec![0..1, 1..2, 2..3, 3..5]);
        assert!(families(&[], &[(0, 8)]).is_empty());
    }

    #[test]
    fn the_guide_table_draws_what_the_binary_search_draws() {
        // Uneven areas, some zero, so that slices hold none or many emitters.
        let areas: Vec<f64> = (0..97)
            .map(|i| {
                if i % 7 == 3 {
                    0.0
                } else {
                    1.0 + (i * 37 % 11) as f64
                }
            })
            .collect();
        let mut cdf = Vec::new();
        let mut total = 0.0;
        for a in &areas {
            total += a;
            cdf.push(total);
        }
        let g = guide(&cdf, total, areas.len());
        for k in 0..=10_000u32 {
            let target = k as f64 / 10_000.0 * total;
            let want = cdf.partition_point(|&c| c < target).min(cdf.len() - 1);
            assert_eq!(draw(&cdf, &g, total, target), want, "target {target}");
        }
        // Exactly on every CDF value.
        for &c in &cdf {
            let want = cdf.partition_point(|&x| x < c).min(cdf.len() - 1);
            assert_eq!(draw(&cdf, &g, total, c), want);
        }
    }
}
