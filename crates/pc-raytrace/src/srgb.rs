//! The sRGB transfer function, and the 8-bit quantisation of the PNG previews through a table
//! that gives exactly what the function gives.
//!
//! `round(255 * srgb_encode(x))` costs an `f64` power per channel: 55 ms for a 1024×1024
//! frame on one core of the Xeon, as long as the frame's deflate at `Compression::Fast`. The
//! table answers the same byte in a few nanoseconds: the output is non-decreasing in `x`, so it
//! is known by the 255 smallest inputs at which it steps up ([`Table::steps`]). A lookup starts
//! from the byte at the start of `x`'s slice of the `f32` bit patterns ([`Table::start`]) and
//! steps up past every threshold at or below `x`, which is rarely more than one.

use std::sync::OnceLock;

/// The exact sRGB transfer function (OETF) of a linear value; the input is clamped to [0, 1]
/// (NaN counts as 0).
pub fn srgb_encode(linear: f32) -> f32 {
    let x = if linear.is_nan() {
        0.0
    } else {
        f64::from(linear.clamp(0.0, 1.0))
    };
    let encoded = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    encoded as f32
}

/// The 8-bit sRGB value of a linear one, `round(255 * srgb_encode(linear))`, by the function
/// itself (the reference that [`to_srgb8`]'s table is built from and tested against).
pub fn to_srgb8_exact(linear: f32) -> u8 {
    (srgb_encode(linear) * 255.0).round() as u8
}

/// The 8-bit sRGB value of a linear one: exactly [`to_srgb8_exact`], through the table.
#[inline]
pub fn to_srgb8(linear: f32) -> u8 {
    // NaN, zero and negative values give 0, values from 1 on give 255 (the clamp).
    if linear.is_nan() || linear <= 0.0 {
        return 0;
    }
    if linear >= 1.0 {
        return 255;
    }
    let t = table();
    let mut v = t.start[(linear.to_bits() >> SLICE_BITS) as usize];
    while linear >= t.steps[v as usize] {
        v += 1;
    }
    v
}

/// Low bits of an `f32` that one slice of [`Table::start`] spans: the positive floats below 1
/// fall into 32,513 slices.
const SLICE_BITS: u32 = 15;

struct Table {
    /// `steps[k]`: the smallest input whose byte is above `k` (`f32::INFINITY` for 255).
    steps: [f32; 256],
    /// The byte of the smallest input of each slice of bit patterns, up to 1.0's.
    start: Vec<u8>,
}

fn table() -> &'static Table {
    static TABLE: OnceLock<Table> = OnceLock::new();
    TABLE.get_or_init(|| {
        let one = 1.0f32.to_bits();
        let mut steps = [f32::INFINITY; 256];
        for (k, step) in steps.iter_mut().enumerate().take(255) {
            // The smallest bit pattern in [0, 1.0] whose byte exceeds k (1.0's is 255).
            let (mut lo, mut hi) = (0u32, one);
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if to_srgb8_exact(f32::from_bits(mid)) as usize > k {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            *step = f32::from_bits(lo);
        }
        let start = (0..=one >> SLICE_BITS)
            .map(|s| to_srgb8_exact(f32::from_bits(s << SLICE_BITS)))
            .collect();
        Table { steps, start }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_encode_values() {
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(0.003_130_8) - 0.040_449_936).abs() < 1e-7);
        // Both branches agree at the threshold.
        let above = 1.055 * 0.003_130_8f64.powf(1.0 / 2.4) - 0.055;
        assert!((f64::from(srgb_encode(0.003_130_8)) - above).abs() < 1e-6);
        assert!(
            (srgb_encode(0.5) - 0.735_356_9).abs() < 1e-6,
            "{}",
            srgb_encode(0.5)
        );
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-7);
        assert_eq!(srgb_encode(-3.0), 0.0);
        assert_eq!(srgb_encode(7.0), srgb_encode(1.0));
        assert_eq!(srgb_encode(f32::NAN), 0.0);
        assert_eq!(srgb_encode(f32::INFINITY), srgb_encode(1.0));
    }

    #[test]
    fn the_table_gives_the_exact_byte() {
        let check = |x: f32| {
            assert_eq!(
                to_srgb8(x),
                to_srgb8_exact(x),
                "x = {x:e} ({:#x})",
                x.to_bits()
            );
        };
        // Every step and its neighbours, where an off-by-one would show.
        for &s in &table().steps[..255] {
            for d in -64i64..=64 {
                check(f32::from_bits((i64::from(s.to_bits()) + d) as u32));
            }
        }
        // A dense sweep of the bit patterns of [0, 1], and beyond.
        for bits in (0..=0x3f90_0000u32).step_by(97) {
            check(f32::from_bits(bits));
        }
        for x in [
            0.0,
            -0.0,
            -1.0,
            1.0,
            1.5,
            f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ] {
            check(x);
        }
        assert_eq!(to_srgb8(0.5), 188);
        assert_eq!(to_srgb8(1.0), 255);
    }

    #[test]
    fn the_steps_rise() {
        let steps = &table().steps;
        assert!(steps[..255].windows(2).all(|w| w[0] < w[1]));
        assert!(steps[0] > 0.0 && steps[254] <= 1.0);
    }
}
