//! pipeline.toml: the scene (models, materials, lights, camera) and every stage's parameters.
//!
//! Loading ([`load_config`]) merges `include`d files (their model paths resolved relative to the
//! file that names them), applies `--set key=value` overrides on the TOML tree, then
//! deserializes with unknown keys rejected, and validates values ([`validate()`]). The parameter
//! blocks that shape artifacts (`[octree]`, `[vmap]`, `[caustics]`, `[fmm]`) are pc-artifact's
//! [`pc_artifact::params`] structs, so the config, the artifact's metadata and the stage's key
//! share one definition; each stage's table adds where it runs (`backend`) and its file name.
//! Every key is documented in docs/pipeline.md.

mod error;
mod load;
mod materials;
mod validate;

use std::collections::BTreeMap;
use std::path::PathBuf;

use pc_artifact::params::{CausticsParams, FmmParams, OctreeParams, VmapParams};
use pc_artifact::PointLight;
use serde::{Deserialize, Serialize};

pub use error::ConfigError;
pub use load::{apply_override, load_config, parse_config, to_toml, OverrideError};
pub use materials::material_table;
pub use validate::{
    validate, MAX_ALBEDO, MAX_COORDINATE, MAX_IMAGE_SIDE, MAX_PIXELS, MAX_RADIANCE,
    MAX_WORLD_COORDINATE,
};

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
    pub lights: Vec<PointLight>,
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
    #[serde(default)]
    pub bake: BakeConfig,
}

/// pc-bake: the lit scan written back as a point cloud.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BakeConfig {
    /// The lit cloud, in `output.dir`; its format follows the extension: `.ply`, `.las`, `.laz`.
    pub file: PathBuf,
    /// Factor on the linear radiance before the sRGB curve makes its 8/16-bit color.
    pub exposure: f32,
}

impl Default for BakeConfig {
    fn default() -> Self {
        BakeConfig {
            file: "lit.ply".into(),
            exposure: 1.0,
        }
    }
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
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// The model's file (.ply, .las, .laz or .e57); after loading it is resolved (relative
    /// paths against the declaring file).
    pub file: PathBuf,
    pub material: String,
    /// Materials by LAS classification code (`{ "2" = "ground", "6" = "building" }`): a point
    /// whose class is listed takes that material, every other point `material`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub classes: Option<BTreeMap<String, String>>,
    /// Factor on the per-point colors (or intensities) that become the albedo of a `"vertex"`
    /// material; the product is clamped to [`MAX_ALBEDO`] and the clamped points counted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo_scale: Option<f32>,
    /// Where the scanner stood, in the file's own coordinates: estimated normals face it. One
    /// position serves every point; with several, a LAS point faces the one its
    /// `point_source_id` indexes (the scan it came from). Overrides the stations an E57 file
    /// gives and `import.sensor`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scanners: Option<Vec<[f64; 3]>>,
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
    /// Degrees: an estimated normal whose tilt error (the standard error of its fitted plane)
    /// is above this is fitted again over a wider neighbourhood, where the wider patch is as
    /// flat (range noise on a dense scan); 0 keeps every fit to `normal_neighbors`.
    #[serde(default = "default_normal_widen_above")]
    pub normal_widen_above: f32,
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
    /// The point of the models' own (georeferenced) frame that becomes the scene's origin;
    /// default: the first model's bounds centre, rounded to whole units, when it is a scan
    /// (LAS, LAZ, E57), else zero. Everything else in the config (camera, lights, `sensor`)
    /// is given relative to it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<[f64; 3]>,
    /// Merge each point closer than this (the model file's units) to an earlier point of the
    /// same model into it: duplicates from overlapping scan stations. Default: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub merge_distance: Option<f32>,
    /// Statistical outlier removal (stray points of a raw scan). Default: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outliers: Option<OutlierConfig>,
}

/// `[import.outliers]`: a point whose mean distance to its `neighbors` nearest points exceeds
/// the mean over the model by more than `std_ratio` standard deviations is removed.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutlierConfig {
    #[serde(default = "default_outlier_neighbors")]
    pub neighbors: usize,
    #[serde(default = "default_outlier_std_ratio")]
    pub std_ratio: f32,
}

fn default_outlier_neighbors() -> usize {
    16
}
fn default_outlier_std_ratio() -> f32 {
    2.0
}

fn default_normal_neighbors() -> usize {
    16
}
fn default_normal_widen_above() -> f32 {
    1.5
}
fn default_radius_neighbors() -> usize {
    8
}

impl Default for ImportConfig {
    fn default() -> Self {
        Self {
            normal_neighbors: default_normal_neighbors(),
            normal_widen_above: default_normal_widen_above(),
            radius_neighbors: default_radius_neighbors(),
            sensor: None,
            drop_invalid: false,
            origin: None,
            merge_distance: None,
            outliers: None,
        }
    }
}

