//! cargo xtask: drives the pcgi pipeline (stage binaries as separate processes), samples
//! scenes, writes the reference-scene config, and runs the benchmarks into BENCHMARKS.md.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use anyhow::{bail, Context, Result};

mod bench;

const USAGE: &str = "\
cargo xtask <command>

commands:
  run [--config FILE] [--set KEY=VALUE]... [--force STAGE|all]... [--from STAGE] [--until STAGE]
                                             run the pipeline's stages in order (release build),
                                             skipping the ones that are up to date (pc-run);
                                             --until pc-bake also writes the lit cloud
  sample <cornell|sphere|glass-box> --points N --out DIR [pc-sample options]
                                             sample a built-in scene into PLY files + scene.toml
  sample scan --points N --out DIR [--format laz|las|e57]
                                             scan the hall with a virtual terrestrial scanner
                                             (three stations) into DIR/hall.laz + scene.toml
  reference-config [--out FILE]              write a pipeline config for ../shared/reference/cornell
  compare IMAGE.exr REFERENCE.exr [--regions FILE] [--diff PNG]
                                             relative RMSE, per-region means (regions: JSON with
                                             rects, as *.stats.json) and a difference image
  compare [--set KEY=VALUE]...               with no image: render ../shared/reference/cornell's
                                             points through the whole chain and compare with
                                             Mitsuba's image (out/reference/image.diff.png)
  walkthrough [--frames N] [--orbit DEG] [--config FILE] [--set KEY=VALUE]...
                                             bring the solution up to date (pc-run), then render
                                             N frames (default 60) of a camera orbit on it as
                                             out/<scene>/walkthrough-{cpu,gpu}/frame_NNNNN.png,
                                             and report frames per second on the CPU and the GPU
  bench [--sizes 1M,4M] [--runs N] [--only octree|rays|caustics|fmm|chain|render|scale|mitsuba|gpu]
        [--peer embree] [--write]
                                             octree build and ray traversal benchmarks; with
                                             --only rays --peer embree, the same rays traced by
                                             Embree (Debian's libembree-dev) in one run,
                                             alternating, with the ratios; with --only mitsuba,
                                             time to pcgi's error on both shared references
                                             against Mitsuba 3 (pip, in a venv); with
                                             --only caustics, photon tracing at about 1M photons
                                             and the caustic lookup (default size 1M); with
                                             --only fmm, the radiosity solve (default sizes
                                             100k,1M,4M; best of N runs); with --only chain,
                                             the whole chain cold and a new view (default 1M);
                                             with --only render, the CPU renderer's camera
                                             samples per second on the default scene (median
                                             of N runs); with --only gpu, the chain with every stage on the
                                             GPU (twice) and on the CPU, each GPU stage's share,
                                             and GPU frames per second (default 1M; skipped
                                             without an adapter). PCGI_BENCH_BIN_DIR=DIR runs
                                             the release binaries in DIR instead of building
                                             (writes BENCHMARKS.md with --write)
";

/// The stages of a render, in dependency order.
pub(crate) const STAGES: &[&str] = &[
    "pc-octree",
    "pc-vmap",
    "pc-caustics",
    "pc-fmm",
    "pc-raytrace",
];
/// The stage after them that writes the lit cloud (run with `--until pc-bake`).
pub(crate) const BAKE: &str = "pc-bake";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match dispatch(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn dispatch(args: &[String]) -> Result<()> {
    match args.first().map(String::as_str) {
        Some("run") => run(&args[1..]),
        Some("sample") => sample(&args[1..]),
        Some("reference-config") => reference_config(&args[1..]),
        Some("compare") => compare(&args[1..]),
        Some("bench") => bench::bench(&args[1..]),
        Some("walkthrough") => walkthrough(&args[1..]),
        Some("-h" | "--help" | "help") | None => {
            print!("{USAGE}");
            Ok(())
        }
        Some(other) => bail!("unknown command `{other}`\n\n{USAGE}"),
    }
}

pub(crate) fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Build the given binaries in release mode and return the folder they are in; with
/// `PCGI_BENCH_BIN_DIR` set, that folder as it is (no toolchain needed).
pub(crate) fn build_release(bins: &[&str]) -> Result<PathBuf> {
    if let Some(dir) = std::env::var_os("PCGI_BENCH_BIN_DIR") {
        let dir = PathBuf::from(dir);
        if let Some(b) = bins.iter().find(|b| !dir.join(b).is_file()) {
            bail!("PCGI_BENCH_BIN_DIR: {} has no {b}", dir.display());
        }
        return Ok(dir);
    }
    let mut cmd = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cmd.current_dir(root())
        .args(["build", "--release", "--quiet"]);
    for b in bins {
        cmd.args(["--bin", b]);
    }
    let status = cmd.status().context("running cargo build")?;
    if !status.success() {
        bail!("cargo build --release failed");
    }
    let target = std::env::var("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|_| root().join("target"));
    Ok(target.join("release"))
}

pub(crate) fn run_checked(cmd: &mut Command, what: &str) -> Result<()> {
    let status = cmd.status().with_context(|| format!("starting {what}"))?;
    if !status.success() {
        bail!("{what} failed ({status})");
    }
    Ok(())
}

/// `cargo xtask run [pc-run options]`: build the stage binaries (release) and run pc-run,
/// which runs the stages that are not up to date. The config defaults to the workspace's
/// pipeline.toml.
fn run(args: &[String]) -> Result<()> {
    let bin = build_release(&[STAGES, &[BAKE, "pc-run", "pc-inspect"]].concat())?;
    let mut cmd = Command::new(bin.join("pc-run"));
    if !args
        .iter()
        .any(|a| a == "--config" || a.starts_with("--config="))
    {
        cmd.arg("--config").arg(root().join("pipeline.toml"));
    }
    cmd.args(args);
    run_checked(&mut cmd, "pc-run")
}

/// `cargo xtask walkthrough`: pc-run, then pc-raytrace --frames on the CPU and on the GPU.
fn walkthrough(args: &[String]) -> Result<()> {
    let mut frames = "60".to_string();
    let mut orbit = None;
    let mut config = root().join("pipeline.toml");
    let mut sets = Vec::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--frames" => frames = it.next().context("--frames needs a count")?.clone(),
            "--orbit" => orbit = Some(it.next().context("--orbit needs degrees")?.clone()),
            "--config" => config = PathBuf::from(it.next().context("--config needs a file")?),
            "--set" => sets.push(it.next().context("--set needs KEY=VALUE")?.clone()),
            other => bail!("walkthrough: unknown option `{other}`"),
        }
    }
    let mut run_args = vec!["--config".to_string(), config.display().to_string()];
    for s in &sets {
        run_args.extend(["--set".to_string(), s.clone()]);
    }
    run(&run_args)?;
    let bin = build_release(&["pc-raytrace"])?;
    let stats_dir = tempfile::tempdir().context("making a temporary folder")?;
    let mut lines = Vec::new();
    for backend in ["cpu", "gpu"] {
        let stats = stats_dir.path().join(format!("{backend}.json"));
        let mut cmd = Command::new(bin.join("pc-raytrace"));
        cmd.args(&run_args)
            .args(["--backend", backend, "--frames", &frames, "--stats-json"])
            .arg(&stats);
        if let Some(o) = &orbit {
            cmd.args(["--orbit", o]);
        }
        let out_dir = walkthrough_dir(&config, backend)?;
        cmd.arg("--frames-dir").arg(&out_dir);
        let status = cmd.status().context("starting pc-raytrace")?;
        if !status.success() {
            if backend == "gpu" {
                lines.push("GPU: none usable here (pc-raytrace --backend gpu failed)".to_string());
                continue;
            }
            bail!("pc-raytrace --frames failed ({status})");
        }
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats)?)?;
        lines.push(format!(
            "{}: {:.2} frames/s on {} ({} frames {}x{} at {} spp in {}; PNG writing excluded)",
            backend.to_uppercase(),
            json["frames_per_second"].as_f64().unwrap_or(0.0),
            json["device"].as_str().unwrap_or("?"),
            json["frames"],
            json["width"],
            json["height"],
            json["spp"],
            out_dir.display()
        ));
    }
    println!("xtask walkthrough:\n  {}", lines.join("\n  "));
    Ok(())
}

