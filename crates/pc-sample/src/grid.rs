//! Shapes to sample, the global spacing and per-patch grid sizes that give the requested
//! number of splats, and the deterministic, parallel sampling itself.

use glam::Vec3;
use pc_import::ply_write::PlyPoints;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::geometry::{Geometry, Patch};
use crate::SampleParams;

/// A shape to sample: its name (used in file names), material name and geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeSpec {
    pub name: String,
    pub material: String,
    pub geometry: Geometry,
}

impl ShapeSpec {
    pub fn new(name: &str, material: &str, geometry: Geometry) -> Self {
        ShapeSpec {
            name: name.to_owned(),
            material: material.to_owned(),
            geometry,
        }
    }
}

/// The splats of one shape.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledShape {
    pub name: String,
    pub material: String,
    pub geometry: Geometry,
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub radii: Vec<f32>,
    /// Analytic surface area.
    pub area: f32,
}

impl SampledShape {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Borrowed view for [`pc_import::ply_write::write_ply`].
    pub fn ply_points(&self) -> PlyPoints<'_> {
        PlyPoints {
            positions: &self.positions,
            normals: Some(&self.normals),
            radii: Some(&self.radii),
            colors: None,
        }
    }
}

/// The global target spacing giving a total count as close as possible to `points`: starts at
/// `sqrt(total_area / points)` and searches ±10 % around it (grid counts are rounded per patch).
pub fn choose_spacing(specs: &[ShapeSpec], points: usize) -> f32 {
    let patches: Vec<Patch> = specs.iter().flat_map(|s| s.geometry.patches()).collect();
    let area: f64 = specs.iter().map(|s| s.geometry.area() as f64).sum();
    let n = points.max(1) as f64;
    let h0 = (area / n).sqrt();
    if !(h0.is_finite() && h0 > 0.0) {
        return 1.0;
    }
    let count = |h: f32| -> usize {
        patches
            .iter()
            .map(|p| {
                let (a, b) = p.dims(h);
                a * b
            })
            .sum()
    };
    const STEPS: i32 = 400;
    let mut best = (usize::MAX, f64::MAX, h0 as f32);
    for k in -STEPS..=STEPS {
        let x = 0.1 * k as f64 / STEPS as f64;
        let h = (h0 * x.exp()) as f32;
        let err = count(h).abs_diff(points.max(1));
        let key = (err, x.abs());
        if key.0 < best.0 || (key.0 == best.0 && key.1 < best.1) {
            best = (err, x.abs(), h);
        }
    }
    best.2
}

/// Grid sizes `(columns, rows)` for every patch of every shape (boxes: 6 faces, spheres: 6
/// cube faces), planned for a total count close to the requested one.
#[derive(Clone, Debug, PartialEq)]
pub struct GridPlan {
    /// The global target spacing the grids started from.
    pub spacing: f32,
    /// `dims[shape][patch]`.
    pub dims: Vec<Vec<(usize, usize)>>,
}

impl GridPlan {
    pub fn total(&self) -> usize {
        self.dims.iter().flatten().map(|(a, b)| a * b).sum()
    }
}

