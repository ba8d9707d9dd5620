//! One scene rendered on the backend asked for, frame after frame: the GPU keeps its buffers
//! between frames; with `auto`, a GPU that cannot take the scene, or fails during a frame,
//! falls back to the CPU (pc-stage's rule); with `gpu` that is an error.

use pc_config::Backend;

use crate::cpu::RayCounts;
use crate::error::RenderError;
use crate::gpu::render::GpuRenderer;
use crate::image::Image;
use crate::scene::RenderScene;

/// Which backend renders, after `auto` is resolved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Device {
    Cpu,
    Gpu,
}

/// A renderer for one scene.
pub struct Renderer {
    gpu: Option<(pc_gpu::GpuContext, GpuRenderer)>,
    /// `auto`: a GPU failure falls back to the CPU instead of failing.
    fallback: bool,
}

impl Renderer {
    pub fn new(sc: &mut RenderScene, backend: Backend) -> Result<Renderer, RenderError> {
        let gpu = pc_stage::gpu_or_cpu(
            crate::stage::STAGE,
            backend,
            pc_stage::Work::Render,
            |ctx| GpuRenderer::new(&ctx, sc).map(|r| Some((ctx, r))),
            || Ok::<_, pc_gpu::GpuError>(None),
        )?;
        if gpu.is_none() {
            sc.prepare_cpu();
        }
        Ok(Renderer {
            gpu,
            fallback: backend == Backend::Auto,
        })
    }

    /// Which device renders.
    pub fn device(&self) -> Device {
        if self.gpu.is_some() {
            Device::Gpu
        } else {
            Device::Cpu
        }
    }

    /// The device, in words.
    pub fn device_name(&self) -> String {
        match &self.gpu {
            Some((ctx, _)) => ctx.describe(),
            None => format!("CPU, {} threads", rayon::current_num_threads()),
        }
    }

    /// Render the scene's camera view (ray counts on the CPU only); `tile_done` hears of each
    /// CPU tile. With `auto`, a GPU that fails here is dropped with a warning and this and later
    /// frames render on the CPU.
    pub fn render(
        &mut self,
        sc: &mut RenderScene,
        aovs: bool,
        tile_done: &(dyn Fn() + Sync),
    ) -> Result<(Image, Option<RayCounts>), RenderError> {
        if let Some((ctx, r)) = &self.gpu {
            match r.render(ctx, sc, aovs) {
                Ok(img) => return Ok((img, None)),
                Err(e) if self.fallback => {
                    pc_stage::device::warn_fallback(crate::stage::STAGE, &ctx.describe(), &e);
                    self.gpu = None;
                    sc.prepare_cpu();
                }
                Err(e) => return Err(e.into()),
            }
        }
        let (img, counts) = crate::cpu::render(sc, aovs, tile_done);
        Ok((img, Some(counts)))
    }
}
