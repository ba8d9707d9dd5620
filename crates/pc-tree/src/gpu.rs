//! The octree on the GPU ([`GpuOctree`], the one upload every kernel binds) and ray casting on
//! the GPU: `shaders/tree/cast.wgsl`, twin of [`crate::intersect`] and [`crate::occluded`],
//! shared by every stage that casts rays in bulk.

use bytemuck::{Pod, Zeroable};
use pc_gpu::{grid, Binding, GpuContext, GpuError, Kernel};
use rayon::prelude::*;

use crate::accel::POOL_SLAB_WORDS;
use crate::{OctreeView, Ray};

/// How much of the octree a kernel binds. The sections go into bindings 0, 1, 2, … in the
/// order of `shaders/common/octree.wgsl`: frame (uniform), nodes, begin/end table, splats,
/// node info, splat areas, splat leaves; each part includes the ones before it. For the walk
/// the nodes' buffer holds after the pool each slot's slab ([`crate::accel::Accel::pool_slabs`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OctreeParts {
    /// Frame and nodes: point location.
    Locate,
    /// And the begin/end table and the splats: the traversal.
    Walk,
    /// And the node info, splat areas and splat leaves: shading and photons.
    Shade,
}

/// The octree's sections in GPU buffers, in binding order.
pub struct GpuOctree {
    buffers: Vec<pc_gpu::Buffer>,
}

impl GpuOctree {
    /// Uploads `parts` of `view` (the mapped sections go into buffers as they are).
    pub fn upload(
        ctx: &GpuContext,
        view: &OctreeView,
        parts: OctreeParts,
    ) -> Result<GpuOctree, GpuError> {
        GpuOctree::upload_with(ctx, view, parts, true)
    }

    /// [`Self::upload`], the walk's slabs all switched off where `slabs` is false: the walk
    /// then visits every cell of the pool (the same hits; for comparisons).
    pub fn upload_with(
        ctx: &GpuContext,
        view: &OctreeView,
        parts: OctreeParts,
        slabs: bool,
    ) -> Result<GpuOctree, GpuError> {
        let nodes = match parts {
            OctreeParts::Locate => ctx.storage("nodes", bytemuck::cast_slice(view.nodes))?,
            // The walk's slabs by slot follow the pool (`trace_between` finds them past
            // `node_count`): the GPU skips and jumps by them as the CPU walk does.
            _ => {
                let slabs = match slabs {
                    true => crate::accel::Accel::new(view).pool_slabs(view),
                    false => vec![[0; POOL_SLAB_WORDS]; view.nodes.len()],
                };
                let mut words = Vec::with_capacity(view.nodes.len() * (1 + POOL_SLAB_WORDS));
                words.extend_from_slice(view.nodes);
                words.extend(slabs.iter().flatten());
                ctx.storage("nodes", bytemuck::cast_slice(&words))?
            }
        };
        // The pool's length as the walk finds its slabs by it (the artifact's frame says so
        // too, written by pc-octree, but the shader must not trust a file for an offset).
        let frame = pc_artifact::octree::Frame {
            node_count: view.nodes.len() as u32,
            ..view.frame
        };
        let mut buffers = vec![ctx.uniform("frame", bytemuck::bytes_of(&frame)), nodes];
        if parts != OctreeParts::Locate {
            buffers.push(ctx.storage("begin_end", bytemuck::cast_slice(view.begin_end))?);
            buffers.push(ctx.storage("splats", bytemuck::cast_slice(view.splats))?);
        }
        if parts == OctreeParts::Shade {
            buffers.push(ctx.storage("node_info", bytemuck::cast_slice(view.node_info))?);
            buffers.push(ctx.storage("splat_area", bytemuck::cast_slice(view.splat_area))?);
            buffers.push(ctx.storage("splat_leaf", bytemuck::cast_slice(view.splat_leaf))?);
        }
        Ok(GpuOctree { buffers })
    }

    /// The buffers, in binding order from 0.
    pub fn buffers(&self) -> impl Iterator<Item = &pc_gpu::Buffer> {
        self.buffers.iter()
    }
}

/// The cast kernel's source (`shaders/tree/cast.wgsl` with the files it requires).
pub fn cast_source() -> Result<String, GpuError> {
    pc_gpu::shaders::source("tree/cast.wgsl")
}

/// One ray as the kernel reads it (WGSL `RayIn`), with the surfaces its ends ignore
/// ([`crate::between::Between`]; a plain ray: none).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RayIn {
    pub origin: [f32; 3],
    pub t_min: f32,
    pub dir: [f32; 3],
    pub t_max: f32,
    /// Per end: its own surface.
    pub own: [OwnIn; 2],
    /// Where the first end's own zone ends and the second's begins.
    pub zones: [f32; 2],
    pub _pad: [f32; 2],
}

