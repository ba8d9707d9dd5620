//! Scene assembly: read every model's file, fill in missing normals and radii, apply transforms,
//! resolve materials, and concatenate everything into one structure-of-arrays splat set.

use std::path::{Path, PathBuf};

use glam::{DVec3, Mat3, Vec3};
use rayon::prelude::*;

use crate::estimate::{
    try_estimate_normals, try_estimate_normals_and_radii, try_estimate_radii, NormalFit,
    Orientation,
};
use crate::points::{read_points, round_origin, Format, PlyOptions, PointSet};
use crate::ImportError;
use pc_artifact::PointLight;
use pc_config::{LoadedConfig, MaterialConfig, ModelConfig};

/// All splats of a scene, models concatenated in config order.
#[derive(Clone, Debug, Default)]
pub struct SceneSplats {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub radii: Vec<f32>,
    /// Per-point albedo factor (the file's linear colors, or intensity, when the point's
    /// material asks for them), else (1, 1, 1).
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
    pub format: Format,
    pub points: usize,
    pub dropped: usize,
    pub drop_reasons: Vec<(String, usize)>,
    pub estimated_normals: bool,
    pub estimated_radii: bool,
    /// Where the per-point albedo came from, when the model's material asks for it.
    pub albedo_from: Option<AlbedoSource>,
    /// Points whose albedo was clamped to [`pc_config::MAX_ALBEDO`].
    pub albedo_clamped: usize,
    /// How estimated normals were oriented.
    pub oriented: Oriented,
}

impl ModelReport {
    /// One line for the terminal: the file, its points and what import did to them.
    pub fn describe(&self) -> String {
        let mut parts = vec![format!("{} points", self.points)];
        if self.dropped > 0 {
            let why: Vec<String> = self
                .drop_reasons
                .iter()
                .map(|(r, n)| format!("{n} {r}"))
                .collect();
            parts.push(format!("{} left out ({})", self.dropped, why.join(", ")));
        }
        if self.estimated_normals {
            parts.push(match self.oriented {
                Oriented::Scanner => "normals estimated, facing the scanner".to_string(),
                Oriented::Stations(n) => format!("normals estimated, facing {n} scan stations"),
                _ => "normals estimated, oriented by propagation".to_string(),
            });
        }
        if self.estimated_radii {
            parts.push("radii estimated".to_string());
        }
        if let Some(src) = self.albedo_from {
            let from = match src {
                AlbedoSource::Color => "color",
                AlbedoSource::Intensity => "intensity",
            };
            parts.push(format!("albedo from {from}"));
            if self.albedo_clamped > 0 {
                parts.push(format!(
                    "{} albedos clamped to {}",
                    self.albedo_clamped,
                    pc_config::MAX_ALBEDO
                ));
            }
        }
        let (path, format) = (self.path.display(), self.format.name());
        format!("{path} ({format}): {}", parts.join(", "))
    }
}

/// The per-point values a `"vertex"` albedo was taken from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AlbedoSource {
    Color,
    /// No color in the file: its intensity, normalized per file, as grey.
    Intensity,
}

