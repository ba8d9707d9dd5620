//! Scene and configuration: pipeline.toml, PLY import, normal and radius estimation, camera, samplers.

pub mod camera;
pub mod cli;
pub mod config;
pub mod error;
pub mod estimate;
pub mod load;
pub mod ply;
pub mod ply_write;
pub mod sample;

pub use error::SceneError;
