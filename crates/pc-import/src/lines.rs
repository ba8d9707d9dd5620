//! Neighbourhoods sampled along lines (docs/import.md, "Line sampling").
//!
//! The spacing radius and the k-nearest plane fit assume a point's nearest neighbours lie
//! around it on its surface. Where a scan is dense along lines and sparse across them they do
//! not: at a terrestrial station's zenith (and nadir) its rings of constant elevation
//! converge, the points lie `R Δθ` apart across the rings and `R θ Δθ` along them (`θ` the
//! angle from the zenith), and within about a fifth of a radian of it the k nearest all lie on
//! the point's own ring. Their fitted plane then turns about the ring with the range noise
//! (the 1M-point hall scan: ceiling normals tilted past 25° within 0.25 m of each zenith),
//! and the radius is the spacing along the ring, so the disks leave the rings apart and
//! sunlight falls through the ceiling.
//!
//! Such a point is found by the shape of its neighbourhood ([`Shape`]) and looks further
//! ([`look`]): the nearest point across its line (at least [`ACROSS_ANGLE`] off it) sets the
//! spacing `s` across; the radius becomes at least [`CLOSE_FACTOR`]` · s`, and where the
//! normal's own neighbours lay on the line, the normal is fitted again over the points within
//! [`FIT_REACH`]` · s`, which span the neighbouring lines too. A border is not a line (a
//! half-disk of neighbours has the same second moment along and across its edge, about the
//! point), so a border point keeps its radius, and the raise is bounded by the spacing across
//! the lines: the disks close the gaps between lines and reach no further into an opening
//! than a line's spacing.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::estimate::{principal_axes, Fit};
use crate::knn::Knn;

/// A neighbourhood is a line where its second moment about the point across the line is below
/// this share of the moment along it. On a plane sampled evenly the share is about 1 (a
/// half-disk at a border: 1 too), and 8 or 16 random neighbours fall below 0.1 about once in
/// a few hundred; on a ring with range noise as large as the spacing along it, 16 neighbours
/// give about 0.08 in 3D, the noise included.
pub(crate) const LINE_SHARE: f64 = 0.1;

/// An offset at least this far off the line's direction (radians) is across it.
pub const ACROSS_ANGLE: f32 = std::f32::consts::FRAC_PI_3;

/// The radius is at least this times the spacing across the lines: lines `s` apart are
/// closed by disks of `s / 2`, and the margin covers their jitter.
pub const CLOSE_FACTOR: f32 = 0.6;

/// A refitted normal takes the points within this many across-spacings: the point's own line
/// and one neighbouring line on each side.
pub const FIT_REACH: f32 = 1.5;

/// How far the look reaches, in distances of the point's k-th neighbour, one round each: the
/// first finds the next ring at a merged scan's zenith (the rings about as far apart as the
/// k-th neighbour along one), the second a little further. (On the 1M hall scan a second round
/// at 8 changed 0.35 % of the splats against 5 and took a quarter second more; a third at 48
/// found nothing: every such ball held more than [`MOST`] points.)
const REACHES: [f32; 2] = [3.0, 5.0];

/// A raised radius is at most this many times the distance of the point's k-th neighbour.
/// Where another station's sparser points lie across a dense scan line (a floor at a wall's
/// foot, seen at a grazing angle from one station and steeply from another), the third point
/// across may lie far off: on the 20M hall scan such radii grew 15-fold, to 14 cm.
const RAISE_CAP: f64 = 1.5;

/// The spacing across a line is read at this many points across it ([`across_spacing`]): the
/// next line has many near its closest, a stray point one.
const ACROSS_RANK: usize = 3;

/// Across the ray, a point nearer than this share of the median distance of the k nearest
/// is the same spot at another range, not across the line.
const SAME_SPOT: f64 = 0.25;

/// A point across the line is at most this many times farther along the ray than across it
/// (on the point's own surface up to 63° from facing the scanner).
const RAY_DEPTH: f64 = 2.0;

/// A refitted plane must face the scanner's ray at least this much (the cosine: within 84°).
const FACING: f64 = 0.1;

