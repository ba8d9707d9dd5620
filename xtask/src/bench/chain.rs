//! The whole chain through pc-run on the Cornell box with a glass and a mirror sphere at each
//! size, 512×512 at 16 samples per pixel: cold (no artifacts), then a new camera on the cached
//! solution (only pc-raytrace runs). `--only chain`.

use std::path::Path;
use std::process::Command;

use anyhow::Result;
use serde_json::Value;

use super::harness::{bench_scene, read_json};
use super::table::{machine, publish, sizes_arg, today};
use crate::{build_release, run_checked, STAGES};

/// The settings of every pass (on top of the bench scene's config).
const BASE: [&str; 4] = [
    "output.dir=out-chain",
    "camera.width=512",
    "camera.height=512",
    "raytrace.spp=16",
];

pub(super) fn bench(sizes: &[usize], write: bool) -> Result<()> {
    let bin = build_release(&[STAGES, &["pc-run", "pc-sample"]].concat())?;
    let mut rows = Vec::new();
    for &n in sizes {
        let config = bench_scene(&bin, n)?;
        let scene = config.parent().unwrap();
        let _ = std::fs::remove_dir_all(scene.join("out-chain"));
        let report = scene.join("chain.json");
        let (cold, v) = pass(&bin, &config, &report, &[])?;
        let (view, w) = pass(&bin, &config, &report, &["camera.origin=[0.4, 0.2, 3.8]"])?;
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
    publish(
        "chain",
        "The whole chain (cargo xtask run)",
        &table(sizes, &rows),
        write,
    )
}

/// One pc-run with [`BASE`] and `extra` settings: its wall time and its `--report`.
fn pass(bin: &Path, config: &Path, report: &Path, extra: &[&str]) -> Result<(f64, Value)> {
    let mut cmd = Command::new(bin.join("pc-run"));
    cmd.arg("--quiet").arg("--config").arg(config);
    for s in BASE.iter().chain(extra) {
        cmd.args(["--set", s]);
    }
    cmd.arg("--report").arg(report);
    let t = std::time::Instant::now();
    run_checked(&mut cmd, "pc-run")?;
    let secs = t.elapsed().as_secs_f64();
    Ok((secs, read_json(report)?))
}

/// A stage's time in a pc-run report: its seconds when it ran, else "cached".
fn stage_time(v: &Value, stage: &str) -> String {
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
}

/// The table for BENCHMARKS.md's `chain` block.
fn table(sizes: &[usize], rows: &[String]) -> String {
    format!(
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
    )
}
