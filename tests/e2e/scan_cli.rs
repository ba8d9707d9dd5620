//! A real-scan round trip: pc-sample's virtual scanner writes a georeferenced LAZ (and E57)
//! with its scene; the stages light it; pc-bake writes the lit cloud as LAZ and PLY. Read back
//! with the `las` crate: every point at its input coordinate within the input's own scale
//! factor, its color the tone-mapped radiance, the linear radiance in float extra bytes that
//! an Extra Bytes VLR describes; a rerun is up to date.

use std::path::Path;

use pcgi_tests::{args, pc_octree, pc_sample, run, temp_dir};

/// Small stage settings for a test run, after the scanner's scene.toml.
const STAGES: &str = "\n[output]\ndir = \"out\"\n[vmap]\nrays = 8\nnear_rays = 8\nheavy_rays = 0\n[caustics]\nphotons = 2000\n[fmm]\nmax_iterations = 4\n[raytrace]\nspp = 1\n[bake]\nfile = \"lit.laz\"\nexposure = 2.0\n";

fn scan(dir: &Path, format: &str) -> std::path::PathBuf {
    pc_sample(args![
        "scan", "--points", "3000", "--out", dir, "--format", format
    ])
    .success();
    let cfg = dir.join("scene.toml");
    let mut text = std::fs::read_to_string(&cfg).unwrap();
    text.push_str(STAGES);
    std::fs::write(&cfg, text).unwrap();
    cfg
}

fn light(cfg: &Path) {
    pc_octree(args!["--quiet", "--config", cfg]).success();
    for stage in ["pc-vmap", "pc-caustics", "pc-fmm"] {
        run(stage, args!["--quiet", "--config", cfg, "--backend", "cpu"]).success();
    }
}

fn srgb(v: f32) -> f32 {
    pc_raytrace::srgb::srgb_encode(v)
}

#[test]
fn a_scan_comes_back_lit_in_its_own_coordinates() {
    let dir = temp_dir();
    let cfg = scan(dir.path(), "laz");
    light(&cfg);
    let out = run("pc-bake", args!["--quiet", "--config", &cfg]).success();
    assert!(
        out.stdout.contains("3000 lit points")
            && out.stdout.contains("origin (512000, 5403000, 212)"),
        "{out:?}"
    );
    let input: Vec<las::Point> = las::Reader::from_path(dir.path().join("hall.laz"))
        .unwrap()
        .points()
        .map(|p| p.unwrap())
        .collect();
    let lit_path = dir.path().join("out/lit.laz");
    let mut reader = las::Reader::from_path(&lit_path).unwrap();
    let header = reader.header().clone();
    let lit: Vec<las::Point> = reader.points().map(|p| p.unwrap()).collect();
    assert_eq!(lit.len(), input.len());
    // Coordinates: within the input's own scale factor (1 mm) of where the scanner put them.
    let scale = las::Reader::from_path(dir.path().join("hall.laz"))
        .unwrap()
        .header()
        .transforms()
        .x
        .scale;
    for (i, (a, b)) in input.iter().zip(&lit).enumerate() {
        let d = (a.x - b.x)
            .abs()
            .max((a.y - b.y).abs())
            .max((a.z - b.z).abs());
        assert!(d <= scale, "point {i}: {d} m from its input");
    }
    // The extra bytes: three floats, described.
    let eb = header
        .vlrs()
        .iter()
        .find(|v| v.user_id == "LASF_Spec" && v.record_id == 4)
        .expect("an Extra Bytes VLR");
    assert_eq!(eb.data.len(), 3 * 192);
    for (k, name) in ["radiance_r", "radiance_g", "radiance_b"]
        .iter()
        .enumerate()
    {
        let rec = &eb.data[k * 192..(k + 1) * 192];
        assert_eq!(rec[2], 9, "float");
        assert_eq!(&rec[4..4 + name.len()], name.as_bytes());
    }
    // Colors: the radiance after exposure 2 through the sRGB curve, 16-bit.
    let mut lit_points = 0;
    for p in &lit {
        let f: Vec<f32> = p
            .extra_bytes
            .chunks(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(f.len(), 3);
        assert!(f.iter().all(|v| v.is_finite() && *v >= 0.0));
        let c = p.color.unwrap();
        let want = (srgb(f[0] * 2.0) * 65535.0).round() as u16;
        assert_eq!(c.red, want);
        lit_points += usize::from(f[0] > 0.0);
    }
    assert!(
        lit_points > lit.len() / 2,
        "{lit_points} of {} lit",
        lit.len()
    );
    // Up to date on a rerun; the PLY beside it holds the same values in doubles.
    let again = run("pc-bake", args!["--quiet", "--if-stale", "--config", &cfg]).success();
    assert!(again.stdout.contains("up to date"), "{again:?}");
    let ply = dir.path().join("out/lit.ply");
    run(
        "pc-bake",
        args!["--quiet", "--config", &cfg, "--output", &ply],
    )
    .success();
    let bytes = std::fs::read(&ply).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = String::from_utf8_lossy(&bytes[..end]);
    assert!(header.contains("element vertex 3000") && header.contains("property double x"));
    assert!(header.contains("property float radiance_r") && header.contains("comment pcgiKey "));
    let rec = &bytes[end..end + 51];
    let x = f64::from_le_bytes(rec[0..8].try_into().unwrap());
    assert!((x - lit[0].x).abs() < 1e-3, "{x} {}", lit[0].x);
}

#[test]
fn an_e57_scan_is_lit_with_normals_facing_its_stations() {
    let dir = temp_dir();
    let cfg = scan(dir.path(), "e57");
    let out = pc_octree(args!["--config", &cfg]).success();
    assert!(
        out.stdout.contains("hall.e57 (E57): 3000 points")
            && out.stdout.contains("facing 3 scan stations")
            && out.stdout.contains("albedo from color"),
        "{out:?}"
    );
}

#[test]
fn baking_without_a_radiosity_names_the_missing_artifact() {
    let dir = temp_dir();
    let cfg = scan(dir.path(), "las");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let out = run("pc-bake", args!["--quiet", "--config", &cfg]);
    let err = out.error(&["baking the lit cloud", "radiosity.pcgi"]);
    assert!(!dir.path().join("out/lit.laz").exists(), "{err}");
}
