//! cargo xtask: drives the pcgi pipeline (stage binaries as separate processes), samples
//! scenes, writes the reference-scene config, and runs the benchmarks into BENCHMARKS.md.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use anyhow::{bail, Context, Result};

const USAGE: &str = "\
cargo xtask <command>

commands:
  run [--config FILE] [--set KEY=VALUE]... [--force STAGE|all]... [--from STAGE] [--until STAGE]
                                             run the pipeline's stages in order (release build),
                                             skipping the ones that are up to date (pc-run)
  sample <cornell|sphere|glass-box> --points N --out DIR [pc-sample options]
                                             sample a built-in scene into PLY files + scene.toml
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
  bench [--sizes 1M,4M] [--runs N] [--only octree|rays|caustics|fmm|chain] [--write]
                                             octree build and ray traversal benchmarks; with
                                             --only caustics, photon tracing at about 1M photons
                                             and the caustic lookup (default size 1M); with
                                             --only fmm, the radiosity solve (default sizes
                                             100k,1M,4M; best of N runs); with --only chain,
                                             the whole chain cold and a new view (default 1M)
                                             (writes BENCHMARKS.md with --write)
";

/// The stages in dependency order. pc-caustics (a later issue) goes before pc-fmm.
const STAGES: &[&str] = &[
    "pc-octree",
    "pc-vmap",
    "pc-caustics",
    "pc-fmm",
    "pc-raytrace",
];

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
        Some("bench") => bench(&args[1..]),
        Some("walkthrough") => walkthrough(&args[1..]),
        Some("-h" | "--help" | "help") | None => {
            print!("{USAGE}");
            Ok(())
        }
        Some(other) => bail!("unknown command `{other}`\n\n{USAGE}"),
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Build the given binaries in release mode and return the folder they are in.
fn build_release(bins: &[&str]) -> Result<PathBuf> {
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

fn run_checked(cmd: &mut Command, what: &str) -> Result<()> {
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
    let bin = build_release(&[STAGES, &["pc-run", "pc-inspect"]].concat())?;
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

fn parse_count(s: &str) -> Result<usize> {
    let s = s.trim();
    let (num, mul) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1_000.0),
        Some('m' | 'M') => (&s[..s.len() - 1], 1_000_000.0),
        _ => (s, 1.0),
    };
    Ok((num
        .parse::<f64>()
        .with_context(|| format!("`{s}` is not a count"))?
        * mul) as usize)
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            m.lines()
                .next()
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|k| k.parse::<u64>().ok())
        })
        .map(|kb| format!("{:.0} GiB", kb as f64 / 1048576.0))
        .unwrap_or_default();
    format!("{cpu}, {cores} cores, {mem}")
}

