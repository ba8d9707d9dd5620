//! pc-caustics's command line: the whole chain on a sampled Cornell box with a glass and a
//! mirror sphere, pc-inspect on the photons and radiosity artifacts, and the errors for a
//! missing, stale, truncated or corrupt input.

use pc_artifact::photons::sections;
use pc_artifact::Artifact;
use pcgi_tests::{args, pc_inspect, pc_octree, run, sampled_cornell, temp_dir};

#[test]
fn traces_inspects_renders_and_rejects_bad_inputs() {
    let dir = temp_dir();
    let d = dir.path();
    let cfg = sampled_cornell(
        d,
        8000,
        true,
        "[vmap]\nleaf_splats = 16\n[fmm]\nemitter_samples = 8\n[caustics]\nphotons = 200000\n\
         [camera]\nwidth = 24\nheight = 24\n[raytrace]\nspp = 1\n",
    );
    let photons = d.join("out").join("photons.pcgi");
    pc_octree(args!["--quiet", "--config", &cfg]).success();
    // No V-map yet: a clear error naming the file.
    run(
        "pc-caustics",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .error(&["vmap.pcgi", "run pc-vmap"]);
    assert!(!photons.exists(), "nothing written on error");
    run(
        "pc-vmap",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    let out = run(
        "pc-caustics",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    assert!(
        out.stdout.contains("pc-caustics: wrote") && out.stdout.contains("photons stored"),
        "{out:?}"
    );
    // The GPU tracer (llvmpipe in CI) writes the same photon map, up to rounding.
    if pc_gpu::test_context().is_some() {
        let on_gpu = d.join("photons-gpu.pcgi");
        run(
            "pc-caustics",
            args![
                "--quiet",
                "--backend",
                "gpu",
                "--config",
                &cfg,
                "-o",
                &on_gpu
            ],
        )
        .success();
        let meta = |p: &std::path::Path| -> pc_artifact::photons::PhotonsMeta {
            Artifact::open(p).unwrap().metadata().unwrap()
        };
        let (c, g) = (meta(&photons), meta(&on_gpu));
        assert_eq!(c.traced, g.traced);
        assert!(g.device != c.device, "{} / {}", g.device, c.device);
        let tol = 4.0 * (c.stored as f64).sqrt();
        assert!(
            (c.stored as f64 - g.stored as f64).abs() <= tol,
            "stored {} on the CPU, {} on the GPU",
            c.stored,
            g.stored
        );
        // The specular links' paths too (the same tracer from diffuse leaves).
        let (cs, gs) = (c.specular.stored as f64, g.specular.stored as f64);
        assert_eq!(c.specular.paths, g.specular.paths);
        assert!(
            cs > 0.0 && (cs - gs).abs() <= 4.0 * cs.sqrt(),
            "specular paths kept: {cs} on the CPU, {gs} on the GPU"
        );
    }
    let out = pc_inspect(args![&photons, "--verify"]).success();
    for needle in [
        "stored of",
        "bounces",
        "in the map",
        "links paths kept",
        "ok (checksums,",
    ] {
        assert!(out.stdout.contains(needle), "{needle}: {out:?}");
    }
    // The specular links (diffuse light through the spheres) depend on the geometry alone: a
    // run with another photon budget (or another light) copies them.
    let links = |p: &std::path::Path| {
        let a = Artifact::open(p).unwrap();
        let meta: pc_artifact::photons::PhotonsMeta = a.metadata().unwrap();
        let flux: Vec<u8> = a
            .section_bytes(pc_artifact::specular::sections::FLUX)
            .unwrap()
            .to_vec();
        (meta.specular, flux)
    };
    let (first, flux) = links(&photons);
    assert!(
        first.stored > 1000 && first.flux_links > 0 && first.gather_links > 0 && !first.reused,
        "{first:?}"
    );
    let out = run(
        "pc-caustics",
        args![
            "--quiet",
            "--backend",
            "cpu",
            "--config",
            &cfg,
            "--set",
            "caustics.photons=150000"
        ],
    )
    .success();
    assert!(out.stdout.contains("reused"), "{out:?}");
    let (again, flux_again) = links(&photons);
    assert!(again.reused && again.key == first.key, "{again:?}");
    assert_eq!(flux, flux_again, "the links are copied as they were");
    run(
        "pc-caustics",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    // pc-fmm takes the caustic energy into its sources; pc-raytrace reads both.
    run(
        "pc-fmm",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();
    let radiosity = d.join("out").join("radiosity.pcgi");
    let out = pc_inspect(args![&radiosity, "--verify"]).success();
    for needle in [
        "converged",
        "residuals",
        "caustic energy",
        "finite and non-negative",
    ] {
        assert!(out.stdout.contains(needle), "{needle}: {out:?}");
    }
    run(
        "pc-raytrace",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .success();

    // A corrupt photon: the renderer names the file and the section.
    let good = std::fs::read(&photons).unwrap();
    let section = Artifact::open(&photons)
        .unwrap()
        .section_info(sections::PHOTONS)
        .expect("a photons section")
        .clone();
    let mut bad = good.clone();
    bad[(section.offset + section.len / 2) as usize] ^= 0x08;
    std::fs::write(&photons, &bad).unwrap();
    run(
        "pc-raytrace",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .error(&["photons.pcgi", "section `photons` is corrupt"]);
    // A truncated one: the same, naming the truncation.
    std::fs::write(&photons, &good[..good.len() / 2]).unwrap();
    run(
        "pc-fmm",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .error(&["photons.pcgi", "truncated"]);
    std::fs::write(&photons, &good).unwrap();

    // A rebuilt octree makes the V-map, and so the photon map, stale.
    pc_octree(args![
        "--quiet",
        "--config",
        &cfg,
        "--set",
        "octree.max_leaf_points=8"
    ])
    .success();
    run(
        "pc-caustics",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .error(&["vmap.pcgi", "stale V-map"]);
    assert_eq!(
        std::fs::read(&photons).unwrap(),
        good,
        "the previous photon map is left as it was"
    );
    // Without the (equally stale) radiosity, the renderer names the photon map.
    std::fs::remove_file(&radiosity).unwrap();
    run(
        "pc-raytrace",
        args!["--quiet", "--backend", "cpu", "--config", &cfg],
    )
    .error(&["photons.pcgi", "stale photon map"]);
}
