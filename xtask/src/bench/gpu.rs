//! The GPU against the CPU on the machine at hand (`--only gpu`): the whole chain through pc-run
//! with every stage on the GPU (twice: the first pass pays the driver's kernel compiles, the
//! second, in a fresh folder, finds them cached), then on the CPU, then a new view each, and
//! GPU walkthroughs at 512² and 1024², 1 spp. Each GPU stage's share (kernels built, bytes up,
//! dispatches, bytes back) comes from its report. Then where `backend = "auto"` should switch:
//! the precompute stages on the GPU and on the CPU with 2, 4, 8 and 16 worker threads
//! (`RAYON_NUM_THREADS`, as many of those as the host has). Without a GPU adapter it says so and
//! skips.
//! docs/gpu.md holds the first such figures (an NVIDIA H100).

use std::path::Path;
use std::process::Command;

use anyhow::Result;
use serde_json::Value;

use super::harness::{bench_scene, ensure_octree, pc_gpu_present, read_json};
use super::table::{machine, publish, sizes_arg, today};
use crate::{build_release, run_checked, STAGES};

/// The chain's settings, as `--only chain` has them.
const BASE: [&str; 3] = ["camera.width=512", "camera.height=512", "raytrace.spp=16"];
/// The stages with a backend key.
const DEVICE_STAGES: [&str; 4] = ["vmap", "caustics", "fmm", "raytrace"];

pub(super) fn bench(sizes: &[usize], write: bool) -> Result<()> {
    let bin = build_release(&[STAGES, &["pc-run", "pc-sample", "pc-raybench"]].concat())?;
    let mut rows = Vec::new();
    let mut shares = Vec::new();
    let mut frames = Vec::new();
    let mut sweeps = Vec::new();
    let mut adapter = String::new();
    for &n in sizes {
        let config = bench_scene(&bin, n)?;
        ensure_octree(&bin, &config)?;
        if !pc_gpu_present(&bin, &config) {
            println!("bench gpu: no GPU adapter: skipped");
            return Ok(());
        }
        adapter = gpu_name(&bin, &config);
        let scene = config.parent().unwrap();
        for (label, backend, dir) in [
            ("GPU, first pass", "gpu", "out-gpu"),
            ("GPU, again", "gpu", "out-gpu2"),
            ("CPU", "cpu", "out-cpu"),
        ] {
            let _ = std::fs::remove_dir_all(scene.join(dir));
            let (cold, v) = pass(&bin, &config, backend, dir, &[], None)?;
            let (view, _) = pass(
                &bin,
                &config,
                backend,
                dir,
                &["camera.origin=[0.4, 0.2, 3.8]"],
                None,
            )?;
            rows.push(format!(
                "| {} | {label} | {} | {cold:.1} s | {view:.2} s |",
                count(n),
                STAGES
                    .iter()
                    .map(|s| seconds(&v, s))
                    .collect::<Vec<_>>()
                    .join(" | "),
            ));
            println!("{}", rows.last().unwrap());
            if backend == "gpu" {
                for s in STAGES {
                    if let Some(g) = stage(&v, s).map(|r| &r["gpu"]).filter(|g| !g.is_null()) {
                        shares.push(share(n, label, s, g));
                    }
                }
            }
        }
        frames.push(walkthrough(&bin, &config, n)?);
        sweeps.extend(sweep(&bin, &config, n)?);
    }
    let t = table(&adapter, sizes, &rows, &shares, &frames, &sweeps);
    publish("gpu", "GPU against CPU", &t, write)
}

/// The adapter's name as pc-raybench reports it (`..., GPU <name> primary ...`).
fn gpu_name(bin: &Path, config: &Path) -> String {
    Command::new(bin.join("pc-raybench"))
        .args(["--width", "8", "--incoherent", "8", "--config"])
        .arg(config)
        .output()
        .ok()
        .and_then(|o| {
            let text = String::from_utf8_lossy(&o.stdout).into_owned();
            let at = text.find(", GPU ")? + 6;
            let end = text[at..].find(" primary")?;
            Some(text[at..at + end].to_string())
        })
        .unwrap_or_else(|| "a GPU".into())
}

