//! Sample pattern shared bit for bit by the CPU and GPU renderers: the counter-based hash RNG
//! of `pc_tree::rng` keyed by seed, pixel, sample and dimension, and stratified pixel positions.

pub use pc_tree::rng::{pcg, rand};

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
