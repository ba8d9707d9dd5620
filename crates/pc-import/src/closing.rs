//! Radii that close a point's neighbourhood in every direction (docs/import.md, "Radius
//! estimation", "Ring sampling").
//!
//! The spacing radius (`sqrt(2π · mean(d²) / k)` over the k nearest) assumes those neighbours
//! lie around the point. Where a scan is dense along lines and sparse across them (a terrestrial
//! station's zenith, where its rings of constant elevation converge), the k nearest all lie on
//! the point's own ring, the radius is the spacing along it, and the disks leave gaps between
//! the rings that light leaks through. So a point's radius is also at least [`CLOSE_FACTOR`]
//! times its *closing distance*: the distance at which its neighbours, taken nearest first and
//! projected on its tangent plane, first leave no angular gap wider than a third of a turn. On
//! a uniform sampling that distance is about the spacing and the factor mostly keeps the radius
//! as it was; across rings it is the gap between the rings. A point on a border never closes
//! (the open side is half a turn) and keeps its radius.

use glam::Vec3;
use rayon::prelude::*;

use crate::knn::Knn;

/// The radius is at least this times the closing distance: two rows `g` apart are closed by
/// disks of `g / 2`, and the margin covers the jitter of the rows.
pub const CLOSE_FACTOR: f32 = 0.6;

/// Neighbours not closed by their k nearest are looked for within this many of their radii
/// (the gaps between a 1M-point scan's zenith rings reach 8 radii).
const CLOSE_REACH: f32 = 10.0;

/// A ball holding more points than this is given up (the point keeps its radius).
const CLOSE_MOST: usize = 1024;

/// Directions of the tangent plane, as bins of a 64-bit mask.
const BINS: u32 = 64;

/// A run of this many empty bins (118°) is a gap wider than a third of a turn, about. A quarter
/// turn (16 bins) raised two thirds of the radii of a random sampling (by 1.23 times at the
/// median) and the hall scan's disk areas by 11 %; a third of a turn raised a third of them (by
/// 1.13) and the disks by 8 %, and closed the hall's zeniths as well.
const OPEN_RUN: u32 = 21;

/// Whether the directions in `mask` leave no run of [`OPEN_RUN`] empty bins, all round.
fn closed(mask: u64) -> bool {
    // Bit b of `run` is set where OPEN_RUN empty bins start at b (circularly).
    let empty = !mask;
    let mut run = empty;
    let mut len = 1;
    while len < OPEN_RUN {
        let step = len.min(OPEN_RUN - len);
        run &= run.rotate_right(step);
        len += step;
    }
    run == 0
}

/// The squared closing distance ([`crate::closing`]) of a point of normal `n` among its
/// neighbours' `offsets` and squared distances `d2`, nearest first; `None` when they never
/// close (a border, or too few of them).
pub fn closing_d2(n: Vec3, neighbours: impl Iterator<Item = (Vec3, f32)>) -> Option<f32> {
    let (u, v) = n.any_orthonormal_pair();
    let mut mask = 0u64;
    for (o, d2) in neighbours {
        let (a, b) = (o.dot(u), o.dot(v));
        if a == 0.0 && b == 0.0 {
            continue; // straight above or below: no direction
        }
        let turn = b.atan2(a) / std::f32::consts::TAU + 0.5; // [0, 1]
        let bin = ((turn * BINS as f32) as u32).min(BINS - 1);
        mask |= 1 << bin;
        if closed(mask) {
            return Some(d2);
        }
    }
    None
}

/// Raises every radius to [`CLOSE_FACTOR`] times its point's closing distance. `first[i]` is
/// the squared closing distance among point i's k nearest (`None` when they did not close);
/// the others are looked for within [`CLOSE_REACH`] radii, with the final normals.
pub fn close_radii(
    knn: &Knn,
    positions: &[Vec3],
    normals: &[Vec3],
    first: &[Option<f32>],
    radii: &mut [f32],
) {
    let reach2: Vec<f32> = (first, &*radii)
        .into_par_iter()
        .map(|(f, &r)| match f {
            None if r.is_finite() && r > 0.0 => (CLOSE_REACH * r) * (CLOSE_REACH * r),
            _ => 0.0,
        })
        .collect();
    let wide = match reach2.iter().any(|&r| r > 0.0) {
        true => knn.map_within(&reach2, CLOSE_MOST, |i, inside, offsets| {
            let mut near: Vec<(Vec3, f32)> = offsets
                .iter()
                .zip(inside)
                .map(|(&o, &(_, d2))| (Vec3::from(o), d2))
                .collect();
            near.sort_by(|a, b| a.1.total_cmp(&b.1));
            closing_d2(normals[i], near.into_iter())
        }),
        false => vec![None; positions.len()],
    };
    (radii, first, &wide).into_par_iter().for_each(|(r, f, w)| {
        if let Some(d2) = f.or(w.flatten()) {
            *r = r.max(CLOSE_FACTOR * d2.sqrt());
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quarter_turn_gap_is_closed_and_a_wider_one_is_not() {
        // Gaps of at most 100° close; one of 140° or 190° does not.
        let n = Vec3::Z;
        let (u, v) = n.any_orthonormal_pair();
        let at = |deg: f32| {
            let a = deg.to_radians();
            ((u * a.cos() + v * a.sin()) * 0.01, 1e-4)
        };
        let four = [at(10.0), at(100.0), at(190.0), at(280.0)];
        assert_eq!(closing_d2(n, four.into_iter()), Some(1e-4));
        let three = [at(0.0), at(110.0), at(220.0)];
        assert_eq!(closing_d2(n, three.into_iter()), None);
        let wide = [at(10.0), at(100.0), at(190.0)];
        assert_eq!(closing_d2(n, wide.into_iter()), None);
        // A straight border: neighbours on one side only.
        let half: Vec<_> = (0..12).map(|k| at(k as f32 * 15.0)).collect();
        assert_eq!(closing_d2(n, half.into_iter()), None);
    }

    #[test]
    fn the_mask_test_finds_every_run() {
        assert!(closed(u64::MAX));
        assert!(!closed(0));
        // One occupied bin every 21 (runs of 20 empty): closed; every 22 (runs of 21): open.
        let every = |k: u32| (0..BINS).step_by(k as usize).fold(0u64, |m, b| m | 1 << b);
        assert!(closed(every(21)));
        assert!(!closed(every(22)));
    }
}
