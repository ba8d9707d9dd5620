//! pc-raytrace: render the scene's octree from the config's camera (thin wrapper over the library).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pc_config::Backend;
use pc_raytrace::stage::{Inputs, RaytraceStage};
use pc_raytrace::walkthrough::Orbit;
use pc_stage::StageArgs;

pc_stage::report_oom!("pc-raytrace");

/// Ray trace the octree (primary and specular rays, diffuse shading, supersampling).
#[derive(Parser)]
#[command(name = "pc-raytrace", version, about)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// cpu, gpu, or auto (the GPU when an adapter exists); default: raytrace.backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// The octree artifact (default: <output.dir>/<octree.file>).
    #[arg(long)]
    octree: Option<PathBuf>,
    /// The radiosity artifact, shown at diffuse hits in `stored` mode and what `auto` mode
    /// looks for (default: <output.dir>/<fmm.file> when it exists; a path given must exist).
    #[arg(long)]
    radiosity: Option<PathBuf>,
    /// The photons artifact whose caustic density estimate diffuse hits add (default:
    /// <output.dir>/<caustics.file> when it exists; a path given must exist).
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
}

fn main() -> ExitCode {
    let a = Args::parse();
    if let Some(frames) = a.frames {
        let w = pc_stage::threads::start().and_then(|_| walkthrough(&a, frames));
        return pc_stage::exit("pc-raytrace", w);
    }
    pc_stage::main(&a.stage, |cfg| {
        Ok(RaytraceStage {
            inputs: Inputs::new(
                &cfg,
                a.octree.clone(),
                a.radiosity.clone(),
                a.photons.clone(),
            ),
            exr: a.output.clone().unwrap_or_else(|| cfg.image_path()),
            backend: a.backend.unwrap_or(cfg.config.raytrace.backend),
            cfg,
        })
    })
}

fn walkthrough(a: &Args, frames: usize) -> anyhow::Result<()> {
    let cfg = a.stage.load()?;
    let inputs = Inputs::new(
        &cfg,
        a.octree.clone(),
        a.radiosity.clone(),
        a.photons.clone(),
    );
    let orbit = Orbit {
        dir: a
            .frames_dir
            .clone()
            .unwrap_or_else(|| cfg.out_dir().join("walkthrough")),
        frames,
        degrees: a.orbit,
    };
    let backend = a.backend.unwrap_or(cfg.config.raytrace.backend);
    let w = pc_raytrace::walkthrough::run(
        &cfg,
        &inputs,
        backend,
        &orbit,
        a.stage.quiet,
        a.stage.stats_json.as_deref(),
    )?;
    pc_stage::say(&pc_stage::with_gpu_times(w.to_string()));
    Ok(())
}
