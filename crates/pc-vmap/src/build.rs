//! The V-map build (seed §7.2, §7.3 phases 2 and 3): a dual traversal of the octree that finds,
//! for every pair of nodes, the coarsest level at which they see each other, with the visible
//! fraction; and the nodes each point light sees. See docs/vmap.md.
//!
//! The traversal is level-synchronous: every round classifies a frontier of node pairs in
//! parallel, casts all the visibility rays the round needs in one batch (CPU or GPU, the same
//! rays), then turns each pair into a link, nothing, or finer pairs for the next round.

use glam::Vec3;
use pc_artifact::octree::node;
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::Link;
use pc_tree::rng::{pcg, rand};
use pc_tree::shaft::{Aabb, DiskBoxes, Shaft};
use pc_tree::{Between, OctreeView, Ray};
use rayon::prelude::*;

// The casters live in pc-tree, shared with pc-fmm's shadow rays; re-exported here, where the
// V-map's callers have always found them.
use pc_gpu::GpuError;
pub use pc_tree::caster::{Caster, CpuCaster, GpuCaster};

use crate::smear::Smear;

/// What the V-map needs per node-pool slot.
#[derive(Clone, Copy, Debug, Default)]
pub struct VNode {
    /// Own splats of the subtree, `[lo, hi)` in the data pool.
    pub lo: u32,
    pub hi: u32,
    pub center: Vec3,
    pub radius: f32,
    pub axis: Vec3,
    /// Cosine of the normal cone's half-angle; -1 when the normals span every direction.
    pub cone_cos: f32,
    /// No pair goes below a V-map leaf.
    pub vleaf: bool,
    /// The summed areas of its splats (in data-pool order, as f64).
    pub area: f64,
    /// For an octree leaf, its roughness (`pc_tree::between::leaf_roughness`), which sets its
    /// splats' own zones; zero elsewhere.
    pub rough: f32,
}

impl VNode {
    pub fn count(&self) -> u32 {
        self.hi - self.lo
    }
}

/// Subtree ranges, normal cones ([`pc_tree::nodes`]) and V-map leaves of every node-pool slot.
pub fn vnodes(view: &OctreeView, leaf_splats: u32) -> Vec<VNode> {
    let ranges = pc_tree::nodes::subtree_ranges(view);
    let cones = pc_tree::nodes::normal_cones(view, &ranges);
    let rough = pc_tree::between::leaf_roughness(view);
    ranges
        .par_iter()
        .zip(&cones)
        .zip(&rough)
        .enumerate()
        .map(|(slot, ((&[lo, hi], &cone_cos), &rough))| {
            if lo >= hi {
                return VNode {
                    cone_cos: -1.0,
                    ..Default::default()
                };
            }
            let info = &view.node_info[slot];
            VNode {
                lo,
                hi,
                center: Vec3::from(info.centroid),
                radius: info.disk_radius,
                axis: Vec3::from(info.normal),
                cone_cos,
                // A V-map leaf's fraction applies to all its splats alike: never mix classes (a
                // light and the ceiling just behind it are not equally visible).
                vleaf: node::is_leaf(view.nodes[slot])
                    || (hi - lo <= leaf_splats && info.class != pc_artifact::octree::class::MIXED),
                area: view.splat_area[lo as usize..hi as usize]
                    .iter()
                    .map(|&a| a as f64)
                    .sum(),
                rough,
            }
        })
        .collect()
}

/// The roughness of the octree leaf that owns splat `i` (its own zone's tolerance).
pub(crate) fn end_rough(view: &OctreeView, vn: &[VNode], i: u32) -> f32 {
    vn[view.splat_leaf[i as usize] as usize].rough
}

/// Non-empty children of an internal node.
pub fn children<'v>(
    view: &OctreeView,
    vn: &'v [VNode],
    slot: u32,
) -> impl Iterator<Item = u32> + 'v {
    let w = view.nodes[slot as usize];
    let first = if node::is_leaf(w) || node::is_empty(w) {
        0
    } else {
        node::ptr(w)
    };
    let count = if first == 0 { 0 } else { 8 };
    (first..first + count).filter(move |&c| vn[c as usize].count() > 0)
}

/// Whether some normal of `a`'s cone can face a direction within `spread` of `dir`.
#[inline]
fn faces(a: &VNode, dir: Vec3, spread: f32) -> bool {
    if a.cone_cos <= -1.0 {
        return true;
    }
    let angle = a.axis.dot(dir).clamp(-1.0, 1.0).acos();
    angle < std::f32::consts::FRAC_PI_2 + a.cone_cos.clamp(-1.0, 1.0).acos() + spread + 1e-4
}

/// Conservative normal-cone test: can any splat of `a` face any splat of `b` and vice versa?
pub fn may_face(a: &VNode, b: &VNode) -> bool {
    let d = b.center - a.center;
    let dist = d.length();
    if dist <= 1e-12 {
        return true;
    }
    let dir = d / dist;
    let spread = ((a.radius + b.radius) / dist).min(1.0).asin();
    faces(a, dir, spread) && faces(b, -dir, spread)
}

/// Opening criterion of the FMM: (R_a + R_b) / distance < theta.
#[inline]
pub fn well_separated(a: &VNode, b: &VNode, theta: f32) -> bool {
    (a.radius + b.radius) < theta * (b.center - a.center).length()
}

/// A sample point on a node's splats: the centre of a splat drawn from the k-th of m strata
/// along the node's Morton-ordered range (spatially stratified). Centres, not random points on
/// the disks: a disk's rim can overhang the surface (past a wall's edge, behind the floor at a
/// corner), where rays would be blocked by the neighbouring surface's own overhang. Returns
/// (data-pool index, point, normal, radius).
pub(crate) fn sample(
    view: &OctreeView,
    v: &VNode,
    seed: u32,
    stream: u32,
    k: u32,
    m: u32,
) -> (u32, Vec3, Vec3, f32) {
    let i = sample_index(v, seed, stream, k, m);
    let s = &view.splats[i as usize];
    (i, Vec3::from(s.position), Vec3::from(s.normal), s.radius)
}

