//! Cleaning a raw scan before it becomes splats: duplicate points merged (overlapping
//! stations scan the same surface twice) and stray points removed (statistical outlier
//! removal). Both are `[import]` options, off by default, applied to each model on its own, in
//! the file's frame, before normals and radii are estimated; what they remove is counted in
//! the model's report. docs/import.md, "Cleaning a scan".

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::knn::{spread, Knn};
use crate::points::PointSet;

/// Keeps the first point of every cluster of points closer than `distance` to it: a point is
/// dropped when an earlier kept point lies within `distance` (file order, so the result does
/// not depend on threads). Returns the kept mask.
///
/// In parallel, in three steps over a grid of cells `2 · distance` wide ([`Grid`]): a ball of
/// radius `distance` lies within the 2 × 2 × 2 cells on the sides of the point's cell that its
/// position in the cell is nearer to, so each point looks at eight cells. (1) A point with no
/// earlier point within `distance` is kept; (2) one with an earlier point of (1) within
/// `distance` is dropped; (3) the rest (chains of near points, each of whose earlier
/// neighbours is itself undecided) are decided in file order, each after every earlier one:
/// 6 % of the points of the 20M hall scan, 25 % at 100M, where the stations' zenith rings hold
/// points a fraction of `distance` apart in file order, so that step stays serial.
/// Each step reads only decisions that are final, so the mask is the one pass in file order
/// gives (`merge_brute_force` in the tests).
pub fn merge_duplicates(positions: &[Vec3], distance: f32) -> Vec<bool> {
    // A little wider than 2 · distance, so that a point the f32 distance test accepts at
    // distance · (1 + rounding) is still in the window; and at least 2⁻⁴⁰ of the farthest
    // coordinate, so that cell coordinates stay far inside i64 (a distance far below the
    // coordinates' precision would put every point in one saturated cell, and the pass would
    // compare every pair). Any side of at least 2 · distance keeps the window whole.
    let reach = positions
        .par_iter()
        .map(|p| p.abs().max_element())
        .reduce(|| 0.0, f32::max);
    let side = (2.0 * f64::from(distance) * (1.0 + 1e-5)).max(f64::from(reach) * 2f64.powi(-40));
    let grid = Grid::new(positions, side, merge_d2(distance));
    // In grid order (`grid.index[s]` is the point at place `s`).
    let n = positions.len();
    // (1) No earlier point near: kept.
    let first: Vec<Merge> = (0..n)
        .into_par_iter()
        .map(|s| match grid.earlier_near(s, |_| true) {
            true => Merge::Unsure,
            false => Merge::Keep,
        })
        .collect();
    // (2) An earlier point of (1) near: dropped.
    let mut state: Vec<Merge> = (0..n)
        .into_par_iter()
        .map(|s| match first[s] {
            Merge::Unsure => match grid.earlier_near(s, |t| first[t] == Merge::Keep) {
                true => Merge::Drop,
                false => Merge::Unsure,
            },
            done => done,
        })
        .collect();
    drop(first);
    // (3) The rest in file order.
    let mut rest: Vec<u32> = (0..n as u32)
        .into_par_iter()
        .filter(|&s| state[s as usize] == Merge::Unsure)
        .collect();
    rest.par_sort_unstable_by_key(|&s| grid.index[s as usize]);
    for s in rest {
        let s = s as usize;
        state[s] = match grid.earlier_near(s, |t| state[t] == Merge::Keep) {
            true => Merge::Drop,
            false => Merge::Keep,
        };
    }
    let mut keep = vec![false; n];
    for (s, &i) in grid.index.iter().enumerate() {
        keep[i as usize] = state[s] == Merge::Keep;
    }
    keep
}

/// A point's standing in [`merge_duplicates`].
#[derive(Clone, Copy, PartialEq, Eq)]
enum Merge {
    Keep,
    Drop,
    /// Not decided yet: an earlier point lies near, not known to be kept.
    Unsure,
}

