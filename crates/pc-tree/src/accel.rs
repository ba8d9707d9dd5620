//! A copy of the octree laid out for the CPU walk: the same cells, the same listed disks in the
//! same order, the same arithmetic, so the hits are identical to [`crate::intersect`]'s
//! (tested); only where the bytes lie changes. pc-octree builds it ([`Accel::build`]) and writes
//! it into the octree artifact ([`pc_artifact::walk`]); the other stages map it
//! ([`Accel::new`]), and build their own only from an octree without it.
//!
//! The artifact's walk is bound by dependent cache misses, not arithmetic (perf on 1M splats:
//! the node descent's loads, the begin/end table's, then the first splat record of each leaf).
//! Four changes:
//! - **Leaf words point at their records.** A copy of the node pool whose leaf words hold a
//!   leaf number instead of a begin/end offset; the leaf's record (32 bytes: its run of chunks
//!   and its slab) replaces the begin/end table and a start table, two dependent misses.
//! - **A slab per leaf.** The listed disks of a leaf on a surface lie in a thin slab about
//!   their mean normal. A ray whose stretch through the cell misses the slab skips the leaf's
//!   tests: a bounce ray leaving a wall crosses its own and the next cells of that wall above
//!   the slab, a primary ray the cells it passes in front of a surface.
//! - **Structure of arrays, 4 disks per chunk.** A leaf's listed disks (own, then referenced,
//!   the table's order) are packed into chunks of [`LANES`]: centres, normals and squared
//!   radii as separate lanes (28 bytes a disk, not the artifact's 64), so one chunk's tests are
//!   SIMD arithmetic and a leaf's run streams through consecutive cache lines. The last chunk of
//!   a run is padded with disks that cannot be hit (zero normal, negative radius²).
//! - **Cold data apart.** The data-pool index is read only for a disk the ray crosses inside its
//!   radius, and the border clip from the disk's own record through it (a copy per listing cost
//!   16 bytes a lane: 1 GB of a 20M-point scan's V-map).
//!
//! This file holds the copy and its walk; `accel/build.rs` builds it (the leaves' runs and
//! slabs, the nodes' blocks and slabs), `accel/lanes.rs` holds the per-chunk SIMD arithmetic
//! with its portable twins.
//!
//! Memory: about 32 bytes per listed disk plus padding (3 listings per splat on scans; 136
//! bytes a splat at the 100M-point scan), mapped page cache when read from the artifact.

use std::borrow::Cow;

use pc_artifact::octree::{node, within_clip, Splat};
use pc_artifact::walk::{
    is_clipped, WalkBlock, WalkChunk, WalkLeaf, WalkView, BLOCK_WORDS, PADDING,
};
use rayon::prelude::*;

use crate::between::{Between, Own, OWN_COS};
use crate::ray::{Hit, Ray, Slab, TraversalStats};
use crate::OctreeView;

mod build;
mod lanes;

use lanes::{cover_lanes, cover_lanes8, has_avx2, lanes, lanes8, prefetch};

/// Disks per chunk.
pub use pc_artifact::walk::LANES;

/// [`LANES`] listed disks: centre, normal, squared radius, lane by lane, and their data-pool
/// indices (the artifact's record, so a mapped walk is read in place).
type Chunk = WalkChunk;

/// A lane that no ray hits: its normal is zero, so every ray counts as parallel to it.
const PAD: Chunk = Chunk {
    px: [0.0; LANES],
    py: [0.0; LANES],
    pz: [0.0; LANES],
    nx: [0.0; LANES],
    ny: [0.0; LANES],
    nz: [0.0; LANES],
    r2: [-1.0; LANES],
    cold: [PADDING; LANES],
};

