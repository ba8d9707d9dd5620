//! What the benchmarks share to run the stages: the bench scenes, the octree they read, the
//! JSON the stages write, the best of several runs, and whether a GPU is there.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Result;

use crate::{root, run_checked};

/// Sample `pc-sample cornell --with-specular` at `n` points under target/bench (once) and write
/// its bench.toml; returns the config path.
pub(super) fn bench_scene(bin: &Path, n: usize) -> Result<PathBuf> {
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

/// Run pc-octree on a bench scene's config unless its octree (`out/octree.pcgi`) is there.
pub(super) fn ensure_octree(bin: &Path, config: &Path) -> Result<()> {
    let scene = config.parent().unwrap();
    if scene.join("out/octree.pcgi").exists() {
        return Ok(());
    }
    run_checked(
        Command::new(bin.join("pc-octree"))
            .arg("--quiet")
            .arg("--config")
            .arg(config),
        "pc-octree",
    )
}

/// A JSON file a stage wrote (`--stats-json`, `--json`, `--report`).
pub(super) fn read_json(path: &Path) -> Result<serde_json::Value> {
    Ok(serde_json::from_str(&std::fs::read_to_string(path)?)?)
}

/// Run `once` (given the run's index) `runs` times and fold the results with `keep(best, new)`,
/// which returns the one to keep. Stops at the first error and returns it with the best so far.
pub(super) fn best_of<T>(
    runs: usize,
    mut once: impl FnMut(usize) -> Result<T>,
    keep: impl Fn(T, T) -> T,
) -> (Option<T>, Option<anyhow::Error>) {
    let mut best = None;
    for run in 0..runs {
        match once(run) {
            Ok(v) => {
                best = Some(match best.take() {
                    Some(b) => keep(b, v),
                    None => v,
                })
            }
            Err(e) => return (best, Some(e)),
        }
    }
    (best, None)
}

/// Whether wgpu finds any adapter (pc-raybench's GPU pass says so without --cpu-only).
pub(super) fn pc_gpu_present(bin: &Path, config: &Path) -> bool {
    Command::new(bin.join("pc-raybench"))
        .args(["--width", "8", "--incoherent", "8", "--config"])
        .arg(config)
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).contains(", GPU "))
        .unwrap_or(false)
}
