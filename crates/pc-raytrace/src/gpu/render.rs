//! The GPU renderer: `shaders/raytrace/render.wgsl`, twin of `crate::cpu::render`.
//!
//! The octree artifact's sections (and the radiosity's) go into storage buffers as they are; the image is rendered in
//! bands of rows so that one dispatch stays short (drivers reset devices whose dispatches run
//! for seconds).

use bytemuck::{Pod, Zeroable};
use pc_gpu::{Binding, GpuContext, GpuError, Kernel};

use pc_tree::gpu::{GpuOctree, OctreeParts};

use crate::image::{Aovs, Image};
use crate::photon_grid::{PhotonGrid, PhotonGroup};
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
    /// Samples of a pixel one dispatch traces at most: all of them on a hardware GPU,
    /// [`SOFTWARE_SAMPLES`] on a software adapter.
    samples_per_invocation: u32,
    /// The output buffers of the image pass and of the second pass, kept from frame to frame.
    kept: std::sync::Mutex<[Option<FrameBuffers>; 2]>,
}

/// A pass's output buffer and its readback, kept from frame to frame: a walkthrough's frames
/// allocate neither (on the H200 a fresh 16 MB pair cost 5-7 ms of a 1024² frame).
struct FrameBuffers {
    out: pc_gpu::Buffer,
    back: pc_gpu::Readback,
}

/// The kernel's pass: samples a pixel, whether it writes AOVs, whether it renders the marked
/// pixels alone (the second pass).
#[derive(Clone, Copy)]
struct Pass {
    spp: u32,
    aovs: bool,
    marked: bool,
}

impl Pass {
    /// Index of the pass's kept buffers.
    fn slot(self) -> usize {
        self.marked as usize
    }
}

/// Storage buffers the kernel binds: the octree's and scene's 9, the output, and radiance,
/// photons, grid offsets, leaf roughness and photon groups.
const STORAGE_BUFFERS: u32 = 15;

