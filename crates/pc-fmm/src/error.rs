//! `FmmError`: what can stop the radiosity solve; every variant names the file, the device or
//! the likely input problem.

use pc_artifact::ArtifactError;
use pc_config::ConfigError;
use pc_gpu::GpuError;

/// Everything that can go wrong solving the radiosity.
#[derive(Debug, thiserror::Error)]
pub enum FmmError {
    #[error(transparent)]
    Artifact(#[from] ArtifactError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The GPU cannot run this plan: a buffer over the device's binding limit, more loop
    /// iterations than a software adapter allows, an order past the generated kernels.
    #[error("FMM on the GPU: {0}")]
    GpuPlan(String),
    /// A residual (or the source term's norm, iteration 0) is not a finite number.
    #[error(
        "the radiosity solve diverged: residual {residual} at iteration {iteration}; the scene \
         has non-finite or absurd values (a splat radius or area of 1e30, an emitter or light \
         brighter than f32 can hold): check the models and the materials"
    )]
    Diverged { iteration: u32, residual: f64 },
}
