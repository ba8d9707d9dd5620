//! The caustic lookup: the hashed grid (dense buckets held as groups) finds the same photons as
//! a brute-force sum, and CPU and GPU render the same image with a photon map.

use glam::Vec3;
use pc_artifact::photons::{sections, Photon};
use pc_artifact::PointLight;
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key};
use pc_config::ShadingMode;
use pc_raytrace::caustic::{Caustics, PhotonGrid};
use pc_raytrace::photon_lanes::{scan, scan_scalar, PhotonLanes, Quad};
use pc_raytrace::scene::RenderScene;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use super::{camera, mixed_room, params};

/// A photons artifact holding `photons` (the sections pc-caustics writes).
fn photon_file(path: &std::path::Path, photons: &[Photon]) -> Artifact {
    let mut w =
        ArtifactWriter::create(path, ArtifactKind::Photons, "test", "0", Key::default()).unwrap();
    w.section(sections::PHOTONS, photons).unwrap();
    w.section(sections::DEPOSIT, &[[0f32; 3]]).unwrap();
    w.metadata(&pc_artifact::photons::PhotonsMeta::default())
        .unwrap();
    w.finish().unwrap();
    Artifact::open(path).unwrap()
}

/// Photons on the floor of the mixed room (y = −1, arriving downwards), denser in a bright
/// spot, and a few on the back wall (z = −1) arriving from the front and from behind.
fn room_photons(n: usize) -> Vec<Photon> {
    let mut rng = Pcg64::seed_from_u64(4);
    (0..n)
        .map(|i| {
            let (position, dir) = if i % 10 == 9 {
                let d = if i % 20 == 9 { 1.0 } else { -1.0 };
                (
                    [
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        -1.0,
                    ],
                    [0.0, 0.0, d],
                )
            } else if i % 2 == 0 {
                let (r, a) = (
                    0.15 * rng.random::<f32>().sqrt(),
                    rng.random_range(0.0f32..std::f32::consts::TAU),
                );
                (
                    [0.3 + r * a.cos(), -1.0, 0.2 + r * a.sin()],
                    [0.0, -1.0, 0.0],
                )
            } else {
                (
                    [
                        rng.random_range(-1.0..1.0),
                        -1.0,
                        rng.random_range(-1.0..1.0),
                    ],
                    Vec3::new(0.3, -1.0, 0.1).normalize().into(),
                )
            };
            Photon {
                position,
                splat: 0,
                dir,
                bounces: 1,
                power: [2e-5, 1.5e-5, 1e-5],
                _pad: 0,
            }
        })
        .collect()
}

/// The hashed grid (the fixed-radius estimate of both renderers) against the brute-force sum over
/// every photon, at 4,000 points of the room's floor and back wall: with 4,000 photons no bucket
/// is dense and the grid holds each photon as it is.
#[test]
fn the_hashed_grid_finds_every_photon_within_the_radius() {
    let photons = room_photons(4_000);
    let grid = PhotonGrid::new(&photons, 0.03);
    assert_eq!(grid.photons.len(), photons.len(), "no bucket is dense");
    let worst = worst_relative_error(&photons, 0.03, 500);
    assert!(worst <= 1e-5, "worst relative error {worst}");
}

/// With 40,000 photons the bright spot's buckets are dense and held as groups: the estimate is
/// still the photon-by-photon one, and a lookup in the spot reads a fraction of the photons it
/// read before (all of its buckets').
#[test]
fn a_dense_bucket_is_grouped_and_keeps_the_estimate() {
    let photons = room_photons(40_000);
    let r = 0.03;
    let grid = PhotonGrid::new(&photons, r);
    assert!(!grid.groups.is_empty(), "the spot's buckets are dense");
    assert_eq!(grid.photons.len(), photons.len());
    let worst = worst_relative_error(&photons, r, 2000);
    assert!(worst <= 1e-5, "worst relative error {worst}");
    // In the spot's middle: every photon of the 8 buckets before, now the groups and the photons
    // of those the radius's edge cuts.
    let x = Vec3::new(0.3, -1.0, 0.2);
    let (buckets, count) = grid.buckets(x);
    let all: u32 = buckets[..count]
        .iter()
        .map(|&b| {
            let b = b as usize;
            let n = grid.mask as usize + 2;
            (grid.offsets[b + 1] - grid.offsets[b])
                + grid.groups[grid.offsets[n + b] as usize..grid.offsets[n + b + 1] as usize]
                    .iter()
                    .map(|g| g.count)
                    .sum::<u32>()
        })
        .sum();
    let reads = grid.reads(x, Vec3::Y);
    assert!(
        reads * 3 < all as usize,
        "a lookup in the spot reads {reads} of {all}"
    );
}

