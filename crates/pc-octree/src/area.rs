//! The area each splat stands for: a partition of unity over the overlapping disks of one
//! surface, with the share of border splats clipped along their border row's line, half a
//! spacing beyond the row.
//! docs/octree.md, "Splat area". Here the pass itself (the slabs, the cover counts, the
//! areas); `area/border.rs` where a share ends, `area/disks.rs` the candidates' arrays,
//! `area/walk.rs` the walks a few leaves share.

use glam::Vec3;
use pc_artifact::octree::{encode_clip, node, tangent_frame, Frame, Splat};

use crate::refs::CellStack;
use rayon::prelude::*;

mod border;
mod disks;
mod walk;
use border::{longest_arc, Border, BORDER_DIRS};
use disks::{Disks, Lane, Lanes};
use walk::{LeafCell, QueryBox, Reach};

/// Points on the unit disk for the area estimate: a Fibonacci (golden-angle) spiral, area
/// uniform, deterministic.
fn disk_pattern(m: u32) -> impl Iterator<Item = (f32, f32)> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..m).map(move |k| {
        let r = ((k as f32 + 0.5) / m as f32).sqrt();
        let a = k as f32 * golden;
        (r * a.cos(), r * a.sin())
    })
}

/// Whether the CPU runs AVX2, for the per-splat loops built for it as well as for the
/// baseline ([`AreaPass::near`], [`AreaPass::area`], [`AreaPass::mark_neighbours`]): their loops over a splat's
/// candidate lanes then run eight lanes at a time, and the cover count's 32-bit products packed
/// (the baseline has no packed 32-bit multiply, and that loop ran a lane at a time). The same
/// values either way (Rust fuses no multiply-add); the octree is the same section for section.
#[cfg(target_arch = "x86_64")]
#[inline]
fn has_avx2() -> bool {
    #[cfg(test)]
    if tests::PORTABLE_ONLY.load(std::sync::atomic::Ordering::Relaxed) {
        return false;
    }
    pc_tree::has_avx2()
}

