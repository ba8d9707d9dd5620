//! Building the walk's copy of a tree ([`Accel::build`]): the leaves' runs of chunks and their
//! slabs, and the internal nodes' blocks with the slab of every disk listed below them where
//! it is thin ([`blocks`]); and the independent check of those slabs ([`Accel::verify_slabs`]).
//! pc-octree runs it once and writes the result into the artifact (docs/raytrace.md, "The CPU
//! walk's layout").

use pc_artifact::octree::{node, BeginEnd};
use pc_artifact::walk::{clipped_bits, BLOCK_WORDS};
use rayon::prelude::*;
use std::borrow::Cow;

use super::lanes::has_avx2;
use super::{node_slab, Accel, Block, Chunk, Leaf, LANES, PAD};
use crate::ray::Slab;
use crate::OctreeView;

impl Accel<'_> {
    /// The copy built in memory from the view's tree (the same whether or not the view has a
    /// walk of its own).
    pub fn build(view: &OctreeView) -> Accel<'static> {
        // Leaves in table order (the table lists leaves in SFC order).
        let offsets: Vec<u32> = BeginEnd::offsets(view.begin_end).collect();
        // Each leaf's slab and chunk count in parallel, then its run by a prefix sum.
        let mut leaves: Vec<Leaf> = offsets
            .par_iter()
            .map(|&o| {
                let (r, refs) = view.leaf(node::leaf(o));
                Leaf {
                    first: 0,
                    end: ((r.end - r.start) as usize + refs.len()).div_ceil(LANES) as u32,
                    word: node::leaf(o),
                    slab: slab(view, r.chain(refs.iter().copied())).to_array(),
                }
            })
            .collect();
        let mut acc = 0u32;
        for l in &mut leaves {
            (l.first, l.end) = (acc, acc + l.end);
            acc = l.end;
        }
        // Padded in parallel too (2 GB at 20M points: one core's fill and page faults).
        let mut chunks = Vec::with_capacity(acc as usize);
        chunks.par_extend(rayon::iter::repeat_n(PAD, acc as usize));
        // Fill each leaf's run in parallel: runs are disjoint.
        let mut runs = Vec::with_capacity(offsets.len());
        let mut rest = &mut chunks[..];
        for l in &leaves {
            let (a, b) = rest.split_at_mut((l.end - l.first) as usize);
            runs.push(a);
            rest = b;
        }
        runs.into_par_iter()
            .zip(offsets.par_iter())
            .for_each(|(run, &o)| {
                let (r, refs) = view.leaf(node::leaf(o));
                for (k, i) in r.chain(refs.iter().copied()).enumerate() {
                    let s = &view.splats[i as usize];
                    let (c, l) = (&mut run[k / LANES], k % LANES);
                    [c.px[l], c.py[l], c.pz[l]] = s.position;
                    [c.nx[l], c.ny[l], c.nz[l]] = s.normal;
                    c.r2[l] = s.radius * s.radius;
                    c.cold[l] = i;
                }
            });
        let (nodes, slabs) = blocks(view, &offsets, &leaves, &chunks);
        Accel {
            nodes: Cow::Owned(nodes),
            slabs,
            leaves: Cow::Owned(leaves),
            chunks: Cow::Owned(chunks),
            clipped: Cow::Owned(clipped_bits(view.splats)),
            surfaces: None,
            wide: has_avx2(),
        }
    }

    /// Internal nodes whose slab the walk tests.
    pub fn slabbed_nodes(&self) -> usize {
        match self.slabs {
            true => self.nodes.iter().filter(|b| b.has_slab != 0).count(),
            false => 0,
        }
    }

    /// Checks that every slab holds every disk it stands for: each leaf's listed disks lie in
    /// the leaf's slab and in the slab of each of its ancestors that has one (reached by the
    /// tree from the root, independently of how the slabs were gathered). For tests.
    pub fn verify_slabs(&self) -> Result<(), String> {
        let nodes: &[u32] = bytemuck::cast_slice(&self.nodes[..]);
        let holds = |s: &Slab, (p, n, r): ([f32; 3], [f32; 3], f32)| {
            let (a, p, n) = (
                glam::Vec3::from(s.axis),
                glam::Vec3::from(p),
                glam::Vec3::from(n),
            );
            let c = a.dot(n);
            let reach = r * (1.0 - c * c).max(0.0).sqrt();
            s.lo <= a.dot(p) - reach && a.dot(p) + reach <= s.hi
        };
        let mut stack: Vec<(u32, Vec<Slab>)> = vec![(nodes[0], Vec::new())];
        while let Some((w, mut above)) = stack.pop() {
            if node::is_empty(w) {
                continue;
            }
            if node::is_leaf(w) {
                let leaf = &self.leaves[node::ptr(w) as usize];
                above.push(Slab::from_array(leaf.slab));
                let run = &self.chunks[leaf.first as usize..leaf.end as usize];
                for (k, d) in run.iter().flat_map(lane_disks).enumerate() {
                    if let Some(s) = above.iter().find(|s| !holds(s, d)) {
                        return Err(format!(
                            "leaf {}: disk {k} {d:?} outside {s:?}",
                            node::ptr(w)
                        ));
                    }
                }
                continue;
            }
            if self.slabs {
                above.extend(node_slab(nodes, w));
            }
            let b = node::ptr(w) as usize;
            for &c in &nodes[b..b + 8] {
                stack.push((c, above.clone()));
            }
        }
        Ok(())
    }
}

