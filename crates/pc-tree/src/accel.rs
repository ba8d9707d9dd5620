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
//! Memory: about 32 bytes per listed disk plus padding (3 listings per splat on scans; 136
//! bytes a splat at the 100M-point scan), mapped page cache when read from the artifact.

use std::borrow::Cow;

use pc_artifact::octree::{node, within_clip, BeginEnd, Splat};
use pc_artifact::walk::{
    clipped_bits, is_clipped, WalkBlock, WalkChunk, WalkLeaf, WalkView, BLOCK_WORDS, PADDING,
};
use rayon::prelude::*;

use crate::between::{Between, Own, OWN_COS};
use crate::ray::{Hit, Ray, Slab, TraversalStats};
use crate::OctreeView;

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

/// Asks the cache for the line holding `x` (a hint: no effect on any result).
#[inline(always)]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of the x86-64 baseline; a prefetch reads nothing the program sees
    // and cannot fault, and the pointer comes from a reference.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((x as *const T).cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// One chunk's ray-disk tests: each lane's plane distance `t` and the mask of lanes hit inside
/// their radius within `[t_min, limit]` (the border clip is left to the caller). The
/// arithmetic is [`crate::ray::intersect_splat`]'s, operation for operation (no fused
/// multiply-add), so `t` is bit for bit the scalar one. SSE on x86-64 (part of its baseline);
/// [`lanes_scalar`] elsewhere and in the test that holds the two together.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn lanes(c: &Chunk, o: [f32; 3], d: [f32; 3], t_min: f32, limit: f32) -> ([f32; LANES], u32) {
    use std::arch::x86_64::*;
    // SAFETY: SSE is part of the x86-64 baseline, so every intrinsic here is available; the
    // loads read `[f32; 4]` fields of a `#[repr(C, align(16))]` struct whose fields are all
    // 16 bytes, so each is 16-byte aligned, and the store writes a local `[f32; 4]`.
    unsafe {
        let (add, sub, mul) = (_mm_add_ps, _mm_sub_ps, _mm_mul_ps);
        let ld = |a: &[f32; LANES]| _mm_load_ps(a.as_ptr());
        let (nx, ny, nz) = (ld(&c.nx), ld(&c.ny), ld(&c.nz));
        let (px, py, pz) = (ld(&c.px), ld(&c.py), ld(&c.pz));
        let (ox, oy, oz) = (_mm_set1_ps(o[0]), _mm_set1_ps(o[1]), _mm_set1_ps(o[2]));
        let (dx, dy, dz) = (_mm_set1_ps(d[0]), _mm_set1_ps(d[1]), _mm_set1_ps(d[2]));
        let denom = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
        let num = add(
            add(mul(sub(px, ox), nx), mul(sub(py, oy), ny)),
            mul(sub(pz, oz), nz),
        );
        let th = _mm_div_ps(num, denom);
        let ex = sub(add(ox, mul(dx, th)), px);
        let ey = sub(add(oy, mul(dy, th)), py);
        let ez = sub(add(oz, mul(dz, th)), pz);
        let d2 = add(add(mul(ex, ex), mul(ey, ey)), mul(ez, ez));
        let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), denom);
        let ok = _mm_and_ps(
            _mm_and_ps(
                _mm_cmpge_ps(abs, _mm_set1_ps(1e-8)),
                _mm_cmpge_ps(th, _mm_set1_ps(t_min)),
            ),
            _mm_and_ps(
                _mm_cmple_ps(th, _mm_set1_ps(limit)),
                _mm_cmple_ps(d2, ld(&c.r2)),
            ),
        );
        let mut t = [0.0f32; LANES];
        _mm_storeu_ps(t.as_mut_ptr(), th);
        (t, _mm_movemask_ps(ok) as u32)
    }
}

