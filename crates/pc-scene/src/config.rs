//! pipeline.toml: the scene (models, materials, lights, camera) and every stage's parameters.
//!
//! Loading merges `include`d files (their model paths resolved relative to the file that names
//! them), applies `--set key=value` overrides on the TOML tree, then deserializes with unknown
//! keys rejected, and validates values. Every key is documented in docs/pipeline.md.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::SceneError;

/// The whole pipeline description.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    /// Other TOML files merged under this one (already merged after loading).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub include: Vec<PathBuf>,
    #[serde(default)]
    pub output: OutputConfig,
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialConfig>,
    #[serde(default)]
    pub models: Vec<ModelConfig>,
    #[serde(default)]
    pub lights: Vec<PointLightConfig>,
    #[serde(default)]
    pub camera: CameraConfig,
    #[serde(default)]
    pub import: ImportConfig,
    #[serde(default)]
    pub octree: OctreeConfig,
    #[serde(default)]
    pub vmap: VmapConfig,
    #[serde(default)]
    pub fmm: FmmConfig,
    #[serde(default)]
    pub caustics: CausticsConfig,
    #[serde(default)]
    pub raytrace: RaytraceConfig,
}

/// Where artifacts and images go.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// Folder for artifacts and images, relative to the config file's folder.
    #[serde(default = "default_out_dir")]
    pub dir: PathBuf,
}

fn default_out_dir() -> PathBuf {
    PathBuf::from("out")
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            dir: default_out_dir(),
        }
    }
}

/// A model: one PLY file with a material and an optional similarity transform.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// PLY path; after loading it is resolved (relative paths against the declaring file).
    pub file: PathBuf,
    pub material: String,
    /// Translation applied last.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translate: Option<[f32; 3]>,
    /// Rotation in degrees about X, then Y, then Z (world axes), applied after scaling.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotate: Option<[f32; 3]>,
    /// Uniform scale, applied first (radii scale with it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f32>,
}

/// Diffuse albedo: an RGB triple, or `"vertex"` for the PLY's per-point colors.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum Albedo {
    Rgb([f32; 3]),
    Source(String),
}

/// A material.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum MaterialConfig {
    Diffuse {
        albedo: Albedo,
    },
    Emitter {
        /// Emitted radiance (linear RGB), from the front side only.
        radiance: [f32; 3],
        /// Diffuse albedo of the emitter's surface; default 0 (a pure emitter).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        albedo: Option<[f32; 3]>,
    },
    Mirror {
        reflectance: [f32; 3],
        #[serde(default, skip_serializing_if = "Option::is_none")]
        phong: Option<f32>,
    },
    Dielectric {
        ior: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        tint: Option<[f32; 3]>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        phong: Option<f32>,
    },
}

impl MaterialConfig {
    pub fn is_specular(&self) -> bool {
        matches!(
            self,
            MaterialConfig::Mirror { .. } | MaterialConfig::Dielectric { .. }
        )
    }
    /// True when the albedo comes from the PLY's colors.
    pub fn wants_vertex_colors(&self) -> bool {
        matches!(
            self,
            MaterialConfig::Diffuse {
                albedo: Albedo::Source(_)
            }
        )
    }
}

/// A point light.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PointLightConfig {
    pub position: [f32; 3],
    /// Radiant intensity, W/sr, linear RGB.
    pub intensity: [f32; 3],
}

/// Which image axis the field of view spans.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum FovAxis {
    X,
    Y,
    #[default]
    Smaller,
    Larger,
}

/// A pinhole camera. Pixel (0, 0) is the top-left pixel. Missing keys take the defaults.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CameraConfig {
    pub origin: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    /// Field of view in degrees along `fov_axis`.
    pub fov: f32,
    #[serde(default)]
    pub fov_axis: FovAxis,
    pub width: u32,
    pub height: u32,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            origin: [0.0, 0.0, 3.9],
            target: [0.0, 0.0, 0.0],
            up: default_up(),
            fov: 39.3077,
            fov_axis: FovAxis::Smaller,
            width: 512,
            height: 512,
        }
    }
}