/// A dense spot of photons of every colour, arriving from many directions (some nearly along
/// the floor) and lying up to a third of a radius off the floor's plane: queries with normals
/// tilted up to 40° put groups on each side of every bound (the radius, the tangent plane's
/// quarter radius, the facing test), and the grid still gives the brute-force sum.
#[test]
fn groups_of_mixed_colours_and_directions_keep_the_estimate() {
    let r = 0.03;
    let mut rng = Pcg64::seed_from_u64(11);
    let photons: Vec<Photon> = (0..30_000)
        .map(|_| {
            let (rad, a) = (
                0.12 * rng.random::<f32>().sqrt(),
                rng.random_range(0.0f32..std::f32::consts::TAU),
            );
            let dir = Vec3::new(
                rng.random_range(-1.0..1.0),
                -rng.random_range(0.05..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize();
            Photon {
                position: [
                    0.3 + rad * a.cos(),
                    -1.0 + rng.random_range(-0.33 * r..0.33 * r),
                    0.2 + rad * a.sin(),
                ],
                splat: rng.random_range(0..4),
                dir: dir.into(),
                bounces: 1,
                power: [0, 1, 2].map(|_| rng.random_range(0.0..3e-5)),
                _pad: 0,
            }
        })
        .collect();
    let grid = PhotonGrid::new(&photons, r);
    assert!(!grid.groups.is_empty(), "the spot's buckets are dense");
    let mut worst = 0.0f32;
    let mut peak = 0.0f32;
    let mut found = Vec::new();
    for _ in 0..3000 {
        let x = Vec3::new(
            0.3 + rng.random_range(-0.15..0.15),
            -1.0 + rng.random_range(-0.2 * r..0.2 * r),
            0.2 + rng.random_range(-0.15..0.15),
        );
        let tilt = rng.random_range(0.0f32..0.7);
        let a = rng.random_range(0.0f32..std::f32::consts::TAU);
        let n = Vec3::new(tilt.sin() * a.cos(), tilt.cos(), tilt.sin() * a.sin());
        let (want, got) = (brute(&photons, x, n, r), grid.irradiance(x, n));
        peak = peak.max(want.max_element());
        found.push((want, got));
    }
    for (want, got) in &found {
        let e = (*want - *got).abs().max_element() / want.max_element().max(0.01 * peak);
        worst = worst.max(e);
    }
    assert!(peak > 0.0);
    assert!(worst <= 1e-4, "worst relative error {worst}");
    // And some groups were settled whole by their bounds (taken or skipped): the spot's middle
    // reads fewer than its buckets' photons, though with directions this mixed most groups
    // stay open.
    let (x, n) = (Vec3::new(0.3, -1.0, 0.2), Vec3::Y);
    let (buckets, count) = grid.buckets(x);
    let at = grid.mask as usize + 2;
    let all: u32 = buckets[..count]
        .iter()
        .map(|&b| {
            let b = b as usize;
            let groups =
                &grid.groups[grid.offsets[at + b] as usize..grid.offsets[at + b + 1] as usize];
            grid.offsets[b + 1] - grid.offsets[b] + groups.iter().map(|g| g.count).sum::<u32>()
        })
        .sum();
    let reads = grid.reads(x, n);
    assert!(reads < all as usize, "{reads} of {all}");
}

/// The buckets a lookup reads are those of the plain statement, in its order: the 2 × 2 × 2
/// cells nearest the point (each axis's own cell and its nearer neighbour), each bucket once,
/// cells below zero left out; at points inside, beside, far outside and on cell faces.
#[test]
fn a_lookup_reads_the_buckets_of_its_eight_nearest_cells() {
    use pc_raytrace::photon_grid::grid_hash;
    let grid = PhotonGrid::new(&room_photons(3000), 0.03);
    let plain = |x: Vec3| {
        let q = (x - Vec3::from(grid.origin)) / grid.cell;
        let (c, f) = (q.floor(), q - q.floor());
        let mut out = Vec::new();
        for i in 0..8u32 {
            let cc: [i64; 3] = std::array::from_fn(|a| {
                let step = if f[a] < 0.5 { -1 } else { 1 };
                c[a] as i64 + if (i >> a) & 1 == 1 { step } else { 0 }
            });
            if cc.iter().any(|&v| v < 0 || v > u32::MAX as i64) {
                continue;
            }
            let h = grid_hash(cc.map(|v| v as u32), grid.mask);
            if !out.contains(&h) {
                out.push(h);
            }
        }
        out
    };
    let mut rng = Pcg64::seed_from_u64(23);
    let o = Vec3::from(grid.origin);
    for k in 0..20_000 {
        let x = match k % 4 {
            0 => Vec3::new(
                rng.random_range(-1.2..1.2),
                rng.random_range(-1.2..1.2),
                rng.random_range(-1.2..1.2),
            ),
            // On cell faces and half-cells.
            1 => {
                o + grid.cell
                    * 0.5
                    * Vec3::new(
                        rng.random_range(-4..60) as f32,
                        rng.random_range(-4..60) as f32,
                        rng.random_range(-4..60) as f32,
                    )
            }
            2 => Vec3::splat(rng.random_range(-1e9..1e9)),
            _ => o - Vec3::splat(rng.random_range(0.0..0.1)),
        };
        let (got, n) = grid.buckets(x);
        assert_eq!(got[..n], plain(x)[..], "point {x}");
    }
}

/// The CPU renderer's lanes (four photons a record) give the grid's photon-by-photon estimate,
/// groups and all, to float rounding: the same photons with the same weights, summed in four
/// running sums.
#[test]
fn the_lanes_give_the_grid_s_estimate() {
    let r = 0.03;
    let photons = room_photons(40_000);
    let grid = PhotonGrid::new(&photons, r);
    assert!(!grid.groups.is_empty(), "the spot's buckets are dense");
    let lanes = PhotonLanes::new(&grid);
    let mut rng = Pcg64::seed_from_u64(21);
    let (mut peak, mut pairs) = (0.0f32, Vec::new());
    for i in 0..3000 {
        let (x, n) = match i % 3 {
            0 => (
                Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    -1.0,
                ),
                Vec3::Z,
            ),
            _ => (
                Vec3::new(
                    0.3 + rng.random_range(-0.2..0.2),
                    -1.0 + rng.random_range(-0.01..0.01),
                    0.2 + rng.random_range(-0.2..0.2),
                ),
                Vec3::new(rng.random_range(-0.3..0.3), 1.0, 0.0).normalize(),
            ),
        };
        let (want, got) = (grid.irradiance(x, n), lanes.irradiance(&grid, x, n));
        peak = peak.max(want.max_element());
        pairs.push((want, got));
    }
    assert!(peak > 0.0);
    let worst = pairs
        .iter()
        .map(|(a, b)| (*a - *b).abs().max_element() / a.max_element().max(1e-3 * peak))
        .fold(0.0, f32::max);
    assert!(worst <= 1e-5, "worst relative error {worst}");
    let lit = pairs.iter().filter(|(a, _)| a.x > 0.0).count();
    assert!(lit > 1000, "{lit} lookups found photons");
}

/// The SSE scan is its portable twin lane for lane, to the bit: photons inside, outside and on
/// the radius's rim, in front of and behind the surface, on and off its tangent plane, and the
/// padding lanes of a partial record.
#[test]
fn the_sse_scan_is_its_scalar_twin() {
    let mut rng = Pcg64::seed_from_u64(22);
    let r = 0.05;
    for trial in 0..200 {
        let count = rng.random_range(0..40);
        let photons: Vec<Photon> = (0..count)
            .map(|i| {
                let mut d = Vec3::new(
                    rng.random_range(-1.5 * r..1.5 * r),
                    rng.random_range(-0.5 * r..0.5 * r),
                    rng.random_range(-1.5 * r..1.5 * r),
                );
                if i % 7 == 0 {
                    d = Vec3::new(r, 0.0, 0.0);
                }
                Photon {
                    position: (Vec3::new(0.1, 0.2, 0.3) + d).into(),
                    splat: 0,
                    dir: Vec3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..0.5),
                        0.2,
                    )
                    .normalize()
                    .into(),
                    bounces: 1,
                    power: [0, 1, 2].map(|_| rng.random_range(0.0..1.0)),
                    _pad: 0,
                }
            })
            .collect();
        let quads: Vec<Quad> = photons.chunks(4).map(Quad::of).collect();
        let n = Vec3::new(rng.random_range(-0.2..0.2), 1.0, 0.1).normalize();
        let x = Vec3::new(0.1, 0.2, 0.3);
        let (a, b) = (scan(&quads, x, n, r), scan_scalar(&quads, x, n, r));
        assert_eq!(
            a.to_array().map(f32::to_bits),
            b.to_array().map(f32::to_bits),
            "trial {trial}"
        );
    }
}

