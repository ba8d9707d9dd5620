//! Batches of visibility rays, on the CPU or the GPU: the one interface the stages that test
//! visibility use (pc-vmap's links and light lists, pc-fmm's shadow rays, tests).

use pc_gpu::GpuError;

use crate::{Between, OctreeView, Ray};

/// Casts batches of visibility rays: `true` where the segment `[t_min, t_max]` is unoccluded.
/// Only a GPU can fail (a dispatch or a readback).
pub trait Caster: Sync {
    fn visible(&self, rays: &[Ray]) -> Result<Vec<bool>, GpuError>;
    /// Visibility of segments between surfaces, past the ends' own roughness
    /// ([`crate::between`]): `true` where nothing else lies between.
    fn visible_between(&self, segs: &[Between]) -> Result<Vec<bool>, GpuError>;
    fn name(&self) -> String;
}

/// The CPU caster: the renderer's traversal over packed leaf lists, rayon across rays.
pub struct CpuCaster<'a> {
    pub view: &'a OctreeView<'a>,
    pub accel: crate::accel::Accel,
}

impl<'a> CpuCaster<'a> {
    pub fn new(view: &'a OctreeView<'a>) -> Self {
        CpuCaster {
            view,
            accel: crate::accel::Accel::new(view),
        }
    }
}

impl Caster for CpuCaster<'_> {
    fn visible(&self, rays: &[Ray]) -> Result<Vec<bool>, GpuError> {
        Ok(self.accel.visible(self.view, rays))
    }
    fn visible_between(&self, segs: &[Between]) -> Result<Vec<bool>, GpuError> {
        Ok(self.accel.visible_between(self.view, segs))
    }
    fn name(&self) -> String {
        format!("CPU, {} threads", rayon::current_num_threads())
    }
}

/// The GPU caster: `shaders/tree/cast.wgsl` with any-hit rays.
pub struct GpuCaster {
    pub ctx: pc_gpu::GpuContext,
    pub caster: crate::gpu::RayCaster,
}

impl Caster for GpuCaster {
    fn visible(&self, rays: &[Ray]) -> Result<Vec<bool>, GpuError> {
        let input: Vec<crate::gpu::RayIn> = rays.iter().map(Into::into).collect();
        let hits = self.caster.cast(&self.ctx, &input, true)?;
        Ok(hits.iter().map(Option::is_none).collect())
    }
    fn visible_between(&self, segs: &[Between]) -> Result<Vec<bool>, GpuError> {
        let input: Vec<crate::gpu::RayIn> = segs.iter().map(Into::into).collect();
        let hits = self.caster.cast(&self.ctx, &input, true)?;
        Ok(hits.iter().map(Option::is_none).collect())
    }
    fn name(&self) -> String {
        self.ctx.describe()
    }
}
