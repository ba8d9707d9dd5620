//! pc-octree: build the octree artifact of the scene in pipeline.toml (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_octree::stage::OctreeStage;
use pc_stage::StageArgs;

pc_stage::report_oom!("pc-octree");

/// Build the adaptive octree (node pool, begin/end table, data pool) of the scene's splats.
#[derive(Parser)]
#[command(name = "pc-octree", version, about)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// Write the artifact here instead of `<output.dir>/<octree.file>`.
    #[arg(long, short)]
    output: Option<PathBuf>,
}

fn main() -> ExitCode {
    let a = Args::parse();
    pc_stage::main(&a.stage, |cfg| {
        Ok(OctreeStage {
            output: a.output.clone().unwrap_or_else(|| cfg.octree_path()),
            cfg,
        })
    })
}