/// How PLY files are imported.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ImportConfig {
    /// Neighbours for PCA normal estimation when a PLY has no normals.
    #[serde(default = "default_normal_neighbors")]
    pub normal_neighbors: usize,
    /// Neighbours for radius estimation when a PLY has no radius.
    #[serde(default = "default_radius_neighbors")]
    pub radius_neighbors: usize,
    /// Orient estimated normals towards this point (the scanner); default: propagate over the
    /// neighbour graph, outward.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor: Option<[f32; 3]>,
    /// Drop invalid points (NaN, zero normal, bad radius) instead of failing, and report them.
    #[serde(default)]
    pub drop_invalid: bool,
}

fn default_normal_neighbors() -> usize {
    16
}
fn default_radius_neighbors() -> usize {
    8
}

impl Default for ImportConfig {
    fn default() -> Self {
        Self {
            normal_neighbors: default_normal_neighbors(),
            radius_neighbors: default_radius_neighbors(),
            sensor: None,
            drop_invalid: false,
        }
    }
}

/// pc-octree parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OctreeConfig {
    /// k: a node is split while it owns more splats than this (§8.5.1).
    #[serde(default = "default_max_leaf_points")]
    pub max_leaf_points: u32,
    /// Deepest level (root = 0), at most 21; leaves there may exceed k or mix classes.
    #[serde(default = "default_max_depth")]
    pub max_depth: u32,
    /// Sample points per splat disk for the splat-area estimate (partition of unity).
    #[serde(default = "default_area_samples")]
    pub area_samples: u32,
    /// Artifact file name inside `output.dir`.
    #[serde(default = "default_octree_file")]
    pub file: PathBuf,
}

fn default_max_leaf_points() -> u32 {
    16
}
fn default_max_depth() -> u32 {
    21
}
fn default_area_samples() -> u32 {
    8
}
fn default_octree_file() -> PathBuf {
    PathBuf::from("octree.pcgi")
}

impl Default for OctreeConfig {
    fn default() -> Self {
        Self {
            max_leaf_points: default_max_leaf_points(),
            max_depth: default_max_depth(),
            area_samples: default_area_samples(),
            file: default_octree_file(),
        }
    }
}

/// pc-vmap parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct VmapConfig {
    /// Opening criterion: well separated when (R_a + R_b) / distance < theta.
    pub theta: f32,
    /// Visibility rays per far-field node pair (and per node for the light lists).
    pub rays: u32,
    /// Near-field pairs of V-map leaves: every splat pair up to this many, else this many
    /// samples.
    pub near_rays: u32,
    /// Nodes with at most this many splats are V-map leaves (their pairs are near-field).
    pub leaf_splats: u32,
    /// Self-hit distance in radii of the splat a visibility ray leaves or reaches (§8.5.6).
    pub self_hit: f32,
    /// Partly visible node pairs exchanging a smaller form factor than this (either way) keep a
    /// partial link instead of being refined to V-map leaves; 0 always refines.
    pub refine_form_factor: f32,
    /// Far-field pairs exchanging at least `heavy_form_factor` (either way) are tested with
    /// `heavy_rays` rays instead of `rays`: a pair that all of a few rays find unoccluded is
    /// linked whole, so the pairs that carry the most light get the most rays.
    pub heavy_rays: u32,
    pub heavy_form_factor: f32,
    /// Where the rays are cast.
    pub backend: Backend,
    pub seed: u32,
    /// Artifact file name inside `output.dir`.
    pub file: PathBuf,
}

impl Default for VmapConfig {
    fn default() -> Self {
        VmapConfig {
            theta: 0.5,
            rays: 16,
            near_rays: 64,
            leaf_splats: 64,
            self_hit: 0.5,
            refine_form_factor: 1e-3,
            heavy_rays: 64,
            heavy_form_factor: 3e-3,
            backend: Backend::Auto,
            seed: 0,
            file: PathBuf::from("vmap.pcgi"),
        }
    }
}

