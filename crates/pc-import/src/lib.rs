//! Point clouds in and out: the readers of PLY ([`ply`]), LAS/LAZ ([`las`]) and E57 ([`e57`]),
//! all giving a [`points::PointSet`] chosen by extension ([`points::read_points`]), the PLY
//! writer ([`ply_write`]), normal and
//! radius estimation for clouds that lack them ([`estimate`], over the neighbour search
//! [`knn`]), and the assembly of
//! pipeline.toml's models into one splat set ([`load`]: transforms, materials). docs/import.md.

pub mod clean;
pub mod e57;
mod edge_on;
mod eigen;
pub mod error;
pub mod estimate;
pub mod knn;
pub mod las;
mod las_guard;
mod lines;
pub mod load;
pub mod ply;
pub mod ply_write;
pub mod points;

pub use error::ImportError;

/// A model file must be a regular file: a FIFO, a socket or a device (`/dev/zero`) never ends,
/// and opening a FIFO alone blocks. Checked before the file is opened.
pub fn check_regular_file(path: &std::path::Path) -> Result<(), ImportError> {
    let meta = std::fs::metadata(path).map_err(|e| ImportError::io(path, e))?;
    if meta.is_file() {
        return Ok(());
    }
    let what = if meta.is_dir() {
        "a folder"
    } else {
        "not a regular file (a FIFO, socket or device)"
    };
    Err(ImportError::ply(
        path,
        format!("{what}: a model must be a file, read whole"),
    ))
}