/// What a leaf's test looks for: the nearest hit, or any hit (passing over those a [`Between`]
/// ignores).
#[derive(Clone, Copy)]
enum Find<'a> {
    Nearest(Option<&'a Between>),
    Any(Option<&'a Between>),
}

/// One leaf: its run of chunks, the view's node word, and the slab its listed disks lie in
/// (axis xyz, lo, hi: [`Slab::to_array`]).
type Leaf = WalkLeaf;

/// One internal node's eight child words and the slab of every disk listed below it: one cache
/// line, so the walk reads the slab with the words it reads anyway. Block 0 holds the root
/// word alone.
type Block = WalkBlock;

/// Words of a node-pool slot's slab for the GPU ([`Accel::pool_slabs`]).
pub const POOL_SLAB_WORDS: usize = 6;

/// A leaf's number in an [`Accel`] (its packed lists), as [`Accel::intersect_in`] reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PackedLeaf(u32);

/// The packed copy of an octree for the CPU walk: mapped from the artifact where pc-octree
/// wrote it ([`pc_artifact::walk`]), else built in memory.
pub struct Accel<'a> {
    /// The view's tree in [`Block`]s: leaf words hold their leaf number (SFC order), internal
    /// words the first word of their children's block.
    nodes: Cow<'a, [Block]>,
    /// Whether the blocks hold slabs (else `nodes` is the view's pool word for word).
    slabs: bool,
    leaves: Cow<'a, [Leaf]>,
    chunks: Cow<'a, [Chunk]>,
    /// A bit per data-pool splat, set where it has a border clip
    /// ([`pc_artifact::walk::clipped_bits`]). A hit reads the splat's record only for a flagged
    /// splat (or for a segment's test of its material near an end): on the 1M box the records'
    /// cache misses were a fifth of an incoherent ray's time.
    clipped: Cow<'a, [u64]>,
    /// Each leaf's disks as one surface, where asked for ([`Accel::with_own_surfaces`]).
    surfaces: Option<Vec<LeafSurface>>,
    /// Whether the walk tests two chunks at a time with AVX2 ([`lanes8`]; [`has_avx2`]).
    wide: bool,
}

/// One packed leaf's disks as a surface: their mean normal, the least cosine of any of their
/// normals to it, and their material (`u32::MAX` where they mix materials, or none).
#[derive(Clone, Copy, Debug, PartialEq)]
struct LeafSurface {
    axis: [f32; 3],
    cos: f32,
    material: u32,
}

impl LeafSurface {
    const NONE: LeafSurface = LeafSurface {
        axis: [0.0; 3],
        cos: -1.0,
        material: u32::MAX,
    };

    /// The disks of chunks `run` (their lanes' normals, and through their indices their
    /// records).
    fn of(chunks: &[Chunk], run: std::ops::Range<usize>, splats: &[Splat]) -> Self {
        let lanes = || {
            run.clone().flat_map(move |ci| {
                (0..LANES).filter_map(move |l| {
                    let c = &chunks[ci];
                    (c.cold[l] != PADDING)
                        .then(|| (glam::Vec3::new(c.nx[l], c.ny[l], c.nz[l]), c.cold[l]))
                })
            })
        };
        let Some((_, first)) = lanes().next() else {
            return Self::NONE;
        };
        let material = splats[first as usize].material;
        if lanes().any(|(_, s)| splats[s as usize].material != material) {
            return Self::NONE;
        }
        let axis = lanes()
            .map(|(n, _)| n)
            .sum::<glam::Vec3>()
            .normalize_or_zero();
        let cos = lanes().map(|(n, _)| n.dot(axis)).fold(1.0f32, f32::min);
        match axis == glam::Vec3::ZERO {
            true => Self::NONE,
            false => LeafSurface {
                axis: axis.into(),
                cos,
                material,
            },
        }
    }

    /// Whether every disk of the leaf is `own`'s surface ([`Own::is`]): its normals lie within
    /// the cone of half-angle `acos cos` about `axis`, so each is within that angle plus the
    /// axis's angle to `own.normal`; the margin keeps the bound below any normal's own
    /// rounded cosine.
    fn all_own(&self, own: &Own) -> bool {
        const MARGIN: f32 = 1e-4;
        let cb = glam::Vec3::from(self.axis).dot(own.normal);
        if self.material == u32::MAX
            || self.material != own.material
            || cb <= 0.0
            || self.cos <= 0.0
        {
            return false;
        }
        let (ca, sa, sb) = (
            self.cos,
            (1.0 - self.cos * self.cos).max(0.0).sqrt(),
            (1.0 - cb * cb).max(0.0).sqrt(),
        );
        ca * cb - sa * sb > OWN_COS + MARGIN
    }
}

impl<'a> Accel<'a> {
    /// The walk of `view`: its artifact's packed walk where it has one (checked when the
    /// artifact was opened), else a copy built now.
    pub fn new(view: &OctreeView<'a>) -> Accel<'a> {
        match view.walk {
            Some(w) => Accel {
                nodes: Cow::Borrowed(w.blocks),
                slabs: w.slabs,
                leaves: Cow::Borrowed(w.leaves),
                chunks: Cow::Borrowed(w.chunks),
                clipped: Cow::Borrowed(w.clipped),
                surfaces: None,
                wide: has_avx2(),
            },
            None => Accel::build(view),
        }
    }

    /// This walk without its AVX2 build: every leaf tested a chunk at a time with SSE (the
    /// same hits bit for bit; for tests and comparisons).
    pub fn portable(mut self) -> Accel<'a> {
        self.wide = false;
        self
    }

