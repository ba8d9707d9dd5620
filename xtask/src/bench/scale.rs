//! The whole chain on virtual scans of the hall (`pc-sample scan`, LAZ) at each size, cold,
//! through pc-bake: every stage's time and peak memory, and both per point of the scan, so
//! that growth faster than N shows. `--only scale` (default sizes 1M, 4M, 20M).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result};
use serde_json::Value;

use super::harness::read_json;
use super::table::{machine, publish, sizes_arg, today};
use crate::{build_release, root, run_checked, STAGES};

pub(super) fn bench(sizes: &[usize], write: bool) -> Result<()> {
    let bin = build_release(&[STAGES, &["pc-run", "pc-sample", "pc-bake"]].concat())?;
    let mut rows = Vec::new();
    for &n in sizes {
        let config = scan(&bin, n)?;
        let scene = config.parent().context("a scan lies in a folder")?;
        let _ = std::fs::remove_dir_all(scene.join("out"));
        let report = scene.join("scale.json");
        let t = std::time::Instant::now();
        run_checked(
            Command::new(bin.join("pc-run"))
                .args(["--quiet", "--until", "pc-bake", "--config"])
                .arg(&config)
                .arg("--report")
                .arg(&report),
            "pc-run",
        )?;
        let cold = t.elapsed().as_secs_f64();
        let v = read_json(&report)?;
        let cells: Vec<String> = STAGES
            .iter()
            .chain(&["pc-bake"])
            .map(|s| cell(&v, s, n))
            .collect();
        let peak = stages(&v)
            .map(|r| r["peak_rss_bytes"].as_f64().unwrap_or(0.0))
            .fold(0.0, f64::max);
        rows.push(format!(
            "| {} | {cold:.0} s ({:.0} µs/point) | {:.1} GB | {} |",
            count(n),
            cold / n as f64 * 1e6,
            peak / 1e9,
            cells.join(" | ")
        ));
        println!("{}", rows.last().unwrap());
    }
    publish("scale", "Scale: virtual scans", &table(sizes, &rows), write)
}

/// The virtual scan of `n` points under target/bench (made once): its scene.toml.
fn scan(bin: &Path, n: usize) -> Result<PathBuf> {
    let dir = root().join("target/bench").join(format!("scan-{n}"));
    let config = dir.join("scene.toml");
    if !config.exists() {
        run_checked(
            Command::new(bin.join("pc-sample"))
                .args(["scan", "--format", "laz", "-n", &n.to_string(), "-o"])
                .arg(&dir),
            "pc-sample",
        )?;
    }
    Ok(config)
}

fn stages(v: &Value) -> impl Iterator<Item = &Value> {
    v.as_array().into_iter().flatten()
}

/// One stage's time and peak memory, absolute and per point of the scan.
fn cell(v: &Value, stage: &str, n: usize) -> String {
    let Some(r) = stages(v).find(|r| r["stage"] == stage) else {
        return "—".to_string();
    };
    let s = r["seconds"].as_f64().unwrap_or(f64::NAN);
    let m = r["peak_rss_bytes"].as_f64().unwrap_or(f64::NAN);
    format!(
        "{s:.1} s, {:.2} GB ({:.1} µs, {:.0} B per point)",
        m / 1e9,
        s / n as f64 * 1e6,
        m / n as f64
    )
}

fn count(n: usize) -> String {
    match n {
        n if n >= 1_000_000 => format!("{}M", n as f64 / 1e6),
        n => format!("{}k", n as f64 / 1e3),
    }
}

/// The table for BENCHMARKS.md's `scale` block.
fn table(sizes: &[usize], rows: &[String]) -> String {
    format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only scale --sizes {}`. The virtual \
scan of the hall (`pc-sample scan --format laz`: 3 stations, sun through a skylight and a lamp), \
cold, through pc-bake, stage defaults (the CPU here). Each stage: its process's wall time and \
peak resident memory (VmHWM), then both per point of the scan (the import merges returns closer \
than the scanner's range noise, so a scan makes fewer splats than it has points). Aims: every \
stage's peak at most 16 GiB at 20M, time per point flat or falling.\n\n\
| points | cold | peak | pc-octree | pc-vmap | pc-caustics | pc-fmm | pc-raytrace | pc-bake |\n\
|---|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.join("\n")
    )
}
