//! pc-vmap's command line: a V-map of a sampled scene, its inspection, the links kept when a
//! light moves, and the error when the octree is missing.

use std::path::Path;

use pcgi_tests::{args, pc_inspect, pc_octree, run, sampled_cornell, temp_dir};

fn scene(dir: &Path) -> std::path::PathBuf {
    sampled_cornell(
        dir,
        3000,
        false,
        "[[lights]]\nposition = [0.0, 0.5, 0.0]\nintensity = [1.0, 1.0, 1.0]\n[vmap]\nleaf_splats = 16\n",
    )
}

#[test]
fn builds_inspects_and_reuses_links() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    let first = run(
        "pc-vmap",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    assert!(
        first.stdout.contains("far and")
            && first.stdout.contains("1 light lists")
            && !first.stdout.contains("reused"),
        "{first:?}"
    );
    let vmap = dir.path().join("out/vmap.pcgi");
    let out = pc_inspect(args![&vmap, "--verify"]).success();
    assert!(
        out.stdout.contains("kind        vmap")
            && out.stdout.contains("ok (checksums, CSR structure"),
        "{out:?}"
    );
    let ply = dir.path().join("links.ply");
    let out = pc_inspect(args![&vmap, "--export-ply", &ply, "--node", "9"]).success();
    assert!(out.stdout.contains("node 9"), "{out:?}");
    assert!(ply.is_file());
    // Moving the light keeps the links.
    let second = run(
        "pc-vmap",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "lights.0.position=[0.2, 0.6, 0.1]"
        ],
    )
    .success();
    assert!(second.stdout.contains("links reused"), "{second:?}");
}

#[test]
fn missing_octree_is_named() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    run("pc-vmap", args!["--quiet", "--config", &cfg])
        .error(&["octree.pcgi", "run pc-octree first"]);
    assert!(!dir.path().join("out/vmap.pcgi").exists());
}
