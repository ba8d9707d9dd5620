//! Validation: every value of a loaded config against its documented range (docs/pipeline.md),
//! the first problem reported with its key.
//!
//! The stages' parameter blocks check themselves ([`pc_artifact::params`]); the scene's values
//! (materials, models, lights, camera) and the renderer's are checked here. Every number has an
//! upper bound as well: a bound keeps one run within memory and time (a 100000×100000 camera is
//! refused here, not by the allocator) or keeps coordinates where f32 arithmetic stays exact
//! enough.

use std::path::Path;

use pc_artifact::params::{int, real, require, End, ParamError};
use serde::Serialize;

use crate::{Albedo, ConfigError, MaterialConfig, PipelineConfig, UnknownKeys};

use End::{Excl, Incl};

/// The largest coordinate (scene units) a config or a model may place anything at: beyond any
/// scene shifted to a local origin, and small enough that every product the stages form (a
/// squared distance across the scene, an inverse area) stays finite in f32. It bounds the
/// extent, not the precision: an f32 coordinate keeps about 7 significant digits, so a
/// georeferenced scan is shifted to a local origin on import.
pub const MAX_COORDINATE: f32 = 1e7;
/// The largest coordinate of a model's own frame (`import.origin`, a model's `scanner`):
/// georeferenced coordinates (UTM, geocentric) stay far below it.
pub const MAX_WORLD_COORDINATE: f64 = 1e9;
/// The largest albedo a per-point color can give (energy must be lost at every bounce for the
/// radiosity solve to converge).
pub const MAX_ALBEDO: f32 = 0.95;
/// The largest image side, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// The most pixels of one image (8192²): the CPU renderer keeps about 60 bytes per pixel.
pub const MAX_PIXELS: u64 = 8192 * 8192;
/// The largest radiance or intensity a config may give (linear RGB).
pub const MAX_RADIANCE: f32 = 1e9;

/// Every value of `c` within its documented range; errors name `path` and the key.
pub fn validate(c: &PipelineConfig, path: &Path) -> Result<(), ConfigError> {
    unknown_keys(c, path)?;
    let param = |e: ParamError| ConfigError::param(path, e);
    scene(c).map_err(param)?;
    c.import_ranges().map_err(param)?;
    c.octree.params.validate().map_err(param)?;
    c.vmap.params.validate().map_err(param)?;
    c.caustics.params.validate().map_err(param)?;
    c.fmm.params.validate().map_err(param)?;
    raytrace(c).map_err(param)?;
    file_names(c).map_err(param)?;
    for (i, m) in c.models.iter().enumerate() {
        if !c.materials.contains_key(&m.material) {
            let known: Vec<&str> = c.materials.keys().map(String::as_str).collect();
            return Err(ConfigError::invalid(
                path,
                format!(
                    "models[{i}] ({}) uses material `{}`, which is not defined (defined: {})",
                    m.file.display(),
                    m.material,
                    known.join(", ")
                ),
            ));
        }
    }
    Ok(())
}

/// A key of a stage's table that no field took.
fn unknown_keys(c: &PipelineConfig, path: &Path) -> Result<(), ConfigError> {
    fn check<T: Serialize + Default>(
        table: &str,
        unknown: &UnknownKeys,
        path: &Path,
    ) -> Result<(), ConfigError> {
        let Some(key) = unknown.keys().next() else {
            return Ok(());
        };
        let known = toml::Value::try_from(T::default())
            .ok()
            .and_then(|v| v.as_table().map(|t| t.keys().cloned().collect::<Vec<_>>()))
            .unwrap_or_default();
        Err(ConfigError::UnknownKey {
            path: path.to_path_buf(),
            key: format!("{table}.{key}"),
            known: known.join(", "),
        })
    }
    check::<crate::OctreeConfig>("octree", &c.octree.unknown, path)?;
    check::<crate::VmapConfig>("vmap", &c.vmap.unknown, path)?;
    check::<crate::CausticsConfig>("caustics", &c.caustics.unknown, path)?;
    check::<crate::FmmConfig>("fmm", &c.fmm.unknown, path)
}

/// Three numbers, each within `lo..hi`.
fn real3(key: &str, v: [f32; 3], lo: End, hi: End) -> Result<(), ParamError> {
    for (x, axis) in v.iter().zip(["[0]", "[1]", "[2]"]) {
        real(&format!("{key}{axis}"), *x, lo, hi)?;
    }
    Ok(())
}

/// A position: every coordinate finite and within ±[`MAX_COORDINATE`].
fn position(key: &str, v: [f32; 3]) -> Result<(), ParamError> {
    real3(key, v, Incl(-MAX_COORDINATE), Incl(MAX_COORDINATE))
}

