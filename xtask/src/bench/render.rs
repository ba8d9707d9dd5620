//! The CPU renderer's rate on the default scene (`pipeline.toml`, 512×512 at 16 spp with its
//! refined pixels): camera samples per second of pc-raytrace's render, the median of `runs`
//! runs on the cached solution, with the chain made first when it is not there. `--only render`
//! (issue 24's target: 10M camera samples per second on two cores).

use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result};
use serde_json::Value;

use super::harness::read_json;
use super::table::{machine, publish, today};
use crate::{build_release, root, run_checked, STAGES};

/// Where the bench keeps the default scene's artifacts (not `out/default`, the user's).
const OUT: &str = "target/bench/render";

pub(super) fn bench(runs: usize, write: bool) -> Result<()> {
    let bin = build_release(&[STAGES, &["pc-run"]].concat())?;
    let config = root().join("pipeline.toml");
    let out = root().join(OUT);
    let dir = format!("output.dir={}", out.display());
    let mut chain = Command::new(bin.join("pc-run"));
    chain.args(["--quiet", "--config"]).arg(&config).args([
        "--set",
        &dir,
        "--set",
        "raytrace.backend=cpu",
    ]);
    run_checked(&mut chain, "pc-run")?;
    let stats = out.join("render.json");
    let mut samples_per_s = Vec::new();
    let mut last = Value::Null;
    for _ in 0..runs {
        last = render(&bin, &config, &dir, &stats)?;
        let samples = number(&last, "camera_samples")?;
        let seconds = number(&last, "render_seconds")?;
        samples_per_s.push(samples / seconds);
        println!(
            "render: {:.0} camera samples in {seconds:.3} s, {:.2}M samples/s",
            samples,
            samples / seconds / 1e6
        );
    }
    samples_per_s.sort_by(f64::total_cmp);
    let median = samples_per_s[samples_per_s.len() / 2];
    let row = format!(
        "| {}×{}, {} spp, {} pixels refined at {} | {:.2}M | {:.2}-{:.2}M | {} |",
        last["width"],
        last["height"],
        last["spp"],
        last["refined"],
        last["refine_spp"],
        median / 1e6,
        samples_per_s[0] / 1e6,
        samples_per_s[samples_per_s.len() - 1] / 1e6,
        last["device"].as_str().unwrap_or("?"),
    );
    publish(
        "render",
        "The CPU renderer's rate",
        &table(runs, &row),
        write,
    )
}

/// One render of the cached solution on the CPU: its `--stats-json`.
fn render(bin: &Path, config: &Path, dir: &str, stats: &Path) -> Result<Value> {
    let mut cmd = Command::new(bin.join("pc-raytrace"));
    cmd.args(["--quiet", "--config"])
        .arg(config)
        .args([
            "--set",
            dir,
            "--set",
            "raytrace.backend=cpu",
            "--stats-json",
        ])
        .arg(stats);
    run_checked(&mut cmd, "pc-raytrace")?;
    read_json(stats)
}

/// A number of pc-raytrace's stats.
fn number(v: &Value, key: &str) -> Result<f64> {
    v[key]
        .as_f64()
        .with_context(|| format!("pc-raytrace's stats have no `{key}`: {v}"))
}

/// The table for BENCHMARKS.md's `render` block.
fn table(runs: usize, row: &str) -> String {
    format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only render --runs {runs}`. The default \
scene (`pipeline.toml`: the Cornell box with a glass and a mirror sphere, 100k splats) on its cached \
solution; pc-raytrace on the CPU, every setting its default. Camera samples: every pixel's spp and the \
refined pixels' second pass (a sample split at glass counts once); the time is the render's, as \
pc-raytrace reports it (the scene's loading and the image's writing apart). Median of {runs} runs. Aim \
(issue 24): 10M samples/s.\n\n\
| image | samples/s (median) | range | device |\n|---|---|---|---|\n{row}\n",
        machine(),
        today(),
    )
}
