//! `ImportError`: the one error type of this crate; every variant names the file it is about.
//!
//! Display always starts with `{path}: `, then says what is wrong and, for per-point problems,
//! which vertex (0-based index in the file's vertex element).

use std::path::{Path, PathBuf};

/// Everything that can go wrong while importing a scene: its model files, estimation, assembly.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file could not be opened or read (the OS error is the source, printed by `{:#}`).
    #[error("{}: cannot read the file", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A malformed PLY header or body; `msg` carries the line (ASCII, header) or byte offset
    /// (binary) when known.
    #[error("{}: {msg}", path.display())]
    Ply { path: PathBuf, msg: String },

    /// A LAS, LAZ or E57 file its reader refused: malformed, truncated, a failed checksum,
    /// header counts that disagree with the body; `msg` says which.
    #[error("{}: {format} file: {msg}", path.display())]
    Scan {
        path: PathBuf,
        format: &'static str,
        msg: String,
    },

    /// The file's extension names no format pcgi reads.
    #[error("{}: unknown model format {ext:?}: pcgi reads .ply, .las, .laz and .e57 files", path.display())]
    UnknownFormat { path: PathBuf, ext: String },

    /// A required vertex property is absent.
    #[error("{}: vertex element has no `{property}` property: {}", path.display(), missing_hint(property))]
    MissingProperty {
        path: PathBuf,
        property: &'static str,
    },

    /// A property we use is declared as a list.
    #[error("{}: property `{property}` is a list, a scalar is expected", path.display())]
    ListProperty { path: PathBuf, property: String },

    /// The header declares no `vertex` element.
    #[error("{}: the file has no `vertex` element", path.display())]
    NoVertexElement { path: PathBuf },

    /// NaN or infinity (or a double beyond the f32 range) in a property we use.
    #[error("{}: vertex {index}: `{property}` is {value}, a finite 32-bit number is required", path.display())]
    NonFinite {
        path: PathBuf,
        index: usize,
        property: String,
        value: f64,
    },

    /// A normal of (near) zero length.
    #[error("{}: vertex {index}: the normal has zero length", path.display())]
    ZeroNormal { path: PathBuf, index: usize },

    /// A radius that is not a positive finite number.
    #[error("{}: vertex {index}: radius {value} is not a positive finite number", path.display())]
    BadRadius {
        path: PathBuf,
        index: usize,
        value: f64,
    },

    /// A point (after its model's transform) or a radius beyond the extent pcgi keeps in f32.
    #[error(
        "{}: vertex {index}: {what} {value:e} lies beyond ±{limit:e} (the extent pcgi works in): \
         shift the model with `translate` or scale it, or set import.drop_invalid to drop such points",
        path.display()
    )]
    OutOfRange {
        path: PathBuf,
        index: usize,
        what: &'static str,
        value: f32,
        limit: f32,
    },

    /// No points (zero vertices, or all of them dropped as invalid).
    #[error("{}: the model has no points", path.display())]
    Empty { path: PathBuf },

    /// The body ends before all vertices the header announces.
    #[error("{}: body ends after {read} of {expected_vertices} vertices", path.display())]
    Truncated {
        path: PathBuf,
        expected_vertices: usize,
        read: usize,
    },

    /// The scene as a whole cannot be imported (no models, too many points); `path` is the
    /// config.
    #[error("{}: {msg}", path.display())]
    Scene { path: PathBuf, msg: String },

    /// A model names a material the config does not define.
    #[error("{}: model {model} uses material `{name}`, which is not defined", path.display())]
    UnknownMaterial {
        path: PathBuf,
        model: usize,
        name: String,
    },

    /// Normal or radius estimation is impossible (too few points, bad parameters).
    #[error("{}: cannot estimate normals or radii: {msg}", path.display())]
    Estimate { path: PathBuf, msg: String },
}

/// Why a missing property matters, for [`ImportError::MissingProperty`].
fn missing_hint(property: &str) -> &'static str {
    match property {
        "x" | "y" | "z" => "x, y and z are required",
        "nx" | "ny" | "nz" => "normals need all of nx, ny and nz",
        "red" | "green" | "blue" | "r" | "g" | "b" => {
            "colors (red, green, blue) are needed for this model's material"
        }
        _ => "it is required",
    }
}

impl ImportError {
    /// `Io` for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// `Ply` for `path`.
    pub fn ply(path: &Path, msg: impl Into<String>) -> Self {
        Self::Ply {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// `Scan` for `path`, a file of `format` ("LAS", "LAZ", "E57").
    pub fn scan(path: &Path, format: &'static str, msg: impl Into<String>) -> Self {
        Self::Scan {
            path: path.to_path_buf(),
            format,
            msg: msg.into(),
        }
    }

    /// `Estimate` for `path`.
    pub fn estimate(path: &Path, msg: impl Into<String>) -> Self {
        Self::Estimate {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            Self::Io { path, .. }
            | Self::Ply { path, .. }
            | Self::Scan { path, .. }
            | Self::UnknownFormat { path, .. }
            | Self::MissingProperty { path, .. }
            | Self::ListProperty { path, .. }
            | Self::NoVertexElement { path }
            | Self::NonFinite { path, .. }
            | Self::ZeroNormal { path, .. }
            | Self::BadRadius { path, .. }
            | Self::Empty { path }
            | Self::Truncated { path, .. }
            | Self::OutOfRange { path, .. }
            | Self::Scene { path, .. }
            | Self::UnknownMaterial { path, .. }
            | Self::Estimate { path, .. } => path,
        }
    }

    /// The vertex index a per-point error is about, if any.
    pub fn vertex_index(&self) -> Option<usize> {
        match self {
            Self::NonFinite { index, .. }
            | Self::OutOfRange { index, .. }
            | Self::ZeroNormal { index, .. }
            | Self::BadRadius { index, .. } => Some(*index),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_starts_with_path() {
        let p = Path::new("scans/room.ply");
        let e = ImportError::NonFinite {
            path: p.into(),
            index: 1234,
            property: "x".into(),
            value: f64::NAN,
        };
        let s = e.to_string();
        assert!(
            s.starts_with("scans/room.ply: vertex 1234: `x` is NaN"),
            "{s}"
        );
        let e = ImportError::MissingProperty {
            path: p.into(),
            property: "y",
        };
        assert_eq!(
            e.to_string(),
            "scans/room.ply: vertex element has no `y` property: x, y and z are required"
        );
        let e = ImportError::Truncated {
            path: p.into(),
            expected_vertices: 100,
            read: 99,
        };
        assert_eq!(
            e.to_string(),
            "scans/room.ply: body ends after 99 of 100 vertices"
        );
        assert_eq!(e.path(), p);
    }
}