/// The data-pool index of [`sample`]: no memory is read.
#[inline]
fn sample_index(v: &VNode, seed: u32, stream: u32, k: u32, m: u32) -> u32 {
    let count = v.count();
    let u0 = rand(seed, stream, k, 0);
    // m = 1: uniform over the whole range (k only picks the random number).
    let (k, m) = if m == 1 { (0, 1) } else { (k, m) };
    v.lo + (((k as f32 + u0) / m as f32 * count as f32) as u32).min(count - 1)
}

/// The data-pool indices of a pair's `n` sample pairs ([`pair_rays`]): the near end stratified
/// along a's range, the far end uniform over b's (the two ends must be independent, or a node
/// paired with itself would pair each splat with itself). With AVX2 where the CPU has it: the
/// hashes' 32-bit multiplies and variable shifts then run eight lanes at a time (x86-64's
/// baseline has neither packed; one sample at a time they were 5 % of pc-vmap's samples on the
/// 1M bench box, 2 % so). The same indices either way ([`sample_pairs_portable`]).
fn sample_pairs(v: (&VNode, &VNode), seed: u32, stream: u32, n: u32) -> Vec<(u32, u32)> {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn avx2(v: (&VNode, &VNode), seed: u32, stream: u32, n: u32) -> Vec<(u32, u32)> {
            sample_pairs_portable(v, seed, stream, n)
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { avx2(v, seed, stream, n) };
        }
    }
    sample_pairs_portable(v, seed, stream, n)
}

/// [`sample_pairs`] for any CPU: a plain loop over a filled vector, so that it compiles into the
/// AVX2 caller (an iterator's collect would be a function of its own, built without AVX2).
#[inline(always)]
fn sample_pairs_portable(
    (va, vb): (&VNode, &VNode),
    seed: u32,
    stream: u32,
    n: u32,
) -> Vec<(u32, u32)> {
    let mut out = vec![(0u32, 0u32); n as usize];
    for k in 0..n {
        let i = sample_index(va, seed, stream, k, n);
        out[k as usize] = (i, sample_index(vb, seed ^ 0x9e37_79b9, stream, k, 1));
    }
    out
}

/// The visibility rays between two nodes, each with the weight of its sample pair in the
/// form-factor sum, w = A_a A_b cos θa cos θb / r²: the fraction of a link is then the visible
/// share of the pair's form factor, which is what the FMM multiplies it with. (A plain share of
/// rays would do far apart, where the kernel is nearly constant, but not for near-field pairs,
/// whose closest splats dominate the sum.) Only sample pairs whose front sides face each other
/// carry light (one-sided surfaces), and only those are cast. Returns how many sample pairs were
/// drawn (the cast ones and the skipped ones).
fn pair_rays(
    view: &OctreeView,
    vn: &[VNode],
    (a, b): (u32, u32),
    near: bool,
    far_rays: u32,
    p: &VmapParams,
    out: &mut Vec<Sample>,
) -> u32 {
    let stream = pcg(a ^ pcg(b));
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    // Near-field pairs: every splat pair when there are at most `near_rays` of them (the kernel
    // is nearly singular there and a few samples would dominate the sum), else that many samples.
    let all = near && (va.count() as u64 * vb.count() as u64) <= p.near_rays as u64;
    let n = if all {
        va.count() * vb.count()
    } else if near {
        p.near_rays
    } else {
        far_rays
    };
    // Sampled pairs: every index first, and a read of each splat and its area, so the cache
    // misses of a pair's scattered samples overlap instead of following one another.
    let sampled: Vec<(u32, u32)> = match all {
        true => Vec::new(),
        false => sample_pairs((va, vb), p.seed, stream, n),
    };
    for &(i, j) in &sampled {
        let (i, j) = (i as usize, j as usize);
        std::hint::black_box((view.splats[i].radius, view.splats[j].radius));
        std::hint::black_box((view.splat_area[i], view.splat_area[j]));
    }
    for k in 0..n {
        let (ia, ib) = match all {
            true => (va.lo + k / vb.count(), vb.lo + k % vb.count()),
            false => sampled[k as usize],
        };
        let (si, sj) = (&view.splats[ia as usize], &view.splats[ib as usize]);
        let (xa, na, ra) = (Vec3::from(si.position), Vec3::from(si.normal), si.radius);
        let (xb, nb, rb) = (Vec3::from(sj.position), Vec3::from(sj.normal), sj.radius);
        if ia == ib {
            continue;
        }
        let d = xb - xa;
        let len = d.length();
        if len <= 1e-9 {
            continue;
        }
        let dir = d / len;
        let (ca, cb) = (na.dot(dir), nb.dot(-dir));
        if ca <= 0.0 || cb <= 0.0 {
            continue;
        }
        // Splats closer than their two self-hit distances see each other (nothing fits
        // between): an empty interval, which every caster reports visible. These are the
        // heaviest pairs of a near-field sum, so they must stay in it.
        let t_min = p.self_hit * ra;
        let t_max = (len - p.self_hit * rb).max(t_min);
        let w = view.splat_area[ia as usize] * view.splat_area[ib as usize] * ca * cb / (len * len);
        out.push(Sample {
            ray: Between::splats(
                (si, end_rough(view, vn, ia)),
                (sj, end_rough(view, vn, ib)),
                dir,
                len,
                t_min,
                t_max,
            ),
            weight: w,
            ends: [ia, ib],
        });
    }
    n
}

/// One sample pair of two nodes: the ray between the two splat centres, the pair's weight in
/// the form-factor sum, and the two splats (data-pool indices).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    pub ray: Between,
    pub weight: f32,
    pub ends: [u32; 2],
}

/// Rays per batch handed to a caster (bounds the memory of a round).
pub(crate) const RAYS_PER_BATCH: u64 = 1 << 22;