/// The largest error of the grid's estimate (through [`Caustics`], as the renderers read it)
/// relative to the brute-force sum at `points` points of the floor and back wall, each error
/// relative to the larger of that point's sum and 1 % of the sums' peak (so that a dim point's
/// rounding does not count as a large error).
fn worst_relative_error(photons: &[Photon], r: f32, points: usize) -> f32 {
    let dir = tempfile::tempdir().unwrap();
    let a = photon_file(&dir.path().join("photons.pcgi"), photons);
    let c = Caustics::new(a.section(sections::PHOTONS).unwrap(), r, 0);
    let mut rng = Pcg64::seed_from_u64(8);
    let mut found = Vec::new();
    for i in 0..points {
        let (x, n) = if i % 4 == 3 {
            (
                Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    -1.0,
                ),
                Vec3::Z,
            )
        } else {
            // Half of the floor's points in the bright spot.
            let (cx, cz, h) = match i % 2 {
                0 => (0.3, 0.2, 0.17),
                _ => (0.0, 0.0, 1.1),
            };
            (
                Vec3::new(
                    cx + rng.random_range(-h..h),
                    -1.0,
                    cz + rng.random_range(-h..h),
                ),
                Vec3::Y,
            )
        };
        let (a, b) = (brute(photons, x, n, r), c.irradiance(x, n));
        found.push((a, b));
    }
    let peak = found
        .iter()
        .map(|(a, _)| a.max_element())
        .fold(0.0, f32::max);
    assert!(peak > 0.0);
    let lit = found
        .iter()
        .filter(|(a, _)| a.max_element() > 0.01 * peak)
        .count();
    assert!(lit > points / 4, "{lit} of {points} lookups found photons");
    found
        .iter()
        .map(|(a, b)| (*a - *b).abs().max_element() / a.max_element().max(0.01 * peak))
        .fold(0.0, f32::max)
}

