//! What a hostile run found (issue 23), one test per case, each reproducing the case first: the
//! number in a test's name is the case's. Inputs are made here; every expectation is the
//! behaviour a careful user should get: a clear error that names the file and the problem, or
//! the run succeeding without losing anything published.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use glam::Vec3;
use pc_import::ply_write::{write_ply, PlyFormat, PlyPoints};
use pcgi_tests::{
    args, bin, files_under, pc_inspect, pc_octree, run, temp_dir, write_pipeline, Grid,
};

use crate::small_artifact;

/// A grid model with one point moved to `p` and its radius set to `r`, in `dir/odd.ply`, and a
/// pipeline.toml for it.
fn odd_point(dir: &Path, p: Vec3, r: f32, extra: &str) -> PathBuf {
    let mut g = Grid::new(8);
    g.positions[5] = p;
    g.radii[5] = r;
    g.write(&dir.join("odd.ply"), PlyFormat::BinaryLittleEndian);
    write_pipeline(dir, &["odd.ply"], extra)
}

#[test]
fn case_01_coordinates_near_f32_max_are_refused_naming_the_model() {
    let dir = temp_dir();
    let cfg = odd_point(dir.path(), Vec3::new(3e38, 0.0, 0.0), 0.1, "");
    pc_octree(args!["--quiet", "--config", &cfg]).error(&[
        "odd.ply",
        "vertex 5",
        "x 3e38 lies beyond ±1e7",
    ]);
    pcgi_tests::assert_nothing_written(dir.path());
    // Dropping such points is the user's choice, and then it is counted.
    let cfg = odd_point(
        dir.path(),
        Vec3::new(0.0, -3e38, 0.0),
        0.1,
        "[import]\ndrop_invalid = true\n",
    );
    let out = pc_octree(args!["--quiet", "--config", &cfg]).success();
    assert!(out.stdout.contains("left out 1 point)"), "{out:?}");
    pc_inspect(args![dir.path().join("out/octree.pcgi"), "--verify"]).success();
}

#[test]
fn case_02_many_coincident_points_build_and_share_their_area() {
    // 20,000 copies of one point of a 16 × 16 grid: the splat-area pass was quadratic in the
    // copies (48 s for 40,000 in release). The copies now share one disk's share.
    let dir = temp_dir();
    let mut g = Grid::new(16);
    let (p, n, r) = (g.positions[100], g.normals[100], g.radii[100]);
    g.positions.extend(std::iter::repeat_n(p, 20_000));
    g.normals.extend(std::iter::repeat_n(n, 20_000));
    g.radii.extend(std::iter::repeat_n(r, 20_000));
    g.write(&dir.path().join("dups.ply"), PlyFormat::BinaryLittleEndian);
    let cfg = write_pipeline(dir.path(), &["dups.ply"], "");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let with = pc_inspect(args![dir.path().join("out/octree.pcgi"), "--verify"]).success();
    Grid::new(16).write(&dir.path().join("plain.ply"), PlyFormat::BinaryLittleEndian);
    let cfg = write_pipeline(dir.path(), &["plain.ply"], "");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let without = pc_inspect(args![dir.path().join("out/octree.pcgi")]).success();
    let area = |o: &pcgi_tests::Output| -> f64 {
        let line = o.stdout.lines().find(|l| l.starts_with("area")).unwrap();
        line.split_whitespace().nth(1).unwrap().parse().unwrap()
    };
    let (a, b) = (area(&with), area(&without));
    assert!(
        (a - b).abs() < 1e-3 * b,
        "area {a} with the copies, {b} without"
    );
}

#[test]
fn case_02_without_normals_and_radii_copies_are_estimated_once() {
    // x-y-z only: normals and radii are estimated, and the kd-tree could not split the copies
    // (3.7 s for 40,000 before "all points coincide"). Copies now share their position's
    // estimate, and a model that is one point repeated is refused before any estimation.
    let dir = temp_dir();
    let g = Grid::new(32);
    let mut positions = g.positions.clone();
    positions.extend(std::iter::repeat_n(g.positions[300], 20_000));
    let write = |name: &str, positions: &[Vec3]| {
        write_ply(
            &dir.path().join(name),
            &PlyPoints::new(positions),
            PlyFormat::BinaryLittleEndian,
            &[],
        )
        .unwrap();
    };
    write("xyz.ply", &positions);
    let cfg = write_pipeline(dir.path(), &["xyz.ply"], "");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    pc_inspect(args![dir.path().join("out/octree.pcgi"), "--verify"]).success();
    write("one.ply", &vec![g.positions[300]; 40_000]);
    let cfg = write_pipeline(dir.path(), &["one.ply"], "");
    pc_octree(args!["--quiet", "--config", &cfg]).error(&["one.ply", "all 40000 points coincide"]);
}

