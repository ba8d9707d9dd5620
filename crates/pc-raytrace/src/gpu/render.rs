//! The GPU renderer: `shaders/raytrace/render.wgsl`, twin of `crate::cpu::render`.
//!
//! The octree artifact's sections (and the radiosity's) go into storage buffers as they are; the image is rendered in
//! bands of rows so that one dispatch stays short (drivers reset devices whose dispatches run
//! for seconds).

use bytemuck::{Pod, Zeroable};
use pc_gpu::{Binding, GpuContext, GpuError, Kernel};

use pc_tree::gpu::{GpuOctree, OctreeParts};

use crate::caustic::PhotonGrid;
use crate::image::{Aovs, Image};
use crate::scene::{Params, RenderScene};

/// The kernel's source (`shaders/raytrace/render.wgsl` with the files it requires).
pub fn source() -> Result<String, GpuError> {
    pc_gpu::shaders::source("raytrace/render.wgsl")
}

/// One output pixel (WGSL `PixelOut`), as the kernel writes it when AOVs are asked for: three
/// words of four; without AOVs it writes the first word alone (colour and depth).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct PixelOut {
    pub rgb: [f32; 3],
    pub depth: f32,
    pub normal: [f32; 3],
    pub splat: u32,
    pub albedo: [f32; 3],
    pub _pad: u32,
}

/// Scene buffers uploaded once, and the compiled kernel.
pub struct GpuRenderer {
    kernel: Kernel,
    octree: GpuOctree,
    /// Materials, lights and emitters, bound after the octree.
    buffers: Vec<pc_gpu::Buffer>,
    radiance: pc_gpu::Buffer,
    photons: PhotonBuffers,
    leaf_rough: pc_gpu::Buffer,
    /// The photon-map fields of [`Params`].
    grid: Params,
    /// Samples one dispatch traces at most ([`SAMPLES_PER_DISPATCH`]).
    samples_per_dispatch: u64,
}

/// Samples per dispatch; bands of rows are sized to stay under this.
const SAMPLES_PER_DISPATCH: u64 = 1 << 21;
/// Pixels a band of the second pass spans at most (its marks go up and its words come back).
const MARKED_BAND_PIXELS: u64 = 1 << 20;

/// Bytes the kernel writes a pixel: [`PixelOut`] with AOVs, else one word of four (its first).
fn pixel_bytes(with_aovs: bool) -> u64 {
    match with_aovs {
        true => std::mem::size_of::<PixelOut>() as u64,
        false => std::mem::size_of::<[u32; 4]>() as u64,
    }
}

impl GpuRenderer {
    pub fn new(ctx: &GpuContext, sc: &RenderScene) -> Result<GpuRenderer, GpuError> {
        let mut b = vec![Binding::Uniform];
        b.extend([Binding::ReadOnly; 9]);
        b.push(Binding::Uniform);
        b.push(Binding::ReadWrite);
        b.extend([Binding::ReadOnly; 5]);
        let limit = ctx.device.limits().max_storage_buffers_per_shader_stage;
        if limit < 14 {
            return Err(GpuError::Device {
                adapter: ctx.describe(),
                msg: format!(
                    "the renderer needs 14 storage buffers per stage, the adapter allows {limit}"
                ),
            });
        }
        let kernel = ctx.kernel("raytrace/render", &source()?, "main", &b)?;
        let emitters: Vec<[u32; 2]> = sc
            .emitters
            .splats
            .iter()
            .zip(&sc.emitters.cdf)
            .map(|(&i, &c)| [i, c.to_bits()])
            .collect();
        let octree = GpuOctree::upload(ctx, &sc.view, OctreeParts::Shade)?;
        let buffers = vec![
            ctx.storage("materials", bytemuck::cast_slice(&sc.materials))?,
            ctx.storage("lights", bytemuck::cast_slice(&sc.lights))?,
            ctx.storage("emitters", bytemuck::cast_slice(&emitters))?,
        ];
        // The leaves' roughness for direct mode's shadow rays (one unused word otherwise).
        let leaf_rough = match sc.rough.is_empty() {
            true => ctx.storage("leaf_rough", &[0u8; 4])?,
            false => ctx.storage("leaf_rough", bytemuck::cast_slice(&sc.rough))?,
        };
        // The radiosity artifact's mapped section, as it is.
        let radiance = match sc.radiance {
            Some(r) => ctx.storage("radiance", bytemuck::cast_slice(r))?,
            None => ctx.storage("radiance", &[0u8; 16])?,
        };
        let (grid, photons) = photon_buffers(ctx, sc)?;
        Ok(GpuRenderer {
            kernel,
            octree,
            buffers,
            radiance,
            photons,
            leaf_rough,
            grid,
            samples_per_dispatch: SAMPLES_PER_DISPATCH,
        })
    }

