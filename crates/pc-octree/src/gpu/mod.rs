//! GPU (wgpu) kernels of the octree stage; each has a CPU twin that tests compare it with.

pub mod locate;

/// Shared WGSL: the octree records and the point-location descent.
pub const COMMON_OCTREE_WGSL: &str = include_str!("../../../../shaders/common/octree.wgsl");