/// Rays `pair_rays` makes for a pair (an upper bound: back-facing samples are skipped).
fn ray_count(vn: &[VNode], a: u32, b: u32, near: bool, p: &VmapParams) -> u32 {
    let (na, nb) = (vn[a as usize].count() as u64, vn[b as usize].count() as u64);
    if near && na * nb <= p.near_rays as u64 {
        (na * nb) as u32
    } else if near {
        p.near_rays
    } else {
        p.rays
    }
}

/// Rays cast first for a far pair (spread over its stratified samples): when they already
/// disagree, the pair is partly visible whatever the others say.
const PROBE_RAYS: usize = 4;

/// What a partly visible far pair becomes; known before any ray, from the nodes, the close
/// occluders and the sample weights.
#[derive(Clone, Copy, PartialEq)]
enum Partly {
    /// Both are V-map leaves: the exhaustive pass.
    Exact,
    /// An occluder close to this node: refine it.
    Refine(u32),
    /// Too little light flows to resolve the shadow edge: a partial link with its fraction.
    Keep,
    /// Finer pairs.
    Split,
}

fn partly(
    vn: &[VNode],
    p: &VmapParams,
    close: &[bool],
    (a, b): (u32, u32),
    r: &[Sample],
) -> Partly {
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    if va.vleaf && vb.vleaf {
        return Partly::Exact;
    }
    let least = p.refine_form_factor * crate::close::REFINE_SHARE;
    if let Some(x) = [a, b]
        .into_iter()
        .find(|&x| close[x as usize] && !vn[x as usize].vleaf)
        .filter(|_| form_factors(va, vb, r) >= least)
    {
        // An occluder close to one of the two changes its splats' visibility sharply
        // (crate::close): refine that one down to a smaller form factor.
        return Partly::Refine(x);
    }
    if p.refine_form_factor > 0.0 && form_factors(va, vb, r) < p.refine_form_factor {
        // Hierarchical radiosity's importance criterion.
        return Partly::Keep;
    }
    Partly::Split
}

/// The indices of a far pair's probe rays: [`PROBE_RAYS`] spread over its samples.
fn probes(n: usize) -> impl Iterator<Item = usize> {
    let k = PROBE_RAYS.min(n);
    (0..k).map(move |i| i * n / k)
}

fn is_probe(i: usize, n: usize) -> bool {
    probes(n).any(|j| j == i)
}

/// Cast the rays of `tested` pairs and decide each: a link, nothing, finer pairs (returned), or
/// a partially visible pair of V-map leaves for the exhaustive pass (returned).
///
/// In two casts. A far pair's probe rays go first; where they disagree (some visible with
/// light-carrying weight, some blocked) and the pair's fate needs no fraction (finer pairs or the
/// exhaustive pass), its other rays are never cast. Every other ray is cast in the second, so
/// the links are exactly those of casting every ray at once (docs/vmap.md, "Cost"). What each
/// pair's rays say (its probes' verdict, its outcome) is worked out in parallel over the pairs;
/// the outcomes are applied in the pairs' order (the links, the finer pairs and the smear's
/// sums come out as from one loop).
// (The round's inputs, its output and its reused buffers: eight arguments.)
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
fn decide(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
    culls: &mut Culls,
    tested: &[(u32, u32, bool)],
    links: &mut Links,
    segs: &mut Segments,
) -> Result<(Vec<(u32, u32)>, Vec<(u32, u32)>), GpuError> {
    let (close, shafts) = (&culls.close[..], culls.shafts.as_ref());
    let per_pair: Vec<PairRays> = tested
        .par_iter()
        .map_init(Vec::new, |stack, &(a, b, near)| {
            let mut r = Vec::with_capacity(p.rays as usize);
            let mut drawn = pair_rays(view, vn, (a, b), near, p.rays, p, &mut r);
            // A pair that all of a few rays find unoccluded is linked whole: a partial occluder
            // slips through with probability (1 − blocked share)^rays, and every miss brightens
            // the receiver. The pairs that carry the most light get more rays.
            if !near
                && p.heavy_rays > p.rays
                && form_factors(&vn[a as usize], &vn[b as usize], &r) >= p.heavy_form_factor
            {
                r.clear();
                drawn = pair_rays(view, vn, (a, b), near, p.heavy_rays, p, &mut r);
            }
            let fate = if near {
                Partly::Keep
            } else {
                partly(vn, p, close, (a, b), &r)
            };
            let open = !near && shafts.is_some_and(|d| shaft_open(view, d, &r, stack));
            let wsum = r.iter().map(|x| x.weight).sum();
            PairRays {
                r,
                drawn,
                fate,
                open,
                wsum,
            }
        })
        .collect();
    if culls.shafts.is_some() {
        culls.tried += tested.iter().filter(|x| !x.2).count() as u64;
        culls.settled += per_pair.iter().filter(|x| x.open).count() as u64;
    }
    // 1. Probes: every ray of a near pair or of one whose partial fate needs its fraction, the
    //    probe rays of the others; none of a pair whose shaft is empty.
    let first = &mut segs.first;
    let starts = gather_rays(&per_pair, |_, x| Some(x.first_rays()), first);
    let seen_first = caster.visible_between(first)?;
    let mut probed: Vec<(Vec<bool>, bool)> = per_pair
        .par_iter()
        .zip(&starts)
        .map(|(x, &at)| x.after_probes(&seen_first[at..]))
        .collect();
    // 2. The rest, where the probes do not settle the pair.
    let unsettled = |x: &PairRays, done: bool| x.probing() && !done;
    let rest = &mut segs.rest;
    let starts = gather_rays(
        &per_pair,
        |k, x| unsettled(x, probed[k].1).then(|| x.rest_rays()),
        rest,
    );
    let seen_rest = caster.visible_between(rest)?;
    probed
        .par_iter_mut()
        .zip(&per_pair)
        .zip(&starts)
        .filter(|(((_, done), x), _)| unsettled(x, *done))
        .for_each(|(((vis, _), x), &at)| {
            for (k, i) in x.rest_rays().enumerate() {
                vis[i] = seen_rest[at + k];
            }
        });
    links.pairs_tested += tested.len() as u64;
    links.rays += (first.len() + rest.len()) as u64;
    // 3. Decide each pair, then apply the outcomes in order.
    let outcomes: Vec<Outcome> = tested
        .par_iter()
        .zip(&per_pair)
        .zip(&probed)
        .map(|((&pair, x), (vis, done))| outcome(vn, p, pair, x, vis, *done))
        .collect();
    let mut next = Vec::new();
    let mut partial = Vec::new();
    let pairs = tested.iter().zip(&per_pair).zip(&probed);
    for (((&(a, b, _), x), (vis, _)), &outcome) in pairs.zip(&outcomes) {
        let (va, vb) = (&vn[a as usize], &vn[b as usize]);
        match outcome {
            Outcome::Nothing => {}
            Outcome::Near(fraction) => {
                let l = |x: u32| Link::near(x, fraction);
                links.pairs.push((a, l(b)));
                if a != b {
                    links.pairs.push((b, l(a)));
                }
                links.near += 1;
                links.smear.add((va, vb), x.drawn, &x.r, vis, fraction);
            }
            Outcome::Far(fraction) => {
                links.pairs.push((a, Link::far(b, fraction)));
                links.pairs.push((b, Link::far(a, fraction)));
                links.far += 1;
                links.smear.add((va, vb), x.drawn, &x.r, vis, fraction);
            }
            Outcome::Exact => partial.push((a, b)),
            Outcome::Refine(n) => {
                let other = if n == a { b } else { a };
                next.extend(children(view, vn, n).map(|c| (c.min(other), c.max(other))));
            }
            Outcome::Split => split(view, vn, a, b, &mut next),
        }
    }
    // Freed where they were made (one allocation a pair), not one by one on this thread.
    (per_pair, probed).into_par_iter().for_each(drop);
    Ok((next, partial))
}

