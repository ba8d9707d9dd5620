//! pc-raytrace: renders the octree (seed §8.2, §8.5.6, §8.5.8-§8.5.14) on the CPU and the GPU.
//!
//! The CPU renderer (`cpu`) is the reference; the GPU renderer (`gpu`, WGSL in
//! `shaders/raytrace/`) follows it line by line with the same sample pattern (`sample`), and a
//! test holds the two images together. See docs/raytrace.md.

pub mod camera;
pub mod camera_near;
pub mod caustic;
pub mod cpu;
pub mod error;
pub mod gpu;
pub mod image;
pub mod per_pixel;
pub mod photon_grid;
pub mod photon_lanes;
pub mod reference;
pub mod refine;
pub mod renderer;
pub mod sample;
pub mod scene;
pub mod srgb;
pub mod stage;
pub mod walkthrough;

pub use error::RenderError;