/// Area each splat stands for: A_i = ∫_{disk i} [x ∈ S_i] / m(x) dA, where m(x) counts the
/// disks of the same surface that cover x and S_i is the part of the plane that splat i's
/// share can reach (all of it, except at a border). In the interior this is a partition of
/// unity: the A_i sum to the surface area whatever the overlap. Estimated with `samples`
/// points per disk. A disk covers x when x is within its radius in its plane, within its slab
/// of its plane (half its radius, or more on a noisy surface: [`AreaPass::slabs`]), and the two
/// normals agree within 60° (so the two sides of a thin wall, or the faces meeting at an edge,
/// do not share area).
///
/// Border clip: the disks at a surface's open border (a wall's edge, the light's edge, a hole)
/// overhang the sampled surface by up to a radius, while a sampled surface ends about half a
/// sample spacing beyond its outermost samples. A splat is on the border in a direction of its
/// tangent plane when no same-surface neighbour lies more than half a spacing out that way;
/// its share then stops half a spacing beyond its row's line along the outward direction: the
/// mean offset of the border row's centres around it ([`AreaPass::align_borders`]), not the
/// outermost neighbour's (the extreme of the row's jitter would set the edge) nor its own (a ray
/// sees the union of the row's disks, which then followed the outermost of their lines). A
/// point's weight counts all covering disks. The half spacing comes from the areas themselves:
/// ½√ of the mean unclipped area of the interior splats around i (first, to find the border,
/// ½√ of the least unclipped area around i, the least being an interior splat's; a second
/// round from the clipped areas changed the reference Cornell areas by under 0.1 % and was
/// dropped).
///
/// Speed: the splats of one leaf share one walk of the tree for their candidate disks
/// ([`AreaPass::per_leaf`]), which each filters in one vector pass ([`AreaPass::near`]).
///
/// Identical splats (the same position, normal, radius and material: duplicate points, as scans
/// of overlapping stations hold thousands of) share a disk exactly, so each gets the same
/// share; the pass computes one representative per group ([`Duplicates`]) and counts it as
/// many times as the group has members wherever it covers a point. Without this, m coincident
/// splats cost O(m²) (they cannot be split, and every list that holds one holds them all).
pub fn splat_areas(
    frame: &Frame,
    nodes: &[u32],
    begin_end: &[u32],
    splats: &[Splat],
    splat_leaf: &[u32],
    samples: u32,
) -> (Vec<f32>, Vec<[f32; 4]>) {
    let runs = leaf_runs(splat_leaf);
    let dups = Duplicates::new(splats, &runs);
    let mut ctx = AreaPass {
        frame,
        nodes,
        begin_end,
        splats,
        runs,
        dups: &dups,
        disks: Disks::of_all(splats, &dups),
        cover_halves: Vec::new(),
        node_extents: Vec::new(),
        pattern: disk_pattern(samples.max(1)).collect(),
        dirs: {
            let angle = |k: usize| k as f32 * std::f32::consts::TAU / BORDER_DIRS as f32;
            (
                std::array::from_fn(|k| angle(k).cos()),
                std::array::from_fn(|k| angle(k).sin()),
            )
        },
    };
    // Both neighbourhood passes look around the same boxes (they depend on the radii only).
    let near_boxes = ctx.neighbour_boxes();
    let (slabs, sure): (Vec<f32>, Vec<bool>) = ctx.slabs(&near_boxes).into_iter().unzip();
    let slabs = dups.spread(slabs);
    ctx.disks.set_slabs(&slabs);
    ctx.cover_halves = cover_halves(splats, &slabs);
    ctx.node_extents = ctx.node_extents();
    let unclipped = dups.spread(ctx.run(None));
    let borders = dups.spread(ctx.borders(&unclipped, &sure));
    let borders = dups.spread(ctx.align_borders(&borders, &unclipped, &near_boxes));
    // An interior splat's clipped pass is its unclipped one, sample for sample (its share
    // accepts every sample, and the cover counts never look at borders): only the border
    // splats run again.
    let areas = dups.spread(ctx.run(Some((&borders, &unclipped))));
    let clips = borders
        .par_iter()
        .zip(splats)
        .map(|(b, s)| {
            let (o1, o2, gap) = match *b {
                Border::Interior => return [0.0; 4],
                Border::Edge { o1, o2, gap } => (o1, o2, gap),
                Border::Open { mask, gap } => match longest_arc(mask) {
                    Some(mid) => ((mid.cos(), mid.sin()), (mid.cos(), mid.sin()), gap),
                    None => return [0.0; 4],
                },
            };
            let (u, v) = tangent_frame(s.normal);
            let (u, v) = (Vec3::from(u), Vec3::from(v));
            let world = |(a, b): (f32, f32)| (u * a + v * b).into();
            encode_clip(world(o1), world(o2), gap)
        })
        .collect();
    (areas, clips)
}

/// The leaves' own ranges of the data pool: runs of the same owner (the pool is in leaf order).
fn leaf_runs(splat_leaf: &[u32]) -> Vec<std::ops::Range<usize>> {
    let n = splat_leaf.len();
    let mut runs = Vec::new();
    let mut start = 0;
    for i in 1..=n {
        if i == n || splat_leaf[i] != splat_leaf[start] {
            runs.push(start..i);
            start = i;
        }
    }
    runs
}

/// What a worker of the per-leaf passes reuses from leaf to leaf.
#[derive(Default)]
struct Scratch {
    stack: CellStack,
    /// The leaves a group's shared walk reached ([`AreaPass::per_leaf`]).
    reached: Vec<LeafCell>,
    cands: Vec<u32>,
    near: Vec<u32>,
    offsets: Vec<(f32, f32)>,
    heights: Vec<f32>,
    /// The candidate disks of a leaf's splats ([`AreaPass::cover_box`]).
    disks: Disks,
    /// One byte a candidate lane: 1 where a filter keeps it ([`for_kept`]).
    keep: Vec<u8>,
    lanes: Lanes,
}

/// Groups of identical splats: each splat's representative (the group's first splat) and, for
/// a representative, how many splats its group holds. Identical splats have the same Morton
/// code, so a group lies in one leaf's own range.
struct Duplicates {
    rep: Vec<u32>,
    count: Vec<u32>,
}

