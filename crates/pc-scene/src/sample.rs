//! Scene samplers: analytic surfaces (rectangles, boxes, spheres) turned into jittered-grid splats, and the built-in scenes.
//!
//! Every surface is cut into a grid of near-square cells whose size is close to one global
//! target spacing `h`, chosen so that the whole scene gets (almost exactly) the requested number
//! of splats (`h ≈ sqrt(total_area / N)`). Each cell gets one splat at its center moved by a
//! uniform random offset of at most `jitter / 2` of a cell along each grid axis; its normal is
//! the exact analytic normal and its radius is the cell size times `radius_factor`, so with the
//! defaults (jitter 0.2, factor 1.0) neighbouring disks overlap and the disks cover the surface.
//!
//! Spheres use a cube-sphere (equal-angle) mapping: six faces of `k × k` cells each, the radius
//! of each splat taken from its own cell's corner spacing.
//!
//! Sampling is deterministic for a given seed: every grid row draws from its own PCG stream
//! derived from (seed, shape name, patch, row), so the result does not depend on the rayon
//! schedule. Shapes, patches and rows are generated in parallel.

use crate::ply_write::{tmp_path, write_ply, PlyFormat, PlyPoints};
use anyhow::{Context, Result};
use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Sampling parameters shared by all scenes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleParams {
    /// Requested total number of splats in the scene.
    pub points: usize,
    pub seed: u64,
    /// Maximum jitter as a fraction of a cell (the offset along each grid axis is uniform in
    /// `[-jitter/2, jitter/2]` cells). In `[0, 1]`.
    pub jitter: f32,
    /// Splat radius divided by the cell size.
    pub radius_factor: f32,
}

impl Default for SampleParams {
    fn default() -> Self {
        SampleParams {
            points: 100_000,
            seed: 0,
            jitter: 0.2,
            radius_factor: 1.0,
        }
    }
}

impl SampleParams {
    /// Parameters for `points` splats, other fields at their defaults.
    pub fn with_points(points: usize) -> Self {
        SampleParams {
            points,
            ..Default::default()
        }
    }

    /// Checks the ranges (points ≥ 1, jitter in [0, 1], radius factor finite and > 0).
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.points == 0 {
            return Err("the number of points must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.jitter) {
            return Err(format!("jitter {} is outside [0, 1]", self.jitter));
        }
        if !(self.radius_factor.is_finite() && self.radius_factor > 0.0) {
            return Err(format!(
                "radius factor {} must be finite and positive",
                self.radius_factor
            ));
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Geometry
// ---------------------------------------------------------------------------------------------

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
    fn patches(&self) -> Vec<Patch> {
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
enum Patch {
    Rect(Rect),
    /// `face`: 0..6 = +x, -x, +y, -y, +z, -z.
    SphereFace {
        sphere: Sphere,
        face: usize,
    },
}

/// `sqrt(4π / 6)`: the side of a cube-sphere face in units of `sqrt(area per face)`.
const CUBE_SPHERE_SIDE: f32 = 1.447_202_4;

fn grid_count(length: f32, h: f32) -> usize {
    let n = (length / h).round();
    if n.is_finite() && n >= 1.0 {
        n as usize
    } else {
        1
    }
}

impl Patch {
    /// Grid size `(columns, rows)` at target spacing `h`.
    fn dims(&self, h: f32) -> (usize, usize) {
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
    fn side_lengths(&self) -> (f32, f32) {
        match self {
            Patch::Rect(r) => (2.0 * r.u.length(), 2.0 * r.v.length()),
            Patch::SphereFace { .. } => (1.0, 1.0),
        }
    }

    /// Fills row `j` (of `nv`) of an `nu × nv` grid.
    #[allow(clippy::too_many_arguments)]
    fn sample_row(
        &self,
        nu: usize,
        nv: usize,
        j: usize,
        rng: &mut Pcg64Mcg,
        params: &SampleParams,
        pos: &mut [Vec3],
        nrm: &mut [Vec3],
        rad: &mut [f32],
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

// ---------------------------------------------------------------------------------------------
// Shapes and scenes
// ---------------------------------------------------------------------------------------------

/// A shape to sample: its name (used in file names), material name and geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeSpec {
    pub name: String,
    pub material: String,
    pub geometry: Geometry,
}

impl ShapeSpec {
    pub fn new(name: &str, material: &str, geometry: Geometry) -> Self {
        ShapeSpec {
            name: name.to_owned(),
            material: material.to_owned(),
            geometry,
        }
    }
}

/// The splats of one shape.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledShape {
    pub name: String,
    pub material: String,
    pub geometry: Geometry,
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub radii: Vec<f32>,
    /// Analytic surface area.
    pub area: f32,
}

impl SampledShape {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Borrowed view for [`write_ply`].
    pub fn ply_points(&self) -> PlyPoints<'_> {
        PlyPoints {
            positions: &self.positions,
            normals: Some(&self.normals),
            radii: Some(&self.radii),
            colors: None,
        }
    }
}

/// A material in the pipeline.toml schema (`[materials.NAME]`).
#[derive(Clone, Debug, PartialEq)]
pub enum MaterialDesc {
    Diffuse {
        albedo: [f32; 3],
    },
    Emitter {
        radiance: [f32; 3],
        albedo: Option<[f32; 3]>,
    },
    Mirror {
        reflectance: [f32; 3],
        phong: Option<f32>,
    },
    Dielectric {
        ior: f32,
        tint: Option<[f32; 3]>,
    },
}

impl MaterialDesc {
    /// The `type = "..."` value.
    pub fn type_name(&self) -> &'static str {
        match self {
            MaterialDesc::Diffuse { .. } => "diffuse",
            MaterialDesc::Emitter { .. } => "emitter",
            MaterialDesc::Mirror { .. } => "mirror",
            MaterialDesc::Dielectric { .. } => "dielectric",
        }
    }

    /// The body of the `[materials.NAME]` table (one `key = value` per line).
    fn toml_body(&self) -> String {
        let mut s = format!("type = \"{}\"\n", self.type_name());
        match self {
            MaterialDesc::Diffuse { albedo } => {
                let _ = writeln!(s, "albedo = {}", toml_vec(*albedo));
            }
            MaterialDesc::Emitter { radiance, albedo } => {
                let _ = writeln!(s, "radiance = {}", toml_vec(*radiance));
                if let Some(a) = albedo {
                    let _ = writeln!(s, "albedo = {}", toml_vec(*a));
                }
            }
            MaterialDesc::Mirror { reflectance, phong } => {
                let _ = writeln!(s, "reflectance = {}", toml_vec(*reflectance));
                if let Some(p) = phong {
                    let _ = writeln!(s, "phong = {}", toml_f32(*p));
                }
            }
            MaterialDesc::Dielectric { ior, tint } => {
                let _ = writeln!(s, "ior = {}", toml_f32(*ior));
                if let Some(t) = tint {
                    let _ = writeln!(s, "tint = {}", toml_vec(*t));
                }
            }
        }
        s
    }
}

/// A point light (`[[lights]]`), intensity in W/sr.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: Vec3,
    pub intensity: Vec3,
}

/// The `[camera]` table.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraDesc {
    pub origin: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Field of view in degrees along `fov_axis`.
    pub fov: f32,
    /// "x", "y" or "smaller".
    pub fov_axis: String,
    pub width: u32,
    pub height: u32,
}

impl CameraDesc {
    /// The Cornell camera: at (0, 0, 3.9) looking at the origin, 39.3077° on the smaller axis.
    pub fn cornell() -> Self {
        CameraDesc {
            origin: Vec3::new(0.0, 0.0, 3.9),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fov: 39.3077,
            fov_axis: "smaller".into(),
            width: 512,
            height: 512,
        }
    }
}

/// A sampled scene, ready for [`write_scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct SampledScene {
    /// Scene name: prefix of the PLY file names ("cornell", "sphere", "glass-box").
    pub name: String,
    pub shapes: Vec<SampledShape>,
    /// Materials in output order.
    pub materials: Vec<(String, MaterialDesc)>,
    pub lights: Vec<PointLight>,
    pub camera: CameraDesc,
    pub params: SampleParams,
    /// The global target spacing the grids were sized from.
    pub spacing: f32,
}