/// A point of a model's own frame: every coordinate finite, within ±[`MAX_WORLD_COORDINATE`].
fn world_position(key: &str, v: [f64; 3]) -> Result<(), ParamError> {
    for (x, axis) in v.iter().zip(["[0]", "[1]", "[2]"]) {
        if !x.is_finite() || x.abs() > MAX_WORLD_COORDINATE {
            return Err(ParamError {
                key: format!("{key}{axis}"),
                expected: format!(
                    "be finite and lie in [-{MAX_WORLD_COORDINATE:e}, {MAX_WORLD_COORDINATE:e}]"
                ),
                got: x.to_string(),
            });
        }
    }
    Ok(())
}

/// Materials, models, lights and the camera.
fn scene(c: &PipelineConfig) -> Result<(), ParamError> {
    for (name, m) in &c.materials {
        let key = |field: &str| format!("materials.{name}.{field}");
        match m {
            MaterialConfig::Diffuse { albedo } => match albedo {
                Albedo::Rgb(a) => real3(&key("albedo"), *a, Incl(0.0), Incl(1.0))?,
                Albedo::Source(s) => require(
                    &key("albedo"),
                    s == "vertex",
                    "be [r, g, b] or \"vertex\"",
                    format!("\"{s}\""),
                )?,
            },
            MaterialConfig::Emitter { radiance, albedo } => {
                real3(&key("radiance"), *radiance, Incl(0.0), Incl(MAX_RADIANCE))?;
                if let Some(a) = albedo {
                    real3(&key("albedo"), *a, Incl(0.0), Incl(1.0))?;
                }
            }
            MaterialConfig::Mirror { reflectance, phong } => {
                real3(&key("reflectance"), *reflectance, Incl(0.0), Incl(1.0))?;
                if let Some(p) = phong {
                    real(&key("phong"), *p, Incl(0.0), Incl(1e6))?;
                }
            }
            MaterialConfig::Dielectric { ior, tint, phong } => {
                real(&key("ior"), *ior, Excl(0.0), Incl(10.0))?;
                if let Some(t) = tint {
                    real3(&key("tint"), *t, Incl(0.0), Incl(1.0))?;
                }
                if let Some(p) = phong {
                    real(&key("phong"), *p, Incl(0.0), Incl(1e6))?;
                }
            }
        }
    }
    for (i, m) in c.models.iter().enumerate() {
        if let Some(s) = m.scale {
            real(&format!("models[{i}].scale"), s, Excl(0.0), Incl(1e6))?;
        }
        if let Some(t) = m.translate {
            position(&format!("models[{i}].translate"), t)?;
        }
        if let Some(r) = m.rotate {
            real3(&format!("models[{i}].rotate"), r, Incl(-1e6), Incl(1e6))?;
        }
        if let Some(a) = m.albedo_scale {
            real(
                &format!("models[{i}].albedo_scale"),
                a,
                Excl(0.0),
                Incl(1e3),
            )?;
        }
        if let Some(list) = &m.scanners {
            int(
                &format!("models[{i}].scanners (count)"),
                list.len() as u64,
                1..=65536,
            )?;
            for (k, p) in list.iter().enumerate() {
                world_position(&format!("models[{i}].scanners[{k}]"), *p)?;
            }
        }
        for (code, material) in m.classes.iter().flatten() {
            let key = format!("models[{i}].classes.{code}");
            if code.parse::<u8>().is_err() {
                return Err(ParamError {
                    key,
                    expected: "be a LAS classification code, 0 to 255".into(),
                    got: format!("{code:?}"),
                });
            }
            if !c.materials.contains_key(material) {
                return Err(ParamError {
                    key,
                    expected: "name a material of [materials]".into(),
                    got: format!("{material:?}"),
                });
            }
        }
    }
    for (i, l) in c.lights.iter().enumerate() {
        position(&format!("lights[{i}].position"), l.position)?;
        real3(
            &format!("lights[{i}].intensity"),
            l.intensity,
            Incl(0.0),
            Incl(MAX_RADIANCE),
        )?;
    }
    camera(&c.camera)
}

fn camera(cam: &crate::CameraConfig) -> Result<(), ParamError> {
    int("camera.width", cam.width, 1..=MAX_IMAGE_SIDE as u64)?;
    int("camera.height", cam.height, 1..=MAX_IMAGE_SIDE as u64)?;
    let pixels = cam.width as u64 * cam.height as u64;
    require(
        "camera.width × camera.height",
        pixels <= MAX_PIXELS,
        &format!("be at most {MAX_PIXELS} pixels (8192²)"),
        format!("{}x{} = {pixels}", cam.width, cam.height),
    )?;
    real("camera.fov", cam.fov, Excl(0.0), Excl(180.0))?;
    position("camera.origin", cam.origin)?;
    position("camera.target", cam.target)?;
    real3("camera.up", cam.up, Incl(-1e6), Incl(1e6))?;
    let d: [f32; 3] = std::array::from_fn(|k| cam.target[k] - cam.origin[k]);
    let u = cam.up;
    let cross = [
        d[1] * u[2] - d[2] * u[1],
        d[2] * u[0] - d[0] * u[2],
        d[0] * u[1] - d[1] * u[0],
    ];
    require(
        "camera",
        cross.iter().map(|x| x * x).sum::<f32>() >= 1e-12,
        "have a target other than its origin and an up not parallel to the view direction",
        format!(
            "origin {:?}, target {:?}, up {:?}",
            cam.origin, cam.target, cam.up
        ),
    )
}

