//! pc-octree's command line on valid scenes: the happy path, overrides, stats, and atomic replacement.

use std::path::Path;

use pcgi_tests::{
    args, count_before, files_under, pc_inspect, pc_octree, pc_sample, temp_dir, write_pipeline,
    Grid,
};

/// `pc-sample cornell` into `dir/scene`, and a pipeline.toml in `dir` that includes it.
fn cornell_pipeline(dir: &Path) -> std::path::PathBuf {
    let scene = dir.join("scene");
    let out = pc_sample(args![
        "cornell",
        "--points",
        "5000",
        "--with-specular",
        "--out",
        scene
    ])
    .success();
    assert!(out.stdout.contains("5000 splats"), "{out:?}");
    assert!(scene.join("scene.toml").is_file(), "{out:?}");
    let cfg = dir.join("pipeline.toml");
    std::fs::write(
        &cfg,
        "include = [\"scene/scene.toml\"]\n\n[output]\ndir = \"out\"\n",
    )
    .unwrap();
    cfg
}

/// Leaves in `pc-inspect` output (`nodes  N (I internal, L leaves of which ...)`).
fn inspect_leaves(stdout: &str) -> u64 {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("nodes "))
        .unwrap_or_else(|| panic!("no `nodes` line in pc-inspect output:\n{stdout}"));
    count_before(line, "leaves").unwrap_or_else(|| panic!("no leaf count in {line:?}"))
}

#[test]
fn cornell_builds_verifies_and_k_changes_the_leaves() {
    let dir = temp_dir();
    let cfg = cornell_pipeline(dir.path());
    let artifact = dir.path().join("out").join("octree.pcgi");

    // Without --quiet: stdout is still the one summary line (progress goes to stderr).
    let out = pc_octree(args!["--config", cfg]).success();
    let lines: Vec<&str> = out.stdout.lines().collect();
    assert_eq!(lines.len(), 1, "one summary line expected: {out:?}");
    let summary = lines[0];
    assert!(summary.starts_with("pc-octree: wrote "), "{out:?}");
    assert!(summary.contains("octree.pcgi"), "{out:?}");
    assert_eq!(count_before(summary, "splats"), Some(5000), "{out:?}");
    assert!(!summary.contains("dropped"), "{out:?}");
    let default_leaves = count_before(summary, "leaves").expect("leaf count in the summary");
    assert!(default_leaves > 0);

    assert!(artifact.is_file(), "{}: missing", artifact.display());
    let out_files = files_under(&dir.path().join("out"));
    assert_eq!(
        out_files,
        vec![Path::new("octree.pcgi").to_path_buf()],
        "only the artifact, no .tmp"
    );

    let out = pc_inspect(args![artifact, "--verify"]).success();
    assert!(
        out.stdout.contains(&format!("{}: ok", artifact.display())),
        "{out:?}"
    );
    assert!(out.stdout.contains("kind        octree"), "{out:?}");
    assert!(out.stdout.contains("splats      5000 (k = 16,"), "{out:?}");
    assert_eq!(inspect_leaves(&out.stdout), default_leaves, "{out:?}");
    assert!(
        out.stdout.contains("classes     diffuse") && out.stdout.contains("dielectric"),
        "--with-specular puts glass in the tree: {out:?}"
    );

    // A smaller k splits further: more leaves, in the summary and in the artifact.
    let k4 = dir.path().join("k4.pcgi");
    let out = pc_octree(args![
        "--config",
        cfg,
        "--set",
        "octree.max_leaf_points=4",
        "--output",
        k4,
        "--quiet"
    ])
    .success();
    let k4_leaves = count_before(&out.stdout, "leaves").expect("leaf count in the summary");
    assert!(
        k4_leaves > default_leaves,
        "k = 4 gives {k4_leaves} leaves, k = 16 gives {default_leaves}"
    );
    let out = pc_inspect(args![k4, "--verify"]).success();
    assert!(out.stdout.contains("(k = 4,"), "{out:?}");
    assert_eq!(inspect_leaves(&out.stdout), k4_leaves, "{out:?}");
    assert!(out.stdout.contains(": ok ("), "{out:?}");
    // --output leaves the configured artifact alone.
    assert!(artifact.is_file());
}

