//! pc-inspect: print what an artifact holds, verify it, or export a debug view as PLY.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::Parser;
use pc_artifact::octree::OctreeFile;
use pc_inspect::{Opened, View};
use pc_stage::say;

pc_stage::report_oom!("pc-inspect");

/// Look inside a pcgi artifact (octree, vmap, photons, radiosity).
#[derive(Parser)]
#[command(name = "pc-inspect", version, about)]
struct Args {
    /// The artifact file.
    file: PathBuf,
    /// Also check that point location finds every splat's leaf (octree artifacts; checksums
    /// and the kind's structure are always checked).
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
    pc_stage::exit("pc-inspect", run(&Args::parse()))
}

fn run(args: &Args) -> anyhow::Result<()> {
    let o = Opened::open(&args.file)?;
    let mut text = pc_inspect::describe(o.artifact());
    text.push_str(&pc_inspect::statistics(&o));
    say(text.trim_end());
    if args.metadata {
        say(&pc_inspect::metadata_json(o.artifact())?);
    }
    if args.verify {
        say(&pc_inspect::verify(&o)?);
    }
    let Some(out) = &args.export_ply else {
        return Ok(());
    };
    match &o {
        Opened::Vmap(vmap) => {
            let node = args
                .node
                .context("--export-ply of a V-map needs --node N (a node-pool index)")?;
            let octree_path = args
                .octree
                .clone()
                .unwrap_or_else(|| args.file.with_file_name("octree.pcgi"));
            let octree = OctreeFile::open(&octree_path)?;
            let n = pc_inspect::export_vmap_links(vmap, &octree, node, out)?;
            say(&format!(
                "pc-inspect: wrote {} ({n} points: node {node} and the nodes it links to)",
                out.display()
            ));
        }
        Opened::Octree(octree) => {
            let n = pc_inspect::export_ply(octree, args.view, out)?;
            say(&format!(
                "pc-inspect: wrote {} ({n} points, {:?} view)",
                out.display(),
                args.view
            ));
        }
        _ => bail!(
            "{}: --export-ply supports octree and V-map artifacts",
            args.file.display()
        ),
    }
    Ok(())
}
