//! pc-compare: compare a render with a reference render over the reference's pixel regions,
//! and write the difference image.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use pc_raytrace::image::{read_exr, write_diff_png};

/// Region means and relative RMSE of a render against a reference (an EXR and its
/// *.stats.json, as in ../shared/reference/cornell).
#[derive(Parser)]
#[command(name = "pc-compare", version, about)]
struct Args {
    /// Our render (linear EXR).
    #[arg(required_unless_present = "write_config")]
    image: Option<PathBuf>,
    /// The reference folder.
    #[arg(long)]
    reference: PathBuf,
    /// Where to write |ours − reference| × scale as a PNG (default: <image>.diff.png).
    #[arg(long)]
    diff: Option<PathBuf>,
    /// Scale of the difference image.
    #[arg(long, default_value_t = 4.0)]
    scale: f32,
    /// Exit with an error when a region's error exceeds this (a fraction, e.g. 0.03).
    #[arg(long)]
    max_region_error: Option<f64>,
    /// Write a pipeline config that renders the reference scene from its sampled points
    /// (materials and camera from the reference's JSON), then compare IMAGE if given.
    #[arg(long, value_name = "FILE")]
    write_config: Option<PathBuf>,
}

fn main() -> ExitCode {
    pc_scene::cli::exit("pc-compare", run(&Args::parse()))
}

fn run(a: &Args) -> anyhow::Result<()> {
    if let Some(out) = &a.write_config {
        let text = pc_raytrace::reference::config_toml(&a.reference)?;
        pc_raytrace::image::write_atomically(out, text.as_bytes())?;
        println!("pc-compare: wrote {}", out.display());
    }
    let Some(image) = &a.image else {
        return Ok(());
    };
    let ours = read_exr(image)?;
    let (report, reference) = pc_raytrace::reference::compare(&ours, &a.reference)
        .with_context(|| format!("comparing {}", image.display()))?;
    let diff = a
        .diff
        .clone()
        .unwrap_or_else(|| image.with_extension("diff.png"));
    write_diff_png(&diff, &ours, &reference, a.scale)?;
    print!("{}", report.table());
    let worst = report.worst();
    println!(
        "pc-compare: {} regions, worst {} at {:.2} %, relative RMSE {:.2} %; wrote {}",
        report.regions.len(),
        worst.map_or("-", |r| r.name.as_str()),
        worst.map_or(0.0, |r| 100.0 * r.error()),
        100.0 * report.rel_rmse,
        diff.display()
    );
    if let (Some(max), Some(w)) = (a.max_region_error, worst) {
        if w.error() > max {
            anyhow::bail!(
                "region `{}` is {:.2} % off the reference, more than {:.2} %",
                w.name,
                100.0 * w.error(),
                100.0 * max
            );
        }
    }
    Ok(())
}
