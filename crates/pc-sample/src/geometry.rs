//! The analytic shapes a scene is made of (rectangles, boxes, spheres) and the jittered grids
//! ("patches") their surfaces are cut into.

use glam::{Quat, Vec3};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

use crate::SampleParams;

/// A parallelogram `center + s·u + t·v`, `s, t ∈ [-1, 1]` (u, v are half-edges).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub center: Vec3,
    pub u: Vec3,
    pub v: Vec3,
    /// Unit normal given to every splat; `normalize(u × v)` unless set explicitly.
    pub normal: Vec3,
}

impl Rect {
    /// Normal `normalize(u × v)`.
    pub fn new(center: Vec3, u: Vec3, v: Vec3) -> Self {
        Rect {
            center,
            u,
            v,
            normal: u.cross(v).normalize(),
        }
    }

    /// Explicit normal (normalized here).
    pub fn with_normal(center: Vec3, u: Vec3, v: Vec3, normal: Vec3) -> Self {
        Rect {
            center,
            u,
            v,
            normal: normal.normalize(),
        }
    }

    /// The same rectangle with the opposite normal.
    pub fn flipped(&self) -> Self {
        Rect {
            normal: -self.normal,
            ..*self
        }
    }

    pub fn area(&self) -> f32 {
        4.0 * self.u.cross(self.v).length()
    }

    /// The point at parameters `s, t ∈ [-1, 1]`.
    pub fn point(&self, s: f32, t: f32) -> Vec3 {
        self.center + s * self.u + t * self.v
    }
}

/// A box, possibly rotated; faces are sampled with outward normals unless `inward`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxShape {
    pub center: Vec3,
    pub half_extents: Vec3,
    pub rotation: Quat,
    pub inward: bool,
}

impl BoxShape {
    pub fn axis_aligned(center: Vec3, half_extents: Vec3) -> Self {
        BoxShape {
            center,
            half_extents,
            rotation: Quat::IDENTITY,
            inward: false,
        }
    }

    /// Rotated by `degrees` about the +y axis through its center.
    pub fn rotated_y(center: Vec3, half_extents: Vec3, degrees: f32) -> Self {
        BoxShape {
            center,
            half_extents,
            rotation: Quat::from_rotation_y(degrees.to_radians()),
            inward: false,
        }
    }

    /// The six faces (+x, -x, +y, -y, +z, -z before rotation), normals outward (or inward).
    pub fn faces(&self) -> [Rect; 6] {
        let r = self.rotation;
        let h = self.half_extents;
        let ax = r * Vec3::X * h.x;
        let ay = r * Vec3::Y * h.y;
        let az = r * Vec3::Z * h.z;
        let c = self.center;
        // (offset, u, v) with u × v pointing outward.
        let faces = [
            Rect::new(c + ax, ay, az),
            Rect::new(c - ax, az, ay),
            Rect::new(c + ay, az, ax),
            Rect::new(c - ay, ax, az),
            Rect::new(c + az, ax, ay),
            Rect::new(c - az, ay, ax),
        ];
        if self.inward {
            faces.map(|f| f.flipped())
        } else {
            faces
        }
    }

    pub fn area(&self) -> f32 {
        let h = self.half_extents;
        8.0 * (h.x * h.y + h.y * h.z + h.z * h.x)
    }
}

/// A sphere; normals outward unless `inward`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub center: Vec3,
    pub radius: f32,
    pub inward: bool,
}

impl Sphere {
    pub fn area(&self) -> f32 {
        4.0 * std::f32::consts::PI * self.radius * self.radius
    }
}

/// The analytic shape behind a sampled shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Geometry {
    Rect(Rect),
    Box(BoxShape),
    Sphere(Sphere),
}

impl Geometry {
    pub fn area(&self) -> f32 {
        match self {
            Geometry::Rect(r) => r.area(),
            Geometry::Box(b) => b.area(),
            Geometry::Sphere(s) => s.area(),
        }
    }

    /// "rectangle", "box" or "sphere".
    pub fn kind(&self) -> &'static str {
        match self {
            Geometry::Rect(_) => "rectangle",
            Geometry::Box(_) => "box",
            Geometry::Sphere(_) => "sphere",
        }
    }

    /// The grid patches the shape is sampled from, in output order.
    pub(crate) fn patches(&self) -> Vec<Patch> {
        match *self {
            Geometry::Rect(r) => vec![Patch::Rect(r)],
            Geometry::Box(b) => b.faces().into_iter().map(Patch::Rect).collect(),
            Geometry::Sphere(s) => (0..6)
                .map(|f| Patch::SphereFace { sphere: s, face: f })
                .collect(),
        }
    }
}

/// One jittered grid: a rectangle, or one of the six faces of a cube-sphere.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Patch {
    Rect(Rect),
    /// `face`: 0..6 = +x, -x, +y, -y, +z, -z.
    SphereFace {
        sphere: Sphere,
        face: usize,
    },
}

/// `sqrt(4π / 6)`: the side of a cube-sphere face in units of `sqrt(area per face)`.
const CUBE_SPHERE_SIDE: f32 = 1.447_202_4;