/// Pairs whose rays [`gather_rays`] copies in one task.
const GATHER_BLOCK: usize = 1024;

/// The rays of every pair that `pick(k, pair k)` names (indices into its samples; `None`:
/// none), pair after pair, copied into `out` (resized to hold them) over blocks of pairs in
/// parallel; returns where each pair's rays start. (Copied by one thread, these 72-byte
/// records were a tenth of the V-map's time at 100k splats while both workers waited.)
fn gather_rays<I: Iterator<Item = usize>>(
    per_pair: &[PairRays],
    pick: impl Fn(usize, &PairRays) -> Option<I> + Sync,
    out: &mut Vec<Between>,
) -> Vec<usize> {
    let count = |k: usize, x: &PairRays| pick(k, x).map_or(0, Iterator::count);
    let counts: Vec<usize> = per_pair
        .par_iter()
        .enumerate()
        .map(|(k, x)| count(k, x))
        .collect();
    let starts = offsets(counts.iter().copied());
    let total = starts.last().map_or(0, |&s| s + counts[counts.len() - 1]);
    // Grown in parallel too; what a longer buffer held before is overwritten.
    out.truncate(total);
    let filler = out
        .first()
        .copied()
        .unwrap_or(Between::plain(Ray::new(Vec3::ZERO, Vec3::X)));
    let grow = total - out.len();
    out.par_extend(rayon::iter::repeat_n(filler, grow));
    let mut blocks = Vec::with_capacity(per_pair.len().div_ceil(GATHER_BLOCK));
    let mut rest = &mut out[..];
    for lo in (0..per_pair.len()).step_by(GATHER_BLOCK) {
        let hi = (lo + GATHER_BLOCK).min(per_pair.len());
        let n = starts[hi - 1] + counts[hi - 1] - starts[lo];
        let (here, after) = rest.split_at_mut(n);
        blocks.push((lo, here));
        rest = after;
    }
    blocks.into_par_iter().for_each(|(lo, here)| {
        let end = (lo + GATHER_BLOCK).min(per_pair.len());
        let rays = (lo..end).flat_map(|k| {
            let x = &per_pair[k];
            pick(k, x).into_iter().flatten().map(|i| x.r[i].ray)
        });
        for (to, ray) in here.iter_mut().zip(rays) {
            *to = ray;
        }
    });
    starts
}

/// Where each of consecutive runs of `counts` starts.
fn offsets(counts: impl Iterator<Item = usize>) -> Vec<usize> {
    let mut at = 0;
    counts
        .map(|n| {
            at += n;
            at - n
        })
        .collect()
}

/// What [`decide`] makes of a tested pair.
#[derive(Clone, Copy)]
enum Outcome {
    Nothing,
    /// A near-field link with this fraction.
    Near(f32),
    /// A far-field link with this fraction.
    Far(f32),
    /// Partly visible V-map leaves, for the exhaustive pass.
    Exact,
    /// Finer pairs of this node (an occluder close to it) with the other.
    Refine(u32),
    /// Finer pairs ([`split`]).
    Split,
}