#[test]
fn case_03_a_camera_too_large_for_memory_is_refused_before_rendering() {
    let dir = temp_dir();
    let (cfg, _) = small_artifact(dir.path());
    for (w, h, key) in [
        ("100000", "100000", "camera.width must be at most 16384"),
        ("4294967295", "1", "camera.width must be at most 16384"),
        (
            "8192",
            "16384",
            "camera.width × camera.height must be at most 67108864",
        ),
    ] {
        run(
            "pc-raytrace",
            args![
                "--quiet",
                "--config",
                &cfg,
                "--set",
                format!("camera.width={w}"),
                "--set",
                format!("camera.height={h}")
            ],
        )
        .error(&["pipeline.toml", key]);
    }
}

#[test]
fn case_04_and_05_vmap_and_fmm_counts_outside_their_ranges_are_refused() {
    let dir = temp_dir();
    let (cfg, _) = small_artifact(dir.path());
    for (stage, set, msg) in [
        (
            "pc-vmap",
            "vmap.near_rays=0",
            "vmap.near_rays must be at least 1",
        ),
        (
            "pc-vmap",
            "vmap.refine_form_factor=-1",
            "vmap.refine_form_factor must be finite and lie in [0, 1], got -1",
        ),
        (
            "pc-fmm",
            "fmm.emitter_samples=4000000000",
            "fmm.emitter_samples must be at most 4096",
        ),
        (
            "pc-fmm",
            "fmm.max_iterations=0",
            "fmm.max_iterations must be at least 1",
        ),
        (
            "pc-caustics",
            "caustics.photons=4000000000",
            "caustics.photons must be at most 100000000",
        ),
    ] {
        run(stage, args!["--quiet", "--config", &cfg, "--set", set]).error(&[msg]);
    }
}

#[cfg(unix)]
#[test]
fn case_06_a_model_that_never_ends_is_refused_before_it_is_read() {
    let dir = temp_dir();
    let fifo = dir.path().join("fifo.ply");
    let made = Command::new("mkfifo").arg(&fifo).status();
    assert!(made.is_ok_and(|s| s.success()), "mkfifo");
    for model in ["/dev/zero", fifo.to_str().unwrap()] {
        let cfg = write_pipeline(dir.path(), &[model], "");
        pc_octree(args!["--quiet", "--config", &cfg]).error(&[model, "not a regular file"]);
    }
}

#[test]
fn case_07_a_png_left_from_another_render_is_redone() {
    let dir = temp_dir();
    let (cfg, _) = small_artifact(dir.path());
    let render = |exposure: &str| {
        run(
            "pc-raytrace",
            args![
                "--quiet",
                "--if-stale",
                "--backend",
                "cpu",
                "--config",
                &cfg,
                "--set",
                "camera.width=24",
                "--set",
                "camera.height=16",
                "--set",
                "raytrace.spp=1",
                "--set",
                format!("raytrace.exposure={exposure}")
            ],
        )
        .success()
    };
    let png = dir.path().join("out/image.png");
    render("1.0");
    let first = std::fs::read(&png).unwrap();
    assert!(render("1.0").stdout.contains("up to date"));
    // Another render's PNG lands, then the run is killed before its EXR: the pair disagrees.
    render("2.0");
    std::fs::write(&png, &first).unwrap();
    let out = render("2.0");
    assert!(
        out.stdout.contains("pc-raytrace: wrote"),
        "the pair is redone: {out:?}"
    );
    let key = pc_raytrace::image::rendered_key(&dir.path().join("out/image.exr"));
    assert!(key.is_some(), "EXR and PNG carry the same key again");
}

#[test]
fn case_08_temporary_files_of_killed_runs_go_even_when_up_to_date() {
    let dir = temp_dir();
    let (cfg, artifact) = small_artifact(dir.path());
    let out_dir = artifact.parent().unwrap();
    // The old fixed name, and one of a process that is gone (pid 0 is never a user process).
    std::fs::write(out_dir.join("octree.pcgi.tmp"), vec![7u8; 1 << 20]).unwrap();
    std::fs::write(
        out_dir.join("octree.pcgi.0.0123456789abcdef.tmp"),
        vec![7u8; 1 << 20],
    )
    .unwrap();
    let out = pc_octree(args!["--quiet", "--if-stale", "--config", &cfg]).success();
    assert!(out.stdout.contains("up to date"), "{out:?}");
    assert_eq!(files_under(out_dir), [PathBuf::from("octree.pcgi")]);
}