fn today() -> String {
    Command::new("date")
        .args(["-u", "+%Y-%m-%d"])
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

fn bench(args: &[String]) -> Result<()> {
    let mut sizes = vec![1_000_000usize, 4_000_000];
    let mut runs = 3usize;
    let mut write = false;
    let mut only: Option<String> = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--sizes" => {
                sizes = it
                    .next()
                    .context("--sizes needs a list")?
                    .split(',')
                    .map(parse_count)
                    .collect::<Result<_>>()?
            }
            "--runs" => runs = it.next().context("--runs needs a number")?.parse()?,
            "--write" => write = true,
            "--only" => {
                only = Some(
                    it.next()
                        .context("--only needs octree, rays, caustics, fmm or chain")?
                        .clone(),
                )
            }
            other => bail!("bench: unknown option `{other}`"),
        }
    }
    let default_sizes = !args.iter().any(|a| a == "--sizes");
    match only.as_deref() {
        Some("caustics") => {
            if default_sizes {
                sizes = vec![1_000_000];
            }
            return bench_caustics(&sizes, runs, write);
        }
        Some("chain") => {
            if default_sizes {
                sizes = vec![1_000_000];
            }
            return bench_chain(&sizes, write);
        }
        Some("fmm") => {
            if default_sizes {
                sizes = vec![100_000, 1_000_000, 4_000_000];
            }
            return bench_fmm(&sizes, runs, write);
        }
        None => {
            // Every benchmark: the stages' own (the radiosity solve at 100k, 1M and 4M), then the
            // whole chain at 1M splats.
            let mut one = vec!["--runs".to_string(), runs.to_string()];
            if write {
                one.push("--write".into());
            }
            for what in ["octree", "rays"] {
                let mut a = vec!["--only".to_string(), what.to_string()];
                a.extend(one.iter().cloned());
                if !default_sizes {
                    a.extend(["--sizes".to_string(), sizes_arg(&sizes)]);
                }
                bench(&a)?;
            }
            let small = if default_sizes {
                vec![1_000_000]
            } else {
                sizes.clone()
            };
            bench_caustics(&small, runs, write)?;
            let fmm_sizes = if default_sizes {
                vec![100_000, 1_000_000, 4_000_000]
            } else {
                sizes.clone()
            };
            bench_fmm(&fmm_sizes, runs, write)?;
            return bench_chain(&small, write);
        }
        Some("octree" | "rays") => {}
        Some(other) => {
            bail!("bench: --only takes octree, rays, caustics, fmm or chain, not `{other}`")
        }
    }
    let bin = build_release(&["pc-sample", "pc-octree", "pc-raybench"])?;
    let mut rows = Vec::new();
    let mut ray_rows = Vec::new();
    for &n in &sizes {
        let config = bench_scene(&bin, n)?;
        let scene = config.parent().unwrap().to_path_buf();
        // The octree the ray benchmark reads.
        if only.as_deref() == Some("rays") && !scene.join("out/octree.pcgi").exists() {
            run_checked(
                Command::new(bin.join("pc-octree"))
                    .arg("--quiet")
                    .arg("--config")
                    .arg(&config),
                "pc-octree",
            )?;
        }
        for threads in [1usize, 2] {
            if only.as_deref() == Some("rays") {
                break;
            }
            let mut best: Option<serde_json::Value> = None;
            for _ in 0..runs {
                let stats = scene.join("stats.json");
                run_checked(
                    Command::new(bin.join("pc-octree"))
                        .env("RAYON_NUM_THREADS", threads.to_string())
                        .arg("--quiet")
                        .arg("--config")
                        .arg(&config)
                        .arg("--stats-json")
                        .arg(&stats),
                    "pc-octree",
                )?;
                let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats)?)?;
                let better = best
                    .as_ref()
                    .is_none_or(|b| v["total_seconds"].as_f64() < b["total_seconds"].as_f64());
                if better {
                    best = Some(v);
                }
            }
            let v = best.unwrap();
            let splats = v["splats"].as_f64().unwrap_or(0.0);
            let build = v["build_seconds"].as_f64().unwrap_or(f64::NAN);
            let import = v["import_seconds"].as_f64().unwrap_or(f64::NAN);
            let total = v["total_seconds"].as_f64().unwrap_or(f64::NAN);
            let phases: Vec<String> = v["phases"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .map(|p| {
                            format!(
                                "{} {:.2}",
                                p["phase"].as_str().unwrap_or("?"),
                                p["seconds"].as_f64().unwrap_or(0.0)
                            )
                        })
                        .collect()
                })
                .unwrap_or_default();
            rows.push(format!(
                "| {:.2}M | {} | {:.2} s | {:.1} M/s | {:.2} s | {:.2} s | {:.1} M/s | {:.0} MiB | {} |",
                splats / 1e6,
                threads,
                build,
                splats / build / 1e6,
                import,
                total,
                splats / total / 1e6,
                v["peak_rss_bytes"].as_f64().unwrap_or(0.0) / 1048576.0,
                phases.join(", ")
            ));
            println!("{}", rows.last().unwrap());
        }
        if only.as_deref() != Some("octree") {
            for threads in [1usize, 2] {
                let stats = scene.join("rays.json");
                let mut best: Option<serde_json::Value> = None;
                for run in 0..runs {
                    let mut cmd = Command::new(bin.join("pc-raybench"));
                    cmd.env("RAYON_NUM_THREADS", threads.to_string())
                        .arg("--config")
                        .arg(&config)
                        .arg("--json")
                        .arg(&stats);
                    // The GPU is measured once per size (it does not depend on CPU threads).
                    if threads != 2 || run > 0 {
                        cmd.arg("--cpu-only");
                    }
                    run_checked(&mut cmd, "pc-raybench")?;
                    let v: serde_json::Value =
                        serde_json::from_str(&std::fs::read_to_string(&stats)?)?;
                    let keep_gpu = best
                        .as_ref()
                        .map(|b| b["gpu"].clone())
                        .filter(|g| !g.is_null());
                    let better = best.as_ref().is_none_or(|b| {
                        v["cpu_primary_rays_per_s"].as_f64() > b["cpu_primary_rays_per_s"].as_f64()
                    });
                    let mut chosen = if better { v } else { best.take().unwrap() };
                    if chosen["gpu"].is_null() {
                        if let Some(g) = keep_gpu {
                            chosen["gpu"] = g;
                        }
                    }
                    best = Some(chosen);
                }
                let v = best.unwrap();
                let m = |k: &str| v[k].as_f64().unwrap_or(f64::NAN) / 1e6;
                let gpu = if v["gpu"].is_null() {
                    "—".to_string()
                } else if let Some(e) = v["gpu"]["error"].as_str() {
                    format!(
                        "not run on {}: {e}",
                        v["gpu"]["device"].as_str().unwrap_or("?")
                    )
                } else {
                    format!(
                        "{:.2} / {:.2} M/s on {}",
                        v["gpu"]["primary_rays_per_s"].as_f64().unwrap_or(f64::NAN) / 1e6,
                        v["gpu"]["incoherent_rays_per_s"]
                            .as_f64()
                            .unwrap_or(f64::NAN)
                            / 1e6,
                        v["gpu"]["device"].as_str().unwrap_or("?")
                    )
                };
                ray_rows.push(format!(
                    "| {:.2}M | {threads} | {:.2} M/s | {:.2} M/s | {gpu} |",
                    v["splats"].as_f64().unwrap_or(0.0) / 1e6,
                    m("cpu_primary_rays_per_s"),
                    m("cpu_incoherent_rays_per_s"),
                ));
                println!("{}", ray_rows.last().unwrap());
            }
        }
    }
    let table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --sizes {} --runs {runs}` (best of {runs}).\n\n\
| splats | threads | build | build rate | PLY import | total (import+build+write) | end-to-end rate | peak memory | build phases (s) |\n\
|---|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(","),
        rows.join("\n")
    );
    let ray_table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --sizes {} --runs {runs} --only rays` (best of {runs}). \
