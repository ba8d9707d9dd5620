//! Normal and radius estimation for point clouds that lack them: k-nearest-neighbour PCA,
//! normal orientation (towards a sensor, or by propagation over the neighbour graph), and
//! splat radii from the local point spacing.
//!
//! Here the entry points, the checks and the `k`-nearest fits; `estimate/widen.rs` the wider
//! fits of noisy normals, `estimate/orient.rs` the orientation by propagation.
//!
//! Neighbours come from one exact all-points search ([`crate::knn::Knn`], built once per
//! call) run in parallel with rayon. Positions must be finite (`read_ply` guarantees it; the
//! `try_` functions check it).

use std::path::Path;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::edge_on;
use crate::eigen::{least_eigen, sym_eigen3};
use crate::knn::Knn;
use crate::lines::{self, Shape};
use crate::ImportError;

mod orient;
mod widen;

use orient::propagate;
use widen::widen;

/// How estimated normals are oriented (PCA gives a direction only up to sign). A sensor or
/// stations also tell each point's ray, along which a scanner's range noise lies: the line
/// rule (docs/import.md, "Line sampling") reads its neighbourhoods across the rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Orientation<'a> {
    /// Every normal faces this point (the scanner position): `n · (sensor - p) >= 0`.
    Sensor(Vec3),
    /// Every normal faces the station its point was scanned from, `stations[of[i]]` (an index
    /// past the list leaves the normal unoriented and the point without a ray).
    Stations { stations: &'a [Vec3], of: &'a [u32] },
    /// Left as PCA gives them (the caller orients them).
    Unoriented,
    /// Consistent orientation by propagation over the k-nearest-neighbour graph, outward at the
    /// extremes of each connected part; see [`estimate_normals`].
    Propagate,
}

impl Orientation<'_> {
    /// The unit direction from point `i` at `p` to its scanner, where known.
    fn ray(&self, i: usize, p: Vec3) -> Option<Vec3> {
        let s = match *self {
            Orientation::Sensor(s) => s,
            Orientation::Stations { stations, of } => *stations.get(*of.get(i)? as usize)?,
            Orientation::Unoriented | Orientation::Propagate => return None,
        };
        (s - p).try_normalize()
    }
}

/// Neighbours per point kept for the orientation graph (memory: 4 bytes each per point).
const GRAPH_NEIGHBOURS: usize = 8;

/// How normals are fitted: to each point's `k` nearest neighbours, widened where that fit is
/// noisy ([`widen`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalFit {
    pub k: usize,
    /// Radians: a fit whose tilt error is above this is fitted again over a wider
    /// neighbourhood; 0 never widens (`import.normal_widen_above`, in degrees there).
    pub widen_above: f32,
}

impl NormalFit {
    /// `k` neighbours, widened above the default tilt error (`import.normal_widen_above`).
    pub fn new(k: usize) -> NormalFit {
        let degrees = pc_config::ImportConfig::default().normal_widen_above;
        NormalFit {
            k,
            widen_above: degrees.to_radians(),
        }
    }

    /// Exactly the `k` nearest neighbours for every point.
    pub fn fixed(k: usize) -> NormalFit {
        NormalFit {
            k,
            widen_above: 0.0,
        }
    }
}

impl From<usize> for NormalFit {
    fn from(k: usize) -> NormalFit {
        NormalFit::new(k)
    }
}

