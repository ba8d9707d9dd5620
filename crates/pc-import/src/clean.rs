//! Cleaning a raw scan before it becomes splats: duplicate points merged (overlapping
//! stations scan the same surface twice) and stray points removed (statistical outlier
//! removal). Both are `[import]` options, off by default, applied to each model on its own, in
//! the file's frame, before normals and radii are estimated; what they remove is counted in
//! the model's report. docs/import.md, "Cleaning a scan".

use glam::{DVec3, Vec3};

use crate::knn::Knn;
use crate::points::PointSet;

/// Keeps the first point of every cluster of points closer than `distance` to it: a point is
/// dropped when an earlier kept point lies within `distance` (file order, so the result does
/// not depend on threads). Returns the kept mask.
///
/// One pass in file order over a grid of cells `2 · distance` wide holding the kept points
/// (a list per cell, threaded through `next`): a ball of radius `distance` lies within the
/// 2 × 2 × 2 cells on the sides of the point's cell that its position in the cell is nearer
/// to, so each point looks up eight cells. Kept points of one cell lie at least `distance`
/// apart, so a cell holds a bounded few of them, however dense the scan.
pub fn merge_duplicates(positions: &[Vec3], distance: f32) -> Vec<bool> {
    const NONE: u32 = u32::MAX;
    // A little wider than 2 · distance, so that a point the f32 distance test accepts at
    // distance · (1 + rounding) is still in the window; and at least 2⁻⁴⁰ of the farthest
    // coordinate, so that cell coordinates stay far inside i64 (a distance far below the
    // coordinates' precision would put every point in one saturated cell, and the pass would
    // compare every pair). Any side of at least 2 · distance keeps the window whole.
    let reach = positions
        .iter()
        .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
    let side = (2.0 * f64::from(distance) * (1.0 + 1e-5)).max(f64::from(reach) * 2f64.powi(-40));
    let d2 = merge_d2(distance);
    let mut cells = CellTable::new();
    let mut next = vec![NONE; positions.len()];
    let mut keep = vec![false; positions.len()];
    for (i, &p) in positions.iter().enumerate() {
        let t = p.as_dvec3() / side;
        let c = t.floor();
        // The neighbour on the side the point is nearer to, per axis.
        let step = (t - c).cmplt(DVec3::splat(0.5));
        let c = [c.x, c.y, c.z].map(|v| v as i64);
        let s = [step.x, step.y, step.z].map(|lower| if lower { -1 } else { 1 });
        let near = (0..8).any(|corner: usize| {
            let at = std::array::from_fn(|a| c[a] + s[a] * ((corner >> a) & 1) as i64);
            let mut j = cells.head(at);
            while j != NONE {
                if positions[j as usize].distance_squared(p) < d2 {
                    return true;
                }
                j = next[j as usize];
            }
            false
        });
        if !near {
            keep[i] = true;
            let head = cells.head_mut(c);
            next[i] = *head;
            *head = i as u32;
        }
    }
    keep
}

/// The squared distance below which two points merge: `distance²`, but never below the
/// smallest normal f32, so that exact copies merge however small the distance (its square
/// would underflow to 0 below about 1e-19).
fn merge_d2(distance: f32) -> f32 {
    (distance * distance).max(f32::MIN_POSITIVE)
}

/// Grid cells (integer coordinates) to the first point of their list: open addressing with
/// linear probing, kept at most half full. Coordinates are wrapped to 21 bits an axis for the
/// key, so cells 2²¹ apart share a list; the callers test real distances, so that costs only
/// the time to test the other cell's points.
struct CellTable {
    keys: Vec<u64>,
    heads: Vec<u32>,
    len: usize,
}

impl CellTable {
    const EMPTY: u64 = u64::MAX;

    fn new() -> CellTable {
        CellTable {
            keys: vec![Self::EMPTY; 1024],
            heads: vec![u32::MAX; 1024],
            len: 0,
        }
    }

    /// The cell's key: its coordinates' low 21 bits (never [`Self::EMPTY`], which has bit 63).
    fn key(c: [i64; 3]) -> u64 {
        let b = |v: i64| (v as u64) & 0x1f_ffff;
        b(c[0]) | b(c[1]) << 21 | b(c[2]) << 42
    }

    /// Where the key's probe sequence starts (Fibonacci hashing).
    fn start(&self, key: u64) -> usize {
        let bits = self.keys.len().trailing_zeros();
        (key.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> (64 - bits)) as usize
    }

    /// The slot that holds `key`, or the empty slot where it would go.
    fn slot(&self, key: u64) -> usize {
        let mask = self.keys.len() - 1;
        let mut s = self.start(key);
        while self.keys[s] != key && self.keys[s] != Self::EMPTY {
            s = (s + 1) & mask;
        }
        s
    }

    /// The cell's first point, `u32::MAX` for none (an empty slot's head).
    fn head(&self, c: [i64; 3]) -> u32 {
        self.heads[self.slot(Self::key(c))]
    }

    /// The cell's first point, made (`u32::MAX`) if the cell has none.
    fn head_mut(&mut self, c: [i64; 3]) -> &mut u32 {
        if 2 * (self.len + 1) > self.keys.len() {
            self.grow();
        }
        let key = Self::key(c);
        let s = self.slot(key);
        if self.keys[s] == Self::EMPTY {
            self.keys[s] = key;
            self.len += 1;
        }
        &mut self.heads[s]
    }

    fn grow(&mut self) {
        let cap = 2 * self.keys.len();
        let keys = std::mem::replace(&mut self.keys, vec![Self::EMPTY; cap]);
        let heads = std::mem::replace(&mut self.heads, vec![u32::MAX; cap]);
        for (k, h) in keys.into_iter().zip(heads) {
            if k != Self::EMPTY {
                let s = self.slot(k);
                (self.keys[s], self.heads[s]) = (k, h);
            }
        }
    }
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
