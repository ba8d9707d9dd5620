//! Where a splat's share of the surface ends: the border test in 32 directions of its tangent
//! plane ([`AreaPass::borders`]), the quick proof that most splats are interior
//! ([`AreaPass::surely_interior`]) and the border rows' common lines
//! ([`AreaPass::align_borders`]). docs/octree.md, "Borders".

use glam::Vec3;
use pc_artifact::octree::{tangent_frame, MAX_CLIP_TURN};
use rayon::prelude::*;

use super::walk::{QueryBox, Reach};
use super::{for_kept, AreaPass, Scratch};

/// Directions in each splat's tangent plane in which its border status is tested.
pub(super) const BORDER_DIRS: usize = 32;
/// The mask with every direction open.
pub(super) const ALL_DIRS: u32 = u32::MAX >> (32 - BORDER_DIRS);

/// Where a splat's share of the surface ends (docs/octree.md, "Splat area").
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Border {
    /// Same-surface neighbours lie out every way: the whole disk.
    Interior,
    /// On a straight stretch of border (the two lines coincide) or at a corner: up to `gap`
    /// beyond the splat along both outward directions `o1`, `o2` of its tangent frame (half a
    /// spacing from [`AreaPass::border`], then its row's line from [`AreaPass::align_borders`]).
    Edge {
        o1: (f32, f32),
        o2: (f32, f32),
        gap: f32,
    },
    /// Open in several separate arcs (a strip one or two samples wide): up to half a spacing
    /// beyond the splat in every open direction (bit k of the mask).
    Open { mask: u32, gap: f32 },
}