/// One pc-run with every stage on `backend`, output in `dir` (with `threads` worker threads
/// when given, else the host's): its wall time and its report.
fn pass(
    bin: &Path,
    config: &Path,
    backend: &str,
    dir: &str,
    extra: &[&str],
    threads: Option<usize>,
) -> Result<(f64, Value)> {
    let report = config.with_file_name(format!("{dir}.json"));
    let mut cmd = Command::new(bin.join("pc-run"));
    if let Some(t) = threads {
        cmd.env("RAYON_NUM_THREADS", t.to_string());
    }
    cmd.arg("--quiet").arg("--config").arg(config);
    let devices = DEVICE_STAGES.map(|s| format!("{s}.backend={backend}"));
    let out = format!("output.dir={dir}");
    for s in BASE
        .iter()
        .chain(extra)
        .copied()
        .chain(devices.iter().map(String::as_str))
    {
        cmd.args(["--set", s]);
    }
    cmd.args(["--set", &out]).arg("--report").arg(&report);
    let t = std::time::Instant::now();
    run_checked(&mut cmd, "pc-run")?;
    Ok((t.elapsed().as_secs_f64(), read_json(&report)?))
}

/// The worker-thread counts of the sweep: 2, 4, 8 and 16, those the host has.
const SWEEP_THREADS: [usize; 4] = [2, 4, 8, 16];

/// The stages whose device `auto` chooses by the host's threads (pc_stage::device::Work).
const PRECOMPUTE: [&str; 3] = ["pc-vmap", "pc-caustics", "pc-fmm"];

/// Where `auto` should switch: each precompute stage on the GPU and on the CPU with each of
/// [`SWEEP_THREADS`] the host has, GPU and CPU alternating, on the first GPU pass's octree (the
/// driver's kernel cache warm). One table row per thread count.
fn sweep(bin: &Path, config: &Path, n: usize) -> Result<Vec<String>> {
    let scene = config.parent().unwrap();
    let host = std::thread::available_parallelism().map_or(1, |p| p.get());
    let mut rows = Vec::new();
    for t in SWEEP_THREADS.into_iter().filter(|&t| t <= host) {
        let mut cells = Vec::new();
        let mut sums = Vec::new();
        for backend in ["gpu", "cpu"] {
            let dir = format!("out-t{t}-{backend}");
            let _ = std::fs::remove_dir_all(scene.join(&dir));
            std::fs::create_dir_all(scene.join(&dir))?;
            std::fs::copy(
                scene.join("out-gpu/octree.pcgi"),
                scene.join(&dir).join("octree.pcgi"),
            )?;
            let (_, v) = pass(bin, config, backend, &dir, &[], Some(t))?;
            let secs: Vec<f64> = PRECOMPUTE
                .iter()
                .map(|s| {
                    stage(&v, s)
                        .and_then(|r| r["seconds"].as_f64())
                        .unwrap_or(f64::NAN)
                })
                .collect();
            cells.push(
                secs.iter()
                    .map(|x| format!("{x:.2}"))
                    .collect::<Vec<_>>()
                    .join(", "),
            );
            sums.push(secs.iter().sum::<f64>());
            let _ = std::fs::remove_dir_all(scene.join(&dir));
        }
        rows.push(format!(
            "| {} | {t} | {} s | {:.1} s | {} s | {:.1} s | {:.2}× |",
            count(n),
            cells[0],
            sums[0],
            cells[1],
            sums[1],
            sums[1] / sums[0]
        ));
        println!("{}", rows.last().unwrap());
    }
    Ok(rows)
}