/// Plans the grids: every patch sized from the spacing of [`choose_spacing`], then single rows
/// or columns added to (or removed from) the patches where that distorts the cells least, while
/// it brings the total closer to `points` (the global spacing alone moves in steps of whole
/// rows of every wall at once, too coarse for small counts).
pub fn plan_grids(specs: &[ShapeSpec], points: usize) -> GridPlan {
    let h = choose_spacing(specs, points);
    let patches: Vec<Vec<Patch>> = specs.iter().map(|s| s.geometry.patches()).collect();
    let mut dims: Vec<Vec<(usize, usize)>> = patches
        .iter()
        .map(|ps| ps.iter().map(|p| p.dims(h)).collect())
        .collect();
    let target = points.max(1) as i64;
    let mut count: i64 = dims.iter().flatten().map(|(a, b)| (a * b) as i64).sum();
    // Cell aspect badness |ln(cell_u / cell_v)|.
    let badness = |p: &Patch, (nu, nv): (usize, usize)| -> f32 {
        let (lu, lv) = p.side_lengths();
        ((lu / nu as f32) / (lv / nv as f32)).ln().abs()
    };
    let limit = 1.5f32.ln();
    for _ in 0..1_000_000 {
        let diff = target - count;
        if diff == 0 {
            break;
        }
        let step: i64 = diff.signum();
        // (badness, shape, patch, new dims, count change)
        type Move = (f32, usize, usize, (usize, usize), i64);
        let mut best: Option<Move> = None;
        for (si, ps) in patches.iter().enumerate() {
            for (pi, p) in ps.iter().enumerate() {
                let (nu, nv) = dims[si][pi];
                let old_bad = badness(p, (nu, nv));
                for axis in 0..2 {
                    let cand = if axis == 0 {
                        ((nu as i64 + step) as usize, nv)
                    } else {
                        (nu, (nv as i64 + step) as usize)
                    };
                    if cand.0 == 0 || cand.1 == 0 {
                        continue;
                    }
                    let delta = (cand.0 * cand.1) as i64 - (nu * nv) as i64;
                    if (diff - delta).abs() >= diff.abs() {
                        continue;
                    }
                    let bad = badness(p, cand);
                    if bad > old_bad.max(limit) {
                        continue;
                    }
                    if best.is_none_or(|b| bad < b.0) {
                        best = Some((bad, si, pi, cand, delta));
                    }
                }
            }
        }
        match best {
            Some((_, si, pi, cand, delta)) => {
                dims[si][pi] = cand;
                count += delta;
            }
            None => break,
        }
    }
    GridPlan { spacing: h, dims }
}

/// Samples every shape (in parallel) on the grids of [`plan_grids`]; returns the shapes and
/// the global target spacing.
pub fn sample_shapes(specs: &[ShapeSpec], params: &SampleParams) -> (Vec<SampledShape>, f32) {
    let plan = plan_grids(specs, params.points);
    let shapes = specs
        .par_iter()
        .zip(&plan.dims)
        .map(|(spec, dims)| sample_shape(spec, dims, params))
        .collect();
    (shapes, plan.spacing)
}

/// Samples one shape on the given grid sizes (one `(columns, rows)` per patch: 1 for a
/// rectangle, 6 for a box or a sphere, see [`GridPlan`]).
pub fn sample_shape(
    spec: &ShapeSpec,
    dims: &[(usize, usize)],
    params: &SampleParams,
) -> SampledShape {
    let patches = spec.geometry.patches();
    assert_eq!(
        patches.len(),
        dims.len(),
        "shape {}: one grid size per patch",
        spec.name
    );
    let total: usize = dims.iter().map(|(a, b)| a * b).sum();
    let mut positions = vec![Vec3::ZERO; total];
    let mut normals = vec![Vec3::ZERO; total];
    let mut radii = vec![0f32; total];
    let shape_key = fnv1a(spec.name.as_bytes());

    // Split the output into one slice triple per patch.
    let mut jobs = Vec::with_capacity(patches.len());
    {
        let (mut p, mut n, mut r) = (&mut positions[..], &mut normals[..], &mut radii[..]);
        for (idx, (patch, &(nu, nv))) in patches.iter().zip(dims).enumerate() {
            let len = nu * nv;
            let (p0, p1) = std::mem::take(&mut p).split_at_mut(len);
            let (n0, n1) = std::mem::take(&mut n).split_at_mut(len);
            let (r0, r1) = std::mem::take(&mut r).split_at_mut(len);
            jobs.push((idx, patch, nu, nv, p0, n0, r0));
            p = p1;
            n = n1;
            r = r1;
        }
    }
    jobs.into_par_iter()
        .for_each(|(idx, patch, nu, nv, p, n, r)| {
            p.par_chunks_mut(nu)
                .zip(n.par_chunks_mut(nu))
                .zip(r.par_chunks_mut(nu))
                .enumerate()
                .for_each(|(j, ((p, n), r))| {
                    let mut rng = Pcg64Mcg::seed_from_u64(stream_seed(
                        params.seed,
                        shape_key,
                        idx as u64,
                        j as u64,
                    ));
                    patch.sample_row((nu, nv, j), &mut rng, params, (p, n, r));
                });
        });

    SampledShape {
        name: spec.name.clone(),
        material: spec.material.clone(),
        geometry: spec.geometry,
        positions,
        normals,
        radii,
        area: spec.geometry.area(),
    }
}

fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn stream_seed(seed: u64, shape: u64, patch: u64, row: u64) -> u64 {
    splitmix64(splitmix64(splitmix64(splitmix64(seed) ^ shape) ^ patch) ^ row)
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3)
    })
}