/// pc-fmm parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct FmmConfig {
    /// Taylor expansion order p of the far field.
    pub order: u32,
    /// Expansion separation: two clusters interact through expansions when
    /// (r_a + r_b) < theta · distance.
    pub theta: f32,
    /// Largest accepted cosine-clamp error of one interaction, as a form factor.
    pub clamp_tol: f32,
    /// The solve stops when the relative residual falls below this.
    pub tolerance: f32,
    /// The solve stops after this many iterations even if not converged.
    pub max_iterations: u32,
    /// Samples per splat of the direct light of the emitting splats (0: none).
    pub emitter_samples: u32,
    /// Of those, how many probe visibility first: a leaf whose probes all agree gives the other
    /// samples their answer without rays (0: every sample casts its ray).
    pub emitter_probes: u32,
    /// The iterative method: "gmres" (default) or "jacobi".
    pub solver: pc_artifact::radiosity::Solver,
    /// GMRES: later products at a lower order as the residual falls (relaxed products).
    pub relax: bool,
    /// Where the FMM passes run.
    pub backend: Backend,
    /// Artifact file name inside `output.dir`.
    pub file: PathBuf,
}

impl Default for FmmConfig {
    fn default() -> Self {
        FmmConfig {
            order: 3,
            theta: 0.5,
            clamp_tol: 1e-4,
            tolerance: 1e-3,
            max_iterations: 200,
            emitter_samples: 64,
            emitter_probes: 16,
            solver: pc_artifact::radiosity::Solver::Gmres,
            relax: true,
            backend: Backend::Auto,
            file: PathBuf::from("radiosity.pcgi"),
        }
    }
}

/// pc-caustics parameters (docs/caustics.md).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CausticsConfig {
    /// Photon budget n_e over the whole sphere of every light: each photon carries the lights'
    /// power over n_e, and only those aimed at specular leaves are traced (§8.5.3).
    pub photons: u32,
    /// Most specular bounces a photon makes.
    pub max_bounces: u32,
    /// Self-hit distance Δ (§8.5.6) in radii of the splat a photon leaves.
    pub self_hit: f32,
    /// Where the photons are traced.
    pub backend: Backend,
    pub seed: u32,
    /// Artifact file name inside `output.dir`.
    pub file: PathBuf,
}

impl Default for CausticsConfig {
    fn default() -> Self {
        CausticsConfig {
            photons: 1_000_000,
            max_bounces: 8,
            self_hit: 0.5,
            backend: Backend::Auto,
            seed: 0,
            file: PathBuf::from("photons.pcgi"),
        }
    }
}

/// What a diffuse hit shows.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum ShadingMode {
    /// `stored` when the radiosity artifact exists, else `direct`.
    #[default]
    Auto,
    /// The radiance stored at the splats: the radiosity artifact's, or emission alone.
    Stored,
    /// Preview: emission plus albedo times direct light from point lights and emitters, with
    /// shadow rays.
    Direct,
}

/// Which device runs a stage's kernels (config key and `--backend` flag alike).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Default, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    Cpu,
    Gpu,
    /// The GPU when an adapter exists, else the CPU.
    #[default]
    Auto,
}

/// pc-raytrace parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RaytraceConfig {
    /// Samples per pixel (stratified on a √n × √n grid when n is a square).
    pub spp: u32,
    /// Specular bounces after the camera ray (§8.5.8's b).
    pub max_bounces: u32,
    pub mode: ShadingMode,
    pub backend: Backend,
    /// Self-hit distance Δ (§8.5.6) in units of the radius of the splat a ray leaves.
    pub self_hit: f32,
    /// Splats within this many radii of a hit's plane blend with it (§8.5.8).
    pub blend_thickness: f32,
    /// Emitter samples per diffuse hit in `direct` mode.
    pub light_samples: u32,
    /// Radiance of rays that leave the scene, linear RGB.
    pub background: [f32; 3],
    /// Exposure multiplier for the PNG preview (the EXR is linear and unscaled).
    pub exposure: f32,
    /// Write depth, normal, albedo and splat-id layers into the EXR.
    pub aovs: bool,
    /// Radius of the caustic density estimate (§8.5.8), in scene units; 0 picks 1/100 of the
    /// root cube's edge.
    pub caustic_radius: f32,
    /// With k > 0, the estimate takes the k nearest photons within `caustic_radius` and their
    /// distance as the radius (k-nearest); 0: every photon within the fixed radius.
    pub caustic_k: u32,
    /// Seed of the sample pattern.
    pub seed: u32,
    /// Image file name inside `output.dir` (an `.exr`; a `.png` preview is written beside it).
    pub image: PathBuf,
}