/// Samples per dispatch; bands of rows are sized to stay under this.
const SAMPLES_PER_DISPATCH: u64 = 1 << 21;
/// Pixels a band of the second pass spans at most (its marks go up and its words come back).
const MARKED_BAND_PIXELS: u64 = 1 << 20;
/// Samples of a pixel one dispatch traces on a software adapter. llvmpipe ends a shader's loops
/// after 65535 iterations per invocation group, all loops together (Mesa's
/// `LP_MAX_TGSI_LOOP_ITERATIONS`), silently: a pixel's later samples were lost (16 samples of
/// a pixel beside a glass ball with three splits each kept 12; 1024 plain ones, 27). One sample
/// a dispatch keeps each invocation to one sample's walks and lookups (docs/raytrace.md,
/// "llvmpipe's loop limit").
const SOFTWARE_SAMPLES: u32 = 1;

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
        if limit < STORAGE_BUFFERS {
            return Err(GpuError::Device {
                adapter: ctx.describe(),
                msg: format!(
                    "the renderer needs {STORAGE_BUFFERS} storage buffers per stage, the adapter allows {limit}"
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
            samples_per_invocation: match ctx.is_software() {
                true => SOFTWARE_SAMPLES,
                false => u32::MAX,
            },
            kept: Default::default(),
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
        let pass = Pass {
            spp: sc.params.spp,
            aovs: with_aovs,
            marked: false,
        };
        let out_size = (w as u64) * (band as u64) * pixel_bytes(with_aovs);
        let mut img = Image::new(w, h);
        let mut aovs = with_aovs.then(|| Aovs {
            depth: vec![0.0; (w * h) as usize],
            normal: vec![[0.0; 3]; (w * h) as usize],
            albedo: vec![[0.0; 3]; (w * h) as usize],
            splat: vec![u32::MAX; (w * h) as usize],
        });
        self.with_buffers(ctx, pass, out_size, |fb| {
            let mut row = 0;
            while row < h {
                let rows = band.min(h - row);
                let at = (row * w) as usize;
                let n = (w * rows) as usize;
                let rgb = &mut img.rgb[at..at + n];
                self.band(ctx, sc, (row, rows), pass, fb, |bytes| {
                    match aovs.as_mut() {
                        Some(a) => unpack_aovs(bytemuck::cast_slice(bytes), rgb, a, at),
                        None => unpack_rgb(bytemuck::cast_slice(bytes), rgb),
                    }
                })?;
                row += rows;
            }
            Ok(())
        })?;
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
        let pass = Pass {
            spp,
            aovs: false,
            marked: true,
        };
        let size = w as u64 * max_rows as u64 * pixel_bytes(false);
        let mut rgb = Vec::with_capacity(pixels.len());
        self.with_buffers(ctx, pass, size, |fb| {
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
                ctx.write(&fb.out, bytemuck::cast_slice(&words));
                let stray = self.band(ctx, sc, (row, rows), pass, fb, |bytes| {
                    let back: &[[u32; 4]] = bytemuck::cast_slice(bytes);
                    let stray = back
                        .iter()
                        .zip(&words)
                        .any(|(b, w)| w[3] != crate::refine::MARK && b != w);
                    rgb.extend(here.iter().map(|&i| {
                        let p = back[(i - at) as usize];
                        [p[0], p[1], p[2]].map(f32::from_bits)
                    }));
                    stray
                })?;
                if stray {
                    return Err(GpuError::Device {
                        adapter: ctx.describe(),
                        msg: "the renderer's second pass wrote pixels it was not asked for".into(),
                    });
                }
                rest = &rest[here.len()..];
            }
            Ok(())
        })?;
        Ok(rgb)
    }

    /// Run `f` with `pass`'s kept buffers, made (or remade larger) to hold `bytes`.
    fn with_buffers<R>(
        &self,
        ctx: &GpuContext,
        pass: Pass,
        bytes: u64,
        f: impl FnOnce(&FrameBuffers) -> Result<R, GpuError>,
    ) -> Result<R, GpuError> {
        let mut kept = match self.kept.lock() {
            Ok(kept) => kept,
            Err(poisoned) => {
                // A pass panicked while holding them: make them afresh.
                let mut kept = poisoned.into_inner();
                *kept = Default::default();
                kept
            }
        };
        let slot = &mut kept[pass.slot()];
        if slot.as_ref().is_none_or(|fb| fb.back.capacity() < bytes) {
            *slot = Some(FrameBuffers {
                out: ctx.output("pixels", bytes)?,
                back: pc_gpu::Readback::new(ctx, bytes),
            });
        }
        let out = f(slot.as_ref().expect("made above"));
        if out.is_err() {
            *slot = None; // a failed pass's buffers are not trusted again
        }
        out
    }

    /// The dispatches over the image rows `row..row + rows` into `fb`'s output, read back into
    /// `f` (`pass.marked`: only the pixels the host marked in the output): one, or on a software
    /// adapter one a sample, each adding its samples to the sums the one before left in the
    /// output (the CPU's order of addition).
    fn band<R>(
        &self,
        ctx: &GpuContext,
        sc: &RenderScene,
        (row, rows): (u32, u32),
        pass: Pass,
        fb: &FrameBuffers,
        f: impl FnOnce(&[u8]) -> R,
    ) -> Result<R, GpuError> {
        let g = &self.grid;
        let w = sc.params.width;
        let mut first = 0;
        while first < pass.spp {
            let count = self.samples_per_invocation.min(pass.spp - first);
            let params = Params {
                spp: pass.spp,
                sample_offset: first,
                sample_count: count,
                row_offset: row,
                rows,
                caustic_radius: g.caustic_radius,
                grid_origin: g.grid_origin,
                grid_mask: g.grid_mask,
                photon_count: g.photon_count,
                grid_cell: g.grid_cell,
                aovs: pass.aovs as u32,
                refine: pass.marked as u32,
                ..sc.params
            };
            let uniform = ctx.uniform("params", bytemuck::bytes_of(&params));
            let mut bind: Vec<&pc_gpu::Buffer> =
                self.octree.buffers().chain(&self.buffers).collect();
            bind.push(&uniform);
            bind.push(&fb.out);
            bind.push(&self.radiance);
            bind.push(&self.photons.photons);
            bind.push(&self.photons.offsets);
            bind.push(&self.leaf_rough);
            bind.push(&self.photons.groups);
            self.kernel
                .run(ctx, &bind, (w.div_ceil(8), rows.div_ceil(8), 1))?;
            first += count;
        }
        let size = (w * rows) as u64 * pixel_bytes(pass.aovs);
        fb.back.read(ctx, &fb.out, size, f)
    }
}

/// A band's colours (the first word of each pixel's four) into `rgb`, in parallel.
fn unpack_rgb(px: &[[f32; 4]], rgb: &mut [[f32; 3]]) {
    use rayon::prelude::*;
    rgb.par_chunks_mut(4096)
        .zip(px.par_chunks(4096))
        .for_each(|(d, s)| {
            for (d, p) in d.iter_mut().zip(s) {
                *d = [p[0], p[1], p[2]];
            }
        });
}

/// A band's pixels with AOVs into `rgb` and `a` (from pixel `at` of the image).
fn unpack_aovs(px: &[PixelOut], rgb: &mut [[f32; 3]], a: &mut Aovs, at: usize) {
    for (i, p) in px.iter().enumerate() {
        rgb[i] = p.rgb;
        a.depth[at + i] = p.depth;
        a.normal[at + i] = p.normal;
        a.albedo[at + i] = p.albedo;
        a.splat[at + i] = p.splat;
    }
}

/// One [`PhotonGroup`]'s bytes: the placeholder of a map without groups.
const GROUP_BYTES: usize = std::mem::size_of::<PhotonGroup>();

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
                groups: ctx.storage("photon_groups", &[0u8; GROUP_BYTES])?,
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
        true => &[0u8; GROUP_BYTES],
        false => bytemuck::cast_slice(&g.groups),
    };
    let buffers = PhotonBuffers {
        photons: ctx.storage("photons", bytemuck::cast_slice(&g.photons))?,
        offsets: ctx.storage("grid_offsets", bytemuck::cast_slice(&g.offsets))?,
        groups: ctx.storage("photon_groups", groups)?,
    };
    Ok((grid, buffers))
}
