use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::*;

fn all_scenes(params: &SampleParams) -> Vec<SampledScene> {
    vec![
        cornell(params, false),
        cornell(params, true),
        sphere(params),
        glass_box(params),
    ]
}

#[test]
fn total_count_close_to_requested() {
    for n in [1_000usize, 5_000, 100_000] {
        for scene in all_scenes(&SampleParams::with_points(n)) {
            let got = scene.total_points();
            let rel = (got as f64 - n as f64).abs() / n as f64;
            assert!(
                rel <= 0.02,
                "{} (specular shapes: {}): {got} splats for {n} requested",
                scene.name,
                scene.shapes.len()
            );
        }
    }
}

#[test]
fn planned_cells_are_near_square() {
    for n in [100usize, 1_000, 5_000, 100_000, 1_000_000, 10_000_000] {
        for specs in [cornell_specs(false), cornell_specs(true), glass_box_specs()] {
            let plan = plan_grids(&specs, n);
            let rel = (plan.total() as f64 - n as f64).abs() / n as f64;
            assert!(
                rel <= if n >= 1000 { 0.02 } else { 0.1 },
                "{n}: {}",
                plan.total()
            );
            for (spec, dims) in specs.iter().zip(&plan.dims) {
                for (p, &(nu, nv)) in spec.geometry.patches().iter().zip(dims) {
                    let (lu, lv) = p.side_lengths();
                    let aspect = (lu / nu as f32) / (lv / nv as f32);
                    let aspect = aspect.max(1.0 / aspect);
                    if nu > 1 && nv > 1 {
                        assert!(aspect <= 1.5 + 1e-4, "{n} {}: {nu}x{nv}", spec.name);
                    }
                }
            }
        }
    }
}

#[test]
fn tiny_and_odd_counts_work() {
    for n in [1usize, 7, 100, 333] {
        for scene in all_scenes(&SampleParams::with_points(n)) {
            assert!(scene.total_points() >= scene.shapes.len());
            for s in &scene.shapes {
                assert!(!s.is_empty());
                assert!(s.radii.iter().all(|r| r.is_finite() && *r > 0.0));
            }
            if n >= 100 {
                let rel = (scene.total_points() as f64 - n as f64).abs() / n as f64;
                assert!(
                    rel < 0.2,
                    "{}: {} for {n}",
                    scene.name,
                    scene.total_points()
                );
            }
        }
    }
}

/// Distance of `p` from the surface and whether `n` is the analytic normal there.
fn on_surface(g: &Geometry, p: Vec3, n: Vec3) -> (f32, bool) {
    let rect_check = |r: &Rect| -> (f32, bool) {
        let d = p - r.center;
        let plane = d.dot(r.u.cross(r.v).normalize()).abs();
        let s = d.dot(r.u) / r.u.length_squared();
        let t = d.dot(r.v) / r.v.length_squared();
        let inside = s.abs() <= 1.0 + 1e-5 && t.abs() <= 1.0 + 1e-5;
        let dist = if inside { plane } else { f32::INFINITY };
        (dist, (n - r.normal).length() < 1e-6)
    };
    match g {
        Geometry::Rect(r) => rect_check(r),
        Geometry::Box(b) => b
            .faces()
            .iter()
            .map(rect_check)
            .filter(|&(_, ok)| ok)
            .fold((f32::INFINITY, false), |a, b| if b.0 < a.0 { b } else { a }),
        Geometry::Sphere(s) => {
            let d = p - s.center;
            let dist = (d.length() - s.radius).abs();
            let expect = if s.inward { -d } else { d } / s.radius;
            (dist, (n - expect).length() < 1e-5)
        }
    }
}

#[test]
fn splats_lie_on_their_shapes_with_exact_normals() {
    for scene in all_scenes(&SampleParams::with_points(20_000)) {
        for s in &scene.shapes {
            assert_eq!(s.positions.len(), s.normals.len());
            assert_eq!(s.positions.len(), s.radii.len());
            for (p, n) in s.positions.iter().zip(&s.normals) {
                assert!(
                    (n.length() - 1.0).abs() < 1e-6,
                    "{}: |n| = {}",
                    s.name,
                    n.length()
                );
                let (dist, normal_ok) = on_surface(&s.geometry, *p, *n);
                assert!(dist < 1e-5, "{} {}: {p} is {dist} off", scene.name, s.name);
                assert!(normal_ok, "{} {}: normal {n} at {p}", scene.name, s.name);
            }
            let area = s.geometry.area();
            assert!((s.area - area).abs() < 1e-6 * area.max(1.0));
        }
    }
}

