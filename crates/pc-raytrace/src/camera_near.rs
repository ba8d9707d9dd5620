//! Where the camera's rays through each pixel can first meet a splat, at the nearest: a lower
//! bound per pixel on the hit distance, from the box of every leaf's own disks projected onto
//! the image (a conservative rasterization). The CPU renderer starts each camera ray's walk
//! there instead of at the camera, so the walk skips the empty cells in front of the surfaces
//! (docs/raytrace.md, "Camera rays start near their surface").
//!
//! Exact: no disk is met by a ray through the pixel before its bound, so the walk from the bound
//! accepts the same first hit, in the same leaf, as the walk from the camera (the cells it
//! skips end before any hit; test `camera_rays_from_their_pixel_bound_hit_what_they_hit_from_the_camera`).
//! A frame makes the bounds only where it has at least a quarter as many camera samples as
//! splats ([`pays`]). The GPU kernel walks from the camera; the images agree either way.

use glam::Vec3;
use pc_tree::OctreeView;
use rayon::prelude::*;

use crate::camera::Camera;

/// The bound of each pixel (row-major), in the camera rays' parameter (their directions are
/// unit vectors, so it is a distance from the camera): at most the distance at which any ray
/// through the pixel meets a splat, 0 where a splat may reach the camera's own plane.
///
/// The data pool holds each leaf's own splats in one run: a run's disks make one box (each
/// disk reaching `r √(1 − n_k²)` along axis k), a few disks a box, which is what the pass
/// projects and writes.
pub fn near_bounds(view: &OctreeView, cam: &Camera) -> Vec<f32> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    if w * h == 0 {
        return Vec::new();
    }
    if view.splat_leaf.len() != view.splats.len() {
        // (The artifact's reader refuses such a tree.) Without each splat's leaf, no runs:
        // every ray starts at the camera.
        return vec![0.0; w * h];
    }
    let frame = Frame::of(cam);
    // One image of bounds per worker, then their least. Any split of the pool into runs holds
    // every disk in some box: a run cut by a chunk's end makes two boxes.
    let parts = rayon::current_num_threads().max(1);
    let per = view.splats.len().div_ceil(parts).max(1);
    view.splats
        .par_chunks(per)
        .zip(view.splat_leaf.par_chunks(per))
        .map(|(splats, leaves)| {
            let mut near = vec![f32::INFINITY; w * h];
            let mut draw = |b: &DiskBox| {
                if let Some((cols, rows, d)) = frame.footprint(b) {
                    for y in rows {
                        for v in &mut near[y * w + cols.start..y * w + cols.end] {
                            *v = v.min(d);
                        }
                    }
                }
            };
            let mut run = DiskBox::EMPTY;
            for (k, s) in splats.iter().enumerate() {
                if k > 0 && leaves[k] != leaves[k - 1] {
                    draw(&run);
                    run = DiskBox::EMPTY;
                }
                run.add(Vec3::from(s.position), Vec3::from(s.normal), s.radius);
            }
            if !splats.is_empty() {
                draw(&run);
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
/// pass costs 15-30 ns a splat on one thread, a camera sample gains 60-200 ns, and the frames
/// measured gained with up to four splats a sample and lost from about six (docs/raytrace.md).
pub fn pays(splats: usize, samples: u64) -> bool {
    splats as u64 <= 4 * samples
}

/// The box of some disks, and their largest radius.
#[derive(Clone, Copy, Debug)]
struct DiskBox {
    lo: Vec3,
    hi: Vec3,
    radius: f32,
}

impl DiskBox {
    const EMPTY: DiskBox = DiskBox {
        lo: Vec3::splat(f32::INFINITY),
        hi: Vec3::splat(f32::NEG_INFINITY),
        radius: 0.0,
    };

    /// Takes in the disk of centre `c`, unit normal `n` and radius `r`.
    fn add(&mut self, c: Vec3, n: Vec3, r: f32) {
        let reach = (Vec3::ONE - n * n).max(Vec3::ZERO).powf(0.5) * r;
        self.lo = self.lo.min(c - reach);
        self.hi = self.hi.max(c + reach);
        self.radius = self.radius.max(r);
    }
}

/// The camera as [`near_bounds`] projects with it.
struct Frame {
    origin: Vec3,
    axes: [Vec3; 3],
    tan: [f32; 2],
    size: [usize; 2],
}

impl Frame {
    fn of(cam: &Camera) -> Frame {
        let tan = [cam.tan_half.0, cam.tan_half.1];
        Frame {
            origin: cam.origin,
            axes: [cam.right, cam.up, cam.forward],
            tan,
            size: [cam.width as usize, cam.height as usize],
        }
    }

    /// The pixels (columns, rows) that rays meeting the box `b` may pass through, and the
    /// least distance from the camera to the box (less a margin far above the rounding of a
    /// hit's parameter); None where no ray through the image meets it.
    fn footprint(
        &self,
        b: &DiskBox,
    ) -> Option<(std::ops::Range<usize>, std::ops::Range<usize>, f32)> {
        let (centre, half) = ((b.lo + b.hi) * 0.5, (b.hi - b.lo) * 0.5);
        let v = centre - self.origin;
        // The box in the camera's frame: its centre, and the half extents of the box around it.
        let [x, y, z] = self.axes.map(|a| a.dot(v));
        let [hx, hy, hz] = self.axes.map(|a| a.abs().dot(half));
        let all = [x, y, z, hx, hy, hz];
        if !all.iter().all(|t| t.is_finite()) || z + hz <= 0.0 {
            return None; // behind the camera (or an empty box)
        }
        // Wholly outside a side plane of the view's pyramid: x − z·tan > 0 over the whole box.
        let [tx, ty] = self.tan;
        if x - z * tx > hx + hz * tx
            || -x - z * tx > hx + hz * tx
            || y - z * ty > hy + hz * ty
            || -y - z * ty > hy + hz * ty
        {
            return None;
        }
        let gap = (self.origin - b.hi)
            .max(b.lo - self.origin)
            .max(Vec3::ZERO)
            .length();
        let d = (gap * (1.0 - 1e-5) - 1e-4 * b.radius).max(0.0);
        let [w, h] = self.size;
        if z - hz <= 0.0 {
            return Some((0..w, 0..h, d)); // it reaches the camera's plane: anywhere
        }
        // x / z and y / z over the box.
        let ratio = |a: f32, ha: f32| {
            let lo = (a - ha) / if a - ha >= 0.0 { z + hz } else { z - hz };
            let hi = (a + ha) / if a + ha >= 0.0 { z - hz } else { z + hz };
            (lo, hi)
        };
        let ((xlo, xhi), (ylo, yhi)) = (ratio(x, hx), ratio(y, hy));
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
