//! The GPU photon tracer: `shaders/caustics/photons.wgsl`, twin of [`crate::trace::Tracer`].
//!
//! One thread per photon id, in dispatches of [`PHOTONS_PER_DISPATCH`] ids (drivers reset devices
//! whose dispatches run for seconds). Each thread writes its photon's fate into its own slot, and
//! the host keeps the stored ones in id order, so the photon list comes out in the order of the
//! CPU twin's [`crate::stage::trace_all`]. Both sides draw the same counter-based random numbers
//! (`pc_tree::rng`), so a photon follows the same path on both up to floating-point rounding.

use bytemuck::{Pod, Zeroable};
use pc_artifact::octree::MaterialRecord;
use pc_artifact::photons::Photon;
use pc_gpu::{grid, Bind, Binding, GpuContext, GpuError, Kernel};
use pc_tree::gpu::{GpuOctree, OctreeParts};
use pc_tree::OctreeView;

use crate::emit::{Aim, Leaves, Sampling, Source};
use crate::stage::Traced;
use crate::trace::Fate;

/// The kernel's source (`shaders/caustics/photons.wgsl` with the files it requires).
pub fn source() -> Result<String, GpuError> {
    pc_gpu::shaders::source("caustics/photons.wgsl")
}

/// Photon ids per dispatch.
pub const PHOTONS_PER_DISPATCH: u32 = 1 << 18;

/// WGSL `Leaf`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct GpuLeaf {
    lo: u32,
    hi: u32,
    area: f32,
    _pad: u32,
}

/// WGSL `Aim`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct GpuAim {
    origin: [f32; 3],
    source_leaf: u32,
    power: [f32; 3],
    target_leaf: u32,
    first: u32,
    sampling: u32,
    k: f32,
    lo: u32,
    hi: u32,
    node: u32,
    _pad: [u32; 2],
}

/// WGSL `PhotonParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct GpuParams {
    seed: u32,
    max_bounces: u32,
    aim_count: u32,
    id_offset: u32,
    count: u32,
    _pad: [u32; 3],
}

/// WGSL `PhotonOut` fates.
const FATE_STORED: u32 = 0;
const FATE_OCCLUDED: u32 = 1;
const FATE_LOST: u32 = 2;

/// The scene on the GPU and the compiled kernel.
pub struct GpuTracer {
    kernel: Kernel,
    octree: GpuOctree,
    /// Materials and leaves, bound after the octree.
    buffers: Vec<pc_gpu::Buffer>,
    /// Each octree leaf's roughness, bound last.
    rough: pc_gpu::Buffer,
    max_bounces: u32,
    seed: u32,
}

impl GpuTracer {
    /// Upload the octree, the materials, the leaves and each octree leaf's roughness `rough`;
    /// `max_bounces` and `seed` as in [`crate::trace::Tracer`].
    pub fn new(
        ctx: &GpuContext,
        (view, rough): (&OctreeView, &[f32]),
        materials: &[MaterialRecord],
        leaves: &Leaves,
        max_bounces: u32,
        seed: u32,
    ) -> Result<GpuTracer, GpuError> {
        let limit = ctx.device.limits().max_storage_buffers_per_shader_stage;
        if limit < 11 {
            return Err(GpuError::Device {
                adapter: ctx.describe(),
                msg: format!(
                    "the photon tracer needs 11 storage buffers per stage, the adapter allows {limit}"
                ),
            });
        }
        let mut b = vec![Binding::Uniform];
        b.extend([Binding::ReadOnly; 9]);
        b.push(Binding::Uniform);
        b.push(Binding::ReadWrite);
        b.push(Binding::ReadOnly);
        let kernel = ctx.kernel("caustics/photons", &source()?, "main", &b)?;
        let gl: Vec<GpuLeaf> = leaves
            .leaves
            .iter()
            .map(|l| GpuLeaf {
                lo: l.lo,
                hi: l.hi,
                area: l.area,
                _pad: 0,
            })
            .collect();
        let octree = GpuOctree::upload(ctx, view, OctreeParts::Shade)?;
        let buffers = vec![
            ctx.storage("materials", bytemuck::cast_slice(materials))?,
            ctx.storage("leaves", bytemuck::cast_slice(&gl))?,
        ];
        Ok(GpuTracer {
            kernel,
            octree,
            buffers,
            rough: ctx.storage("leaf_rough", bytemuck::cast_slice(rough))?,
            max_bounces,
            seed,
        })
    }