impl Duplicates {
    fn new(splats: &[Splat], runs: &[std::ops::Range<usize>]) -> Duplicates {
        let n = splats.len();
        let key = |s: &Splat| -> [u32; 8] {
            let b = |x: f32| x.to_bits();
            [
                b(s.position[0]),
                b(s.position[1]),
                b(s.position[2]),
                b(s.normal[0]),
                b(s.normal[1]),
                b(s.normal[2]),
                b(s.radius),
                s.material,
            ]
        };
        let groups: Vec<Vec<(u32, u32)>> = runs
            .par_iter()
            .filter(|r| r.len() > 1)
            .cloned()
            .map(|r| {
                let mut idx: Vec<u32> = (r.start as u32..r.end as u32).collect();
                idx.sort_by_key(|&i| (key(&splats[i as usize]), i));
                let mut out = Vec::new();
                let mut g = 0;
                while g < idx.len() {
                    let k = key(&splats[idx[g] as usize]);
                    let mut e = g + 1;
                    while e < idx.len() && key(&splats[idx[e] as usize]) == k {
                        e += 1;
                    }
                    for &i in &idx[g + 1..e] {
                        out.push((i, idx[g]));
                    }
                    g = e;
                }
                out
            })
            .collect();
        let mut rep: Vec<u32> = (0..n as u32).collect();
        let mut count = vec![1u32; n];
        for (i, r) in groups.into_iter().flatten() {
            rep[i as usize] = r;
            count[r as usize] += 1;
        }
        Duplicates { rep, count }
    }

    /// Whether splat `i` is its group's representative (computed, not copied).
    #[inline]
    fn is_rep(&self, i: u32) -> bool {
        self.rep[i as usize] == i
    }

    /// How many splats splat `j`'s group counts where it covers a point (0 for a member that is
    /// not its group's representative, so that a list counts each group once).
    #[inline]
    fn weight(&self, j: u32) -> u32 {
        if self.is_rep(j) {
            self.count[j as usize]
        } else {
            0
        }
    }

    /// `per_splat` (computed for the representatives) with every member given its
    /// representative's value.
    fn spread<T: Copy>(&self, mut per_splat: Vec<T>) -> Vec<T> {
        for (i, &r) in self.rep.iter().enumerate() {
            if r as usize != i {
                per_splat[i] = per_splat[r as usize];
            }
        }
        per_splat
    }
}

/// What one partition-of-unity pass over the disks needs.
struct AreaPass<'a> {
    frame: &'a Frame,
    nodes: &'a [u32],
    begin_end: &'a [u32],
    splats: &'a [Splat],
    /// The leaves' own ranges of the pool ([`leaf_runs`]).
    runs: Vec<std::ops::Range<usize>>,
    dups: &'a Duplicates,
    /// Every splat's disk ([`Disks::of_all`]), so that a walk copies a leaf's own splats as
    /// one range of each array.
    disks: Disks,
    /// Per splat, once the slabs are set, the half extents of the box around its centre that
    /// holds every point its disk covers ([`cover_halves`]).
    cover_halves: Vec<Vec3>,
    /// Per node-pool slot, the largest of those below it, axis by axis
    /// ([`Self::node_extents`]).
    node_extents: Vec<Vec3>,
    pattern: Vec<(f32, f32)>,
    /// The border directions' cosines and sines (apart, so loops over them run in vector
    /// lanes).
    dirs: ([f32; BORDER_DIRS], [f32; BORDER_DIRS]),
}

