//! The area each splat stands for: a partition of unity over the overlapping disks of one
//! surface, with the share of border splats clipped half a spacing beyond them.
//! docs/octree.md, "Splat area".

use glam::Vec3;
use pc_artifact::octree::{encode_clip, node, tangent_frame, Frame, Splat, MAX_CLIP_TURN};
use pc_tree::locate_normalized;

use crate::refs::{push_children_in_box, CellStack};
use rayon::prelude::*;

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

/// Directions in each splat's tangent plane in which its border status is tested.
const BORDER_DIRS: usize = 32;
/// The mask with every direction open.
const ALL_DIRS: u32 = u32::MAX >> (32 - BORDER_DIRS);

/// Where a splat's share of the surface ends (docs/octree.md, "Splat area").
#[derive(Clone, Copy, Debug, PartialEq)]
enum Border {
    /// Same-surface neighbours lie out every way: the whole disk.
    Interior,
    /// On a straight stretch of border (the two lines coincide) or at a corner: up to half a
    /// spacing beyond the splat along both outward directions `o1`, `o2` of its tangent frame.
    Edge {
        o1: (f32, f32),
        o2: (f32, f32),
        gap: f32,
    },
    /// Open in several separate arcs (a strip one or two samples wide): up to half a spacing
    /// beyond the splat in every open direction (bit k of the mask).
    Open { mask: u32, gap: f32 },
}