impl Default for RaytraceConfig {
    fn default() -> Self {
        RaytraceConfig {
            spp: 16,
            max_bounces: 8,
            mode: ShadingMode::Auto,
            backend: Backend::Auto,
            self_hit: 0.5,
            blend_thickness: 0.5,
            light_samples: 1,
            background: [0.0; 3],
            exposure: 1.0,
            aovs: false,
            caustic_radius: 0.0,
            caustic_k: 0,
            seed: 0,
            image: PathBuf::from("image.exr"),
        }
    }
}

/// A loaded configuration: the merged, overridden, validated config and where it came from.
#[derive(Clone, Debug)]
pub struct LoadedConfig {
    pub config: PipelineConfig,
    /// The top-level file.
    pub path: PathBuf,
    /// The folder relative paths in the top-level file resolve against.
    pub base_dir: PathBuf,
    /// The merged, overridden TOML text (for provenance).
    pub text: String,
}

impl LoadedConfig {
    /// The output folder, resolved.
    pub fn out_dir(&self) -> PathBuf {
        self.base_dir.join(&self.config.output.dir)
    }
    /// The octree artifact path, resolved.
    pub fn octree_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.octree.file)
    }
    /// The vmap artifact path, resolved.
    pub fn vmap_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.vmap.file)
    }
    /// The point lights as stored in artifacts and keys: position then intensity.
    pub fn light_records(&self) -> Vec<[f32; 6]> {
        self.config
            .lights
            .iter()
            .map(|l| {
                let (p, i) = (l.position, l.intensity);
                [p[0], p[1], p[2], i[0], i[1], i[2]]
            })
            .collect()
    }
    /// The radiosity artifact path, resolved.
    pub fn radiosity_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.fmm.file)
    }
    /// The photons artifact path, resolved.
    pub fn photons_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.caustics.file)
    }
    /// The rendered image path, resolved.
    pub fn image_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.raytrace.image)
    }
}

fn cfg_err(path: &Path, msg: impl Into<String>) -> SceneError {
    SceneError::Config {
        path: path.to_path_buf(),
        msg: msg.into(),
    }
}

/// Read `path`, merge its includes, apply `overrides` (`key.path=value`), validate.
pub fn load_config(path: &Path, overrides: &[String]) -> Result<LoadedConfig, SceneError> {
    let mut stack = Vec::new();
    let mut value = read_tree(path, &mut stack)?;
    for o in overrides {
        apply_override(&mut value, o).map_err(|m| cfg_err(path, format!("--set {o}: {m}")))?;
    }
    let text = toml::to_string(&value).map_err(|e| cfg_err(path, e.to_string()))?;
    let mut config: PipelineConfig = value
        .try_into()
        .map_err(|e: toml::de::Error| cfg_err(path, e.message().to_string()))?;
    config.include.clear();
    validate(&config, path)?;
    let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    Ok(LoadedConfig {
        config,
        path: path.to_path_buf(),
        base_dir,
        text,
    })
}

/// Parse a config from text (relative paths resolve against `base_dir`), for tests and tools.
pub fn parse_config(text: &str, base_dir: &Path) -> Result<LoadedConfig, SceneError> {
    let pseudo = base_dir.join("<inline>");
    let value: toml::Value = toml::from_str(text).map_err(|e| cfg_err(&pseudo, e.to_string()))?;
    let config: PipelineConfig = value
        .try_into()
        .map_err(|e: toml::de::Error| cfg_err(&pseudo, e.message().to_string()))?;
    validate(&config, &pseudo)?;
    Ok(LoadedConfig {
        config,
        path: pseudo,
        base_dir: base_dir.to_path_buf(),
        text: text.to_string(),
    })
}