/// A ball holding more points than this is given up (the point keeps its estimate).
const MOST: usize = 4096;

/// The across neighbour must lie on the refitted plane, within this slope (31°: the range
/// noise of both points, 1.6 of its deviations apart at 0.35, failed one look in ten).
const ON_PLANE: f32 = 0.6;

/// Which of a point's estimates its neighbourhood's shape leaves unsure.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) enum Shape {
    /// Neighbours around the point: both estimates stand.
    #[default]
    Around,
    /// The radius's neighbours lie on a line in the point's tangent plane (the normal's, more
    /// of them, did not): the radius is the spacing along the line.
    RadiusOnLine,
    /// The normal's neighbours lie on a line in space: the fitted plane turns about it with
    /// the noise, and the radius is wrong too.
    Line,
}

impl Shape {
    /// The shape of point `i`'s neighbourhood: `normal_near` its k nearest for the normal,
    /// `radius_near` for the radius (both nearest first), `normal` the plane fitted to the
    /// first, `ray` the unit direction to its scanner where known. The line in space is
    /// looked for across the ray: the range noise along it, as deep as the spacing along a
    /// ring or deeper, would make a ring's points a sheet ([`across_ray`]).
    pub(crate) fn of(
        positions: &[Vec3],
        i: usize,
        normal_near: &[(u32, f32)],
        radius_near: &[(u32, f32)],
        normal: Vec3,
        ray: Option<Vec3>,
    ) -> Shape {
        let o = positions[i].as_dvec3();
        let offset = |&(j, _): &(u32, f32)| positions[j as usize].as_dvec3() - o;
        let in_space = match ray {
            Some(u) => is_line_in_plane(normal_near.iter().map(offset), u),
            None => is_line(normal_near.iter().map(offset)),
        };
        if in_space {
            return Shape::Line;
        }
        match is_line_in_plane(radius_near.iter().map(offset), normal) {
            true => Shape::RadiusOnLine,
            false => Shape::Around,
        }
    }
}

/// [`is_line`] for offsets projected on the plane of normal `n` (across the ray, or on the
/// tangent plane): the eigenvalues of a 2×2 second moment, in closed form (the estimate asks
/// this of every point, twice; Jacobi sweeps took a tenth of the import).
fn is_line_in_plane(offsets: impl Iterator<Item = DVec3>, n: Vec3) -> bool {
    let (e1, e2) = n.as_dvec3().any_orthonormal_pair();
    let (mut a, mut b, mut c) = (0.0f64, 0.0f64, 0.0f64);
    for o in offsets {
        let (x, y) = (o.dot(e1), o.dot(e2));
        a += x * x;
        b += x * y;
        c += y * y;
    }
    let (mean, half) = ((a + c) / 2.0, ((a - c) / 2.0).hypot(b));
    let (large, small) = (mean + half, mean - half);
    large > 0.0 && small < LINE_SHARE * large
}

/// An offset less its part along the scanner's ray `ray` (all of it where there is none):
/// what is left of it once the range noise is taken out.
fn across_ray(o: DVec3, ray: Option<Vec3>) -> DVec3 {
    match ray {
        Some(u) => {
            let u = u.as_dvec3();
            o - u * o.dot(u)
        }
        None => o,
    }
}

/// Whether offsets from a point lie along one line through it ([`LINE_SHARE`]): the second
/// moment about the point, not about the mean, so that a border's half-disk is no line.
fn is_line(offsets: impl Iterator<Item = DVec3>) -> bool {
    let (vals, _) = principal_axes(offsets);
    vals[0] > 0.0 && vals[1] < LINE_SHARE * vals[0]
}

/// The direction of a line through a point, from offsets of points on it (the axis of their
/// largest second moment about the point).
fn line_direction(offsets: impl Iterator<Item = DVec3>) -> DVec3 {
    principal_axes(offsets).1[0]
}

