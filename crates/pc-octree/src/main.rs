//! pc-octree: build the octree artifact of the scene in pipeline.toml (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};

/// Build the adaptive octree (node pool, begin/end table, data pool) of the scene's splats.
#[derive(Parser)]
#[command(name = "pc-octree", version, about)]
struct Args {
    #[command(flatten)]
    stage: pc_scene::cli::StageArgs,
    /// Write the artifact here instead of `<output.dir>/<octree.file>`.
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// Also write the timings, counts and peak memory as JSON (for `cargo xtask bench`).
    #[arg(long, value_name = "FILE")]
    stats_json: Option<PathBuf>,
}

fn main() -> ExitCode {
    pc_scene::cli::exit("pc-octree", run(&Args::parse()))
}

fn run(args: &Args) -> anyhow::Result<()> {
    let cfg = args.stage.load()?;
    let out = args.output.clone().unwrap_or_else(|| cfg.octree_path());
    let key = pc_octree::stage::octree_key(&cfg)
        .with_context(|| format!("building the octree for {}", args.stage.config.display()))?;
    let started = Instant::now();
    if args
        .stage
        .gate_artifact("pc-octree", &out, &key, pc_artifact::ArtifactKind::Octree)?
        == pc_scene::cli::Gate::Done
    {
        return Ok(());
    }
    let bar = if args.stage.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(cfg.config.models.len() as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} {prefix:>10} [{bar:30}] {pos}/{len} {msg}")?
            .progress_chars("=> "),
    );
    bar.set_prefix("import");
    bar.enable_steady_tick(Duration::from_millis(100));
    let mut on_import = |done: usize, _total: usize| bar.set_position(done as u64);
    let mut on_phase = |name: &str| {
        bar.set_prefix("build");
        bar.set_message(name.to_string());
    };
    let summary = pc_octree::stage::run(&cfg, &out, &mut on_import, &mut on_phase)
        .with_context(|| format!("building the octree for {}", args.stage.config.display()))?;
    bar.finish_and_clear();
    let s = &summary.octree.stats;
    let secs = started.elapsed().as_secs_f64();
    let dropped = if summary.dropped > 0 {
        format!(", dropped {} invalid points", summary.dropped)
    } else {
        String::new()
    };
    println!(
        "pc-octree: wrote {} ({} splats, {} nodes, {} leaves, depth {}, {} extra refs{}) in {:.2} s (import {:.2} s, build {:.2} s, {:.1} M splats/s)",
        summary.path.display(),
        s.splats,
        s.nodes,
        s.leaves,
        s.depth,
        s.extra_refs,
        dropped,
        secs,
        summary.import_seconds,
        summary.build_seconds,
        s.splats as f64 / summary.build_seconds.max(1e-9) / 1e6
    );
    if let Some(path) = &args.stats_json {
        let phases: Vec<String> = s
            .timings
            .iter()
            .map(|(n, t)| format!("{{\"phase\": \"{n}\", \"seconds\": {t:.6}}}"))
            .collect();
        let json = format!(
            "{{\"splats\": {}, \"nodes\": {}, \"leaves\": {}, \"extra_refs\": {}, \"depth\": {}, \"import_seconds\": {:.6}, \"build_seconds\": {:.6}, \"write_seconds\": {:.6}, \"total_seconds\": {:.6}, \"peak_rss_bytes\": {}, \"threads\": {}, \"phases\": [{}]}}\n",
            s.splats, s.nodes, s.leaves, s.extra_refs, s.depth, summary.import_seconds, summary.build_seconds, summary.write_seconds, secs,
            peak_rss_bytes().unwrap_or(0), rayon::current_num_threads(), phases.join(", ")
        );
        std::fs::write(path, json).with_context(|| format!("writing {}", path.display()))?;
    }
    args.stage
        .finish("pc-octree", "ran", &summary.path, &key, secs)
}

/// Peak resident memory of this process (Linux: VmHWM in /proc/self/status).
fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
