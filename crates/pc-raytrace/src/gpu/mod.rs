//! GPU (wgpu) kernels of the renderer; each has a CPU twin in `crate::cpu` that tests compare.

pub mod render;