fn raytrace(c: &PipelineConfig) -> Result<(), ParamError> {
    let r = &c.raytrace;
    int("raytrace.spp", r.spp, 1..=65536)?;
    int("raytrace.refine", r.refine, 0..=4096)?;
    int(
        "raytrace.spp × raytrace.refine",
        r.spp as u64 * r.refine as u64,
        0..=65536,
    )?;
    real(
        "raytrace.refine_contrast",
        r.refine_contrast,
        Excl(0.0),
        Excl(2.0),
    )?;
    int("raytrace.max_bounces", r.max_bounces, 0..=64)?;
    int("raytrace.splits", r.splits, 0..=crate::MAX_SPLITS as u64)?;
    real("raytrace.self_hit", r.self_hit, Incl(0.0), Incl(100.0))?;
    real(
        "raytrace.blend_thickness",
        r.blend_thickness,
        Incl(0.0),
        Incl(100.0),
    )?;
    int("raytrace.light_samples", r.light_samples, 1..=1024)?;
    real3(
        "raytrace.background",
        r.background,
        Incl(0.0),
        Incl(MAX_RADIANCE),
    )?;
    real("raytrace.exposure", r.exposure, Excl(0.0), Incl(1e6))?;
    real(
        "raytrace.caustic_radius",
        r.caustic_radius,
        Incl(0.0),
        Incl(MAX_COORDINATE),
    )?;
    int("raytrace.caustic_k", r.caustic_k, 0..=4096)
}

/// Every artifact and image key names a file (inside `output.dir`): not empty, not `.` or a
/// folder path.
fn file_names(c: &PipelineConfig) -> Result<(), ParamError> {
    for (key, path) in [
        ("octree.file", &c.octree.file),
        ("vmap.file", &c.vmap.file),
        ("caustics.file", &c.caustics.file),
        ("fmm.file", &c.fmm.file),
        ("raytrace.image", &c.raytrace.image),
        ("bake.file", &c.bake.file),
    ] {
        let text = path.to_string_lossy();
        require(
            key,
            path.file_name().is_some() && !text.ends_with('/') && !text.ends_with('\\'),
            "name a file inside output.dir",
            format!("{text:?}"),
        )?;
    }
    let ext = c
        .bake
        .file
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    require(
        "bake.file",
        matches!(ext.as_deref(), Some("ply" | "las" | "laz")),
        "end in .ply, .las or .laz",
        format!("{:?}", c.bake.file.to_string_lossy()),
    )?;
    real("bake.exposure", c.bake.exposure, Excl(0.0), Incl(1e9))?;
    Ok(())
}

/// What the config names on disk and must be of the right kind: `output.dir`, where it exists,
/// is a folder; an artifact's or the image's path, where it exists, is not a folder.
pub fn check_paths(cfg: &crate::LoadedConfig) -> Result<(), ConfigError> {
    let out = cfg.out_dir();
    if out.exists() && !out.is_dir() {
        return Err(ConfigError::invalid(
            &cfg.path,
            format!("output.dir: {} is a file, not a folder", out.display()),
        ));
    }
    for (key, path) in [
        ("octree.file", cfg.octree_path()),
        ("vmap.file", cfg.vmap_path()),
        ("caustics.file", cfg.photons_path()),
        ("fmm.file", cfg.radiosity_path()),
        ("raytrace.image", cfg.image_path()),
        ("bake.file", cfg.bake_path()),
    ] {
        if path.is_dir() {
            return Err(ConfigError::invalid(
                &cfg.path,
                format!("{key}: {} is a folder, not a file", path.display()),
            ));
        }
    }
    Ok(())
}

impl PipelineConfig {
    /// `[import]`'s ranges.
    fn import_ranges(&self) -> Result<(), ParamError> {
        let i = &self.import;
        int(
            "import.normal_neighbors",
            i.normal_neighbors as u64,
            3..=256,
        )?;
        real(
            "import.normal_widen_above",
            i.normal_widen_above,
            Incl(0.0),
            Incl(45.0),
        )?;
        int(
            "import.radius_neighbors",
            i.radius_neighbors as u64,
            1..=256,
        )?;
        if let Some(s) = i.sensor {
            position("import.sensor", s)?;
        }
        if let Some(o) = i.origin {
            world_position("import.origin", o)?;
        }
        if let Some(d) = i.merge_distance {
            real("import.merge_distance", d, Excl(0.0), Incl(1e6))?;
        }
        if let Some(o) = i.outliers {
            int("import.outliers.neighbors", o.neighbors as u64, 2..=256)?;
            real(
                "import.outliers.std_ratio",
                o.std_ratio,
                Excl(0.0),
                Incl(100.0),
            )?;
        }
        Ok(())
    }
}
