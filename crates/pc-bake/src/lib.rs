//! pc-bake: the lit scan as a point cloud. Every splat's outgoing radiance (its radiosity,
//! plus the caustic density estimate the renderer adds, times its albedo over π) is written at
//! the point it came from, in the models' own coordinates (the scene's f64 origin added back),
//! as 8/16-bit color through the sRGB curve after `bake.exposure`, with the linear radiance as
//! extra fields: PLY (`radiance_r/g/b` float properties) or LAS/LAZ (point format 2 with three
//! float extra bytes described by an Extra Bytes VLR). docs/bake.md.
//!
//! [`lit::lit_points`] computes the values; [`write`](mod@write) writes them; [`stage`] is the binary's
//! driver.

pub mod error;
pub mod lit;
pub mod stage;
pub mod write;

pub use error::BakeError;
