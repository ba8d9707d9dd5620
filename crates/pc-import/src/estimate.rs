//! Normal and radius estimation for point clouds that lack them: k-nearest-neighbour PCA,
//! normal orientation (towards a sensor, or by propagation over the neighbour graph), and
//! splat radii from the local point spacing.
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

/// A widened neighbourhood's radius, in the `k`-th neighbour's distances: at least the first,
/// at most the second.
const WIDEN_RADIUS: (f32, f32) = (2.0, 4.0);
/// A wider fit is kept only while the variance across its plane stays within this factor of
/// the noise of the narrower fits around it: range noise does not grow with the radius, a
/// crease or a curve does. Not 1: the narrower fits underestimate the noise (the thinnest
/// direction of a few points), and on the 20M hall scan's flat faces the ratio runs from 1 to
/// 3, median 1.6 (docs/import.md, "Noise: wider neighbourhoods"); the crease test bounds it
/// from above.
const WIDEN_FLAT: f32 = 2.5;
/// A wider fit is also kept where it is at most this many times as thick (in variance) as the
/// same ball at half its radius: range noise does not grow with the radius. Where the noise is
/// deeper than the k nearest are wide (the 20M hall scan's zeniths: 2.5 mm of noise, the 16
/// nearest within 4.6 mm), the narrower fits are thinner than the noise by chance and the
/// test against their noise refused every wider fit (3.7 times their variance at 4 k-th
/// distances, 1.3 times the half ball's).
const WIDEN_GROWTH: f32 = 2.0;
/// Where a wider fit's half ball lay within the noise's depth, the fit is tried once more in a
/// ball whose half clears it: a half radius of at least `.0` standard deviations of the noise
/// (the wider fit's thinness), the whole ball at most `.1` times the `k`-th neighbour's
/// distance.
const WIDEN_DEEP: (f32, f32) = (3.0, 8.0);
/// Fits whose own tilt error is below this share of the tolerance are taken as they are.
const WIDEN_LOOK: f32 = 0.35;

