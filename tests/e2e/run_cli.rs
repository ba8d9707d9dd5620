//! pc-run, the pipeline driver (`cargo xtask run`): stages skipped when up to date, exactly the
//! stages a change touches rerun, --force/--from/--until, and a killed stage leaving its
//! previous output for the next run to redo.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use pc_artifact::vmap::VmapMeta;
use pc_artifact::Artifact;
use pcgi_tests::{args, bin, run, sampled_cornell, temp_dir};

/// A sampled Cornell box with a glass and a mirror sphere, a point light, and small settings.
fn scene(d: &Path) -> PathBuf {
    sampled_cornell(
        d,
        6000,
        true,
        "[[lights]]\nposition = [0.3, 0.7, 0.3]\nintensity = [0.5, 0.5, 0.5]\n\
         [vmap]\nleaf_splats = 16\n[fmm]\nemitter_samples = 8\n[caustics]\nphotons = 100000\n\
         [camera]\nwidth = 32\nheight = 32\n[raytrace]\nspp = 1\n",
    )
}

/// `pc-run --config CFG ARGS`: stage → (status, key), in the order they ran.
fn pc_run(cfg: &Path, extra: &[&str]) -> Vec<(String, String, String)> {
    let report = cfg.with_file_name("run.json");
    let mut a = args!["--quiet", "--config", cfg, "--report", &report];
    a.extend(extra.iter().map(Into::into));
    let out = run("pc-run", a).success();
    let last = out.stdout.lines().last().unwrap_or("");
    assert!(last.starts_with("pc-run: "), "{out:?}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    json.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r["stage"].as_str().unwrap().to_string(),
                r["status"].as_str().unwrap().to_string(),
                r["key"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

/// The stages that ran.
fn ran(runs: &[(String, String, String)]) -> Vec<&str> {
    runs.iter()
        .filter(|r| r.1 == "ran")
        .map(|r| r.0.as_str())
        .collect()
}

fn keys(runs: &[(String, String, String)]) -> BTreeMap<String, String> {
    runs.iter().map(|r| (r.0.clone(), r.2.clone())).collect()
}

const ALL: [&str; 5] = [
    "pc-octree",
    "pc-vmap",
    "pc-caustics",
    "pc-fmm",
    "pc-raytrace",
];

#[test]
fn reruns_exactly_the_stages_a_change_touches() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    let out = dir.path().join("out");
    let first = pc_run(&cfg, &[]);
    assert_eq!(ran(&first), ALL, "a cold run runs every stage");
    let again = pc_run(&cfg, &[]);
    assert!(ran(&again).is_empty(), "nothing changed: {again:?}");
    assert_eq!(keys(&again), keys(&first));

    // Each stage's --print-key is the key its output carries.
    for (stage, _, key) in &first {
        let o = run(stage, args!["--config", &cfg, "--print-key"]).success();
        assert_eq!(o.stdout.trim(), key, "{stage}");
    }

    // Only the camera: only the render.
    let camera = ["--set", "camera.fov=30"];
    let r = pc_run(&cfg, &camera);
    assert_eq!(ran(&r), ["pc-raytrace"]);
    assert_ne!(keys(&r)["pc-raytrace"], keys(&first)["pc-raytrace"]);

    // A point light moved: the light lists, photons, radiosity and render, never the links.
    let vmap_meta = || -> VmapMeta {
        Artifact::open(out.join("vmap.pcgi"))
            .unwrap()
            .metadata()
            .unwrap()
    };
    let before = vmap_meta();
    assert!(!before.links_reused);
    let light = [
        "--set",
        "camera.fov=30",
        "--set",
        "lights.0.position=[0.2, 0.7, 0.3]",
    ];
    let r = pc_run(&cfg, &light);
    assert_eq!(ran(&r), ["pc-vmap", "pc-caustics", "pc-fmm", "pc-raytrace"]);
    let after = vmap_meta();
    assert_eq!(after.links_key, before.links_key);
    assert!(after.links_reused, "the V-map links were recomputed");

    // An albedo: the radiosity and the render only (photons store the power that arrives).
    let albedo = [
        "--set",
        "camera.fov=30",
        "--set",
        "lights.0.position=[0.2, 0.7, 0.3]",
        "--set",
        "materials.red.albedo=[0.5, 0.1, 0.1]",
    ];
    let r = pc_run(&cfg, &albedo);
    assert_eq!(ran(&r), ["pc-fmm", "pc-raytrace"]);
    let r = pc_run(&cfg, &albedo);
    assert!(ran(&r).is_empty(), "{r:?}");

    // A glass's index of refraction: the photons too.
    let mut ior = albedo.to_vec();
    ior.extend(["--set", "materials.glass.ior=1.4"]);
    let r = pc_run(&cfg, &ior);
    assert_eq!(ran(&r), ["pc-caustics", "pc-fmm", "pc-raytrace"]);

    // The octree parameters: everything.
    let mut leaf = ior.clone();
    leaf.extend(["--set", "octree.max_leaf_points=12"]);
    assert_eq!(ran(&pc_run(&cfg, &leaf)), ALL);
}

#[test]
fn force_from_and_until_choose_the_stages() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    assert_eq!(
        ran(&pc_run(&cfg, &["--until", "pc-vmap"])),
        ["pc-octree", "pc-vmap"]
    );
    let r = pc_run(&cfg, &[]);
    assert_eq!(ran(&r), ["pc-caustics", "pc-fmm", "pc-raytrace"]);
    let r = pc_run(&cfg, &["--force", "fmm"]);
    assert_eq!(ran(&r), ["pc-fmm"]);
    assert_eq!(r.len(), 5);
    let r = pc_run(
        &cfg,
        &["--from", "pc-fmm", "--until", "pc-fmm", "--force", "pc-fmm"],
    );
    assert_eq!(r.len(), 1);
    assert_eq!(ran(&r), ["pc-fmm"]);
    let r = pc_run(&cfg, &["--from", "raytrace", "--set", "camera.fov=25"]);
    assert_eq!(r.len(), 1);
    assert_eq!(ran(&r), ["pc-raytrace"]);
    assert_eq!(ran(&pc_run(&cfg, &["--force", "all"])), ALL);

    run("pc-run", args!["--config", &cfg, "--force", "pc-render"]).error(&[
        "`pc-render` is not a stage (one of: pc-octree, pc-vmap, pc-caustics, pc-fmm, pc-raytrace, pc-bake)",
    ]);
    // pc-bake runs only when asked for, after the rest.
    let r = pc_run(&cfg, &["--until", "pc-bake"]);
    assert_eq!(r.len(), 6);
    assert_eq!(ran(&r), ["pc-bake"]);
    run(
        "pc-run",
        args!["--config", &cfg, "--from", "fmm", "--until", "vmap"],
    )
    .error(&["--from pc-fmm comes after --until pc-vmap"]);
    run("pc-run", args!["--config", dir.path().join("missing.toml")])
        .error(&["missing.toml: no such config file"]);
    // A stage that fails stops the run and says which: pc-fmm on a truncated photon map
    // (with --from, pc-caustics is not there to redo it).
    let photons = dir.path().join("out").join("photons.pcgi");
    let full = std::fs::read(&photons).unwrap();
    std::fs::write(&photons, &full[..full.len() / 2]).unwrap();
    let image = dir.path().join("out").join("image.exr");
    let before = std::fs::read(&image).unwrap();
    let o = run(
        "pc-run",
        args!["--quiet", "--config", &cfg, "--from", "fmm", "--force", "raytrace"],
    );
    assert_eq!(o.code, Some(2), "{o:?}");
    assert!(
        o.stderr.starts_with("pc-fmm: error: ") && o.stderr.contains("photons.pcgi"),
        "the stage says what is wrong: {o:?}"
    );
    assert!(
        o.stderr.contains(
            "pc-run: error: pc-fmm failed (exit status: 2); the stages before it are done"
        ),
        "{o:?}"
    );
    assert_eq!(
        std::fs::read(&image).unwrap(),
        before,
        "pc-raytrace did not run"
    );
    // Without --from, pc-caustics sees the damage and redoes the photon map.
    let r = pc_run(&cfg, &[]);
    assert_eq!(
        ran(&r),
        ["pc-caustics"],
        "same photons, same key downstream"
    );
}

#[test]
fn a_killed_stage_leaves_its_previous_output_and_the_next_run_redoes_it() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    let first = pc_run(&cfg, &[]);
    let image = dir.path().join("out").join("image.exr");
    let bytes = std::fs::read(&image).unwrap();

    // A render long enough to be killed in the middle.
    let slow = [
        "--set",
        "camera.width=256",
        "--set",
        "camera.height=256",
        "--set",
        "raytrace.spp=64",
    ];
    // On one CPU thread: a GPU (an H100 rendered it in 0.3 s) or many cores finish too soon.
    let mut child = Command::new(bin("pc-raytrace"))
        .args(["--quiet", "--if-stale", "--backend", "cpu", "--config"])
        .arg(&cfg)
        .args(slow)
        .env("RAYON_NUM_THREADS", "1")
        .spawn()
        .unwrap();
    let started = Instant::now();
    while started.elapsed() < Duration::from_millis(700) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the render finished before it could be killed"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(
        std::fs::read(&image).unwrap(),
        bytes,
        "the previous image is intact"
    );
    // Its key is the old one: the killed render is stale, and the next run redoes only it.
    assert!(ran(&pc_run(&cfg, &[])).is_empty());
    let r = pc_run(&cfg, &slow);
    assert_eq!(ran(&r), ["pc-raytrace"]);
    assert_ne!(keys(&r)["pc-raytrace"], keys(&first)["pc-raytrace"]);
    assert_ne!(std::fs::read(&image).unwrap(), bytes);
}

