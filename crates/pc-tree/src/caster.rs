//! Batches of visibility rays, on the CPU or the GPU: the one interface the stages that test
//! visibility use (pc-vmap's links and light lists, pc-fmm's shadow rays, tests).

use pc_gpu::GpuError;
use rayon::prelude::*;

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
    pub accel: crate::accel::Accel<'a>,
}

impl<'a> CpuCaster<'a> {
    pub fn new(view: &'a OctreeView<'a>) -> Self {
        CpuCaster {
            view,
            accel: crate::accel::Accel::new(view).with_own_surfaces(view),
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

// The records are made and the answers read on all cores: on the H100 these serial loops over
// 41M rays took longer than the kernels (docs/gpu.md).
impl Caster for GpuCaster {
    fn visible(&self, rays: &[Ray]) -> Result<Vec<bool>, GpuError> {
        let input: Vec<crate::gpu::RayIn> = rays.par_iter().map(Into::into).collect();
        self.caster.visible(&self.ctx, &input)
    }
    fn visible_between(&self, segs: &[Between]) -> Result<Vec<bool>, GpuError> {
        let input: Vec<crate::gpu::RayIn> = segs.par_iter().map(Into::into).collect();
        self.caster.visible(&self.ctx, &input)
    }
    fn name(&self) -> String {
        self.ctx.describe()
    }
}

/// A caster that adds up the wall time spent in another's casts, so a stage can tell its rays'
/// time from the rest (pc-vmap's `casting` timing).
pub struct Timed<'a> {
    pub inner: &'a dyn Caster,
    nanos: std::sync::atomic::AtomicU64,
}

impl<'a> Timed<'a> {
    pub fn new(inner: &'a dyn Caster) -> Self {
        Timed {
            inner,
            nanos: Default::default(),
        }
    }

    /// Seconds spent in casts so far.
    pub fn seconds(&self) -> f64 {
        self.nanos.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9
    }

    fn timed<T>(&self, f: impl FnOnce() -> T) -> T {
        let t = std::time::Instant::now();
        let out = f();
        let ns = t.elapsed().as_nanos() as u64;
        self.nanos
            .fetch_add(ns, std::sync::atomic::Ordering::Relaxed);
        out
    }
}

impl Caster for Timed<'_> {
    fn visible(&self, rays: &[Ray]) -> Result<Vec<bool>, GpuError> {
        self.timed(|| self.inner.visible(rays))
    }
    fn visible_between(&self, segs: &[Between]) -> Result<Vec<bool>, GpuError> {
        self.timed(|| self.inner.visible_between(segs))
    }
    fn name(&self) -> String {
        self.inner.name()
    }
}
