//! Pinhole camera: primary-ray generation with Mitsuba's conventions (pixel (0,0) top-left).
//!
//! For a film position (sx, sy) in `[0, 1]²` (sx to the right, sy down) the world direction is
//! `normalize(forward + (2 sx - 1) tx · right + (1 - 2 sy) ty · up)` where `right =
//! normalize(forward × up)`, `up = right × forward`, and (tx, ty) are the tangents of the half
//! field of view along x and y (the configured axis gets tan(fov/2), the other scales by the
//! aspect ratio). This is the same ray Mitsuba 3 builds from `look_at` (its local +x points to
//! the image's left, hence the sign flips cancel); a test checks it against rays Mitsuba
//! produced for the reference Cornell box.

use glam::Vec3;

use pc_config::{CameraConfig, FovAxis};

/// A ready-to-use pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub origin: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    /// tan of half the field of view along x and y.
    pub tan_half: (f32, f32),
    pub width: u32,
    pub height: u32,
}

impl Camera {
    pub fn new(c: &CameraConfig) -> Camera {
        let origin = Vec3::from(c.origin);
        let forward = (Vec3::from(c.target) - origin).normalize();
        let right = forward.cross(Vec3::from(c.up)).normalize();
        let up = right.cross(forward);
        let (w, h) = (c.width as f32, c.height as f32);
        let t = (c.fov.to_radians() * 0.5).tan();
        let along_x = match c.fov_axis {
            FovAxis::X => true,
            FovAxis::Y => false,
            FovAxis::Smaller => w <= h,
            FovAxis::Larger => w >= h,
        };
        let tan_half = if along_x {
            (t, t * h / w)
        } else {
            (t * w / h, t)
        };
        Camera {
            origin,
            forward,
            right,
            up,
            tan_half,
            width: c.width,
            height: c.height,
        }
    }

    /// Unit direction through film position (sx, sy) in `[0, 1]²` (sx right, sy down).
    #[inline]
    pub fn direction(&self, sx: f32, sy: f32) -> Vec3 {
        let x = (2.0 * sx - 1.0) * self.tan_half.0;
        let y = (1.0 - 2.0 * sy) * self.tan_half.1;
        (self.forward + x * self.right + y * self.up).normalize()
    }

    /// Unit direction through the point (u, v) in [0,1)² of pixel (i, j).
    #[inline]
    pub fn pixel_direction(&self, i: u32, j: u32, u: f32, v: f32) -> Vec3 {
        self.direction(
            (i as f32 + u) / self.width as f32,
            (j as f32 + v) / self.height as f32,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference scene's camera reproduces the rays Mitsuba generated (sensor.test_rays).
    #[test]
    fn matches_mitsuba_test_rays() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/reference/cornell/cornell.scene.json"
        );
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| {
            panic!("{path}: {e} (the reference data lives in ../shared beside the repository)")
        });
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        let s = &json["sensor"];
        let v3 = |v: &serde_json::Value| -> [f32; 3] {
            [
                v[0].as_f64().unwrap() as f32,
                v[1].as_f64().unwrap() as f32,
                v[2].as_f64().unwrap() as f32,
            ]
        };
        let axis = match s["fov_axis"].as_str().unwrap() {
            "x" => FovAxis::X,
            "y" => FovAxis::Y,
            "smaller" => FovAxis::Smaller,
            other => panic!("unexpected fov axis {other}"),
        };
        let cfg = CameraConfig {
            origin: v3(&s["origin"]),
            target: v3(&s["target"]),
            up: v3(&s["up"]),
            fov: s["fov_deg"].as_f64().unwrap() as f32,
            fov_axis: axis,
            width: s["film"]["width"].as_u64().unwrap() as u32,
            height: s["film"]["height"].as_u64().unwrap() as u32,
        };
        let cam = Camera::new(&cfg);
        let rays = json["test_rays"].as_array().unwrap();
        assert!(rays.len() >= 4);
        for r in rays {
            let f = &r["film_pos"];
            let d = cam.direction(f[0].as_f64().unwrap() as f32, f[1].as_f64().unwrap() as f32);
            let want = Vec3::from(v3(&r["direction"]));
            assert!(
                (d - want).length() < 2e-6,
                "film {f}: got {d}, Mitsuba {want}"
            );
            // Mitsuba starts rays at the near clip plane along the same line through the origin.
            let o = Vec3::from(v3(&r["origin"]));
            let along = (o - cam.origin).cross(d).length();
            assert!(along < 1e-5, "origin off the ray line by {along}");
        }
    }

    #[test]
    fn non_square_fov_axes() {
        let mut c = CameraConfig {
            width: 200,
            height: 100,
            fov: 90.0,
            ..Default::default()
        };
        c.fov_axis = FovAxis::X;
        let cam = Camera::new(&c);
        assert!((cam.tan_half.0 - 1.0).abs() < 1e-6 && (cam.tan_half.1 - 0.5).abs() < 1e-6);
        c.fov_axis = FovAxis::Smaller;
        let cam = Camera::new(&c);
        assert!((cam.tan_half.1 - 1.0).abs() < 1e-6 && (cam.tan_half.0 - 2.0).abs() < 1e-6);
        // pixel (0,0) is top-left: its ray points left (-right) and up.
        let d = cam.pixel_direction(0, 0, 0.5, 0.5);
        assert!(d.dot(cam.right) < 0.0 && d.dot(cam.up) > 0.0);
    }
}