/// A tested pair's outcome from its rays' visibility (`done`: its probes settled it partly
/// visible).
fn outcome(
    vn: &[VNode],
    p: &VmapParams,
    (a, b, near): (u32, u32, bool),
    x: &PairRays,
    vis: &[bool],
    done: bool,
) -> Outcome {
    let (r, fate) = (&x.r, x.fate);
    let total = r.len();
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    if total == 0 {
        return Outcome::Nothing; // no sample pair faces each other
    }
    if !done {
        let seen = vis.iter().filter(|&&v| v).count();
        if seen == 0 {
            // All rays blocked. With at least half the samples carrying light, a visible
            // share above about a tenth would have shown (0.9^16 < 0.2): drop the pair.
            // With fewer informative samples (nodes whose splats mostly face away), refine
            // instead, unless both are V-map leaves or the pair's form factor is below the
            // importance threshold (what a partly visible pair would keep unrefined): two
            // patches of one rough surface, whose few facing samples graze it.
            let refine = !near
                && total * 2 < p.rays as usize
                && !(va.vleaf && vb.vleaf)
                && form_factors(va, vb, r) >= p.refine_form_factor;
            return match refine {
                true => Outcome::Split,
                false => Outcome::Nothing,
            };
        }
        let (wvis, wsum) = weights(r, vis);
        let Some(fraction) = link_fraction(wvis, wsum, seen, total) else {
            return Outcome::Nothing; // the visible samples carry no weight: no light flows
        };
        if near {
            return Outcome::Near(fraction);
        }
        if seen == total || fate == Partly::Keep {
            return Outcome::Far(fraction);
        }
    }
    // Partly visible, a fate without a fraction (`Keep` is never settled by its probes).
    match fate {
        Partly::Exact => Outcome::Exact,
        Partly::Refine(n) => Outcome::Refine(n),
        Partly::Keep | Partly::Split => Outcome::Split,
    }
}

/// A tested pair's sample rays, how many sample pairs were drawn ([`pair_rays`]), what it
/// becomes if partly visible, whether its shaft is empty ([`shaft_open`]), and its samples'
/// summed weight.
struct PairRays {
    r: Vec<Sample>,
    drawn: u32,
    fate: Partly,
    open: bool,
    wsum: f32,
}

impl PairRays {
    /// Whether the pair casts its probe rays first and the rest only where they do not settle
    /// it ([`decide`]): a far pair whose partial fate needs no fraction.
    fn probing(&self) -> bool {
        !self.open && self.fate != Partly::Keep && self.r.len() > PROBE_RAYS
    }

    /// The indices of the rays the pair casts first: its probes, or every ray, or none where
    /// its shaft is empty.
    fn first_rays(&self) -> impl Iterator<Item = usize> {
        let n = self.r.len();
        let k = match (self.open, self.probing()) {
            (true, _) => 0,
            (false, true) => PROBE_RAYS.min(n),
            (false, false) => n,
        };
        // [`probes`], which for k = n is every ray.
        (0..k).map(move |i| i * n / k)
    }

    /// The rays a probing pair casts second, where its probes do not settle it.
    fn rest_rays(&self) -> impl Iterator<Item = usize> {
        let n = self.r.len();
        (0..n).filter(move |&i| !is_probe(i, n))
    }

    /// The visibility of the pair's rays as far as its first cast tells (`seen` from its first
    /// ray on), and whether the probes settle it partly visible: some visible with
    /// light-carrying weight (which keeps the whole pair's fraction above zero, as casting
    /// every ray would find), some blocked.
    fn after_probes(&self, seen: &[bool]) -> (Vec<bool>, bool) {
        let r = &self.r;
        if self.open {
            // Every ray open: what casting them would find.
            return (vec![true; r.len()], false);
        }
        if !self.probing() {
            return (seen[..r.len()].to_vec(), false);
        }
        let mut vis = vec![false; r.len()];
        let (mut any_seen, mut any_blocked, mut weight) = (false, false, 0.0f32);
        for (k, i) in probes(r.len()).enumerate() {
            vis[i] = seen[k];
            any_seen |= vis[i];
            any_blocked |= !vis[i];
            weight += if vis[i] { r[i].weight } else { 0.0 };
        }
        let wsum = self.wsum;
        let done = any_seen && any_blocked && wsum.is_finite() && weight / wsum > 0.0;
        (vis, done)
    }
}

/// What settles a pair without rays, besides its nodes: the nodes with an occluder close by
/// ([`crate::close`]) and the disks' boxes for shaft culling ([`shaft_open`]).
pub(crate) struct Culls {
    pub close: Vec<bool>,
    /// The disks' boxes while far pairs try their shafts: a rough scan's own noise stands
    /// inside nearly every shaft, and there the descents cost pc-vmap 2-4 % for nothing, so
    /// they are dropped once not worth trying ([`Culls::give_up_unless_worth`]; 52 bytes a
    /// node, 285 MB on the 20M hall scan). The links never depend on it, only the time.
    pub shafts: Option<DiskBoxes>,
    /// Far pairs that tried their shafts so far, and those settled.
    pub tried: u64,
    pub settled: u64,
}

impl Culls {
    /// Shafts are tried until [`SHAFT_TRIAL`] far pairs have, and then while they settle at
    /// least one in [`SHAFT_WORTH`]; once they do not, the disks' boxes go.
    fn give_up_unless_worth(&mut self) {
        if self.tried >= SHAFT_TRIAL && self.settled * SHAFT_WORTH < self.tried {
            self.shafts = None;
        }
    }
}

/// Far pairs that try their shafts before [`Culls::give_up_unless_worth`] judges by their
/// record.
const SHAFT_TRIAL: u64 = 20_000;
/// The least share (one in this many) of far pairs that shafts must settle to be tried on.
const SHAFT_WORTH: u64 = 50;

/// Whether shaft culling proves every ray of `r` (one far pair's) open: no disk's box meets the
/// shaft from the box of their near ends to the box of their far ends, over the part of each
/// segment where a hit counts (pc_tree::shaft, Haines and Wallace's shaft culling). Casting
/// them would find each visible, so the pair's decision is the same without a ray (hits an end's
/// own zone ignores only make a ray more visible). docs/vmap.md, "Empty shafts".
fn shaft_open(view: &OctreeView, shafts: &DiskBoxes, r: &[Sample], stack: &mut Vec<u32>) -> bool {
    if r.is_empty() {
        return false;
    }
    let (mut a, mut b) = (Aabb::EMPTY, Aabb::EMPTY);
    let (mut t_min, mut end) = (f32::INFINITY, f32::INFINITY);
    for s in r {
        // The ray starts at the near end's centre.
        let (xa, xb) = (
            s.ray.ray.origin,
            Vec3::from(view.splats[s.ends[1] as usize].position),
        );
        a.grow(xa);
        b.grow(xb);
        t_min = t_min.min(s.ray.ray.t_min);
        end = end.min((xb - xa).length() - s.ray.ray.t_max);
    }
    Shaft::new(a, b, t_min, end).is_some_and(|shaft| !shafts.any_meets(view, &shaft, stack))
}

