//! GPU (wgpu) kernels of the renderer; each has a CPU twin in `crate::cpu` that tests compare.

pub mod render;

/// Shared WGSL: octree records and point location.
pub const COMMON_OCTREE_WGSL: &str = include_str!("../../../../shaders/common/octree.wgsl");