    /// Trace every photon of `aims` (ids in aim order, as [`crate::stage::trace_all`]);
    /// `progress` gets the photons done after each dispatch.
    pub fn trace_all(
        &self,
        ctx: &GpuContext,
        aims: &[Aim],
        progress: &dyn Fn(u64),
    ) -> Result<Traced, GpuError> {
        let mut out = Traced::default();
        self.dispatch_all(ctx, aims, &mut |start, slots| {
            for (k, p) in slots.iter().enumerate() {
                match p._pad {
                    FATE_STORED => {
                        out.photons.push(Photon { _pad: 0, ..*p });
                        out.id.push((start + k as u64) as u32);
                    }
                    FATE_OCCLUDED => out.occluded += 1,
                    _ => out.lost += 1,
                }
            }
            out.traced += slots.len() as u64;
            progress(slots.len() as u64);
        })?;
        Ok(out)
    }

    /// The fate of every photon of `aims`, by id (for tests against the CPU twin).
    pub fn fates(&self, ctx: &GpuContext, aims: &[Aim]) -> Result<Vec<Fate>, GpuError> {
        let mut out = Vec::new();
        self.dispatch_all(ctx, aims, &mut |_, slots| {
            out.extend(slots.iter().map(|p| match p._pad {
                FATE_STORED => Fate::Stored(Photon { _pad: 0, ..*p }),
                FATE_OCCLUDED => Fate::Occluded,
                FATE_LOST => Fate::Lost,
                _ => Fate::Absorbed,
            }))
        })?;
        Ok(out)
    }

    /// Run the kernel over every photon id of `aims`, handing each dispatch's slots (photon
    /// records with the fate in `_pad`, and the id of the first) to `sink` in id order.
    fn dispatch_all(
        &self,
        ctx: &GpuContext,
        aims: &[Aim],
        sink: &mut dyn FnMut(u64, &[Photon]),
    ) -> Result<(), GpuError> {
        let mut ga = Vec::with_capacity(aims.len());
        let mut total = 0u64;
        for a in aims.iter().filter(|a| a.photons > 0) {
            let (origin, source_leaf) = match a.source {
                Source::Point(p) => (p.into(), u32::MAX),
                Source::Area(e) => ([0.0; 3], e),
            };
            let (sampling, k, lo, hi, node) = match a.sampling {
                Sampling::Whole => (0, 0.0, 0, 0, 0),
                Sampling::Area { k } => (1, k, 0, 0, 0),
                Sampling::Direction { k, lo, hi, node } => (2, k, lo, hi, node),
            };
            ga.push(GpuAim {
                origin,
                source_leaf,
                power: a.power,
                target_leaf: a.target,
                first: total as u32,
                sampling,
                k,
                lo,
                hi,
                node,
                _pad: [0; 2],
            });
            total += a.photons as u64;
        }
        if total > u32::MAX as u64 {
            return Err(GpuError::Device {
                adapter: ctx.describe(),
                msg: format!("{total} photons do not fit 32-bit photon ids"),
            });
        }
        if total == 0 {
            return Ok(());
        }
        // Bound in windows: a dispatch reads only the aims its photon ids fall in, so any
        // number of aims fits a device's binding limit (llvmpipe's 128 MiB refused the default
        // budget's 2.4M aims of a small scene).
        let aims_buf = ctx.storage_windowed("aims", bytemuck::cast_slice(&ga))?;
        let record = std::mem::size_of::<GpuAim>();
        let align = (ctx.device.limits().min_storage_buffer_offset_alignment as usize)
            .div_ceil(record)
            .max(1);
        let per = PHOTONS_PER_DISPATCH.min(total as u32);
        let size = per as u64 * std::mem::size_of::<Photon>() as u64;
        let photons_buf = ctx.output("photons", size)?;
        let mut done = 0u64;
        while done < total {
            let count = (total - done).min(per as u64) as u32;
            let (lo, hi) = aim_window(&ga, done, count, align);
            let params = GpuParams {
                seed: self.seed,
                max_bounces: self.max_bounces,
                aim_count: (hi - lo) as u32,
                id_offset: done as u32,
                count,
                _pad: [0; 3],
            };
            let pb = ctx.uniform("photon_params", bytemuck::bytes_of(&params));
            let mut bind: Vec<Bind> = self
                .octree
                .buffers()
                .chain(&self.buffers)
                .map(Bind::whole)
                .collect();
            let bytes = |i: usize| (i * record) as u64;
            bind.push(Bind::window(&aims_buf, bytes(lo), bytes(hi - lo)));
            bind.push(Bind::whole(&pb));
            bind.push(Bind::whole(&photons_buf));
            bind.push(Bind::whole(&self.rough));
            self.kernel.run_binds(ctx, &bind, grid(count, 64))?;
            let bytes = ctx.read(
                &photons_buf,
                count as u64 * std::mem::size_of::<Photon>() as u64,
            )?;
            // A copy: the readback bytes carry no alignment guarantee for the cast.
            let slots: Vec<Photon> = bytemuck::pod_collect_to_vec(&bytes);
            sink(done, &slots);
            done += count as u64;
        }
        Ok(())
    }
}