fn read_tree(path: &Path, stack: &mut Vec<PathBuf>) -> Result<toml::Value, SceneError> {
    let canon = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    if stack.contains(&canon) {
        return Err(cfg_err(path, "include cycle"));
    }
    let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut value: toml::Value = toml::from_str(&text).map_err(|e| cfg_err(path, e.to_string()))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    // Included files' model paths become absolute (resolved against the included file's
    // folder), so they do not depend on where the top-level file is.
    let abs_dir = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    // Resolve model paths relative to the file that declares them, so an included file keeps
    // pointing at its own PLYs. The top-level file keeps relative paths (resolved at load).
    if !stack.is_empty() {
        if let Some(models) = value.get_mut("models").and_then(|m| m.as_array_mut()) {
            for m in models {
                if let Some(f) = m.get_mut("file") {
                    if let Some(s) = f.as_str() {
                        let p = Path::new(s);
                        if p.is_relative() {
                            *f =
                                toml::Value::String(abs_dir.join(p).to_string_lossy().into_owned());
                        }
                    }
                }
            }
        }
    }
    let includes: Vec<PathBuf> = match value.get("include") {
        None => Vec::new(),
        Some(toml::Value::Array(a)) => a
            .iter()
            .map(|v| {
                v.as_str()
                    .map(|s| dir.join(s))
                    .ok_or_else(|| cfg_err(path, "`include` must be a list of paths"))
            })
            .collect::<Result<_, _>>()?,
        Some(_) => return Err(cfg_err(path, "`include` must be a list of paths")),
    };
    if let Some(t) = value.as_table_mut() {
        t.remove("include");
    }
    stack.push(canon);
    let mut merged = toml::Value::Table(Default::default());
    for inc in &includes {
        let sub = read_tree(inc, stack)?;
        merge(&mut merged, sub);
    }
    stack.pop();
    merge(&mut merged, value);
    Ok(merged)
}