/// How a model's normals were oriented.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Oriented {
    /// The file gave normals.
    Given,
    /// Toward the model's `scanner`, or `import.sensor`.
    Scanner,
    /// Toward the station of the scan each point belongs to (E57 poses).
    Stations(usize),
    /// By propagation over the neighbour graph.
    Propagated,
}

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct LoadedScene {
    pub splats: SceneSplats,
    /// Materials in a fixed order (sorted by name); `SceneSplats::material` indexes this.
    pub materials: Vec<(String, MaterialConfig)>,
    pub lights: Vec<PointLight>,
    pub models: Vec<ModelReport>,
    /// The point of the models' own frame at the scene's origin: a splat at `p` is at
    /// `origin + p` in the files' coordinates (f64).
    pub origin: DVec3,
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

/// The scene's origin in the models' frame: `import.origin`, else the first model's bounds
/// centre rounded to whole units when it is a scan, else zero (PLY scenes stay where they are).
pub fn scene_origin(cfg: &LoadedConfig, first: &PointSet, format: Format) -> DVec3 {
    if let Some(o) = cfg.config.import.origin {
        return DVec3::from(o);
    }
    match (format.is_scan(), first.bounds()) {
        (true, Some((lo, hi))) => round_origin((lo + hi) * 0.5),
        _ => DVec3::ZERO,
    }
}

/// The materials of one model: its own, and those its `classes` pick, as indices into the
/// scene's sorted material list.
struct ModelMaterials {
    default: u32,
    by_class: Option<[u32; 256]>,
}

impl ModelMaterials {
    fn new(
        cfg: &LoadedConfig,
        mi: usize,
        m: &ModelConfig,
        materials: &[(String, MaterialConfig)],
    ) -> Result<Self, ImportError> {
        let index_of = |name: &str| {
            materials
                .iter()
                .position(|(n, _)| n == name)
                .map(|i| i as u32)
                .ok_or_else(|| ImportError::UnknownMaterial {
                    path: cfg.path.clone(),
                    model: mi,
                    name: name.to_string(),
                })
        };
        let default = index_of(&m.material)?;
        let by_class = match &m.classes {
            None => None,
            Some(classes) => {
                let mut table = [default; 256];
                for (code, name) in classes {
                    // validate() checked the codes; a bad one here is a config built in code.
                    let code: u8 = code.parse().map_err(|_| ImportError::Scene {
                        path: cfg.path.clone(),
                        msg: format!("models[{mi}].classes: {code:?} is not a class code 0-255"),
                    })?;
                    table[code as usize] = index_of(name)?;
                }
                Some(table)
            }
        };
        Ok(Self { default, by_class })
    }

    /// The material of point `i`.
    fn of(&self, classes: Option<&[u8]>, i: usize) -> u32 {
        match (&self.by_class, classes) {
            (Some(t), Some(c)) => t[c[i] as usize],
            _ => self.default,
        }
    }

    fn any(&self, mut f: impl FnMut(u32) -> bool) -> bool {
        match &self.by_class {
            Some(t) => t.iter().any(|&m| f(m)),
            None => f(self.default),
        }
    }
}

/// The per-point albedo factors a model's `"vertex"` materials take: the file's colors, else
/// its intensity as grey, times `albedo_scale`, clamped to [`pc_config::MAX_ALBEDO`].
/// Returns the factors, their source and how many points were clamped.
fn albedo_factors(
    path: &Path,
    pts: &PointSet,
    scale: f32,
) -> Result<(Vec<Vec3>, AlbedoSource, usize), ImportError> {
    let (values, source): (Vec<Vec3>, _) = match (&pts.colors, &pts.intensity) {
        (Some(c), _) => (c.clone(), AlbedoSource::Color),
        (None, Some(i)) => (
            i.iter().map(|&v| Vec3::splat(v)).collect(),
            AlbedoSource::Intensity,
        ),
        (None, None) => {
            return Err(ImportError::MissingProperty {
                path: path.to_path_buf(),
                property: "red",
            })
        }
    };
    let max = pc_config::MAX_ALBEDO;
    let mut clamped = 0usize;
    let factors = values
        .into_iter()
        .map(|c| {
            let a = (c * scale).max(Vec3::ZERO);
            if a.max_element() > max {
                clamped += 1;
            }
            a.min(Vec3::splat(max))
        })
        .collect();
    Ok((factors, source, clamped))
}

/// Estimated normals, how they were oriented, and the radii when asked for.
type Estimated = (Vec<Vec3>, Oriented, Option<Vec<f32>>);

/// Normals for a model that has none, and how they were oriented: toward the model's
/// `scanner` (file frame), else the file's stations, else `import.sensor` (scene frame), else
/// by propagation. `from_scene` maps a scene-frame point to the file's offsets. With
/// `radius_k`, the radii too, from the same neighbour pass.
fn model_normals(
    cfg: &LoadedConfig,
    m: &ModelConfig,
    path: &Path,
    pts: &PointSet,
    from_scene: impl Fn(Vec3) -> Vec3,
    radius_k: Option<usize>,
) -> Result<Estimated, ImportError> {
    let import = &cfg.config.import;
    let fit = NormalFit {
        k: import.normal_neighbors,
        widen_above: import.normal_widen_above.to_radians(),
    };
    let local = |p: DVec3| (p - pts.origin).as_vec3();
    let estimate = |orient| match radius_k {
        Some(kr) => try_estimate_normals_and_radii(path, &pts.positions, fit, orient, kr)
            .map(|(n, r)| (n, Some(r))),
        None => try_estimate_normals(path, &pts.positions, fit, orient).map(|n| (n, None)),
    };
    match m.scanners.as_deref() {
        Some([s]) => {
            let s = local(DVec3::from(*s));
            let (n, r) = estimate(Orientation::Sensor(s))?;
            return Ok((n, Oriented::Scanner, r));
        }
        Some(list) if !list.is_empty() => {
            let of = scanner_of_points(path, pts, list.len())?;
            let stations: Vec<Vec3> = list.iter().map(|&s| local(DVec3::from(s))).collect();
            let (stations, of) = (&stations[..], &of[..]);
            let (n, r) = estimate(Orientation::Stations { stations, of })?;
            return Ok((n, Oriented::Stations(list.len()), r));
        }
        _ => {}
    }
    if let Some(of) = &pts.station_of {
        let stations: Vec<Vec3> = pts.stations.iter().map(|&s| local(s)).collect();
        let (stations, of) = (&stations[..], &of[..]);
        let (n, r) = estimate(Orientation::Stations { stations, of })?;
        return Ok((n, Oriented::Stations(pts.stations.len()), r));
    }
    if let Some(s) = cfg.config.import.sensor {
        // import.sensor is in the scene frame: bring it into the file's offsets.
        let sensor = Orientation::Sensor(from_scene(Vec3::from(s)));
        let (n, r) = estimate(sensor)?;
        return Ok((n, Oriented::Scanner, r));
    }
    let (n, r) = estimate(Orientation::Propagate)?;
    Ok((n, Oriented::Propagated, r))
}

/// Each point's index into a model's `scanners`: its LAS `point_source_id`.
fn scanner_of_points(path: &Path, pts: &PointSet, count: usize) -> Result<Vec<u32>, ImportError> {
    let Some(ids) = &pts.source_ids else {
        return Err(ImportError::Scene {
            path: path.to_path_buf(),
            msg: format!(
                "{count} scanners are given, but the file has no point_source_id to tell which \
                 scan each point came from (LAS only): give one scanner"
            ),
        });
    };
    ids.iter()
        .enumerate()
        .map(|(i, &id)| {
            if (id as usize) < count {
                Ok(u32::from(id))
            } else {
                Err(ImportError::Scene {
                    path: path.to_path_buf(),
                    msg: format!(
                        "point {i}: point_source_id {id} names no scanner ({count} are given)"
                    ),
                })
            }
        })
        .collect()
}

/// The `[import]` cleaning options applied to one model's points.
fn clean(import: &pc_config::ImportConfig, pts: &mut PointSet) {
    if let Some(d) = import.merge_distance {
        let keep = crate::clean::merge_duplicates(&pts.positions, d);
        pts.retain(&keep, "duplicates merged");
    }
    if let Some(o) = import.outliers {
        let keep = crate::clean::remove_outliers(&pts.positions, o.neighbors, o.std_ratio);
        pts.retain(&keep, "statistical outliers");
    }
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
    let opts = PlyOptions {
        drop_invalid: c.import.drop_invalid,
    };
    let mut out = SceneSplats::default();
    let mut reports = Vec::with_capacity(c.models.len());
    let mut origin = None;
    for (mi, m) in c.models.iter().enumerate() {
        let path = model_path(cfg, m);
        let mats = ModelMaterials::new(cfg, mi, m, &materials)?;
        let format = Format::of(&path)?;
        let mut pts = read_points(&path, &opts)?;
        clean(&c.import, &mut pts);
        let origin = *origin.get_or_insert_with(|| scene_origin(cfg, &pts, format));
        let report = add_model(
            cfg, m, &path, format, pts, origin, &mats, &materials, &mut out,
        )?;
        reports.push(report);
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
        origin: origin.unwrap_or(DVec3::ZERO),
    })
}

