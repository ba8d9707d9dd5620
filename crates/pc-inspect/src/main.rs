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
    /// Which debug view to export.
    #[arg(long, value_enum, default_value = "splats")]
    view: View,
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
        let n = pc_inspect::export_ply(&a, args.view, out)?;
        println!(
            "pc-inspect: wrote {} ({n} points, {:?} view)",
            out.display(),
            args.view
        );
    }
    Ok(())
}
