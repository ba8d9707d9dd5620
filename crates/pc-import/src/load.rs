//! Scene assembly: read every model's PLY, fill in missing normals and radii, apply transforms,
//! resolve materials, and concatenate everything into one structure-of-arrays splat set.

use std::path::PathBuf;

use glam::{Mat3, Vec3};

use crate::estimate::{try_estimate_normals, try_estimate_radii, Orientation};
use crate::ply::{read_ply, PlyOptions};
use crate::ImportError;
use pc_artifact::PointLight;
use pc_config::{LoadedConfig, MaterialConfig, ModelConfig};

/// All splats of a scene, models concatenated in config order.
#[derive(Clone, Debug, Default)]
pub struct SceneSplats {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub radii: Vec<f32>,
    /// Per-point linear RGB color (from the PLY when the material asks for it), else (1, 1, 1).
    pub albedo: Vec<Vec3>,
    /// Index into `LoadedScene::materials`.
    pub material: Vec<u32>,
}

impl SceneSplats {
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// What happened to one model during import.
#[derive(Clone, Debug)]
pub struct ModelReport {
    pub path: PathBuf,
    pub points: usize,
    pub dropped: usize,
    pub drop_reasons: Vec<(String, usize)>,
    pub estimated_normals: bool,
    pub estimated_radii: bool,
}

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct LoadedScene {
    pub splats: SceneSplats,
    /// Materials in a fixed order (sorted by name); `SceneSplats::material` indexes this.
    pub materials: Vec<(String, MaterialConfig)>,
    pub lights: Vec<PointLight>,
    pub models: Vec<ModelReport>,
}

impl LoadedScene {
    pub fn dropped(&self) -> usize {
        self.models.iter().map(|m| m.dropped).sum()
    }
}

/// Resolve a model's file against the config's folder.
pub fn model_path(cfg: &LoadedConfig, m: &ModelConfig) -> PathBuf {
    if m.file.is_absolute() {
        m.file.clone()
    } else {
        cfg.base_dir.join(&m.file)
    }
}

/// The model transform: uniform scale, then rotations about X, Y, Z (degrees), then translation.
pub fn model_transform(m: &ModelConfig) -> (f32, Mat3, Vec3) {
    let s = m.scale.unwrap_or(1.0);
    let r = m.rotate.unwrap_or([0.0; 3]);
    let rot = Mat3::from_rotation_z(r[2].to_radians())
        * Mat3::from_rotation_y(r[1].to_radians())
        * Mat3::from_rotation_x(r[0].to_radians());
    (s, rot, Vec3::from(m.translate.unwrap_or([0.0; 3])))
}

/// What of a transformed point lies beyond ±[`pc_config::MAX_COORDINATE`], the extent pcgi
/// works in (near 3e38 the root cube's size overflows to infinity): a coordinate, or the radius.
fn out_of_range(x: Vec3, r: f32) -> Option<(&'static str, f32)> {
    let limit = pc_config::MAX_COORDINATE;
    for (c, what) in x.to_array().into_iter().zip(["x", "y", "z"]) {
        if c.is_nan() || c.abs() > limit {
            return Some((what, c));
        }
    }
    (r.is_nan() || r > limit).then_some(("the radius", r))
}

/// Load every model of the config. `progress(done, total)` is called after each model.
pub fn load_scene(
    cfg: &LoadedConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<LoadedScene, ImportError> {
    let c = &cfg.config;
    if c.models.is_empty() {
        return Err(ImportError::Scene {
            path: cfg.path.clone(),
            msg: "the scene has no models ([[models]])".into(),
        });
    }
    let materials: Vec<(String, MaterialConfig)> = c
        .materials
        .iter()
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    let index_of = |name: &str| materials.iter().position(|(n, _)| n == name);
    let opts = PlyOptions {
        drop_invalid: c.import.drop_invalid,
    };
    let mut out = SceneSplats::default();
    let mut reports = Vec::with_capacity(c.models.len());
    for (mi, m) in c.models.iter().enumerate() {
        let path = model_path(cfg, m);
        let mat_index = index_of(&m.material).ok_or_else(|| ImportError::UnknownMaterial {
            path: cfg.path.clone(),
            model: mi,
            name: m.material.clone(),
        })?;
        let material = &materials[mat_index].1;
        let pts = read_ply(&path, &opts)?;
        let n = pts.positions.len();
        let estimated_normals = pts.normals.is_none();
        let estimated_radii = pts.radii.is_none();
        let normals = match pts.normals {
            Some(nrm) => nrm,
            None => {
                let orient = match c.import.sensor {
                    Some(s) => Orientation::Sensor(Vec3::from(s)),
                    None => Orientation::Propagate,
                };
                try_estimate_normals(&path, &pts.positions, c.import.normal_neighbors, orient)?
            }
        };
        let radii = match pts.radii {
            Some(r) => r,
            None => try_estimate_radii(&path, &pts.positions, c.import.radius_neighbors)?,
        };
        // Per-point colors multiply the material's color; without them the factor is 1, so
        // a material's albedo can change without rebuilding the octree.
        let colors = if material.wants_vertex_colors() {
            match pts.colors {
                Some(c) => Some(c),
                None => {
                    return Err(ImportError::MissingProperty {
                        path: path.clone(),
                        property: "red",
                    })
                }
            }
        } else {
            None
        };
        let (s, rot, t) = model_transform(m);
        out.positions.reserve(n);
        let mut beyond = 0usize;
        for i in 0..n {
            let x = rot * (pts.positions[i] * s) + t;
            let r = radii[i] * s;
            if let Some((what, value)) = out_of_range(x, r) {
                if c.import.drop_invalid {
                    beyond += 1;
                    continue;
                }
                return Err(ImportError::OutOfRange {
                    path,
                    index: i,
                    what,
                    value,
                    limit: pc_config::MAX_COORDINATE,
                });
            }
            out.positions.push(x);
            out.normals.push((rot * normals[i]).normalize());
            out.radii.push(r);
            out.albedo.push(
                colors
                    .as_ref()
                    .map_or(Vec3::ONE, |c| c[i].clamp(Vec3::ZERO, Vec3::ONE)),
            );
            out.material.push(mat_index as u32);
        }
        let mut drop_reasons = pts.drop_reasons;
        if beyond > 0 {
            drop_reasons.push(("beyond the extent".to_string(), beyond));
        }
        reports.push(ModelReport {
            path,
            points: n - beyond,
            dropped: pts.dropped + beyond,
            drop_reasons,
            estimated_normals,
            estimated_radii,
        });
        progress(mi + 1, c.models.len());
    }
    if out.positions.len() > u32::MAX as usize / 2 {
        return Err(ImportError::Scene {
            path: cfg.path.clone(),
            msg: format!(
                "{} splats: more than this build supports",
                out.positions.len()
            ),
        });
    }
    Ok(LoadedScene {
        splats: out,
        materials,
        lights: c.lights.clone(),
        models: reports,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transform_order_is_scale_rotate_translate() {
        let m = ModelConfig {
            file: "x.ply".into(),
            material: "m".into(),
            translate: Some([1.0, 0.0, 0.0]),
            rotate: Some([0.0, 90.0, 0.0]),
            scale: Some(2.0),
        };
        let (s, r, t) = model_transform(&m);
        let p = r * (Vec3::X * s) + t;
        // X scaled to 2, rotated 90° about Y goes to -Z, then moved by +X.
        assert!((p - Vec3::new(1.0, 0.0, -2.0)).length() < 1e-5, "{p}");
    }
}
