//! pc-raytrace's command line: rendering a sampled scene, and the errors when its inputs are
//! missing or no longer match the octree.

use std::path::Path;

use pcgi_tests::{args, files_under, pc_octree, run, sampled_cornell, temp_dir};

fn scene(dir: &Path) -> std::path::PathBuf {
    sampled_cornell(
        dir,
        4000,
        true,
        "[camera]\nwidth = 40\nheight = 32\n[raytrace]\nspp = 4\nmode = \"direct\"\n",
    )
}

#[test]
fn renders_exr_and_png_on_the_cpu() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let stats = dir.path().join("stats.json");
    let out = run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "raytrace.aovs=true",
            "--stats-json",
            &stats
        ],
    )
    .success();
    assert!(out.stdout.contains("40x32, 4 spp"), "{out:?}");
    // The stats count every camera sample: each pixel's spp, and the refined pixels' second pass
    // (`cargo xtask bench --only render` divides them by the render's time).
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let refined = json["refined"].as_u64().unwrap();
    let samples = 40 * 32 * 4 + refined * json["refine_spp"].as_u64().unwrap();
    assert_eq!(json["camera_samples"].as_u64(), Some(samples), "{json}");
    assert_eq!(json["rays"]["camera"].as_u64(), Some(samples), "{json}");
    assert!(
        json["render_seconds"].as_f64().is_some_and(|s| s > 0.0),
        "{json}"
    );
    assert!(out.stdout.lines().count() == 1, "{out:?}");
    let exr = dir.path().join("out/image.exr");
    let png = dir.path().join("out/image.png");
    assert!(exr.is_file() && png.is_file());
    let img = pc_raytrace::image::read_exr(&exr).unwrap();
    assert_eq!((img.width, img.height), (40, 32));
    assert!(img.aovs.is_some());
    let mean = img.mean();
    assert!(mean.iter().all(|m| *m > 0.0 && m.is_finite()), "{mean:?}");
    assert!(files_under(dir.path())
        .iter()
        .all(|p| p.extension().is_none_or(|e| e != "tmp")));
}

#[test]
fn missing_octree_is_named() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    let err = run(
        "pc-raytrace",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .error(&["octree.pcgi", "run pc-octree first"]);
    assert!(!dir.path().join("out/image.exr").exists(), "{err}");
}

#[test]
fn material_changes_that_need_a_new_octree_are_refused() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    // A color change is fine without rebuilding the octree.
    run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "materials.white.albedo=[0.2, 0.2, 0.2]"
        ],
    )
    .success();
    // A class change is not.
    run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "materials.white.type=emitter",
            "--set",
            "materials.white.radiance=[1, 1, 1]"
        ],
    )
    .error(&["`white` changed class", "rerun pc-octree"]);
    // Nor is a renamed material set.
    run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "materials.chalk.type=diffuse",
            "--set",
            "materials.chalk.albedo=[0.5, 0.5, 0.5]"
        ],
    )
    .error(&["chalk", "rerun pc-octree"]);
}

#[test]
fn gpu_backend_renders_the_same_scene() {
    if pc_gpu::GpuContext::new().is_err() {
        assert!(
            !pc_gpu::gpu_required(),
            "PC_REQUIRE_GPU=1 but no GPU adapter"
        );
        return;
    }
    let dir = temp_dir();
    let cfg = scene(dir.path());
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let cpu = run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "-o",
            dir.path().join("cpu.exr")
        ],
    )
    .success();
    let gpu = run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "gpu",
            "--config",
            &cfg,
            "-o",
            dir.path().join("gpu.exr")
        ],
    )
    .success();
    // The GPU's share ends the summary, which stays one line (docs/gpu.md).
    assert!(!cpu.stdout.contains("[GPU:"), "{cpu:?}");
    assert_eq!(gpu.stdout.lines().count(), 1, "{gpu:?}");
    assert!(
        gpu.stdout.contains("[GPU: 1 kernels built in ") && gpu.stdout.contains(" dispatches "),
        "{gpu:?}"
    );
    let a = pc_raytrace::image::read_exr(&dir.path().join("cpu.exr")).unwrap();
    let b = pc_raytrace::image::read_exr(&dir.path().join("gpu.exr")).unwrap();
    let c = pc_raytrace::image::compare(&b, &a).unwrap();
    assert!(c.mean_relative < 2e-3, "{c}");
}
