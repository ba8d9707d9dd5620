//! The emitting splats' direct light, `D_i = ρ_i/π ∫ Lₑ cos θ_i cos θ_j / r² V dA`, added to the
//! system's source term: stratified samples of the emitters per receiving splat, visibility by
//! exact shaft culling where a shaft to the emitters holds few disks, else by probes and shadow
//! rays (docs/fmm.md, "Direct light of the emitters").

use std::ops::Range;

use glam::Vec3;
use pc_gpu::GpuError;
use pc_tree::caster::Caster;
use pc_tree::{OctreeView, Ray};

use crate::lanes;
use crate::system::System;
use crate::tree::Points;
use pc_tree::shaft::{Aabb, DiskBoxes, Shaft, Slab};

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
    /// Settle leaves whose shaft to the emitters is empty without rays ([`pc_tree::shaft`]).
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
/// ([`pc_tree::shaft`], exact). Elsewhere it is tested adaptively: `probes` of
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
) -> Result<EmitterRays, GpuError> {
    let Some(pass) = Pass::new(view, pts, &sys.emission, how) else {
        return Ok(EmitterRays::default());
    };
    let receivers: Vec<u32> = (0..view.splats.len() as u32)
        .filter(|&i| pts.active[i as usize] && sys.albedo[i as usize] != [0.0; 3])
        .collect();
    let groups = leaf_groups(&receivers, &pts.leaf);
    let mut counts = EmitterRays::default();
    let mut light: Vec<(u32, Vec3)> = Vec::new();
    // Leaves in families: those under the highest octree nodes of at most `SHAFT_FAMILY`
    // splats. A family's leaves first share one shaft (of their boxes together): when it
    // holds few enough disks, one descent and one box tree serve them all, where each leaf's
    // own would cost as much (the leaves in a shaft grow with N, the leaves that ask too).
    // Otherwise each leaf takes its own shaft.
    let families = families(&groups, &pass.disks.subtrees(view, SHAFT_FAMILY));
    for fams in batches(&families, &groups, how.samples) {
        light.clear();
        pass.batch(&groups, fams, tester, &mut counts, &mut light)?;
        for &(i, e) in &light {
            let iu = i as usize;
            let add = Vec3::from(sys.albedo[iu]) * e;
            sys.source[iu] = (Vec3::from(sys.source[iu]) + add).into();
        }
    }
    Ok(counts)
}

/// Consecutive families in bounded batches: at most about 4M samples in flight (a batch keeps
/// the samples of the leaves left to the probes), at least one family each.
fn batches<'f>(
    families: &'f [Range<usize>],
    groups: &[&[u32]],
    samples: u32,
) -> Vec<&'f [Range<usize>]> {
    let batch = ((1usize << 22) / samples as usize).max(1);
    let family_len =
        |f: &Range<usize>| -> usize { groups[f.clone()].iter().map(|g| g.len()).sum() };
    let mut out = Vec::new();
    let mut f0 = 0;
    while f0 < families.len() {
        let mut f1 = f0;
        let mut n = 0;
        while f1 < families.len() && (n == 0 || n + family_len(&families[f1]) <= batch) {
            n += family_len(&families[f1]);
            f1 += 1;
        }
        out.push(&families[f0..f1]);
        f0 = f1;
    }
    out
}

/// Everything one computation of the emitters' direct light reads: the sampler, the disks'
/// boxes for shaft culling and the emitters' own box.
struct Pass<'a> {
    view: &'a OctreeView<'a>,
    /// The emitted radiance per splat (the system's).
    emission: &'a [[f32; 3]],
    sampler: Sampler<'a>,
    disks: DiskBoxes,
    disk_lanes: lanes::DiskLanes,
    /// The box of the emitters' centres.
    emitter_box: Aabb,
    /// A shadow ray's end margin at the emitters: `self_hit` of their smallest radius.
    end: f32,
    self_hit: f32,
    shafts: bool,
}

/// What the workers of one family reuse from leaf to leaf.
#[derive(Default)]
struct Scratch {
    stack: Vec<u32>,
    cands: Vec<((u32, u32), Aabb, Slab)>,
    leaf_lanes: lanes::LeafLanes,
}

