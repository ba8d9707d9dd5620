//! `RenderError`: what can stop a render; every variant names the file it is about.

use pc_artifact::ArtifactError;
use pc_config::ConfigError;
use pc_gpu::GpuError;

use crate::image::ImageError;

/// Everything that can go wrong rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Artifact(#[from] ArtifactError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("a walkthrough needs at least one frame")]
    NoFrames,
    #[error("{}: cannot write the file", path.display())]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
}