    /// Dispatches of at most `n` samples (at least a row's, or a marked pixel's): smaller ones
    /// split a small image into several bands (tests).
    pub fn with_samples_per_dispatch(mut self, n: u64) -> GpuRenderer {
        self.samples_per_dispatch = n.max(1);
        self
    }

    /// Render the image (bands of rows, each a dispatch of 8×8 pixel blocks).
    pub fn render(
        &self,
        ctx: &GpuContext,
        sc: &RenderScene,
        with_aovs: bool,
    ) -> Result<Image, GpuError> {
        let (w, h) = (sc.params.width, sc.params.height);
        let per_row = w as u64 * sc.params.spp as u64;
        let band = (self.samples_per_dispatch / per_row.max(1)).clamp(1, h as u64) as u32;
        let out_size = (w as u64) * (band as u64) * pixel_bytes(with_aovs);
        let out = ctx.output("pixels", out_size)?;
        let mut img = Image::new(w, h);
        let mut aovs = with_aovs.then(|| Aovs {
            depth: vec![0.0; (w * h) as usize],
            normal: vec![[0.0; 3]; (w * h) as usize],
            albedo: vec![[0.0; 3]; (w * h) as usize],
            splat: vec![u32::MAX; (w * h) as usize],
        });
        let mut row = 0;
        while row < h {
            let rows = band.min(h - row);
            let bytes = self.band(ctx, sc, (row, rows), sc.params.spp, with_aovs, false, &out)?;
            let at = (row * w) as usize;
            match aovs.as_mut() {
                Some(a) => {
                    let px: &[PixelOut] = bytemuck::cast_slice(&bytes);
                    for (i, p) in px.iter().enumerate() {
                        img.rgb[at + i] = p.rgb;
                        a.depth[at + i] = p.depth;
                        a.normal[at + i] = p.normal;
                        a.albedo[at + i] = p.albedo;
                        a.splat[at + i] = p.splat;
                    }
                }
                None => {
                    let px: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
                    for (i, p) in px.iter().enumerate() {
                        img.rgb[at + i] = [p[0], p[1], p[2]];
                    }
                }
            }
            row += rows;
        }
        img.aovs = aovs;
        Ok(img)
    }

    /// The colours of `pixels` (row-major indices, ascending) at `spp` samples each (the pattern
    /// of `spp`): the second pass of [`crate::refine`]. Band by band, the host marks the band's
    /// pixels in the output buffer ([`crate::refine::MARK`]) and the kernel renders those alone;
    /// a band holds as many marked pixels as one dispatch's samples allow, over at most
    /// [`MARKED_BAND_PIXELS`] pixels. A word the kernel was not asked for must come back as the
    /// host wrote it, else the pass fails (and `auto` falls back to the CPU).
    pub fn render_marked(
        &self,
        ctx: &GpuContext,
        sc: &RenderScene,
        pixels: &[u32],
        spp: u32,
    ) -> Result<Vec<[f32; 3]>, GpuError> {
        if pixels.is_empty() {
            return Ok(Vec::new()); // no buffer to make for nothing
        }
        let (w, h) = (sc.params.width, sc.params.height);
        let max_rows = (MARKED_BAND_PIXELS / w as u64).clamp(1, h as u64) as u32;
        let per_band = (self.samples_per_dispatch / spp.max(1) as u64).max(1) as usize;
        let out = ctx.output("pixels", w as u64 * max_rows as u64 * pixel_bytes(false))?;
        let mut rgb = Vec::with_capacity(pixels.len());
        let mut rest = pixels;
        while let Some(&first) = rest.first() {
            let row = first / w;
            let end = (row + max_rows).min(h) * w;
            let here = &rest[..rest.len().min(per_band)];
            let here = &here[..here.iter().take_while(|&&i| i < end).count()];
            let rows = here[here.len() - 1] / w - row + 1;
            let at = row * w;
            let mut words = vec![[0u32; 4]; (w * rows) as usize];
            for &i in here {
                words[(i - at) as usize][3] = crate::refine::MARK;
            }
            ctx.write(&out, bytemuck::cast_slice(&words));
            let bytes = self.band(ctx, sc, (row, rows), spp, false, true, &out)?;
            let back: &[[u32; 4]] = bytemuck::cast_slice(&bytes);
            let stray = back
                .iter()
                .zip(&words)
                .any(|(b, w)| w[3] != crate::refine::MARK && b != w);
            if stray {
                return Err(GpuError::Device {
                    adapter: ctx.describe(),
                    msg: "the renderer's second pass wrote pixels it was not asked for".into(),
                });
            }
            rgb.extend(here.iter().map(|&i| {
                let p = back[(i - at) as usize];
                [p[0], p[1], p[2]].map(f32::from_bits)
            }));
            rest = &rest[here.len()..];
        }
        Ok(rgb)
    }