impl<'a> Pass<'a> {
    /// The pass for `sys`'s emitters, `None` when there is nothing to sample.
    fn new(
        view: &'a OctreeView<'a>,
        pts: &Points,
        emission: &'a [[f32; 3]],
        how: EmitterSampling,
    ) -> Option<Pass<'a>> {
        let EmitterSampling {
            samples,
            probes,
            self_hit,
            shafts,
        } = how;
        let emitters: Vec<u32> = (0..view.splats.len() as u32)
            .filter(|&j| emission[j as usize] != [0.0; 3] && pts.active[j as usize])
            .collect();
        if emitters.is_empty() || samples == 0 {
            return None;
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
        // Shaft culling: the emitters' box and their smallest radius.
        let mut emitter_box = Aabb::EMPTY;
        let mut emitter_r_min = f32::INFINITY;
        for &j in &emitters {
            let sj = &view.splats[j as usize];
            emitter_box.grow(sj.position.into());
            emitter_r_min = emitter_r_min.min(sj.radius);
        }
        // Eight slices per emitter: the scan after the guide is nearly always empty (a branch
        // that is predicted).
        let slices = 8 * emitters.len().max(1);
        let guide = guide(&cdf, total, slices);
        let points = emitters
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
            .collect();
        Some(Pass {
            view,
            emission,
            sampler: Sampler {
                view,
                emitters,
                points,
                cdf,
                guide,
                total,
                samples,
                every,
                self_hit,
            },
            disks: DiskBoxes::new(view),
            disk_lanes: lanes::DiskLanes::new(view.splats),
            emitter_box,
            end: self_hit * emitter_r_min,
            self_hit,
            shafts,
        })
    }

    /// A leaf's receivers: the box of their centres, their smallest radius, and whether any
    /// faces some point of the emitters' box.
    fn leaf_box(&self, group: &[u32]) -> (Aabb, f32, bool) {
        let eb = &self.emitter_box;
        let mut a = Aabb::EMPTY;
        let mut r_min = f32::INFINITY;
        let mut faces = false;
        for &i in group {
            let si = &self.view.splats[i as usize];
            let (x, n) = (Vec3::from(si.position), Vec3::from(si.normal));
            a.grow(x);
            r_min = r_min.min(si.radius);
            // Some point of the emitters' box in front of the receiver?
            let c = (eb.min + eb.max) * 0.5;
            let h = (eb.max - eb.min) * 0.5;
            // (With a rounding margin: a sample's own cosine test decides.)
            let slack = 1e-5 * (n.abs().dot(h) + (c - x).length());
            faces |= n.dot(c - x) + n.abs().dot(h) > -slack;
        }
        (a, r_min, faces)
    }

    /// The shaft from a box of receivers (smallest radius `r_min`) to the emitters, if it holds
    /// few enough disks: their leaves are left in `s.cands`.
    fn shaft_holds_few(&self, a: Aabb, r_min: f32, s: &mut Scratch) -> bool {
        self.shafts
            && Shaft::new(a, self.emitter_box, self.self_hit * r_min, self.end).is_some_and(
                |shaft| {
                    self.disks.leaves(
                        self.view,
                        &shaft,
                        SHAFT_CANDIDATES,
                        &mut s.stack,
                        &mut s.cands,
                    )
                },
            )
    }

    /// A culled leaf's light: the samples summed as they are drawn, each ray tested against the
    /// disks of the shaft's leaves (`open`: none, all open).
    fn culled_light(&self, group: &[u32], open: bool, leaf_lanes: &lanes::LeafLanes) -> LeafLight {
        let mut samples = 0;
        let light = group
            .iter()
            .map(|&i| {
                let mut e = Vec3::ZERO;
                self.sampler.each(i, |(ray, j, w, _)| {
                    samples += 1;
                    if open || !lanes::blocked(leaf_lanes, &self.disk_lanes, &ray) {
                        e += Vec3::from(self.emission[j as usize]) * w;
                    }
                });
                (i, e)
            })
            .collect();
        LeafLight::Done { light, samples }
    }