/// [`lanes`] of two chunks at once (lanes 0-3 the first's, 4-7 the second's) with AVX2's
/// eight-lane registers: the same operations in the same order on each lane, so `t` and the
/// mask are bit for bit two [`lanes`] calls' (`lanes8_are_two_lanes_calls`).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn lanes8(
    c0: &Chunk,
    c1: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; 2 * LANES], u32) {
    use std::arch::x86_64::*;
    let (add, sub, mul) = (_mm256_add_ps, _mm256_sub_ps, _mm256_mul_ps);
    // SAFETY (the loads): each field is a 16-byte-aligned `[f32; 4]` of a `#[repr(C,
    // align(16))]` struct whose fields are all 16 bytes.
    let ld = |a: &[f32; LANES], b: &[f32; LANES]| {
        _mm256_insertf128_ps::<1>(
            _mm256_castps128_ps256(_mm_load_ps(a.as_ptr())),
            _mm_load_ps(b.as_ptr()),
        )
    };
    let (nx, ny, nz) = (ld(&c0.nx, &c1.nx), ld(&c0.ny, &c1.ny), ld(&c0.nz, &c1.nz));
    let (px, py, pz) = (ld(&c0.px, &c1.px), ld(&c0.py, &c1.py), ld(&c0.pz, &c1.pz));
    let [ox, oy, oz] = o.map(|x| _mm256_set1_ps(x));
    let [dx, dy, dz] = d.map(|x| _mm256_set1_ps(x));
    let denom = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
    let num = add(
        add(mul(sub(px, ox), nx), mul(sub(py, oy), ny)),
        mul(sub(pz, oz), nz),
    );
    let th = _mm256_div_ps(num, denom);
    let ex = sub(add(ox, mul(dx, th)), px);
    let ey = sub(add(oy, mul(dy, th)), py);
    let ez = sub(add(oz, mul(dz, th)), pz);
    let d2 = add(add(mul(ex, ex), mul(ey, ey)), mul(ez, ez));
    let abs = _mm256_andnot_ps(_mm256_set1_ps(-0.0), denom);
    // Ordered comparisons (false on NaN), as SSE's cmpge/cmple.
    let ok = _mm256_and_ps(
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(abs, _mm256_set1_ps(1e-8)),
            _mm256_cmp_ps::<_CMP_GE_OQ>(th, _mm256_set1_ps(t_min)),
        ),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LE_OQ>(th, _mm256_set1_ps(limit)),
            _mm256_cmp_ps::<_CMP_LE_OQ>(d2, ld(&c0.r2, &c1.r2)),
        ),
    );
    let mut t = [0.0f32; 2 * LANES];
    _mm256_storeu_ps(t.as_mut_ptr(), th);
    (t, _mm256_movemask_ps(ok) as u32)
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn lanes8(
    c0: &Chunk,
    c1: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; 2 * LANES], u32) {
    let ((t0, m0), (t1, m1)) = (lanes(c0, o, d, t_min, limit), lanes(c1, o, d, t_min, limit));
    let mut t = [0.0f32; 2 * LANES];
    t[..LANES].copy_from_slice(&t0);
    t[LANES..].copy_from_slice(&t1);
    (t, m0 | m1 << LANES)
}

/// Whether this CPU runs the walk's AVX2 build ([`lanes8`]).
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn lanes(c: &Chunk, o: [f32; 3], d: [f32; 3], t_min: f32, limit: f32) -> ([f32; LANES], u32) {
    lanes_scalar(c, o, d, t_min, limit)
}