/// The aims that photon ids `first .. first + count` fall in, `[lo, hi)` with `lo` a multiple of
/// `align` (the binding offset's alignment, in records): ids are numbered aim after aim
/// (`first` rising), and the kernel finds an id's aim by binary search within the window.
fn aim_window(aims: &[GpuAim], first: u64, count: u32, align: usize) -> (usize, usize) {
    let end = first + count as u64;
    let lo = aims
        .partition_point(|a| a.first as u64 <= first)
        .saturating_sub(1);
    let hi = aims.partition_point(|a| (a.first as u64) < end);
    (lo / align * align, hi.max(lo + 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A window holds every aim its ids fall in, starts aligned, and no more than that.
    #[test]
    fn aim_windows_cover_their_ids() {
        let firsts = [0u32, 3, 4, 10, 11, 20];
        let aims: Vec<GpuAim> = firsts
            .iter()
            .map(|&first| GpuAim {
                first,
                ..Default::default()
            })
            .collect();
        let total = 25u64;
        for align in [1, 2, 4] {
            for first in 0..total {
                for count in 1..=(total - first) as u32 {
                    let (lo, hi) = aim_window(&aims, first, count, align);
                    assert_eq!(lo % align, 0);
                    let owner = |id: u64| firsts.iter().rposition(|&f| f as u64 <= id).unwrap();
                    for id in first..first + count as u64 {
                        assert!((lo..hi).contains(&owner(id)), "{first} {count} {align}");
                    }
                    assert!(hi <= owner(first + count as u64 - 1) + 1);
                }
            }
        }
    }

    /// The kernel validates, and its records have the sizes and offsets of the Rust ones.
    #[test]
    fn wgsl_records_match_rust_layouts() {
        let module = pc_gpu::validate_wgsl(&source().unwrap()).unwrap();
        for (name, size) in [
            ("Leaf", std::mem::size_of::<GpuLeaf>()),
            ("Aim", std::mem::size_of::<GpuAim>()),
            ("PhotonParams", std::mem::size_of::<GpuParams>()),
            ("PhotonOut", std::mem::size_of::<Photon>()),
            ("Material", std::mem::size_of::<MaterialRecord>()),
        ] {
            let (wsize, _) = pc_gpu::wgsl_struct_layout(&module, name)
                .unwrap_or_else(|| panic!("no struct {name}"));
            assert_eq!(wsize as usize, size, "{name}");
        }
        let off = |s: &str, m: &str| {
            let (_, members) = pc_gpu::wgsl_struct_layout(&module, s).unwrap();
            members.iter().find(|x| x.0 == m).unwrap().1 as usize
        };
        assert_eq!(off("Aim", "power"), std::mem::offset_of!(GpuAim, power));
        assert_eq!(off("Aim", "first"), std::mem::offset_of!(GpuAim, first));
        assert_eq!(off("Aim", "k"), std::mem::offset_of!(GpuAim, k));
        assert_eq!(off("Aim", "hi"), std::mem::offset_of!(GpuAim, hi));
        assert_eq!(
            off("PhotonParams", "id_offset"),
            std::mem::offset_of!(GpuParams, id_offset)
        );
        assert_eq!(
            off("PhotonOut", "power"),
            std::mem::offset_of!(Photon, power)
        );
        assert_eq!(off("PhotonOut", "fate"), std::mem::offset_of!(Photon, _pad));
    }
}
