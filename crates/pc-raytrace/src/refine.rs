//! Refined pixels: after the first pass, the pixels that differ sharply from a neighbour (an
//! object's silhouette, a light's rim, a caustic's speck) are rendered again with more samples.
//!
//! Where a pixel is smooth, `spp` samples of the stored solution already give its value to well
//! under a percent; at a high-contrast edge the same samples give its coverage in steps of
//! 1/`spp`, and the reference light's rim or a box's silhouette against a wall then held most
//! of the image's per-pixel error. A marked pixel is rendered afresh with `refine.spp` samples on
//! their own stratified pattern (the first pass's are dropped), so its value is exactly the one
//! a whole render at `refine.spp` would give it, on either backend: the CPU traces the marked
//! pixels' samples ([`crate::cpu::render_pixels`]), the GPU kernel runs a second time and
//! skips every pixel whose output word the host did not mark ([`MARK`]). docs/raytrace.md,
//! "Refined pixels".

use rayon::prelude::*;

use crate::image::Image;

/// The fourth lane of a marked pixel's output word in the GPU's second pass (the first pass
/// writes a finite depth's bits there, never this NaN pattern).
pub const MARK: u32 = 0xffff_ffff;

/// The second pass's settings (`raytrace.refine` × `raytrace.spp`, `raytrace.refine_contrast`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refine {
    /// Samples of a marked pixel; no second pass unless above the first pass's `spp`.
    pub spp: u32,
    /// The relative difference from a neighbour that marks a pixel ([`marked`]).
    pub contrast: f32,
}

impl Refine {
    /// Whether a second pass follows a first pass of `spp` samples.
    pub fn after(&self, spp: u32) -> bool {
        self.spp > spp
    }
}

/// The pixels (row-major indices, ascending) of `img` that differ from one of their eight
/// neighbours by more than `contrast`: |a − b| / (½(a + b) + 0.01 m), the largest over the three
/// channels, with m the mean of every finite channel value (the floor keeps black from marking
/// its own noise; it is the per-pixel error's, pc-compare's, floor). A pixel that is not finite
/// is marked, and so are its neighbours.
pub fn marked(img: &Image, contrast: f32) -> Vec<u32> {
    let (w, h) = (img.width as usize, img.height as usize);
    if w * h == 0 {
        return Vec::new();
    }
    let finite = |c: &f32| c.is_finite();
    let (sum, n) = img
        .rgb
        .par_iter()
        .flat_map_iter(|p| p.iter().copied().filter(finite))
        .map(|c| (c as f64, 1u64))
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let floor = (0.01 * sum / n.max(1) as f64) as f32;
    let differ = |a: &[f32; 3], b: &[f32; 3]| {
        (0..3).any(|c| {
            let (x, y) = (a[c], b[c]);
            !(x.is_finite() && y.is_finite()) || (x - y).abs() > contrast * (0.5 * (x + y) + floor)
        })
    };
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let rows = y.saturating_sub(1)..(y + 2).min(h);
            (0..w).filter_map(move |x| {
                let p = &img.rgb[y * w + x];
                let cols = x.saturating_sub(1)..(x + 2).min(w);
                let edge = rows
                    .clone()
                    .flat_map(|yy| cols.clone().map(move |xx| yy * w + xx))
                    .any(|j| differ(p, &img.rgb[j]));
                edge.then_some((y * w + x) as u32)
            })
        })
        .collect()
}

/// `img` with each of `pixels` replaced by the matching value of `values`.
pub fn merge(img: &mut Image, pixels: &[u32], values: &[[f32; 3]]) {
    for (&i, &v) in pixels.iter().zip(values) {
        img.rgb[i as usize] = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> Image {
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                img.rgb[(y * w + x) as usize] = [f(x, y); 3];
            }
        }
        img
    }

    #[test]
    fn an_edge_marks_the_pixels_on_both_sides_and_nothing_else() {
        // A bright half beside a dark one, with a smooth ramp on the bright side.
        let img = image(8, 4, |x, _| if x < 4 { 0.1 } else { 1.0 + 0.01 * x as f32 });
        let want: Vec<u32> = (0..4).flat_map(|y| [y * 8 + 3, y * 8 + 4]).collect();
        assert_eq!(marked(&img, 0.25), want);
        // Nothing differs by more than 2 (the edge: 0.9 / 0.55 ≈ 1.6).
        assert!(marked(&img, 2.0).is_empty());
    }

    #[test]
    fn a_speck_marks_itself_and_its_eight_neighbours() {
        let img = image(5, 5, |x, y| if (x, y) == (2, 2) { 3.0 } else { 0.2 });
        let want: Vec<u32> = (1..4)
            .flat_map(|y| (1..4).map(move |x| y * 5 + x))
            .collect();
        assert_eq!(marked(&img, 0.25), want);
    }

    #[test]
    fn a_pixel_that_is_not_finite_is_marked_with_its_neighbours_and_spoils_nothing_else() {
        let mut img = image(6, 3, |x, _| if x < 3 { 0.1 } else { 1.0 });
        img.rgb[0] = [f32::NAN, 0.1, 0.1];
        let want = [0, 1, 2, 3, 6, 7, 8, 9, 14, 15];
        assert_eq!(marked(&img, 0.25), want);
    }

    #[test]
    fn black_does_not_mark_its_noise() {
        // Differences far below 1 % of the image's mean count for nothing.
        let img = image(6, 6, |x, y| match (x, y) {
            (0, 0) => 10.0,
            _ if (x + y) % 2 == 0 => 0.0,
            _ => 1e-4,
        });
        assert_eq!(marked(&img, 0.25), vec![0, 1, 6, 7]);
    }
}
