//! pc-caustics: trace the caustic photon map (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use pc_scene::config::Backend;

/// Caustic photon map: photons from the lights aimed at the specular leaves they see, traced
/// through the octree, stored on diffuse splats with a kd-tree (seed §8.5.2 to §8.5.7).
#[derive(Parser)]
#[command(name = "pc-caustics", version, about)]
struct Args {
    #[command(flatten)]
    stage: pc_scene::cli::StageArgs,
    /// Where the photons are traced: cpu, gpu, or auto; default: caustics.backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The vmap artifact (default: <output.dir>/<vmap.file>).
    #[arg(long)]
    vmap: Option<PathBuf>,
    /// The photons artifact to write (default: <output.dir>/<caustics.file>).
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// Also write the counts and timings here as JSON (for `cargo xtask bench`).
    #[arg(long, value_name = "FILE")]
    stats_json: Option<PathBuf>,
}

fn main() -> ExitCode {
    pc_scene::cli::exit("pc-caustics", run(&Args::parse()))
}

fn run(args: &Args) -> anyhow::Result<()> {
    let cfg = args.stage.load()?;
    let octree = args.octree.clone().unwrap_or_else(|| cfg.octree_path());
    let vmap = args.vmap.clone().unwrap_or_else(|| cfg.vmap_path());
    let out = args.output.clone().unwrap_or_else(|| cfg.photons_path());
    let backend = args.backend.unwrap_or(cfg.config.caustics.backend);
    let key = pc_caustics::stage::key(&cfg, &octree, &vmap)
        .with_context(|| format!("tracing the photons for {}", args.stage.config.display()))?;
    let started = std::time::Instant::now();
    if args.stage.gate_artifact(
        "pc-caustics",
        &out,
        &key,
        pc_artifact::ArtifactKind::Photons,
    )? == pc_scene::cli::Gate::Done
    {
        return Ok(());
    }
    let bar = if args.stage.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0)
    };
    bar.set_style(ProgressStyle::with_template(
        "caustics {bar:30} {human_pos}/{human_len} photons {elapsed}",
    )?);
    let s = pc_caustics::stage::run(&cfg, &octree, &vmap, &out, backend, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })
    .with_context(|| format!("tracing the photons for {}", args.stage.config.display()))?;
    bar.finish_and_clear();
    let m = &s.meta;
    let trace_s = m
        .timings
        .iter()
        .find(|t| t.0 == "trace")
        .map_or(0.0, |t| t.1);
    println!(
        "pc-caustics: wrote {} ({} photons stored of {} traced, {} hidden, {} lost; {:.2} M photons/s) in {:.2} s on {}",
        s.path.display(),
        m.stored,
        m.traced,
        m.occluded,
        m.lost,
        m.traced as f64 / trace_s.max(1e-9) / 1e6,
        s.seconds,
        m.device
    );
    if let Some(path) = &args.stats_json {
        let json = format!(
            "{{\"budget\": {}, \"traced\": {}, \"stored\": {}, \"occluded\": {}, \"lost\": {}, \"trace_seconds\": {trace_s:.6}, \"total_seconds\": {:.6}, \"photons_per_s\": {:.0}, \"device\": \"{}\"}}\n",
            m.params.photons,
            m.traced,
            m.stored,
            m.occluded,
            m.lost,
            s.seconds,
            m.traced as f64 / trace_s.max(1e-9),
            m.device.replace('"', "'")
        );
        std::fs::write(path, json).with_context(|| format!("writing {}", path.display()))?;
    }
    args.stage.finish(
        "pc-caustics",
        "ran",
        &s.path,
        &key,
        started.elapsed().as_secs_f64(),
    )
}