/// Widens the neighbourhoods of noisy normals. A scanner's range noise is millimetres
/// whatever the point spacing, so at a dense spacing the `k` nearest points span a patch
/// hardly wider than the noise is deep, and their plane tilts by many degrees (the 20M-point
/// hall scan: a median of 8–16° from the true wall at `k` = 16).
///
/// A plane fitted to `m` points spread `s` wide with noise `σ` tilts by about `σ / (s √m)`
/// ([`Fit`]); on a surface `m` grows with `s²`, so the tilt falls with the square of the
/// radius. A fit whose tilt error is above `above` ([`NormalFit::widen_above`]) is fitted
/// again over every point within the radius that brings its error to `above`, at least
/// [`WIDEN_RADIUS`]`.0` and at most `.1` times its `k`-th neighbour's distance. The wider
/// fit is kept where it stays as flat as the noise ([`WIDEN_FLAT`]): near a crease or on a
/// tight curve it does not. Where the ball's half lay within the noise's depth (a scan merged
/// closer than its noise is deep, which leaves blobs: the 100M hall scan's zeniths), its fit is
/// tried once more in a ball whose half clears the noise ([`WIDEN_DEEP`]). A fit wider than
/// the least radius that still fails is tried once more at the least; failing that, the
/// `k`-nearest normal stays.
///
/// The noise is not the fit's own thinness, a sample of `k + 1` points (±40 % at 17), but the
/// median over the fits around it ([`pooled_thin`]): a fit that came out thin by chance is
/// widened too, and is not held to a tolerance it beat by chance. Fits far below the
/// tolerance (a smooth surface: [`WIDEN_LOOK`]) are taken as they are.
///
/// The neighbourhood thus follows the noise, as Mitra, Nguyen and Guibas (2004, "Estimating
/// surface normals in noisy point cloud data") ask, with the flatness test in place of their
/// curvature estimate. `fits[i]` is point `i`'s fit to its `k` nearest and the squared
/// distance of the `k`-th.
fn widen(knn: &Knn, normals: &mut [Vec3], fits: &[(Fit, f32)], above: f32) {
    let (least, most) = (
        WIDEN_RADIUS.0 * WIDEN_RADIUS.0,
        WIDEN_RADIUS.1 * WIDEN_RADIUS.1,
    );
    let mut reach2: Vec<f32> = fits
        .par_iter()
        .map(|&(ref f, d2)| {
            let noisy = f.error > WIDEN_LOOK * above && f.count > 3;
            match above > 0.0 && noisy && d2 > 0.0 {
                // The error falls with the square of the radius.
                true => d2 * (f.error / above).clamp(least, most),
                false => 0.0,
            }
        })
        .collect();
    // Whether a point's ball was already widened past the noise's depth (once at most).
    let mut deepened = vec![false; fits.len()];
    let deepest = WIDEN_DEEP.1 * WIDEN_DEEP.1;
    // At most three balls a point: the first, one past the noise, the least.
    for _ in 0..3 {
        if !reach2.iter().any(|&r| r > 0.0) {
            break;
        }
        // Twice the points of the widest ball on a plane (every k-nearest fit holds the same
        // k + 1): a stray point's ball, sized by its far neighbours, is given up instead of
        // spanning the cloud.
        let cap = 2 * (deepest as usize) * (fits[0].0.count as usize).max(1);
        let wider = knn.map_within(&reach2, cap, |i, inside, offsets| {
            let noise = pooled_thin(fits, i, inside);
            // The k-nearest fit's error with its patch's noise: within the tolerance, no wider
            // fit is asked (an empty one stands for it).
            let fit = fits[i].0;
            let error = match fit.thin > 0.0 {
                true => fit.error * (noise / fit.thin).sqrt(),
                false => f32::INFINITY,
            };
            if error <= above {
                return (Fit::NONE, noise, false);
            }
            let all = offsets.iter().map(|&o| Vec3::from(o).as_dvec3());
            let wide = Fit::of_offsets(all.clone());
            if wide.thin <= WIDEN_FLAT * noise {
                return (wide, noise, false); // flat as the noise: kept, growth not asked
            }
            // The same ball at half the radius, for the growth test. Range noise does not
            // thicken a fit as its ball grows; a crease or a curve does (4 and 16 times the
            // variance for twice the radius).
            let quarter = reach2[i] / 4.0;
            let half = all
                .zip(inside)
                .filter(|&(_, &(_, d2))| d2 <= quarter)
                .map(|(o, _)| o);
            let half = Fit::of_offsets(half);
            let grows = half.count < 2 * fit.count || wide.thin > WIDEN_GROWTH * half.thin;
            (wide, noise, grows)
        });
        (&mut *normals, fits, &mut reach2, &mut deepened, &wider)
            .into_par_iter()
            .for_each(|(n, &(fit, d2), r2, deep, wider)| {
                let Some((f, noise, grows)) = *wider else {
                    *r2 = 0.0; // given up (or never asked): not asked again
                    return;
                };
                // An empty wide fit: the k-nearest one is within the tolerance.
                if f.count <= fit.count {
                    *r2 = 0.0;
                } else if f.thin <= WIDEN_FLAT * noise || !grows {
                    *n = f.normal;
                    *r2 = 0.0;
                } else {
                    // The half ball lay within the noise's depth (the wide fit's thinness
                    // measures it): its fit was a blob, and the test compared a blob with the
                    // noise. Once, wide enough that the half ball clears it.
                    let past = 4.0 * WIDEN_DEEP.0 * WIDEN_DEEP.0 * f.thin;
                    if !*deep && *r2 < past && *r2 < deepest * d2 {
                        *deep = true;
                        *r2 = past.min(deepest * d2);
                        return;
                    }
                    // Not flat: once more at the least radius, if this was wider.
                    *r2 = match *r2 > least * d2 * 1.001 {
                        true => least * d2,
                        false => 0.0,
                    };
                }
            });
    }
}

/// The median thinness of the `k`-nearest fits of point `i` and of up to [`POOLED`] points
/// `inside` its wider patch: the noise across the surface there, from many samples.
fn pooled_thin(fits: &[(Fit, f32)], i: usize, inside: &[(u32, f32)]) -> f32 {
    let mut t = [0f32; POOLED + 1];
    t[0] = fits[i].0.thin;
    let n = 1 + inside.len().min(POOLED);
    for (t, &(j, _)) in t[1..n].iter_mut().zip(inside) {
        *t = fits[j as usize].0.thin;
    }
    let t = &mut t[..n];
    *t.select_nth_unstable_by(n / 2, f32::total_cmp).1
}

/// Fits read for [`pooled_thin`] at most, besides the point's own.
const POOLED: usize = 32;

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

// ---------------------------------------------------------------------------------------------
// Orientation by propagation

