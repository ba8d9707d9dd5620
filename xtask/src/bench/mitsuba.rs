//! `--only mitsuba`: time to an image of a given error, pcgi against Mitsuba 3 path tracing
//! the same scene on the same cores.
//!
//! For each shared reference (../shared/reference/cornell and cornell-mirror-glass): pcgi
//! renders it from its sampled points with the defaults (`pc-compare --write-config`), cold
//! (every stage) and again for a new view (pc-raytrace alone on the cached solution), and
//! pc-compare gives its per-pixel relative error against the reference. Then Mitsuba, in a
//! virtual environment of its own (target/bench/mitsuba-venv, `pip install mitsuba`), renders
//! the reference's own scene description at doubling sample counts until its error is as low
//! (xtask/peer/mitsuba_time.py). The time Mitsuba needs for exactly pcgi's error is
//! interpolated between the last two counts with error ∝ 1/√spp. Without Python, the package
//! or a libLLVM new enough for Mitsuba's LLVM backend the peer is skipped with the reason.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde_json::Value;

use super::table::{machine, publish, today};
use crate::{build_release, root, run_checked, STAGES};

/// The version the shared references were rendered with.
const MITSUBA: &str = "mitsuba==3.9.1";

/// Threads for both renderers (this machine's cores).
const THREADS: usize = 2;

