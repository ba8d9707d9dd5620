//! `CausticsError`: what can stop pc-caustics; every variant names the file or the device.

use pc_artifact::ArtifactError;
use pc_config::ConfigError;
use pc_gpu::GpuError;

/// Everything that can go wrong tracing the photon map.
#[derive(Debug, thiserror::Error)]
pub enum CausticsError {
    #[error(transparent)]
    Artifact(#[from] ArtifactError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
}