/// Append one model's points to `out`: normals and radii estimated where missing, albedo and
/// material per point, moved into the scene frame (f64 shift, then the model's transform).
#[allow(clippy::too_many_arguments)]
fn add_model(
    cfg: &LoadedConfig,
    m: &ModelConfig,
    path: &Path,
    format: Format,
    pts: PointSet,
    origin: DVec3,
    mats: &ModelMaterials,
    materials: &[(String, MaterialConfig)],
    out: &mut SceneSplats,
) -> Result<ModelReport, ImportError> {
    let c = &cfg.config;
    let n = pts.positions.len();
    let (s, rot, t) = model_transform(m);
    // The file's offsets into the scene frame: one f64 shift for the whole file.
    let shift = (pts.origin - origin).as_vec3();
    let from_scene = |x: Vec3| rot.transpose() * (x - t) / s - shift;
    let estimated_normals = pts.normals.is_none();
    let estimated_radii = pts.radii.is_none();
    // Radii missing too: estimated in the normals' neighbour pass.
    let radius_k = estimated_radii.then_some(c.import.radius_neighbors);
    let (normals, oriented, radii) = match &pts.normals {
        Some(nrm) => (nrm.clone(), Oriented::Given, None),
        None => model_normals(cfg, m, path, &pts, from_scene, radius_k)?,
    };
    let radii = match (&pts.radii, radii) {
        (Some(r), _) => r.clone(),
        (None, Some(r)) => r,
        (None, None) => try_estimate_radii(path, &pts.positions, c.import.radius_neighbors)?,
    };
    // Per-point colors multiply the material's color; without them the factor is 1, so a
    // material's albedo can change without rebuilding the octree.
    let wants = |i: u32| materials[i as usize].1.wants_vertex_colors();
    let (factors, albedo_from, albedo_clamped) = if mats.any(wants) {
        let (f, src, clamped) = albedo_factors(path, &pts, m.albedo_scale.unwrap_or(1.0))?;
        (Some(f), Some(src), clamped)
    } else {
        (None, None, 0)
    };
    let classes = pts.classes.as_deref();
    // Point by point in parallel, appended in input order (one loop pushing into five growing
    // arrays took seconds at 20M points, on one core).
    let position = |i: usize| rot * ((pts.positions[i] + shift) * s) + t;
    let radius = |i: usize| radii[i] * s;
    let beyond_extent = |i: usize| out_of_range(position(i), radius(i));
    if !c.import.drop_invalid {
        let first = (0..n)
            .into_par_iter()
            .find_map_first(|i| beyond_extent(i).map(|e| (i, e)));
        if let Some((index, (what, value))) = first {
            return Err(ImportError::OutOfRange {
                path: path.to_path_buf(),
                index,
                what,
                value,
                limit: pc_config::MAX_COORDINATE,
            });
        }
    }
    // The points kept, where some are dropped (`None`: all). (A scene holds at most 2³¹
    // splats, `load_scene`; a model beyond that is refused here before its indices would wrap.)
    if n > u32::MAX as usize / 2 {
        return Err(ImportError::Scene {
            path: cfg.path.clone(),
            msg: format!(
                "{}: {n} points, more than this build supports",
                path.display()
            ),
        });
    }
    let kept: Option<Vec<u32>> = c.import.drop_invalid.then(|| {
        (0..n as u32)
            .into_par_iter()
            .filter(|&i| beyond_extent(i as usize).is_none())
            .collect()
    });
    let kept = kept.as_deref();
    let beyond = kept.map_or(0, |k| n - k.len());
    append(&mut out.positions, kept, n, position);
    append(&mut out.normals, kept, n, |i| {
        (rot * normals[i]).normalize()
    });
    append(&mut out.radii, kept, n, radius);
    append(&mut out.material, kept, n, |i| mats.of(classes, i));
    append(&mut out.albedo, kept, n, |i| match &factors {
        Some(f) if wants(mats.of(classes, i)) => f[i],
        _ => Vec3::ONE,
    });
    let mut drop_reasons = pts.drop_reasons;
    if beyond > 0 {
        drop_reasons.push(("beyond the extent".to_string(), beyond));
    }
    Ok(ModelReport {
        path: path.to_path_buf(),
        format,
        points: n - beyond,
        dropped: pts.dropped + beyond,
        drop_reasons,
        estimated_normals,
        estimated_radii,
        albedo_from,
        albedo_clamped,
        oriented,
    })
}

/// Appends `f(i)` for the points `kept` (all `n` where `None`) to `out`, in order, computed in
/// parallel.
fn append<T: Send>(
    out: &mut Vec<T>,
    kept: Option<&[u32]>,
    n: usize,
    f: impl Fn(usize) -> T + Sync + Send,
) {
    match kept {
        None => out.par_extend((0..n).into_par_iter().map(f)),
        Some(k) => out.par_extend(k.par_iter().map(|&i| f(i as usize))),
    }
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
            ..ModelConfig::default()
        };
        let (s, r, t) = model_transform(&m);
        let p = r * (Vec3::X * s) + t;
        // X scaled to 2, rotated 90° about Y goes to -Z, then moved by +X.
        assert!((p - Vec3::new(1.0, 0.0, -2.0)).length() < 1e-5, "{p}");
    }
}
