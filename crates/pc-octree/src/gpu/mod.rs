//! GPU (wgpu) kernels of the octree stage; each has a CPU twin that tests compare it with.

pub mod locate;
