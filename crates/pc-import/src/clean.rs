//! Cleaning a raw scan before it becomes splats: duplicate points merged (overlapping
//! stations scan the same surface twice) and stray points removed (statistical outlier
//! removal). Both are `[import]` options, off by default, applied to each model on its own, in
//! the file's frame, before normals and radii are estimated; what they remove is counted in
//! the model's report. docs/import.md, "Cleaning a scan".

use std::collections::HashMap;

use glam::{IVec3, Vec3};

use crate::knn::Knn;
use crate::points::PointSet;

/// Keeps the first point of every cluster of points closer than `distance` to it: a point is
/// dropped when an earlier kept point lies within `distance` (file order, so the result does
/// not depend on threads). One pass over a hash grid of cell `distance`. Returns the kept mask.
pub fn merge_duplicates(positions: &[Vec3], distance: f32) -> Vec<bool> {
    let cell_of = |p: Vec3| (p / distance).floor().as_ivec3();
    let d2 = distance * distance;
    let mut grid: HashMap<IVec3, Vec<u32>> = HashMap::new();
    let mut keep = vec![false; positions.len()];
    for (i, &p) in positions.iter().enumerate() {
        let c = cell_of(p);
        let near = (-1..=1).any(|dz| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    grid.get(&(c + IVec3::new(dx, dy, dz))).is_some_and(|v| {
                        v.iter()
                            .any(|&j| positions[j as usize].distance_squared(p) < d2)
                    })
                })
            })
        });
        if !near {
            keep[i] = true;
            grid.entry(c).or_default().push(i as u32);
        }
    }
    keep
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