/// Keys of a stage's table that no field took: an unknown (misspelt) key is an error
/// ([`validate()`]), not a silently ignored setting. (serde's `deny_unknown_fields` does not work
/// with the flattened parameter block, so the leftovers are collected here.)
pub type UnknownKeys = BTreeMap<String, toml::Value>;

/// `[octree]`: the octree's shape and the artifact's file name.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct OctreeConfig {
    #[serde(flatten)]
    pub params: OctreeParams,
    /// Artifact file name inside `output.dir`.
    #[serde(default = "default_octree_file")]
    pub file: PathBuf,
    #[serde(flatten, skip_serializing)]
    pub unknown: UnknownKeys,
}

fn default_octree_file() -> PathBuf {
    PathBuf::from("octree.pcgi")
}

impl Default for OctreeConfig {
    fn default() -> Self {
        OctreeConfig {
            params: OctreeParams::default(),
            file: default_octree_file(),
            unknown: UnknownKeys::new(),
        }
    }
}

/// `[vmap]`: what shapes the links, where the rays are cast, the artifact's file name.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct VmapConfig {
    #[serde(flatten)]
    pub params: VmapParams,
    /// Where the rays are cast.
    #[serde(default)]
    pub backend: Backend,
    /// Artifact file name inside `output.dir`.
    #[serde(default = "default_vmap_file")]
    pub file: PathBuf,
    #[serde(flatten, skip_serializing)]
    pub unknown: UnknownKeys,
}

fn default_vmap_file() -> PathBuf {
    PathBuf::from("vmap.pcgi")
}

impl Default for VmapConfig {
    fn default() -> Self {
        VmapConfig {
            params: VmapParams::default(),
            backend: Backend::Auto,
            file: default_vmap_file(),
            unknown: UnknownKeys::new(),
        }
    }
}

/// `[fmm]`: the radiosity solve, where it runs, the artifact's file name.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FmmConfig {
    #[serde(flatten)]
    pub params: FmmParams,
    /// Where the FMM passes run.
    #[serde(default)]
    pub backend: Backend,
    /// Artifact file name inside `output.dir`.
    #[serde(default = "default_fmm_file")]
    pub file: PathBuf,
    #[serde(flatten, skip_serializing)]
    pub unknown: UnknownKeys,
}

fn default_fmm_file() -> PathBuf {
    PathBuf::from("radiosity.pcgi")
}

impl Default for FmmConfig {
    fn default() -> Self {
        FmmConfig {
            params: FmmParams::default(),
            backend: Backend::Auto,
            file: default_fmm_file(),
            unknown: UnknownKeys::new(),
        }
    }
}

/// `[caustics]`: the photon pass (docs/caustics.md), where it runs, the artifact's file name.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CausticsConfig {
    #[serde(flatten)]
    pub params: CausticsParams,
    /// Where the photons are traced.
    #[serde(default)]
    pub backend: Backend,
    /// Artifact file name inside `output.dir`.
    #[serde(default = "default_caustics_file")]
    pub file: PathBuf,
    #[serde(flatten, skip_serializing)]
    pub unknown: UnknownKeys,
}

fn default_caustics_file() -> PathBuf {
    PathBuf::from("photons.pcgi")
}