impl SampledScene {
    pub fn total_points(&self) -> usize {
        self.shapes.iter().map(SampledShape::len).sum()
    }

    pub fn total_area(&self) -> f32 {
        self.shapes.iter().map(|s| s.area).sum()
    }

    /// PLY file name of a shape: `<scene>-<shape>.ply`.
    pub fn file_name(&self, shape: &SampledShape) -> String {
        format!("{}-{}.ply", self.name, shape.name)
    }

    /// The scene.toml text (pipeline.toml schema: materials, models, lights, camera).
    pub fn to_toml(&self) -> String {
        let p = &self.params;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# generated by pc-sample: {}, {} points, seed {}",
            self.name,
            self.total_points(),
            p.seed
        );
        let _ = writeln!(
            s,
            "# requested {} points; target spacing {}, jitter {}, radius factor {}; {} models",
            p.points,
            self.spacing,
            p.jitter,
            p.radius_factor,
            self.shapes.len()
        );
        for (name, m) in &self.materials {
            let _ = writeln!(s, "\n[materials.{}]", toml_key(name));
            s.push_str(&m.toml_body());
        }
        for shape in &self.shapes {
            let _ = writeln!(s, "\n[[models]]");
            let _ = writeln!(s, "file = {}", toml_str(&self.file_name(shape)));
            let _ = writeln!(s, "material = {}", toml_str(&shape.material));
        }
        for l in &self.lights {
            let _ = writeln!(s, "\n[[lights]]");
            let _ = writeln!(s, "position = {}", toml_vec(l.position.to_array()));
            let _ = writeln!(s, "intensity = {}", toml_vec(l.intensity.to_array()));
        }
        let c = &self.camera;
        let _ = writeln!(s, "\n[camera]");
        let _ = writeln!(s, "origin = {}", toml_vec(c.origin.to_array()));
        let _ = writeln!(s, "target = {}", toml_vec(c.target.to_array()));
        let _ = writeln!(s, "up = {}", toml_vec(c.up.to_array()));
        let _ = writeln!(s, "fov = {}", toml_f32(c.fov));
        let _ = writeln!(s, "fov_axis = {}", toml_str(&c.fov_axis));
        let _ = writeln!(s, "width = {}", c.width);
        let _ = writeln!(s, "height = {}", c.height);
        s
    }
}

fn toml_f32(x: f32) -> String {
    if x.is_nan() {
        "nan".into()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        // Debug prints the shortest round-trip text and always includes a '.' or an exponent.
        format!("{x:?}")
    }
}

fn toml_vec(v: [f32; 3]) -> String {
    format!(
        "[{}, {}, {}]",
        toml_f32(v[0]),
        toml_f32(v[1]),
        toml_f32(v[2])
    )
}