/// A far pair's rays (`p.rays` of them, those that carry light) and whether shaft culling
/// proves them all open ([`shaft_open`]); what [`build_links`] decides a far pair on before
/// any ray is cast.
pub fn far_pair_shaft(
    view: &OctreeView,
    vn: &[VNode],
    shafts: &DiskBoxes,
    p: &VmapParams,
    (a, b): (u32, u32),
) -> (bool, Vec<Between>) {
    let mut r = Vec::new();
    pair_rays(view, vn, (a, b), false, p.rays, p, &mut r);
    let open = shaft_open(view, shafts, &r, &mut Vec::new());
    (open, r.iter().map(|x| x.ray).collect())
}

/// The exhaustive pass over partially visible pairs of V-map leaves: their fraction is the only
/// estimate the links carry, so every splat pair (up to `near_rays`) is cast, like the near field.
fn exact_partial(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
    partial: &[(u32, u32)],
    links: &mut Links,
) -> Result<(), GpuError> {
    {
        let per_pair: Vec<(Vec<Sample>, u32)> = partial
            .par_iter()
            .map(|&(a, b)| {
                let mut r = Vec::new();
                let drawn = pair_rays(view, vn, (a, b), true, p.rays, p, &mut r);
                (r, drawn)
            })
            .collect();
        let mut rays: Vec<Between> = Vec::new();
        rays.par_extend(
            per_pair
                .par_iter()
                .flat_map_iter(|r| r.0.iter().map(|r| r.ray)),
        );
        let visible = caster.visible_between(&rays)?;
        links.rays += rays.len() as u64;
        let starts = offsets(per_pair.iter().map(|r| r.0.len()));
        let fractions: Vec<Option<f32>> = per_pair
            .par_iter()
            .zip(&starts)
            .map(|((r, _), &at)| {
                let vis = &visible[at..at + r.len()];
                let (wvis, wsum) = weights(r, vis);
                let seen = vis.iter().filter(|&&v| v).count();
                let weighed = wvis > 0.0 && wsum > 0.0;
                link_fraction(wvis, wsum, seen, r.len()).filter(|_| weighed)
            })
            .collect();
        let each = partial.iter().zip(&per_pair).zip(&starts).zip(&fractions);
        for (((&(a, b), (r, drawn)), &at), f) in each {
            if let &Some(f) = f {
                links.pairs.push((a, Link::far(b, f)));
                links.pairs.push((b, Link::far(a, f)));
                links.far += 1;
                let (va, vb) = (&vn[a as usize], &vn[b as usize]);
                links
                    .smear
                    .add((va, vb), *drawn, r, &visible[at..at + r.len()], f);
            }
        }
        per_pair.into_par_iter().for_each(drop);
    }
    Ok(())
}

/// The summed weights of a pair's visible samples and of all its samples.
fn weights(samples: &[Sample], visible: &[bool]) -> (f32, f32) {
    let all = samples.iter().map(|x| x.weight).sum();
    let seen = samples
        .iter()
        .zip(visible)
        .filter(|(_, &v)| v)
        .map(|(x, _)| x.weight)
        .sum();
    (seen, all)
}

/// A link's fraction from its samples: the visible share of their weights, in (0, 1]; the share
/// of rays where no sample has weight (or the weights overflowed); `None` where the visible
/// samples carry no weight at all (splats of zero area: on a 20M-point scan quantised to a
/// millimetre, coincident points share their area and some get none), which the artifact's
/// readers would refuse as a fraction of 0.
fn link_fraction(wvis: f32, wsum: f32, seen: usize, total: usize) -> Option<f32> {
    if seen == total {
        return Some(1.0);
    }
    let by_rays = seen as f32 / total as f32;
    let f = match wsum > 0.0 && (wvis / wsum).is_finite() {
        true => (wvis / wsum).min(1.0),
        false => by_rays,
    };
    (f > 0.0).then_some(f)
}

/// The larger of the two form factors F_AB, F_BA estimated from a pair's sample weights: the
/// mean weight times the number of splat pairs over π estimates Σ A_i A_j cos cos / (π r²), the
/// area-weighted form factor between the nodes; divide by each node's area.
fn form_factors(va: &VNode, vb: &VNode, samples: &[Sample]) -> f32 {
    if samples.is_empty() {
        return 0.0;
    }
    let mean = samples.iter().map(|s| s.weight as f64).sum::<f64>() / samples.len() as f64;
    let pairs = va.count() as f64 * vb.count() as f64;
    let total = mean * pairs / std::f64::consts::PI;
    let area = |v: &VNode| v.area.max(1e-30);
    (total / area(va)).max(total / area(vb)) as f32
}

/// Result of a build.
#[derive(Debug, Default)]
pub struct Links {
    /// (node, link) pairs, both directions of every link.
    pub pairs: Vec<(u32, Link)>,
    pub far: u64,
    pub near: u64,
    pub pairs_tested: u64,
    pub rays: u64,
    /// Nodes with an occluder close by ([`crate::close`]).
    pub close: u64,
    /// What the links' shared fractions misstate of each splat's visible transfer.
    pub smear: Smear,
    /// Per node-pool slot: the share of a V-map leaf's probes that a surface close over it
    /// blocks ([`crate::close::contact_shares`]).
    pub contact: Vec<f32>,
}

#[derive(Clone, Copy)]
enum Step {
    Drop,
    Split(u32, u32),
    Rays { near: bool },
}