/// The render publishes two files: what a killed render left of the PNG goes too (found by
/// the kill test on a fresh clone: only the EXR's temporaries were looked for).
#[test]
fn case_08_a_killed_renders_png_temporaries_go_too() {
    let dir = temp_dir();
    let cfg = pcgi_tests::sampled_cornell(
        dir.path(),
        1500,
        false,
        "[raytrace]\nspp = 1\nmode = \"direct\"\n",
    );
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let render = || {
        pcgi_tests::run(
            "pc-raytrace",
            args![
                "--quiet",
                "--if-stale",
                "--config",
                &cfg,
                "--backend",
                "cpu"
            ],
        )
        .success()
    };
    render();
    let out_dir = dir.path().join("out");
    for name in [
        "image.png.0.0123456789abcdef.tmp",
        "image.exr.0.fedcba9876543210.tmp",
    ] {
        std::fs::write(out_dir.join(name), vec![7u8; 1 << 16]).unwrap();
    }
    assert!(render().stdout.contains("up to date"));
    let tmps: Vec<_> = files_under(&out_dir)
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(tmps.is_empty(), "{tmps:?}");
}

#[test]
fn case_09_concurrent_runs_on_one_folder_both_succeed_and_publish_a_whole_artifact() {
    let dir = temp_dir();
    let (cfg, artifact) = small_artifact(dir.path());
    for round in 0..3 {
        let spawn = || {
            Command::new(bin("pc-octree"))
                .args(args![
                    "--quiet",
                    "--config",
                    &cfg,
                    "--set",
                    format!("octree.max_leaf_points={}", 4 + round)
                ])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        };
        let (a, b) = (spawn(), spawn());
        for child in [a, b] {
            let out = child.wait_with_output().unwrap();
            assert!(
                out.status.success(),
                "round {round}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            assert!(String::from_utf8_lossy(&out.stdout).contains("pc-octree: wrote"));
        }
        pc_inspect(args![&artifact, "--verify"]).success();
        assert_eq!(
            files_under(artifact.parent().unwrap()),
            [PathBuf::from("octree.pcgi")]
        );
    }
}

#[cfg(unix)]
#[test]
fn case_10_a_closed_or_full_stdout_does_not_fail_a_run_that_published() {
    let dir = temp_dir();
    let (cfg, artifact) = small_artifact(dir.path());
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let status = Command::new(bin("pc-octree"))
        .args(args![
            "--quiet",
            "--config",
            &cfg,
            "--set",
            "octree.max_leaf_points=3"
        ])
        .stdout(full)
        .status()
        .unwrap();
    assert_eq!(status.code(), Some(0), "stdout is /dev/full");
    // A closed pipe (`pc-octree ... | true`).
    let mut child = Command::new(bin("pc-octree"))
        .args(args![
            "--quiet",
            "--config",
            &cfg,
            "--set",
            "octree.max_leaf_points=5"
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let verify = pc_inspect(args![&artifact]).success();
    assert!(
        verify.stdout.contains("(k = 5,"),
        "the last run's artifact: {verify:?}"
    );
}

#[test]
fn case_11_a_named_input_that_does_not_exist_is_an_error() {
    let dir = temp_dir();
    let (cfg, _) = small_artifact(dir.path());
    let missing = dir.path().join("nowhere/radiosity.pcgi");
    run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--radiosity",
            &missing
        ],
    )
    .error(&["nowhere/radiosity.pcgi", "not found: run pc-fmm first"]);
    let missing = dir.path().join("nowhere/photons.pcgi");
    run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--photons",
            &missing
        ],
    )
    .error(&["nowhere/photons.pcgi", "not found: run pc-caustics first"]);
    run(
        "pc-vmap",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    run(
        "pc-fmm",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--photons",
            &missing
        ],
    )
    .error(&["nowhere/photons.pcgi", "not found: run pc-caustics first"]);
    assert!(!dir.path().join("out/image.exr").exists());
    assert!(!dir.path().join("out/radiosity.pcgi").exists());
}

#[test]
fn case_12_an_absurd_radius_is_refused_at_import() {
    let dir = temp_dir();
    let cfg = odd_point(dir.path(), Vec3::new(0.1, 0.0, 0.1), 1e30, "");
    pc_octree(args!["--quiet", "--config", &cfg]).error(&[
        "odd.ply",
        "vertex 5",
        "the radius 1e30 lies beyond ±1e7",
    ]);
}