fn toml_str(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for ch in s.chars() {
        match ch {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 || c == '\u{7f}' => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn toml_key(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        s.to_owned()
    } else {
        toml_str(s)
    }
}

/// The built-in scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneKind {
    Cornell,
    Sphere,
    GlassBox,
}

impl SceneKind {
    pub const ALL: [SceneKind; 3] = [SceneKind::Cornell, SceneKind::Sphere, SceneKind::GlassBox];

    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Cornell => "cornell",
            SceneKind::Sphere => "sphere",
            SceneKind::GlassBox => "glass-box",
        }
    }
}

impl std::str::FromStr for SceneKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        SceneKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| format!("unknown scene {s:?} (expected cornell, sphere or glass-box)"))
    }
}

/// Builds a built-in scene (`with_specular` only affects `cornell`).
pub fn build_scene(kind: SceneKind, params: &SampleParams, with_specular: bool) -> SampledScene {
    match kind {
        SceneKind::Cornell => cornell(params, with_specular),
        SceneKind::Sphere => sphere(params),
        SceneKind::GlassBox => glass_box(params),
    }
}

/// The global target spacing giving a total count as close as possible to `points`: starts at
/// `sqrt(total_area / points)` and searches ±10 % around it (grid counts are rounded per patch).
pub fn choose_spacing(specs: &[ShapeSpec], points: usize) -> f32 {
    let patches: Vec<Patch> = specs.iter().flat_map(|s| s.geometry.patches()).collect();
    let area: f64 = specs.iter().map(|s| s.geometry.area() as f64).sum();
    let n = points.max(1) as f64;
    let h0 = (area / n).sqrt();
    if !(h0.is_finite() && h0 > 0.0) {
        return 1.0;
    }
    let count = |h: f32| -> usize {
        patches
            .iter()
            .map(|p| {
                let (a, b) = p.dims(h);
                a * b
            })
            .sum()
    };
    const STEPS: i32 = 400;
    let mut best = (usize::MAX, f64::MAX, h0 as f32);
    for k in -STEPS..=STEPS {
        let x = 0.1 * k as f64 / STEPS as f64;
        let h = (h0 * x.exp()) as f32;
        let err = count(h).abs_diff(points.max(1));
        let key = (err, x.abs());
        if key.0 < best.0 || (key.0 == best.0 && key.1 < best.1) {
            best = (err, x.abs(), h);
        }
    }
    best.2
}

/// Grid sizes `(columns, rows)` for every patch of every shape (boxes: 6 faces, spheres: 6
/// cube faces), planned for a total count close to the requested one.
#[derive(Clone, Debug, PartialEq)]
pub struct GridPlan {
    /// The global target spacing the grids started from.
    pub spacing: f32,
    /// `dims[shape][patch]`.
    pub dims: Vec<Vec<(usize, usize)>>,
}

impl GridPlan {
    pub fn total(&self) -> usize {
        self.dims.iter().flatten().map(|(a, b)| a * b).sum()
    }
}

/// Plans the grids: every patch sized from the spacing of [`choose_spacing`], then single rows
/// or columns added to (or removed from) the patches where that distorts the cells least, while
/// it brings the total closer to `points` (the global spacing alone moves in steps of whole
/// rows of every wall at once, too coarse for small counts).
pub fn plan_grids(specs: &[ShapeSpec], points: usize) -> GridPlan {
    let h = choose_spacing(specs, points);
    let patches: Vec<Vec<Patch>> = specs.iter().map(|s| s.geometry.patches()).collect();
    let mut dims: Vec<Vec<(usize, usize)>> = patches
        .iter()
        .map(|ps| ps.iter().map(|p| p.dims(h)).collect())
        .collect();
    let target = points.max(1) as i64;
    let mut count: i64 = dims.iter().flatten().map(|(a, b)| (a * b) as i64).sum();
    // Cell aspect badness |ln(cell_u / cell_v)|.
    let badness = |p: &Patch, (nu, nv): (usize, usize)| -> f32 {
        let (lu, lv) = p.side_lengths();
        ((lu / nu as f32) / (lv / nv as f32)).ln().abs()
    };
    let limit = 1.5f32.ln();
    for _ in 0..1_000_000 {
        let diff = target - count;
        if diff == 0 {
            break;
        }
        let step: i64 = diff.signum();
        // (badness, shape, patch, new dims, count change)
        type Move = (f32, usize, usize, (usize, usize), i64);
        let mut best: Option<Move> = None;
        for (si, ps) in patches.iter().enumerate() {
            for (pi, p) in ps.iter().enumerate() {
                let (nu, nv) = dims[si][pi];
                let old_bad = badness(p, (nu, nv));
                for axis in 0..2 {
                    let cand = if axis == 0 {
                        ((nu as i64 + step) as usize, nv)
                    } else {
                        (nu, (nv as i64 + step) as usize)
                    };
                    if cand.0 == 0 || cand.1 == 0 {
                        continue;
                    }
                    let delta = (cand.0 * cand.1) as i64 - (nu * nv) as i64;
                    if (diff - delta).abs() >= diff.abs() {
                        continue;
                    }
                    let bad = badness(p, cand);
                    if bad > old_bad.max(limit) {
                        continue;
                    }
                    if best.is_none_or(|b| bad < b.0) {
                        best = Some((bad, si, pi, cand, delta));
                    }
                }
            }
        }
        match best {
            Some((_, si, pi, cand, delta)) => {
                dims[si][pi] = cand;
                count += delta;
            }
            None => break,
        }
    }
    GridPlan { spacing: h, dims }
}

/// Samples every shape (in parallel) on the grids of [`plan_grids`]; returns the shapes and
/// the global target spacing.
pub fn sample_shapes(specs: &[ShapeSpec], params: &SampleParams) -> (Vec<SampledShape>, f32) {
    let plan = plan_grids(specs, params.points);
    let shapes = specs
        .par_iter()
        .zip(&plan.dims)
        .map(|(spec, dims)| sample_shape(spec, dims, params))
        .collect();
    (shapes, plan.spacing)
}

