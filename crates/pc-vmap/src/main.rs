//! pc-vmap: compute the V-map of the scene's octree (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_config::Backend;
use pc_stage::StageArgs;
use pc_vmap::stage::VmapStage;

pc_stage::report_oom!("pc-vmap");

/// View-independent visibility links between octree nodes, and the nodes each light sees.
#[derive(Parser)]
#[command(name = "pc-vmap", version, about)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
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
    let a = Args::parse();
    pc_stage::main(&a.stage, |cfg| {
        Ok(VmapStage {
            octree: a.octree.clone().unwrap_or_else(|| cfg.octree_path()),
            output: a.output.clone().unwrap_or_else(|| cfg.vmap_path()),
            backend: a.backend.unwrap_or(cfg.config.vmap.backend),
            cfg,
        })
    })
}
