//! pc-sample: samples a built-in scene (cornell, sphere, glass-box) into splat PLY files and a
//! scene.toml, or scans the hall with a virtual terrestrial scanner into LAS/LAZ/E57 (`scan`).

use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use pc_import::ply_write::PlyFormat;
use pc_sample::{build_scene, write_scene_with_format, SampleParams, SceneKind};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

pc_stage::report_oom!("pc-sample");

#[derive(Clone, Copy, Debug, ValueEnum)]
enum SceneArg {
    /// Cornell box (open at z = +1), ceiling light, two boxes; `--with-specular` adds glass and mirror spheres.
    Cornell,
    /// Closed unit sphere, inward normals, every splat emitting (furnace test).
    Sphere,
    /// White room with a ceiling light and a floating glass sphere (caustic test).
    GlassBox,
    /// A virtual terrestrial scan of a hall (columns, a niche with a figure, a skylight) from
    /// three stations, written as a scanner writes it (--format) with a scene.toml.
    Scan,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum FormatArg {
    Las,
    Laz,
    E57,
}

impl From<SceneArg> for SceneKind {
    fn from(s: SceneArg) -> Self {
        match s {
            SceneArg::Cornell => SceneKind::Cornell,
            SceneArg::Sphere => SceneKind::Sphere,
            SceneArg::GlassBox => SceneKind::GlassBox,
            SceneArg::Scan => unreachable!("the scan is not a sampled scene"),
        }
    }
}

/// Sample a built-in scene into oriented disks (splats): one PLY per shape plus scene.toml.
#[derive(Debug, Parser)]
#[command(name = "pc-sample", version)]
struct Args {
    /// Scene to sample.
    #[arg(value_enum)]
    scene: SceneArg,
    /// Total number of splats (approximate, within rounding of the grids); accepts 250000, 1e6, 100k, 4M.
    #[arg(long, short = 'n', value_parser = parse_count)]
    points: usize,
    /// Output directory (created if needed).
    #[arg(long, short = 'o')]
    out: PathBuf,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Jitter as a fraction of a grid cell, in [0, 1].
    #[arg(long, default_value_t = 0.2)]
    jitter: f32,
    /// Splat radius divided by the grid cell size.
    #[arg(long, default_value_t = 1.0)]
    radius_factor: f32,
    /// cornell only: add a glass sphere and a mirror sphere.
    #[arg(long)]
    with_specular: bool,
    /// Write ASCII PLY instead of binary little-endian.
    #[arg(long)]
    ascii: bool,
    /// scan only: the file format (the file is `hall.<format>`).
    #[arg(long, value_enum, default_value = "laz")]
    format: FormatArg,