/// Deep-merge `top` over `base`: tables merge key by key, arrays of tables (models, lights)
/// concatenate, everything else is replaced.
fn merge(base: &mut toml::Value, top: toml::Value) {
    match (base, top) {
        (toml::Value::Table(b), toml::Value::Table(t)) => {
            for (k, v) in t {
                match b.get_mut(&k) {
                    Some(existing) => merge(existing, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (toml::Value::Array(b), toml::Value::Array(t))
            if t.iter().all(|v| v.is_table()) && !t.is_empty() =>
        {
            b.extend(t);
        }
        (b, t) => *b = t,
    }
}

/// Apply one `a.b.c=value` override. The value is parsed as TOML (`0.5`, `[1, 2, 3]`, `"x"`,
/// `true`); anything that does not parse is taken as a string. Array elements are addressed by
/// index (`models.0.material=glass`).
pub fn apply_override(root: &mut toml::Value, spec: &str) -> Result<(), String> {
    let (key, raw) = spec.split_once('=').ok_or("expected key=value")?;
    let key = key.trim();
    if key.is_empty() {
        return Err("empty key".into());
    }
    let raw = raw.trim();
    let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = root;
    for (i, part) in parts.iter().enumerate() {
        let last = i + 1 == parts.len();
        cur = match cur {
            toml::Value::Table(t) => {
                if last {
                    t.insert(part.to_string(), value);
                    return Ok(());
                }
                t.entry(part.to_string())
                    .or_insert_with(|| toml::Value::Table(Default::default()))
            }
            toml::Value::Array(a) => {
                let idx: usize = part
                    .parse()
                    .map_err(|_| format!("`{part}` is not an index into an array"))?;
                let len = a.len();
                let slot = a
                    .get_mut(idx)
                    .ok_or_else(|| format!("index {idx} is out of range (array has {len})"))?;
                if last {
                    *slot = value;
                    return Ok(());
                }
                slot
            }
            _ => return Err(format!("`{part}`: the key above it is not a table")),
        };
    }
    Ok(())
}

fn finite3(v: [f32; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn validate(c: &PipelineConfig, path: &Path) -> Result<(), SceneError> {
    let err = |m: String| Err(cfg_err(path, m));
    for (name, m) in &c.materials {
        match m {
            MaterialConfig::Diffuse {
                albedo: Albedo::Rgb(a),
            }
            | MaterialConfig::Emitter {
                albedo: Some(a), ..
            } => {
                if !finite3(*a) || a.iter().any(|x| !(0.0..=1.0).contains(x)) {
                    return err(format!(
                        "materials.{name}.albedo must lie in [0, 1], got {a:?}"
                    ));
                }
            }
            MaterialConfig::Diffuse {
                albedo: Albedo::Source(s),
            } if s != "vertex" => {
                return err(format!(
                    "materials.{name}.albedo must be [r, g, b] or \"vertex\", got \"{s}\""
                ));
            }
            _ => {}
        }
        match m {
            MaterialConfig::Emitter { radiance, .. }
                if !finite3(*radiance) || radiance.iter().any(|x| *x < 0.0) =>
            {
                return err(format!(
                    "materials.{name}.radiance must be finite and non-negative, got {radiance:?}"
                ));
            }
            MaterialConfig::Mirror { reflectance: r, .. }
            | MaterialConfig::Dielectric { tint: Some(r), .. }
                if !finite3(*r) || r.iter().any(|x| !(0.0..=1.0).contains(x)) =>
            {
                return err(format!(
                    "materials.{name}: reflectance/tint must lie in [0, 1], got {r:?}"
                ));
            }
            MaterialConfig::Dielectric { ior, .. } if !(ior.is_finite() && *ior > 0.0) => {
                return err(format!("materials.{name}.ior must be positive, got {ior}"));
            }
            _ => {}
        }
        if let MaterialConfig::Mirror { phong: Some(p), .. }
        | MaterialConfig::Dielectric { phong: Some(p), .. } = m
        {
            if !(p.is_finite() && *p >= 0.0) {
                return err(format!(
                    "materials.{name}.phong must be a non-negative exponent, got {p}"
                ));
            }
        }
    }
    for (i, m) in c.models.iter().enumerate() {
        if !c.materials.contains_key(&m.material) {
            let known: Vec<&str> = c.materials.keys().map(String::as_str).collect();
            return err(format!(
                "models[{i}] ({}) uses material `{}`, which is not defined (defined: {})",
                m.file.display(),
                m.material,
                known.join(", ")
            ));
        }
        if let Some(s) = m.scale {
            if !(s.is_finite() && s > 0.0) {
                return err(format!("models[{i}].scale must be positive, got {s}"));
            }
        }
        if m.translate.is_some_and(|t| !finite3(t)) || m.rotate.is_some_and(|t| !finite3(t)) {
            return err(format!("models[{i}]: translate/rotate must be finite"));
        }
    }
    for (i, l) in c.lights.iter().enumerate() {
        if !finite3(l.position) || !finite3(l.intensity) || l.intensity.iter().any(|x| *x < 0.0) {
            return err(format!(
                "lights[{i}]: position must be finite and intensity non-negative"
            ));
        }
    }
    let cam = &c.camera;
    if cam.width == 0 || cam.height == 0 {
        return err(format!(
            "camera: width and height must be positive, got {}x{}",
            cam.width, cam.height
        ));
    }
    if !(cam.fov > 0.0 && cam.fov < 180.0) {
        return err(format!(
            "camera.fov must lie in (0, 180) degrees, got {}",
            cam.fov
        ));
    }
    if !finite3(cam.origin) || !finite3(cam.target) || !finite3(cam.up) {
        return err("camera: origin, target and up must be finite".into());
    }
    let d = [
        cam.target[0] - cam.origin[0],
        cam.target[1] - cam.origin[1],
        cam.target[2] - cam.origin[2],
    ];
    let cross = [
        d[1] * cam.up[2] - d[2] * cam.up[1],
        d[2] * cam.up[0] - d[0] * cam.up[2],
        d[0] * cam.up[1] - d[1] * cam.up[0],
    ];
    if cross.iter().map(|x| x * x).sum::<f32>() < 1e-12 {
        return err("camera: target equals origin, or up is parallel to the view direction".into());
    }
    let o = &c.octree;
    if o.max_leaf_points == 0 {
        return err("octree.max_leaf_points must be at least 1".into());
    }
    if o.max_depth == 0 || o.max_depth > 21 {
        return err(format!(
            "octree.max_depth must lie in 1..=21, got {}",
            o.max_depth
        ));
    }
    if o.area_samples == 0 || o.area_samples > 64 {
        return err(format!(
            "octree.area_samples must lie in 1..=64, got {}",
            o.area_samples
        ));
    }
    let v = &c.vmap;
    if !(v.theta.is_finite() && v.theta > 0.0 && v.theta < 2.0) {
        return err(format!("vmap.theta must lie in (0, 2), got {}", v.theta));
    }
    if v.rays == 0 || v.rays > 4096 || v.leaf_splats == 0 {
        return err(format!(
            "vmap.rays must lie in 1..=4096 and vmap.leaf_splats be positive, got {} and {}",
            v.rays, v.leaf_splats
        ));
    }
    if !(v.self_hit.is_finite() && v.self_hit >= 0.0) {
        return err("vmap.self_hit must be finite and non-negative".into());
    }
    if v.heavy_rays > 4096 || !(v.heavy_form_factor.is_finite() && v.heavy_form_factor >= 0.0) {
        return err(format!(
            "vmap.heavy_rays must lie in 0..=4096 and vmap.heavy_form_factor be finite and \
             non-negative, got {} and {}",
            v.heavy_rays, v.heavy_form_factor
        ));
    }
    let f = &c.fmm;
    if f.order > 12 {
        return err(format!("fmm.order must lie in 0..=12, got {}", f.order));
    }
    if !(f.theta.is_finite() && f.theta > 0.0 && f.theta < 1.0) {
        return err(format!("fmm.theta must lie in (0, 1), got {}", f.theta));
    }
    if !(f.clamp_tol.is_finite() && f.clamp_tol >= 0.0) {
        return err("fmm.clamp_tol must be finite and non-negative".into());
    }
    if !(f.tolerance.is_finite() && f.tolerance > 0.0) || f.max_iterations == 0 {
        return err(format!(
            "fmm.tolerance must be positive and fmm.max_iterations at least 1, got {} and {}",
            f.tolerance, f.max_iterations
        ));
    }
    let r = &c.raytrace;
    if r.spp == 0 || r.spp > 65536 {
        return err(format!("raytrace.spp must lie in 1..=65536, got {}", r.spp));
    }
    if r.max_bounces > 64 {
        return err(format!(
            "raytrace.max_bounces must be at most 64, got {}",
            r.max_bounces
        ));
    }
    if !(r.self_hit.is_finite() && r.self_hit >= 0.0)
        || !(r.blend_thickness.is_finite() && r.blend_thickness >= 0.0)
    {
        return err(
            "raytrace.self_hit and raytrace.blend_thickness must be finite and non-negative".into(),
        );
    }
    if !(r.exposure.is_finite() && r.exposure > 0.0)
        || !finite3(r.background)
        || r.background.iter().any(|x| *x < 0.0)
    {
        return err(
            "raytrace.exposure must be positive and raytrace.background finite and non-negative"
                .into(),
        );
    }
    if !(r.caustic_radius.is_finite() && r.caustic_radius >= 0.0) || r.caustic_k > 4096 {
        return err(format!(
            "raytrace.caustic_radius must be finite and non-negative and raytrace.caustic_k at \
             most 4096, got {} and {}",
            r.caustic_radius, r.caustic_k
        ));
    }
    let k = &c.caustics;
    if k.max_bounces == 0 || k.max_bounces > 64 || !(k.self_hit.is_finite() && k.self_hit >= 0.0) {
        return err(format!(
            "caustics.max_bounces must lie in 1..=64 and caustics.self_hit be finite and \
             non-negative, got {} and {}",
            k.max_bounces, k.self_hit
        ));
    }
    if r.light_samples == 0 || r.light_samples > 1024 {
        return err(format!(
            "raytrace.light_samples must lie in 1..=1024, got {}",
            r.light_samples
        ));
    }
    if c.import.normal_neighbors < 3 || c.import.radius_neighbors < 1 {
        return err(
            "import: normal_neighbors must be at least 3 and radius_neighbors at least 1".into(),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str = r#"
[materials.white]
type = "diffuse"
albedo = [0.5, 0.5, 0.5]
[materials.glass]
type = "dielectric"
ior = 1.5
[[models]]
file = "a.ply"
material = "white"
"#;

    #[test]
    fn parses_and_defaults() {
        let c = parse_config(BASE, Path::new("/x")).unwrap();
        assert_eq!(c.config.octree.max_leaf_points, 16);
        assert_eq!(c.config.camera.fov_axis, FovAxis::Smaller);
        assert!(c.config.materials["glass"].is_specular());
    }

    #[test]
    fn unknown_material_is_named() {
        let t = BASE.replace("material = \"white\"", "material = \"chalk\"");
        let e = parse_config(&t, Path::new("/x")).unwrap_err().to_string();
        assert!(e.contains("chalk") && e.contains("white"), "{e}");
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let t = format!("{BASE}\n[octree]\nmax_leaf_point = 3\n");
        let e = parse_config(&t, Path::new("/x")).unwrap_err().to_string();
        assert!(e.contains("max_leaf_point"), "{e}");
    }

    #[test]
    fn overrides_apply_to_tables_and_arrays() {
        let mut v: toml::Value = toml::from_str(BASE).unwrap();
        apply_override(&mut v, "octree.max_leaf_points=4").unwrap();
        apply_override(&mut v, "models.0.material=glass").unwrap();
        apply_override(&mut v, "camera.origin=[1, 2, 3]").unwrap();
        assert_eq!(v["octree"]["max_leaf_points"].as_integer(), Some(4));
        assert_eq!(v["models"][0]["material"].as_str(), Some("glass"));
        assert!(apply_override(&mut v, "models.5.material=glass")
            .unwrap_err()
            .contains("out of range"));
        assert!(apply_override(&mut v, "nokey").is_err());
    }

    #[test]
    fn includes_merge_and_resolve_paths() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("scene")).unwrap();
        std::fs::write(dir.path().join("scene/scene.toml"), BASE).unwrap();
        std::fs::write(
            dir.path().join("pipeline.toml"),
            "include = [\"scene/scene.toml\"]\n[octree]\nmax_leaf_points = 8\n[materials.white]\nalbedo = [0.25, 0.25, 0.25]\n",
        )
        .unwrap();
        let c = load_config(
            &dir.path().join("pipeline.toml"),
            &["octree.max_depth=10".into()],
        )
        .unwrap();
        assert_eq!(c.config.octree.max_leaf_points, 8);
        assert_eq!(c.config.octree.max_depth, 10);
        assert_eq!(
            c.config.models[0].file,
            dir.path().join("scene").join("a.ply")
        );
        assert_eq!(
            c.config.materials["white"],
            MaterialConfig::Diffuse {
                albedo: Albedo::Rgb([0.25; 3])
            }
        );
    }

    #[test]
    fn bad_values_are_explained() {
        for (over, needle) in [
            ("octree.max_depth=30", "max_depth"),
            ("camera.width=0", "width"),
            ("materials.glass.ior=-1", "ior"),
            ("materials.white.albedo=[2, 0, 0]", "albedo"),
            ("camera.up=[0, 0, -1]", "parallel"),
        ] {
            let mut v: toml::Value = toml::from_str(BASE).unwrap();
            apply_override(&mut v, over).unwrap();
            let text = toml::to_string(&v).unwrap();
            let e = parse_config(&text, Path::new("/x"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{over}: {e}");
        }
    }
}