/// Every point of a cloud in cells of side `side`, sorted by cell along a Morton curve and,
/// within a cell, by file order. A cell's neighbours mostly lie near it along the curve, so a
/// point finds them by a galloping search from its own cell in the sorted list of occupied
/// cells, in memory it has just read (a hash table of cells, read at random, cost 2.5 times
/// as much on a 4M-point scan).
struct Grid {
    /// The points' positions, in grid order.
    at: Vec<Vec3>,
    /// The file index of the point at each place.
    index: Vec<u32>,
    /// The cell of the point at each place (its number in `codes`).
    cell: Vec<u32>,
    /// The occupied cells' codes, ascending, and the first place of each (and the end).
    codes: Vec<u64>,
    starts: Vec<u32>,
    side: f64,
    d2: f32,
}

impl Grid {
    fn new(positions: &[Vec3], side: f64, d2: f32) -> Grid {
        assert!(
            positions.len() < u32::MAX as usize,
            "at most u32::MAX − 1 points"
        );
        let mut order: Vec<(u64, u32)> = positions
            .par_iter()
            .enumerate()
            .map(|(i, &p)| (code(cell_of(p, side).0), i as u32))
            .collect();
        // (The pairs are unique: the result does not depend on the sort.)
        order.par_sort_unstable();
        let firsts: Vec<u32> = (0..order.len() as u32)
            .into_par_iter()
            .filter(|&s| s == 0 || order[s as usize].0 != order[s as usize - 1].0)
            .collect();
        let codes = firsts.par_iter().map(|&s| order[s as usize].0).collect();
        let mut starts = firsts;
        starts.push(order.len() as u32);
        let mut cell = vec![0u32; order.len()];
        cell.par_chunks_mut(1 << 16)
            .enumerate()
            .for_each(|(k, chunk)| {
                let lo = k << 16;
                let mut c = starts.partition_point(|&s| s as usize <= lo) - 1;
                for (s, out) in (lo..).zip(chunk) {
                    while starts[c + 1] as usize <= s {
                        c += 1;
                    }
                    *out = c as u32;
                }
            });
        let index: Vec<u32> = order.par_iter().map(|&(_, i)| i).collect();
        drop(order);
        let at = index.par_iter().map(|&i| positions[i as usize]).collect();
        Grid {
            at,
            index,
            cell,
            codes,
            starts,
            side,
            d2,
        }
    }

    /// The number of the occupied cell with code `want`, searched from cell `from` outward.
    fn find(&self, from: usize, want: u64) -> Option<usize> {
        let codes = &self.codes;
        let (lo, hi) = if want >= codes[from] {
            let mut step = 1;
            let mut lo = from;
            while lo + step < codes.len() && codes[lo + step] < want {
                lo += step;
                step *= 2;
            }
            (lo, (lo + step + 1).min(codes.len()))
        } else {
            let mut step = 1;
            let mut hi = from;
            while hi >= step && codes[hi - step] > want {
                hi -= step;
                step *= 2;
            }
            (hi.saturating_sub(step), hi)
        };
        let at = lo + codes[lo..hi].partition_point(|&c| c < want);
        (at < codes.len() && codes[at] == want).then_some(at)
    }

    /// Whether a point earlier in the file than the one at place `s`, and `of(place)`, lies
    /// within the distance of it.
    fn earlier_near(&self, s: usize, of: impl Fn(usize) -> bool) -> bool {
        let (p, i) = (self.at[s], self.index[s]);
        let (c, near) = cell_of(p, self.side);
        let step = near.map(|lower| if lower { -1 } else { 1 });
        let own = self.cell[s] as usize;
        (0..8).any(|corner: usize| {
            let at = std::array::from_fn(|a| c[a] + step[a] * ((corner >> a) & 1) as i64);
            let Some(k) = (match corner {
                0 => Some(own),
                _ => self.find(own, code(at)),
            }) else {
                return false;
            };
            // Within a cell, file order: the earlier points come first.
            (self.starts[k] as usize..self.starts[k + 1] as usize)
                .take_while(|&t| self.index[t] < i)
                .any(|t| self.at[t].distance_squared(p) < self.d2 && of(t))
        })
    }
}