impl AreaPass<'_> {
    fn leaf_list(&self, w: u32) -> (std::ops::Range<u32>, &[u32]) {
        match pc_artifact::octree::BeginEnd::leaf(self.begin_end, node::ptr(w)) {
            Some((b, e, r)) => (b..e, r),
            None => (0..0, &[]),
        }
    }

    /// The disks of the same surface that can cover some point of disk i (i included), as
    /// lanes ([`Lanes`]), from `cands` (its leaf's candidates, [`AreaPass::per_leaf`]). A disk j (radius r_j, slab t_j,
    /// normals at angle θ) covers points within r_j of its centre in its plane and t_j off it,
    /// so it can cover a point of disk i only when
    /// - its centre lies within r_i + √(r_j² + t_j²) of splat i's, and
    /// - the offset of its centre, a along splat i's plane and b off it, has
    ///   (|a| − r_i) cos θ ≤ r_j + |b| sin θ: a point p of disk i (|p| ≤ r_i) is
    ///   (p − a − b n_i) from centre j, and its part along plane j is at least
    ///   |p − a| cos θ − |b| sin θ long.
    ///
    /// The second test keeps a noisy wall's lanes to about those within r_i + r_j along it,
    /// however far the slabs reach off it.
    fn near(&self, i: usize, cands: &Disks, keep: &mut Vec<u8>, near: &mut Lanes) {
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            #[target_feature(enable = "avx2")]
            fn avx2(p: &AreaPass<'_>, i: usize, c: &Disks, keep: &mut Vec<u8>, near: &mut Lanes) {
                p.near_portable(i, c, keep, near)
            }
            // SAFETY: the CPU has AVX2 (`has_avx2`).
            return unsafe { avx2(self, i, cands, keep, near) };
        }
        self.near_portable(i, cands, keep, near)
    }

    /// [`Self::near`] on any CPU.
    #[inline(always)]
    fn near_portable(&self, i: usize, cands: &Disks, keep: &mut Vec<u8>, near: &mut Lanes) {
        let s = &self.splats[i];
        let (c, n, r) = (Vec3::from(s.position), Vec3::from(s.normal), s.radius);
        let m = cands.len();
        let (px, py, pz) = (&cands.px[..m], &cands.py[..m], &cands.pz[..m]);
        let (nx, ny, nz) = (&cands.nx[..m], &cands.ny[..m], &cands.nz[..m]);
        let (radius, extent) = (&cands.radius[..m], &cands.extent[..m]);
        let (material, weight) = (&cands.material[..m], &cands.weight[..m]);
        keep.clear();
        keep.resize(m, 0);
        // One pass the compiler can run in vector lanes, then the copies.
        for l in 0..m {
            let cos = nx[l] * n.x + ny[l] * n.y + nz[l] * n.z;
            let (dx, dy, dz) = (px[l] - c.x, py[l] - c.y, pz[l] - c.z);
            let d2 = dx * dx + dy * dy + dz * dz;
            let b = dx * n.x + dy * n.y + dz * n.z;
            let sin = (1.0 - cos * cos).max(0.0).sqrt();
            let reach = r + extent[l];
            // (|a| − r) cos θ ≤ r_j + |b| sin θ, squared (both sides ≥ 0 once cos θ ≥ 0.5).
            let side = r * cos + radius[l] + b.abs() * sin;
            keep[l] = u8::from(
                (material[l] == s.material)
                    & (weight[l] > 0)
                    & (cos >= 0.5)
                    & (d2 <= reach * reach)
                    & ((d2 - b * b) * cos * cos <= side * side),
            );
        }
        let (u, v) = tangent_frame(s.normal);
        let (u, v) = (Vec3::from(u), Vec3::from(v));
        near.clear();
        for_kept(keep, |l| {
            let d = Vec3::new(px[l], py[l], pz[l]) - c;
            let nl = Vec3::new(nx[l], ny[l], nz[l]);
            near.push(Lane {
                h0: -d.dot(nl),
                hu: r * u.dot(nl),
                hv: r * v.dot(nl),
                d0: d.length_squared(),
                du: -2.0 * r * u.dot(d),
                dv: -2.0 * r * v.dot(d),
                r2: radius[l] * radius[l],
                slab: cands.slab[l],
                weight: weight[l],
            });
        });
    }

    /// The box of the splats `todo` (one leaf's) for their cover counts: every disk that can
    /// cover a point of one of them is a representative among the own splats of a leaf whose
    /// cover box ([`cover_halves`]) can reach within r_i of a splat i, found by a walk
    /// ([`Reach::Extents`]) that prunes a node when its cell, widened by the largest such half
    /// extents below it ([`Self::node_extents`]), misses the box of the splats' centres widened
    /// by their largest radius. A large disk from afar is found however large; a fixed box
    /// (twice a splat's own reach) collected three times the candidates on a dense noisy scan.
    /// None when `todo` is empty.
    fn cover_box(&self, todo: impl Iterator<Item = usize>) -> Option<QueryBox> {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut radius = 0.0f32;
        let mut any = false;
        for i in todo {
            let c = Vec3::from(self.splats[i].position);
            (lo, hi) = (lo.min(c), hi.max(c));
            radius = radius.max(self.splats[i].radius);
            any = true;
        }
        let origin = Vec3::from(self.frame.origin);
        any.then(|| QueryBox {
            lo: (lo - origin) * self.frame.inv_size,
            hi: (hi - origin) * self.frame.inv_size,
            radius,
            centres: (lo, hi),
        })
    }

    /// Per node-pool slot, the largest half extents of the splats' cover boxes below it
    /// ([`cover_halves`]), axis by axis: how far from its centre, along each axis, a disk there
    /// can cover a point.
    fn node_extents(&self) -> Vec<Vec3> {
        fn visit(pass: &AreaPass, slot: u32, out: &mut [Vec3]) -> Vec3 {
            let w = pass.nodes[slot as usize];
            let e = if w & node::EMPTY != 0 {
                Vec3::ZERO
            } else if w & node::LEAF != 0 {
                let (own, _) = pass.leaf_list(w);
                let own = own.start as usize..own.end as usize;
                pass.cover_halves[own]
                    .iter()
                    .copied()
                    .fold(Vec3::ZERO, Vec3::max)
            } else {
                (0..8)
                    .map(|k| visit(pass, node::ptr(w) + k, out))
                    .fold(Vec3::ZERO, Vec3::max)
            };
            out[slot as usize] = e;
            e
        }
        let mut out = vec![Vec3::ZERO; self.nodes.len()];
        if !self.nodes.is_empty() {
            visit(self, 0, &mut out);
        }
        out
    }

    /// How far splat i's neighbourhood reaches: √1.25 · 2r_i (the farthest centre of a disk of
    /// the same radius that can overlap it, with the plane tolerance).
    fn reach(&self, i: usize) -> f32 {
        2.0 * self.splats[i].radius * 1.25f32.sqrt()
    }

    /// Splat i's query box in root coordinates.
    fn query_box(&self, i: usize) -> (Vec3, Vec3) {
        self.box_around(i, self.reach(i))
    }

    /// The box of half width `half` (world units) around splat i's centre, in root coordinates.
    fn box_around(&self, i: usize, half: f32) -> (Vec3, Vec3) {
        let c = Vec3::from(self.splats[i].position);
        let half = Vec3::splat(half);
        let q = |p: Vec3| (p - Vec3::from(self.frame.origin)) * self.frame.inv_size;
        (q(c - half), q(c + half))
    }

    /// The union of the query boxes of the representatives among `run` (one leaf's splats),
    /// in root coordinates: the own splats of the leaves it meets ([`Reach::Cells`]) hold
    /// every splat's neighbourhood. A leaf's reference list only holds the disks that reach
    /// that leaf's cell, which would cut neighbourhoods at cell walls. None without a
    /// representative. Its `centres` are the same boxes' union in world units, a hair wider
    /// than [`Self::reach`] against rounding: no centre outside it is any splat's neighbour.
    fn neighbour_box(&self, run: impl Iterator<Item = usize>) -> Option<QueryBox> {
        let ((lo, hi), centres) = run
            .filter(|&i| self.dups.is_rep(i as u32))
            .map(|i| {
                let (c, reach) = (Vec3::from(self.splats[i].position), self.reach(i));
                let half = Vec3::splat(reach * (1.0 + 1e-5)) + c.abs() * 1e-6;
                (self.query_box(i), (c - half, c + half))
            })
            .reduce(|((lo, hi), (a, b)), ((lo2, hi2), (a2, b2))| {
                ((lo.min(lo2), hi.max(hi2)), (a.min(a2), b.max(b2)))
            })?;
        Some(QueryBox {
            lo,
            hi,
            radius: 0.0,
            centres,
        })
    }

    /// Every leaf's [`Self::neighbour_box`].
    fn neighbour_boxes(&self) -> Vec<Option<QueryBox>> {
        self.runs
            .par_iter()
            .map(|run| self.neighbour_box(run.clone()))
            .collect()
    }

    /// Marks in `keep` the lanes of `disks` ([`Self::neighbour_box`]) on splat i's surface
    /// (its material, normals within 60°) whose centres lie within [`Self::reach`] of its centre
    /// and `rise` of its plane, and sets `heights` to every lane's |height| above that plane.
    /// One pass the compiler can run in vector lanes.
    fn mark_neighbours(
        &self,
        i: usize,
        disks: &Disks,
        rise: f32,
        keep: &mut Vec<u8>,
        heights: &mut Vec<f32>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            #[target_feature(enable = "avx2")]
            fn avx2(
                p: &AreaPass<'_>,
                i: usize,
                disks: &Disks,
                rise: f32,
                keep: &mut Vec<u8>,
                heights: &mut Vec<f32>,
            ) {
                p.mark_neighbours_portable(i, disks, rise, keep, heights)
            }
            // SAFETY: the CPU has AVX2 (`has_avx2`).
            return unsafe { avx2(self, i, disks, rise, keep, heights) };
        }
        self.mark_neighbours_portable(i, disks, rise, keep, heights)
    }

    /// [`Self::mark_neighbours`] on any CPU.
    #[inline(always)]
    fn mark_neighbours_portable(
        &self,
        i: usize,
        disks: &Disks,
        rise: f32,
        keep: &mut Vec<u8>,
        heights: &mut Vec<f32>,
    ) {
        let s = &self.splats[i];
        let (c, n) = (Vec3::from(s.position), Vec3::from(s.normal));
        let reach = self.reach(i);
        let m = disks.len();
        let (px, py, pz) = (&disks.px[..m], &disks.py[..m], &disks.pz[..m]);
        let (nx, ny, nz) = (&disks.nx[..m], &disks.ny[..m], &disks.nz[..m]);
        let (material, weight) = (&disks.material[..m], &disks.weight[..m]);
        keep.clear();
        keep.resize(m, 0);
        heights.clear();
        heights.resize(m, 0.0);
        for l in 0..m {
            let (dx, dy, dz) = (px[l] - c.x, py[l] - c.y, pz[l] - c.z);
            let h = (dx * n.x + dy * n.y + dz * n.z).abs();
            keep[l] = u8::from(
                (material[l] == s.material)
                    & (weight[l] > 0)
                    & (nx[l] * n.x + ny[l] * n.y + nz[l] * n.z >= 0.5)
                    & (dx * dx + dy * dy + dz * dz <= reach * reach)
                    & (h <= rise),
            );
            heights[l] = h;
        }
    }

    /// The same-surface splats whose centres lie within [`Self::reach`] of splat i and half
    /// that of its plane (i included), from `sc` ([`Self::neighbour_box`]), in `sc.near`.
    fn neighbourhood(&self, i: usize, sc: &mut Scratch) {
        self.mark_neighbours(
            i,
            &sc.disks,
            0.5 * self.reach(i),
            &mut sc.keep,
            &mut sc.heights,
        );
        sc.near.clear();
        let (cands, near) = (&sc.cands, &mut sc.near);
        for_kept(&sc.keep, |l| near.push(cands[l]));
    }

    /// Each splat's slab ([`COVER_DEVIATIONS`]): the height off its plane within which its disk
    /// covers a point. Half its radius, or on a noisy surface so many deviations of its
    /// neighbours' heights above its plane, whichever is more. The deviation is the median of
    /// the same-surface neighbours' |height| within [`Self::reach`] (and as high), over
    /// 0.6745, as robust a scale as a few dozen heights give, and a nearby surface of the same
    /// material and facing (a step) moves it little.
    ///
    /// Why: the disks of a wall cover each other only where each stands within its slab of the
    /// other's plane. Range noise puts the centres σ off the wall, so two neighbours differ by
    /// about √2 σ, and once the radius is not several σ (a dense scan: 5 mm disks on a ceiling
    /// with 2 mm of noise) half a radius misses a third of the neighbours: every sample seems
    /// covered by fewer disks than cover it, and the wall's splats stood for twice its area.
    ///
    /// The same neighbourhood tells whether the splat is surely interior
    /// ([`Self::surely_interior`]), returned beside its slab.
    fn slabs(&self, near_boxes: &[Option<QueryBox>]) -> Vec<(f32, bool)> {
        self.per_leaf(Reach::Cells, near_boxes, |sc, run| {
            run.map(|i| {
                if !self.dups.is_rep(i as u32) {
                    return (0.0, false); // the representative's, spread afterwards
                }
                let reach = self.reach(i);
                self.mark_neighbours(i, &sc.disks, reach, &mut sc.keep, &mut sc.heights);
                let interior = self.surely_interior(i, sc);
                let deviation = self.height_deviation(i, sc);
                let slab = (0.5 * self.splats[i].radius).max(COVER_DEVIATIONS * deviation);
                (slab, interior)
            })
            .collect()
        })
    }

    /// The robust deviation (median |h| / 0.6745) of the heights h above splat i's plane of its
    /// same-surface neighbours within [`Self::reach`] (and as high), from the lanes of `sc`
    /// ([`Self::neighbour_box`]) that [`Self::mark_neighbours`] marked with that reach; 0 with
    /// fewer than [`MIN_HEIGHTS`] of them.
    fn height_deviation(&self, i: usize, sc: &mut Scratch) -> f32 {
        let mut k = 0;
        let (cands, heights) = (&sc.cands, &mut sc.heights);
        for_kept(&sc.keep, |l| {
            if cands[l] as usize != i {
                heights[k] = heights[l];
                k += 1;
            }
        });
        sc.heights.truncate(k);
        if k < MIN_HEIGHTS {
            return 0.0;
        }
        let (_, median, _) = sc.heights.select_nth_unstable_by(k / 2, f32::total_cmp);
        *median / 0.6745
    }

    /// One partition-of-unity pass, leaf by leaf; `borders` clips the border splats' shares,
    /// and the interior splats take their area from the unclipped pass given with them.
    fn run(&self, borders: Option<(&[Border], &[f32])>) -> Vec<f32> {
        let todo = |i: usize| {
            self.dups.is_rep(i as u32) && borders.is_none_or(|(b, _)| b[i] != Border::Interior)
        };
        let boxes: Vec<_> = self
            .runs
            .par_iter()
            .map(|run| self.cover_box(run.clone().filter(|&i| todo(i))))
            .collect();
        self.per_leaf(Reach::Extents, &boxes, |sc, run| {
            run.map(|i| {
                if !todo(i) {
                    // A member (the representative's, spread afterwards) or an interior
                    // splat of the clipped pass.
                    return borders.map_or(0.0, |(_, unclipped)| unclipped[i]);
                }
                let border = borders.map_or(Border::Interior, |(b, _)| b[i]);
                self.near(i, &sc.disks, &mut sc.keep, &mut sc.lanes);
                self.area(i, border, &sc.lanes)
            })
            .collect()
        })
    }

    /// Splat i's share: its disk's samples that its `border` accepts, each weighted by one over
    /// the number of disks among `near` that cover it. Built for AVX2 too ([`has_avx2`]).
    fn area(&self, i: usize, border: Border, near: &Lanes) -> f32 {
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            #[target_feature(enable = "avx2")]
            fn avx2(p: &AreaPass<'_>, i: usize, border: Border, near: &Lanes) -> f32 {
                p.area_portable(i, border, near)
            }
            // SAFETY: the CPU has AVX2 (`has_avx2`).
            return unsafe { avx2(self, i, border, near) };
        }
        self.area_portable(i, border, near)
    }

    /// [`Self::area`] on any CPU.
    #[inline(always)]
    fn area_portable(&self, i: usize, border: Border, near: &Lanes) -> f32 {
        let s = &self.splats[i];
        let mut acc = 0.0f32;
        for &(a, b) in &self.pattern {
            // The sample's tangent coordinates are (a, b) · radius by construction.
            if !self.accepts(border, a * s.radius, b * s.radius) {
                continue;
            }
            acc += 1.0
                / near
                    .cover(a, b, s.radius * s.radius * (a * a + b * b))
                    .max(1) as f32;
        }
        std::f32::consts::PI * s.radius * s.radius * acc / self.pattern.len() as f32
    }
}