#[test]
fn normals_point_the_right_way() {
    let scene = cornell(&SampleParams::with_points(5_000), true);
    let get = |name: &str| scene.shapes.iter().find(|s| s.name == name).unwrap();
    // Room walls face the inside of the box.
    for s in ["floor", "ceiling", "back", "red-wall", "green-wall"] {
        let sh = get(s);
        for (p, n) in sh.positions.iter().zip(&sh.normals) {
            assert!(n.dot(-*p) > 0.9, "{s}: normal {n} at {p}");
        }
    }
    assert!(get("light").normals.iter().all(|n| n.y < -0.999));
    // Boxes and specular spheres face outward.
    for s in ["short-box", "tall-box", "glass-sphere", "mirror-sphere"] {
        let sh = get(s);
        let c = match sh.geometry {
            Geometry::Box(b) => b.center,
            Geometry::Sphere(sp) => sp.center,
            Geometry::Rect(r) => r.center,
        };
        assert!(sh
            .positions
            .iter()
            .zip(&sh.normals)
            .all(|(p, n)| n.dot(*p - c) > 0.0));
    }
    let furnace = sphere(&SampleParams::with_points(2_000));
    let sh = &furnace.shapes[0];
    assert!(sh
        .positions
        .iter()
        .zip(&sh.normals)
        .all(|(p, n)| n.dot(*p) < 0.0));
}

/// Every test point on every face is inside some disk of that face (same normal).
#[test]
fn disks_cover_every_surface() {
    let mut rng = Pcg64Mcg::seed_from_u64(12345);
    let params = SampleParams::with_points(5_000);
    for scene in [cornell(&params, true), sphere(&params), glass_box(&params)] {
        for s in &scene.shapes {
            let faces: Vec<Rect> = match s.geometry {
                Geometry::Rect(r) => vec![r],
                Geometry::Box(b) => b.faces().to_vec(),
                Geometry::Sphere(sp) => {
                    for _ in 0..3_000 {
                        let q = loop {
                            let v = Vec3::new(
                                rng.random::<f32>() * 2.0 - 1.0,
                                rng.random::<f32>() * 2.0 - 1.0,
                                rng.random::<f32>() * 2.0 - 1.0,
                            );
                            let l = v.length();
                            if l > 1e-3 && l <= 1.0 {
                                break sp.center + v / l * sp.radius;
                            }
                        };
                        let covered = s
                            .positions
                            .iter()
                            .zip(&s.radii)
                            .any(|(p, r)| (q - *p).length() <= *r);
                        assert!(covered, "{} {}: {q} not covered", scene.name, s.name);
                    }
                    continue;
                }
            };
            for f in faces {
                let idx: Vec<usize> = (0..s.len())
                    .filter(|&i| (s.normals[i] - f.normal).length() < 1e-5)
                    .collect();
                assert!(!idx.is_empty());
                let mut worst = 0f32;
                for _ in 0..2_000 {
                    let q = f.point(
                        rng.random::<f32>() * 2.0 - 1.0,
                        rng.random::<f32>() * 2.0 - 1.0,
                    );
                    let best = idx
                        .iter()
                        .map(|&i| (q - s.positions[i]).length() / s.radii[i])
                        .fold(f32::INFINITY, f32::min);
                    worst = worst.max(best);
                }
                // Corners included: with jitter 0.2 the farthest point is ≈ 0.85 cell.
                assert!(worst <= 0.9, "{} {}: worst {worst}", scene.name, s.name);
                for corner in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                    let q = f.point(corner.0, corner.1);
                    assert!(idx
                        .iter()
                        .any(|&i| (q - s.positions[i]).length() <= s.radii[i]));
                }
            }
        }
    }
}

#[test]
fn radius_is_cell_size_times_factor() {
    let mut params = SampleParams::with_points(10_000);
    let a = cornell(&params, false);
    params.radius_factor = 1.5;
    let b = cornell(&params, false);
    assert_eq!(a.spacing, b.spacing);
    for (sa, sb) in a.shapes.iter().zip(&b.shapes) {
        assert_eq!(sa.positions, sb.positions);
        for (ra, rb) in sa.radii.iter().zip(&sb.radii) {
            assert!((rb - 1.5 * ra).abs() < 1e-6);
        }
    }
    // Rectangle radii stay within rounding of the target spacing; cells are near-square.
    for s in &a.shapes {
        if let Geometry::Rect(_) = s.geometry {
            let r = s.radii[0];
            assert!(
                r > 0.8 * a.spacing && r < 1.5 * a.spacing,
                "{}: {r}",
                s.name
            );
        }
    }
    // πr² is a few times the area each splat stands for.
    let ratio = a
        .shapes
        .iter()
        .map(|s| {
            s.radii
                .iter()
                .map(|r| std::f32::consts::PI * r * r)
                .sum::<f32>()
        })
        .sum::<f32>()
        / a.total_area();
    assert!(ratio > 2.5 && ratio < 4.0, "coverage ratio {ratio}");
}

