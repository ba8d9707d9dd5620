//! Killing each stage at random moments (SIGKILL, the worst a crash or an impatient user can
//! do) never loses what was published: after a kill the stage's output is the previous file,
//! byte for byte, or a complete new one that verifies; the next run finishes and leaves no
//! temporary file behind. The moments are drawn from a fixed seed over each stage's own run
//! time, so every run of the test kills at the same fractions.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use pcgi_tests::{args, bin, files_under, pc_inspect, run, sampled_cornell, temp_dir};

/// The stages, their outputs, and a `--set` that makes each rerun with a new key.
const STAGES: [(&str, &str, &str); 5] = [
    ("pc-octree", "octree.pcgi", "octree.area_samples"),
    ("pc-vmap", "vmap.pcgi", "vmap.seed"),
    ("pc-caustics", "photons.pcgi", "caustics.seed"),
    ("pc-fmm", "radiosity.pcgi", "fmm.emitter_samples"),
    ("pc-raytrace", "image.exr", "raytrace.seed"),
];

/// Kills per stage.
const KILLS: u32 = 4;

fn scene(d: &Path) -> PathBuf {
    sampled_cornell(
        d,
        3000,
        true,
        "[[lights]]\nposition = [0.3, 0.7, 0.3]\nintensity = [0.5, 0.5, 0.5]\n\
         [vmap]\nleaf_splats = 16\nrays = 8\n[fmm]\nemitter_samples = 8\n\
         [caustics]\nphotons = 50000\n[camera]\nwidth = 48\nheight = 48\n[raytrace]\nspp = 2\n",
    )
}

/// A fraction in [0, 1) from a counter (a fixed sequence, the same every run).
fn fraction(k: u32) -> f64 {
    let x = (k as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 11;
    x as f64 / (1u64 << 53) as f64
}

/// The published output checks out: an artifact verifies; each image of the pair reads whole
/// and carries a key (a kill between the PNG and the EXR may leave them from two renders, which
/// the next run detects and redoes, `raytrace_cli`).
fn intact(output: &Path) -> Result<(), String> {
    if output.extension().is_some_and(|e| e == "exr") {
        let exr = pc_raytrace::image::exr_key(output);
        let png = pc_raytrace::image::png_key(&output.with_extension("png"));
        return match (exr, png) {
            (Some(_), Some(_)) => Ok(()),
            _ => Err(format!("{}: an image is incomplete", output.display())),
        };
    }
    let o = run("pc-inspect", args![output, "--verify"]);
    match o.code {
        Some(0) => Ok(()),
        _ => Err(format!("{}: {}", output.display(), o.stderr)),
    }
}

#[cfg(unix)]
#[test]
fn killed_stages_never_lose_a_published_output() {
    let dir = temp_dir();
    let cfg = scene(dir.path());
    let out_dir = dir.path().join("out");
    // Publish every output once.
    run("pc-run", args!["--quiet", "--config", &cfg]).success();
    let mut k = 0;
    // How many kills landed before the stage published (its output unchanged).
    let mut caught = 0;
    for (stage, file, key) in STAGES {
        let output = out_dir.join(file);
        // How long a run of the stage takes here, with a new key each time.
        let stage_args = |value: u32| {
            let mut a = args![
                "--quiet",
                "--config",
                &cfg,
                "--set",
                format!("{key}={value}")
            ];
            if stage != "pc-octree" {
                a.extend(args!["--backend", "cpu"]);
            }
            a
        };
        let t = Instant::now();
        run(stage, stage_args(1)).success();
        let full = t.elapsed();
        for kill in 0..KILLS {
            k += 1;
            let before = std::fs::read(&output).unwrap();
            let at = full.mul_f64(fraction(k) * 1.2);
            let mut child = Command::new(bin(stage))
                .args(stage_args(2 + kill))
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap();
            std::thread::sleep(at);
            let _ = child.kill();
            let _ = child.wait();
            let after = std::fs::read(&output).unwrap_or_else(|e| {
                panic!(
                    "{stage} killed at {at:?}: {} is gone: {e}",
                    output.display()
                )
            });
            if after == before {
                caught += 1;
            } else {
                intact(&output).unwrap_or_else(|e| {
                    panic!("{stage} killed at {at:?}: a new output that does not check out: {e}")
                });
            }
        }
        // The next run finishes, and no temporary file is left.
        run(stage, stage_args(9)).success();
        intact(&output).unwrap();
        let tmps: Vec<_> = files_under(&out_dir)
            .into_iter()
            .filter(|p| p.to_string_lossy().ends_with(".tmp"))
            .collect();
        assert!(tmps.is_empty(), "{stage}: temporary files left: {tmps:?}");
    }
    // The test means something only if kills land while stages work.
    eprintln!("kill: {caught} of {k} kills landed before the stage published");
    assert!(caught > 0, "no kill landed while a stage was running");
    // The chain as a whole is still consistent: every artifact verifies.
    for (_, file, _) in &STAGES[..4] {
        pc_inspect(args![out_dir.join(file), "--verify"]).success();
    }
}
