//! pc-run: run the pipeline's stages in order, skipping those that are up to date (thin
//! wrapper over the library; `cargo xtask run` builds the binaries and calls it).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Parser;
use pc_run::{Options, Stage};

/// Run pc-octree, pc-vmap, pc-caustics, pc-fmm and pc-raytrace (and pc-bake with
/// `--until pc-bake`) as separate processes in dependency order. A stage whose output already has the key this run would give it (hashed
/// from the stage's version, its parameters, the keys of its input artifacts and the content
/// of its input files) is skipped as up to date.
#[derive(Parser)]
#[command(name = "pc-run", version, about)]
struct Args {
    /// The pipeline description.
    #[arg(long, default_value = "pipeline.toml")]
    config: PathBuf,
    /// Override a config key in every stage, e.g. `--set camera.fov=30` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Run this stage even when it is up to date (repeatable; `all` for every stage).
    #[arg(long, value_name = "STAGE")]
    force: Vec<String>,
    /// Start at this stage: the ones before it are neither checked nor run.
    #[arg(long, value_name = "STAGE")]
    from: Option<String>,
    /// Stop after this stage (default pc-raytrace; `pc-bake` also writes the lit cloud).
    #[arg(long, value_name = "STAGE")]
    until: Option<String>,
    /// Where the stage binaries are (default: this executable's folder).
    #[arg(long, value_name = "DIR")]
    bin_dir: Option<PathBuf>,
    /// No progress bars from the stages.
    #[arg(long, short)]
    quiet: bool,
    /// Also write what each stage did as JSON (stage, status, seconds, key, output).
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

fn main() -> ExitCode {
    match run(&Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pc-run: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &Args) -> anyhow::Result<()> {
    let bin_dir = match &args.bin_dir {
        Some(d) => d.clone(),
        None => pc_run::own_bin_dir()?,
    };
    let mut opts = Options::new(&args.config, bin_dir);
    opts.sets = args.set.clone();
    opts.quiet = args.quiet;
    for f in &args.force {
        if f == "all" {
            opts.force = Stage::ALL.to_vec();
        } else {
            opts.force.push(Stage::parse(f)?);
        }
    }
    if let Some(s) = &args.from {
        opts.from = Stage::parse(s)?;
    }
    if let Some(s) = &args.until {
        opts.until = Stage::parse(s)?;
    }
    let started = Instant::now();
    let runs = pc_run::run(&opts, &mut |_| {})?;
    if let Some(path) = &args.report {
        std::fs::write(path, pc_run::to_json(&runs))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    println!(
        "pc-run: {}",
        pc_run::summary(&runs, started.elapsed().as_secs_f64())
    );
    Ok(())
}