/// Area each splat stands for: A_i = ∫_{disk i} [x ∈ S_i] / m(x) dA, where m(x) counts the
/// disks of the same surface that cover x and S_i is the part of the plane that splat i's
/// share can reach (all of it, except at a border). In the interior this is a partition of
/// unity: the A_i sum to the surface area whatever the overlap. Estimated with `samples`
/// points per disk. A disk covers x when x is within its radius in its plane, within half a
/// radius of its plane, and the two normals agree within 60° (so the two sides of a thin wall,
/// or the faces meeting at an edge, do not share area).
///
/// Border clip: the disks at a surface's open border (a wall's edge, the light's edge, a hole)
/// overhang the sampled surface by up to a radius, while a sampled surface ends about half a
/// sample spacing beyond its outermost samples. A splat is on the border in a direction of its
/// tangent plane when no same-surface neighbour lies more than half a spacing out that way;
/// its share then stops half a spacing beyond its own centre along the outward direction (the
/// middle of its open directions). Each border splat uses its own position rather than the
/// outermost of its neighbours, and a point's weight counts all covering disks, so the jitter
/// of the border row averages out instead of the extreme sample setting the edge. The half
/// spacing comes from the areas themselves: g_i = ½√(least unclipped area around i), the
/// least being an interior splat's (a second round from the clipped areas changed the
/// reference Cornell areas by under 0.1 % and was dropped).
///
/// Speed: the owner leaf's list (own + referenced splats) holds every disk that reaches the
/// owner cell, so for the samples that fall inside that cell it is enough to test the few disks
/// that overlap disk i at all (filtered once per splat); samples outside the cell locate their
/// own leaf and test its list.
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
    leaf_depth: &[u8],
    samples: u32,
) -> (Vec<f32>, Vec<[f32; 4]>) {
    let dups = Duplicates::new(splats, splat_leaf);
    let ctx = AreaPass {
        frame,
        nodes,
        begin_end,
        splats,
        splat_leaf,
        dups: &dups,
        pattern: disk_pattern(samples.max(1)).collect(),
        leaf_depth,
        dirs: {
            let angle = |k: usize| k as f32 * std::f32::consts::TAU / BORDER_DIRS as f32;
            (
                std::array::from_fn(|k| angle(k).cos()),
                std::array::from_fn(|k| angle(k).sin()),
            )
        },
    };
    let unclipped = dups.spread(ctx.run(None));
    let borders = dups.spread(ctx.borders(&unclipped));
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

/// What a worker of [`AreaPass::borders`] reuses from leaf to leaf.
#[derive(Default)]
struct Scratch {
    stack: CellStack,
    cands: Vec<u32>,
    near: Vec<u32>,
    offsets: Vec<(f32, f32)>,
}

/// Groups of identical splats: each splat's representative (the group's first splat) and, for
/// a representative, how many splats its group holds. Identical splats have the same Morton
/// code, so a group lies in one leaf's own range.
struct Duplicates {
    rep: Vec<u32>,
    count: Vec<u32>,
}

impl Duplicates {
    fn new(splats: &[Splat], splat_leaf: &[u32]) -> Duplicates {
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
        let groups: Vec<Vec<(u32, u32)>> = leaf_runs(splat_leaf)
            .into_par_iter()
            .filter(|r| r.len() > 1)
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
    splat_leaf: &'a [u32],
    dups: &'a Duplicates,
    leaf_depth: &'a [u8],
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
    /// lanes ([`Near`]).
    fn near(&self, i: usize, near: &mut Near) {
        let s = &self.splats[i];
        let c = Vec3::from(s.position);
        let n = Vec3::from(s.normal);
        let (own, refs) = self.leaf_list(self.nodes[self.splat_leaf[i] as usize]);
        near.clear();
        for j in own.chain(refs.iter().copied()) {
            if !self.dups.is_rep(j) {
                continue;
            }
            let o = &self.splats[j as usize];
            let reach = s.radius + o.radius;
            if o.material == s.material
                && Vec3::from(o.normal).dot(n) >= 0.5
                && (Vec3::from(o.position) - c).length_squared() <= reach * reach * 1.25
            {
                near.push(o, self.dups.weight(j));
            }
        }
    }

    /// How far splat i's neighbourhood reaches: √1.25 · 2r_i (the farthest centre of a disk of
    /// the same radius that can overlap it, with the plane tolerance).
    fn reach(&self, i: usize) -> f32 {
        2.0 * self.splats[i].radius * 1.25f32.sqrt()
    }

    /// Splat i's query box in root coordinates.
    fn query_box(&self, i: usize) -> (Vec3, Vec3) {
        let c = Vec3::from(self.splats[i].position);
        let reach = Vec3::splat(self.reach(i));
        let q = |p: Vec3| (p - Vec3::from(self.frame.origin)) * self.frame.inv_size;
        (q(c - reach), q(c + reach))
    }

    /// The representatives among the own splats of every leaf whose cell meets the box
    /// `[bmin, bmax]` (root coordinates), depth first. A leaf's reference list only holds the
    /// disks that reach that leaf's cell, which would cut neighbourhoods at cell walls.
    fn own_splats_in_box(&self, bmin: Vec3, bmax: Vec3, out: &mut Vec<u32>, stack: &mut CellStack) {
        out.clear();
        stack.clear();
        stack.push((0, Vec3::ZERO, 1.0));
        while let Some((slot, lo, size)) = stack.pop() {
            let w = self.nodes[slot as usize];
            if w & node::EMPTY != 0 {
                continue;
            }
            if w & node::LEAF != 0 {
                let (own, _) = self.leaf_list(w);
                out.extend(own.filter(|&j| self.dups.is_rep(j)));
                continue;
            }
            push_children_in_box(w, lo, size, bmin, bmax, stack);
        }
    }

    /// The same-surface splats whose centres lie within [`Self::reach`] of splat i (i
    /// included), taken from `cands`, which holds (in the walk's order) the own splats of at
    /// least every leaf that splat i's query box meets.
    fn neighbourhood(&self, i: usize, cands: &[u32], out: &mut Vec<u32>) {
        let s = &self.splats[i];
        let c = Vec3::from(s.position);
        let n = Vec3::from(s.normal);
        let reach = self.reach(i);
        out.clear();
        out.extend(cands.iter().copied().filter(|&j| {
            let o = &self.splats[j as usize];
            let d = Vec3::from(o.position) - c;
            o.material == s.material
                && Vec3::from(o.normal).dot(n) >= 0.5
                && d.length_squared() <= reach * reach
                && d.dot(n).abs() <= 0.5 * reach
        }));
    }

    /// Each splat's border status, from its same-surface neighbourhood (one query serves
    /// both steps). First half the local sample spacing, g_i = ½√(least unclipped area in the
    /// neighbourhood). Then direction k is open when no neighbour's offset projects more than
    /// g_i onto it (a smaller offset is the jitter of the border row, not more surface). One arc
    /// of open directions is a stretch of border (or a corner) whose outward direction is the
    /// arc's middle.
    ///
    /// The splats of one leaf share one walk of the tree: the own splats of the leaves that
    /// the union of their query boxes meets, which every splat's own neighbourhood filters.
    /// Every leaf a splat's box meets, the union meets, and the walk visits the leaves in the
    /// same order either way, so each neighbourhood is what a walk of its own would give.
    fn borders(&self, unclipped: &[f32]) -> Vec<Border> {
        let runs = leaf_runs(self.splat_leaf);
        runs.into_par_iter()
            .map_init(Scratch::default, |sc, run| {
                let reps = run.clone().filter(|&i| self.dups.is_rep(i as u32));
                let (bmin, bmax) = reps.fold(
                    (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                    |(lo, hi), i| {
                        let (a, b) = self.query_box(i);
                        (lo.min(a), hi.max(b))
                    },
                );
                self.own_splats_in_box(bmin, bmax, &mut sc.cands, &mut sc.stack);
                run.map(|i| {
                    if !self.dups.is_rep(i as u32) {
                        return Border::Interior; // the representative's, spread afterwards
                    }
                    self.neighbourhood(i, &sc.cands, &mut sc.near);
                    self.border(i, &sc.near, unclipped, &mut sc.offsets)
                })
                .collect::<Vec<_>>()
            })
            .flatten_iter()
            .collect()
    }

    /// Splat i's border status from its neighbourhood `near` ([`Self::borders`]).
    fn border(
        &self,
        i: usize,
        near: &[u32],
        unclipped: &[f32],
        offsets: &mut Vec<(f32, f32)>,
    ) -> Border {
        let least = near
            .iter()
            .map(|&j| unclipped[j as usize])
            .fold(f32::INFINITY, f32::min);
        let g = 0.5 * least.max(0.0).sqrt();
        let s = &self.splats[i];
        let (u, v) = tangent_frame(s.normal);
        let (u, v, c) = (Vec3::from(u), Vec3::from(v), Vec3::from(s.position));
        offsets.clear();
        offsets.extend(near.iter().map(|&j| {
            let d = Vec3::from(self.splats[j as usize].position) - c;
            (d.dot(u), d.dot(v))
        }));
        let (cos, sin) = &self.dirs;
        let mut reach = [0.0f32; BORDER_DIRS];
        for &(a, b) in offsets.iter() {
            for k in 0..BORDER_DIRS {
                reach[k] = reach[k].max(a * cos[k] + b * sin[k]);
            }
        }
        let mask = reach
            .iter()
            .enumerate()
            .filter(|(_, &h)| h < g)
            .fold(0u32, |m, (k, _)| m | 1 << k);
        border_from_mask(mask, g, offsets)
    }

    /// Whether a splat's share reaches the point at (p, q) in its own tangent frame.
    #[inline]
    fn accepts(&self, border: Border, p: f32, q: f32) -> bool {
        match border {
            Border::Interior => true,
            Border::Edge { o1, o2, gap } => {
                p * o1.0 + q * o1.1 <= gap && p * o2.0 + q * o2.1 <= gap
            }
            Border::Open { mask, gap } => (0..BORDER_DIRS)
                .filter(|k| mask >> k & 1 != 0)
                .all(|k| p * self.dirs.0[k] + q * self.dirs.1[k] <= gap),
        }
    }

    /// One partition-of-unity pass; `borders` clips the border splats' shares, and the interior
    /// splats take their area from the unclipped pass given with them.
    fn run(&self, borders: Option<(&[Border], &[f32])>) -> Vec<f32> {
        let origin = Vec3::from(self.frame.origin);
        let inv_size = self.frame.inv_size;
        (0..self.splats.len())
            .into_par_iter()
            .map_init(Near::default, |near: &mut Near, i| {
                if !self.dups.is_rep(i as u32) {
                    return 0.0; // the representative's, spread afterwards
                }
                let border = borders.map_or(Border::Interior, |(b, _)| b[i]);
                if let (Border::Interior, Some((_, unclipped))) = (border, borders) {
                    return unclipped[i];
                }
                let s = &self.splats[i];
                let c = Vec3::from(s.position);
                let n = Vec3::from(s.normal);
                let owner = self.splat_leaf[i];
                let depth = self.leaf_depth[owner as usize] as u32;
                let scale = (1u32 << depth) as f32;
                let cell = ((c - origin) * inv_size * scale).floor();
                self.near(i, near);
                let (u, v) = tangent_frame(s.normal);
                let (u, v) = (Vec3::from(u), Vec3::from(v));
                let mut acc = 0.0f32;
                for &(a, b) in &self.pattern {
                    let x = c + (u * a + v * b) * s.radius;
                    // The sample's tangent coordinates are (a, b) · radius by construction.
                    if !self.accepts(border, a * s.radius, b * s.radius) {
                        continue;
                    }
                    let q = (x - origin) * inv_size;
                    let weight = |j: u32| {
                        if covers(&self.splats[j as usize], x, n, s.material) {
                            self.dups.weight(j)
                        } else {
                            0
                        }
                    };
                    // floor(q · scale) == cell, without a call to floorf per sample.
                    let qs = q * scale;
                    let cover: u32 = if qs.cmpge(cell).all() && qs.cmplt(cell + 1.0).all() {
                        near.cover(x)
                    } else if q.cmpge(Vec3::ZERO).all() && q.cmplt(Vec3::ONE).all() {
                        let loc = locate_normalized(self.nodes, q);
                        if node::is_leaf(loc.node) {
                            let (own, refs) = self.leaf_list(loc.node);
                            own.chain(refs.iter().copied()).map(weight).sum()
                        } else {
                            0
                        }
                    } else {
                        0
                    };
                    acc += 1.0 / cover.max(1) as f32;
                }
                std::f32::consts::PI * s.radius * s.radius * acc / self.pattern.len() as f32
            })
            .collect()
    }
}

/// The middle (an angle in the tangent frame) of the longest run of open directions, or None
/// when every direction is open (an isolated splat) or none is.
fn longest_arc(mask: u32) -> Option<f32> {
    if mask == 0 || mask == ALL_DIRS {
        return None;
    }
    let (mut best, mut best_len) = (0usize, 0usize);
    for start in 0..BORDER_DIRS {
        let prev = (start + BORDER_DIRS - 1) % BORDER_DIRS;
        if mask >> start & 1 == 0 || mask >> prev & 1 != 0 {
            continue;
        }
        let len = (0..BORDER_DIRS)
            .take_while(|k| mask >> ((start + k) % BORDER_DIRS) & 1 != 0)
            .count();
        if len > best_len {
            (best, best_len) = (start, len);
        }
    }
    Some((best as f32 + (best_len as f32 - 1.0) * 0.5) * std::f32::consts::TAU / BORDER_DIRS as f32)
}

/// Border status from the mask of open directions (bit k: direction k is open) and the
/// neighbours' offsets in the splat's tangent frame.
///
/// One run of open directions (an open direction whose predecessor is closed starts a run) is
/// a stretch of border or a corner. Its two ends are found to a fraction of a degree by
/// bisection between the last open and the first closed direction; each end is set by one
/// neighbour, the next sample along the border that way, and the border there runs through
/// the splat towards it, so its outward normal is perpendicular to that neighbour's offset.
/// When the two normals differ by more than [`CORNER_TURN`] the splat sits at a corner and
/// keeps both lines; otherwise the stretch is straight and a single line faces their bisector
/// (which averages the jitter of the two neighbours instead of following each; the middle of
/// the run would lean towards the nearer of the two).
fn border_from_mask(mask: u32, gap: f32, offsets: &[(f32, f32)]) -> Border {
    if mask == 0 {
        return Border::Interior;
    }
    let starts = mask & !mask.rotate_left(1);
    if starts.count_ones() != 1 || mask == ALL_DIRS {
        // Several runs (a strip one or two samples wide) or all open (an isolated splat).
        return Border::Open { mask, gap };
    }
    let step = std::f32::consts::TAU / BORDER_DIRS as f32;
    let first = starts.trailing_zeros() as usize;
    let len = (0..BORDER_DIRS)
        .take_while(|k| mask >> ((first + k) % BORDER_DIRS) & 1 != 0)
        .count();
    let reach = |t: f32| {
        let (c, s) = (t.cos(), t.sin());
        offsets
            .iter()
            .enumerate()
            .map(|(j, &(a, b))| (a * c + b * s, j))
            .fold((f32::NEG_INFINITY, usize::MAX), |m, x| {
                if x.0 > m.0 {
                    x
                } else {
                    m
                }
            })
    };
    // (open, closed) angle pairs, bisected to about 0.05°.
    let bisect = |mut open: f32, mut closed: f32| {
        for _ in 0..8 {
            let mid = 0.5 * (open + closed);
            if reach(mid).0 < gap {
                open = mid;
            } else {
                closed = mid;
            }
        }
        (open, reach(closed).1)
    };
    let start = first as f32 * step;
    let end = start + (len - 1) as f32 * step;
    let (a, ja) = bisect(start, start - step);
    let (b, jb) = bisect(end, end + step);
    let (Some(&pa), Some(&pb)) = (offsets.get(ja), offsets.get(jb)) else {
        let middle = 0.5 * (a + b);
        let o = (middle.cos(), middle.sin());
        return Border::Edge { o1: o, o2: o, gap };
    };
    // Outward normals: the start's neighbour lies clockwise of the run, the end's
    // counterclockwise, and the outward side is the run's.
    let na = pa.1.atan2(pa.0) + std::f32::consts::FRAC_PI_2;
    let nb = pb.1.atan2(pb.0) - std::f32::consts::FRAC_PI_2;
    // The turn from na to nb, taken the run's way round (−π, π].
    let turn =
        (nb - na + std::f32::consts::PI).rem_euclid(std::f32::consts::TAU) - std::f32::consts::PI;
    if turn.is_nan() || turn <= CORNER_TURN {
        // A straight stretch: one line along the bisector of the two border directions.
        let middle = na + 0.5 * turn;
        let o = (middle.cos(), middle.sin());
        return Border::Edge { o1: o, o2: o, gap };
    }
    let half = (0.5 * turn).min(MAX_CLIP_TURN);
    let mid = na + 0.5 * turn;
    Border::Edge {
        o1: ((mid - half).cos(), (mid - half).sin()),
        o2: ((mid + half).cos(), (mid + half).sin()),
        gap,
    }
}

/// The least turn between a border's two outward normals (see [`border_from_mask`]) that
/// makes a splat a corner with two clip lines: 40°, well above the jitter of a straight
/// border row and well below a box's right angle.
const CORNER_TURN: f32 = 40.0 * std::f32::consts::PI / 180.0;

#[inline]
fn covers(o: &Splat, x: Vec3, n: Vec3, material: u32) -> bool {
    if o.material != material {
        return false;
    }
    let d = x - Vec3::from(o.position);
    let d2 = d.length_squared();
    let r2 = o.radius * o.radius;
    // |h| <= r/2 and in-plane distance <= r imply |d|² <= 1.25 r²: the cheap test first.
    if d2 > 1.25 * r2 {
        return false;
    }
    let on = Vec3::from(o.normal);
    if on.dot(n) < 0.5 {
        return false;
    }
    let h = d.dot(on);
    h.abs() <= 0.5 * o.radius && d2 - h * h <= r2
}

/// The disks that can cover a splat's samples (its [`AreaPass::near`] list: one surface, one
/// material, normals within 60° of the splat's), lane by lane, so that a sample's cover count is
/// one vector loop over them. The arithmetic is [`covers`]' less the tests every lane has
/// passed already (the material, the normals), operation for operation, so the counts are
/// the same.
#[derive(Default)]
struct Near {
    px: Vec<f32>,
    py: Vec<f32>,
    pz: Vec<f32>,
    nx: Vec<f32>,
    ny: Vec<f32>,
    nz: Vec<f32>,
    radius: Vec<f32>,
    /// How many splats each disk counts for ([`Duplicates::weight`]).
    weight: Vec<u32>,
}

impl Near {
    fn clear(&mut self) {
        for v in [
            &mut self.px,
            &mut self.py,
            &mut self.pz,
            &mut self.nx,
            &mut self.ny,
            &mut self.nz,
            &mut self.radius,
        ] {
            v.clear();
        }
        self.weight.clear();
    }

    fn push(&mut self, o: &Splat, weight: u32) {
        let ([px, py, pz], [nx, ny, nz]) = (o.position, o.normal);
        self.px.push(px);
        self.py.push(py);
        self.pz.push(pz);
        self.nx.push(nx);
        self.ny.push(ny);
        self.nz.push(nz);
        self.radius.push(o.radius);
        self.weight.push(weight);
    }

    /// Σ weight over the disks that cover `x` ([`covers`] for each).
    #[inline]
    fn cover(&self, x: Vec3) -> u32 {
        let n = self.weight.len();
        let (px, py, pz) = (&self.px[..n], &self.py[..n], &self.pz[..n]);
        let (nx, ny, nz, radius) = (
            &self.nx[..n],
            &self.ny[..n],
            &self.nz[..n],
            &self.radius[..n],
        );
        let mut sum = 0u32;
        for l in 0..n {
            let (dx, dy, dz) = (x.x - px[l], x.y - py[l], x.z - pz[l]);
            let d2 = dx * dx + dy * dy + dz * dz;
            let r2 = radius[l] * radius[l];
            let h = dx * nx[l] + dy * ny[l] + dz * nz[l];
            let inside = d2 <= 1.25 * r2 && h.abs() <= 0.5 * radius[l] && d2 - h * h <= r2;
            sum += if inside { self.weight[l] } else { 0 };
        }
        sum
    }
}
