//! `--only rays --peer embree`: the same rays traced by pcgi and by Embree in one run.
//!
//! pc-raybench writes the bench scene's disks, its primary and incoherent rays and its own first
//! hits (`--dump`); a small C harness (xtask/peer/embree_rays.c, built here against Debian's
//! `libembree-dev`, dev-only) builds Embree's BVH over the same disks as oriented discs and
//! traces the same rays. Runs alternate pcgi, Embree, pcgi, ... and each figure is the median,
//! since absolute times on a shared machine drift between runs; the table gives the ratios.
//! Without the library the peer is skipped with a message.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use serde_json::Value;

use super::harness::{bench_scene, ensure_octree, read_json};
use super::table::{machine, publish, sizes_arg, today};
use crate::{root, run_checked};

/// Build the Embree harness; `None` (with the reason printed) when Embree is not installed.
pub(super) fn build_harness() -> Result<Option<PathBuf>> {
    let header = Path::new("/usr/include/embree3/rtcore.h");
    if !header.exists() {
        println!(
            "bench: Embree is not installed ({} is missing; Debian: apt install libembree-dev): \
             the peer is skipped",
            header.display()
        );
        return Ok(None);
    }
    let out = root().join("target/bench/peer");
    std::fs::create_dir_all(&out)?;
    let exe = out.join("embree_rays");
    let status = Command::new("cc")
        .args(["-O3", "-o"])
        .arg(&exe)
        .arg(root().join("xtask/peer/embree_rays.c"))
        .args(["-lembree3", "-lpthread", "-lm"])
        .status()
        .context("starting cc for the Embree harness")?;
    if !status.success() {
        bail!("building the Embree harness (xtask/peer/embree_rays.c) failed ({status})");
    }
    Ok(Some(exe))
}

/// The measured figures of one size and thread count (medians over the runs).
struct Row {
    splats: f64,
    threads: usize,
    /// pcgi and Embree: primary, incoherent and shadow rays/s, build seconds, and pcgi's
    /// primary rays from their pixel's bound (Embree: its primary rays again).
    pcgi: [f64; 5],
    embree: [f64; 5],
}

/// Rows for every size on 1 and 2 threads, and the first-hit agreement line of each size.
pub(super) fn bench(
    bin: &Path,
    harness: &Path,
    sizes: &[usize],
    runs: usize,
    write: bool,
) -> Result<()> {
    let mut rows = Vec::new();
    let mut agreement = Vec::new();
    let mut peer = String::new();
    for &n in sizes {
        let config = bench_scene(bin, n)?;
        let scene = config.parent().unwrap();
        ensure_octree(bin, &config)?;
        let dump = scene.join("peer");
        raybench(bin, &config, &scene.join("rays.json"), 2, Some(&dump))?;
        for threads in [1usize, 2] {
            let (mut p, mut e) = (Vec::new(), Vec::new());
            for _ in 0..runs {
                let v = raybench(bin, &config, &scene.join("rays.json"), threads, None)?;
                let o = super::octree::build(bin, &config, &scene.join("stats.json"), threads)?;
                p.push([
                    num(&v, "cpu_primary_rays_per_s"),
                    num(&v, "cpu_incoherent_rays_per_s"),
                    num(&v, "cpu_shadow_rays_per_s"),
                    num(&o, "build_seconds"),
                    num(&v, "cpu_bounded_primary_rays_per_s"),
                ]);
                let v = embree(harness, &dump, threads)?;
                peer = v["peer"].as_str().unwrap_or("Embree").to_string();
                e.push([
                    num(&v, "primary_rays_per_s"),
                    num(&v, "incoherent_rays_per_s"),
                    num(&v, "shadow_rays_per_s"),
                    num(&v, "build_s"),
                    num(&v, "primary_rays_per_s"),
                ]);
            }
            let row = Row {
                splats: n as f64,
                threads,
                pcgi: medians(&p),
                embree: medians(&e),
            };
            println!("{}", row.line());
            rows.push(row);
        }
        agreement.push(first_hits(&dump, n)?);
        println!("{}", agreement.last().unwrap());
    }
    let table = format!(
        "Machine: {}. Date: {}. Command: `cargo xtask bench --only rays --peer embree --sizes {} --runs {runs}` \
(medians of {runs} alternating runs). Peer: {peer} (Debian's libembree-dev), oriented-disc primitives over the same \
disks, `rtcIntersect1` on the same rays, threads handed chunks of 4096 rays; pcgi: pc-raybench's CPU traversal \
(the renderer's). Primary rays: one per pixel centre of a 1024×1024 view from the scene camera; incoherent rays: \
from random splats, cosine-distributed about their normals; shadow rays: segments between two random splats \
facing each other, any hit (`rtcOccluded1`; pcgi: `Accel::visible`, the V-map's caster). Build: pc-octree's \
build including the splat areas and border clips (import excluded) against Embree's scene commit. Camera \
rays: the primary rays as pcgi's CPU renderer casts them, each from its pixel's bound (docs/raytrace.md, \
\"Camera rays start near their surface\"; the bounds' pass over every splat timed with them, the same hits), \
against Embree's primary rays (which could be given such bounds too; its single-ray API has none). Each cell: \
pcgi / Embree (ratio; above 1 pcgi is faster).\n\n\
| splats | threads | primary rays | incoherent rays | shadow rays | build | camera rays from their pixel's bound |\n\
|---|---|---|---|---|---|---|\n{}\n\n{}\n",
        machine(),
        today(),
        sizes_arg(sizes),
        rows.iter().map(Row::line).collect::<Vec<_>>().join("\n"),
        agreement.join("\n\n")
    );
    publish(
        "peer-rays",
        "Ray casting against Embree (`--peer embree`)",
        &table,
        write,
    )
}