/// The slab of a leaf's listed disks ([`Leaf::slab`]): about their mean normal, each disk
/// reaching `r · sin θ` either side of its centre's level (θ between its normal and the axis),
/// padded by 10⁻³ of the largest radius and 10⁻⁵ of the coordinates' size, far above the
/// rounding of a hit point, so a leaf is skipped only where no hit can be.
fn slab(view: &OctreeView, listed: impl Iterator<Item = u32> + Clone) -> Slab {
    let disks = listed.map(|i| {
        let s = &view.splats[i as usize];
        (s.position, s.normal, s.radius)
    });
    slab_of(disks)
}

/// [`slab`] of disks given as (centre, normal, radius).
fn slab_of(disks: impl Iterator<Item = ([f32; 3], [f32; 3], f32)> + Clone) -> Slab {
    let sum: glam::Vec3 = disks.clone().map(|d| glam::Vec3::from(d.1)).sum();
    match sum.try_normalize() {
        Some(axis) => slab_about(axis, disks),
        None => Slab::WHOLE,
    }
}

/// The slab about a unit `axis` that holds the disks, padded as [`slab`] says.
fn slab_about(axis: glam::Vec3, disks: impl Iterator<Item = ([f32; 3], [f32; 3], f32)>) -> Slab {
    let mut e = Extent::EMPTY;
    for (p, n, r) in disks {
        e.add(axis, p, n, r);
    }
    e.slab(axis)
}

/// [`slab_about`] the disks of `chunks` (not their padding, radii `√r²`), four lanes at a time
/// on x86-64: the same operations in the same order, so the same slab bit for bit
/// (`simd_lanes_match_scalar_lanes`). The node slabs' pass visits each listed disk once per
/// ancestor (1.5 s of the 20M scan's 2.6 s walk build, one disk at a time).
fn slab_about_chunks<'c>(axis: glam::Vec3, chunks: impl Iterator<Item = &'c Chunk>) -> Slab {
    chunk_extent(axis, chunks).slab(axis)
}

/// What a slab about an axis needs of its disks: the least and greatest level reached, the
/// largest radius and the coordinates' size.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Extent {
    lo: f32,
    hi: f32,
    r_max: f32,
    size: f32,
}

impl Extent {
    const EMPTY: Extent = Extent {
        lo: f32::INFINITY,
        hi: f32::NEG_INFINITY,
        r_max: 0.0,
        size: 0.0,
    };

    /// One disk (centre `p`, normal `n`, radius `r`) about `axis`.
    #[inline(always)]
    fn add(&mut self, axis: glam::Vec3, p: [f32; 3], n: [f32; 3], r: f32) {
        let (p, n) = (glam::Vec3::from(p), glam::Vec3::from(n));
        let c = axis.dot(n);
        let reach = r * (1.0 - c * c).max(0.0).sqrt();
        self.lo = self.lo.min(axis.dot(p) - reach);
        self.hi = self.hi.max(axis.dot(p) + reach);
        self.r_max = self.r_max.max(r);
        self.size = self.size.max(p.abs().max_element() + r);
    }