/// [`lanes`] one lane at a time.
#[allow(clippy::needless_range_loop)] // lane l of seven arrays
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn lanes_scalar(
    c: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; LANES], u32) {
    let ([ox, oy, oz], [dx, dy, dz]) = (o, d);
    let mut t = [0.0f32; LANES];
    let mut mask = 0u32;
    for l in 0..LANES {
        let denom = dx * c.nx[l] + dy * c.ny[l] + dz * c.nz[l];
        let th = ((c.px[l] - ox) * c.nx[l] + (c.py[l] - oy) * c.ny[l] + (c.pz[l] - oz) * c.nz[l])
            / denom;
        let (ex, ey, ez) = (
            ox + dx * th - c.px[l],
            oy + dy * th - c.py[l],
            oz + dz * th - c.pz[l],
        );
        let inside = ex * ex + ey * ey + ez * ez <= c.r2[l];
        let ok = denom.abs() >= 1e-8 && th >= t_min && th <= limit && inside;
        t[l] = th;
        mask |= (ok as u32) << l;
    }
    (t, mask)
}

/// One chunk's cover tests for [`Accel::covering`]: each lane's height `h` of the point `x`
/// over the disk's plane, its squared in-plane distance `ρ²`, and the mask of lanes that face
/// the normal `n` (`n_j · n > 0`) with `ρ² < r²` (padding lanes never: zero normal). The
/// arithmetic is [`crate::covering`]'s, operation for operation. SSE on x86-64;
/// [`cover_lanes_scalar`] elsewhere and in the test that holds the two together.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn cover_lanes(c: &Chunk, x: [f32; 3], n: [f32; 3]) -> ([f32; LANES], [f32; LANES], u32) {
    use std::arch::x86_64::*;
    // SAFETY: as in `lanes`: SSE is baseline on x86-64, the loads read 16-byte aligned
    // `[f32; 4]` fields of a `#[repr(C, align(16))]` struct, the stores write local arrays.
    unsafe {
        let (add, sub, mul) = (_mm_add_ps, _mm_sub_ps, _mm_mul_ps);
        let ld = |a: &[f32; LANES]| _mm_load_ps(a.as_ptr());
        let (nx, ny, nz) = (ld(&c.nx), ld(&c.ny), ld(&c.nz));
        let facing = add(
            add(mul(nx, _mm_set1_ps(n[0])), mul(ny, _mm_set1_ps(n[1]))),
            mul(nz, _mm_set1_ps(n[2])),
        );
        let dx = sub(_mm_set1_ps(x[0]), ld(&c.px));
        let dy = sub(_mm_set1_ps(x[1]), ld(&c.py));
        let dz = sub(_mm_set1_ps(x[2]), ld(&c.pz));
        let h = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
        let d2 = add(add(mul(dx, dx), mul(dy, dy)), mul(dz, dz));
        let rho2 = sub(d2, mul(h, h));
        let ok = _mm_and_ps(
            _mm_cmpgt_ps(facing, _mm_set1_ps(crate::ray::BLEND_MIN_COS)),
            _mm_cmplt_ps(rho2, ld(&c.r2)),
        );
        let (mut ho, mut ro) = ([0.0f32; LANES], [0.0f32; LANES]);
        _mm_storeu_ps(ho.as_mut_ptr(), h);
        _mm_storeu_ps(ro.as_mut_ptr(), rho2);
        (ho, ro, _mm_movemask_ps(ok) as u32)
    }
}

