//! `OctreeError`: what can stop pc-octree; every variant names the file it is about.

use std::path::PathBuf;

use pc_artifact::ArtifactError;
use pc_import::ImportError;

use crate::build::BuildError;

/// Everything that can go wrong building the octree artifact.
#[derive(Debug, thiserror::Error)]
pub enum OctreeError {
    #[error(transparent)]
    Import(#[from] ImportError),
    #[error(transparent)]
    Artifact(#[from] ArtifactError),
    /// A model's file could not be read for the key.
    #[error("{}: cannot read the model", path.display())]
    Model {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The build refused the scene (`config` names the pipeline that described it).
    #[error("{}: {error}", config.display())]
    Build { config: PathBuf, error: BuildError },
}