    /// The padded slab ([`slab`]); the whole space without disks.
    fn slab(&self, axis: glam::Vec3) -> Slab {
        if self.lo > self.hi {
            return Slab::WHOLE; // no disks
        }
        let pad = 1e-3 * self.r_max + 1e-5 * self.size;
        Slab {
            axis: axis.to_array(),
            lo: self.lo - pad,
            hi: self.hi + pad,
        }
    }
}

/// [`Extent`] of the chunks' disks, SSE lanes (x86-64 baseline); [`chunk_extent_scalar`]
/// elsewhere and in the test that holds the two together.
#[cfg(target_arch = "x86_64")]
fn chunk_extent<'c>(axis: glam::Vec3, chunks: impl Iterator<Item = &'c Chunk>) -> Extent {
    use std::arch::x86_64::*;
    // SAFETY: SSE and SSE2 are part of the x86-64 baseline; the loads read 16-byte aligned
    // `[f32; 4]` fields of a `#[repr(C, align(16))]` struct, the stores write local arrays.
    unsafe {
        let (add, sub, mul) = (_mm_add_ps, _mm_sub_ps, _mm_mul_ps);
        let ld = |a: &[f32; LANES]| _mm_load_ps(a.as_ptr());
        // Lanes of `a` where `keep`, else `other`.
        let pick = |keep, a, other| _mm_or_ps(_mm_and_ps(keep, a), _mm_andnot_ps(keep, other));
        let (ax, ay, az) = (
            _mm_set1_ps(axis.x),
            _mm_set1_ps(axis.y),
            _mm_set1_ps(axis.z),
        );
        let (zero, one, sign) = (_mm_setzero_ps(), _mm_set1_ps(1.0), _mm_set1_ps(-0.0));
        let (inf, ninf) = (_mm_set1_ps(f32::INFINITY), _mm_set1_ps(f32::NEG_INFINITY));
        let (mut lo, mut hi, mut r_max, mut size) = (inf, ninf, zero, zero);
        for c in chunks {
            let r2 = ld(&c.r2);
            let disk = _mm_cmpge_ps(r2, zero);
            let r = _mm_sqrt_ps(r2);
            let (px, py, pz) = (ld(&c.px), ld(&c.py), ld(&c.pz));
            let cos = add(
                add(mul(ax, ld(&c.nx)), mul(ay, ld(&c.ny))),
                mul(az, ld(&c.nz)),
            );
            let reach = mul(r, _mm_sqrt_ps(_mm_max_ps(sub(one, mul(cos, cos)), zero)));
            let level = add(add(mul(ax, px), mul(ay, py)), mul(az, pz));
            lo = _mm_min_ps(lo, pick(disk, sub(level, reach), inf));
            hi = _mm_max_ps(hi, pick(disk, add(level, reach), ninf));
            r_max = _mm_max_ps(r_max, pick(disk, r, zero));
            let far = _mm_max_ps(
                _mm_max_ps(_mm_andnot_ps(sign, px), _mm_andnot_ps(sign, py)),
                _mm_andnot_ps(sign, pz),
            );
            size = _mm_max_ps(size, pick(disk, add(far, r), zero));
        }
        let lanes = |v| {
            let mut a = [0.0f32; LANES];
            _mm_storeu_ps(a.as_mut_ptr(), v);
            a
        };
        let (lo, hi, r_max, size) = (lanes(lo), lanes(hi), lanes(r_max), lanes(size));
        Extent {
            lo: lo.into_iter().fold(f32::INFINITY, f32::min),
            hi: hi.into_iter().fold(f32::NEG_INFINITY, f32::max),
            r_max: r_max.into_iter().fold(0.0, f32::max),
            size: size.into_iter().fold(0.0, f32::max),
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn chunk_extent<'c>(axis: glam::Vec3, chunks: impl Iterator<Item = &'c Chunk>) -> Extent {
    chunk_extent_scalar(axis, chunks)
}

/// [`chunk_extent`] one disk at a time.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn chunk_extent_scalar<'c>(axis: glam::Vec3, chunks: impl Iterator<Item = &'c Chunk>) -> Extent {
    let mut e = Extent::EMPTY;
    for (p, n, r) in chunks.flat_map(lane_disks) {
        e.add(axis, p, n, r);
    }
    e
}

/// A chunk's disks (not its padding) as (centre, normal, radius).
fn lane_disks(c: &Chunk) -> impl Iterator<Item = ([f32; 3], [f32; 3], f32)> + '_ {
    (0..LANES).filter(|&l| c.r2[l] >= 0.0).map(|l| {
        let p = [c.px[l], c.py[l], c.pz[l]];
        (p, [c.nx[l], c.ny[l], c.nz[l]], c.r2[l].sqrt())
    })
}