/// What a point's wider look found ([`look`]).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Found {
    /// Nothing across the line within the reach: look further.
    Nothing,
    /// Across the line, but not on the point's surface (another surface, or a line in space):
    /// the estimates stand.
    NotItsSurface,
    /// The least radius that closes the gaps across the line, and the normal fitted over the
    /// neighbouring lines (where the shape asked for it).
    Across { radius: f32, normal: Option<Vec3> },
}

/// Looks across the lines for every point whose [`Shape`] is not `Around`, and raises its
/// radius (where radii are asked) and refits its normal by what it finds: see the module.
/// `kth2[i]` is the squared distance of point `i`'s k-th neighbour, `k` the neighbours its
/// line was found among.
pub(crate) fn close(
    knn: &Knn,
    shapes: &[Shape],
    kth2: &[f32],
    k: usize,
    ray: impl Fn(usize) -> Option<Vec3> + Sync,
    normals: &mut [Vec3],
    mut radii: Option<&mut [f32]>,
) {
    let mut pending: Vec<bool> = shapes.par_iter().map(|&s| s != Shape::Around).collect();
    for reach in REACHES {
        if !pending.iter().any(|&p| p) {
            break;
        }
        let reach2: Vec<f32> = (&pending, kth2)
            .into_par_iter()
            .map(|(&p, &d2)| match p {
                true => reach * reach * d2,
                false => 0.0,
            })
            .collect();
        let found = knn.map_within(&reach2, MOST, |i, inside, offsets| {
            look(shapes[i], normals[i], ray(i), k, inside, offsets)
        });
        (&mut pending, &found, &mut *normals)
            .into_par_iter()
            .for_each(|(p, found, n)| {
                *p = *found == Some(Found::Nothing);
                if let Some(Found::Across {
                    normal: Some(normal),
                    ..
                }) = found
                {
                    *n = *normal;
                }
            });
        if let Some(radii) = radii.as_deref_mut() {
            (radii, &found).into_par_iter().for_each(|(r, found)| {
                if let Some(Found::Across { radius, .. }) = found {
                    *r = r.max(*radius);
                }
            });
        }
    }
}

/// One point's look ([`close`]): its neighbours `inside` the reach (index, squared distance)
/// at `offsets` from it. The line and the spacing across it are read across the scanner's
/// `ray` where there is one ([`across_ray`]).
fn look(
    shape: Shape,
    normal: Vec3,
    ray: Option<Vec3>,
    k: usize,
    inside: &[(u32, f32)],
    offsets: &[[f32; 3]],
) -> Found {
    // (squared distance, offset, the offset across the ray)
    let mut near: Vec<(f32, DVec3, DVec3)> = inside
        .iter()
        .zip(offsets)
        .map(|(&(_, d2), &o)| {
            let o = Vec3::from(o).as_dvec3();
            (d2, o, across_ray(o, ray))
        })
        .collect();
    let k = k.min(near.len());
    if k < 2 {
        return Found::Nothing;
    }
    near.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
    let kth2 = near[k - 1].0 as f64;
    let line = line_direction(near[..k].iter().map(|&(_, _, q)| q));
    let Some((s2, across)) = across_spacing(&near, k, line, ray) else {
        return Found::Nothing;
    };
    // The plane: refitted over the neighbouring lines (at least the k nearest, so that the
    // fit is never narrower than the first), or the given normal's through the k nearest;
    // through the centroid of the points it was fitted to, which the point's own range noise
    // does not move.
    let reach2 = match shape {
        Shape::Line => (FIT_REACH as f64 * FIT_REACH as f64 * s2).max(kth2),
        _ => kth2,
    };
    let fitted = || {
        near.iter()
            .filter(|&&(d2, _, _)| d2 as f64 <= reach2)
            .map(|&(_, o, _)| o)
    };
    let n = match shape {
        Shape::Line => Fit::of_offsets(fitted()).normal.as_dvec3(),
        _ => normal.as_dvec3(),
    };
    let centroid = fitted().sum::<DVec3>() / (fitted().count() + 1) as f64;
    let height = (across - centroid).dot(n);
    let flat = (across - n * across.dot(n)).length();
    // A scanner sees a surface from its front: a plane on edge to the ray (a fit over a
    // column's silhouette, one line and nothing beside it) is no plane it scanned.
    let faces_ray = ray.is_none_or(|u| n.dot(u.as_dvec3()).abs() >= FACING);
    match height.abs() <= ON_PLANE as f64 * flat && line.dot(n).abs() < 0.5 && faces_ray {
        true => Found::Across {
            radius: (CLOSE_FACTOR as f64 * flat).min(RAISE_CAP * kth2.sqrt()) as f32,
            normal: (shape == Shape::Line).then(|| n.as_vec3()),
        },
        false => Found::NotItsSurface,
    }
}