pub(super) fn bench(write: bool) -> Result<()> {
    let bin = build_release(&[STAGES, &["pc-run", "pc-compare"]].concat())?;
    let python = match venv() {
        Ok(p) => p,
        Err(e) => {
            println!("bench: Mitsuba is not available ({e:#}): the peer is skipped");
            return Ok(());
        }
    };
    let mut rows = Vec::new();
    for name in ["cornell", "cornell-mirror-glass"] {
        let reference = root().join("../shared/reference").join(name);
        if !reference.exists() {
            bail!("{}: the shared reference is missing", reference.display());
        }
        let dir = root().join("target/bench/mitsuba").join(name);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        let config = dir.join("config.toml");
        run_checked(
            Command::new(bin.join("pc-compare"))
                .arg("--write-config")
                .arg(&config)
                .arg("--reference")
                .arg(&reference),
            "pc-compare --write-config",
        )?;
        // Cold: the whole chain from no artifacts; a new view: the renderer alone on them.
        let stage = |name: &str| {
            timed(
                Command::new(bin.join(name))
                    .args(["-q", "--config"])
                    .arg(&config),
                name,
            )
        };
        let cold = stage("pc-run")?;
        let new_view = stage("pc-raytrace")?;
        let image = dir.join("image.exr");
        let error = pcgi_error(&bin, &image, &reference)?;
        let peer = run_peer(&python, &reference, error, &image)?;
        let row = row(name, error, cold, new_view, &peer);
        println!("{row}");
        rows.push(row);
    }
    let table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only mitsuba`. pcgi: the shared reference's \
100k sampled points with every default (`pc-compare --write-config`), 256×256; cold = the whole chain from no \
artifacts (`pc-run`), new view = pc-raytrace alone on the cached solution. Mitsuba: the reference's own scene \
description (the exact shapes, `path` integrator, max depth 64), `llvm_ad_rgb` on {THREADS} threads, passes of at \
most 256 spp at doubling counts until its per-pixel relative error against the reference is at most pcgi's; \
Mitsuba's time for exactly pcgi's error is interpolated between the last two counts (error ∝ 1/√spp; kernel \
compilation excluded). Error: sqrt(mean(((x − ref) / (|ref| + 0.01·mean(ref)))²)) over all pixels and channels.\n\n\
| reference | pcgi error | pcgi cold | pcgi new view | Mitsuba spp at that error | Mitsuba time | cold / Mitsuba | Mitsuba / new view |\n\
|---|---|---|---|---|---|---|---|\n{}\n",
        machine(),
        today(),
        rows.join("\n")
    );
    publish(
        "mitsuba",
        "Time to an image against Mitsuba 3",
        &table,
        write,
    )
}

/// The virtual environment's Python with Mitsuba installed (made on first use).
fn venv() -> Result<PathBuf> {
    let dir = root().join("target/bench/mitsuba-venv");
    let python = dir.join("bin/python");
    if !python.exists() {
        run_checked(
            Command::new("python3").args(["-m", "venv"]).arg(&dir),
            "python3 -m venv",
        )?;
    }
    let ok = Command::new(&python)
        .args(["-c", "import mitsuba, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        run_checked(
            Command::new(&python).args(["-m", "pip", "install", "--quiet", MITSUBA, "numpy"]),
            "pip install mitsuba",
        )?;
    }
    Ok(python)
}

/// Wall seconds of a command that must succeed.
fn timed(cmd: &mut Command, what: &str) -> Result<f64> {
    let t = std::time::Instant::now();
    run_checked(cmd, what)?;
    Ok(t.elapsed().as_secs_f64())
}

/// pc-compare's whole-image per-pixel relative error of `image` against the reference.
fn pcgi_error(bin: &Path, image: &Path, reference: &Path) -> Result<f64> {
    let out = Command::new(bin.join("pc-compare"))
        .arg(image)
        .arg("--reference")
        .arg(reference)
        .output()
        .context("starting pc-compare")?;
    let text = String::from_utf8_lossy(&out.stdout);
    let key = "per-pixel relative error: ";
    text.lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .with_context(|| format!("pc-compare printed no `{key}` line:\n{text}"))
}

/// The Mitsuba harness's JSON for pcgi's error.
fn run_peer(python: &Path, reference: &Path, error: f64, image: &Path) -> Result<Value> {
    let out = Command::new(python)
        .arg(root().join("xtask/peer/mitsuba_time.py"))
        .arg(reference)
        .arg(error.to_string())
        .arg(THREADS.to_string())
        .arg(image)
        .output()
        .context("starting the Mitsuba harness")?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let hint = if err.contains("LLVM") {
            " (Mitsuba's LLVM backend needs libLLVM 16 or newer; Debian: apt install libllvm19)"
        } else {
            ""
        };
        bail!(
            "the Mitsuba harness failed ({}){hint}: {}",
            out.status,
            err.lines().last().unwrap_or("")
        );
    }
    let line = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(line.lines().last().unwrap_or("")).context("the Mitsuba harness's JSON")
}

/// One table row; Mitsuba's time at pcgi's error interpolated between its last two steps.
fn row(name: &str, error: f64, cold: f64, new_view: f64, peer: &Value) -> String {
    let steps: Vec<(f64, f64, f64)> = peer["steps"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|s| {
                    let f = |k: &str| s[k].as_f64().unwrap_or(f64::NAN);
                    (f("spp"), f("seconds"), f("error"))
                })
                .collect()
        })
        .unwrap_or_default();
    let reached = peer["reached"].as_bool().unwrap_or(false);
    let (spp, secs) = match steps.as_slice() {
        [.., (s0, t0, e0), (s1, t1, _)] if reached => {
            // spp where a 1/√spp curve through the previous step meets pcgi's error, and the time
            // at the last step's rate (seconds per spp past the previous step).
            let spp = (s0 * (e0 / error).powi(2)).clamp(*s0, *s1);
            (spp, t0 + (t1 - t0) * (spp - s0) / (s1 - s0))
        }
        [(s, t, _)] if reached => (*s, *t),
        [.., (s, t, _)] => (*s, *t),
        [] => (f64::NAN, f64::NAN),
    };
    let note = if reached { "" } else { " (not reached)" };
    format!(
        "| {name} | {error:.4} | {cold:.2} s | {new_view:.2} s | {spp:.0}{note} | {secs:.2} s | {:.2} | {:.1} |",
        cold / secs,
        secs / new_view
    )
}