/// Samples one shape on the given grid sizes (one `(columns, rows)` per patch: 1 for a
/// rectangle, 6 for a box or a sphere, see [`GridPlan`]).
pub fn sample_shape(
    spec: &ShapeSpec,
    dims: &[(usize, usize)],
    params: &SampleParams,
) -> SampledShape {
    let patches = spec.geometry.patches();
    assert_eq!(
        patches.len(),
        dims.len(),
        "shape {}: one grid size per patch",
        spec.name
    );
    let total: usize = dims.iter().map(|(a, b)| a * b).sum();
    let mut positions = vec![Vec3::ZERO; total];
    let mut normals = vec![Vec3::ZERO; total];
    let mut radii = vec![0f32; total];
    let shape_key = fnv1a(spec.name.as_bytes());

    // Split the output into one slice triple per patch.
    let mut jobs = Vec::with_capacity(patches.len());
    {
        let (mut p, mut n, mut r) = (&mut positions[..], &mut normals[..], &mut radii[..]);
        for (idx, (patch, &(nu, nv))) in patches.iter().zip(dims).enumerate() {
            let len = nu * nv;
            let (p0, p1) = std::mem::take(&mut p).split_at_mut(len);
            let (n0, n1) = std::mem::take(&mut n).split_at_mut(len);
            let (r0, r1) = std::mem::take(&mut r).split_at_mut(len);
            jobs.push((idx, patch, nu, nv, p0, n0, r0));
            p = p1;
            n = n1;
            r = r1;
        }
    }
    jobs.into_par_iter()
        .for_each(|(idx, patch, nu, nv, p, n, r)| {
            p.par_chunks_mut(nu)
                .zip(n.par_chunks_mut(nu))
                .zip(r.par_chunks_mut(nu))
                .enumerate()
                .for_each(|(j, ((p, n), r))| {
                    let mut rng = Pcg64Mcg::seed_from_u64(stream_seed(
                        params.seed,
                        shape_key,
                        idx as u64,
                        j as u64,
                    ));
                    patch.sample_row(nu, nv, j, &mut rng, params, p, n, r);
                });
        });

    SampledShape {
        name: spec.name.clone(),
        material: spec.material.clone(),
        geometry: spec.geometry,
        positions,
        normals,
        radii,
        area: spec.geometry.area(),
    }
}

fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn stream_seed(seed: u64, shape: u64, patch: u64, row: u64) -> u64 {
    splitmix64(splitmix64(splitmix64(splitmix64(seed) ^ shape) ^ patch) ^ row)
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3)
    })
}

/// The five walls of the room [-1, 1]^3 open at z = +1, normals into the room:
/// floor, ceiling, back, left (x = -1), right (x = +1).
fn room_walls() -> [Rect; 5] {
    [
        Rect::new(Vec3::new(0.0, -1.0, 0.0), Vec3::Z, Vec3::X),
        Rect::new(Vec3::new(0.0, 1.0, 0.0), Vec3::X, Vec3::Z),
        Rect::new(Vec3::new(0.0, 0.0, -1.0), Vec3::X, Vec3::Y),
        Rect::new(Vec3::new(-1.0, 0.0, 0.0), Vec3::Y, Vec3::Z),
        Rect::new(Vec3::new(1.0, 0.0, 0.0), Vec3::Z, Vec3::Y),
    ]
}

/// The ceiling light: 0.46 × 0.38 at y = 0.99, facing down.
fn ceiling_light() -> Rect {
    Rect::new(
        Vec3::new(0.0, 0.99, 0.0),
        Vec3::new(0.23, 0.0, 0.0),
        Vec3::new(0.0, 0.0, 0.19),
    )
}

const WHITE: [f32; 3] = [0.75, 0.75, 0.75];
const RED: [f32; 3] = [0.63, 0.065, 0.05];
const GREEN: [f32; 3] = [0.14, 0.45, 0.091];

fn light_material() -> MaterialDesc {
    MaterialDesc::Emitter {
        radiance: [17.0, 12.0, 4.0],
        albedo: Some([0.78, 0.78, 0.78]),
    }
}

fn glass_material() -> MaterialDesc {
    MaterialDesc::Dielectric {
        ior: 1.5,
        tint: Some([1.0, 1.0, 1.0]),
    }
}

fn mirror_material() -> MaterialDesc {
    MaterialDesc::Mirror {
        reflectance: [0.95, 0.95, 0.95],
        phong: None,
    }
}

/// Shapes of the Cornell box (see [`cornell`]).
pub fn cornell_specs(with_specular: bool) -> Vec<ShapeSpec> {
    let [floor, ceiling, back, left, right] = room_walls();
    let mut specs = vec![
        ShapeSpec::new("floor", "white", Geometry::Rect(floor)),
        ShapeSpec::new("ceiling", "white", Geometry::Rect(ceiling)),
        ShapeSpec::new("back", "white", Geometry::Rect(back)),
        ShapeSpec::new("red-wall", "red", Geometry::Rect(left)),
        ShapeSpec::new("green-wall", "green", Geometry::Rect(right)),
        ShapeSpec::new("light", "light", Geometry::Rect(ceiling_light())),
        ShapeSpec::new(
            "short-box",
            "white",
            Geometry::Box(BoxShape::rotated_y(
                Vec3::new(0.35, -0.7, 0.3),
                Vec3::splat(0.3),
                -17.0,
            )),
        ),
        ShapeSpec::new(
            "tall-box",
            "white",
            Geometry::Box(BoxShape::rotated_y(
                Vec3::new(-0.33, -0.4, -0.3),
                Vec3::new(0.3, 0.6, 0.3),
                17.0,
            )),
        ),
    ];
    if with_specular {
        // Glass sphere on the floor, front left; mirror sphere resting on the short box.
        specs.push(ShapeSpec::new(
            "glass-sphere",
            "glass",
            Geometry::Sphere(Sphere {
                center: Vec3::new(-0.4, -0.75, 0.55),
                radius: 0.25,
                inward: false,
            }),
        ));
        specs.push(ShapeSpec::new(
            "mirror-sphere",
            "mirror",
            Geometry::Sphere(Sphere {
                center: Vec3::new(0.35, -0.18, 0.3),
                radius: 0.22,
                inward: false,
            }),
        ));
    }
    specs
}

