//! pc-fmm's command line: the whole chain on a sampled Cornell box, the radiosity shown by
//! pc-raytrace in `auto` mode, and the errors for a missing or stale V-map.

use pcgi_tests::{args, pc_octree, run, sampled_cornell, temp_dir};

#[test]
fn solves_renders_and_rejects_stale_inputs() {
    let dir = temp_dir();
    let d = dir.path();
    let cfg = sampled_cornell(
        d,
        4000,
        false,
        "[vmap]\nleaf_splats = 16\n[fmm]\nemitter_samples = 16\n[camera]\nwidth = 32\nheight = 32\n[raytrace]\nspp = 1\n",
    );
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    // No V-map yet: a clear error naming the file.
    let out = run(
        "pc-fmm",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    );
    assert_eq!(out.code, Some(2), "{out:?}");
    assert!(
        out.stderr.contains("vmap.pcgi") && out.stderr.contains("run pc-vmap"),
        "{out:?}"
    );
    run(
        "pc-vmap",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    let out = run(
        "pc-fmm",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    assert!(
        out.stdout.contains("pc-fmm: wrote") && out.stdout.contains("iterations"),
        "{out:?}"
    );
    assert!(!out.stdout.contains("not converged"), "{out:?}");
    let out = run(
        "pc-raytrace",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    assert!(out.stdout.contains("stored shading"), "{out:?}");
    // A rebuilt octree (another k) makes the V-map and the radiosity stale.
    pc_octree(args![
        "--quiet",
        "--config",
        &cfg,
        "--set",
        "octree.max_leaf_points=8"
    ])
    .success();
    let out = run(
        "pc-fmm",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    );
    assert_eq!(out.code, Some(2), "{out:?}");
    assert!(out.stderr.contains("stale V-map"), "{out:?}");
    let out = run(
        "pc-raytrace",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    );
    assert_eq!(out.code, Some(2), "{out:?}");
    assert!(out.stderr.contains("stale radiosity"), "{out:?}");
}