    /// The light of a family's leaves: shaft culling (every sample of a leaf whose shaft to the
    /// emitters no disk enters is open; where disks enter, its rays are tested against them
    /// alone), first with one shaft for the whole family. A culled leaf's light is summed at
    /// once; the others keep their samples for the probes.
    fn family(&self, members: &[&[u32]], s: &mut Scratch) -> Vec<LeafLight> {
        let boxes: Vec<(Aabb, f32, bool)> = members.iter().map(|g| self.leaf_box(g)).collect();
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
        if members.len() > 1 && self.shaft_holds_few(a, r_min, s) {
            let open = s.cands.is_empty();
            if !open {
                s.leaf_lanes.load(&s.cands);
            }
            return members
                .iter()
                .zip(&boxes)
                .map(|(g, &(_, _, faces))| {
                    if faces {
                        self.culled_light(g, open, &s.leaf_lanes)
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
                if !self.shaft_holds_few(a, r_min, s) {
                    let mut smp = Vec::new();
                    let mut ends = Vec::with_capacity(group.len());
                    for &i in group.iter() {
                        self.sampler.each(i, |x| smp.push(x));
                        ends.push(smp.len());
                    }
                    return LeafLight::Pending { smp, ends };
                }
                let open = s.cands.is_empty();
                if !open {
                    s.leaf_lanes.load(&s.cands);
                }
                self.culled_light(group, open, &s.leaf_lanes)
            })
            .collect()
    }

    /// The light of one batch of families' leaves, `(receiver, irradiance × π / ρ)` pairs into
    /// `light`, counting samples and rays into `counts`.
    fn batch(
        &self,
        groups: &[&[u32]],
        fams: &[Range<usize>],
        tester: &dyn Caster,
        counts: &mut EmitterRays,
        light: &mut Vec<(u32, Vec3)>,
    ) -> Result<(), GpuError> {
        use rayon::prelude::*;
        let chunk = &groups[fams[0].start..fams[fams.len() - 1].end];
        let per_family: Vec<Vec<LeafLight>> = fams
            .par_iter()
            .map_init(Scratch::default, |s, fam| {
                self.family(&groups[fam.clone()], s)
            })
            .collect();
        let leaves: Vec<LeafLight> = per_family.into_iter().flatten().collect();
        let mut pending: Vec<(&[u32], &[Sample], &[usize])> = Vec::new();
        for (group, leaf) in chunk.iter().zip(&leaves) {
            match leaf {
                LeafLight::Done { light: l, samples } => {
                    light.extend_from_slice(l);
                    counts.settled += *samples as u64;
                    counts.samples += *samples as u64;
                }
                LeafLight::Pending { smp, ends } => {
                    pending.push((group, smp, ends));
                    counts.samples += smp.len() as u64;
                }
            }
        }
        self.probe(&pending, tester, counts, light)
    }

    /// The leaves culling left: the probes' shadow rays first; a leaf whose probes all agree
    /// gives the rest their answer, the others cast every ray.
    fn probe(
        &self,
        pending: &[(&[u32], &[Sample], &[usize])],
        tester: &dyn Caster,
        counts: &mut EmitterRays,
        light: &mut Vec<(u32, Vec3)>,
    ) -> Result<(), GpuError> {
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
        counts.cast += (probe_rays.len() + rest_rays.len()) as u64;
        let (mut pa, mut ra) = (0, 0);
        for ((group, smp, ends), verdict) in pending.iter().zip(&verdicts) {
            let mut start = 0;
            for (&i, &end) in group.iter().zip(ends.iter()) {
                let own = &smp[start..end];
                start = end;
                let e = self.gather(own, &mut |k| {
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
        Ok(())
    }

    /// The light a receiver takes from its samples, given their visibility.
    fn gather(&self, smp: &[Sample], seen: &mut dyn FnMut(usize) -> bool) -> Vec3 {
        let mut e = Vec3::ZERO;
        for (k, &(_, j, w, _)) in smp.iter().enumerate() {
            if seen(k) {
                e += Vec3::from(self.emission[j as usize]) * w;
            }
        }
        e
    }
}

/// The receivers grouped by the leaf that owns them (`leaf` per splat; a leaf's splats are
/// contiguous).
fn leaf_groups<'r>(receivers: &'r [u32], leaf: &[u32]) -> Vec<&'r [u32]> {
    let mut groups: Vec<&[u32]> = Vec::new();
    let mut start = 0;
    for k in 1..=receivers.len() {
        if k == receivers.len() || leaf[receivers[k] as usize] != leaf[receivers[start] as usize] {
            groups.push(&receivers[start..k]);
            start = k;
        }
    }
    groups
}
/// The leaf groups (receivers, in splat order) in families: per subtree range `[lo, hi)` (in
/// splat order, covering every splat), the range of groups whose receivers lie in it; empty
/// ones left out.
fn families(groups: &[&[u32]], subtrees: &[(u32, u32)]) -> Vec<Range<usize>> {
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
    emitters: Vec<u32>,
    /// What a sample reads of each emitter, in one place (not the whole splat and its area).
    points: Vec<EmitterPoint>,
    cdf: Vec<f64>,
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
        draw(&self.cdf, &self.guide, self.total, target)
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