/// The spacing across a point's `line` among its neighbours `near` (the first `k` of them
/// its k nearest): the squared distance across the ray of the [`ACROSS_RANK`]-th nearest
/// point at least [`ACROSS_ANGLE`] off the line, and that point's offset. A single point
/// nearer (another station's, a stray return) does not set it; nor do points nearer across
/// the ray than [`SAME_SPOT`] of the k nearest's median, which are the same spot at another
/// range (the rows straight above a station), nor points more than [`RAY_DEPTH`] times
/// farther along the `ray` than across it, which lie behind or before the point (a wall
/// behind a column's silhouette).
fn across_spacing(
    near: &[(f32, DVec3, DVec3)],
    k: usize,
    line: DVec3,
    ray: Option<Vec3>,
) -> Option<(f64, DVec3)> {
    let mut spread: Vec<f64> = near[..k]
        .iter()
        .map(|&(_, _, q)| q.length_squared())
        .collect();
    let mid = spread.len() / 2;
    let least2 = SAME_SPOT * SAME_SPOT * *spread.select_nth_unstable_by(mid, f64::total_cmp).1;
    let cos2 = (ACROSS_ANGLE.cos() as f64).powi(2);
    let mut across: Vec<(f64, DVec3)> = near
        .iter()
        .map(|&(_, o, q)| (q.length_squared(), o, q))
        .filter(|&(q2, _, q)| q.dot(line).powi(2) <= cos2 * q2 && q2 > least2.max(0.0))
        .filter(|&(q2, o, _)| {
            ray.is_none_or(|u| o.dot(u.as_dvec3()).powi(2) <= RAY_DEPTH * RAY_DEPTH * q2)
        })
        .map(|(q2, o, _)| (q2, o))
        .collect();
    if across.len() < ACROSS_RANK {
        return None;
    }
    Some(
        *across
            .select_nth_unstable_by(ACROSS_RANK - 1, |a, b| a.0.total_cmp(&b.0))
            .1,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn near_of(points: &[Vec3]) -> (Vec<Vec3>, Vec<(u32, f32)>) {
        let mut all = vec![Vec3::ZERO];
        all.extend_from_slice(points);
        let near = (1..all.len() as u32)
            .map(|j| (j, all[j as usize].length_squared()))
            .collect();
        (all, near)
    }

    #[test]
    fn a_line_a_plane_and_a_border_have_their_shapes() {
        // On a line (x), with noise in z as large as the spacing: a line in space.
        let line: Vec<Vec3> = (1..=8)
            .flat_map(|j| {
                let (x, z) = (j as f32 * 0.002, if j % 2 == 0 { 0.002 } else { -0.002 });
                [Vec3::new(x, 0.0, z), Vec3::new(-x, 0.0, z)]
            })
            .collect();
        let (pts, near) = near_of(&line);
        assert_eq!(
            Shape::of(&pts, 0, &near, &near[..8], Vec3::Z, None),
            Shape::Line
        );
        // A square grid around the point, and its half (a border along y = 0).
        let grid: Vec<Vec3> = (-2..=2)
            .flat_map(|a| (-2..=2).map(move |b| Vec3::new(a as f32, b as f32, 0.0)))
            .filter(|p| *p != Vec3::ZERO)
            .collect();
        let (pts, near) = near_of(&grid);
        assert_eq!(
            Shape::of(&pts, 0, &near, &near[..8], Vec3::Z, None),
            Shape::Around
        );
        let half: Vec<Vec3> = grid.iter().copied().filter(|p| p.y >= 0.0).collect();
        let (pts, near) = near_of(&half);
        assert_eq!(
            Shape::of(&pts, 0, &near, &near[..8], Vec3::Z, None),
            Shape::Around
        );
        // Sixteen on a plane, the nearest eight of them on a line of it.
        let mut rows: Vec<Vec3> = (1..=4)
            .flat_map(|j| [Vec3::X * j as f32, -Vec3::X * j as f32])
            .collect();
        rows.extend((-3..=4).map(|j| Vec3::new(j as f32, 5.0, 0.0)));
        let (pts, near) = near_of(&rows);
        assert_eq!(
            Shape::of(&pts, 0, &near, &near[..8], Vec3::Z, None),
            Shape::RadiusOnLine
        );
    }

    /// `look`'s arguments for the points `pts` around a point at the origin.
    fn ball(pts: &[Vec3]) -> (Vec<(u32, f32)>, Vec<[f32; 3]>) {
        pts.iter()
            .enumerate()
            .filter(|(_, p)| **p != Vec3::ZERO)
            .map(|(j, p)| ((j as u32, p.length_squared()), p.to_array()))
            .unzip()
    }

    #[test]
    fn a_look_across_finds_the_next_line_or_another_surface() {
        // Lines along x, 5 apart in y, dense along x; the point on the middle one.
        let row = |y: f32| (-20..=20).map(move |j| Vec3::new(j as f32 * 0.5, y, 0.0));
        let pts: Vec<Vec3> = row(-5.0).chain(row(0.0)).chain(row(5.0)).collect();
        let (inside, offsets) = ball(&pts);
        match look(Shape::Line, Vec3::Y, None, 16, &inside, &offsets) {
            Found::Across { radius, normal } => {
                // The third nearest across: (0, 5) and (±0.5, 5).
                let third = (25.0f32 + 0.25).sqrt();
                assert!((radius - CLOSE_FACTOR * third).abs() < 1e-5, "{radius}");
                assert!(normal.unwrap().z.abs() > 0.999, "{normal:?}");
            }
            f => panic!("{f:?}"),
        }
        // The radius alone: the normal stays as given.
        match look(Shape::RadiusOnLine, Vec3::Z, None, 16, &inside, &offsets) {
            Found::Across {
                radius,
                normal: None,
            } => assert!((radius - CLOSE_FACTOR * (25.0f32 + 0.25).sqrt()).abs() < 1e-5),
            f => panic!("{f:?}"),
        }
        // Only the point's own line within the reach: nothing across yet.
        let (inside, offsets) = ball(&row(0.0).collect::<Vec<_>>());
        assert_eq!(
            look(Shape::Line, Vec3::Y, None, 16, &inside, &offsets),
            Found::Nothing
        );
        // A wire (normal y) beside a wall 4 away along y and 3 below: off its plane.
        let wire: Vec<Vec3> = row(0.0)
            .chain((-4..=4).map(|j| Vec3::new(j as f32, 4.0, -3.0)))
            .collect();
        let (inside, offsets) = ball(&wire);
        assert_eq!(
            look(Shape::RadiusOnLine, Vec3::Y, None, 16, &inside, &offsets),
            Found::NotItsSurface
        );
        // A column's silhouette seen from -y: its points one vertical line, a wall 0.5 behind
        // it, right beside the line across the ray but far along it: nothing across.
        let edge: Vec<Vec3> =
            (-20..=20)
                .map(|j| Vec3::new(0.0, 0.0, j as f32 * 0.002))
                .chain((-20..=20).flat_map(|j| {
                    [-1.0f32, 1.0].map(|x| Vec3::new(x * 0.006, 0.5, j as f32 * 0.006))
                }))
                .collect();
        let (inside, offsets) = ball(&edge);
        let ray = Some(-Vec3::Y);
        assert_eq!(
            look(Shape::Line, Vec3::X, ray, 16, &inside, &offsets),
            Found::Nothing
        );
    }
}
