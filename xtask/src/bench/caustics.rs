//! pc-caustics: photons per second at about one million traced photons (CPU on 1 and 2
//! threads, the GPU when wgpu finds one), and the caustic lookup cost per shaded hit
//! (`--only caustics`).

use std::path::Path;
use std::process::Command;

use anyhow::Result;
use serde_json::Value;

use super::harness::{bench_scene, best_of, ensure_octree, pc_gpu_present, read_json};
use super::table::{machine, publish, sizes_arg, today};
use crate::{build_release, run_checked};

pub(super) fn bench(sizes: &[usize], runs: usize, write: bool) -> Result<()> {
    let bin = build_release(&[
        "pc-sample",
        "pc-octree",
        "pc-vmap",
        "pc-caustics",
        "pc-raybench",
    ])?;
    let mut rows = Vec::new();
    let mut lookup_rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(&bin, n)?;
        ensure_octree(&bin, &config)?;
        // Up to date V-map links are reused; only the light lists are redone.
        run_checked(
            Command::new(bin.join("pc-vmap"))
                .args(["--quiet", "--backend", "cpu", "--config"])
                .arg(&config),
            "pc-vmap",
        )?;
        trace_rows(&bin, &config, n, runs, &mut rows)?;
        // The lookup, on the map just written (the last run's).
        lookup_rows.push(lookup_row(&bin, &config, n)?);
        println!("{}", lookup_rows.last().unwrap());
    }
    publish(
        "caustics",
        "Caustic photon map (pc-caustics)",
        &table(sizes, runs, &rows, &lookup_rows),
        write,
    )
}

/// The tracing rows of one size: the budget that traces about 1M photons, then the best of
/// `runs` runs on each device (a failed run adds a "not run" row).
fn trace_rows(
    bin: &Path,
    config: &Path,
    n: usize,
    runs: usize,
    rows: &mut Vec<String>,
) -> Result<()> {
    let stats = config.parent().unwrap().join("caustics.json");
    let caustics = |backend: &str, threads: usize, budget: u64| {
        trace(bin, config, &stats, backend, threads, budget)
    };
    // The budget covers the lights' whole sphere; scale it so that about 1M are traced.
    let probe = caustics("cpu", 2, 2_000_000)?;
    let traced = probe["traced"].as_f64().unwrap_or(0.0).max(1.0);
    let budget = ((2e6 * 1e6 / traced).ceil() as u64).min(u32::MAX as u64);
    let mut devices = vec![("cpu", 1usize), ("cpu", 2)];
    if pc_gpu_present(bin, config) {
        devices.push(("gpu", 2));
    }
    for (backend, threads) in devices {
        let (best, err) = best_of(
            runs,
            |_| caustics(backend, threads, budget),
            |b, v| {
                if v["paths_per_s"].as_f64() > b["paths_per_s"].as_f64() {
                    v
                } else {
                    b
                }
            },
        );
        if let Some(e) = err {
            rows.push(format!(
                "| {:.2}M | {backend}: not run: {e:#} | | | | | |",
                n as f64 / 1e6
            ));
        }
        if let Some(v) = best {
            rows.push(trace_row(&v, n, backend, threads, budget));
            println!("{}", rows.last().unwrap());
        }
    }
    Ok(())
}

/// One pc-caustics run with `budget` photons on `backend` and `threads` threads; its
/// `--stats-json`.
fn trace(
    bin: &Path,
    config: &Path,
    stats: &Path,
    backend: &str,
    threads: usize,
    budget: u64,
) -> Result<Value> {
    run_checked(
        Command::new(bin.join("pc-caustics"))
            .env("RAYON_NUM_THREADS", threads.to_string())
            .args(["--quiet", "--backend", backend, "--config"])
            .arg(config)
            .arg("--set")
            .arg(format!("caustics.photons={budget}"))
            // The photons alone: the specular links' paths are the same tracer, timed apart.
            .arg("--set")
            .arg("caustics.specular_paths=0")
            .arg("--stats-json")
            .arg(stats),
        "pc-caustics",
    )?;
    read_json(stats)
}

fn trace_row(v: &Value, n: usize, backend: &str, threads: usize, budget: u64) -> String {
    let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    format!(
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
        f("paths_per_s") / 1e6,
    )
}

/// The caustic lookup's row of one size: pc-raybench --caustics on the photon map there.
fn lookup_row(bin: &Path, config: &Path, n: usize) -> Result<String> {
    let rays = config.parent().unwrap().join("lookups.json");
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
            .arg(config)
            .arg("--json")
            .arg(&rays),
        "pc-raybench",
    )?;
    let v = read_json(&rays)?;
    let c = &v["caustic"];
    let f = |k: &str| c[k].as_f64().unwrap_or(f64::NAN);
    Ok(format!(
        "| {:.2}M | {:.0}k | {:.4} | {:.0}k ({:.0} % near photons) | {:.0} ns | {:.0} ns (k {}) | {:.0} ns (built in {:.3} s; {:.0} groups; reads {:.1} a lookup, at most {:.0}) | {:.0} ns |",
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
        f("groups"),
        f("reads_mean"),
        f("reads_max"),
        f("lanes_ns"),
    ))
}

/// The table for BENCHMARKS.md's `caustics` block.
fn table(sizes: &[usize], runs: usize, rows: &[String], lookup_rows: &[String]) -> String {
    format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only caustics --sizes {} --runs {runs}` \
(best of {runs}). Scene: `pc-sample cornell --with-specular` (glass and mirror spheres); the budget is \
scaled so that about 1M photons are traced (the budget covers the lights' whole sphere, only photons \
aimed at light-visible specular leaves are traced). Trace time: the tracing alone (the emission plan and the tracers' setup, the leaves' roughness and surfaces, are timed apart since 2026-11-29, session 61; they were in it before).\n\n\
| splats | device | budget | traced | stored | trace | photons/s |\n|---|---|---|---|---|---|---|\n{}\n\n\
Caustic lookup per shaded hit (CPU, per thread): the diffuse hits of 512×512 primary rays from the scene \
camera, on the photon map above; fixed radius through a kd-tree (kiddo's, built before the timing: \
the grid's predecessor), k-nearest through it (the renderers' `caustic_k` path), and the hashed grid both \
renderers read for the fixed radius (dense buckets held as groups; a lookup's reads are its photons and \
groups), photon by photon as the GPU reads it and four photons at a time as the CPU renderer does \
(`photon_lanes`).\n\n\
| splats | photons | radius | lookups | kd-tree, fixed radius | kd-tree, k-nearest | hashed grid, photon by photon (the GPU's) | the grid four at a time (the CPU's) |\n|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.join("\n"),
        lookup_rows.join("\n")
    )
}
