//! The built-in scenes: the Cornell box (with or without specular spheres), the furnace sphere
//! and the glass box.

use glam::Vec3;
use pc_artifact::PointLight;
use pc_config::{Albedo, CameraConfig, FovAxis, MaterialConfig};

use crate::geometry::{BoxShape, Geometry, Rect, Sphere};
use crate::grid::{sample_shapes, SampledShape, ShapeSpec};
use crate::SampleParams;

/// A sampled scene, ready for [`crate::write::write_scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct SampledScene {
    /// Scene name: prefix of the PLY file names ("cornell", "sphere", "glass-box").
    pub name: String,
    pub shapes: Vec<SampledShape>,
    /// Materials in output order.
    pub materials: Vec<(String, MaterialConfig)>,
    pub lights: Vec<PointLight>,
    pub camera: CameraConfig,
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

fn diffuse(albedo: [f32; 3]) -> MaterialConfig {
    MaterialConfig::Diffuse {
        albedo: Albedo::Rgb(albedo),
    }
}

fn light_material() -> MaterialConfig {
    MaterialConfig::Emitter {
        radiance: [17.0, 12.0, 4.0],
        albedo: Some([0.78, 0.78, 0.78]),
    }
}

fn glass_material() -> MaterialConfig {
    MaterialConfig::Dielectric {
        ior: 1.5,
        tint: Some([1.0, 1.0, 1.0]),
        phong: None,
    }
}

fn mirror_material() -> MaterialConfig {
    MaterialConfig::Mirror {
        reflectance: [0.95, 0.95, 0.95],
        phong: None,
    }
}

/// The Cornell camera: at (0, 0, 3.9) looking at the origin, 39.3077° on the smaller axis,
/// 512 × 512 (pipeline.toml's default camera).
fn cornell_camera() -> CameraConfig {
    CameraConfig::default()
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
        ("white".to_string(), diffuse(WHITE)),
        ("red".to_string(), diffuse(RED)),
        ("green".to_string(), diffuse(GREEN)),
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
        camera: cornell_camera(),
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
            MaterialConfig::Emitter {
                radiance: [1.0, 1.0, 1.0],
                albedo: Some([0.5, 0.5, 0.5]),
            },
        )],
        lights: Vec::new(),
        camera: CameraConfig {
            origin: [0.0; 3],
            target: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            fov: 60.0,
            fov_axis: FovAxis::Smaller,
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
            ("white".to_string(), diffuse(WHITE)),
            ("light".to_string(), light_material()),
            ("glass".to_string(), glass_material()),
        ],
        lights: Vec::new(),
        camera: cornell_camera(),
        params: *params,
        spacing,
    }
}
