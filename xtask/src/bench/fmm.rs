//! The radiosity solve of pc-fmm on the bench scenes (after pc-octree, pc-vmap and
//! pc-caustics): the best of `runs` runs on the CPU, and one on the GPU when wgpu finds one
//! (llvmpipe refuses plans beyond its loop limit: the row says so). Times are pc-fmm's own, from
//! the artifact's metadata (`pc-inspect --metadata`). `--only fmm`.

use std::path::Path;
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde_json::Value;

use super::harness::{bench_scene, best_of, pc_gpu_present};
use super::table::{machine, publish, sizes_arg, today};
use crate::{build_release, run_checked};

pub(super) fn bench(sizes: &[usize], runs: usize, write: bool) -> Result<()> {
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
        // The inputs, made or found up to date.
        for stage in ["pc-octree", "pc-vmap", "pc-caustics"] {
            run_checked(
                Command::new(bin.join(stage))
                    .args(["--quiet", "--if-stale", "--config"])
                    .arg(&config),
                stage,
            )?;
        }
        let mut backends = vec!["cpu"];
        if pc_gpu_present(&bin, &config) {
            backends.push("gpu");
        }
        for backend in backends {
            let tries = if backend == "cpu" { runs } else { 1 };
            let (best, err) = best_of(
                tries,
                |_| solve(&bin, &config, backend).map(|v| (total(&v), v)),
                |b, v| if v.0 < b.0 { v } else { b },
            );
            if let Some(e) = err {
                rows.push(format!(
                    "| {:.2}M | {backend}: not run: {e:#} | | | | | | | | |",
                    n as f64 / 1e6
                ));
            }
            let Some((total, v)) = best else { continue };
            rows.push(row(&v, n, backend, total));
            println!("{}", rows.last().unwrap());
        }
    }
    publish(
        "fmm",
        "Radiosity solve (pc-fmm)",
        &table(sizes, runs, &rows),
        write,
    )
}

/// One pc-fmm run on `backend`; the radiosity artifact's metadata (pc-inspect --metadata).
fn solve(bin: &Path, config: &Path, backend: &str) -> Result<Value> {
    let run = Command::new(bin.join("pc-fmm"))
        .args(["--quiet", "--backend", backend, "--config"])
        .arg(config)
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
        .arg(config.parent().unwrap().join("out/radiosity.pcgi"))
        .output()
        .context("starting pc-inspect")?;
    let text = String::from_utf8_lossy(&out.stdout);
    let json = text
        .find("\n{")
        .map(|i| &text[i + 1..])
        .context("pc-inspect printed no metadata")?;
    Ok(serde_json::from_str(json)?)
}

/// The phases' total (not the per-iteration mean, also listed).
fn total(v: &Value) -> f64 {
    v["timings"]
        .as_array()
        .map(|t| {
            t.iter()
                .filter(|x| x[0] != "per iteration")
                .filter_map(|x| x[1].as_f64())
                .sum()
        })
        .unwrap_or(f64::NAN)
}

fn row(v: &Value, n: usize, backend: &str, total: f64) -> String {
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
    format!(
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
    )
}

/// The table for BENCHMARKS.md's `fmm` block.
fn table(sizes: &[usize], runs: usize, rows: &[String]) -> String {
    format!(
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
    )
}
