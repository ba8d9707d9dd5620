//! pc-inspect: print what an artifact holds, verify it, or export a debug view as PLY.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_artifact::Artifact;
use pc_inspect::View;

/// Look inside a pcgi artifact (octree, vmap, photons, radiosity).
#[derive(Parser)]
#[command(name = "pc-inspect", version, about)]
struct Args {
    /// The artifact file.
    file: PathBuf,
    /// Also run the kind's structural checks (checksums are always checked).
    #[arg(long)]
    verify: bool,
    /// Print the metadata (parameters, counts, timings, provenance) as JSON.
    #[arg(long)]
    metadata: bool,
    /// Write a debug view as a PLY file (open it in CloudCompare or MeshLab).
    #[arg(long, value_name = "OUT.ply")]
    export_ply: Option<PathBuf>,
    /// Which debug view to export (octree artifacts).
    #[arg(long, value_enum, default_value = "splats")]
    view: View,
    /// V-map artifacts: export the links of this node (node-pool index) with --export-ply.
    #[arg(long)]
    node: Option<u32>,
    /// V-map artifacts: the octree it was made from (default: octree.pcgi beside it).
    #[arg(long)]
    octree: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pc-inspect: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &Args) -> anyhow::Result<()> {
    let a = Artifact::open(&args.file)?;
    print!("{}", pc_inspect::describe(&a));
    print!("{}", pc_inspect::statistics(&a)?);
    if args.metadata {
        println!("{}", pc_inspect::metadata_json(&a)?);
    }
    if args.verify {
        println!("{}", pc_inspect::verify(&args.file)?);
    }
    if let Some(out) = &args.export_ply {
        if a.header().kind == pc_artifact::ArtifactKind::Vmap {
            let node = args.node.ok_or_else(|| {
                anyhow::anyhow!("--export-ply of a V-map needs --node N (a node-pool index)")
            })?;
            let octree_path = args
                .octree
                .clone()
                .unwrap_or_else(|| args.file.with_file_name("octree.pcgi"));
            let octree = Artifact::open(&octree_path)?;
            let n = pc_inspect::export_vmap_links(&a, &octree, node, out)?;
            println!(
                "pc-inspect: wrote {} ({n} points: node {node} and the nodes it links to)",
                out.display()
            );
        } else {
            let n = pc_inspect::export_ply(&a, args.view, out)?;
            println!(
                "pc-inspect: wrote {} ({n} points, {:?} view)",
                out.display(),
                args.view
            );
        }
    }
    Ok(())
}
