//! `VmapError`: what can stop pc-vmap; every variant names the file or the device it is about.

use pc_artifact::ArtifactError;
use pc_gpu::GpuError;

/// Everything that can go wrong computing a V-map.
#[derive(Debug, thiserror::Error)]
pub enum VmapError {
    #[error(transparent)]
    Artifact(#[from] ArtifactError),
    /// The GPU failed (finding it, or casting a batch of rays mid-way).
    #[error(transparent)]
    Gpu(#[from] GpuError),
}
