//! Sample pattern shared bit for bit by the CPU and GPU renderers: a counter-based hash RNG
//! (PCG hash) keyed by seed, pixel, sample and dimension, and stratified pixel positions.

/// PCG hash (Jarzynski & Olano 2020, "Hash Functions for GPU Rendering"). WGSL twin `pcg`.
#[inline]
pub fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747796405).wrapping_add(2891336453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277803737);
    (word >> 22) ^ word
}

/// A uniform number in [0, 1) for (seed, pixel, sample, dimension), 24 random bits.
#[inline]
pub fn rand(seed: u32, pixel: u32, sample: u32, dim: u32) -> f32 {
    let h = pcg(pixel ^ pcg(sample ^ pcg(dim ^ pcg(seed))));
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Position inside the pixel of sample `k` of `spp`: stratified on a g×g grid when spp = g²
/// (jittered within each stratum), otherwise uniform random.
#[inline]
pub fn pixel_offset(seed: u32, pixel: u32, k: u32, spp: u32) -> (f32, f32) {
    let jx = rand(seed, pixel, k, 0);
    let jy = rand(seed, pixel, k, 1);
    let g = (spp as f32).sqrt() as u32;
    if g * g == spp && g > 1 {
        let gf = g as f32;
        (((k % g) as f32 + jx) / gf, ((k / g) as f32 + jy) / gf)
    } else {
        (jx, jy)
    }
}

/// Random-number dimension of the `i`-th draw at bounce `bounce` (0, 1 are the pixel offset).
#[inline]
pub const fn dim(bounce: u32, i: u32) -> u32 {
    2 + bounce * 16 + i
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_and_in_range() {
        let mut sum = 0.0f64;
        for i in 0..100_000u32 {
            let u = rand(7, i, i / 3, 5);
            assert!((0.0..1.0).contains(&u));
            sum += u as f64;
        }
        assert!((sum / 100_000.0 - 0.5).abs() < 0.005);
    }

    #[test]
    fn stratified_offsets_fill_their_strata() {
        for k in 0..16 {
            let (x, y) = pixel_offset(1, 42, k, 16);
            assert_eq!(((x * 4.0) as u32, (y * 4.0) as u32), (k % 4, k / 4));
        }
    }
}