/// Frames per second of 30-frame GPU walkthroughs at 512² (the seed's size) and 1024², 1 spp,
/// without the second pass over high-contrast pixels, on the first GPU pass's solution: one
/// line each, with a frame's milliseconds of dispatch and of kernel on the GPU's clock.
fn walkthrough(bin: &Path, config: &Path, n: usize) -> Result<String> {
    let mut lines = Vec::new();
    for size in [512, 1024] {
        let stats = config.with_file_name("walkthrough.json");
        let frames = config.with_file_name("frames");
        let side = size.to_string();
        run_checked(
            Command::new(bin.join("pc-raytrace"))
                .args(["--quiet", "--backend", "gpu", "--frames", "30", "--config"])
                .arg(config)
                .args(["--set", "output.dir=out-gpu"])
                .args(["--set", &format!("camera.width={side}")])
                .args(["--set", &format!("camera.height={side}")])
                .args(["--set", "raytrace.spp=1"])
                // One sample a pixel, as the seed's frame rates: no second pass over the edges.
                .args(["--set", "raytrace.refine=0"])
                .arg("--frames-dir")
                .arg(&frames)
                .arg("--stats-json")
                .arg(&stats),
            "pc-raytrace --frames",
        )?;
        let v = read_json(&stats)?;
        let _ = std::fs::remove_dir_all(&frames);
        let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
        let g = |k: &str| v["gpu_times"][k].as_f64().unwrap_or(f64::NAN);
        let frames_n = f("frames");
        lines.push(format!(
            "{} at {size}²: {:.1} frames/s rendering, {:.1} with the PNGs written; a frame's dispatch {:.2} ms, its kernel {:.2} ms on the GPU's clock",
            count(n),
            f("frames_per_second"),
            frames_n / f("frames_seconds"),
            1e3 * g("dispatch_seconds") / frames_n,
            1e3 * g("kernel_seconds") / frames_n,
        ));
    }
    Ok(lines.join("; "))
}

fn stage<'a>(v: &'a Value, name: &str) -> Option<&'a Value> {
    v.as_array()?.iter().find(|r| r["stage"] == name)
}

/// A stage's seconds in a report, or "cached".
fn seconds(v: &Value, name: &str) -> String {
    match stage(v, name) {
        Some(r) if r["status"] == "ran" => {
            format!("{:.2} s", r["seconds"].as_f64().unwrap_or(f64::NAN))
        }
        Some(_) => "cached".into(),
        None => "—".into(),
    }
}

/// One row of the GPU shares table.
fn share(n: usize, pass: &str, name: &str, g: &Value) -> String {
    let f = |k: &str| g[k].as_f64().unwrap_or(f64::NAN);
    format!(
        "| {} | {pass} | {name} | {} in {:.2} s | {:.0} MB in {:.2} s | {} in {:.2} s | {:.0} MB in {:.2} s |",
        count(n),
        f("kernels_built"),
        f("build_seconds"),
        f("upload_bytes") / 1e6,
        f("upload_seconds"),
        f("dispatches"),
        f("dispatch_seconds"),
        f("read_bytes") / 1e6,
        f("read_seconds"),
    )
}

fn count(n: usize) -> String {
    format!("{:.2}M", n as f64 / 1e6)
}

/// The tables for BENCHMARKS.md's `gpu` block.
fn table(
    adapter: &str,
    sizes: &[usize],
    rows: &[String],
    shares: &[String],
    frames: &[String],
    sweeps: &[String],
) -> String {
    format!(
        "Machine: {}; GPU: {adapter}. Date: {}. Command: `cargo xtask bench --only gpu --sizes {}`. Cornell box with a \
glass and a mirror sphere, 512×512, 16 spp, every stage on the device named (`<stage>.backend`); \
each pass in a fresh output folder, so the V-map's links are never reused. Times are each stage's \
process wall time as pc-run measured it.\n\n\
| splats | pass | {} | cold chain | new view |\n|---|---|---|---|---|---|---|---|---|\n{}\n\n\
The GPU's share of each stage (kernels built, bytes up, dispatches, bytes back; docs/gpu.md):\n\n\
| splats | pass | stage | kernels built | up | dispatches | back |\n|---|---|---|---|---|---|---|\n{}\n\n\
Walkthroughs on the GPU, 30 frames, 1 spp (`raytrace.refine = 0`): {}.\n\n\
Where `backend = \"auto\"` switches (pc_stage::device::AUTO_GPU_MAX_THREADS): pc-vmap, pc-caustics and \
pc-fmm on the GPU and on the CPU with `RAYON_NUM_THREADS` worker threads, the GPU pass's octree, seconds each:\n\n\
| splats | threads | GPU | together | CPU | together | CPU / GPU |\n|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        STAGES.join(" | "),
        rows.join("\n"),
        shares.join("\n"),
        frames.join("; "),
        sweeps.join("\n")
    )
}
