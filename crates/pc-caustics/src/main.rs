//! pc-caustics: trace the caustic photon map (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_caustics::stage::CausticsStage;
use pc_config::Backend;
use pc_stage::StageArgs;

pc_stage::report_oom!("pc-caustics");

/// Caustic photon map: photons from the lights aimed at the specular leaves they see, traced
/// through the octree, stored on diffuse splats with a kd-tree (seed §8.5.2 to §8.5.7).
#[derive(Parser)]
#[command(name = "pc-caustics", version, about)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
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
}

fn main() -> ExitCode {
    let a = Args::parse();
    pc_stage::main(&a.stage, |cfg| {
        Ok(CausticsStage {
            octree: a.octree.clone().unwrap_or_else(|| cfg.octree_path()),
            vmap: a.vmap.clone().unwrap_or_else(|| cfg.vmap_path()),
            output: a.output.clone().unwrap_or_else(|| cfg.photons_path()),
            backend: a.backend.unwrap_or(cfg.config.caustics.backend),
            cfg,
        })
    })
}
