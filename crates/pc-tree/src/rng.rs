//! Counter-based random numbers shared by every stage and by the WGSL kernels: a PCG hash of
//! (seed, stream, index, dimension), so CPU and GPU draw identical numbers without state.

/// PCG hash (Jarzynski & Olano 2020, "Hash Functions for GPU Rendering"). WGSL twin `pcg`.
#[inline]
pub fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747796405).wrapping_add(2891336453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277803737);
    (word >> 22) ^ word
}

/// A uniform number in [0, 1) for (seed, stream, index, dimension), 24 random bits.
#[inline]
pub fn rand(seed: u32, stream: u32, index: u32, dim: u32) -> f32 {
    let h = pcg(stream ^ pcg(index ^ pcg(dim ^ pcg(seed))));
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}
