//! pc-fmm: solve the diffuse global illumination of the scene (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use pc_scene::config::Backend;

/// Radiosity of every diffuse splat by the Fast Multipole Method over the V-map's links.
#[derive(Parser)]
#[command(name = "pc-fmm", version, about)]
struct Args {
    #[command(flatten)]
    stage: pc_scene::cli::StageArgs,
    /// Where the FMM runs: cpu, gpu, or auto; default: fmm.backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The vmap artifact (default: <output.dir>/<vmap.file>).
    #[arg(long)]
    vmap: Option<PathBuf>,
    /// The photons artifact whose caustic energy feeds the solve when it exists (default:
    /// <output.dir>/<caustics.file>).
    #[arg(long)]
    photons: Option<PathBuf>,
    /// The radiosity artifact to write (default: <output.dir>/<fmm.file>).
    #[arg(long, short)]
    output: Option<PathBuf>,
}

struct Bar {
    bar: ProgressBar,
    quiet: bool,
}

impl pc_fmm::stage::Progress for Bar {
    fn phase(&mut self, what: &str) {
        self.bar.set_message(what.to_string());
    }
    fn iteration(&mut self, it: u32, residual: f64) {
        self.bar
            .set_message(format!("solve: iteration {it}, residual {residual:.3e}"));
        if !self.quiet {
            self.bar
                .println(format!("  iteration {it:3}: residual {residual:.3e}"));
        }
    }
}

fn main() -> ExitCode {
    pc_scene::cli::exit("pc-fmm", run(&Args::parse()))
}

fn run(args: &Args) -> anyhow::Result<()> {
    let cfg = args.stage.load()?;
    let octree = args.octree.clone().unwrap_or_else(|| cfg.octree_path());
    let vmap = args.vmap.clone().unwrap_or_else(|| cfg.vmap_path());
    let out = args.output.clone().unwrap_or_else(|| cfg.radiosity_path());
    let photons = args.photons.clone().unwrap_or_else(|| cfg.photons_path());
    let backend = args.backend.unwrap_or(cfg.config.fmm.backend);
    let key = pc_fmm::stage::key(&cfg, &octree, &vmap, &photons)
        .with_context(|| format!("solving the radiosity for {}", args.stage.config.display()))?;
    let started = std::time::Instant::now();
    if args
        .stage
        .gate_artifact("pc-fmm", &out, &key, pc_artifact::ArtifactKind::Radiosity)?
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
        "{spinner} fmm {msg} {elapsed}",
    )?);
    bar.enable_steady_tick(Duration::from_millis(100));
    let mut progress = Bar {
        bar,
        quiet: args.stage.quiet,
    };
    let s = pc_fmm::stage::run(&cfg, &octree, &vmap, &photons, &out, backend, &mut progress)
        .with_context(|| format!("solving the radiosity for {}", args.stage.config.display()))?;
    progress.bar.finish_and_clear();
    let m = &s.meta;
    let per_it = m
        .timings
        .iter()
        .find(|t| t.0 == "per iteration")
        .map_or(0.0, |t| t.1);
    println!(
        "pc-fmm: wrote {} ({} splats, {} iterations{}, residual {:.2e}, {:.3} s per iteration; tasks: {} M2L, {} P2L, {} M2P, {} P2P over {} pairs) in {:.2} s on {}",
        s.path.display(),
        m.active_splats,
        m.iterations,
        if m.converged { "" } else { " (not converged)" },
        m.residuals.last().copied().unwrap_or(0.0),
        per_it,
        m.m2l,
        m.p2l,
        m.m2p,
        m.p2p,
        m.p2p_pairs,
        s.seconds,
        m.device
    );
    args.stage.finish(
        "pc-fmm",
        "ran",
        &s.path,
        &key,
        started.elapsed().as_secs_f64(),
    )
}
