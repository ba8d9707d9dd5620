//! pc-raytrace: render the scene's octree from the config's camera (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use pc_scene::cli::Gate;
use pc_scene::config::Backend;

/// Ray trace the octree (primary and specular rays, diffuse shading, supersampling).
#[derive(Parser)]
#[command(name = "pc-raytrace", version, about)]
struct Args {
    #[command(flatten)]
    stage: pc_scene::cli::StageArgs,
    /// cpu, gpu, or auto (the GPU when an adapter exists); default: raytrace.backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The radiosity artifact (default: <output.dir>/<fmm.file>); shown at diffuse hits in
    /// `stored` mode, and what `auto` mode looks for.
    #[arg(long)]
    radiosity: Option<PathBuf>,
    /// The photons artifact (default: <output.dir>/<caustics.file>); when it exists, diffuse
    /// hits add its caustic density estimate.
    #[arg(long)]
    photons: Option<PathBuf>,
    /// The EXR to write (default: <output.dir>/<raytrace.image>); a PNG preview goes beside it.
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// Render a walkthrough of this many frames instead (the config's camera orbiting its
    /// target, on the cached solution), as a numbered PNG sequence.
    #[arg(long, value_name = "N")]
    frames: Option<usize>,
    /// Where the walkthrough's frames go (default: <output.dir>/walkthrough).
    #[arg(long, value_name = "DIR", requires = "frames")]
    frames_dir: Option<PathBuf>,
    /// The walkthrough's orbit, in degrees, centred on the config's camera.
    #[arg(long, value_name = "DEG", default_value_t = 24.0, requires = "frames")]
    orbit: f32,
    /// Also write the walkthrough's timings as JSON (for `cargo xtask walkthrough`).
    #[arg(long, value_name = "FILE", requires = "frames")]
    stats_json: Option<PathBuf>,
}

fn main() -> ExitCode {
    pc_scene::cli::exit("pc-raytrace", run(&Args::parse()))
}

fn run(args: &Args) -> anyhow::Result<()> {
    let cfg = args.stage.load()?;
    let octree = args.octree.clone().unwrap_or_else(|| cfg.octree_path());
    let exr = args.output.clone().unwrap_or_else(|| cfg.image_path());
    let radiosity = args
        .radiosity
        .clone()
        .unwrap_or_else(|| cfg.radiosity_path());
    let photons = args.photons.clone().unwrap_or_else(|| cfg.photons_path());
    let backend = args.backend.unwrap_or(cfg.config.raytrace.backend);
    if let Some(frames) = args.frames {
        return walkthrough(args, &cfg, &octree, &radiosity, &photons, backend, frames);
    }
    let key = pc_raytrace::stage::render_key(&cfg, &octree, &radiosity, &photons, backend)
        .with_context(|| format!("rendering {}", args.stage.config.display()))?;
    let started = std::time::Instant::now();
    if args
        .stage
        .gate("pc-raytrace", &exr, &key, pc_raytrace::image::exr_key)?
        == Gate::Done
    {
        return Ok(());
    }
    let bar = if args.stage.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0)
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} render [{bar:30}] {pos}/{len} tiles {elapsed}")?
            .progress_chars("=> "),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let tick = || bar.inc(1);
    let mut set_len = |n: u64| bar.set_length(n);
    let s = pc_raytrace::stage::run(
        &cfg,
        &octree,
        &radiosity,
        &photons,
        &exr,
        backend,
        Some(&key),
        &tick,
        &mut set_len,
    )
    .with_context(|| format!("rendering {}", args.stage.config.display()))?;
    bar.finish_and_clear();
    let p = &cfg.config.raytrace;
    let (w, h) = (s.image.width, s.image.height);
    let rays = s.counts.map(|c| c.camera + c.bounce + c.shadow);
    let rate = rays
        .map(|r| format!(", {:.2} M rays/s", r as f64 / s.seconds / 1e6))
        .unwrap_or_default();
    println!(
        "pc-raytrace: wrote {} and {} ({w}x{h}, {} spp, {} shading{}) in {:.2} s on {}{}",
        s.exr.display(),
        s.png.display(),
        p.spp,
        format!("{:?}", s.mode).to_lowercase(),
        if s.caustics { " with caustics" } else { "" },
        s.seconds,
        s.device_name,
        rate
    );
    args.stage.finish(
        "pc-raytrace",
        "ran",
        &exr,
        &key,
        started.elapsed().as_secs_f64(),
    )
}

fn walkthrough(
    args: &Args,
    cfg: &pc_scene::config::LoadedConfig,
    octree: &std::path::Path,
    radiosity: &std::path::Path,
    photons: &std::path::Path,
    backend: Backend,
    frames: usize,
) -> anyhow::Result<()> {
    let dir = args
        .frames_dir
        .clone()
        .unwrap_or_else(|| cfg.out_dir().join("walkthrough"));
    let bar = if args.stage.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(frames as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} walkthrough [{bar:30}] {pos}/{len} frames {elapsed}",
        )?
        .progress_chars("=> "),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let w = pc_raytrace::stage::walkthrough(
        cfg,
        octree,
        radiosity,
        photons,
        &dir,
        frames,
        args.orbit,
        backend,
        &mut |_| bar.inc(1),
    )
    .with_context(|| format!("rendering a walkthrough of {}", args.stage.config.display()))?;
    bar.finish_and_clear();
    let c = &cfg.config;
    let fps = frames as f64 / w.render_seconds.max(1e-9);
    println!(
        "pc-raytrace: wrote {frames} frames to {} ({}x{}, {} spp, {:.0}° orbit): {fps:.2} frames/s rendering on {} (setup {:.2} s, PNG writing {:.2} s)",
        dir.display(),
        c.camera.width,
        c.camera.height,
        c.raytrace.spp,
        args.orbit,
        w.device_name,
        w.setup_seconds,
        w.write_seconds
    );
    if let Some(path) = &args.stats_json {
        let json = serde_json::json!({
            "frames": frames,
            "width": c.camera.width,
            "height": c.camera.height,
            "spp": c.raytrace.spp,
            "device": w.device_name,
            "gpu": w.device == pc_raytrace::stage::Device::Gpu,
            "render_seconds": w.render_seconds,
            "write_seconds": w.write_seconds,
            "setup_seconds": w.setup_seconds,
            "frames_per_second": fps,
        });
        pc_artifact::write_file_atomically(path, format!("{json}\n").as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
