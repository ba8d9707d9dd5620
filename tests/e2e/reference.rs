//! The reference Cornell box (~100k splats in shared/reference/cornell/points-100k): pc-octree builds it with splat areas that add up to the surface area, and the whole chain renders it within 3 % of Mitsuba in every region.

use std::path::PathBuf;

use pc_artifact::octree::sections;
use pc_artifact::Artifact;
use pcgi_tests::{args, pc_inspect, pc_octree, run, temp_dir, toml_string};

/// Where the reference data is expected, relative to this package.
fn reference_dir() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/reference/cornell"
    ))
}

#[test]
fn reference_cornell_octree_areas_match_the_surface() {
    let dir = reference_dir();
    let points = dir.join("points-100k");
    let json_path = points.join("cornell.materials.json");
    assert!(
        json_path.is_file(),
        "the reference data is missing: expected {} (the reference Cornell box, \
         shared/reference/cornell next to the workspace)",
        json_path.display()
    );
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&json_path)
            .unwrap_or_else(|e| panic!("{}: {e}", json_path.display())),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", json_path.display()));
    let total_area = json["total_area"]
        .as_f64()
        .unwrap_or_else(|| panic!("{}: no `total_area`", json_path.display()));
    let files: Vec<&String> = json["files"]
        .as_object()
        .unwrap_or_else(|| panic!("{}: no `files`", json_path.display()))
        .keys()
        .collect();
    assert_eq!(files.len(), 8, "{}: {files:?}", json_path.display());

    // The octree only cares about the material classes: one diffuse material for all.
    let tmp = temp_dir();
    let mut text = String::from(
        "[output]\ndir = \"out\"\n\n[materials.white]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n",
    );
    for f in &files {
        let ply = points.join(f);
        assert!(ply.is_file(), "{}: missing", ply.display());
        text.push_str(&format!(
            "[[models]]\nfile = {}\nmaterial = \"white\"\n\n",
            toml_string(&ply.display().to_string())
        ));
    }
    let cfg = tmp.path().join("cornell.toml");
    std::fs::write(&cfg, text).unwrap();

    let out = pc_octree(args!["--config", cfg, "--quiet"]).success();
    let artifact = tmp.path().join("out").join("octree.pcgi");
    let out_v = pc_inspect(args![artifact, "--verify"]).success();
    assert!(out_v.stdout.contains(": ok ("), "{out_v:?}");

    let a = Artifact::open(&artifact).unwrap();
    let areas: &[f32] = a.section(sections::SPLAT_AREA).unwrap();
    assert!(
        (90_000..=110_000).contains(&areas.len()),
        "about 100k splats expected, got {}: {out:?}",
        areas.len()
    );
    assert!(areas.iter().all(|x| x.is_finite() && *x >= 0.0));
    let sum: f64 = areas.iter().map(|&x| x as f64).sum();
    let rel = (sum - total_area).abs() / total_area;
    assert!(
        rel < 0.06,
        "splat areas sum to {sum}, the reference surface is {total_area} ({:.1} % off)",
        rel * 100.0
    );
}

/// The whole chain on the reference Cornell box's points (pc-octree, pc-vmap, pc-fmm,
/// pc-raytrace with the stage defaults), compared with Mitsuba's render over the regions of
/// Render the scene of the reference folder `dir` with pcgi's defaults (`pc-compare
/// --write-config`'s config) in `out`; the image's path.
fn render_reference(dir: &std::path::Path, out: &std::path::Path) -> PathBuf {
    let cfg = out.join("reference.toml");
    let text = pc_raytrace::reference::config_toml(dir).unwrap();
    std::fs::write(&cfg, text).unwrap();
    run("pc-run", args!["--config", cfg, "--quiet"]).success();
    out.join("image.exr")
}