/// Cornell box in [-1, 1]^3, open at z = +1, camera at (0, 0, 3.9) looking down -z: white
/// floor, ceiling and back wall, red wall at x = -1, green wall at x = +1 (normals into the box),
/// a 0.46 × 0.38 emitter at y = 0.99 facing down, a short and a tall box rotated about y
/// (outward normals). `with_specular` adds a glass sphere (ior 1.5) on the floor and a mirror
/// sphere on the short box.
pub fn cornell(params: &SampleParams, with_specular: bool) -> SampledScene {
    let specs = cornell_specs(with_specular);
    let (shapes, spacing) = sample_shapes(&specs, params);
    let mut materials = vec![
        ("white".to_string(), MaterialDesc::Diffuse { albedo: WHITE }),
        ("red".to_string(), MaterialDesc::Diffuse { albedo: RED }),
        ("green".to_string(), MaterialDesc::Diffuse { albedo: GREEN }),
        ("light".to_string(), light_material()),
    ];
    if with_specular {
        materials.push(("glass".to_string(), glass_material()));
        materials.push(("mirror".to_string(), mirror_material()));
    }
    SampledScene {
        name: "cornell".into(),
        shapes,
        materials,
        lights: Vec::new(),
        camera: CameraDesc::cornell(),
        params: *params,
        spacing,
    }
}

/// Furnace test: a closed unit sphere at the origin with inward normals, every splat an
/// emitter (radiance 1, albedo 0.5, so the converged radiance everywhere is 1 / (1 - 0.5) = 2).
/// Camera at the center looking down -z.
pub fn sphere(params: &SampleParams) -> SampledScene {
    let specs = vec![ShapeSpec::new(
        "shell",
        "emitter",
        Geometry::Sphere(Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
            inward: true,
        }),
    )];
    let (shapes, spacing) = sample_shapes(&specs, params);
    SampledScene {
        name: "sphere".into(),
        shapes,
        materials: vec![(
            "emitter".to_string(),
            MaterialDesc::Emitter {
                radiance: [1.0, 1.0, 1.0],
                albedo: Some([0.5, 0.5, 0.5]),
            },
        )],
        lights: Vec::new(),
        camera: CameraDesc {
            origin: Vec3::ZERO,
            target: Vec3::new(0.0, 0.0, -1.0),
            up: Vec3::Y,
            fov: 60.0,
            fov_axis: "smaller".into(),
            width: 512,
            height: 512,
        },
        params: *params,
        spacing,
    }
}

/// Shapes of the glass-box scene (see [`glass_box`]).
pub fn glass_box_specs() -> Vec<ShapeSpec> {
    let [floor, ceiling, back, left, right] = room_walls();
    vec![
        ShapeSpec::new("floor", "white", Geometry::Rect(floor)),
        ShapeSpec::new("ceiling", "white", Geometry::Rect(ceiling)),
        ShapeSpec::new("back", "white", Geometry::Rect(back)),
        ShapeSpec::new("left-wall", "white", Geometry::Rect(left)),
        ShapeSpec::new("right-wall", "white", Geometry::Rect(right)),
        ShapeSpec::new("light", "light", Geometry::Rect(ceiling_light())),
        ShapeSpec::new(
            "glass-sphere",
            "glass",
            Geometry::Sphere(Sphere {
                center: Vec3::new(0.0, -0.2, 0.0),
                radius: 0.35,
                inward: false,
            }),
        ),
    ]
}

/// Caustic test: the Cornell room (all white, open at z = +1, same light and camera) with a
/// glass sphere (ior 1.5, radius 0.35) floating under the light; it focuses the light into a
/// caustic on the floor.
pub fn glass_box(params: &SampleParams) -> SampledScene {
    let specs = glass_box_specs();
    let (shapes, spacing) = sample_shapes(&specs, params);
    SampledScene {
        name: "glass-box".into(),
        shapes,
        materials: vec![
            ("white".to_string(), MaterialDesc::Diffuse { albedo: WHITE }),
            ("light".to_string(), light_material()),
            ("glass".to_string(), glass_material()),
        ],
        lights: Vec::new(),
        camera: CameraDesc::cornell(),
        params: *params,
        spacing,
    }
}

// ---------------------------------------------------------------------------------------------
// Output
// ---------------------------------------------------------------------------------------------

/// Writes one binary little-endian PLY per shape (`<scene>-<shape>.ply`, `float x y z nx ny nz
/// radius`) and `scene.toml` into `dir` (created if needed); returns the path of `scene.toml`.
pub fn write_scene(scene: &SampledScene, dir: &Path) -> Result<PathBuf> {
    write_scene_with_format(scene, dir, PlyFormat::BinaryLittleEndian)
}

