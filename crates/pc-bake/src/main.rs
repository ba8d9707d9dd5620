//! pc-bake: write the lit scan as a point cloud (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_bake::stage::BakeStage;
use pc_stage::StageArgs;

pc_stage::report_oom!("pc-bake");

/// The lit cloud: every splat with its radiance (radiosity plus the caustic estimate),
/// tone-mapped to color, with the linear values as extra fields, in the models' own
/// (georeferenced) coordinates, as PLY, LAS or LAZ (by the extension of bake.file).
#[derive(Parser)]
#[command(name = "pc-bake", version, about)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The radiosity artifact (default: <output.dir>/<fmm.file>).
    #[arg(long)]
    radiosity: Option<PathBuf>,
    /// The photons artifact whose caustics are added (default: <output.dir>/<caustics.file>
    /// when it exists; a path given must exist).
    #[arg(long)]
    photons: Option<PathBuf>,
    /// The lit cloud to write (default: <output.dir>/<bake.file>).
    #[arg(long, short)]
    output: Option<PathBuf>,
}

fn main() -> ExitCode {
    let a = Args::parse();
    pc_stage::main(&a.stage, |cfg| {
        Ok(BakeStage {
            octree: a.octree.clone().unwrap_or_else(|| cfg.octree_path()),
            radiosity: a.radiosity.clone().unwrap_or_else(|| cfg.radiosity_path()),
            photons: pc_stage::OptionalInput::new(a.photons.clone(), cfg.photons_path()),
            output: a.output.clone().unwrap_or_else(|| cfg.bake_path()),
            cfg,
        })
    })
}