    /// One dispatch over the image rows `row..row + rows` at `spp` samples a pixel into `out`,
    /// read back (`marked`: only the pixels the host marked in `out`).
    // (The dispatch's rows, sample count and output: seven arguments.)
    #[allow(clippy::too_many_arguments)]
    fn band(
        &self,
        ctx: &GpuContext,
        sc: &RenderScene,
        (row, rows): (u32, u32),
        spp: u32,
        with_aovs: bool,
        marked: bool,
        out: &pc_gpu::Buffer,
    ) -> Result<Vec<u8>, GpuError> {
        let g = &self.grid;
        let params = Params {
            spp,
            row_offset: row,
            rows,
            caustic_radius: g.caustic_radius,
            grid_origin: g.grid_origin,
            grid_mask: g.grid_mask,
            photon_count: g.photon_count,
            grid_cell: g.grid_cell,
            aovs: with_aovs as u32,
            refine: marked as u32,
            ..sc.params
        };
        let uniform = ctx.uniform("params", bytemuck::bytes_of(&params));
        let mut bind: Vec<&pc_gpu::Buffer> = self.octree.buffers().chain(&self.buffers).collect();
        bind.push(&uniform);
        bind.push(out);
        bind.push(&self.radiance);
        bind.push(&self.photons.photons);
        bind.push(&self.photons.offsets);
        bind.push(&self.leaf_rough);
        bind.push(&self.photons.groups);
        let w = sc.params.width;
        self.kernel
            .run(ctx, &bind, (w.div_ceil(8), rows.div_ceil(8), 1))?;
        ctx.read(out, (w * rows) as u64 * pixel_bytes(with_aovs))
    }
}

/// The photon map's buffers (crate::photon_grid::PhotonGrid): photons, offsets, groups.
struct PhotonBuffers {
    photons: pc_gpu::Buffer,
    offsets: pc_gpu::Buffer,
    groups: pc_gpu::Buffer,
}

/// The photon-map fields of [`Params`] and the grid's buffers (placeholders without a map).
fn photon_buffers(ctx: &GpuContext, sc: &RenderScene) -> Result<(Params, PhotonBuffers), GpuError> {
    let mut grid = Params::default();
    let c = match &sc.caustics {
        Some(c) if c.k > 0 => {
            return Err(GpuError::Device {
                adapter: ctx.describe(),
                msg: format!(
                    "the GPU renderer's caustic estimate is fixed-radius only \
                     (raytrace.caustic_k = {}: k-nearest renders on the CPU)",
                    c.k
                ),
            })
        }
        Some(c) if !c.photons.is_empty() => c,
        _ => {
            let buffers = PhotonBuffers {
                photons: ctx.storage("photons", &[0u8; 48])?,
                offsets: ctx.storage("grid_offsets", &[0u8; 8])?,
                groups: ctx.storage("photon_groups", &[0u8; 64])?,
            };
            return Ok((grid, buffers));
        }
    };
    let g = PhotonGrid::new(c.photons, c.radius);
    grid.caustic_radius = g.radius;
    grid.grid_origin = g.origin;
    grid.grid_mask = g.mask;
    grid.photon_count = g.photons.len() as u32;
    grid.grid_cell = g.cell;
    let groups: &[u8] = match g.groups.is_empty() {
        true => &[0u8; 64],
        false => bytemuck::cast_slice(&g.groups),
    };
    let buffers = PhotonBuffers {
        photons: ctx.storage("photons", bytemuck::cast_slice(&g.photons))?,
        offsets: ctx.storage("grid_offsets", bytemuck::cast_slice(&g.offsets))?,
        groups: ctx.storage("photon_groups", groups)?,
    };
    Ok((grid, buffers))
}