/// Unit normals by principal component analysis of each point's `k` nearest neighbours.
///
/// **Direction.** For each point, the covariance of itself and its `k` nearest neighbours is
/// accumulated in f64 (relative to the point, so large coordinates lose no precision) and
/// diagonalized with a cyclic Jacobi solver; the normal is the eigenvector of the smallest
/// eigenvalue, i.e. the direction in which the neighbourhood is thinnest. Degenerate
/// neighbourhoods (coincident or collinear points) still give a unit vector, just an arbitrary
/// one among the equally thin directions.
///
/// **Orientation.**
/// * [`Orientation::Sensor`]: each normal is flipped to face the sensor point.
/// * [`Orientation::Propagate`] (Hoppe et al. 1992, "Surface reconstruction from unorganized
///   points", §3.3): the graph joins every point to its nearest neighbours (the first
///   `min(k, 8)`, made symmetric). Each connected component is handled on its own. Its seed is
///   the point that is extreme along one of the six directions ±x, ±y, ±z — of those six
///   candidates, the one whose normal is most parallel to its direction — and the seed normal
///   is oriented along that direction (outward: at the extreme point of a closed surface the
///   outward normal points away from the rest of it). The orientation then propagates along a
///   minimum spanning tree of the component with edge weight `1 - |n_i · n_j|` (Prim's
///   algorithm; a bucket queue over the weight, quantized in steps of ≈ 0.08° of angle): the
///   next point reached is always the one whose normal is most nearly parallel to an already
///   oriented neighbour, so the sign is decided across flat
///   regions first and across sharp creases last, and each new normal is flipped to agree
///   (`n_j · n_i >= 0`) with the tree neighbour it is reached from. Hoppe adds the Euclidean MST
///   to the graph to make it connected; here separate components are instead seeded
///   separately, which is the same for a component that is one closed surface.
///
/// `k` is clamped to `positions.len() - 1`; for fewer than 3 points the result is degenerate
/// (use [`try_estimate_normals`] to get an error instead). Costs one neighbour search over all
/// points ([`Knn`], parallel), plus O(E) sequential work for `Propagate` (E ≈ 10 n).
///
/// Exact copies of a position are estimated once ([`Distinct`]) and share its normal.
pub fn estimate_normals(
    positions: &[Vec3],
    fit: impl Into<NormalFit>,
    orient: Orientation,
) -> Vec<Vec3> {
    estimate(positions, Some((fit.into(), orient)), None).0
}

/// Normals ([`estimate_normals`], `k_normals` neighbours) and radii ([`estimate_radii`],
/// `k_radii`) together: one search ([`Knn`]) for the nearest `max(k_normals, k_radii)` of each point
/// serves both (the radii read the nearest `k_radii` of the same list), where two passes
/// cost two searches (with the kd-tree before the search: 1.5 of the import's 5 s at 1M
/// scanned points).
pub fn estimate_normals_and_radii(
    positions: &[Vec3],
    fit: impl Into<NormalFit>,
    orient: Orientation,
    k_radii: usize,
) -> (Vec<Vec3>, Vec<f32>) {
    estimate(positions, Some((fit.into(), orient)), Some(k_radii))
}

/// What is asked of one neighbour pass: normals (neighbours, orientation), radii (neighbours).
/// Exact copies of a position are estimated once ([`Distinct`]).
fn estimate(
    positions: &[Vec3],
    normals: Option<(NormalFit, Orientation)>,
    radii: Option<usize>,
) -> (Vec<Vec3>, Vec<f32>) {
    match Distinct::of(positions) {
        Some(d) => {
            // Each distinct position is scanned from its first copy's station.
            let of_first: Vec<u32>;
            let normals = match normals {
                Some((fit, Orientation::Stations { stations, of })) => {
                    of_first = d.first.iter().map(|&i| of[i as usize]).collect();
                    let of = &of_first[..];
                    Some((fit, Orientation::Stations { stations, of }))
                }
                other => other,
            };
            let (n, r) = estimate_distinct(&d.points, normals, radii);
            (d.spread(&n), d.spread(&r))
        }
        None => estimate_distinct(positions, normals, radii),
    }
}

