//! pc-fmm: solve the diffuse global illumination of the scene (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_config::Backend;
use pc_fmm::stage::{FmmStage, Inputs};
use pc_stage::StageArgs;

pc_stage::report_oom!("pc-fmm");

/// Radiosity of every diffuse splat by the Fast Multipole Method over the V-map's links.
#[derive(Parser)]
#[command(name = "pc-fmm", version, about)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// Where the FMM runs: cpu, gpu, or auto; default: fmm.backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The vmap artifact (default: <output.dir>/<vmap.file>).
    #[arg(long)]
    vmap: Option<PathBuf>,
    /// The photons artifact whose caustic energy feeds the solve (default:
    /// <output.dir>/<caustics.file> when it exists; a path given must exist).
    #[arg(long)]
    photons: Option<PathBuf>,
    /// The radiosity artifact to write (default: <output.dir>/<fmm.file>).
    #[arg(long, short)]
    output: Option<PathBuf>,
}

fn main() -> ExitCode {
    let a = Args::parse();
    pc_stage::main(&a.stage, |cfg| {
        Ok(FmmStage {
            inputs: Inputs::new(&cfg, a.octree.clone(), a.vmap.clone(), a.photons.clone()),
            output: a.output.clone().unwrap_or_else(|| cfg.radiosity_path()),
            backend: a.backend.unwrap_or(cfg.config.fmm.backend),
            cfg,
        })
    })
}