    /// scan only: the range noise's standard deviation in metres at zero range (it grows by a
    /// tenth of this per metre); 0 for a noiseless scan.
    #[arg(long, default_value_t = 0.002)]
    range_noise: f64,
}

fn parse_count(s: &str) -> std::result::Result<usize, String> {
    let t = s.trim().replace('_', "");
    let (num, mult) = match t.chars().last() {
        Some('k' | 'K') => (&t[..t.len() - 1], 1e3),
        Some('m' | 'M') => (&t[..t.len() - 1], 1e6),
        _ => (&t[..], 1.0),
    };
    if let Ok(n) = num.parse::<usize>() {
        return n
            .checked_mul(mult as usize)
            .ok_or_else(|| format!("point count too large: {s:?}"));
    }
    let x: f64 = num
        .parse()
        .map_err(|_| format!("not a point count: {s:?}"))?;
    let v = x * mult;
    if !(0.0..=1e12).contains(&v) || v.fract() != 0.0 {
        return Err(format!("not a whole point count: {s:?}"));
    }
    Ok(v as usize)
}

/// `pc-sample scan`: the virtual scanner.
fn run_scan(args: &Args) -> Result<()> {
    use pc_sample::scan::{
        room::Room, write::write_scan_scene, write_scan, ScanFormat, ScanParams,
    };
    let start = Instant::now();
    if args.points == 0 || args.points > 1_000_000_000 {
        bail!("--points {}: a scan holds 1 to 1e9 points", args.points);
    }
    let format = match args.format {
        FormatArg::Las => ScanFormat::Las,
        FormatArg::Laz => ScanFormat::Laz,
        FormatArg::E57 => ScanFormat::E57,
    };
    if !(args.range_noise.is_finite() && (0.0..=1.0).contains(&args.range_noise)) {
        bail!(
            "--range-noise {}: a standard deviation of 0 to 1 m",
            args.range_noise
        );
    }
    let params = ScanParams {
        noise: args.range_noise,
        noise_per_metre: 0.1 * args.range_noise,
        ..ScanParams::hall(args.points as u64, args.seed)
    };
    let name = format!("hall.{}", format.extension());
    let path = args.out.join(&name);
    let n = write_scan(&Room::hall(), &params, format, &path)
        .with_context(|| format!("writing the scan {}", path.display()))?;
    let toml = write_scan_scene(&args.out, &name, &params, format)
        .with_context(|| format!("writing {}", args.out.join("scene.toml").display()))?;
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "wrote {} ({n} points from {} stations, {:.1} M points/s) and {} in {seconds:.2} s",
        path.display(),
        params.stations.len(),
        n as f64 / seconds / 1e6,
        toml.display()
    );
    Ok(())
}

fn run(args: Args) -> Result<()> {
    if matches!(args.scene, SceneArg::Scan) {
        return run_scan(&args);
    }
    let start = Instant::now();
    let params = SampleParams {
        points: args.points,
        seed: args.seed,
        jitter: args.jitter,
        radius_factor: args.radius_factor,
    };
    if let Err(e) = params.validate() {
        bail!("{e}");
    }
    let kind = SceneKind::from(args.scene);
    if args.with_specular && kind != SceneKind::Cornell {
        eprintln!(
            "warning: --with-specular only applies to cornell; ignored for {}",
            kind.name()
        );
    }
    let scene = build_scene(kind, &params, args.with_specular);
    let format = if args.ascii {
        PlyFormat::Ascii
    } else {
        PlyFormat::BinaryLittleEndian
    };
    let toml = write_scene_with_format(&scene, &args.out, format)
        .with_context(|| format!("writing scene {} to {}", kind.name(), args.out.display()))?;
    println!(
        "wrote {} models, {} splats, to {} in {:.2} s",
        scene.shapes.len(),
        scene.total_points(),
        toml.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pc-sample: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts() {
        assert_eq!(parse_count("1000"), Ok(1000));
        assert_eq!(parse_count("100k"), Ok(100_000));
        assert_eq!(parse_count("4M"), Ok(4_000_000));
        assert_eq!(parse_count("1e6"), Ok(1_000_000));
        assert_eq!(parse_count("2.5M"), Ok(2_500_000));
        assert_eq!(parse_count("1_000"), Ok(1000));
        assert!(parse_count("x").is_err());
        assert!(parse_count("-5").is_err());
        assert!(parse_count("1.5").is_err());
    }

    #[test]
    fn cli_parses() {
        use clap::CommandFactory;
        Args::command().debug_assert();
        let a = Args::try_parse_from([
            "pc-sample",
            "cornell",
            "--points",
            "1000",
            "--out",
            "/tmp/x",
            "--with-specular",
            "--radius-factor",
            "1.5",
        ])
        .unwrap();
        assert!(a.with_specular);
        assert_eq!(a.points, 1000);
        assert_eq!(a.radius_factor, 1.5);
        assert!(Args::try_parse_from(["pc-sample", "glass-box", "--points", "10"]).is_err());
        let g = Args::try_parse_from(["pc-sample", "glass-box", "-n", "10", "-o", "d"]).unwrap();
        assert!(matches!(g.scene, SceneArg::GlassBox));
    }
}
