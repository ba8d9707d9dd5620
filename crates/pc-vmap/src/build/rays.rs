//! A pair's sample points and visibility rays ([`pair_rays`]), and the batches of rays a
//! round casts at once ([`gather_rays`]).

use glam::Vec3;
use pc_artifact::params::VmapParams;
use pc_tree::rng::{pcg, rand};
use pc_tree::{Between, OctreeView, Ray};
use rayon::prelude::*;

use super::settle::PairRays;
use super::vnode::{end_rough, VNode};

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
pub(super) fn sample_index(v: &VNode, seed: u32, stream: u32, k: u32, m: u32) -> u32 {
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
pub(super) fn sample_pairs(v: (&VNode, &VNode), seed: u32, stream: u32, n: u32) -> Vec<(u32, u32)> {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn avx2(v: (&VNode, &VNode), seed: u32, stream: u32, n: u32) -> Vec<(u32, u32)> {
            sample_pairs_portable(v, seed, stream, n)
        }
        if pc_tree::has_avx2() {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { avx2(v, seed, stream, n) };
        }
    }
    sample_pairs_portable(v, seed, stream, n)
}

/// [`sample_pairs`] for any CPU: a plain loop over a filled vector, so that it compiles into the
/// AVX2 caller (an iterator's collect would be a function of its own, built without AVX2).
#[inline(always)]
pub(super) fn sample_pairs_portable(
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
pub(super) fn pair_rays(
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

/// Pairs whose rays [`gather_rays`] copies in one task.
pub(super) const GATHER_BLOCK: usize = 1024;

/// The rays of every pair that `pick(k, pair k)` names (indices into its samples; `None`:
/// none), pair after pair, copied into `out` (resized to hold them) over blocks of pairs in
/// parallel; returns where each pair's rays start. (Copied by one thread, these 72-byte
/// records were a tenth of the V-map's time at 100k splats while both workers waited.)
pub(super) fn gather_rays<I: Iterator<Item = usize>>(
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
pub(super) fn offsets(counts: impl Iterator<Item = usize>) -> Vec<usize> {
    let mut at = 0;
    counts
        .map(|n| {
            at += n;
            at - n
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::settle::Partly;
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
