//! pc-vmap: compute the V-map of the scene's octree (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use pc_scene::config::Backend;

/// View-independent visibility links between octree nodes, and the nodes each light sees.
#[derive(Parser)]
#[command(name = "pc-vmap", version, about)]
struct Args {
    #[command(flatten)]
    stage: pc_scene::cli::StageArgs,
    /// Where rays are cast: cpu, gpu, or auto; default: vmap.backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The vmap artifact to write (default: <output.dir>/<vmap.file>).
    #[arg(long, short)]
    output: Option<PathBuf>,
}

fn main() -> ExitCode {
    pc_scene::cli::exit("pc-vmap", run(&Args::parse()))
}

fn run(args: &Args) -> anyhow::Result<()> {
    let cfg = args.stage.load()?;
    let octree = args.octree.clone().unwrap_or_else(|| cfg.octree_path());
    let out = args.output.clone().unwrap_or_else(|| cfg.vmap_path());
    let backend = args.backend.unwrap_or(cfg.config.vmap.backend);
    let key = pc_vmap::stage::key(&cfg, &octree)
        .with_context(|| format!("computing the V-map for {}", args.stage.config.display()))?;
    let started = std::time::Instant::now();
    if args
        .stage
        .gate_artifact("pc-vmap", &out, &key, pc_artifact::ArtifactKind::Vmap)?
        == pc_scene::cli::Gate::Done
    {
        return Ok(());
    }
    let bar = if args.stage.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new_spinner()
    };
    bar.set_style(ProgressStyle::with_template(
        "{spinner} vmap {msg} {elapsed}",
    )?);
    bar.enable_steady_tick(Duration::from_millis(100));
    let mut round = |level: usize, frontier: usize| {
        bar.set_message(format!("round {level}: {frontier} node pairs next"))
    };
    let s = pc_vmap::stage::run(&cfg, &octree, &out, backend, &mut round)
        .with_context(|| format!("computing the V-map for {}", args.stage.config.display()))?;
    bar.finish_and_clear();
    let m = &s.meta;
    println!(
        "pc-vmap: wrote {} ({} far and {} near links{}, {} node pairs tested, {} rays, {} light lists) in {:.2} s on {}",
        s.path.display(),
        m.far_links,
        m.near_links,
        if m.links_reused { " reused" } else { "" },
        m.pairs_tested,
        m.rays_cast,
        m.lights.len(),
        s.seconds,
        m.device
    );
    args.stage.finish(
        "pc-vmap",
        "ran",
        &s.path,
        &key,
        started.elapsed().as_secs_f64(),
    )
}