#[test]
fn deterministic_with_seed() {
    let p = SampleParams {
        points: 30_000,
        seed: 7,
        ..Default::default()
    };
    assert_eq!(cornell(&p, true), cornell(&p, true));
    assert_eq!(sphere(&p), sphere(&p));
    let q = SampleParams { seed: 8, ..p };
    let (a, b) = (cornell(&p, true), cornell(&q, true));
    assert_eq!(a.total_points(), b.total_points());
    assert_ne!(a.shapes[0].positions, b.shapes[0].positions);
    // Zero jitter gives the plain grid, whatever the seed.
    let z0 = SampleParams { jitter: 0.0, ..p };
    let z1 = SampleParams { jitter: 0.0, ..q };
    assert_eq!(glass_box(&z0).shapes, glass_box(&z1).shapes);
}

#[test]
fn write_scene_files_and_toml() {
    let dir = tempfile::tempdir().unwrap();
    let scene = cornell(&SampleParams::with_points(3_000), true);
    let toml_path = write_scene(&scene, dir.path()).unwrap();
    assert_eq!(toml_path, dir.path().join("scene.toml"));
    let text = std::fs::read_to_string(&toml_path).unwrap();
    assert!(text.starts_with("# generated by pc-sample: cornell, "));
    let v: toml::Table = text.parse().unwrap();
    let keys: Vec<&str> = v.keys().map(String::as_str).collect();
    assert_eq!(keys.len(), 3, "{keys:?}");
    let mats = v["materials"].as_table().unwrap();
    assert_eq!(mats["white"]["type"].as_str(), Some("diffuse"));
    assert_eq!(mats["light"]["type"].as_str(), Some("emitter"));
    assert_eq!(mats["light"]["radiance"].as_array().unwrap().len(), 3);
    assert_eq!(mats["glass"]["ior"].as_float(), Some(1.5));
    assert_eq!(mats["mirror"]["type"].as_str(), Some("mirror"));
    let models = v["models"].as_array().unwrap();
    assert_eq!(models.len(), scene.shapes.len());
    for (m, s) in models.iter().zip(&scene.shapes) {
        let file = m["file"].as_str().unwrap();
        assert_eq!(file, format!("cornell-{}.ply", s.name));
        assert!(mats.contains_key(m["material"].as_str().unwrap()));
        let bytes = std::fs::read(dir.path().join(file)).unwrap();
        let marker = b"end_header\n";
        let hlen = bytes
            .windows(marker.len())
            .position(|w| w == marker)
            .unwrap()
            + marker.len();
        let header = std::str::from_utf8(&bytes[..hlen]).unwrap();
        assert!(header.contains("format binary_little_endian 1.0\n"));
        assert!(header.contains(&format!("element vertex {}\n", s.len())));
        assert!(header.contains(
            "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float radius\nend_header\n"
        ));
        assert_eq!(bytes.len(), hlen + s.len() * 28);
        let f = |k: usize| {
            f32::from_le_bytes(bytes[hlen + 4 * k..hlen + 4 * k + 4].try_into().unwrap())
        };
        let last = s.len() - 1;
        assert_eq!(f(7 * last + 1), s.positions[last].y);
        assert_eq!(f(7 * last + 6), s.radii[last]);
    }
    let cam = v["camera"].as_table().unwrap();
    assert_eq!(cam["fov_axis"].as_str(), Some("smaller"));
    assert_eq!(cam["width"].as_integer(), Some(512));
    let origin: Vec<f64> = cam["origin"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_float().unwrap())
        .collect();
    assert_eq!(origin, vec![0.0, 0.0, 3.9]);
    // No stray temporary files.
    for e in std::fs::read_dir(dir.path()).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(!name.ends_with(".tmp"), "{name}");
    }
}

/// The written scene loads through the pipeline's own config parser and PLY reader.
#[test]
fn written_scenes_load_through_the_pipeline() {
    for (kind, spec) in [
        (SceneKind::Cornell, true),
        (SceneKind::Sphere, false),
        (SceneKind::GlassBox, false),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let scene = build_scene(kind, &SampleParams::with_points(2_000), spec);
        let toml_path = write_scene(&scene, dir.path()).unwrap();
        let cfg = pc_config::load_config(&toml_path, &[]).unwrap();
        assert_eq!(cfg.config.models.len(), scene.shapes.len());
        assert_eq!(cfg.config.materials.len(), scene.materials.len());
        let loaded = pc_import::load::load_scene(&cfg, &mut |_, _| {}).unwrap();
        assert_eq!(loaded.splats.len(), scene.total_points());
        assert_eq!(loaded.dropped(), 0);
        assert!(loaded
            .models
            .iter()
            .all(|m| !m.estimated_normals && !m.estimated_radii));
        let first = &scene.shapes[0];
        assert_eq!(loaded.splats.positions[..first.len()], first.positions[..]);
        assert_eq!(loaded.splats.radii[..first.len()], first.radii[..]);
    }
}

#[test]
fn scene_kind_names() {
    for k in SceneKind::ALL {
        assert_eq!(k.name().parse::<SceneKind>(), Ok(k));
    }
    assert!("box".parse::<SceneKind>().is_err());
}
