//! The per-pixel relative error of a render against a reference, and the band around the
//! light's border that dominates it (docs/chain.md, "Per-pixel error").
//!
//! `sqrt(mean(((ours − ref) / (|ref| + 0.01 · mean(ref)))²))` over every pixel and channel,
//! `mean(ref)` the reference's mean over every pixel and channel: each pixel counts by its own
//! relative error (the whole-image relative RMSE divides by the image's RMS, so the light's
//! pixels decide it), and the `0.01 · mean(ref)` floor keeps black pixels from dividing by zero.
//! This is the figure a path tracer's noise is measured by (Mitsuba's time to an equal error).

use crate::image::Image;

/// Half-width in pixels of the band around the light's border.
pub const LIGHT_BAND: u32 = 3;

/// Pixels at least this fraction of the reference's brightest pixel (largest channel) are the
/// light's (the light itself, and its images in mirrors and glass).
pub const LIGHT_FRACTION: f32 = 0.5;

/// The per-pixel relative error over the pixels not `skip`ped (every pixel when `skip` is
/// `None`); 0 when none is left. The images must be of one size.
pub fn error(ours: &Image, reference: &Image, skip: Option<&[bool]>) -> f64 {
    let n = reference.rgb.len().max(1) as f64;
    let mean = reference
        .rgb
        .iter()
        .map(|p| p.iter().map(|&c| c as f64).sum::<f64>())
        .sum::<f64>()
        / (3.0 * n);
    // A black reference (mean 0) still divides by something: any difference is then huge.
    let floor = (0.01 * mean).max(1e-12);
    let (mut sum, mut count) = (0.0f64, 0u64);
    for (k, (o, r)) in ours.rgb.iter().zip(&reference.rgb).enumerate() {
        if skip.is_some_and(|s| s[k]) {
            continue;
        }
        for c in 0..3 {
            let (o, r) = (o[c] as f64, r[c] as f64);
            let e = (o - r) / (r.abs() + floor);
            sum += e * e;
            count += 1;
        }
    }
    match count {
        0 => 0.0,
        _ => (sum / count as f64).sqrt(),
    }
}

/// The pixels within [`LIGHT_BAND`] pixels (in both axes) of the light's border: those whose
/// square window of half-width `LIGHT_BAND` holds light and non-light pixels of the reference
/// (light: [`LIGHT_FRACTION`] of its brightest pixel or more).
pub fn light_band(reference: &Image) -> Vec<bool> {
    let (w, h) = (reference.width as i64, reference.height as i64);
    let brightest = reference
        .rgb
        .iter()
        .map(|p| p[0].max(p[1]).max(p[2]))
        .fold(0.0f32, f32::max);
    let light: Vec<bool> = reference
        .rgb
        .iter()
        .map(|p| brightest > 0.0 && p[0].max(p[1]).max(p[2]) >= LIGHT_FRACTION * brightest)
        .collect();
    let b = LIGHT_BAND as i64;
    let mut band = vec![false; light.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut any, mut all) = (false, true);
            for yy in (y - b).max(0)..=(y + b).min(h - 1) {
                for xx in (x - b).max(0)..=(x + b).min(w - 1) {
                    let l = light[(yy * w + xx) as usize];
                    any |= l;
                    all &= l;
                }
            }
            band[(y * w + x) as usize] = any && !all;
        }
    }
    band
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> [f32; 3]) -> Image {
        let mut im = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                im.rgb[(y * w + x) as usize] = f(x, y);
            }
        }
        im
    }

    #[test]
    fn a_uniform_tenth_too_bright_is_a_tenth_over_one_plus_the_floor() {
        let r = image(8, 8, |_, _| [0.5; 3]);
        let o = image(8, 8, |_, _| [0.55; 3]);
        // (0.05) / (0.5 + 0.01 · 0.5)
        let want = 0.05 / 0.505;
        assert!((error(&o, &r, None) - want).abs() < 1e-6);
        assert_eq!(error(&r, &r, None), 0.0);
    }

    #[test]
    fn black_reference_pixels_divide_by_the_floor() {
        // Half the pixels 1, half 0: mean 0.5, floor 0.005; ours 0.01 where the reference is 0.
        let r = image(4, 2, |x, _| if x < 2 { [1.0; 3] } else { [0.0; 3] });
        let o = image(4, 2, |x, _| if x < 2 { [1.0; 3] } else { [0.01; 3] });
        let want = ((0.01f64 / 0.005).powi(2) / 2.0).sqrt();
        assert!((error(&o, &r, None) - want).abs() < 1e-5);
    }

    #[test]
    fn the_band_is_three_pixels_either_side_of_a_square_lights_border() {
        // A 10x10 light in a 40x40 image: the band is the 16x16 square about it minus the
        // light's 4x4 inside, 256 − 16 = 240 pixels.
        let r = image(40, 40, |x, y| {
            match (15..25).contains(&x) && (15..25).contains(&y) {
                true => [10.0; 3],
                false => [0.3; 3],
            }
        });
        let band = light_band(&r);
        assert_eq!(band.iter().filter(|&&b| b).count(), 16 * 16 - 4 * 4);
        assert!(band[(12 * 40 + 12) as usize] && !band[(11 * 40 + 11) as usize]);
        assert!(band[(17 * 40 + 17) as usize] && !band[(18 * 40 + 18) as usize]);
        // Errors only in the band leave the rest exact.
        let o = image(40, 40, |x, y| {
            let p = r.rgb[(y * 40 + x) as usize];
            match band[(y * 40 + x) as usize] {
                true => [p[0] * 2.0; 3],
                false => p,
            }
        });
        assert!(error(&o, &r, None) > 0.1);
        assert_eq!(error(&o, &r, Some(&band)), 0.0);
    }
}