/// [`estimate`] on positions without exact copies: empty vectors for what is not asked.
fn estimate_distinct(
    positions: &[Vec3],
    normals: Option<(NormalFit, Orientation)>,
    radii: Option<usize>,
) -> (Vec<Vec3>, Vec<f32>) {
    let n = positions.len();
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    // (A single point has no neighbour: its radius falls back to 1 below.)
    let kn = normals.map_or(0, |(f, _)| f.k.min(n - 1));
    let kr = radii.map_or(0, |k| k.clamp(1, (n - 1).max(1)));
    let orient = normals.map(|(_, o)| o);
    let kg = match orient {
        Some(Orientation::Propagate) => kn.min(GRAPH_NEIGHBOURS),
        _ => 0,
    };
    let knn = Knn::new(positions);
    let kq = kn.max(kr);
    // One neighbour query per point serves the normal, the radius and the graph row.
    let estimate_one = |i: usize, near: &[(u32, f32)]| {
        let fit = match normals {
            Some(_) => {
                let near = &near[..kn.min(near.len())];
                let kth2 = near.last().map_or(0.0, |&(_, d2)| d2);
                (Fit::of(positions, i, near), kth2)
            }
            None => (Fit::NONE, 0.0),
        };
        let r = match radii {
            Some(_) => {
                let near = &near[..kr.min(near.len())];
                let sum: f64 = near.iter().map(|&(_, d2)| d2 as f64).sum();
                let mean = sum / near.len().max(1) as f64;
                (2.0 * std::f64::consts::PI * mean / kr as f64).sqrt() as f32
            }
            None => 0.0,
        };
        // Neighbours along a line leave both estimates unsure (crate::lines).
        // (With the radius not asked, kr is 0 and only the normal's shape counts.)
        let shape = match normals {
            Some(_) => {
                let (kn, kr) = (kn.min(near.len()), kr.min(near.len()));
                let ray = orient.and_then(|o| o.ray(i, positions[i]));
                Shape::of(positions, i, &near[..kn], &near[..kr], fit.0.normal, ray)
            }
            None => Shape::Around,
        };
        (fit, (r, shape))
    };
    type Rows = (Vec<(Fit, f32)>, Vec<(f32, Shape)>, Vec<u32>);
    let (fits, radius_rows, graph): Rows = if kg == 0 {
        let (f, r) = knn.map(kq, estimate_one).into_par_iter().unzip();
        (f, r, Vec::new())
    } else {
        let rows = knn.map(kq, |i, near| {
            let (f, r) = estimate_one(i, near);
            let mut row = [u32::MAX; GRAPH_NEIGHBOURS];
            for (g, &(j, _)) in row.iter_mut().take(kg).zip(near) {
                *g = j;
            }
            (f, r, row)
        });
        let graph = rows
            .par_iter()
            .flat_map_iter(|(_, _, row)| row[..kg].iter().copied())
            .collect();
        let (f, r) = rows.into_par_iter().map(|(f, r, _)| (f, r)).unzip();
        (f, r, graph)
    };
    let (mut out_r, shapes): (Vec<f32>, Vec<Shape>) = radius_rows.into_par_iter().unzip();
    let mut out_n: Vec<Vec3> = fits.par_iter().map(|(f, _)| f.normal).collect();
    if let Some((fit, _)) = normals {
        widen(&knn, &mut out_n, &fits, fit.widen_above);
    }
    let kth2: Vec<f32> = match normals {
        Some(_) => fits.par_iter().map(|&(_, d2)| d2).collect(),
        None => Vec::new(),
    };
    let ray = |i: usize| orient.and_then(|o| o.ray(i, positions[i]));
    if shapes.iter().any(|&s| s != Shape::Around) {
        let radii = radii.map(|_| &mut out_r[..]);
        lines::close(&knn, &shapes, &kth2, kn, ray, &mut out_n, radii);
    }
    match orient {
        Some(orient) => {
            orient_normals(positions, &mut out_n, orient, &graph, kg);
            if let Orientation::Sensor(_) | Orientation::Stations { .. } = orient {
                edge_on::settle(&knn, &mut out_n, &kth2, ray);
            }
        }
        None => out_n = Vec::new(),
    }
    match radii.is_some() {
        true => replace_bad_radii(&mut out_r),
        false => out_r = Vec::new(),
    }
    (out_n, out_r)
}

/// Orient PCA normals as `orient` asks ([`estimate_normals`]); `graph` holds each point's
/// nearest `kg` neighbours for propagation.
fn orient_normals(
    positions: &[Vec3],
    normals: &mut [Vec3],
    orient: Orientation,
    graph: &[u32],
    kg: usize,
) {
    match orient {
        Orientation::Sensor(_) | Orientation::Stations { .. } => {
            normals
                .par_iter_mut()
                .zip(positions.par_iter())
                .enumerate()
                .for_each(|(i, (nrm, &p))| {
                    if orient.ray(i, p).is_some_and(|u| nrm.dot(u) < 0.0) {
                        *nrm = -*nrm;
                    }
                });
        }
        Orientation::Propagate => propagate(positions, normals, graph, kg),
        Orientation::Unoriented => {}
    }
}

/// [`estimate_normals`], with an [`ImportError::Estimate`] naming `path` when the input cannot
/// give meaningful normals: `k < 2`, fewer than `k + 1` points, or a non-finite position.
pub fn try_estimate_normals(
    path: &Path,
    positions: &[Vec3],
    fit: impl Into<NormalFit>,
    orient: Orientation,
) -> Result<Vec<Vec3>, ImportError> {
    let fit = fit.into();
    check_normals(path, positions, fit.k, orient)?;
    Ok(estimate_normals(positions, fit, orient))
}

