//! Input artifacts a stage uses when they exist (pc-fmm's and pc-raytrace's photon map,
//! pc-raytrace's radiosity).

use std::path::{Path, PathBuf};

/// An input that is optional at its default path, but required when named on the command line:
/// a path the user typed that does not exist is an error, never silently ignored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OptionalInput {
    pub path: PathBuf,
    /// Named on the command line: it must exist.
    pub required: bool,
}

impl OptionalInput {
    /// `arg` when given (required), else `default` (used only when it exists).
    pub fn new(arg: Option<PathBuf>, default: PathBuf) -> OptionalInput {
        match arg {
            Some(path) => OptionalInput {
                path,
                required: true,
            },
            None => OptionalInput {
                path: default,
                required: false,
            },
        }
    }

    /// Whether the stage reads it: it exists, or it was named (then reading it reports the
    /// missing file).
    pub fn wanted(&self) -> bool {
        self.required || self.path.exists()
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_named_input_is_wanted_even_when_missing() {
        let missing = PathBuf::from("/nonexistent/photons.pcgi");
        assert!(!OptionalInput::new(None, missing.clone()).wanted());
        assert!(OptionalInput::new(Some(missing), PathBuf::from("x")).wanted());
    }
}