    /// Whether this walk is the artifact's, mapped (not built in memory).
    pub fn is_mapped(&self) -> bool {
        matches!(self.chunks, Cow::Borrowed(_))
    }

    /// The sections pc-octree writes ([`pc_artifact::walk::write`]).
    pub fn walk(&self) -> WalkView<'_> {
        WalkView {
            slabs: self.slabs,
            blocks: &self.nodes,
            leaves: &self.leaves,
            chunks: &self.chunks,
            clipped: &self.clipped,
        }
    }

    /// This walk, passing whole over a leaf that the stretch of a segment's ray through it
    /// leaves within the first end's own zone and whose disks are all that end's own surface
    /// ([`Own::is`]): every hit there is one [`Between::ignores`] would pass over, one disk at
    /// a time. Costs 20 bytes a leaf and one pass over the disks.
    pub fn with_own_surfaces(mut self, view: &OctreeView) -> Accel<'a> {
        let chunks = &self.chunks[..];
        let surfaces = self
            .leaves
            .par_iter()
            .map(|leaf| {
                let run = leaf.first as usize..leaf.end as usize;
                LeafSurface::of(chunks, run, view.splats)
            })
            .collect();
        self.surfaces = Some(surfaces);
        self
    }

    /// This walk's slabs by the view's node-pool slot, for the GPU's walk of the pool
    /// (`trace_between`, shaders/common/traverse.wgsl), which skips and jumps by them as
    /// [`crate::ray::walk_with`] does: per slot the slab's axis xyz, lo and hi as bits and a flag,
    /// 1 where the walk tests it (an internal node with a slab; a leaf whose slab is finite:
    /// the shader has no infinities), else 0 (an empty node, or one it never skips).
    pub fn pool_slabs(&self, view: &OctreeView) -> Vec<[u32; POOL_SLAB_WORDS]> {
        let words: &[u32] = bytemuck::cast_slice(&self.nodes[..]);
        let mut out = vec![[0u32; POOL_SLAB_WORDS]; view.nodes.len()];
        let with_flag = |s: [f32; 5]| {
            let [x, y, z, lo, hi] = s.map(f32::to_bits);
            [x, y, z, lo, hi, 1]
        };
        // (pool slot, the walk's word for the same node): the walk's children of an internal
        // word lie at its pointer, in the pool's order, blocks or plain words alike. Where a
        // file's walk does not follow its pool (a word of another kind, or out of bounds), the
        // slots below keep no slab: the GPU then walks them cell by cell.
        let internal = |w: u32| w & (node::LEAF | node::EMPTY) == 0;
        let mut stack: Vec<(usize, u32)> = words.first().map(|&w| (0, w)).into_iter().collect();
        while let Some((slot, walk_word)) = stack.pop() {
            let word = view.nodes[slot];
            if node::is_leaf(word) && node::is_leaf(walk_word) {
                if let Some(leaf) = self.leaves.get(node::ptr(walk_word) as usize) {
                    if leaf.slab.iter().all(|x| x.is_finite()) {
                        out[slot] = with_flag(leaf.slab);
                    }
                }
            } else if internal(word) && internal(walk_word) {
                let (pool, walk) = (node::ptr(word) as usize, node::ptr(walk_word) as usize);
                let span = if self.slabs { BLOCK_WORDS as usize } else { 8 };
                if walk + span > words.len() {
                    continue;
                }
                if let Some(s) = self.slabs.then(|| node_slab(words, walk_word)).flatten() {
                    out[slot] = with_flag(s.to_array());
                }
                stack.extend((0..8).map(|c| (pool + c, words[walk + c])));
            }
        }
        out
    }

    /// Bytes held.
    pub fn memory(&self) -> usize {
        self.chunks.len() * std::mem::size_of::<Chunk>()
            + self.clipped.len() * std::mem::size_of::<u64>()
            + self.leaves.len() * std::mem::size_of::<Leaf>()
            + self.nodes.len() * std::mem::size_of::<Block>()
    }

    /// The nearest hit in `[ray.t_min, limit]` among the leaf's listed disks (`Find::Any`: the
    /// first found), the disks' records read from `splats`, passing over those `between`
    /// ignores (`Find::Nearest(Some(_))`, `Find::Any(Some(_))`). The arithmetic is
    /// [`crate::ray::intersect_splat`]'s, operation for operation, lane by lane; lanes are taken
    /// in listing order, so ties resolve as there.
    ///
    /// `WIDE` tests two chunks at a time with [`lanes8`] (the same lanes, the same results):
    /// only [`Self::cast_wide`], which runs where the CPU has AVX2, instantiates it.
    #[inline(always)]
    fn test<const WIDE: bool>(
        &self,
        ray: &Ray,
        w: u32,
        limit: f32,
        (splats, find): (&[pc_artifact::octree::Splat], Find),
        stats: &mut TraversalStats,
    ) -> Option<Hit> {
        let (any, between) = match find {
            Find::Nearest(between) => (false, between),
            Find::Any(between) => (true, between),
        };
        let leaf = &self.leaves[node::ptr(w) as usize];
        // No disk can be hit outside the leaf's slab.
        if Slab::from_array(leaf.slab).misses(ray, limit) {
            return None;
        }
        // Nor one that is not passed over, where the ray leaves the leaf within its origin's own
        // zone and every disk is the origin's own surface.
        if let (Some(b), Some(surfaces)) = (between, &self.surfaces) {
            if limit < b.zones[0] && surfaces[node::ptr(w) as usize].all_own(&b.ends[0]) {
                return None;
            }
        }
        // A hit's material, for a segment's test near one of its ends: the one material of
        // all the leaf's disks where it has one (20 bytes a leaf), else the splat's record.
        let material = |splat: u32| {
            let surface = self.surfaces.as_ref().map(|s| &s[node::ptr(w) as usize]);
            match surface.map_or(u32::MAX, |s| s.material) {
                u32::MAX => splats[splat as usize].material,
                one => one,
            }
        };
        let ([ox, oy, oz], [dx, dy, dz]) = (ray.origin.to_array(), ray.dir.to_array());
        let (a, b) = (leaf.first as usize, leaf.end as usize);
        stats.splat_tests += ((b - a) * LANES) as u64;
        let mut best: Option<Hit> = None;
        let (o, d) = ([ox, oy, oz], [dx, dy, dz]);
        let mut run = &self.chunks[a..b];
        while !run.is_empty() {
            // A group of one chunk, or of two where `WIDE`: lane k of the group is lane
            // k % LANES of its chunk k / LANES.
            let (group, t, mut candidates) = match run {
                [c0, c1, ..] if WIDE => {
                    // SAFETY: `WIDE` is instantiated only by `cast_wide`, which runs only
                    // where the CPU has AVX2 (`self.wide`, from `has_avx2`).
                    let (t, m) = unsafe { lanes8(c0, c1, o, d, ray.t_min, limit) };
                    (&run[..2], t, m)
                }
                [c, ..] => {
                    let (t4, m) = lanes(c, o, d, ray.t_min, limit);
                    let mut t = [0.0; 2 * LANES];
                    t[..LANES].copy_from_slice(&t4);
                    (&run[..1], t, m)
                }
                [] => unreachable!(),
            };
            run = &run[group.len()..];
            while candidates != 0 {
                let k = candidates.trailing_zeros() as usize;
                candidates &= candidates - 1;
                if best.is_some_and(|h| t[k] >= h.t) {
                    continue;
                }
                let (c, l) = (&group[k / LANES], k % LANES);
                let splat = c.cold[l];
                let (p, n) = ([c.px[l], c.py[l], c.pz[l]], [c.nx[l], c.ny[l], c.nz[l]]);
                if let Some(b) = between {
                    if b.ignores_with(t[k], n, || material(splat)) {
                        continue;
                    }
                }
                let x = [ox + dx * t[k], oy + dy * t[k], oz + dz * t[k]];
                if !is_clipped(&self.clipped, splat)
                    || within_clip(p, n, splats[splat as usize].clip, x)
                {
                    best = Some(Hit {
                        t: t[k],
                        splat,
                        leaf: leaf.word,
                    });
                    if any {
                        return best;
                    }
                    // The caller reads the hit's record next (its material, radius, colour),
                    // which the walk does not: fetch it while the rest of the leaf is tested.
                    prefetch(&splats[splat as usize]);
                }
            }
        }
        best
    }

    /// Same as [`crate::intersect`].
    pub fn intersect(
        &self,
        view: &OctreeView,
        ray: &Ray,
        stats: &mut TraversalStats,
    ) -> Option<Hit> {
        self.intersect_in(view, ray, stats).map(|(hit, _)| hit)
    }

    /// [`Self::intersect`], with the packed number of the leaf the hit was found in (for
    /// [`Self::covering`]).
    pub fn intersect_in(
        &self,
        view: &OctreeView,
        ray: &Ray,
        stats: &mut TraversalStats,
    ) -> Option<(Hit, PackedLeaf)> {
        self.cast(view, ray, Find::Nearest(None), stats)
    }

    /// The nearest hit along `seg.ray` that [`Between::ignores`] does not pass over: a ray
    /// leaving a rough surface ([`Between::leaving`]) finds the first other surface, not the
    /// noise of its own. WGSL twin: `trace_between` with `any_hit` false,
    /// shaders/common/traverse.wgsl.
    pub fn intersect_between(
        &self,
        view: &OctreeView,
        seg: &Between,
        stats: &mut TraversalStats,
    ) -> Option<Hit> {
        self.cast(view, &seg.ray, Find::Nearest(Some(seg)), stats)
            .map(|(hit, _)| hit)
    }

    /// Same as [`crate::covering`] for the leaf the hit was found in, read from the packed
    /// lanes the walk has just streamed through (the artifact's records of the referenced
    /// disks lie all over the data pool): the same disks in the same order with the same
    /// weights, bit for bit. Only a disk that passes the cheap tests reads its record (for the
    /// radius itself; the lanes hold its square).
    pub fn covering(
        &self,
        view: &OctreeView,
        leaf: PackedLeaf,
        x: glam::Vec3,
        n: glam::Vec3,
        thickness: f32,
        out: &mut Vec<(u32, f32)>,
    ) {
        if self.wide {
            // SAFETY: `self.wide` is set only where the CPU has AVX2 (`has_avx2`).
            return unsafe { self.covering_wide(view, leaf, x, n, thickness, out) };
        }
        self.covering_in::<false>(view, leaf, x, n, thickness, out)
    }

    /// [`Self::covering`] built for AVX2, two chunks at a time ([`cover_lanes8`]).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
    unsafe fn covering_wide(
        &self,
        view: &OctreeView,
        leaf: PackedLeaf,
        x: glam::Vec3,
        n: glam::Vec3,
        thickness: f32,
        out: &mut Vec<(u32, f32)>,
    ) {
        self.covering_in::<true>(view, leaf, x, n, thickness, out)
    }

    /// [`Self::covering`]'s loop, two chunks at a time where `WIDE` (instantiated only by
    /// [`Self::covering_wide`]).
    #[inline(always)]
    fn covering_in<const WIDE: bool>(
        &self,
        view: &OctreeView,
        leaf: PackedLeaf,
        x: glam::Vec3,
        n: glam::Vec3,
        thickness: f32,
        out: &mut Vec<(u32, f32)>,
    ) {
        out.clear();
        let leaf = &self.leaves[leaf.0 as usize];
        let (a, b) = (leaf.first as usize, leaf.end as usize);
        let (xa, na) = (x.to_array(), n.to_array());
        let mut run = &self.chunks[a..b];
        while !run.is_empty() {
            // A group of one chunk, or of two where `WIDE`, as in `test`.
            let (group, (h, rho2, mut inside)) = match run {
                // SAFETY: `WIDE` is instantiated only by `covering_wide`, which runs only
                // where the CPU has AVX2.
                [c0, c1, ..] if WIDE => (&run[..2], unsafe { cover_lanes8(c0, c1, xa, na) }),
                [c, ..] => {
                    let (h4, rho4, m) = cover_lanes(c, xa, na);
                    let (mut h, mut rho2) = ([0.0; 2 * LANES], [0.0; 2 * LANES]);
                    h[..LANES].copy_from_slice(&h4);
                    rho2[..LANES].copy_from_slice(&rho4);
                    (&run[..1], (h, rho2, m))
                }
                [] => unreachable!(),
            };
            run = &run[group.len()..];
            while inside != 0 {
                let k = inside.trailing_zeros() as usize;
                inside &= inside - 1;
                let (c, l) = (&group[k / LANES], k % LANES);
                let splat = c.cold[l];
                let record = &view.splats[splat as usize];
                let (p, sn) = (
                    glam::Vec3::new(c.px[l], c.py[l], c.pz[l]),
                    glam::Vec3::new(c.nx[l], c.ny[l], c.nz[l]),
                );
                if h[k].abs() <= thickness * record.radius
                    && within_clip(p.into(), sn.into(), record.clip, (x - sn * h[k]).into())
                {
                    let u = 1.0 - rho2[k] / c.r2[l];
                    out.push((splat, u * u));
                }
            }
        }
    }

    /// Visibility of many rays (rayon across rays): `true` where nothing blocks the ray.
    pub fn visible(&self, view: &OctreeView, rays: &[Ray]) -> Vec<bool> {
        rays.par_iter()
            .map_init(TraversalStats::default, |st, r| !self.occluded(view, r, st))
            .collect()
    }

    /// Same as [`crate::occluded`].
    pub fn occluded(&self, view: &OctreeView, ray: &Ray, stats: &mut TraversalStats) -> bool {
        self.walk_any(view, ray, None, stats)
    }

    /// Whether a disk blocks the segment, passing over those [`Between::ignores`]
    /// (unaccelerated twin: [`crate::ray::occluded_between`]).
    pub fn occluded_between(
        &self,
        view: &OctreeView,
        seg: &Between,
        stats: &mut TraversalStats,
    ) -> bool {
        self.walk_any(view, &seg.ray, Some(seg), stats)
    }

    /// Visibility of many segments between surfaces (rayon across segments): `true` where
    /// nothing but the ends' own surfaces lies between ([`Between::ignores`]).
    pub fn visible_between(&self, view: &OctreeView, segs: &[Between]) -> Vec<bool> {
        segs.par_iter()
            .map_init(TraversalStats::default, |st, s| {
                !self.walk_any(view, &s.ray, Some(s), st)
            })
            .collect()
    }

    /// Whether a disk blocks the ray, passing over those `between` ignores. WGSL twin:
    /// `trace_between`, shaders/common/traverse.wgsl.
    fn walk_any(
        &self,
        view: &OctreeView,
        ray: &Ray,
        between: Option<&Between>,
        stats: &mut TraversalStats,
    ) -> bool {
        self.cast(view, ray, Find::Any(between), stats).is_some()
    }

    /// The walk of `ray` through the packed tree, each leaf tested for what `find` asks: the
    /// hit, and the packed number of the leaf it was found in (the walk returns at the first
    /// leaf that gives a hit: the last leaf tested).
    fn cast(
        &self,
        view: &OctreeView,
        ray: &Ray,
        find: Find,
        stats: &mut TraversalStats,
    ) -> Option<(Hit, PackedLeaf)> {
        if self.wide && matches!(find, Find::Nearest(_)) {
            // SAFETY: `self.wide` is set only where the CPU has AVX2 (`has_avx2`).
            return unsafe { self.cast_wide(view, ray, find, stats) };
        }
        self.cast_in::<false>(view, ray, find, stats)
    }

    /// [`Self::cast`] built for AVX2, its leaves tested two chunks at a time ([`lanes8`]).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
    unsafe fn cast_wide(
        &self,
        view: &OctreeView,
        ray: &Ray,
        find: Find,
        stats: &mut TraversalStats,
    ) -> Option<(Hit, PackedLeaf)> {
        self.cast_in::<true>(view, ray, find, stats)
    }

    /// [`Self::cast`]'s walk, its leaves tested by [`Self::test`]`::<WIDE>`.
    #[inline(always)]
    fn cast_in<const WIDE: bool>(
        &self,
        view: &OctreeView,
        ray: &Ray,
        find: Find,
        stats: &mut TraversalStats,
    ) -> Option<(Hit, PackedLeaf)> {
        let nodes: &[u32] = bytemuck::cast_slice(&self.nodes[..]);
        let slab = |w| match self.slabs {
            true => node_slab(nodes, w),
            false => None,
        };
        let mut leaf = PackedLeaf(0);
        let hit = crate::ray::walk_with(view, nodes, ray, stats, slab, |w, limit, st| {
            leaf = PackedLeaf(node::ptr(w));
            self.test::<WIDE>(ray, w, limit, (view.splats, find), st)
        })?;
        Some((hit, leaf))
    }
}

/// The slab of an internal word's block, where it has one worth testing.
#[inline(always)]
fn node_slab(nodes: &[u32], w: u32) -> Option<Slab> {
    let b = node::ptr(w) as usize;
    let f = |k: usize| f32::from_bits(nodes[b + 8 + k]);
    (nodes[b + 13] != 0).then(|| Slab {
        axis: [f(0), f(1), f(2)],
        lo: f(3),
        hi: f(4),
    })
}