/// [`write_scene`] with a chosen PLY encoding.
pub fn write_scene_with_format(
    scene: &SampledScene,
    dir: &Path,
    format: PlyFormat,
) -> Result<PathBuf> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create directory {}", dir.display()))?;
    let p = &scene.params;
    scene
        .shapes
        .par_iter()
        .map(|shape| -> Result<()> {
            let path = dir.join(scene.file_name(shape));
            let comments = vec![
                format!("scene {}", scene.name),
                format!("shape {} ({})", shape.name, shape.geometry.kind()),
                format!("material {}", shape.material),
                format!(
                    "target spacing {}, jitter {}, radius factor {}, seed {}",
                    scene.spacing, p.jitter, p.radius_factor, p.seed
                ),
                "generated by pc-sample".to_string(),
            ];
            write_ply(&path, &shape.ply_points(), format, &comments)
                .with_context(|| format!("cannot write {}", path.display()))
        })
        .collect::<Result<Vec<()>>>()?;
    let toml_path = dir.join("scene.toml");
    let tmp = tmp_path(&toml_path);
    std::fs::write(&tmp, scene.to_toml())
        .and_then(|()| std::fs::rename(&tmp, &toml_path))
        .inspect_err(|_| {
            let _ = std::fs::remove_file(&tmp);
        })
        .with_context(|| format!("cannot write {}", toml_path.display()))?;
    Ok(toml_path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all_scenes(params: &SampleParams) -> Vec<SampledScene> {
        vec![
            cornell(params, false),
            cornell(params, true),
            sphere(params),
            glass_box(params),
        ]
    }

    #[test]
    fn total_count_close_to_requested() {
        for n in [1_000usize, 5_000, 100_000] {
            for scene in all_scenes(&SampleParams::with_points(n)) {
                let got = scene.total_points();
                let rel = (got as f64 - n as f64).abs() / n as f64;
                assert!(
                    rel <= 0.02,
                    "{} (specular shapes: {}): {got} splats for {n} requested",
                    scene.name,
                    scene.shapes.len()
                );
            }
        }
    }

    #[test]
    fn planned_cells_are_near_square() {
        for n in [100usize, 1_000, 5_000, 100_000, 1_000_000, 10_000_000] {
            for specs in [cornell_specs(false), cornell_specs(true), glass_box_specs()] {
                let plan = plan_grids(&specs, n);
                let rel = (plan.total() as f64 - n as f64).abs() / n as f64;
                assert!(
                    rel <= if n >= 1000 { 0.02 } else { 0.1 },
                    "{n}: {}",
                    plan.total()
                );
                for (spec, dims) in specs.iter().zip(&plan.dims) {
                    for (p, &(nu, nv)) in spec.geometry.patches().iter().zip(dims) {
                        let (lu, lv) = p.side_lengths();
                        let aspect = (lu / nu as f32) / (lv / nv as f32);
                        let aspect = aspect.max(1.0 / aspect);
                        if nu > 1 && nv > 1 {
                            assert!(aspect <= 1.5 + 1e-4, "{n} {}: {nu}x{nv}", spec.name);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn tiny_and_odd_counts_work() {
        for n in [1usize, 7, 100, 333] {
            for scene in all_scenes(&SampleParams::with_points(n)) {
                assert!(scene.total_points() >= scene.shapes.len());
                for s in &scene.shapes {
                    assert!(!s.is_empty());
                    assert!(s.radii.iter().all(|r| r.is_finite() && *r > 0.0));
                }
                if n >= 100 {
                    let rel = (scene.total_points() as f64 - n as f64).abs() / n as f64;
                    assert!(
                        rel < 0.2,
                        "{}: {} for {n}",
                        scene.name,
                        scene.total_points()
                    );
                }
            }
        }
    }

    /// Distance of `p` from the surface and whether `n` is the analytic normal there.
    fn on_surface(g: &Geometry, p: Vec3, n: Vec3) -> (f32, bool) {
        let rect_check = |r: &Rect| -> (f32, bool) {
            let d = p - r.center;
            let plane = d.dot(r.u.cross(r.v).normalize()).abs();
            let s = d.dot(r.u) / r.u.length_squared();
            let t = d.dot(r.v) / r.v.length_squared();
            let inside = s.abs() <= 1.0 + 1e-5 && t.abs() <= 1.0 + 1e-5;
            let dist = if inside { plane } else { f32::INFINITY };
            (dist, (n - r.normal).length() < 1e-6)
        };
        match g {
            Geometry::Rect(r) => rect_check(r),
            Geometry::Box(b) => b
                .faces()
                .iter()
                .map(rect_check)
                .filter(|&(_, ok)| ok)
                .fold((f32::INFINITY, false), |a, b| if b.0 < a.0 { b } else { a }),
            Geometry::Sphere(s) => {
                let d = p - s.center;
                let dist = (d.length() - s.radius).abs();
                let expect = if s.inward { -d } else { d } / s.radius;
                (dist, (n - expect).length() < 1e-5)
            }
        }
    }

    #[test]
    fn splats_lie_on_their_shapes_with_exact_normals() {
        for scene in all_scenes(&SampleParams::with_points(20_000)) {
            for s in &scene.shapes {
                assert_eq!(s.positions.len(), s.normals.len());
                assert_eq!(s.positions.len(), s.radii.len());
                for (p, n) in s.positions.iter().zip(&s.normals) {
                    assert!(
                        (n.length() - 1.0).abs() < 1e-6,
                        "{}: |n| = {}",
                        s.name,
                        n.length()
                    );
                    let (dist, normal_ok) = on_surface(&s.geometry, *p, *n);
                    assert!(dist < 1e-5, "{} {}: {p} is {dist} off", scene.name, s.name);
                    assert!(normal_ok, "{} {}: normal {n} at {p}", scene.name, s.name);
                }
                let area = s.geometry.area();
                assert!((s.area - area).abs() < 1e-6 * area.max(1.0));
            }
        }
    }

    #[test]
    fn normals_point_the_right_way() {
        let scene = cornell(&SampleParams::with_points(5_000), true);
        let get = |name: &str| scene.shapes.iter().find(|s| s.name == name).unwrap();
        // Room walls face the inside of the box.
        for s in ["floor", "ceiling", "back", "red-wall", "green-wall"] {
            let sh = get(s);
            for (p, n) in sh.positions.iter().zip(&sh.normals) {
                assert!(n.dot(-*p) > 0.9, "{s}: normal {n} at {p}");
            }
        }
        assert!(get("light").normals.iter().all(|n| n.y < -0.999));
        // Boxes and specular spheres face outward.
        for s in ["short-box", "tall-box", "glass-sphere", "mirror-sphere"] {
            let sh = get(s);
            let c = match sh.geometry {
                Geometry::Box(b) => b.center,
                Geometry::Sphere(sp) => sp.center,
                Geometry::Rect(r) => r.center,
            };
            assert!(sh
                .positions
                .iter()
                .zip(&sh.normals)
                .all(|(p, n)| n.dot(*p - c) > 0.0));
        }
        let furnace = sphere(&SampleParams::with_points(2_000));
        let sh = &furnace.shapes[0];
        assert!(sh
            .positions
            .iter()
            .zip(&sh.normals)
            .all(|(p, n)| n.dot(*p) < 0.0));
    }

    /// Every test point on every face is inside some disk of that face (same normal).
    #[test]
    fn disks_cover_every_surface() {
        let mut rng = Pcg64Mcg::seed_from_u64(12345);
        let params = SampleParams::with_points(5_000);
        for scene in [cornell(&params, true), sphere(&params), glass_box(&params)] {
            for s in &scene.shapes {
                let faces: Vec<Rect> = match s.geometry {
                    Geometry::Rect(r) => vec![r],
                    Geometry::Box(b) => b.faces().to_vec(),
                    Geometry::Sphere(sp) => {
                        for _ in 0..3_000 {
                            let q = loop {
                                let v = Vec3::new(
                                    rng.random::<f32>() * 2.0 - 1.0,
                                    rng.random::<f32>() * 2.0 - 1.0,
                                    rng.random::<f32>() * 2.0 - 1.0,
                                );
                                let l = v.length();
                                if l > 1e-3 && l <= 1.0 {
                                    break sp.center + v / l * sp.radius;
                                }
                            };
                            let covered = s
                                .positions
                                .iter()
                                .zip(&s.radii)
                                .any(|(p, r)| (q - *p).length() <= *r);
                            assert!(covered, "{} {}: {q} not covered", scene.name, s.name);
                        }
                        continue;
                    }
                };
                for f in faces {
                    let idx: Vec<usize> = (0..s.len())
                        .filter(|&i| (s.normals[i] - f.normal).length() < 1e-5)
                        .collect();
                    assert!(!idx.is_empty());
                    let mut worst = 0f32;
                    for _ in 0..2_000 {
                        let q = f.point(
                            rng.random::<f32>() * 2.0 - 1.0,
                            rng.random::<f32>() * 2.0 - 1.0,
                        );
                        let best = idx
                            .iter()
                            .map(|&i| (q - s.positions[i]).length() / s.radii[i])
                            .fold(f32::INFINITY, f32::min);
                        worst = worst.max(best);
                    }
                    // Corners included: with jitter 0.2 the farthest point is ≈ 0.85 cell.
                    assert!(worst <= 0.9, "{} {}: worst {worst}", scene.name, s.name);
                    for corner in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
                        let q = f.point(corner.0, corner.1);
                        assert!(idx
                            .iter()
                            .any(|&i| (q - s.positions[i]).length() <= s.radii[i]));
                    }
                }
            }
        }
    }

    #[test]
    fn radius_is_cell_size_times_factor() {
        let mut params = SampleParams::with_points(10_000);
        let a = cornell(&params, false);
        params.radius_factor = 1.5;
        let b = cornell(&params, false);
        assert_eq!(a.spacing, b.spacing);
        for (sa, sb) in a.shapes.iter().zip(&b.shapes) {
            assert_eq!(sa.positions, sb.positions);
            for (ra, rb) in sa.radii.iter().zip(&sb.radii) {
                assert!((rb - 1.5 * ra).abs() < 1e-6);
            }
        }
        // Rectangle radii stay within rounding of the target spacing; cells are near-square.
        for s in &a.shapes {
            if let Geometry::Rect(_) = s.geometry {
                let r = s.radii[0];
                assert!(
                    r > 0.8 * a.spacing && r < 1.5 * a.spacing,
                    "{}: {r}",
                    s.name
                );
            }
        }
        // πr² is a few times the area each splat stands for.
        let ratio = a
            .shapes
            .iter()
            .map(|s| {
                s.radii
                    .iter()
                    .map(|r| std::f32::consts::PI * r * r)
                    .sum::<f32>()
            })
            .sum::<f32>()
            / a.total_area();
        assert!(ratio > 2.5 && ratio < 4.0, "coverage ratio {ratio}");
    }

    #[test]
    fn deterministic_with_seed() {
        let p = SampleParams {
            points: 30_000,
            seed: 7,
            ..Default::default()
        };
        assert_eq!(cornell(&p, true), cornell(&p, true));
        assert_eq!(sphere(&p), sphere(&p));
        let q = SampleParams { seed: 8, ..p };
        let (a, b) = (cornell(&p, true), cornell(&q, true));
        assert_eq!(a.total_points(), b.total_points());
        assert_ne!(a.shapes[0].positions, b.shapes[0].positions);
        // Zero jitter gives the plain grid, whatever the seed.
        let z0 = SampleParams { jitter: 0.0, ..p };
        let z1 = SampleParams { jitter: 0.0, ..q };
        assert_eq!(glass_box(&z0).shapes, glass_box(&z1).shapes);
    }

    #[test]
    fn write_scene_files_and_toml() {
        let dir = tempfile::tempdir().unwrap();
        let scene = cornell(&SampleParams::with_points(3_000), true);
        let toml_path = write_scene(&scene, dir.path()).unwrap();
        assert_eq!(toml_path, dir.path().join("scene.toml"));
        let text = std::fs::read_to_string(&toml_path).unwrap();
        assert!(text.starts_with("# generated by pc-sample: cornell, "));
        let v: toml::Table = text.parse().unwrap();
        let keys: Vec<&str> = v.keys().map(String::as_str).collect();
        assert_eq!(keys.len(), 3, "{keys:?}");
        let mats = v["materials"].as_table().unwrap();
        assert_eq!(mats["white"]["type"].as_str(), Some("diffuse"));
        assert_eq!(mats["light"]["type"].as_str(), Some("emitter"));
        assert_eq!(mats["light"]["radiance"].as_array().unwrap().len(), 3);
        assert_eq!(mats["glass"]["ior"].as_float(), Some(1.5));
        assert_eq!(mats["mirror"]["type"].as_str(), Some("mirror"));
        let models = v["models"].as_array().unwrap();
        assert_eq!(models.len(), scene.shapes.len());
        for (m, s) in models.iter().zip(&scene.shapes) {
            let file = m["file"].as_str().unwrap();
            assert_eq!(file, format!("cornell-{}.ply", s.name));
            assert!(mats.contains_key(m["material"].as_str().unwrap()));
            let bytes = std::fs::read(dir.path().join(file)).unwrap();
            let marker = b"end_header\n";
            let hlen = bytes
                .windows(marker.len())
                .position(|w| w == marker)
                .unwrap()
                + marker.len();
            let header = std::str::from_utf8(&bytes[..hlen]).unwrap();
            assert!(header.contains("format binary_little_endian 1.0\n"));
            assert!(header.contains(&format!("element vertex {}\n", s.len())));
            assert!(header.contains(
                "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float radius\nend_header\n"
            ));
            assert_eq!(bytes.len(), hlen + s.len() * 28);
            let f = |k: usize| {
                f32::from_le_bytes(bytes[hlen + 4 * k..hlen + 4 * k + 4].try_into().unwrap())
            };
            let last = s.len() - 1;
            assert_eq!(f(7 * last + 1), s.positions[last].y);
            assert_eq!(f(7 * last + 6), s.radii[last]);
        }
        let cam = v["camera"].as_table().unwrap();
        assert_eq!(cam["fov_axis"].as_str(), Some("smaller"));
        assert_eq!(cam["width"].as_integer(), Some(512));
        let origin: Vec<f64> = cam["origin"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_float().unwrap())
            .collect();
        assert_eq!(origin, vec![0.0, 0.0, 3.9]);
        // No stray temporary files.
        for e in std::fs::read_dir(dir.path()).unwrap() {
            let name = e.unwrap().file_name().into_string().unwrap();
            assert!(!name.ends_with(".tmp"), "{name}");
        }
    }

    /// The written scene loads through the pipeline's own config parser and PLY reader.
    #[test]
    fn written_scenes_load_through_the_pipeline() {
        for (kind, spec) in [
            (SceneKind::Cornell, true),
            (SceneKind::Sphere, false),
            (SceneKind::GlassBox, false),
        ] {
            let dir = tempfile::tempdir().unwrap();
            let scene = build_scene(kind, &SampleParams::with_points(2_000), spec);
            let toml_path = write_scene(&scene, dir.path()).unwrap();
            let cfg = crate::config::load_config(&toml_path, &[]).unwrap();
            assert_eq!(cfg.config.models.len(), scene.shapes.len());
            assert_eq!(cfg.config.materials.len(), scene.materials.len());
            let loaded = crate::load::load_scene(&cfg, &mut |_, _| {}).unwrap();
            assert_eq!(loaded.splats.len(), scene.total_points());
            assert_eq!(loaded.dropped(), 0);
            assert!(loaded
                .models
                .iter()
                .all(|m| !m.estimated_normals && !m.estimated_radii));
            let first = &scene.shapes[0];
            assert_eq!(loaded.splats.positions[..first.len()], first.positions[..]);
            assert_eq!(loaded.splats.radii[..first.len()], first.radii[..]);
        }
    }

    #[test]
    fn toml_number_formatting() {
        assert_eq!(toml_f32(17.0), "17.0");
        assert_eq!(toml_f32(0.75), "0.75");
        assert_eq!(toml_f32(39.3077), "39.3077");
        assert_eq!(toml_vec([1.0, 0.065, 1e-7]), "[1.0, 0.065, 1e-7]");
        let t: toml::Table = format!("x = {}", toml_vec([1.0, 0.065, 1e-7]))
            .parse()
            .unwrap();
        assert_eq!(t["x"].as_array().unwrap().len(), 3);
        assert_eq!(toml_key("white"), "white");
        assert_eq!(toml_key("a b"), "\"a b\"");
    }

    #[test]
    fn scene_kind_names() {
        for k in SceneKind::ALL {
            assert_eq!(k.name().parse::<SceneKind>(), Ok(k));
        }
        assert!("box".parse::<SceneKind>().is_err());
    }
}
