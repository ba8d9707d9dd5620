//! `BakeError`: what can stop pc-bake.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    #[error(transparent)]
    Artifact(#[from] pc_artifact::ArtifactError),
    #[error(transparent)]
    Config(#[from] pc_config::ConfigError),
    /// The lit cloud could not be written.
    #[error("{}: cannot write the lit cloud", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}