#[test]
fn stats_json_matches_the_summary() {
    let dir = temp_dir();
    Grid::new(12).write(&dir.path().join("grid.ply"), Default::default());
    let cfg = write_pipeline(dir.path(), &["grid.ply"], "");
    let stats = dir.path().join("stats.json");
    let out = pc_octree(args!["--config", cfg, "--quiet", "--stats-json", stats]).success();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(json["splats"], 144, "{json}");
    assert_eq!(
        json["leaves"].as_u64(),
        count_before(&out.stdout, "leaves"),
        "{json} vs {out:?}"
    );
    assert!(json["phases"].as_array().is_some_and(|p| !p.is_empty()));
}

#[test]
fn rerun_replaces_the_artifact_atomically_and_a_failed_run_keeps_the_old_one() {
    let dir = temp_dir();
    let (cfg, artifact) = crate::small_artifact(dir.path());
    let first = std::fs::read(&artifact).unwrap();

    // A successful rerun with other parameters replaces the file (by rename: a new inode, so
    // a reader that mapped the old one keeps seeing it whole).
    #[cfg(unix)]
    let old_inode = {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(&artifact).unwrap().ino()
    };
    pc_octree(args![
        "--config",
        cfg,
        "--quiet",
        "--set",
        "octree.max_leaf_points=2"
    ])
    .success();
    let second = std::fs::read(&artifact).unwrap();
    assert_ne!(first, second, "k = 2 must give another artifact");
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let new_inode = std::fs::metadata(&artifact).unwrap().ino();
        assert_ne!(old_inode, new_inode, "the artifact was rewritten in place");
    }
    assert_eq!(
        files_under(&dir.path().join("out")),
        vec![Path::new("octree.pcgi").to_path_buf()]
    );

    // A failing rerun (the PLY now has a NaN) leaves the previous artifact as it was.
    let mut grid = Grid::new(16);
    grid.positions[3].y = f32::NAN;
    grid.write(&dir.path().join("grid.ply"), Default::default());
    pc_octree(args!["--config", cfg, "--quiet"]).error(&["grid.ply", "vertex 3", "NaN"]);
    assert_eq!(
        std::fs::read(&artifact).unwrap(),
        second,
        "old artifact changed"
    );
    assert_eq!(
        files_under(&dir.path().join("out")),
        vec![Path::new("octree.pcgi").to_path_buf()],
        "no .tmp left"
    );
    let out = pc_inspect(args![artifact, "--verify"]).success();
    assert!(out.stdout.contains(": ok ("), "{out:?}");
}

#[cfg(unix)]
#[test]
fn a_failure_while_writing_keeps_the_old_artifact() {
    let dir = temp_dir();
    let (cfg, artifact) = crate::small_artifact(dir.path());
    let first = std::fs::read(&artifact).unwrap();
    // The disk fills up during the write (files may grow to 4 KiB): the failure comes after the
    // build, at the write, the latest point where an in-place writer would already have done
    // damage.
    let err = pcgi_tests::run_limited(
        &pcgi_tests::bin("pc-octree"),
        args![
            "--config",
            cfg,
            "--quiet",
            "--set",
            "octree.max_leaf_points=2"
        ],
        pcgi_tests::Limit::FileSize(4096),
    )
    .error(&["octree.pcgi.", ".tmp"]);
    assert!(
        err.contains("File too large"),
        "the OS reason is shown: {err}"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path().join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, ["octree.pcgi"], "the temporary file is removed");
    assert_eq!(
        std::fs::read(&artifact).unwrap(),
        first,
        "old artifact changed"
    );
    pc_inspect(args![artifact, "--verify"]).success();
}