impl Row {
    fn line(&self) -> String {
        let (p, e) = (self.pcgi, self.embree);
        let rate = |k: usize| {
            format!(
                "{:.2} / {:.2} M/s ({:.2})",
                p[k] / 1e6,
                e[k] / 1e6,
                p[k] / e[k]
            )
        };
        format!(
            "| {:.2}M | {} | {} | {} | {} | {:.2} / {:.2} s ({:.2}) | {} |",
            self.splats / 1e6,
            self.threads,
            rate(0),
            rate(1),
            rate(2),
            p[3],
            e[3],
            e[3] / p[3],
            rate(4),
        )
    }
}

fn num(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or(f64::NAN)
}

/// Per column, the median of the runs.
fn medians<const N: usize>(runs: &[[f64; N]]) -> [f64; N] {
    std::array::from_fn(|k| {
        let mut c: Vec<f64> = runs.iter().map(|r| r[k]).collect();
        c.sort_by(f64::total_cmp);
        let m = c.len() / 2;
        if c.len() % 2 == 1 {
            c[m]
        } else {
            0.5 * (c[m - 1] + c[m])
        }
    })
}

/// One pc-raybench CPU run on `threads` threads (with `dump`, also writing the peer's input).
fn raybench(
    bin: &Path,
    config: &Path,
    json: &Path,
    threads: usize,
    dump: Option<&Path>,
) -> Result<Value> {
    let mut cmd = Command::new(bin.join("pc-raybench"));
    cmd.env("RAYON_NUM_THREADS", threads.to_string())
        .arg("--config")
        .arg(config)
        .arg("--cpu-only")
        .arg("--json")
        .arg(json);
    if let Some(d) = dump {
        cmd.arg("--dump").arg(d);
    }
    run_checked(&mut cmd, "pc-raybench")?;
    read_json(json)
}

/// One harness run; its JSON line.
fn embree(harness: &Path, dump: &Path, threads: usize) -> Result<Value> {
    let out = Command::new(harness)
        .arg(dump)
        .arg(threads.to_string())
        .output()
        .context("starting the Embree harness")?;
    if !out.status.success() {
        bail!(
            "the Embree harness failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    serde_json::from_slice(&out.stdout).context("the Embree harness's JSON line")
}

/// Reads `name` (f32 pairs: distance, index bits) from the dump folder.
fn hits(dump: &Path, name: &str) -> Result<Vec<(f32, u32)>> {
    let path = dump.join(name);
    let bytes = std::fs::read(&path).with_context(|| path.display().to_string())?;
    Ok(bytes
        .chunks_exact(8)
        .map(|c| {
            let t = f32::from_le_bytes(c[0..4].try_into().unwrap());
            (t, u32::from_le_bytes(c[4..8].try_into().unwrap()))
        })
        .collect())
}

/// Whether pcgi's and Embree's first hits agree, per ray set: both miss, or both hit within
/// 10⁻⁴ of the distance (the two disk tests round differently). Differences are counted
/// apart where either hit disk is border-clipped (pcgi clips it, Embree's disc is whole).
fn first_hits(dump: &Path, n: usize) -> Result<String> {
    let disks = std::fs::read(dump.join("disks.f32"))?;
    let clipped = |i: u32| -> bool {
        let o = 32 * i as usize + 28;
        i != u32::MAX
            && disks
                .get(o..o + 4)
                .is_some_and(|b| f32::from_le_bytes(b.try_into().unwrap()) > 0.0)
    };
    let mut parts = Vec::new();
    for set in ["primary", "incoherent"] {
        let (a, b) = (
            hits(dump, &format!("{set}.pcgi"))?,
            hits(dump, &format!("{set}.embree"))?,
        );
        if a.len() != b.len() {
            bail!(
                "{}: {set}: pcgi has {} rays, Embree {}",
                dump.display(),
                a.len(),
                b.len()
            );
        }
        let (mut differ, mut at_clip, mut pcgi_nearer, mut pcgi_misses) =
            (0usize, 0usize, 0usize, 0usize);
        for (&(ta, ia), &(tb, ib)) in a.iter().zip(&b) {
            let agree = (ta.is_infinite() && tb.is_infinite())
                || (ta - tb).abs() <= 1e-4 * ta.abs().max(1e-3);
            if !agree {
                differ += 1;
                at_clip += (clipped(ia) || clipped(ib)) as usize;
                pcgi_nearer += (ta < tb) as usize;
                pcgi_misses += (ta.is_infinite() && tb.is_finite()) as usize;
            }
        }
        parts.push(format!(
            "{set} rays: {:.3} % agree ({differ} of {} differ: {at_clip} of them at a border-clipped disk, \
             pcgi nearer on {pcgi_nearer}, pcgi missing Embree's hit on {pcgi_misses})",
            100.0 * (a.len() - differ) as f64 / a.len().max(1) as f64,
            a.len()
        ));
    }
    let (a, b) = (
        std::fs::read(dump.join("shadow.pcgi"))?,
        std::fs::read(dump.join("shadow.embree"))?,
    );
    let differ = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .filter(|(x, y)| x != y)
        .count();
    parts.push(format!(
        "shadow rays: {differ} of {} answers differ (a border-clipped disk blocks for Embree, \
         whose disc is whole, and not always for pcgi)",
        a.len() / 4
    ));
    Ok(format!(
        "First hits at {:.2}M splats: {}.",
        n as f64 / 1e6,
        parts.join("; ")
    ))
}
