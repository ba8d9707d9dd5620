//! Point clouds in and out: the PLY reader ([`ply`]) and writer ([`ply_write`]), normal and
//! radius estimation for clouds that lack them ([`estimate`]), and the assembly of
//! pipeline.toml's models into one splat set ([`load`]: transforms, materials). docs/import.md.

pub mod error;
pub mod estimate;
pub mod load;
pub mod ply;
pub mod ply_write;

pub use error::ImportError;
