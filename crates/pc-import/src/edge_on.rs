//! Normals their scanner sees edge-on (docs/import.md, "Orientation").
//!
//! A normal is turned to face the scanner that saw its point: its sign is that of `n · ray`.
//! Where the scanner sees the surface edge-on (a column's silhouette, incidence near 90°) that
//! product is about zero and its sign is the fit's noise: on the 20M-point hall scan 521
//! splats along the columns' silhouettes faced into the columns (dark specks where a render
//! sees them).
//! Such a point takes its sign from the neighbours that their scanners see squarely instead:
//! it turns to agree with the sum of their normals, where they agree enough to tell, and
//! where the turn leaves it facing away from its scanner by the fit's few degrees, it moves
//! onto the plane of the ray (a surface its scanner saw faces it, if only just).

use glam::Vec3;
use rayon::prelude::*;

use crate::knn::Knn;

/// A normal is seen edge-on where `|n · ray|` is below this (incidence past 81°).
pub const EDGE_ON: f32 = 0.15;

/// The neighbours asked: those within this many of the point's k-th neighbour distances.
const REACH: f32 = 2.0;

/// A ball holding more points than this is given up (the sign stays).
const MOST: usize = 1024;

/// Re-decides the sign of every normal seen edge-on by its scanner (`ray(i)`, the unit
/// direction from point `i` to it; none, none decided) by its squarely seen neighbours;
/// `kth2[i]` is the squared distance of point `i`'s k-th neighbour. Normals face their
/// scanners before and after.
pub(crate) fn settle(
    knn: &Knn,
    normals: &mut [Vec3],
    kth2: &[f32],
    ray: impl Fn(usize) -> Option<Vec3> + Sync,
) {
    let squarely = |i: usize| ray(i).is_some_and(|u| normals[i].dot(u).abs() >= EDGE_ON);
    let reach2: Vec<f32> = (0..normals.len())
        .into_par_iter()
        .map(|i| match ray(i).is_some() && !squarely(i) {
            true => REACH * REACH * kth2[i],
            false => 0.0,
        })
        .collect();
    if !reach2.iter().any(|&r| r > 0.0) {
        return;
    }
    let flip = knn.map_within(&reach2, MOST, |i, inside, _| {
        let (mut agree, mut weight) = (0.0f32, 0.0f32);
        for &(j, _) in inside.iter().filter(|&&(j, _)| squarely(j as usize)) {
            let c = normals[i].dot(normals[j as usize]);
            agree += c;
            weight += c.abs();
        }
        // Flip only where the squarely seen neighbours disagree clearly (most of their
        // weight against): a crease's other face, at right angles, tells nothing.
        agree < -0.5 * weight && weight > 0.0
    });
    normals
        .par_iter_mut()
        .zip(&flip)
        .enumerate()
        .for_each(|(i, (n, f))| {
            if let (Some(true), Some(u)) = (f, ray(i)) {
                *n = turned(*n, u);
            }
        });
}

/// `n` turned round, and where that leaves it facing away from its scanner (`u`, the unit
/// direction to it) by the fit's noise, moved onto the plane of the ray: a surface the
/// scanner saw faces it, if only just.
fn turned(n: Vec3, u: Vec3) -> Vec3 {
    let n = -n;
    match n.dot(u) < 0.0 {
        true => (n - u * n.dot(u) + u * 1e-4).normalize_or(n),
        false => n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_turned_normal_still_faces_its_scanner() {
        let u = Vec3::Y;
        // Facing it by a little, turned: away by as little, then onto the ray's plane.
        let n = Vec3::new(1.0, 0.02, 0.0).normalize();
        let t = turned(n, u);
        assert!(t.dot(u) >= 0.0 && t.dot(u) < 1e-3, "{t}");
        assert!(t.dot(-n) > 0.999, "{t}");
        // Facing away by a little, turned: facing it, unmoved.
        let n = Vec3::new(1.0, -0.02, 0.0).normalize();
        assert_eq!(turned(n, u), -n);
    }
}
