//! An image against a reference: error statistics and a difference picture.

use std::path::Path;

use super::png_io::write_png_bytes;
use super::{Image, ImageError};
use crate::srgb::to_srgb8;

/// The relative differences of [`compare`] use `max(|b|, RELATIVE_FLOOR * mean(|b|) + 1e-6)`
/// as denominator, so that (nearly) black reference pixels do not blow them up.
pub const RELATIVE_FLOOR: f64 = 0.01;

/// Error statistics of an image `a` against a reference `b`.
///
/// With `d = a - b` per pixel and channel, `m = mean(|b|)` over all pixels and channels and the
/// floor `f = RELATIVE_FLOOR * m + 1e-6`:
/// - `mean_relative = mean(|d| / max(|b|, f))`: relative error, where pixels darker than 1 % of
///   the mean brightness are measured relative to that floor instead of their own value;
/// - `max_abs = max(|d|)` (NaN if any difference is NaN);
/// - `rmse_relative = sqrt(mean(d²)) / m` (0 if `a == b`, `inf` if only `m` is 0).
///
/// All statistics are 0 for identical (or empty) images and NaN if any difference is NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Comparison {
    pub mean_relative: f64,
    pub max_abs: f32,
    pub rmse_relative: f64,
}

impl std::fmt::Display for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "mean relative {:.5}, rmse relative {:.5}, max abs {:.5}",
            self.mean_relative, self.rmse_relative, self.max_abs
        )
    }
}

/// Two images of different sizes, or an image whose buffers do not match its size.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SizeMismatch(pub(super) String);

/// Compares `a` against the reference `b` (see [`Comparison`]); an error if the sizes differ.
pub fn compare(a: &Image, b: &Image) -> Result<Comparison, SizeMismatch> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(SizeMismatch(format!(
            "image sizes differ: {}x{} vs {}x{}",
            a.width, a.height, b.width, b.height
        )));
    }
    a.check_sizes()?;
    b.check_sizes()?;
    let count = 3 * b.rgb.len();
    if count == 0 {
        return Ok(Comparison {
            mean_relative: 0.0,
            max_abs: 0.0,
            rmse_relative: 0.0,
        });
    }
    let n = count as f64;
    let mean_b = b
        .rgb
        .iter()
        .flatten()
        .map(|&v| f64::from(v).abs())
        .sum::<f64>()
        / n;
    let floor = RELATIVE_FLOOR * mean_b + 1e-6;
    let (mut rel_sum, mut sq_sum, mut max_abs) = (0.0f64, 0.0f64, 0.0f32);
    for (pa, pb) in a.rgb.iter().zip(&b.rgb) {
        for c in 0..3 {
            let d = (pa[c] - pb[c]).abs();
            // `f32::max` would drop NaN; keep it so that a broken image never passes.
            if d.is_nan() || max_abs.is_nan() {
                max_abs = f32::NAN;
            } else {
                max_abs = max_abs.max(d);
            }
            let d = f64::from(d);
            rel_sum += d / f64::from(pb[c]).abs().max(floor);
            sq_sum += d * d;
        }
    }
    let rmse = (sq_sum / n).sqrt();
    let rmse_relative = if rmse == 0.0 { 0.0 } else { rmse / mean_b };
    Ok(Comparison {
        mean_relative: rel_sum / n,
        max_abs,
        rmse_relative,
    })
}

/// Writes `|a - b| * scale` per channel as an 8-bit sRGB PNG (black where the images agree, full
/// intensity where a difference is NaN), for inspecting failing image tests.
/// Fails with [`ImageError::Format`] if the sizes differ.
pub fn write_diff_png(path: &Path, a: &Image, b: &Image, scale: f32) -> Result<(), ImageError> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(ImageError::format(
            path,
            format!(
                "cannot diff a {}x{} image against a {}x{} one",
                a.width, a.height, b.width, b.height
            ),
        ));
    }
    a.check_sizes().map_err(|m| ImageError::format(path, m.0))?;
    b.check_sizes().map_err(|m| ImageError::format(path, m.0))?;
    let pixels: Vec<u8> = a
        .rgb
        .iter()
        .zip(&b.rgb)
        .flat_map(|(pa, pb)| {
            [0, 1, 2].map(|c| {
                let d = (pa[c] - pb[c]).abs();
                // NaN differences are shown at full intensity.
                if d.is_nan() {
                    255
                } else {
                    to_srgb8(d * scale)
                }
            })
        })
        .collect();
    write_png_bytes(path, a.width, a.height, &pixels, None)
}