/// The fixed-radius estimate by brute force over every photon: those within `r` of `x` that
/// arrived from the front of the surface of normal `n` and lie within a quarter radius of its
/// tangent plane, under the Epanechnikov kernel.
fn brute(photons: &[Photon], x: Vec3, n: Vec3, r: f32) -> Vec3 {
    photons
        .iter()
        .filter(|q| Vec3::from(q.dir).dot(n) < 0.0)
        .map(|q| {
            let d2 = (Vec3::from(q.position) - x).length_squared();
            let off = (Vec3::from(q.position) - x).dot(n).abs();
            match d2 <= r * r && off <= 0.25 * r {
                true => Vec3::from(q.power) * (1.0 - d2 / (r * r)).max(0.0),
                false => Vec3::ZERO,
            }
        })
        .sum::<Vec3>()
        * (2.0 / (std::f32::consts::PI * r * r))
}

/// The grid finds a lone photon just inside the radius, from every side, at any scale of
/// coordinates, and nothing far from every photon.
#[test]
fn the_grid_never_hides_a_photon() {
    let mut rng = Pcg64::seed_from_u64(12);
    for (scale, r) in [(1.0f32, 0.03f32), (300.0, 0.5), (0.01, 1e-4)] {
        let photons: Vec<Photon> = room_photons(300)
            .into_iter()
            .map(|mut p| {
                p.position = p.position.map(|c| c * scale);
                p
            })
            .collect();
        let c = Caustics::new(&photons, r, 0);
        let mut found = 0;
        for (i, p) in photons.iter().enumerate().filter(|(_, p)| p.dir[1] < 0.0) {
            // A point on the floor at 0.9 to 0.9999 r from the photon, in any direction.
            let a = rng.random_range(0.0f32..std::f32::consts::TAU);
            let d = r * rng.random_range(0.9f32..0.9999);
            let x = Vec3::from(p.position) + Vec3::new(d * a.cos(), 0.0, d * a.sin());
            let brute = brute(&photons, x, Vec3::Y, r);
            let e = c.irradiance(x, Vec3::Y);
            assert!(
                (e - brute).abs().max_element() <= 1e-3 * brute.max_element(),
                "scale {scale}, photon {i}: {e} vs {brute}"
            );
            found += (e.x > 0.0) as usize;
        }
        assert!(found > 100, "{found} lookups found their photon");
        // Far from every photon: nothing.
        assert_eq!(c.irradiance(Vec3::splat(5.0 * scale), Vec3::Y), Vec3::ZERO);
    }
}