Primary rays: one per pixel centre of a 1024×1024 view from the scene camera. Incoherent rays: from random splats, \
cosine-distributed about their normals (diffuse bounce rays). GPU: rays uploaded, cast, hits read back (no GPU \
is lent to this machine; a software adapter, when present, is listed as such).\n\n\
| splats | CPU threads | CPU primary | CPU incoherent | GPU primary / incoherent |\n|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(","),
        ray_rows.join("\n")
    );
    println!("\n{table}\n{ray_table}");
    if write && !ray_rows.is_empty() {
        write_bench_block(
            "rays",
            "Ray traversal (pc-tree, used by pc-raytrace)",
            &ray_table,
        )?;
    }
    if write && !rows.is_empty() {
        write_bench_block("octree", "pc-octree build", &table)?;
    }
    Ok(())
}

/// Sample `pc-sample cornell --with-specular` at `n` points under target/bench (once) and write
/// its bench.toml; returns the config path.
fn bench_scene(bin: &Path, n: usize) -> Result<PathBuf> {
    let scene = root().join("target/bench").join(format!("cornell-{n}"));
    if !scene.join("scene.toml").exists() {
        run_checked(
            Command::new(bin.join("pc-sample"))
                .args([
                    "cornell",
                    "--with-specular",
                    "--points",
                    &n.to_string(),
                    "--out",
                ])
                .arg(&scene),
            "pc-sample",
        )?;
    }
    let config = scene.join("bench.toml");
    std::fs::write(
        &config,
        "include = [\"scene.toml\"]\n[output]\ndir = \"out\"\n",
    )?;
    Ok(config)
}

