//! Where the camera's rays through each pixel can first meet a splat, at the nearest: a lower
//! bound per pixel on the hit distance, from every splat's bounding sphere projected onto the
//! image (a conservative rasterization). The CPU renderer starts each camera ray's walk there
//! instead of at the camera, so the walk skips the empty cells in front of the surfaces
//! (docs/raytrace.md, "Camera rays start near their surface").
//!
//! Exact: no disk is met by a ray through the pixel before its bound, so the walk from the bound
//! accepts the same first hit, in the same leaf, as the walk from the camera (the cells it
//! skips end before any hit; test `camera_rays_from_their_pixel_bound_hit_what_they_hit_from_the_camera`).
//! The pass costs 45-65 ns a splat on one thread of the AMD EPYC, and saves 60-210 ns a camera
//! sample (the default scene, the 4M and 20M hall scans), so a frame makes it only where it has
//! at least as many camera samples as splats ([`pays`]). The GPU kernel walks from the camera;
//! the images agree either way.

use glam::Vec3;
use pc_tree::OctreeView;
use rayon::prelude::*;

use crate::camera::Camera;

/// The bound of each pixel (row-major), in the camera rays' parameter (their directions are
/// unit vectors, so it is a distance from the camera): at most the distance at which any ray
/// through the pixel meets a splat, 0 where a splat may reach the camera's own plane.
pub fn near_bounds(view: &OctreeView, cam: &Camera) -> Vec<f32> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    if w * h == 0 {
        return Vec::new();
    }
    let frame = Frame::of(cam);
    // One image of bounds per worker, then their least: a splat touches a few pixels, and
    // neighbouring splats (the data pool's Morton order) the same ones.
    let parts = rayon::current_num_threads().max(1);
    let per = view.splats.len().div_ceil(parts).max(1);
    view.splats
        .par_chunks(per)
        .map(|chunk| {
            let mut near = vec![f32::INFINITY; w * h];
            for s in chunk {
                let (c, r) = (Vec3::from(s.position), s.radius);
                if let Some((cols, rows, d)) = frame.footprint(c, r) {
                    for y in rows {
                        for v in &mut near[y * w + cols.start..y * w + cols.end] {
                            *v = v.min(d);
                        }
                    }
                }
            }
            near
        })
        .reduce_with(|mut a, b| {
            a.iter_mut().zip(&b).for_each(|(x, &y)| *x = x.min(y));
            a
        })
        .unwrap_or_else(|| vec![f32::INFINITY; w * h])
}

/// Whether a frame of `samples` camera samples over `splats` splats gains by the bounds: the
/// pass costs about what a camera sample gains, per splat.
pub fn pays(splats: usize, samples: u64) -> bool {
    splats as u64 <= samples
}

/// The camera as [`near_bounds`] projects with it.
struct Frame {
    origin: Vec3,
    axes: [Vec3; 3],
    tan: [f32; 2],
    /// √(1 + tan²) per image axis: a side plane's normal, unnormalised, is that long.
    slant: [f32; 2],
    size: [usize; 2],
}

impl Frame {
    fn of(cam: &Camera) -> Frame {
        let tan = [cam.tan_half.0, cam.tan_half.1];
        Frame {
            origin: cam.origin,
            axes: [cam.right, cam.up, cam.forward],
            tan,
            slant: tan.map(|t| (1.0 + t * t).sqrt()),
            size: [cam.width as usize, cam.height as usize],
        }
    }

    /// The pixels (columns, rows) that rays meeting the sphere of radius `r` around `c` may
    /// pass through, and the least distance from the camera to the sphere (less a margin far
    /// above the rounding of a hit's parameter); None where no ray through the image meets it.
    fn footprint(
        &self,
        c: Vec3,
        r: f32,
    ) -> Option<(std::ops::Range<usize>, std::ops::Range<usize>, f32)> {
        let v = c - self.origin;
        let [x, y, z] = self.axes.map(|a| a.dot(v));
        if !(x.is_finite() && y.is_finite() && z.is_finite() && r.is_finite()) || z + r <= 0.0 {
            return None; // behind the camera
        }
        // Outside a side plane of the view's pyramid by more than its radius.
        let [tx, ty] = self.tan;
        let [kx, ky] = self.slant.map(|k| k * r);
        if x - z * tx > kx || -x - z * tx > kx || y - z * ty > ky || -y - z * ty > ky {
            return None;
        }
        let d = ((v.length() - r) * (1.0 - 1e-5) - 1e-4 * r).max(0.0);
        let [w, h] = self.size;
        if z - r <= 0.0 {
            return Some((0..w, 0..h, d)); // it reaches the camera's plane: anywhere
        }
        // The sphere's box seen from the camera: x / z and y / z over its corners.
        let ratio = |a: f32| {
            let lo = (a - r) / if a - r >= 0.0 { z + r } else { z - r };
            let hi = (a + r) / if a + r >= 0.0 { z - r } else { z + r };
            (lo, hi)
        };
        let ((xlo, xhi), (ylo, yhi)) = (ratio(x), ratio(y));
        // Pixel (column, row) of a film position, a hundredth of a pixel wider each way for the
        // rounding (of a sample's direction, and of these ratios).
        let cols = span(
            (xlo / tx + 1.0) * 0.5 * w as f32,
            (xhi / tx + 1.0) * 0.5 * w as f32,
            w,
        );
        let rows = span(
            (1.0 - yhi / ty) * 0.5 * h as f32,
            (1.0 - ylo / ty) * 0.5 * h as f32,
            h,
        );
        Some((cols?, rows?, d))
    }
}

/// The pixels from the one holding film coordinate `lo` to the one holding `hi` (in pixels),
/// each widened by [`MARGIN`], clipped to `0..n`; None when empty, all of them when either is
/// NaN.
fn span(lo: f32, hi: f32, n: usize) -> Option<std::ops::Range<usize>> {
    if lo.is_nan() || hi.is_nan() {
        return Some(0..n);
    }
    let clip = |t: f32| t.floor().clamp(-1.0, n as f32) as i64;
    let (a, b) = (
        clip(lo - MARGIN).max(0),
        clip(hi + MARGIN).min(n as i64 - 1),
    );
    (a <= b).then(|| a as usize..b as usize + 1)
}

/// Pixels a footprint is widened by each way: far above the rounding of a film coordinate
/// (2.4·10⁻⁴ of a pixel at 4,000 pixels), far below the pixel itself, whose widening by a
/// whole pixel tripled the pass's writes on sub-pixel splats.
const MARGIN: f32 = 0.01;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_are_clipped_and_widened() {
        assert_eq!(span(3.2, 5.9, 10), Some(3..6));
        assert_eq!(span(3.995, 4.5, 10), Some(3..5));
        assert_eq!(span(4.2, 4.995, 10), Some(4..6));
        assert_eq!(span(-40.0, -3.5, 10), None);
        assert_eq!(span(12.0, 30.0, 10), None);
        assert_eq!(span(-1.0, 0.5, 10), Some(0..1));
        assert_eq!(span(f32::NEG_INFINITY, f32::INFINITY, 10), Some(0..10));
        assert_eq!(span(9.5, 9.7, 10), Some(9..10));
        assert_eq!(span(f32::NAN, 3.0, 10), Some(0..10));
    }
}