/// A cell's place along the Morton curve: its coordinates' low 21 bits interleaved, so cells
/// 2²¹ apart share a code (the callers test real distances, so that costs only the time to
/// test the other cell's points).
fn code(c: [i64; 3]) -> u64 {
    let b = |v: i64| (v as u64 & 0x1f_ffff) as u32;
    spread(b(c[0])) | spread(b(c[1])) << 1 | spread(b(c[2])) << 2
}

/// The cell holding `p` (side `side`), and per axis whether `p` lies in the cell's lower half
/// (its ball then reaches into the lower neighbour).
fn cell_of(p: Vec3, side: f64) -> ([i64; 3], [bool; 3]) {
    let t = p.as_dvec3() / side;
    let c = t.floor();
    let lower = (t - c).cmplt(DVec3::splat(0.5));
    (
        [c.x, c.y, c.z].map(|v| v as i64),
        [lower.x, lower.y, lower.z],
    )
}

/// The squared distance below which two points merge: `distance²`, but never below the
/// smallest normal f32, so that exact copies merge however small the distance (its square
/// would underflow to 0 below about 1e-19).
fn merge_d2(distance: f32) -> f32 {
    (distance * distance).max(f32::MIN_POSITIVE)
}

/// Statistical outlier removal (Rusu et al. 2008, as PCL's `StatisticalOutlierRemoval`): the
/// mean distance of each point to its `k` nearest neighbours; a point whose mean exceeds the
/// mean of all by more than `std_ratio` standard deviations is dropped. Returns the kept mask.
pub fn remove_outliers(positions: &[Vec3], k: usize, std_ratio: f32) -> Vec<bool> {
    let n = positions.len();
    if n <= k {
        return vec![true; n];
    }
    let means: Vec<f64> = Knn::new(positions).map(k, |_, near| {
        let sum: f64 = near.iter().map(|&(_, d2)| f64::from(d2).sqrt()).sum();
        sum / near.len().max(1) as f64
    });
    let mean = means.iter().sum::<f64>() / n as f64;
    let var = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / n as f64;
    let limit = mean + f64::from(std_ratio) * var.sqrt();
    means.iter().map(|&m| m <= limit).collect()
}

impl PointSet {
    /// Keep the points whose `keep` entry is true, in every per-point array; the others are
    /// counted under `reason`.
    pub fn retain(&mut self, keep: &[bool], reason: &str) {
        let gone = keep.iter().filter(|k| !**k).count();
        if gone == 0 {
            return;
        }
        fn filter<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut it = keep.iter();
            v.retain(|_| *it.next().unwrap_or(&true));
        }
        filter(&mut self.positions, keep);
        for v in [&mut self.normals, &mut self.colors].into_iter().flatten() {
            filter(v, keep);
        }
        for v in [&mut self.radii, &mut self.intensity].into_iter().flatten() {
            filter(v, keep);
        }
        if let Some(v) = &mut self.classes {
            filter(v, keep);
        }
        if let Some(v) = &mut self.source_ids {
            filter(v, keep);
        }
        if let Some(v) = &mut self.station_of {
            filter(v, keep);
        }
        self.dropped += gone;
        self.drop_reasons.push((reason.to_string(), gone));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn duplicates_within_the_distance_merge_into_the_first() {
        let p = [
            Vec3::ZERO,
            Vec3::new(0.004, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 0.006, 0.0),
            Vec3::new(1.0, 0.003, 0.0),
            Vec3::ZERO,
        ];
        assert_eq!(
            merge_duplicates(&p, 0.005),
            [true, false, true, true, false, false]
        );
    }

    /// The rule itself, point by point against every earlier kept point.
    fn merge_brute_force(p: &[Vec3], distance: f32) -> Vec<bool> {
        let mut keep = vec![false; p.len()];
        let d2 = merge_d2(distance);
        for i in 0..p.len() {
            keep[i] = !(0..i).any(|j| keep[j] && p[j].distance_squared(p[i]) < d2);
        }
        keep
    }

