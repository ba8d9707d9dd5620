//! The pc-raytrace stage: config + octree artifact → image (EXR + PNG preview).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use pc_artifact::octree::{MaterialRecord, OctreeMeta};
use pc_artifact::{Artifact, ArtifactKind};
use pc_scene::camera::Camera;
use pc_scene::config::{Backend, LoadedConfig};
use pc_scene::load::material_table;
use pc_tree::OctreeView;

use crate::cpu::RayCounts;
use crate::image::{write_exr, write_png, Image};
use crate::scene::RenderScene;

pub use pc_scene::cli::current_materials;

/// Which backend runs, after `auto` is resolved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Device {
    Cpu,
    Gpu,
}

/// What one render made.
pub struct Summary {
    pub image: Image,
    pub device: Device,
    pub device_name: String,
    pub seconds: f64,
    pub counts: Option<RayCounts>,
    pub exr: PathBuf,
    pub png: PathBuf,
}

/// Render the config's camera view of the octree at `octree_path` and write the images.
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    exr: &Path,
    backend: Backend,
    tile_done: &(dyn Fn() + Sync),
    total_tiles: &mut dyn FnMut(u64),
) -> anyhow::Result<Summary> {
    let art = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let view = OctreeView::from_artifact(&art)?;
    let materials = current_materials(cfg, &art)?;
    let c = &cfg.config;
    let camera = Camera::new(&c.camera);
    let mut sc = RenderScene::new(view, materials, &c.lights, &camera, &c.raytrace);
    let gpu = match backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(pc_gpu::GpuContext::new()?),
        // `auto` means a real GPU: a software rasterizer (llvmpipe) is slower than the CPU path.
        Backend::Auto => pc_gpu::GpuContext::new().ok().filter(|g| !g.is_software()),
    };
    let t = Instant::now();
    // With `auto`, a GPU that cannot take the scene (too large for its buffers, too few
    // bindings) falls back to the CPU with a warning; with `gpu` it is an error.
    let gpu_image = match &gpu {
        Some(ctx) => match crate::gpu::render::GpuRenderer::new(ctx, &sc)
            .and_then(|r| r.render(ctx, &sc, c.raytrace.aovs))
        {
            Ok(img) => Some((img, ctx.describe())),
            Err(e) if backend == Backend::Auto => {
                eprintln!(
                    "pc-raytrace: warning: rendering on the CPU: the GPU {} cannot: {e}",
                    ctx.describe()
                );
                None
            }
            Err(e) => return Err(e.into()),
        },
        None => None,
    };
    let (image, device, device_name, counts) = match gpu_image {
        Some((img, name)) => (img, Device::Gpu, name, None),
        None => {
            sc.prepare_cpu();
            let w = sc.params.width.div_ceil(16) as u64 * sc.params.height.div_ceil(16) as u64;
            total_tiles(w);
            let (img, counts) = crate::cpu::render(&sc, c.raytrace.aovs, tile_done);
            (
                img,
                Device::Cpu,
                format!("CPU, {} threads", rayon::current_num_threads()),
                Some(counts),
            )
        }
    };
    let seconds = t.elapsed().as_secs_f64();
    write_exr(exr, &image)?;
    let png = exr.with_extension("png");
    write_png(&png, &image, c.raytrace.exposure)?;
    Ok(Summary {
        image,
        device,
        device_name,
        seconds,
        counts,
        exr: exr.to_path_buf(),
        png,
    })
}
