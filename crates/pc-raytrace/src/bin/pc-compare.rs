//! pc-compare: compare a render with a reference render over the reference's pixel regions,
//! and write the difference image.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use pc_raytrace::image::{read_exr, write_diff_png};

pc_stage::report_oom!("pc-compare");

/// Relative RMSE, per-pixel relative error and region means of a render against a reference
/// render, and the difference image: `pc-compare IMAGE.exr REFERENCE.exr [--regions FILE]`, or `pc-compare IMAGE.exr
/// --reference DIR` for a reference folder (an EXR and its *.stats.json, as in
/// ../shared/reference/cornell).
#[derive(Parser)]
#[command(name = "pc-compare", version)]
struct Args {
    /// Our render (linear EXR).
    #[arg(required_unless_present = "write_config")]
    image: Option<PathBuf>,
    /// The reference render (linear EXR, same size).
    #[arg(conflicts_with = "reference", required_unless_present_any = ["reference", "write_config"])]
    reference_image: Option<PathBuf>,
    /// Regions to compare (JSON: `regions` maps names to `{"rect": [x0, y0, x1, y1]}`, pixels
    /// from the top left, as in a reference's *.stats.json).
    #[arg(long, value_name = "FILE", conflicts_with = "reference")]
    regions: Option<PathBuf>,
    /// A reference folder instead of REFERENCE_IMAGE: its *.stats.json names the EXR and the
    /// regions.
    #[arg(long, value_name = "DIR")]
    reference: Option<PathBuf>,
    /// Where to write |ours − reference| × scale as a PNG (default: `<image>.diff.png`).
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
    pc_stage::exit("pc-compare", run(&Args::parse()))
}

fn run(a: &Args) -> anyhow::Result<()> {
    if let Some(out) = &a.write_config {
        let dir = a
            .reference
            .as_ref()
            .context("--write-config needs --reference DIR")?;
        let text = pc_raytrace::reference::config_toml(dir)?;
        pc_raytrace::image::write_atomically(out, text.as_bytes())?;
        println!("pc-compare: wrote {}", out.display());
    }
    let Some(image) = &a.image else {
        return Ok(());
    };
    let ours = read_exr(image)?;
    let (report, reference) = match (&a.reference_image, &a.reference) {
        (Some(path), _) => {
            let reference = read_exr(path)?;
            let report = pc_raytrace::reference::compare_images(
                &ours,
                &reference,
                path,
                a.regions.as_deref(),
            )
            .with_context(|| format!("comparing {}", image.display()))?;
            (report, reference)
        }
        (None, Some(dir)) => pc_raytrace::reference::compare(&ours, dir)
            .with_context(|| format!("comparing {}", image.display()))?,
        (None, None) => anyhow::bail!("give a reference image or --reference DIR"),
    };
    let diff = a
        .diff
        .clone()
        .unwrap_or_else(|| image.with_extension("diff.png"));
    write_diff_png(&diff, &ours, &reference, a.scale)?;
    print!("{}", report.table());
    let worst = report.worst();
    println!(
        "pc-compare: {} regions, worst {} at {:.2} %, relative RMSE {:.2} %, per-pixel relative error {:.4} ({:.4} outside the light's border); wrote {}",
        report.regions.len(),
        worst.map_or("-", |r| r.name.as_str()),
        worst.map_or(0.0, |r| 100.0 * r.error()),
        100.0 * report.rel_rmse,
        report.per_pixel,
        report.per_pixel_outside_band,
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