impl AreaPass<'_> {
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
    ///
    /// A splat its slab's pass found surely interior ([`Self::surely_interior`]) is not looked
    /// at again; a leaf's query box holds only the others', and a leaf without them walks
    /// nothing.
    pub(super) fn borders(&self, unclipped: &[f32], sure: &[bool]) -> Vec<Border> {
        let boxes: Vec<Option<QueryBox>> = self
            .runs
            .par_iter()
            .map(|run| self.neighbour_box(run.clone().filter(|&i| !sure[i])))
            .collect();
        self.per_leaf(Reach::Cells, &boxes, |sc, run| {
            run.map(|i| {
                if !self.dups.is_rep(i as u32) || sure[i] {
                    // Non-representatives take the representative's, spread afterwards.
                    return Border::Interior;
                }
                self.neighbourhood(i, sc);
                self.border(i, &sc.near, unclipped, &mut sc.offsets)
            })
            .collect()
        })
    }

    /// Splat i's border status from its neighbourhood `near` ([`Self::borders`]).
    pub(super) fn border(
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
        let (u, v, c) = self.tangent_axes(i);
        offsets.clear();
        offsets.extend(near.iter().map(|&j| {
            let d = Vec3::from(self.splats[j as usize].position) - c;
            (d.dot(u), d.dot(v))
        }));
        let reach = self.directional_reach(offsets.iter().copied());
        let mask = reach
            .iter()
            .enumerate()
            .filter(|(_, &h)| h < g)
            .fold(0u32, |m, (k, _)| m | 1 << k);
        border_from_mask(mask, g, offsets)
    }

    /// Splat i's tangent axes and centre.
    pub(super) fn tangent_axes(&self, i: usize) -> (Vec3, Vec3, Vec3) {
        let s = &self.splats[i];
        let (u, v) = tangent_frame(s.normal);
        (Vec3::from(u), Vec3::from(v), Vec3::from(s.position))
    }

    /// How far out along each of the [`BORDER_DIRS`] directions of a tangent plane these
    /// offsets in it reach (0 at least: the splat's own place).
    pub(super) fn directional_reach(
        &self,
        offsets: impl Iterator<Item = (f32, f32)>,
    ) -> [f32; BORDER_DIRS] {
        let (cos, sin) = &self.dirs;
        let mut reach = [0.0f32; BORDER_DIRS];
        for (a, b) in offsets {
            for k in 0..BORDER_DIRS {
                reach[k] = reach[k].max(a * cos[k] + b * sin[k]);
            }
        }
        reach
    }

    /// Whether [`Self::border`] will surely find splat i interior whatever the unclipped areas,
    /// from the lanes `sc.keep` marks within [`Self::reach`] of it ([`Self::slabs`]): those
    /// within half of that off its plane are the border's neighbourhood. The border opens a
    /// direction where no neighbour reaches past its half spacing, which is at most ½√ of
    /// splat i's own disk's area (i is among its neighbours, and a share is at most its disk;
    /// 0.1 % more for the rounding). So where every direction has a neighbour reaching past
    /// that, none can open. A direction is settled by the first neighbour that reaches past
    /// the gap in it, and the test ends once all are. False is only "look again": the
    /// border's pass looks at the rest, 1.7 % of the 4M hall scan's splats and 1.4 % of the
    /// 1M Cornell box's.
    pub(super) fn surely_interior(&self, i: usize, sc: &Scratch) -> bool {
        let rise = 0.5 * self.reach(i);
        let (u, v, c) = self.tangent_axes(i);
        let (d, cands, heights) = (&sc.disks, &sc.cands, &sc.heights);
        let r = self.splats[i].radius;
        let most_gap = 0.5 * (std::f32::consts::PI * r * r * 1.001).sqrt();
        let (cos, sin) = &self.dirs;
        let mut own = false;
        let mut reached = 0u32;
        for_kept(&sc.keep, |l| {
            own |= cands[l] as usize == i;
            if heights[l] <= rise && reached != ALL_DIRS {
                let o = Vec3::new(d.px[l], d.py[l], d.pz[l]) - c;
                let (a, b) = (o.dot(u), o.dot(v));
                for k in 0..BORDER_DIRS {
                    reached |= u32::from(a * cos[k] + b * sin[k] >= most_gap) << k;
                }
            }
        });
        own && reached == ALL_DIRS
    }

    /// The border rows' splats clipped along one line: each border splat's gap moved to where
    /// the splats of its row put the border on average. A straight border splat's row is the
    /// straight border splats around it whose outward directions lie within 30° of its own
    /// (itself included); the line is their centres' mean offset along its outward direction
    /// plus half the spacing of the interior around it (½√ of the mean unclipped area of its
    /// interior neighbours: the least area [`Self::border`] takes is an interior splat's, but
    /// the smallest of several, and the one line now stands for the whole row). A corner splat
    /// keeps its two lines but one gap (the clip's encoding has one), the mean of its two
    /// rows' lines, each row taken with the corner in it.
    ///
    /// Why: a ray sees the union of the clipped disks, and a point just past a border is
    /// covered by two or three of the row's disks, so the visible edge ran along the outermost
    /// of their lines, which the row's jitter sets (up to half a spacing either way): the
    /// reference Cornell light's rim wobbled by a fifth of a pixel, and being 70 times
    /// brighter than the ceiling beside it, its rim pixels held a third of the image's squared
    /// per-pixel error. A jittered grid's border row lies on average half a spacing inside
    /// its edge, so the mean of its lines is the edge (docs/octree.md, "Borders").
    pub(super) fn align_borders(
        &self,
        borders: &[Border],
        unclipped: &[f32],
        near_boxes: &[Option<QueryBox>],
    ) -> Vec<Border> {
        let is_edge = |i: usize| matches!(borders[i], Border::Edge { .. });
        let boxes: Vec<Option<QueryBox>> = self
            .runs
            .par_iter()
            .zip(near_boxes)
            .map(|(run, b)| run.clone().any(is_edge).then_some(*b).flatten())
            .collect();
        self.per_leaf(Reach::Cells, &boxes, |sc, run| {
            run.map(|i| match borders[i] {
                Border::Edge { o1, o2, gap } if self.dups.is_rep(i as u32) => {
                    self.neighbourhood(i, sc);
                    let half = self.interior_half_spacing(&sc.near, borders, unclipped);
                    let row = |o| self.row_offset(i, self.outward(i, o), &sc.near, borders);
                    let line = match o1 == o2 {
                        true => row(o1),
                        false => 0.5 * (row(o1) + row(o2)),
                    };
                    let aligned = (line + half.unwrap_or(gap)).clamp(0.25 * gap, 2.5 * gap);
                    // A row of zero-area splats (coincident points) keeps step 1's gap.
                    let gap = if aligned.is_finite() { aligned } else { gap };
                    Border::Edge { o1, o2, gap }
                }
                b => b,
            })
            .collect()
        })
    }

    /// The mean offset along `o` (world space, from splat i's centre) of the centres of splat
    /// i's row facing `o`: the straight border splats among `near` whose outward directions
    /// lie within 30° of `o`, and splat i ([`Self::align_borders`]).
    pub(super) fn row_offset(&self, i: usize, o: Vec3, near: &[u32], borders: &[Border]) -> f32 {
        let c = Vec3::from(self.splats[i].position);
        let (mut sum, mut n) = (0.0f32, 1u32);
        for &j in near.iter().filter(|&&j| j as usize != i) {
            let j = j as usize;
            let Border::Edge { o1, o2, .. } = borders[j] else {
                continue;
            };
            if o1 == o2 && self.outward(j, o1).dot(o) >= ROW_FACING {
                sum += (Vec3::from(self.splats[j].position) - c).dot(o);
                n += 1;
            }
        }
        sum / n as f32
    }

    /// Half the spacing of the interior splats among `near`: ½√ of their mean unclipped area,
    /// each group of identical splats counted once with its whole area (its representative's
    /// share times its count); None without any.
    pub(super) fn interior_half_spacing(
        &self,
        near: &[u32],
        borders: &[Border],
        unclipped: &[f32],
    ) -> Option<f32> {
        let (sum, n) = near
            .iter()
            .filter(|&&j| borders[j as usize] == Border::Interior)
            .fold((0.0f32, 0u32), |(s, n), &j| {
                (
                    s + self.dups.weight(j) as f32 * unclipped[j as usize],
                    n + 1,
                )
            });
        (n > 0).then(|| 0.5 * (sum / n as f32).max(0.0).sqrt())
    }

    /// Splat i's outward direction `o` (in its tangent frame) in world space.
    pub(super) fn outward(&self, i: usize, o: (f32, f32)) -> Vec3 {
        let (u, v) = tangent_frame(self.splats[i].normal);
        Vec3::from(u) * o.0 + Vec3::from(v) * o.1
    }

    /// Whether a splat's share reaches the point at (p, q) in its own tangent frame.
    #[inline(always)]
    pub(super) fn accepts(&self, border: Border, p: f32, q: f32) -> bool {
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
}

/// The middle (an angle in the tangent frame) of the longest run of open directions, or None
/// when every direction is open (an isolated splat) or none is.
pub(super) fn longest_arc(mask: u32) -> Option<f32> {
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
pub(super) fn border_from_mask(mask: u32, gap: f32, offsets: &[(f32, f32)]) -> Border {
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
pub(super) const CORNER_TURN: f32 = 40.0 * std::f32::consts::PI / 180.0;

/// The least cosine between two border splats' outward directions for one to count in the
/// other's row ([`AreaPass::align_borders`]): 30°, past a straight row's jitter, short of a
/// corner's turn.
pub(super) const ROW_FACING: f32 = 0.866;