#[test]
fn a_walkthrough_renders_numbered_frames_on_the_cached_solution() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    pc_run(&cfg, &[]);
    let out = dir.path().join("out");
    // A three-frame walkthrough on `backend` into `frames`, with any further arguments.
    let walk = |backend: &str, frames: &Path, extra: Vec<std::ffi::OsString>| {
        let mut a = args![
            "--quiet",
            "--config",
            &cfg,
            "--backend",
            backend,
            "--frames",
            "3",
            "--frames-dir",
            frames
        ];
        a.extend(extra);
        run("pc-raytrace", a)
    };
    let mut backends = vec!["cpu"];
    if pc_gpu::test_context().is_some() {
        backends.push("gpu");
    }
    for backend in backends {
        // The single image on this backend, and a three-frame orbit whose middle frame is the
        // config's camera.
        let single = out.join(format!("single-{backend}.exr"));
        run(
            "pc-raytrace",
            args![
                "--quiet",
                "--config",
                &cfg,
                "--backend",
                backend,
                "-o",
                &single
            ],
        )
        .success();
        let frames = out.join(format!("walk-{backend}"));
        let stats = out.join(format!("walk-{backend}.json"));
        let o = walk(backend, &frames, args!["--stats-json", &stats]).success();
        assert!(
            o.stdout.contains("wrote 3 frames") && o.stdout.contains("frames/s"),
            "{o:?}"
        );
        let names = pcgi_tests::files_under(&frames);
        assert_eq!(
            names,
            ["frame_00000.png", "frame_00001.png", "frame_00002.png"].map(PathBuf::from),
            "{backend}"
        );
        let read = |n: &str| pcgi_tests::png_pixels(&frames.join(n));
        assert_eq!(
            read("frame_00001.png"),
            pcgi_tests::png_pixels(&single.with_extension("png")),
            "{backend}: the middle frame is the config's view"
        );
        assert_ne!(read("frame_00000.png"), read("frame_00001.png"));
        assert_ne!(read("frame_00002.png"), read("frame_00001.png"));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        assert_eq!(json["frames"], 3);
        assert_eq!(json["gpu"], backend == "gpu");
        assert!(json["frames_per_second"].as_f64().unwrap() > 0.0);
    }
    run(
        "pc-raytrace",
        args!["--quiet", "--config", &cfg, "--frames", "0"],
    )
    .error(&["a walkthrough needs at least one frame"]);
    // A frame the writer thread cannot write stops the walkthrough with that frame's path.
    let blocked = out.join("blocked");
    std::fs::write(&blocked, b"a file where the frames' folder should be").unwrap();
    walk("cpu", &blocked, vec![])
        .error(&[&format!("{}: ", blocked.join("frame_00000.png").display())]);
}