/// `f(l)` for every lane `l` that `keep` marks (one byte a lane, 0 or 1), in order. Eight
/// lanes are read as one word, so the few kept among a walk's hundreds of candidates cost a
/// word each (a byte-by-byte scan was the largest part of [`AreaPass::near`]).
#[inline]
fn for_kept(keep: &[u8], mut f: impl FnMut(usize)) {
    for (w, c) in keep.chunks(8).enumerate() {
        let mut word = [0u8; 8];
        word[..c.len()].copy_from_slice(c);
        let mut bits = u64::from_le_bytes(word);
        while bits != 0 {
            f(w * 8 + bits.trailing_zeros() as usize / 8);
            bits &= bits - 1;
        }
    }
}

/// Per splat, the half extents along the axes of the box around its centre that holds every
/// point its disk covers: the points within its radius r in its plane and its slab t off it
/// ([`Lanes::cover`]), a flat cylinder whose box reaches r √(1 − n_k²) + t |n_k| along axis k.
/// On a noisy dense scan the slab outgrows the radius (5 mm disks, 9 mm slabs on the hall scan
/// at 20M points), and a ball of radius √(r² + t²) around each disk would reach twice as far
/// along an axis-aligned wall as the disk does.
fn cover_halves(splats: &[Splat], slabs: &[f32]) -> Vec<Vec3> {
    splats
        .par_iter()
        .zip(slabs)
        .map(|(s, &t)| {
            let n = Vec3::from(s.normal);
            crate::refs::disk_half_extent(n, s.radius) + n.abs() * t
        })
        .collect()
}

