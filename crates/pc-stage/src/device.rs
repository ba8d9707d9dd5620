//! Where a stage's kernels run: the backend a config or `--backend` asks for, resolved to a GPU
//! context or the CPU, with the one fallback rule every stage follows.

use pc_config::Backend;
use pc_gpu::{GpuContext, GpuError};

/// What a stage's kernels do, which decides where `auto` runs them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Work {
    /// Rendering: `auto` takes a hardware GPU whenever there is one. On an NVIDIA H100 the
    /// renderer ran 1.4-1.6× faster than its host's 16 CPU threads (docs/gpu.md).
    Render,
    /// The precomputation (V-map, photons, FMM): `auto` takes a hardware GPU only on a host
    /// with at most [`AUTO_GPU_MAX_THREADS`] worker threads. Their host work (sampling,
    /// deciding, moving records) is the same on either device and scales with the threads, so
    /// from some count on the CPU alone is as fast (docs/gpu.md).
    Precompute,
}

/// The most worker threads with which `auto` runs the precomputation on a hardware GPU
/// ([`Work::Precompute`]); with more it stays on the CPU. Measured on an NVIDIA H200 with 2, 4,
/// 8 and 16 of its host's threads (docs/gpu.md, "Where auto switches"): on the 1M Cornell
/// chain the GPU was faster in every stage at 2-8 threads (1.2-1.8× the stages together) and
/// level at 16 (12.5 s against 12.7 s), and on the 1M hall scan's V-map 3.1× faster at 2
/// threads and 1.26× at 16. Again on an H200 (2026-11-28): the 1M Cornell stages 0.88× at 16
/// threads, the 20M hall scan's stages 1.29× at 16 (38.9 s against 50.1 s). More threads were
/// not measured; the CPU's share keeps growing with them while the GPU's stays.
pub const AUTO_GPU_MAX_THREADS: usize = 16;

/// The GPU for `backend` and `work`: `cpu` none; `gpu` a context, or the error that there is
/// none; `auto` a hardware GPU when one exists and `work` gains from it ([`Work`]), else none (a
/// software rasterizer such as llvmpipe is slower than the CPU).
pub fn gpu_for(backend: Backend, work: Work) -> Result<Option<GpuContext>, GpuError> {
    match backend {
        Backend::Cpu => Ok(None),
        Backend::Gpu => GpuContext::new().map(Some),
        Backend::Auto if !auto_takes_gpu(work, rayon::current_num_threads()) => Ok(None),
        Backend::Auto => Ok(GpuContext::hardware()),
    }
}

/// Start looking for the GPU that [`gpu_for`] will ask for, where that look is the slow one
/// (`auto`'s search for a hardware adapter, [`GpuContext::look_for_hardware`]): a stage calls
/// this first, and its own start overlaps the search.
pub fn look_early(backend: Backend, work: Work) {
    if backend == Backend::Auto && auto_takes_gpu(work, rayon::current_num_threads()) {
        GpuContext::look_for_hardware();
    }
}

/// Whether `auto` looks for a GPU for `work` on a host with `threads` worker threads.
pub fn auto_takes_gpu(work: Work, threads: usize) -> bool {
    match work {
        Work::Render => true,
        Work::Precompute => threads <= AUTO_GPU_MAX_THREADS,
    }
}

/// Runs the work on the device `backend` asks for: `gpu(context)` when there is a GPU for it
/// ([`gpu_for`] with `work`), else `cpu()`. With `auto`, a GPU that cannot take the work (`gpu` fails: too
/// large for its buffers, too few bindings) falls back to the CPU with a warning on stderr
/// naming `stage`; with `gpu` that failure is the error.
pub fn gpu_or_cpu<T, E>(
    stage: &str,
    backend: Backend,
    work: Work,
    gpu: impl FnOnce(GpuContext) -> Result<T, E>,
    cpu: impl FnOnce() -> Result<T, E>,
) -> Result<T, E>
where
    E: From<GpuError> + std::fmt::Display,
{
    let Some(ctx) = gpu_for(backend, work)? else {
        return cpu();
    };
    let name = ctx.describe();
    match gpu(ctx) {
        Ok(t) => Ok(t),
        Err(e) if backend == Backend::Auto => {
            warn_fallback(stage, &name, &e);
            cpu()
        }
        Err(e) => Err(e),
    }
}

/// The warning of a fallback from the GPU `gpu` to the CPU.
pub fn warn_fallback(stage: &str, gpu: &str, why: &dyn std::fmt::Display) {
    eprintln!("{stage}: warning: running on the CPU: the GPU {gpu} cannot: {why}");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_keeps_the_precomputation_on_many_cores_and_renders_on_a_gpu() {
        assert!(auto_takes_gpu(Work::Render, 64));
        assert!(auto_takes_gpu(Work::Precompute, 2));
        assert!(auto_takes_gpu(Work::Precompute, AUTO_GPU_MAX_THREADS));
        assert!(!auto_takes_gpu(Work::Precompute, AUTO_GPU_MAX_THREADS + 1));
        assert!(!auto_takes_gpu(Work::Precompute, 64));
        // `cpu` never opens a device, whatever the work.
        assert!(gpu_for(Backend::Cpu, Work::Render).unwrap().is_none());
    }
}