/// cornell.stats.json: every region's mean within 3 % (issue 5's target; the light bounces
/// without limit there, so the radiosity solve must converge to match).
#[test]
fn reference_cornell_render_matches_mitsuba_within_3_percent() {
    let dir = reference_dir();
    let tmp = temp_dir();
    let image = render_reference(&dir, tmp.path());
    // The validation command (`cargo xtask compare IMAGE REFERENCE --regions FILE` runs it).
    let diff = tmp.path().join("diff.png");
    let out = run(
        "pc-compare",
        args![
            &image,
            dir.join("cornell.exr"),
            "--regions",
            dir.join("cornell.stats.json"),
            "--diff",
            &diff,
            "--max-region-error",
            "0.03"
        ],
    )
    .success();
    println!("{}", out.stdout);
    assert!(out.stdout.contains("relative RMSE"), "{out:?}");
    assert!(out.stdout.contains("pc-compare: 10 regions"), "{out:?}");
    let png = std::fs::read(&diff).unwrap();
    assert_eq!(&png[1..4], b"PNG", "{}", diff.display());
    let size = |at: usize| u32::from_be_bytes(png[at..at + 4].try_into().unwrap());
    assert_eq!(
        (size(16), size(20)),
        (256, 256),
        "the IHDR of the difference image"
    );
    let ours = pc_raytrace::image::read_exr(&image).unwrap();
    let (report, _) = pc_raytrace::reference::compare(&ours, &dir).unwrap();
    println!("{}", report.table());
    println!("relative RMSE {:.2} %", 100.0 * report.rel_rmse);
    assert_eq!(report.regions.len(), 10, "{}", report.table());
    // 0.0445 since the blend keeps perpendicular walls apart at a corner (0.0627 before each
    // border row was clipped along one line; docs/octree.md "Borders", docs/raytrace.md).
    assert!(
        report.per_pixel < 0.05,
        "per-pixel relative error {:.4}:\n{}",
        report.per_pixel,
        report.table()
    );
    for r in &report.regions {
        assert!(
            r.error() < 0.03,
            "region `{}` is {:.2} % off Mitsuba's reference:\n{}",
            r.name,
            100.0 * r.error(),
            report.table()
        );
    }
}

/// cornell-mirror-glass: a mirror box and a glass sphere, light through both onto diffuse
/// surfaces (the specular links and the caustic photons). Issue 21: every region within 3 %.
/// With the default seeds the worst is 2.62 % (floor-front-of-mirror, since each border row is
/// clipped along one line: 1.53 % before, docs/octree.md "Borders"). Over `caustics.seed` 0-3 the
/// worst regions are 2.55-2.71 % (the same), the ceiling (whose light is 44 % specular links)
/// 0.2-2.3 % (0.7-2.4 % before; an earlier solve reached 3.20 % on one seed). The seed's split lost
/// 40 % of the ceiling and 39 % of the mirror's view of the red wall. The per-pixel relative
/// error is 0.0492-0.0504 over `caustics.seed` 0-2 since the links' smoothing leaves out what a
/// surface in front hides; 0.069-0.074 before, half of it the ceiling seen through the gap above
/// the light (docs/caustics.md, "Shadows in the smoothing").
#[test]
fn reference_mirror_glass_render_is_within_3_percent() {
    let dir = reference_dir()
        .parent()
        .unwrap()
        .join("cornell-mirror-glass");
    assert!(dir.is_dir(), "no reference at {}", dir.display());
    let tmp = temp_dir();
    let ours = pc_raytrace::image::read_exr(&render_reference(&dir, tmp.path())).unwrap();
    let (report, _) = pc_raytrace::reference::compare(&ours, &dir).unwrap();
    println!("{}", report.table());
    assert_eq!(report.regions.len(), 15, "{}", report.table());
    assert!(
        report.per_pixel < 0.056,
        "per-pixel relative error {:.4}:\n{}",
        report.per_pixel,
        report.table()
    );
    for r in &report.regions {
        assert!(
            r.error() < 0.03,
            "region `{}` is {:.2} % off Mitsuba's reference:\n{}",
            r.name,
            100.0 * r.error(),
            report.table()
        );
    }
}