/// How many deviations of its neighbours' heights a disk's slab reaches off its plane
/// ([`AreaPass::slabs`]): two neighbours' heights differ by √2 σ where each centre is σ off
/// the surface, so 3.5 of them is about 5 σ, which the heights of two neighbours pass at 1 in
/// 2000. Measured on the hall scan at 20M points (5 mm disks, 1.5-2 mm of noise), a numerical
/// copy of this pass gave a ceiling patch 1.82 times its area with half-radius slabs, 1.035
/// with 3 σ, 1.001 with 4 σ and 0.999 with 5 σ.
const COVER_DEVIATIONS: f32 = 3.5;

/// The fewest neighbour heights a deviation is taken from; below it the slab is half a radius.
const MIN_HEIGHTS: usize = 4;

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicBool, Ordering};

    use glam::Vec3;
    use pc_artifact::octree::class;
    use pc_testkit::Soa;
    use rand::SeedableRng;
    use rand_pcg::Pcg64;

    use crate::{build, BuildInput, OctreeParams};

    /// Makes [`super::has_avx2`] say no, so that the portable loops run on this CPU too.
    pub(super) static PORTABLE_ONLY: AtomicBool = AtomicBool::new(false);

    /// The loops built for AVX2 give the portable ones' areas and clips to the bit, on a scene
    /// with borders, corners and a curved surface (a jittered floor, a wall meeting it, a ball).
    #[test]
    fn the_avx2_loops_give_the_portable_areas() {
        let mut rng = Pcg64::seed_from_u64(3);
        let mut s = Soa::default();
        s.rect(Vec3::ZERO, Vec3::X, Vec3::Y, 0.04, 0, &mut rng);
        s.rect(
            Vec3::new(0.0, 1.0, 0.5),
            Vec3::X,
            0.5 * Vec3::Z,
            0.04,
            0,
            &mut rng,
        );
        s.sphere(Vec3::new(0.3, 0.2, 0.4), 0.2, 3_000, 0);
        let albedo = s.ones();
        let input = BuildInput {
            positions: &s.p,
            normals: &s.n,
            radii: &s.r,
            albedo: &albedo,
            material: &s.m,
            material_class: &[class::DIFFUSE],
        };
        let o = build(&input, &OctreeParams::default(), &mut |_| {}).unwrap();
        let areas = || {
            super::splat_areas(
                &o.frame,
                &o.nodes,
                &o.begin_end,
                &o.splats,
                &o.splat_leaf,
                8,
            )
        };
        let (fast, fast_clips) = areas();
        PORTABLE_ONLY.store(true, Ordering::Relaxed);
        let (portable, portable_clips) = areas();
        PORTABLE_ONLY.store(false, Ordering::Relaxed);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&fast), bits(&portable));
        assert_eq!(fast_clips, portable_clips);
        assert!(
            portable_clips.iter().any(|c| *c != [0.0; 4]),
            "the scene has borders"
        );
    }
}