/// `<output.dir>/walkthrough-<backend>` of a config (the output folder read from its
/// `[output] dir`, relative to the config's folder; `out` when unset).
fn walkthrough_dir(config: &Path, backend: &str) -> Result<PathBuf> {
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("{}: cannot read", config.display()))?;
    let value: toml::Value =
        toml::from_str(&text).with_context(|| format!("{}: not TOML", config.display()))?;
    let dir = value
        .get("output")
        .and_then(|o| o.get("dir"))
        .and_then(|d| d.as_str())
        .unwrap_or("out");
    let base = config.parent().unwrap_or(Path::new("."));
    Ok(base.join(dir).join(format!("walkthrough-{backend}")))
}

/// `cargo xtask compare IMAGE.exr REFERENCE.exr [--regions FILE] [pc-compare options]`
/// compares two renders; with no image, the reference comparison: reference config, every
/// stage, then pc-compare against ../shared/reference/cornell.
fn compare(args: &[String]) -> Result<()> {
    if args.first().is_some_and(|a| !a.starts_with('-')) {
        let bin = build_release(&["pc-compare"])?;
        return run_checked(
            Command::new(bin.join("pc-compare")).args(args),
            "pc-compare",
        );
    }
    let mut sets = Vec::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--set" => sets.push(it.next().context("--set needs KEY=VALUE")?.clone()),
            other => bail!("compare: unknown option `{other}`"),
        }
    }
    let config = root().join("out/reference/cornell.toml");
    reference_config(&["--out".to_string(), config.display().to_string()])?;
    let mut run_args = vec!["--config".to_string(), config.display().to_string()];
    for s in &sets {
        run_args.extend(["--set".to_string(), s.clone()]);
    }
    run(&run_args)?;
    let bin = build_release(&["pc-compare"])?;
    let reference = root().join("../shared/reference/cornell");
    run_checked(
        Command::new(bin.join("pc-compare"))
            .arg(root().join("out/reference/image.exr"))
            .arg(reference.join("cornell.exr"))
            .arg("--regions")
            .arg(reference.join("cornell.stats.json")),
        "pc-compare",
    )
}

fn sample(args: &[String]) -> Result<()> {
    let bin = build_release(&["pc-sample"])?;
    run_checked(Command::new(bin.join("pc-sample")).args(args), "pc-sample")
}

/// Write a pipeline config for the reference Cornell box (pc-compare reads its materials and
/// camera from the reference folder; nothing is copied into the code).
fn reference_config(args: &[String]) -> Result<()> {
    let mut out = root().join("out/reference/cornell.toml");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--out" => out = PathBuf::from(it.next().context("--out needs a file")?),
            other => bail!("reference-config: unknown option `{other}`"),
        }
    }
    let bin = build_release(&["pc-compare"])?;
    run_checked(
        Command::new(bin.join("pc-compare"))
            .arg("--reference")
            .arg(root().join("../shared/reference/cornell"))
            .arg("--write-config")
            .arg(&out),
        "pc-compare",
    )
}
