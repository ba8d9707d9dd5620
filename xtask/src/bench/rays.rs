//! Ray traversal through pc-raybench: primary and incoherent rays on the CPU (best of N runs on
//! 1 and 2 threads) and once per size on the GPU (`--only rays`).

use std::path::Path;
use std::process::Command;

use anyhow::Result;
use serde_json::Value;

use super::harness::{bench_scene, best_of, ensure_octree, read_json};
use super::table::{machine, sizes_arg, today};
use crate::run_checked;

/// One row per size and thread count (each printed as it comes).
pub(super) fn rows(bin: &Path, sizes: &[usize], runs: usize) -> Result<Vec<String>> {
    let mut rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(bin, n)?;
        let stats = config.parent().unwrap().join("rays.json");
        // The octree the ray benchmark reads.
        ensure_octree(bin, &config)?;
        for threads in [1usize, 2] {
            // The GPU is measured once per size (it does not depend on CPU threads).
            let (best, err) = best_of(
                runs,
                |run| cast(bin, &config, &stats, threads, threads != 2 || run > 0),
                keep,
            );
            if let Some(e) = err {
                return Err(e);
            }
            rows.push(row(&best.unwrap(), threads));
            println!("{}", rows.last().unwrap());
        }
    }
    Ok(rows)
}

/// One pc-raybench run on `threads` threads; its `--json`.
fn cast(bin: &Path, config: &Path, stats: &Path, threads: usize, cpu_only: bool) -> Result<Value> {
    let mut cmd = Command::new(bin.join("pc-raybench"));
    cmd.env("RAYON_NUM_THREADS", threads.to_string())
        .arg("--config")
        .arg(config)
        .arg("--json")
        .arg(stats);
    if cpu_only {
        cmd.arg("--cpu-only");
    }
    run_checked(&mut cmd, "pc-raybench")?;
    read_json(stats)
}

/// The faster CPU run, with the GPU's result of whichever run measured it.
fn keep(best: Value, v: Value) -> Value {
    let keep_gpu = Some(best["gpu"].clone()).filter(|g| !g.is_null());
    let better = v["cpu_primary_rays_per_s"].as_f64() > best["cpu_primary_rays_per_s"].as_f64();
    let mut chosen = if better { v } else { best };
    if chosen["gpu"].is_null() {
        if let Some(g) = keep_gpu {
            chosen["gpu"] = g;
        }
    }
    chosen
}

fn row(v: &Value, threads: usize) -> String {
    let m = |k: &str| v[k].as_f64().unwrap_or(f64::NAN) / 1e6;
    let gpu = &v["gpu"];
    let gpu = if gpu.is_null() {
        "—".to_string()
    } else if let Some(e) = gpu["error"].as_str() {
        format!("not run on {}: {e}", gpu["device"].as_str().unwrap_or("?"))
    } else {
        let g = |k: &str| gpu[k].as_f64().unwrap_or(f64::NAN) / 1e6;
        format!(
            "{:.2} / {:.2} M/s ({:.1} / {:.1} M/s in the kernels) on {}",
            g("primary_rays_per_s"),
            g("incoherent_rays_per_s"),
            g("primary_kernel_rays_per_s"),
            g("incoherent_kernel_rays_per_s"),
            gpu["device"].as_str().unwrap_or("?")
        )
    };
    format!(
        "| {:.2}M | {threads} | {:.2} M/s | {:.2} M/s | {gpu} |",
        v["splats"].as_f64().unwrap_or(0.0) / 1e6,
        m("cpu_primary_rays_per_s"),
        m("cpu_incoherent_rays_per_s"),
    )
}

/// The table for BENCHMARKS.md's `rays` block.
pub(super) fn table(sizes: &[usize], runs: usize, rows: &[String]) -> String {
    format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --sizes {} --runs {runs} --only rays` (best of {runs}). \
Primary rays: one per pixel centre of a 1024×1024 view from the scene camera. Incoherent rays: from random splats, \
cosine-distributed about their normals (diffuse bounce rays). GPU: rays uploaded, cast, hits read back, and in \
parentheses per second of the kernels alone (no GPU is lent to this machine; a software adapter, when present, is \
listed as such).\n\n\
| splats | CPU threads | CPU primary | CPU incoherent | GPU primary / incoherent |\n|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.join("\n")
    )
}