/// An end's own surface as the kernel reads it (WGSL `Own`; [`crate::between::Own`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct OwnIn {
    pub normal: [f32; 3],
    pub material: u32,
}

impl From<&Ray> for RayIn {
    fn from(r: &Ray) -> RayIn {
        RayIn::from(&crate::between::Between::plain(*r))
    }
}

impl From<&crate::between::Between> for RayIn {
    fn from(b: &crate::between::Between) -> RayIn {
        let r = &b.ray;
        let own = b.ends.map(|e| OwnIn {
            normal: e.normal.into(),
            material: e.material,
        });
        RayIn {
            origin: r.origin.into(),
            t_min: r.t_min,
            dir: r.dir.into(),
            t_max: r.t_max.min(f32::MAX),
            own,
            // (Infinite zones become the largest floats: WGSL has no infinities.)
            zones: b.zones.map(|z| z.clamp(-f32::MAX, f32::MAX)),
            _pad: [0.0; 2],
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct CastParams {
    count: u32,
    any_hit: u32,
    _pad: [u32; 2],
}

/// The octree on the GPU and a compiled cast kernel.
pub struct RayCaster {
    kernel: Kernel,
    tree: GpuOctree,
}

/// Rays per dispatch (bounded so a dispatch stays short).
const RAYS_PER_DISPATCH: usize = 1 << 22;

impl RayCaster {
    pub fn new(ctx: &GpuContext, view: &OctreeView) -> Result<RayCaster, GpuError> {
        RayCaster::with_slabs(ctx, view, true)
    }

    /// [`Self::new`], its walk without the slabs where `slabs` is false
    /// ([`GpuOctree::upload_with`]).
    pub fn with_slabs(
        ctx: &GpuContext,
        view: &OctreeView,
        slabs: bool,
    ) -> Result<RayCaster, GpuError> {
        let b = [
            Binding::Uniform,
            Binding::ReadOnly,
            Binding::ReadOnly,
            Binding::ReadOnly,
            Binding::ReadOnly,
            Binding::Uniform,
            Binding::ReadWrite,
        ];
        let kernel = ctx.kernel("tree/cast", &cast_source()?, "main", &b)?;
        let tree = GpuOctree::upload_with(ctx, view, OctreeParts::Walk, slabs)?;
        Ok(RayCaster { kernel, tree })
    }

    /// Nearest hit (t, data-pool index) of each ray, or with `any_hit` the first hit found.
    pub fn cast(
        &self,
        ctx: &GpuContext,
        rays: &[RayIn],
        any_hit: bool,
    ) -> Result<Vec<Option<(f32, u32)>>, GpuError> {
        let mut out = Vec::with_capacity(rays.len());
        self.dispatch(ctx, rays, any_hit, |words| {
            out.par_extend(
                words
                    .par_iter()
                    .map(|w| (w[1] != u32::MAX).then(|| (f32::from_bits(w[0]), w[1]))),
            )
        })?;
        Ok(out)
    }

    /// Whether each ray's segment is free of hits (any-hit rays).
    pub fn visible(&self, ctx: &GpuContext, rays: &[RayIn]) -> Result<Vec<bool>, GpuError> {
        let mut out = Vec::with_capacity(rays.len());
        self.dispatch(ctx, rays, true, |words| {
            out.par_extend(words.par_iter().map(|w| w[1] == u32::MAX))
        })?;
        Ok(out)
    }

    /// Cast `rays` in dispatches of at most [`RAYS_PER_DISPATCH`]; `take` reads each
    /// dispatch's hits in order ([t bits, data-pool index or `u32::MAX`] per ray).
    fn dispatch(
        &self,
        ctx: &GpuContext,
        rays: &[RayIn],
        any_hit: bool,
        mut take: impl FnMut(&[[u32; 2]]),
    ) -> Result<(), GpuError> {
        for chunk in rays.chunks(RAYS_PER_DISPATCH) {
            let params = CastParams {
                count: chunk.len() as u32,
                any_hit: any_hit as u32,
                _pad: [0; 2],
            };
            let rb = ctx.storage("rays", bytemuck::cast_slice(chunk))?;
            let pb = ctx.uniform("cast_params", bytemuck::bytes_of(&params));
            let size = (chunk.len() * 8) as u64;
            let hb = ctx.output("hits", size)?;
            let binds: Vec<&pc_gpu::Buffer> = self.tree.buffers().chain([&rb, &pb, &hb]).collect();
            self.kernel.run(ctx, &binds, grid(chunk.len() as u32, 64))?;
            let bytes = ctx.read(&hb, size)?;
            take(bytemuck::cast_slice(&bytes));
        }
        Ok(())
    }
}