/// [`cover_lanes`] of two chunks at once with AVX2 (lanes 0-3 the first's, 4-7 the second's):
/// the same operations lane for lane, so bit for bit two [`cover_lanes`] calls.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn cover_lanes8(
    c0: &Chunk,
    c1: &Chunk,
    x: [f32; 3],
    n: [f32; 3],
) -> ([f32; 2 * LANES], [f32; 2 * LANES], u32) {
    use std::arch::x86_64::*;
    let (add, sub, mul) = (_mm256_add_ps, _mm256_sub_ps, _mm256_mul_ps);
    // SAFETY (the loads): as in `lanes8`.
    let ld = |a: &[f32; LANES], b: &[f32; LANES]| {
        _mm256_insertf128_ps::<1>(
            _mm256_castps128_ps256(_mm_load_ps(a.as_ptr())),
            _mm_load_ps(b.as_ptr()),
        )
    };
    let (nx, ny, nz) = (ld(&c0.nx, &c1.nx), ld(&c0.ny, &c1.ny), ld(&c0.nz, &c1.nz));
    let [sx, sy, sz] = n.map(|v| _mm256_set1_ps(v));
    let facing = add(add(mul(nx, sx), mul(ny, sy)), mul(nz, sz));
    let dx = sub(_mm256_set1_ps(x[0]), ld(&c0.px, &c1.px));
    let dy = sub(_mm256_set1_ps(x[1]), ld(&c0.py, &c1.py));
    let dz = sub(_mm256_set1_ps(x[2]), ld(&c0.pz, &c1.pz));
    let h = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
    let d2 = add(add(mul(dx, dx), mul(dy, dy)), mul(dz, dz));
    let rho2 = sub(d2, mul(h, h));
    // Ordered comparisons (false on NaN), as SSE's cmpgt/cmplt.
    let ok = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_GT_OQ>(facing, _mm256_set1_ps(crate::ray::BLEND_MIN_COS)),
        _mm256_cmp_ps::<_CMP_LT_OQ>(rho2, ld(&c0.r2, &c1.r2)),
    );
    let (mut ho, mut ro) = ([0.0f32; 2 * LANES], [0.0f32; 2 * LANES]);
    _mm256_storeu_ps(ho.as_mut_ptr(), h);
    _mm256_storeu_ps(ro.as_mut_ptr(), rho2);
    (ho, ro, _mm256_movemask_ps(ok) as u32)
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn cover_lanes8(
    c0: &Chunk,
    c1: &Chunk,
    x: [f32; 3],
    n: [f32; 3],
) -> ([f32; 2 * LANES], [f32; 2 * LANES], u32) {
    let ((h0, r0, m0), (h1, r1, m1)) = (cover_lanes(c0, x, n), cover_lanes(c1, x, n));
    let (mut h, mut rho2) = ([0.0f32; 2 * LANES], [0.0f32; 2 * LANES]);
    (
        h[..LANES].copy_from_slice(&h0),
        h[LANES..].copy_from_slice(&h1),
    );
    (
        rho2[..LANES].copy_from_slice(&r0),
        rho2[LANES..].copy_from_slice(&r1),
    );
    (h, rho2, m0 | m1 << LANES)
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn cover_lanes(c: &Chunk, x: [f32; 3], n: [f32; 3]) -> ([f32; LANES], [f32; LANES], u32) {
    cover_lanes_scalar(c, x, n)
}

/// [`cover_lanes`] one lane at a time, with glam as [`crate::covering`] computes it.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn cover_lanes_scalar(c: &Chunk, x: [f32; 3], n: [f32; 3]) -> ([f32; LANES], [f32; LANES], u32) {
    let (x, n) = (glam::Vec3::from(x), glam::Vec3::from(n));
    let (mut h, mut rho2, mut mask) = ([0.0f32; LANES], [0.0f32; LANES], 0u32);
    for l in 0..LANES {
        let sn = glam::Vec3::new(c.nx[l], c.ny[l], c.nz[l]);
        let d = x - glam::Vec3::new(c.px[l], c.py[l], c.pz[l]);
        h[l] = d.dot(sn);
        rho2[l] = d.length_squared() - h[l] * h[l];
        let ok = sn.dot(n) > crate::ray::BLEND_MIN_COS && rho2[l] < c.r2[l];
        mask |= (ok as u32) << l;
    }
    (h, rho2, mask)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SSE lanes and the scalar ones agree bit for bit, and AVX2's eight lanes with two SSE
    /// calls where the CPU has AVX2, on random disks and rays including
    /// parallel rays, padding lanes and ties at the interval's ends (the cover lanes on the
    /// same disks, the ray's origin and direction standing for a point and a normal; the node
    /// slabs' extents about the ray's direction).
    #[test]
    fn simd_lanes_match_scalar_lanes() {
        let mut seed = 12345u32;
        let mut rnd = || {
            seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
        };
        for k in 0..20_000 {
            let mut c = PAD;
            for l in 0..LANES - (k % 2) {
                [c.px[l], c.py[l], c.pz[l]] = [rnd(), rnd(), rnd()];
                let n = glam::Vec3::new(rnd(), rnd(), rnd()).normalize_or_zero();
                [c.nx[l], c.ny[l], c.nz[l]] = n.to_array();
                c.r2[l] = 0.5 * rnd().abs();
            }
            let o = [rnd(), rnd(), rnd()];
            let mut d = glam::Vec3::new(rnd(), rnd(), rnd())
                .normalize_or_zero()
                .to_array();
            if k % 7 == 0 {
                d = [c.nz[0], 0.0, -c.nx[0]]; // parallel to lane 0's plane
            }
            let (t_min, limit) = (0.1 * rnd().abs(), 2.0 * rnd().abs());
            let (ch, cr, cm) = cover_lanes(&c, o, d);
            let (sh, sr, sm) = cover_lanes_scalar(&c, o, d);
            assert_eq!(cm, sm, "case {k}");
            for l in 0..LANES {
                assert_eq!(ch[l].to_bits(), sh[l].to_bits(), "case {k} lane {l}");
                assert_eq!(cr[l].to_bits(), sr[l].to_bits(), "case {k} lane {l}");
            }
            let axis = glam::Vec3::from(d);
            if axis != glam::Vec3::ZERO {
                let (simd, scalar) = (
                    chunk_extent(axis, [c, PAD, c].iter()),
                    chunk_extent_scalar(axis, [c, PAD, c].iter()),
                );
                let bits = |e: Extent| [e.lo, e.hi, e.r_max, e.size].map(f32::to_bits);
                assert_eq!(bits(simd), bits(scalar), "case {k}");
            }
            let (a, ma) = lanes(&c, o, d, t_min, limit);
            let (b, mb) = lanes_scalar(&c, o, d, t_min, limit);
            assert_eq!(ma, mb, "case {k}");
            for l in 0..LANES {
                assert!(
                    a[l].to_bits() == b[l].to_bits() || (a[l].is_nan() && b[l].is_nan()),
                    "case {k} lane {l}"
                );
            }
            if has_avx2() {
                // Two chunks at once: this one and one with its lanes reversed.
                let mut e = c;
                for f in [
                    &mut e.px, &mut e.py, &mut e.pz, &mut e.nx, &mut e.ny, &mut e.nz,
                ] {
                    f.reverse();
                }
                e.r2.reverse();
                // SAFETY: the CPU has AVX2.
                let (wh, wr, wm) = unsafe { cover_lanes8(&c, &e, o, d) };
                let ((h0, r0, m0), (h1, r1, m1)) = (cover_lanes(&c, o, d), cover_lanes(&e, o, d));
                assert_eq!(wm, m0 | m1 << LANES, "case {k}");
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&wh), bits(&[h0, h1].concat()), "case {k}");
                assert_eq!(bits(&wr), bits(&[r0, r1].concat()), "case {k}");
                // The stretch as drawn, and one that ends and starts exactly on two lanes' t.
                for (t_min, limit) in [(t_min, limit), (a[1].min(a[0]), a[0].max(a[1]))] {
                    let (a, ma) = lanes(&c, o, d, t_min, limit);
                    let (b, mb) = lanes(&e, o, d, t_min, limit);
                    // SAFETY: the CPU has AVX2.
                    let (w, mw) = unsafe { lanes8(&c, &e, o, d, t_min, limit) };
                    assert_eq!(mw, ma | mb << LANES, "case {k}");
                    for (l, (x, y)) in w.iter().zip(a.iter().chain(&b)).enumerate() {
                        assert!(
                            x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
                            "case {k} lane {l}"
                        );
                    }
                }
            }
        }
    }
}