/// Orient `normals` consistently; `graph` holds `kg` neighbour indices per point (u32::MAX for
/// none). See [`estimate_normals`].
fn propagate(positions: &[Vec3], normals: &mut [Vec3], graph: &[u32], kg: usize) {
    let n = positions.len();
    if kg == 0 {
        // One point at most per component: orient each as a seed.
        for i in 0..n {
            orient_seed(positions, normals, &[i as u32]);
        }
        return;
    }
    let row = |i: usize| {
        graph[i * kg..(i + 1) * kg]
            .iter()
            .copied()
            .filter(|&j| j != u32::MAX)
    };
    // Make the graph symmetric: store the reverse edges j -> i that j's own list lacks.
    let mut rev_count = vec![0u32; n + 1];
    let mutual = |i: usize, j: usize| graph[j * kg..(j + 1) * kg].contains(&(i as u32));
    for i in 0..n {
        for j in row(i) {
            if !mutual(i, j as usize) {
                rev_count[j as usize + 1] += 1;
            }
        }
    }
    for i in 0..n {
        rev_count[i + 1] += rev_count[i];
    }
    let rev_start = rev_count;
    let mut fill = rev_start.clone();
    let mut rev = vec![0u32; rev_start[n] as usize];
    for i in 0..n {
        for j in row(i) {
            if !mutual(i, j as usize) {
                let f = &mut fill[j as usize];
                rev[*f as usize] = i as u32;
                *f += 1;
            }
        }
    }
    let adj = |i: usize| {
        row(i).chain(
            rev[rev_start[i] as usize..rev_start[i + 1] as usize]
                .iter()
                .copied(),
        )
    };

    let mut seen = vec![false; n]; // component labelling
    let mut done = vec![false; n]; // oriented
    let mut stack: Vec<u32> = Vec::new();
    let mut comp: Vec<u32> = Vec::new();
    let mut queue = BucketQueue::new();
    let mut best = vec![u16::MAX; n]; // best queued weight bucket per point
    for start in 0..n {
        if seen[start] {
            continue;
        }
        // The component of `start`.
        comp.clear();
        stack.push(start as u32);
        seen[start] = true;
        while let Some(i) = stack.pop() {
            comp.push(i);
            for j in adj(i as usize) {
                if !seen[j as usize] {
                    seen[j as usize] = true;
                    stack.push(j);
                }
            }
        }
        let seed = orient_seed(positions, normals, &comp);
        // Prim's MST from the seed, orienting each point from the tree edge that reaches it.
        let mut push = |queue: &mut BucketQueue, normals: &[Vec3], done: &[bool], i: u32| {
            let ni = normals[i as usize];
            for j in adj(i as usize) {
                if !done[j as usize] {
                    let b = weight_bucket(ni.dot(normals[j as usize]));
                    if b < best[j as usize] {
                        best[j as usize] = b;
                        queue.push(b, j, i);
                    }
                }
            }
        };
        done[seed as usize] = true;
        push(&mut queue, normals, &done, seed);
        while let Some((j, from)) = queue.pop() {
            if done[j as usize] {
                continue;
            }
            done[j as usize] = true;
            if normals[j as usize].dot(normals[from as usize]) < 0.0 {
                normals[j as usize] = -normals[j as usize];
            }
            push(&mut queue, normals, &done, j);
        }
    }
}

/// Buckets of the Prim queue.
const BUCKETS: usize = 1024;

/// The MST edge weight `1 - |cos|`, quantized monotonically: `sqrt(1 - |cos|)` is nearly
/// proportional to the angle between the normals (≈ θ/√2), so one bucket is ≈ 0.08°.
#[inline]
fn weight_bucket(cos: f32) -> u16 {
    let w = (1.0 - cos.abs()).max(0.0);
    ((w.sqrt() * (BUCKETS - 1) as f32).round() as usize).min(BUCKETS - 1) as u16
}

/// A priority queue over small integer keys (a bucket queue): O(1) push, pop scans forward
/// from the lowest possibly non-empty bucket. Entries are (point, the point it is reached
/// from). Within a bucket the order is last-in first-out.
struct BucketQueue {
    buckets: Vec<Vec<(u32, u32)>>,
    low: usize,
    len: usize,
}

impl BucketQueue {
    fn new() -> Self {
        Self {
            buckets: (0..BUCKETS).map(|_| Vec::new()).collect(),
            low: BUCKETS,
            len: 0,
        }
    }

    fn push(&mut self, key: u16, j: u32, from: u32) {
        let k = key as usize;
        self.buckets[k].push((j, from));
        self.low = self.low.min(k);
        self.len += 1;
    }

    fn pop(&mut self) -> Option<(u32, u32)> {
        if self.len == 0 {
            self.low = BUCKETS;
            return None;
        }
        while self.buckets[self.low].is_empty() {
            self.low += 1;
        }
        self.len -= 1;
        self.buckets[self.low].pop()
    }
}

/// Pick the seed of a component (see [`estimate_normals`]), orient its normal outward, and
/// return its index.
fn orient_seed(positions: &[Vec3], normals: &mut [Vec3], comp: &[u32]) -> u32 {
    let mut best = (comp[0], Vec3::X, f32::NEG_INFINITY);
    for axis in 0..3 {
        for sign in [1.0f32, -1.0] {
            let ext = *comp
                .iter()
                .max_by(|&&a, &&b| {
                    (sign * positions[a as usize][axis])
                        .total_cmp(&(sign * positions[b as usize][axis]))
                })
                .unwrap();
            let mut dir = Vec3::ZERO;
            dir[axis] = sign;
            let score = normals[ext as usize].dot(dir).abs();
            if score > best.2 {
                best = (ext, dir, score);
            }
        }
    }
    let (seed, dir, _) = best;
    if normals[seed as usize].dot(dir) < 0.0 {
        normals[seed as usize] = -normals[seed as usize];
    }
    seed
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