/// [`estimate_normals_and_radii`], with the errors of [`try_estimate_normals`] and
/// [`try_estimate_radii`].
pub fn try_estimate_normals_and_radii(
    path: &Path,
    positions: &[Vec3],
    fit: impl Into<NormalFit>,
    orient: Orientation,
    k_radii: usize,
) -> Result<(Vec<Vec3>, Vec<f32>), ImportError> {
    let fit = fit.into();
    check_normals(path, positions, fit.k, orient)?;
    check_radii(path, positions, k_radii)?;
    Ok(estimate_normals_and_radii(positions, fit, orient, k_radii))
}

fn check_normals(
    path: &Path,
    positions: &[Vec3],
    k: usize,
    orient: Orientation,
) -> Result<(), ImportError> {
    if k < 2 {
        return Err(ImportError::estimate(
            path,
            format!("normal estimation needs at least 2 neighbours, k = {k}"),
        ));
    }
    check_input(path, positions, k, "normal")?;
    if let Orientation::Stations { stations, of } = orient {
        if of.len() != positions.len() {
            return Err(ImportError::estimate(
                path,
                format!(
                    "{} station indices for {} points",
                    of.len(),
                    positions.len()
                ),
            ));
        }
        if let Some(s) = stations.iter().find(|s| !s.is_finite()) {
            return Err(ImportError::estimate(
                path,
                format!("station {s} is not finite"),
            ));
        }
    }
    if let Orientation::Sensor(s) = orient {
        if !s.is_finite() {
            return Err(ImportError::estimate(
                path,
                format!("sensor {s} is not finite"),
            ));
        }
    }
    Ok(())
}

/// Splat radius per point from the local point spacing.
///
/// With `d_j` the distances to the point's `k` nearest neighbours (itself excluded),
///
/// ```text
/// r = sqrt(2π · mean(d_j²) / k)
/// ```
///
/// Why: if the `k` neighbours fill a disk of radius `R` uniformly, `mean(d²) = R²/2` and the
/// disk holds about `k` points, so the surface area per point is `πR²/k = 2π·mean(d²)/k`; `r` is
/// the side of that area, i.e. the local grid spacing `h`. Averaging all `k` squared distances is
/// much less noisy than using the k-th distance alone. On a square grid of spacing `h`, `k = 8`
/// gives `mean(d²) = 1.5h²` and `r ≈ 1.09h`; `k = 4` gives `1.25h`, `k = 12` `1.10h`, `k = 20`
/// `1.03h`. Coverage needs `r` above the largest distance from a surface point to its nearest
/// sample: `0.71h` on a square grid, `0.58×` the spacing on a hexagonal one; so disks of
/// neighbours overlap by a wide margin, and jittered grids (samples moved by up to ±h/4) stay
/// closed. At the border of a scan there are fewer neighbours on one side and `r` grows
/// (up to ~1.4×), which closes borders rather than opening them.
///
/// Exact copies of a position are estimated once ([`Distinct`]) and share its radius (the
/// octree's splat-area pass then shares one disk's area among them). `k` is clamped to the
/// number of distinct positions − 1; a single point, or all points coincident, gets radius 1
/// (use [`try_estimate_radii`] to get an error instead).
pub fn estimate_radii(positions: &[Vec3], k: usize) -> Vec<f32> {
    estimate(positions, None, Some(k)).1
}