/// Classify a pair without rays.
fn classify(view: &OctreeView, vn: &[VNode], a: u32, b: u32, theta: f32) -> Step {
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    if a == b {
        return if va.vleaf {
            Step::Rays { near: true }
        } else {
            Step::Split(a, b)
        };
    }
    if !may_face(va, vb) {
        return Step::Drop;
    }
    if well_separated(va, vb, theta) {
        return Step::Rays { near: false };
    }
    if va.vleaf && vb.vleaf {
        return Step::Rays { near: true };
    }
    let _ = view;
    Step::Split(a, b)
}

/// The finer pairs of (a, b): all child pairs of a self pair, else the children of the larger
/// non-leaf node against the other.
fn split(view: &OctreeView, vn: &[VNode], a: u32, b: u32, out: &mut Vec<(u32, u32)>) {
    if a == b {
        let kids: Vec<u32> = children(view, vn, a).collect();
        for (i, &x) in kids.iter().enumerate() {
            for &y in &kids[i..] {
                out.push((x, y));
            }
        }
        return;
    }
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    let split_a = !va.vleaf && (vb.vleaf || va.radius >= vb.radius);
    if split_a {
        out.extend(children(view, vn, a).map(|c| (c.min(b), c.max(b))));
    } else {
        out.extend(children(view, vn, b).map(|c| (c.min(a), c.max(a))));
    }
}

/// The segments of a batch's two casts, kept from batch to batch: allocated afresh, a
/// batch's few hundred megabytes came from the system as new pages each time, and faulting them
/// in cost as much as filling them.
#[derive(Default)]
struct Segments {
    first: Vec<Between>,
    rest: Vec<Between>,
}

/// Build the links of the octree. `round` is called after each round with the frontier size.
pub fn build_links(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
    round: &mut dyn FnMut(usize, usize),
) -> Result<Links, GpuError> {
    let mut links = Links {
        smear: Smear::new(view.splats.len()),
        ..Default::default()
    };
    if vn[0].count() == 0 {
        return Ok(links);
    }
    let close = crate::close::close_occluders(view, vn, p, caster)?;
    links.close = close.iter().filter(|&&c| c).count() as u64;
    let mut culls = Culls {
        close,
        shafts: Some(DiskBoxes::new(view)),
        tried: 0,
        settled: 0,
    };
    links.contact = crate::close::contact_shares(view, vn, p, caster)?;
    let mut frontier: Vec<(u32, u32)> = vec![(0, 0)];
    let mut segs = Segments::default();
    let mut level = 0;
    while !frontier.is_empty() {
        level += 1;
        // 1. Classify in parallel; collect finer pairs and the pairs that need rays.
        let steps: Vec<Step> = frontier
            .par_iter()
            .map(|&(a, b)| classify(view, vn, a, b, p.theta))
            .collect();
        let mut next: Vec<(u32, u32)> = Vec::new();
        let mut tested: Vec<(u32, u32, bool)> = Vec::new();
        let mut partial: Vec<(u32, u32)> = Vec::new();
        for (&(a, b), s) in frontier.iter().zip(&steps) {
            match *s {
                Step::Drop => {}
                Step::Split(a, b) => split(view, vn, a, b, &mut next),
                Step::Rays { near } => tested.push((a, b, near)),
            }
        }
        // 2.-4. Rays for the tested pairs, in chunks of bounded size (memory), then decide.
        let mut first = 0;
        while first < tested.len() {
            let mut last = first;
            let mut budget = 0u64;
            while last < tested.len() && budget < RAYS_PER_BATCH {
                let (a, b, near) = tested[last];
                budget += ray_count(vn, a, b, near, p) as u64;
                last += 1;
            }
            culls.give_up_unless_worth();
            let (more, part) = decide(
                view,
                vn,
                p,
                caster,
                &mut culls,
                &tested[first..last],
                &mut links,
                &mut segs,
            )?;
            next.extend(more);
            partial.extend(part);
            first = last;
        }
        let mut first = 0;
        while first < partial.len() {
            let last = (first + (RAYS_PER_BATCH / p.near_rays.max(1) as u64).max(1) as usize)
                .min(partial.len());
            exact_partial(view, vn, p, caster, &partial[first..last], &mut links)?;
            first = last;
        }
        round(level, next.len());
        frontier = next;
    }
    Ok(links)
}

/// For each point light, the V-map leaves it sees, with the fraction of their sample rays that
/// reach it.
pub fn light_lists(
    view: &OctreeView,
    vn: &[VNode],
    lights: &[Vec3],
    p: &VmapParams,
    caster: &dyn Caster,
) -> Result<Vec<Vec<Link>>, GpuError> {
    let mut out = Vec::with_capacity(lights.len());
    for (li, &pos) in lights.iter().enumerate() {
        // Descend by geometry alone: every V-map leaf whose splats may face the light. Rays
        // decide only at the leaves: a few samples of a large node cannot prove it unlit (a
        // sun seen through a skylight lights a small patch of a large room, which its samples
        // miss), nor fully lit (a shadow can cover a corner the samples missed).
        let mut leaves = Vec::new();
        let mut frontier: Vec<u32> = if vn[0].count() > 0 { vec![0] } else { vec![] };
        while let Some(a) = frontier.pop() {
            let v = &vn[a as usize];
            let d = pos - v.center;
            let dist = d.length();
            if !(dist <= v.radius || faces(v, d / dist, (v.radius / dist).min(1.0).asin())) {
                continue;
            }
            if v.vleaf {
                leaves.push(a);
            } else {
                frontier.extend(children(view, vn, a));
            }
        }
        leaves.sort_unstable();
        let per: Vec<Vec<Between>> = leaves
            .par_iter()
            .map(|&a| {
                let v = &vn[a as usize];
                let stream = pcg(a ^ pcg(0x5151 + li as u32));
                let mut r = Vec::new();
                for k in 0..p.rays {
                    let (i, x, n, rad) = sample(view, v, p.seed, stream, k, p.rays);
                    let d = pos - x;
                    let len = d.length();
                    if len <= 1e-9 || n.dot(d) <= 0.0 {
                        continue;
                    }
                    let ray = Ray {
                        origin: x,
                        dir: d / len,
                        t_min: p.self_hit * rad,
                        t_max: len * (1.0 - 1e-4),
                    };
                    r.push(Between::leaving(
                        ray,
                        (&view.splats[i as usize], end_rough(view, vn, i)),
                    ));
                }
                r
            })
            .collect();
        let mut list = Vec::new();
        let rays: Vec<Between> = per.iter().flatten().copied().collect();
        let visible = caster.visible_between(&rays)?;
        let mut at = 0;
        for (&a, r) in leaves.iter().zip(&per) {
            let total = r.len();
            let seen = visible[at..at + total].iter().filter(|&&v| v).count();
            at += total;
            if seen > 0 {
                list.push(Link::far(a, seen as f32 / total as f32));
            }
        }
        list.sort_by_key(|l| l.node);
        out.push(list);
    }
    Ok(out)
}