pub(crate) fn grid_count(length: f32, h: f32) -> usize {
    let n = (length / h).round();
    if n.is_finite() && n >= 1.0 {
        n as usize
    } else {
        1
    }
}

impl Patch {
    /// Grid size `(columns, rows)` at target spacing `h`.
    pub(crate) fn dims(&self, h: f32) -> (usize, usize) {
        match self {
            Patch::Rect(r) => (
                grid_count(2.0 * r.u.length(), h),
                grid_count(2.0 * r.v.length(), h),
            ),
            Patch::SphereFace { sphere, .. } => {
                let k = grid_count(CUBE_SPHERE_SIDE * sphere.radius, h);
                (k, k)
            }
        }
    }

    /// Lengths of the two grid axes (for a sphere face, in units of the face's angular side).
    pub(crate) fn side_lengths(&self) -> (f32, f32) {
        match self {
            Patch::Rect(r) => (2.0 * r.u.length(), 2.0 * r.v.length()),
            Patch::SphereFace { .. } => (1.0, 1.0),
        }
    }

    /// Fills row `j` (of `nv`) of an `nu × nv` grid: `(nu, nv, j)`, the row's positions, normals
    /// and radii in `out`.
    pub(crate) fn sample_row(
        &self,
        (nu, nv, j): (usize, usize, usize),
        rng: &mut Pcg64Mcg,
        params: &SampleParams,
        (pos, nrm, rad): (&mut [Vec3], &mut [Vec3], &mut [f32]),
    ) {
        let jit = params.jitter.clamp(0.0, 1.0);
        let frac = |rng: &mut Pcg64Mcg| 0.5 + jit * (rng.random::<f32>() - 0.5);
        match self {
            Patch::Rect(r) => {
                let du = 2.0 / nu as f32;
                let dv = 2.0 / nv as f32;
                let cell = (2.0 * r.u.length() / nu as f32).max(2.0 * r.v.length() / nv as f32);
                let radius = cell * params.radius_factor;
                for i in 0..nu {
                    let s = -1.0 + (i as f32 + frac(rng)) * du;
                    let t = -1.0 + (j as f32 + frac(rng)) * dv;
                    pos[i] = r.point(s, t);
                    nrm[i] = r.normal;
                    rad[i] = radius;
                }
            }
            Patch::SphereFace { sphere, face } => {
                let (e, t1, t2) = cube_face_frame(*face);
                let k = nu as f32;
                let dir = |a: f32, b: f32| -> Vec3 {
                    let q = std::f32::consts::FRAC_PI_4;
                    (e + (q * a).tan() * t1 + (q * b).tan() * t2).normalize()
                };
                let b0 = -1.0 + 2.0 * j as f32 / nv as f32;
                let b1 = -1.0 + 2.0 * (j + 1) as f32 / nv as f32;
                let rr = sphere.radius;
                let sign = if sphere.inward { -1.0 } else { 1.0 };
                // Corner directions of this row's cells, shared between neighbours.
                let a_at = |i: usize| -1.0 + 2.0 * i as f32 / k;
                let lo: Vec<Vec3> = (0..=nu).map(|i| dir(a_at(i), b0) * rr).collect();
                let hi: Vec<Vec3> = (0..=nu).map(|i| dir(a_at(i), b1) * rr).collect();
                for i in 0..nu {
                    let (a0, a1) = (a_at(i), a_at(i + 1));
                    let (c00, c10, c01, c11) = (lo[i], lo[i + 1], hi[i], hi[i + 1]);
                    // Cell size: longest edge, or longest diagonal / √2 for skewed cells.
                    let cell = (c10 - c00)
                        .length()
                        .max((c01 - c00).length())
                        .max((c11 - c10).length())
                        .max((c11 - c01).length())
                        .max((c11 - c00).length() * std::f32::consts::FRAC_1_SQRT_2)
                        .max((c10 - c01).length() * std::f32::consts::FRAC_1_SQRT_2);
                    let a = a0 + frac(rng) * (a1 - a0);
                    let b = b0 + frac(rng) * (b1 - b0);
                    let d = dir(a, b);
                    pos[i] = sphere.center + d * rr;
                    nrm[i] = d * sign;
                    rad[i] = cell * params.radius_factor;
                }
            }
        }
    }
}

/// (face normal, tangent 1, tangent 2) of cube face `f` with t1 × t2 = normal.
fn cube_face_frame(f: usize) -> (Vec3, Vec3, Vec3) {
    match f {
        0 => (Vec3::X, Vec3::Y, Vec3::Z),
        1 => (Vec3::NEG_X, Vec3::Z, Vec3::Y),
        2 => (Vec3::Y, Vec3::Z, Vec3::X),
        3 => (Vec3::NEG_Y, Vec3::X, Vec3::Z),
        4 => (Vec3::Z, Vec3::X, Vec3::Y),
        _ => (Vec3::NEG_Z, Vec3::Y, Vec3::X),
    }
}