#[test]
fn case_13_messages_name_the_path_and_the_problem() {
    let dir = temp_dir();
    let (cfg, _) = small_artifact(dir.path());
    // output.dir is a file.
    std::fs::write(dir.path().join("afile"), b"x").unwrap();
    pc_octree(args![
        "--quiet",
        "--config",
        &cfg,
        "--set",
        "output.dir=\"afile\""
    ])
    .error(&["output.dir", "afile is a file, not a folder"]);
    // An artifact name that names no file, and an image that is a folder.
    pc_octree(args![
        "--quiet",
        "--config",
        &cfg,
        "--set",
        "octree.file=\"\""
    ])
    .error(&["octree.file must name a file inside output.dir"]);
    run(
        "pc-raytrace",
        args!["--quiet", "--config", &cfg, "--set", "raytrace.image=\".\""],
    )
    .error(&["raytrace.image must name a file inside output.dir"]);
    std::fs::create_dir_all(dir.path().join("out/img.exr")).unwrap();
    run(
        "pc-raytrace",
        args![
            "--quiet",
            "--config",
            &cfg,
            "--set",
            "raytrace.image=\"img.exr\""
        ],
    )
    .error(&["raytrace.image", "img.exr is a folder, not a file"]);
    // The OS error is printed once.
    std::fs::write(
        dir.path().join("out/sub"),
        b"a file where a folder is wanted",
    )
    .unwrap();
    let err = run(
        "pc-raytrace",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "raytrace.image=\"sub/image.exr\"",
            "--set",
            "camera.width=8",
            "--set",
            "camera.height=8"
        ],
    )
    .error(&["out/sub is a file, not a folder"]);
    assert!(err.matches("(os error").count() <= 1, "{err}");
    // A Latin-1 byte in a PLY comment is not a reason to refuse the model.
    let ply = dir.path().join("latin1.ply");
    let mut bytes = b"ply\nformat ascii 1.0\ncomment scanned by Fran\xe7ois at 20\xb0C\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float radius\nend_header\n".to_vec();
    bytes.extend_from_slice(b"0 0 0 0 1 0 0.1\n0.1 0 0 0 1 0 0.1\n0 0 0.1 0 1 0 0.1\n");
    std::fs::File::create(&ply)
        .unwrap()
        .write_all(&bytes)
        .unwrap();
    let cfg = write_pipeline(dir.path(), &["latin1.ply"], "");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    // Outside a comment, the line is named.
    let bad: Vec<u8> = String::from_utf8_lossy(&bytes)
        .replace("property float radius", "property float r\u{0}dius")
        .bytes()
        .map(|b| if b == 0 { 0xe4 } else { b })
        .collect();
    std::fs::write(&ply, bad).unwrap();
    pc_octree(args!["--quiet", "--config", &cfg])
        .error(&["latin1.ply", "header line 11 is not UTF-8 text"]);
    // Each tool describes itself.
    let help = run("pc-compare", args!["--help"]).success();
    assert!(help.stdout.starts_with("Relative RMSE"), "{}", help.stdout);
    assert!(!help.stdout.contains("Stage 5"), "{}", help.stdout);
}

/// A stage whose memory runs out (here a 20 MB address space; on a real scan, a 100M-point
/// octree under `ulimit -v` ended in a bare `memory allocation of 1600000000 bytes failed` and
/// SIGABRT) says so with its name and exits with code 2, and the output published before is
/// intact; the next run with memory succeeds and leaves no temporary file.
#[cfg(target_os = "linux")]
#[test]
fn a_stage_out_of_memory_says_so_and_keeps_what_was_published() {
    let dir = temp_dir();
    // 100k points: the build itself needs more than the limit (3,000 fit in it).
    let cfg = pcgi_tests::sampled_cornell(dir.path(), 100_000, false, "");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let out = dir.path().join("out").join("octree.pcgi");
    let before = std::fs::read(&out).unwrap();
    // Sixteen worker threads, as on a 16-core host: their stacks do not fit in the cap, and
    // the stage runs on fewer instead of panicking in rayon.
    let o = pcgi_tests::run_limited_env(
        &bin("pc-octree"),
        args![
            "--quiet",
            "--config",
            &cfg,
            "--set",
            "octree.area_samples=40"
        ],
        pcgi_tests::Limit::AddressSpace(20 << 20),
        &[("RAYON_NUM_THREADS", "16")],
    );
    assert_eq!(o.code, Some(2), "{o:?}");
    assert!(
        o.stderr
            .starts_with("pc-octree: error: out of memory: the system refused ")
            && o.stderr.contains("nothing was published"),
        "{o:?}"
    );
    assert_eq!(o.stderr.lines().count(), 1, "one message: {o:?}");
    assert_eq!(
        std::fs::read(&out).unwrap(),
        before,
        "the published octree changed"
    );
    pc_octree(args![
        "--quiet",
        "--config",
        &cfg,
        "--set",
        "octree.area_samples=40"
    ])
    .success();
    let stray: Vec<_> = files_under(dir.path())
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(stray.is_empty(), "temporary files left: {stray:?}");
}