#[test]
fn cpu_and_gpu_render_the_same_caustics() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let photons = room_photons(60_000);
    // The spot's buckets are dense: both renderers read its groups.
    assert!(!PhotonGrid::new(&photons, 0.04).groups.is_empty());
    let a = photon_file(&dir.path().join("photons.pcgi"), &photons);
    let (o, mats) = mixed_room();
    let cam = camera(Vec3::new(0.0, 0.0, 3.5), Vec3::ZERO, Vec3::Y, 40.0, 48, 40);
    let light = PointLight::new([0.2, 0.7, 0.3], [0.6; 3]);
    let mut p = params(4, ShadingMode::Direct);
    p.max_bounces = 6;
    let mut sc = RenderScene::new(o.view(), mats, &[light], &cam, &p);
    sc.caustics = Some(Caustics::new(
        a.section(sections::PHOTONS).unwrap(),
        0.04,
        0,
    ));
    sc.prepare_cpu();
    let (cpu, _) = pc_raytrace::cpu::render(&sc, false, &|| {});
    let gpu = pc_raytrace::gpu::render::GpuRenderer::new(&ctx, &sc)
        .unwrap()
        .render(&ctx, &sc, false)
        .unwrap();
    let c = pc_raytrace::image::compare(&gpu, &cpu).unwrap();
    assert!(c.mean_relative < 1e-3, "{c} on {}", ctx.describe());
    // The caustic shows: brighter than the same render without it.
    sc.caustics = None;
    let (plain, _) = pc_raytrace::cpu::render(&sc, false, &|| {});
    assert!(
        cpu.mean()[0] > 1.05 * plain.mean()[0],
        "{:?} vs {:?}",
        cpu.mean(),
        plain.mean()
    );
    // k-nearest stays on the CPU: the GPU renderer says so.
    sc.caustics = Some(Caustics::new(
        a.section(sections::PHOTONS).unwrap(),
        0.04,
        16,
    ));
    let err = pc_raytrace::gpu::render::GpuRenderer::new(&ctx, &sc)
        .err()
        .expect("k-nearest on the GPU is refused");
    assert!(err.to_string().contains("k-nearest"), "{err}");
}

/// The k-nearest estimate over a uniform photon density matches it where at least k photons lie
/// within the radius, and where fewer do it divides by the search disk, not by the farthest
/// photon found: one photon beside the point is not a bright spot.
#[test]
fn k_nearest_divides_by_the_search_disk_where_photons_are_sparse() {
    let photon = |x: f32, z: f32| Photon {
        position: [x, 0.0, z],
        splat: 0,
        dir: [0.0, -1.0, 0.0],
        bounces: 1,
        power: [1.0; 3],
        _pad: 0,
    };
    let (x, n) = (Vec3::ZERO, Vec3::Y);
    let r = 0.1f32;
    // One photon 1 mm from the point.
    let one = [photon(0.001, 0.0)];
    let c = Caustics::new(&one, r, 50);
    let e = c.irradiance(x, n).x;
    let want = 1.0 / (std::f32::consts::PI * r * r);
    assert!((e / want - 1.0).abs() < 1e-5, "{e} against {want}");
    // A grid of 1 photon per mm²: k = 50 nearest give about 1 per mm² (= 1e6 per m²).
    let grid: Vec<Photon> = (-100..=100)
        .flat_map(|i| (-100..=100).map(move |j| (i, j)))
        .map(|(i, j)| photon(i as f32 * 1e-3, j as f32 * 1e-3))
        .collect();
    let c = Caustics::new(&grid, r, 50);
    let e = c.irradiance(x, n).x;
    assert!((e / 1e6 - 1.0).abs() < 0.15, "{e} against 1e6");
}