fn sizes_arg(sizes: &[usize]) -> String {
    sizes
        .iter()
        .map(|n| n.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

/// The whole chain through pc-run on the Cornell box with a glass and a mirror sphere at each
/// size, 512×512 at 16 samples per pixel: cold (no artifacts), then a new camera on the cached
/// solution (only pc-raytrace runs).
fn bench_chain(sizes: &[usize], write: bool) -> Result<()> {
    let bin = build_release(&[STAGES, &["pc-run", "pc-sample"]].concat())?;
    let mut rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(&bin, n)?;
        let scene = config.parent().unwrap().to_path_buf();
        let out = scene.join("out-chain");
        let _ = std::fs::remove_dir_all(&out);
        let report = scene.join("chain.json");
        let base = [
            "output.dir=out-chain",
            "camera.width=512",
            "camera.height=512",
            "raytrace.spp=16",
        ];
        let pass = |extra: &[&str]| -> Result<(f64, serde_json::Value)> {
            let mut cmd = Command::new(bin.join("pc-run"));
            cmd.arg("--quiet").arg("--config").arg(&config);
            for s in base.iter().chain(extra) {
                cmd.args(["--set", s]);
            }
            cmd.arg("--report").arg(&report);
            let t = std::time::Instant::now();
            run_checked(&mut cmd, "pc-run")?;
            let secs = t.elapsed().as_secs_f64();
            Ok((
                secs,
                serde_json::from_str(&std::fs::read_to_string(&report)?)?,
            ))
        };
        let stage_time = |v: &serde_json::Value, stage: &str| -> String {
            v.as_array()
                .and_then(|a| a.iter().find(|r| r["stage"] == stage))
                .map(|r| {
                    if r["status"] == "ran" {
                        format!("{:.1} s", r["seconds"].as_f64().unwrap_or(f64::NAN))
                    } else {
                        "cached".to_string()
                    }
                })
                .unwrap_or_else(|| "—".to_string())
        };
        let (cold, v) = pass(&[])?;
        let (view, w) = pass(&["camera.origin=[0.4, 0.2, 3.8]"])?;
        let stages: Vec<String> = STAGES.iter().map(|s| stage_time(&v, s)).collect();
        rows.push(format!(
            "| {:.2}M | {cold:.1} s | {} | {view:.2} s | {} |",
            n as f64 / 1e6,
            stages.join(" | "),
            STAGES
                .iter()
                .map(|s| format!("{} {}", &s[3..], stage_time(&w, s)))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        println!("{}", rows.last().unwrap());
    }
    let table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only chain --sizes {}`. Cornell box with a \
glass and a mirror sphere (`pc-sample cornell --with-specular`), 512×512, 16 spp, stage defaults \
(backend `auto`: the CPU here). Cold: no artifacts; new view: another camera on the cached solution. \
Times are each stage's process wall time as pc-run measured it. Aims: cold under 60 s, new view under 5 s.\n\n\
| splats | cold | pc-octree | pc-vmap | pc-caustics | pc-fmm | pc-raytrace | new view | new view per stage |\n\
|---|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.join("\n")
    );
    publish("chain", "The whole chain (cargo xtask run)", &table, write)
}

/// Print a benchmark's table, and with `write` put it in BENCHMARKS.md ([`write_bench_block`]).
fn publish(name: &str, heading: &str, table: &str, write: bool) -> Result<()> {
    println!("\n{table}");
    if write {
        write_bench_block(name, heading, table)?;
    }
    Ok(())
}

/// Replace the block between `<!-- bench:NAME:begin/end -->` in BENCHMARKS.md with `table`
/// (appended under `heading` the first time).
fn write_bench_block(name: &str, heading: &str, table: &str) -> Result<()> {
    let path = root().join("BENCHMARKS.md");
    let text = std::fs::read_to_string(&path).unwrap_or_default();
    let (begin, end) = (
        format!("<!-- bench:{name}:begin -->"),
        format!("<!-- bench:{name}:end -->"),
    );
    let new = match (text.find(&begin), text.find(&end)) {
        (Some(b), Some(e)) if b < e => format!("{}{begin}\n{table}{}", &text[..b], &text[e..]),
        _ => format!("{text}\n## {heading}\n\n{begin}\n{table}{end}\n"),
    };
    std::fs::write(&path, new)?;
    println!("xtask: updated {}", path.display());
    Ok(())
}

/// Photons per second of pc-caustics at about one million traced photons (CPU on 1 and 2
/// threads, the GPU when wgpu finds one), and the caustic lookup cost per shaded hit.
fn bench_caustics(sizes: &[usize], runs: usize, write: bool) -> Result<()> {
    let bin = build_release(&[
        "pc-sample",
        "pc-octree",
        "pc-vmap",
        "pc-caustics",
        "pc-raybench",
    ])?;
    let read_json = |p: &Path| -> Result<serde_json::Value> {
        Ok(serde_json::from_str(&std::fs::read_to_string(p)?)?)
    };
    let mut rows = Vec::new();
    let mut lookup_rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(&bin, n)?;
        let dir = config.parent().unwrap().to_path_buf();
        if !dir.join("out/octree.pcgi").exists() {
            run_checked(
                Command::new(bin.join("pc-octree"))
                    .arg("--quiet")
                    .arg("--config")
                    .arg(&config),
                "pc-octree",
            )?;
        }
        // Up to date V-map links are reused; only the light lists are redone.
        run_checked(
            Command::new(bin.join("pc-vmap"))
                .args(["--quiet", "--backend", "cpu", "--config"])
                .arg(&config),
            "pc-vmap",
        )?;
        let stats = dir.join("caustics.json");
        let caustics = |backend: &str, threads: usize, budget: u64| -> Result<serde_json::Value> {
            run_checked(
                Command::new(bin.join("pc-caustics"))
                    .env("RAYON_NUM_THREADS", threads.to_string())
                    .args(["--quiet", "--backend", backend, "--config"])
                    .arg(&config)
                    .arg("--set")
                    .arg(format!("caustics.photons={budget}"))
                    .arg("--stats-json")
                    .arg(&stats),
                "pc-caustics",
            )?;
            read_json(&stats)
        };
        // The budget covers the lights' whole sphere; scale it so that about 1M are traced.
        let probe = caustics("cpu", 2, 2_000_000)?;
        let traced = probe["traced"].as_f64().unwrap_or(0.0).max(1.0);
        let budget = ((2e6 * 1e6 / traced).ceil() as u64).min(u32::MAX as u64);
        let gpu_present = pc_gpu_present(&bin, &config);
        let mut devices = vec![("cpu", 1usize), ("cpu", 2)];
        if gpu_present {
            devices.push(("gpu", 2));
        }
        for (backend, threads) in devices {
            let mut best: Option<serde_json::Value> = None;
            for _ in 0..runs {
                match caustics(backend, threads, budget) {
                    Ok(v) => {
                        if best.as_ref().is_none_or(|b| {
                            v["photons_per_s"].as_f64() > b["photons_per_s"].as_f64()
                        }) {
                            best = Some(v);
                        }
                    }
                    Err(e) => {
                        rows.push(format!(
                            "| {:.2}M | {backend}: not run: {e:#} | | | | | |",
                            n as f64 / 1e6
                        ));
                        break;
                    }
                }
            }
            if let Some(v) = best {
                let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
                rows.push(format!(
                    "| {:.2}M | {} | {} | {:.2}M | {:.0}k | {:.2} s | {:.2} M/s |",
                    n as f64 / 1e6,
                    if backend == "cpu" {
                        format!(
                            "CPU, {threads} thread{}",
                            if threads > 1 { "s" } else { "" }
                        )
                    } else {
                        v["device"].as_str().unwrap_or("GPU").to_string()
                    },
                    budget,
                    f("traced") / 1e6,
                    f("stored") / 1e3,
                    f("trace_seconds"),
                    f("photons_per_s") / 1e6,
                ));
                println!("{}", rows.last().unwrap());
            }
        }
        // The lookup, on the map just written (the last run's).
        let rays = dir.join("lookups.json");
        run_checked(
            Command::new(bin.join("pc-raybench"))
                .args([
                    "--cpu-only",
                    "--caustics",
                    "--width",
                    "512",
                    "--incoherent",
                    "1000",
                ])
                .arg("--config")
                .arg(&config)
                .arg("--json")
                .arg(&rays),
            "pc-raybench",
        )?;
        let v = read_json(&rays)?;
        let c = &v["caustic"];
        let f = |k: &str| c[k].as_f64().unwrap_or(f64::NAN);
        lookup_rows.push(format!(
            "| {:.2}M | {:.0}k | {:.4} | {:.0}k ({:.0} % near photons) | {:.0} ns | {:.0} ns (k {}) | {:.0} ns (built in {:.3} s) |",
            n as f64 / 1e6,
            f("photons") / 1e3,
            f("radius"),
            f("lookups") / 1e3,
            100.0 * f("found") / f("lookups"),
            f("kdtree_ns"),
            f("knn_ns"),
            c["k"],
            f("grid_ns"),
            f("grid_build_s"),
        ));
        println!("{}", lookup_rows.last().unwrap());
    }
    let table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only caustics --sizes {} --runs {runs}` \
(best of {runs}). Scene: `pc-sample cornell --with-specular` (glass and mirror spheres); the budget is \
scaled so that about 1M photons are traced (the budget covers the lights' whole sphere, only photons \
aimed at light-visible specular leaves are traced). Trace time: emission plan excluded, tracing only.\n\n\
| splats | device | budget | traced | stored | trace | photons/s |\n|---|---|---|---|---|---|---|\n{}\n\n\
Caustic lookup per shaded hit (CPU, per thread): the diffuse hits of 512×512 primary rays from the scene \
camera, on the photon map above; fixed radius through the kd-tree queried in place, k-nearest through \
it, and the hashed grid the GPU renderer uses, run on the CPU.\n\n\
| splats | photons | radius | lookups | kd-tree, fixed radius | kd-tree, k-nearest | hashed grid |\n|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(","),
        rows.join("\n"),
        lookup_rows.join("\n")
    );
    publish(
        "caustics",
        "Caustic photon map (pc-caustics)",
        &table,
        write,
    )
}

/// The radiosity solve of pc-fmm on the bench scenes (after pc-octree, pc-vmap and pc-caustics):
/// the best of `runs` runs on the CPU, and one on the GPU when wgpu finds one (llvmpipe refuses
/// plans beyond its loop limit: the row says so). Times are pc-fmm's own, from the artifact's
/// metadata (`pc-inspect --metadata`).
fn bench_fmm(sizes: &[usize], runs: usize, write: bool) -> Result<()> {
    let bin = build_release(&[
        "pc-sample",
        "pc-octree",
        "pc-vmap",
        "pc-caustics",
        "pc-fmm",
        "pc-inspect",
        "pc-raybench",
    ])?;
    let mut rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(&bin, n)?;
        let dir = config.parent().unwrap().to_path_buf();
        // The inputs, made or found up to date.
        for stage in ["pc-octree", "pc-vmap", "pc-caustics"] {
            run_checked(
                Command::new(bin.join(stage))
                    .args(["--quiet", "--if-stale", "--config"])
                    .arg(&config),
                stage,
            )?;
        }
        let solve = |backend: &str| -> Result<serde_json::Value> {
            let run = Command::new(bin.join("pc-fmm"))
                .args(["--quiet", "--backend", backend, "--config"])
                .arg(&config)
                .output()
                .context("starting pc-fmm")?;
            if !run.status.success() {
                let err = String::from_utf8_lossy(&run.stderr);
                let last = err.trim().lines().last().unwrap_or("pc-fmm failed");
                // The reason, without the stage's name and the config's path.
                let at = format!("{}: ", config.display());
                bail!("{}", last.rsplit(at.as_str()).next().unwrap_or(last));
            }
            let out = Command::new(bin.join("pc-inspect"))
                .arg("--metadata")
                .arg(dir.join("out/radiosity.pcgi"))
                .output()
                .context("starting pc-inspect")?;
            let text = String::from_utf8_lossy(&out.stdout);
            let json = text
                .find("\n{")
                .map(|i| &text[i + 1..])
                .context("pc-inspect printed no metadata")?;
            Ok(serde_json::from_str(json)?)
        };
        let mut backends = vec!["cpu"];
        if pc_gpu_present(&bin, &config) {
            backends.push("gpu");
        }
        for backend in backends {
            let tries = if backend == "cpu" { runs } else { 1 };
            let mut best: Option<(f64, serde_json::Value)> = None;
            for _ in 0..tries {
                match solve(backend) {
                    Ok(v) => {
                        // The phases (not the per-iteration mean, also listed).
                        let total: f64 = v["timings"]
                            .as_array()
                            .map(|t| {
                                t.iter()
                                    .filter(|x| x[0] != "per iteration")
                                    .filter_map(|x| x[1].as_f64())
                                    .sum()
                            })
                            .unwrap_or(f64::NAN);
                        if best.as_ref().is_none_or(|b| total < b.0) {
                            best = Some((total, v));
                        }
                    }
                    Err(e) => {
                        rows.push(format!(
                            "| {:.2}M | {backend}: not run: {e:#} | | | | | | | | |",
                            n as f64 / 1e6
                        ));
                        break;
                    }
                }
            }
            let Some((total, v)) = best else { continue };
            let time = |k: &str| -> f64 {
                v["timings"]
                    .as_array()
                    .and_then(|t| t.iter().find(|x| x[0] == k))
                    .and_then(|x| x[1].as_f64())
                    .unwrap_or(f64::NAN)
            };
            let active = v["active_splats"].as_f64().unwrap_or(f64::NAN);
            let iterations = v["iterations"].as_f64().unwrap_or(f64::NAN);
            let per_product = time("solve") / iterations;
            let orders: Vec<String> = v["orders"]
                .as_array()
                .map(|o| o.iter().map(|x| x.to_string()).collect())
                .unwrap_or_default();
            rows.push(format!(
                "| {:.2}M ({:.3}M active) | {} | {total:.2} s | {:.2} s | {:.2} s | {:.2} s | {iterations} | {:.3} s | {} | {:.2} µs |",
                n as f64 / 1e6,
                active / 1e6,
                v["device"].as_str().unwrap_or(backend),
                time("plan"),
                time("source term"),
                time("solve"),
                per_product,
                orders.join(" "),
                per_product / active * 1e6,
            ));
            println!("{}", rows.last().unwrap());
        }
    }
    let table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only fmm --sizes {} --runs {runs}` \
(best of {runs} on the CPU, one run on a GPU). Scene: `pc-sample cornell --with-specular`; pc-fmm's \
defaults (GMRES with relaxed products, order 3, tolerance 1e-3), caustic energy in the sources. \
Times are pc-fmm's own (tree, plan, emitters' direct light and caustic energy, solve); per product: \
the solve over its products.\n\n\
| splats | device | total | plan | source term | solve | products | per product | orders | per active splat per product |\n\
|---|---|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.join("\n")
    );
    publish("fmm", "Radiosity solve (pc-fmm)", &table, write)
}

/// Whether wgpu finds any adapter (pc-raybench's GPU pass says so without --cpu-only).
fn pc_gpu_present(bin: &Path, config: &Path) -> bool {
    Command::new(bin.join("pc-raybench"))
        .args(["--width", "8", "--incoherent", "8", "--config"])
        .arg(config)
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).contains(", GPU "))
        .unwrap_or(false)
}