    #[test]
    fn merging_matches_the_rule_point_by_point() {
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut u = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        let d = 0.01;
        for origin in [Vec3::ZERO, Vec3::new(512.25, -403.5, 21.0)] {
            let mut p = Vec::new();
            // A noisy plane with spacing near the distance, a dense clump, exact copies, points
            // on cell borders, and strays.
            for i in 0..1500 {
                let (x, y) = ((i % 50) as f32 * 0.008, (i / 50) as f32 * 0.008);
                p.push(origin + Vec3::new(x + 0.004 * u(), y + 0.004 * u(), 0.003 * u()));
            }
            for _ in 0..500 {
                p.push(origin + Vec3::new(0.2, 0.1, 0.0) + 0.02 * Vec3::new(u(), u(), u()));
            }
            for k in 0..200 {
                p.push(p[k * 7]);
                p.push(origin + Vec3::new(k as f32 * 2.0 * d, 0.5, 0.0));
                p.push(origin + Vec3::new(k as f32 * 2.0 * d + 0.999 * d, 0.5, 0.0));
                p.push(origin + 10.0 * Vec3::new(u(), u(), u()));
            }
            // Shuffle the file order.
            for i in (1..p.len()).rev() {
                p.swap(i, (u() * (i + 1) as f32) as usize % (i + 1));
            }
            let got = merge_duplicates(&p, d);
            assert_eq!(got, merge_brute_force(&p, d), "origin {origin}");
            let merged = got.iter().filter(|k| !**k).count();
            assert!(merged > 500 && merged < p.len() - 500, "{merged} merged");
        }
        // A distance far below the coordinates' precision merges exact copies only, and does
        // not put every point in one cell (which would compare every pair).
        let p: Vec<Vec3> = (0..4000)
            .map(|i| Vec3::new(100.0 + (i % 71) as f32 * 0.01, (i / 71) as f32 * 0.01, 5.0))
            .chain([Vec3::new(100.0, 0.0, 5.0)])
            .collect();
        let kept = merge_duplicates(&p, 1e-30);
        assert_eq!(kept, merge_brute_force(&p, 1e-30));
        assert_eq!(kept.iter().filter(|k| !**k).count(), 1);
        // Cells 2²¹ apart share a key, not a merge.
        let far = 2.0 * (1u32 << 21) as f32 * 1.000_01;
        let p =
            [0.0, 0.5, far, far + 0.5, far + 3.0, 0.4, far + 0.1].map(|x| Vec3::new(x, 0.0, 0.0));
        assert_eq!(merge_duplicates(&p, 1.0), merge_brute_force(&p, 1.0));
        assert_eq!(
            merge_duplicates(&p, 1.0),
            [true, false, true, false, true, false, false]
        );
    }

    #[test]
    fn long_chains_of_near_points_merge_as_in_file_order() {
        // A scanner's ring near its zenith: points a seventh of the distance apart in file
        // order, each near the six before it, twice over (a second station), then a grid.
        let d = 0.01;
        let mut p: Vec<Vec3> = (0..3000)
            .map(|k| {
                let a = k as f32 * d / 7.0 / 0.3;
                Vec3::new(0.3 * a.cos(), 0.3 * a.sin(), 0.0)
            })
            .collect();
        let second: Vec<Vec3> = p
            .iter()
            .rev()
            .map(|&q| q + Vec3::new(0.0, 0.0, 0.4 * d))
            .collect();
        p.extend(second);
        p.extend(
            (0..2000).map(|k| Vec3::new((k % 40) as f32 * 0.6 * d, (k / 40) as f32 * 0.6 * d, 0.5)),
        );
        assert_eq!(merge_duplicates(&p, d), merge_brute_force(&p, d));
    }

    #[test]
    fn a_stray_point_off_a_plane_is_an_outlier() {
        let mut p: Vec<Vec3> = (0..400)
            .map(|i| Vec3::new((i % 20) as f32 * 0.01, (i / 20) as f32 * 0.01, 0.0))
            .collect();
        p.push(Vec3::new(0.1, 0.1, 0.5));
        let keep = remove_outliers(&p, 8, 2.0);
        assert!(!keep[400], "the stray point goes");
        assert!(keep[..400].iter().all(|k| *k), "the plane stays");
    }
}
