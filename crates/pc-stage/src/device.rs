//! Where a stage's kernels run: the backend a config or `--backend` asks for, resolved to a GPU
//! context or the CPU, with the one fallback rule every stage follows.

use pc_config::Backend;
use pc_gpu::{GpuContext, GpuError};

/// The GPU for `backend`: `cpu` none; `gpu` a context, or the error that there is none;
/// `auto` a hardware GPU when one exists (a software rasterizer such as llvmpipe is slower than
/// the CPU), else none.
pub fn gpu_for(backend: Backend) -> Result<Option<GpuContext>, GpuError> {
    match backend {
        Backend::Cpu => Ok(None),
        Backend::Gpu => GpuContext::new().map(Some),
        Backend::Auto => Ok(GpuContext::new().ok().filter(|g| !g.is_software())),
    }
}

/// Runs the work on the device `backend` asks for: `gpu(context)` when there is a GPU for it
/// ([`gpu_for`]), else `cpu()`. With `auto`, a GPU that cannot take the work (`gpu` fails: too
/// large for its buffers, too few bindings) falls back to the CPU with a warning on stderr
/// naming `stage`; with `gpu` that failure is the error.
pub fn gpu_or_cpu<T, E>(
    stage: &str,
    backend: Backend,
    gpu: impl FnOnce(GpuContext) -> Result<T, E>,
    cpu: impl FnOnce() -> Result<T, E>,
) -> Result<T, E>
where
    E: From<GpuError> + std::fmt::Display,
{
    let Some(ctx) = gpu_for(backend)? else {
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