impl Default for CausticsConfig {
    fn default() -> Self {
        CausticsConfig {
            params: CausticsParams::default(),
            backend: Backend::Auto,
            file: default_caustics_file(),
            unknown: UnknownKeys::new(),
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
    /// A hardware GPU where it pays (rendering always; the V-map, photons and FMM on hosts of
    /// at most 16 threads: docs/gpu.md), else the CPU.
    #[default]
    Auto,
}

/// pc-raytrace parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RaytraceConfig {
    /// Samples per pixel (stratified on a √n × √n grid when n is a square).
    pub spp: u32,
    /// Pixels that differ from a neighbour by more than `refine_contrast` after the first pass
    /// are rendered again with `refine` times `spp` samples (their own stratified pattern); 0 or
    /// 1: no second pass. docs/raytrace.md, "Refined pixels".
    pub refine: u32,
    /// The relative difference from a neighbour that marks a pixel for `refine`:
    /// |a − b| / (½(a + b) + 0.01 · the image's mean), the largest over the three channels
    /// (below 2, which no two pixels exceed).
    pub refine_contrast: f32,
    /// Specular bounces after the camera ray (§8.5.8's b).
    pub max_bounces: u32,
    /// Dielectric hits per camera sample at which the path takes both ways out, the reflection
    /// and the refraction, each weighted by its Fresnel share, instead of choosing one at
    /// random (at most [`MAX_SPLITS`]; 0: a random choice at every hit). docs/raytrace.md,
    /// "Splitting at glass".
    pub splits: u32,
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
    /// Radius of the caustic density estimate (§8.5.8), in scene units; 0 picks 1/200 of the
    /// root cube's edge.
    pub caustic_radius: f32,
    /// With k > 0, the estimate takes the k nearest photons within `caustic_radius` and the k-th
    /// one's distance as the radius (`caustic_radius` where fewer lie within it: k-nearest);
    /// 0: every photon within the fixed radius.
    pub caustic_k: u32,
    /// Seed of the sample pattern.
    pub seed: u32,
    /// Image file name inside `output.dir` (an `.exr`; a `.png` preview is written beside it).
    pub image: PathBuf,
}

/// The most `raytrace.splits`: the renderers hold this many branches of a camera sample
/// waiting (the GPU kernel's three slots, shaders/raytrace/render.wgsl). A fourth split
/// changed the reference's per-pixel error by 10⁻⁴ (docs/raytrace.md, "Splitting at glass").
pub const MAX_SPLITS: u32 = 3;

impl Default for RaytraceConfig {
    fn default() -> Self {
        RaytraceConfig {
            spp: 16,
            refine: 4,
            refine_contrast: 1.0,
            max_bounces: 8,
            splits: 2,
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

impl RaytraceConfig {
    /// Samples of a pixel the second pass refines: `refine` × `spp` (no second pass unless
    /// above `spp`).
    pub fn refine_spp(&self) -> u32 {
        self.spp.saturating_mul(self.refine)
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
    /// The radiosity artifact path, resolved.
    pub fn radiosity_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.fmm.file)
    }
    /// The photons artifact path, resolved.
    pub fn photons_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.caustics.file)
    }
    /// The lit cloud's path (pc-bake), resolved.
    pub fn bake_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.bake.file)
    }
    /// The rendered image path, resolved.
    pub fn image_path(&self) -> PathBuf {
        self.out_dir().join(&self.config.raytrace.image)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

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
        assert_eq!(c.config.octree.params.max_leaf_points, 16);
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
    fn a_value_of_the_wrong_type_names_its_key() {
        // In the file, in a model's table, and from --set: the key, then serde's reason.
        let t = format!("{BASE}\n[raytrace]\nspp = -1\n");
        let e = parse_config(&t, Path::new("/x")).unwrap_err().to_string();
        assert!(
            e.contains("raytrace.spp: invalid value: integer `-1`"),
            "{e}"
        );
        let t = BASE.replace("file = \"a.ply\"", "file = 3");
        let e = parse_config(&t, Path::new("/x")).unwrap_err().to_string();
        assert!(
            e.contains("models[0].file: invalid type: integer `3`"),
            "{e}"
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pipeline.toml");
        std::fs::write(&path, BASE).unwrap();
        let e = load_config(&path, &["camera.fov=\"wide\"".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("pipeline.toml") && e.contains("camera.fov: invalid type: string \"wide\""),
            "{e}"
        );
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let t = format!("{BASE}\n[octree]\nmax_leaf_point = 3\n");
        let e = parse_config(&t, Path::new("/x")).unwrap_err().to_string();
        assert!(e.contains("max_leaf_point"), "{e}");
    }

    #[test]
    fn retired_keys_say_what_took_their_place() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pipeline.toml");
        std::fs::write(&path, format!("{BASE}\n[caustics]\nself_hit = 0.5\n")).unwrap();
        let e = load_config(&path, &[]).unwrap_err().to_string();
        assert!(e.contains("pipeline.toml"), "{e}");
        assert!(e.contains("[caustics] self_hit is no longer read"), "{e}");
        assert!(
            e.contains("own zone") && e.contains("delete the line"),
            "{e}"
        );
        std::fs::write(&path, BASE).unwrap();
        let e = load_config(&path, &["caustics.self_hit=0.1".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--set caustics.self_hit=0.1: [caustics] self_hit"),
            "{e}"
        );
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
            .to_string()
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
        assert_eq!(c.config.octree.params.max_leaf_points, 8);
        assert_eq!(c.config.octree.params.max_depth, 10);
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

    #[test]
    fn written_numbers_are_the_f32_values_shortest_text() {
        #[derive(serde::Serialize)]
        struct T {
            a: f32,
            b: f32,
            c: f32,
            v: [f32; 3],
        }
        let text = to_toml(&T {
            a: 17.0,
            b: 0.75,
            c: 39.3077,
            v: [1.0, 0.065, 1e-7],
        })
        .unwrap();
        assert!(text.contains("a = 17.0\n"), "{text}");
        assert!(text.contains("b = 0.75\n"), "{text}");
        assert!(text.contains("c = 39.3077\n"), "{text}");
        let t: toml::Table = text.parse().unwrap();
        let v: Vec<f32> = t["v"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_float().unwrap() as f32)
            .collect();
        assert_eq!(v, [1.0, 0.065, 1e-7]);
    }
}