/// Radii that are not finite and positive (all neighbours coincide) become the median of the
/// good ones, or 1 when there are none.
fn replace_bad_radii(radii: &mut [f32]) {
    let good = |r: f32| r.is_finite() && r > 0.0;
    if radii.iter().all(|&r| good(r)) {
        return;
    }
    let mut ok: Vec<f32> = radii.iter().copied().filter(|&r| good(r)).collect();
    let fallback = if ok.is_empty() {
        1.0
    } else {
        let mid = ok.len() / 2;
        *ok.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    for r in radii.iter_mut() {
        if !good(*r) {
            *r = fallback;
        }
    }
}

/// [`estimate_radii`], with an [`ImportError::Estimate`] naming `path` when `k == 0`, there are
/// fewer than `k + 1` points, a position is not finite, or all points coincide.
pub fn try_estimate_radii(
    path: &Path,
    positions: &[Vec3],
    k: usize,
) -> Result<Vec<f32>, ImportError> {
    check_radii(path, positions, k)?;
    Ok(estimate_radii(positions, k))
}

fn check_radii(path: &Path, positions: &[Vec3], k: usize) -> Result<(), ImportError> {
    if k == 0 {
        return Err(ImportError::estimate(
            path,
            "radius estimation needs at least 1 neighbour, k = 0",
        ));
    }
    check_input(path, positions, k, "radius")
}

fn check_input(path: &Path, positions: &[Vec3], k: usize, what: &str) -> Result<(), ImportError> {
    let n = positions.len();
    if n < k + 1 {
        return Err(ImportError::estimate(
            path,
            format!(
                "{what} estimation with {k} neighbours needs at least {} points, the model has {n}",
                k + 1
            ),
        ));
    }
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(ImportError::estimate(
            path,
            format!("point {i} has a non-finite position {}", positions[i]),
        ));
    }
    if positions.iter().all(|&p| p == positions[0]) {
        return Err(ImportError::estimate(
            path,
            format!("all {n} points coincide: there is no surface to estimate a {what} from"),
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Exact copies

/// The distinct positions of a point set and, for each point, which one it is. Scans merged
/// from overlapping stations hold many exact copies of a point. A kd-tree cannot split a
/// bucket of equal points, so each query near them scans all the copies (40k copies of one
/// point took 3.7 s, a million would take hours), and copies fill a point's `k` neighbours
/// with zero distances, leaving no surface to fit. Estimating on the distinct positions
/// avoids both; copies then get their position's normal and radius.
struct Distinct {
    points: Vec<Vec3>,
    /// The input index of each distinct position's first copy.
    first: Vec<u32>,
    /// Index into `points` of each input point.
    of: Vec<u32>,
}

impl Distinct {
    /// `None` when every position is distinct (`-0.0` and `0.0` are the same position). The
    /// distinct positions keep the order of their first copy. The copies are grouped by a
    /// parallel sort of the positions' bits (a hash map filled in input order took seconds at
    /// 20M points, on one core).
    fn of(positions: &[Vec3]) -> Option<Distinct> {
        let key = |p: &Vec3| (*p + Vec3::ZERO).to_array().map(f32::to_bits);
        let mut sorted: Vec<([u32; 3], u32)> = positions
            .par_iter()
            .enumerate()
            .map(|(i, p)| (key(p), i as u32))
            .collect();
        sorted.par_sort_unstable();
        if !sorted.par_windows(2).any(|w| w[0].0 == w[1].0) {
            return None;
        }
        // Each point's first copy: the least index with its bits (first in its group).
        let mut first = vec![0u32; positions.len()];
        for group in sorted.chunk_by(|a, b| a.0 == b.0) {
            for &(_, i) in group {
                first[i as usize] = group[0].1;
            }
        }
        drop(sorted);
        let (mut points, mut firsts) = (Vec::new(), Vec::new());
        let mut id = vec![0u32; positions.len()];
        for (i, &f) in first.iter().enumerate() {
            if f as usize == i {
                id[i] = points.len() as u32;
                points.push(positions[i]);
                firsts.push(i as u32);
            }
        }
        let of = first.par_iter().map(|&f| id[f as usize]).collect();
        Some(Distinct {
            points,
            first: firsts,
            of,
        })
    }

    /// Per-point values from per-distinct-position ones (none from none: what was not asked).
    fn spread<T: Copy>(&self, values: &[T]) -> Vec<T> {
        if values.is_empty() {
            return Vec::new();
        }
        self.of.iter().map(|&j| values[j as usize]).collect()
    }
}

// ---------------------------------------------------------------------------------------------
// PCA

/// A plane fitted by PCA to a point and the points around it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Fit {
    /// The unit eigenvector of the smallest eigenvalue.
    pub(crate) normal: Vec3,
    /// The smallest eigenvalue of the covariance (per point): the variance across the plane.
    thin: f32,
    /// The standard error of the normal's tilt, radians ([`Fit::of_offsets`]).
    error: f32,
    /// Points in the fit, the point itself included.
    count: u32,
}

impl Fit {
    /// No fit (normals not asked for).
    const NONE: Fit = Fit {
        normal: Vec3::ZERO,
        thin: 0.0,
        error: 0.0,
        count: 0,
    };

    /// The plane through point `i` and the points `nb` (input index, distance).
    fn of(positions: &[Vec3], i: usize, nb: &[(u32, f32)]) -> Fit {
        let o = positions[i].as_dvec3();
        Fit::of_offsets(
            nb.iter()
                .map(|&(j, _)| positions[j as usize].as_dvec3() - o),
        )
    }

    /// The plane through a point and others at these offsets from it.
    pub(crate) fn of_offsets(offsets: impl Iterator<Item = DVec3> + Clone) -> Fit {
        let m = (offsets.clone().count() + 1) as f64;
        let mean = offsets.clone().sum::<DVec3>() / m; // the point itself contributes 0
        let mut c = [[0f64; 3]; 3];
        let mut add = |d: DVec3| {
            let d = d.to_array();
            for r in 0..3 {
                for s in r..3 {
                    c[r][s] += d[r] * d[s];
                }
            }
        };
        add(-mean);
        for d in offsets {
            add(d - mean);
        }
        c[1][0] = c[0][1];
        c[2][0] = c[0][2];
        c[2][1] = c[1][2];
        let (vals, v) = least_eigen(c).unwrap_or_else(|| {
            let (vals, vecs) = sym_eigen3(c);
            let mut order = [0usize, 1, 2];
            order.sort_by(|&a, &b| vals[a].total_cmp(&vals[b]));
            let axis = DVec3::new(vecs[0][order[0]], vecs[1][order[0]], vecs[2][order[0]]);
            (order.map(|k| vals[k]), axis)
        });
        let l = v.length();
        let normal = if l.is_finite() && l > 0.0 {
            (v / l).as_vec3()
        } else {
            Vec3::Z
        };
        let (thin, narrow) = (vals[0].max(0.0) / m, vals[1].max(0.0) / m);
        // A plane's slope fitted by least squares to m points with residual variance σ² and
        // spread s² along an axis has a standard error σ / (s √m); σ² is m λ₀ / (m − 3).
        let error = if m > 3.0 && narrow > 0.0 {
            (thin / ((m - 3.0) * narrow)).sqrt()
        } else {
            f64::INFINITY
        };
        Fit {
            normal,
            thin: thin as f32,
            error: error as f32,
            count: m as u32,
        }
    }
}

/// The second moments of offsets from a point about the point itself (not about their mean),
/// largest first, and their axes.
pub(crate) fn principal_axes(offsets: impl Iterator<Item = DVec3>) -> ([f64; 3], [DVec3; 3]) {
    let mut c = [[0f64; 3]; 3];
    for d in offsets {
        let d = d.to_array();
        for r in 0..3 {
            for s in 0..3 {
                c[r][s] += d[r] * d[s];
            }
        }
    }
    let (vals, vecs) = sym_eigen3(c);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]));
    let axis = |k: usize| DVec3::new(vecs[0][k], vecs[1][k], vecs[2][k]);
    (
        order.map(|k| vals[k]),
        [axis(order[0]), axis(order[1]), axis(order[2])],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distinct_positions_keep_first_copy_order() {
        let a = Vec3::new(1.0, 2.0, 3.0);
        let b = Vec3::new(0.0, -0.0, 5.0);
        let c = Vec3::new(-0.0, 0.0, 5.0); // the same position as b
        let d = Vec3::new(1.0, 2.0, 3.5);
        let pts = [d, a, b, a, c, d, a];
        let got = Distinct::of(&pts).expect("copies");
        assert_eq!(got.points, vec![d, a, b]);
        assert_eq!(got.of, vec![0, 1, 2, 1, 2, 0, 1]);
        assert!(Distinct::of(&[a, b, d]).is_none());
        assert!(Distinct::of(&[]).is_none());
    }

    #[test]
    fn plane_normal_is_axis() {
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                pts.push(Vec3::new(i as f32 * 0.1, j as f32 * 0.1, 3.0));
            }
        }
        let n = estimate_normals(&pts, 8, Orientation::Sensor(Vec3::new(0.0, 0.0, -10.0)));
        assert!(n.iter().all(|v| (v.z + 1.0).abs() < 1e-5), "{:?}", n[0]);
    }
}