/// CSR of the links: row offsets per node-pool slot (+1) and the links sorted by row.
pub fn csr(nodes: usize, mut pairs: Vec<(u32, Link)>) -> (Vec<u32>, Vec<Link>) {
    pairs.par_sort_unstable_by_key(|&(a, l)| (a, l.node));
    let mut offsets = vec![0u32; nodes + 1];
    for &(a, _) in &pairs {
        offsets[a as usize + 1] += 1;
    }
    for i in 0..nodes {
        offsets[i + 1] += offsets[i];
    }
    (offsets, pairs.into_iter().map(|p| p.1).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pairs of `n` samples each, sample `i` of pair `k` a ray whose origin names both.
    fn pairs(sizes: &[usize]) -> Vec<PairRays> {
        let ray = |k: usize, i: usize| {
            let o = Vec3::new(k as f32, i as f32, 0.0);
            Between::plain(Ray::new(o, Vec3::Z))
        };
        sizes
            .iter()
            .enumerate()
            .map(|(k, &n)| PairRays {
                r: (0..n)
                    .map(|i| Sample {
                        ray: ray(k, i),
                        weight: 1.0,
                        ends: [0, 1],
                    })
                    .collect(),
                drawn: n as u32,
                fate: Partly::Split,
                open: k % 7 == 3,
                wsum: n as f32,
            })
            .collect()
    }

    #[test]
    fn gathered_rays_are_the_pairs_rays_in_order_across_blocks() {
        // More pairs than a block holds, some with no rays, some whose shaft is open.
        let sizes: Vec<usize> = (0..3 * GATHER_BLOCK + 17).map(|k| (k * 5) % 23).collect();
        let per_pair = pairs(&sizes);
        for old in [0, 5, 1_000_000] {
            // Whatever the buffer held before (shorter or longer) is replaced.
            let mut out = vec![Between::plain(Ray::new(Vec3::ONE, Vec3::X)); old];
            let starts = gather_rays(&per_pair, |_, x| Some(x.first_rays()), &mut out);
            let want: Vec<Between> = per_pair
                .iter()
                .flat_map(|x| x.first_rays().map(|i| x.r[i].ray))
                .collect();
            assert_eq!(out, want);
            let mut at = 0;
            for (x, &s) in per_pair.iter().zip(&starts) {
                assert_eq!(s, at);
                at += x.first_rays().count();
            }
            // A pick that skips pairs: their runs are empty.
            let skip = |k: usize, x: &PairRays| k.is_multiple_of(3).then(|| x.rest_rays());
            gather_rays(&per_pair, skip, &mut out);
            let pp = &per_pair;
            let want: Vec<Between> = (0..pp.len())
                .filter_map(|k| skip(k, &pp[k]).map(|it| (k, it)))
                .flat_map(|(k, it)| it.map(move |i| pp[k].r[i].ray))
                .collect();
            assert_eq!(out, want);
        }
    }

    #[test]
    fn a_link_fraction_lies_in_zero_one_or_there_is_no_link() {
        assert_eq!(link_fraction(3.0, 3.0, 16, 16), Some(1.0));
        assert_eq!(link_fraction(1.0, 4.0, 8, 16), Some(0.25));
        // Visible samples of zero weight (splats of zero area): no light flows, no link.
        assert_eq!(link_fraction(0.0, 4.0, 8, 16), None);
        // No weight anywhere, or weights that overflowed: the share of rays.
        assert_eq!(link_fraction(0.0, 0.0, 4, 16), Some(0.25));
        assert_eq!(
            link_fraction(f32::INFINITY, f32::INFINITY, 8, 16),
            Some(0.5)
        );
        assert_eq!(link_fraction(f32::NAN, 1.0, 8, 16), Some(0.5));
    }

    /// The pair samples' indices are the portable loop's on every path (AVX2 where the CPU has
    /// it), for nodes of one splat to thousands and counts that fill no whole vector.
    #[test]
    fn sample_pairs_are_the_portable_loop_s() {
        let node = |lo: u32, hi: u32| VNode {
            lo,
            hi,
            center: Vec3::ZERO,
            radius: 1.0,
            axis: Vec3::Z,
            cone_cos: -1.0,
            vleaf: true,
            area: 1.0,
            rough: 0.0,
        };
        for (a, b) in [(node(0, 1), node(5, 6)), (node(3, 40), node(100, 5000))] {
            for n in [1, 3, 8, 16, 17, 64, 100] {
                for (seed, stream) in [(1, 7), (0xdead_beef, pcg(12) ^ pcg(5))] {
                    let portable = sample_pairs_portable((&a, &b), seed, stream, n);
                    assert_eq!(sample_pairs((&a, &b), seed, stream, n), portable);
                    assert!(portable
                        .iter()
                        .all(|&(i, j)| (a.lo..a.hi).contains(&i) && (b.lo..b.hi).contains(&j)));
                }
            }
        }
    }
}