/// A node slab is tested only when thinner than this share of the node's cell: a thicker one
/// seldom lets a ray past, and the test costs the cell's exit and the slab's arithmetic.
const THIN: f32 = 0.25;

/// A node is a candidate for a slab only where its normals' mean has at least this length
/// (nearly one orientation); the others are not worth the pass over their disks.
const ALIGNED: f32 = 0.9;

/// Nor where more disks than this are listed below it: the pass over a node's disks is repeated
/// at every level, and the few nodes above this size seldom lie in one thin slab.
const MAX_SLAB_DISKS: u32 = 1 << 20;

/// The view's tree as [`Block`]s, depth first, with the slab of each internal node's listed
/// disks (every leaf below it) where it is thin. Without room for the pointers (over 67M
/// internal nodes) the blocks carry no slabs.
fn blocks(
    view: &OctreeView,
    offsets: &[u32],
    leaves: &[Leaf],
    chunks: &[Chunk],
) -> (Vec<Block>, bool) {
    let zero = Block {
        words: [0; 8],
        slab: [0; 5],
        has_slab: 0,
        _pad: [0; 2],
    };
    // The blocks and, per block, the view's word and its depth.
    let mut blocks = vec![zero];
    let mut info: Vec<(u32, u32)> = vec![(0, 0)];
    let mut stack = Vec::new();
    // The reader checks that every leaf word points at a leaf's start.
    let leaf = |w: u32| node::LEAF | offsets.binary_search(&node::ptr(w)).unwrap_or(0) as u32;
    let map =
        |w: u32, depth: u32, blocks: &mut Vec<Block>, info: &mut Vec<_>, stack: &mut Vec<u32>| {
            if node::is_leaf(w) {
                leaf(w)
            } else if node::is_empty(w) {
                w
            } else {
                let b = blocks.len() as u32;
                blocks.push(zero);
                info.push((w, depth));
                stack.push(b);
                node::internal(b.saturating_mul(BLOCK_WORDS))
            }
        };
    let root = map(view.nodes[0], 0, &mut blocks, &mut info, &mut stack);
    blocks[0].words[0] = root;
    // The reader's checks make the pool a forest of forward pointers, not yet a tree: groups
    // shared by two parents would be copied twice. More blocks than groups means sharing.
    let groups = view.nodes.len() / 8;
    let mut order = Vec::new();
    while let Some(b) = stack.pop() {
        if blocks.len() > groups + 1 {
            break;
        }
        order.push(b);
        let (w, depth) = info[b as usize];
        for c in 0..8 {
            let child = view.nodes[(node::ptr(w) + c) as usize];
            let word = map(child, depth + 1, &mut blocks, &mut info, &mut stack);
            blocks[b as usize].words[c as usize] = word;
        }
    }
    if blocks.len() > groups + 1 || blocks.len() as u64 * BLOCK_WORDS as u64 > node::MAX_PTR as u64
    {
        // Shared groups, or too many internal nodes for block pointers: the view's pool as it
        // is, leaf words rewritten, read as plain words (no slabs).
        let mut flat = vec![zero; view.nodes.len().div_ceil(BLOCK_WORDS as usize)];
        let words: &mut [u32] = bytemuck::cast_slice_mut(&mut flat);
        for (to, &w) in words.iter_mut().zip(view.nodes) {
            *to = if node::is_leaf(w) { leaf(w) } else { w };
        }
        return (flat, false);
    }
    // The normals' sum and the disk count below each block, children before parents (reverse
    // depth-first order): where the normals nearly agree, the node is worth a slab.
    let run = |l: &Leaf| &chunks[l.first as usize..l.end as usize];
    let leaf_sums: Vec<(glam::Vec3, u32)> = leaves
        .par_iter()
        .map(|l| {
            let disks = run(l).iter().flat_map(lane_disks);
            disks.fold((glam::Vec3::ZERO, 0), |(s, n), d| {
                (s + glam::Vec3::from(d.1), n + 1)
            })
        })
        .collect();
    let mut sums = vec![(glam::Vec3::ZERO, 0u32); blocks.len()];
    for &b in order.iter().rev() {
        for &w in &blocks[b as usize].words {
            let (s, n) = match (node::is_leaf(w), node::is_empty(w)) {
                (true, _) => leaf_sums[node::ptr(w) as usize],
                (_, true) => continue,
                _ => sums[(node::ptr(w) / BLOCK_WORDS) as usize],
            };
            sums[b as usize].0 += s;
            sums[b as usize].1 += n;
        }
    }
    // A block whose one non-empty child is internal holds exactly that child's disks, and so
    // its slab: along such chains (deep in a scan's tree) it is computed once.
    let only: Vec<Option<usize>> = blocks
        .iter()
        .enumerate()
        .map(|(b, block)| {
            let mut kids = block.words.iter().filter(|&&w| !node::is_empty(w));
            match (b, kids.next(), kids.next()) {
                (1.., Some(&w), None) if !node::is_leaf(w) => {
                    Some((node::ptr(w) / BLOCK_WORDS) as usize)
                }
                _ => None,
            }
        })
        .collect();
    // Each other candidate's slab over every disk listed in the leaves below it (the leaves'
    // table order need not follow the tree's near cell borders, so they are gathered by the
    // tree).
    let all: &[u32] = bytemuck::cast_slice(&blocks);
    let mut slabs: Vec<Option<Slab>> = (0..blocks.len())
        .into_par_iter()
        .map(|b| {
            let (sum, n) = sums[b];
            let aligned = sum.length() >= ALIGNED * n as f32;
            if b == 0 || n == 0 || n > MAX_SLAB_DISKS || !aligned || only[b].is_some() {
                return None;
            }
            let mut below = Vec::new();
            let mut stack = vec![node::internal(b as u32 * BLOCK_WORDS)];
            while let Some(w) = stack.pop() {
                for &c in &all[node::ptr(w) as usize..node::ptr(w) as usize + 8] {
                    match (node::is_leaf(c), node::is_empty(c)) {
                        (true, _) => below.push(node::ptr(c)),
                        (_, true) => {}
                        _ => stack.push(c),
                    }
                }
            }
            let chunks = below.iter().flat_map(|&l| run(&leaves[l as usize]));
            Some(slab_about_chunks(sum.normalize(), chunks))
        })
        .collect();
    for &b in order.iter().rev() {
        if let Some(c) = only[b as usize] {
            slabs[b as usize] = slabs[c];
        }
    }
    // Kept where thin for the node's own cell.
    let size = view.frame.size;
    for ((block, s), &(_, depth)) in blocks.iter_mut().zip(slabs).zip(&info) {
        let cell = size * 0.5f32.powi(depth.min(64) as i32);
        if let Some(s) = s.filter(|s| s.hi - s.lo < THIN * cell) {
            let [ax, ay, az] = s.axis;
            block.slab = [ax, ay, az, s.lo, s.hi].map(f32::to_bits);
            block.has_slab = 1;
        }
    }
    (blocks, true)
}

#[cfg(test)]
mod tests {
    use super::super::lanes::tests::cases;
    use super::super::PAD;
    use super::*;

    /// The node slabs' extents of chunks about a direction, four lanes at a time, are the
    /// scalar ones bit for bit (the random chunks and rays of the lanes' test).
    #[test]
    fn simd_extents_match_scalar_extents() {
        for (k, c, _, d, _, _) in cases() {
            let axis = glam::Vec3::from(d);
            if axis != glam::Vec3::ZERO {
                let (simd, scalar) = (
                    chunk_extent(axis, [c, PAD, c].iter()),
                    chunk_extent_scalar(axis, [c, PAD, c].iter()),
                );
                let bits = |e: Extent| [e.lo, e.hi, e.r_max, e.size].map(f32::to_bits);
                assert_eq!(bits(simd), bits(scalar), "case {k}");
            }
        }
    }
}
