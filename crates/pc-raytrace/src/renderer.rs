//! One scene rendered on the backend asked for, frame after frame: the GPU keeps its buffers
//! between frames; with `auto`, a GPU that cannot take the scene, or fails during a frame,
//! falls back to the CPU (pc-stage's rule); with `gpu` that is an error.

use pc_config::Backend;

use crate::cpu::RayCounts;
use crate::error::RenderError;
use crate::gpu::render::GpuRenderer;
use crate::image::Image;
use crate::refine;
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
    ) -> Result<Frame, RenderError> {
        if let Some((ctx, r)) = &self.gpu {
            match r
                .render(ctx, sc, aovs)
                .and_then(|img| refine_gpu(ctx, r, sc, img))
            {
                Ok((image, refined)) => {
                    return Ok(Frame {
                        image,
                        counts: None,
                        refined,
                    })
                }
                Err(e) if self.fallback => {
                    pc_stage::device::warn_fallback(crate::stage::STAGE, &ctx.describe(), &e);
                    self.gpu = None;
                    sc.prepare_cpu();
                }
                Err(e) => return Err(e.into()),
            }
        }
        let (mut img, counts) = crate::cpu::render(sc, aovs, tile_done);
        let pixels = to_refine(sc, &img);
        let (values, more) = crate::cpu::render_pixels(sc, &pixels, sc.refine.spp);
        refine::merge(&mut img, &pixels, &values);
        Ok(Frame {
            image: img,
            counts: Some(counts.plus(more)),
            refined: pixels.len(),
        })
    }
}

/// A rendered frame.
pub struct Frame {
    pub image: Image,
    /// Ray counts (the CPU's alone).
    pub counts: Option<RayCounts>,
    /// Pixels the second pass rendered again ([`crate::refine`]).
    pub refined: usize,
}

/// The second pass on the GPU ([`crate::refine`]).
fn refine_gpu(
    ctx: &pc_gpu::GpuContext,
    r: &GpuRenderer,
    sc: &RenderScene,
    mut img: Image,
) -> Result<(Image, usize), pc_gpu::GpuError> {
    let pixels = to_refine(sc, &img);
    let values = r.render_marked(ctx, sc, &pixels, sc.refine.spp)?;
    refine::merge(&mut img, &pixels, &values);
    Ok((img, pixels.len()))
}

/// The pixels of the first pass's `img` that the second pass renders again (none without one).
fn to_refine(sc: &RenderScene, img: &Image) -> Vec<u32> {
    match sc.refine.after(sc.params.spp) {
        true => refine::marked(img, sc.refine.contrast),
        false => Vec::new(),
    }
}
