//! `ConfigError`: what can be wrong with a pipeline config; every variant names the file.

use std::path::{Path, PathBuf};

use pc_artifact::params::ParamError;

/// Everything that can go wrong loading or applying a config.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be opened or read (the OS error is the source, printed by `{:#}`).
    #[error("{}: cannot read the file", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The TOML is malformed, a value has the wrong type, or values do not fit together.
    #[error("{}: {msg}", path.display())]
    Invalid { path: PathBuf, msg: String },

    /// A parameter outside its documented range.
    #[error("{}: {error}", path.display())]
    Param { path: PathBuf, error: ParamError },

    /// A key that its table does not know (a misspelling, or a key of another version).
    #[error("{}: unknown key `{key}` (the table's keys: {known})", path.display())]
    UnknownKey {
        path: PathBuf,
        key: String,
        known: String,
    },

    /// The config's materials are not those the octree was built with.
    #[error("{}: {msg}: rerun pc-octree", octree.display())]
    OctreeMaterials { octree: PathBuf, msg: String },
}

impl ConfigError {
    /// `Invalid` for `path`.
    pub fn invalid(path: &Path, msg: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// `Param` for `path`.
    pub fn param(path: &Path, error: ParamError) -> ConfigError {
        ConfigError::Param {
            path: path.to_path_buf(),
            error,
        }
    }
}
