//! pc-octree's build: the best of N runs on 1 and 2 threads at each size (`--only octree`).

use std::path::Path;
use std::process::Command;

use anyhow::Result;
use serde_json::Value;

use super::harness::{bench_scene, best_of, read_json};
use super::table::{machine, sizes_arg, today};
use crate::run_checked;

/// One row per size and thread count (each printed as it comes).
pub(super) fn rows(bin: &Path, sizes: &[usize], runs: usize) -> Result<Vec<String>> {
    let mut rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(bin, n)?;
        let stats = config.parent().unwrap().join("stats.json");
        for threads in [1usize, 2] {
            let (best, err) = best_of(
                runs,
                |_| build(bin, &config, &stats, threads),
                |b, v| {
                    if v["total_seconds"].as_f64() < b["total_seconds"].as_f64() {
                        v
                    } else {
                        b
                    }
                },
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

/// One pc-octree run on `threads` threads; its `--stats-json`.
pub(super) fn build(bin: &Path, config: &Path, stats: &Path, threads: usize) -> Result<Value> {
    run_checked(
        Command::new(bin.join("pc-octree"))
            .env("RAYON_NUM_THREADS", threads.to_string())
            .arg("--quiet")
            .arg("--config")
            .arg(config)
            .arg("--stats-json")
            .arg(stats),
        "pc-octree",
    )?;
    read_json(stats)
}

fn row(v: &Value, threads: usize) -> String {
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
    format!(
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
    )
}

/// The table for BENCHMARKS.md's `octree` block.
pub(super) fn table(sizes: &[usize], runs: usize, rows: &[String]) -> String {
    format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --sizes {} --runs {runs}` (best of {runs}).\n\n\
| splats | threads | build | build rate | PLY import | total (import+build+write) | end-to-end rate | peak memory | build phases (s) |\n\
|---|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.join("\n")
    )
}
