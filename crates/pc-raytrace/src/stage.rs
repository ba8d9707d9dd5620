//! The pc-raytrace stage: config + octree (+ radiosity, photon map) → image (EXR + PNG preview).
//!
//! Which artifacts a render reads: the octree always; the radiosity in `stored` and `auto`
//! shading when it exists (or was named); the photon map when it exists (or was named). The
//! render's key covers those artifacts' keys, the materials, lights, camera, every `raytrace`
//! parameter and the backend asked for, and is written into both images: the PNG first, the EXR
//! last, and the pair counts as up to date only when both carry the key
//! ([`crate::image::rendered_key`]).

use std::path::{Path, PathBuf};

use pc_artifact::octree::OctreeFile;
use pc_artifact::photons::PhotonMapFile;
use pc_artifact::radiosity::RadiosityFile;
use pc_artifact::{Artifact, ArtifactKind, Key, KeyHasher};
use pc_config::{Backend, LoadedConfig, RaytraceConfig, ShadingMode};
use pc_stage::{OptionalInput, Progress, Stage};
use pc_tree::OctreeView;

use crate::camera::Camera;
use crate::cpu::RayCounts;
use crate::error::RenderError;
use crate::image::{png_path, write_exr_keyed, write_png_keyed, Image};
use crate::renderer::{Device, Renderer};
use crate::scene::RenderScene;

/// The producing stage's name and version (the render's key starts with them).
pub const STAGE: &str = "pc-raytrace";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// The artifacts a render reads.
#[derive(Clone, Debug)]
pub struct Inputs {
    pub octree: PathBuf,
    /// Shown at diffuse hits in `stored` shading; what `auto` shading looks for.
    pub radiosity: OptionalInput,
    /// Diffuse hits add its caustic density estimate.
    pub photons: OptionalInput,
}

impl Inputs {
    /// The config's default paths, replaced by those given.
    pub fn new(
        cfg: &LoadedConfig,
        octree: Option<PathBuf>,
        radiosity: Option<PathBuf>,
        photons: Option<PathBuf>,
    ) -> Inputs {
        Inputs {
            octree: octree.unwrap_or_else(|| cfg.octree_path()),
            radiosity: OptionalInput::new(radiosity, cfg.radiosity_path()),
            photons: OptionalInput::new(photons, cfg.photons_path()),
        }
    }

    /// Whether a render of `cfg` reads the radiosity.
    fn reads_radiosity(&self, cfg: &RaytraceConfig) -> bool {
        cfg.mode != ShadingMode::Direct && self.radiosity.wanted()
    }
}

/// What one render made.
pub struct Summary {
    /// The shading mode used (`auto` resolved).
    pub mode: ShadingMode,
    pub image: Image,
    pub device: Device,
    pub device_name: String,
    pub seconds: f64,
    pub counts: Option<RayCounts>,
    /// Pixels the second pass rendered again (`raytrace.refine`; crate::refine).
    pub refined: usize,
    /// Whether a photon map was shown.
    pub caustics: bool,
    pub exr: PathBuf,
    pub png: PathBuf,
}

/// The density-estimate radius: `raytrace.caustic_radius`, or 1/200 of the root cube's edge
/// when it is 0. (1/100 flattened the glass ball's caustic on `cornell-mirror-glass` by 3 %,
/// 1/200 by 2 %, with 1M photons; the other regions did not move.)
pub fn caustic_radius(rt: &RaytraceConfig, view: &OctreeView) -> f32 {
    if rt.caustic_radius > 0.0 {
        rt.caustic_radius
    } else {
        view.frame.size / 200.0
    }
}

/// The render's key from the keys of the artifacts it reads (see the module documentation).
fn key_of(
    cfg: &LoadedConfig,
    octree: &Key,
    radiosity: Option<&Key>,
    photons: Option<&Key>,
    backend: Backend,
) -> Key {
    let c = &cfg.config;
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(octree);
    if let Some(k) = radiosity {
        h.update_str("radiosity").update_key(k);
    }
    if let Some(k) = photons {
        h.update_str("photons").update_key(k);
    }
    h.update_serialize(&c.materials)
        .update_serialize(&c.lights)
        .update_serialize(&c.camera)
        .update_serialize(&c.raytrace)
        .update_serialize(&backend);
    h.finish()
}

/// The render's key, from the input artifacts' headers (validated, nothing rendered).
pub fn render_key(
    cfg: &LoadedConfig,
    inputs: &Inputs,
    backend: Backend,
) -> Result<Key, RenderError> {
    let input = |path: &Path, kind| Artifact::input_key(path, kind);
    let octree = input(&inputs.octree, ArtifactKind::Octree)?;
    let radiosity = match inputs.reads_radiosity(&cfg.config.raytrace) {
        true => Some(input(inputs.radiosity.path(), ArtifactKind::Radiosity)?),
        false => None,
    };
    let photons = match inputs.photons.wanted() {
        true => Some(input(inputs.photons.path(), ArtifactKind::Photons)?),
        false => None,
    };
    Ok(key_of(
        cfg,
        &octree,
        radiosity.as_ref(),
        photons.as_ref(),
        backend,
    ))
}

/// The render scene of `cfg` (octree, materials, lights, camera, and the radiosity and photon
/// map it shows), handed to `f` with the shading mode (`auto` resolved) and the render's key;
/// the artifacts stay mapped while `f` runs.
///
/// Shading: `stored` shows the radiosity when it is read (else the materials' emission alone);
/// `auto` is `stored` when the radiosity exists and `direct` otherwise.
pub fn with_scene<R>(
    cfg: &LoadedConfig,
    inputs: &Inputs,
    backend: Backend,
    f: impl FnOnce(&mut RenderScene, ShadingMode, Key) -> Result<R, RenderError>,
) -> Result<R, RenderError> {
    let octree = OctreeFile::open(&inputs.octree)?;
    let materials = cfg.materials_for(&octree)?;
    let c = &cfg.config;
    let mut rt = c.raytrace.clone();
    // The two are opened and checked side by side (0.08 s of a new view at 1M splats).
    let (radiosity, photons) = rayon::join(
        || match inputs.reads_radiosity(&rt) {
            true => RadiosityFile::open(inputs.radiosity.path(), &octree.id()).map(Some),
            false => Ok(None),
        },
        || match inputs.photons.wanted() {
            true => PhotonMapFile::open(inputs.photons.path(), &octree.id()).map(Some),
            false => Ok(None),
        },
    );
    let (radiosity, photons) = (radiosity?, photons?);
    let key = key_of(
        cfg,
        &octree.key(),
        radiosity.as_ref().map(|r| r.key()).as_ref(),
        photons.as_ref().map(|p| p.key()).as_ref(),
        backend,
    );
    if rt.mode == ShadingMode::Auto {
        rt.mode = match radiosity {
            Some(_) => ShadingMode::Stored,
            None => ShadingMode::Direct,
        };
    }
    let view = octree.view();
    let radius = caustic_radius(&rt, &view);
    let mut sc = RenderScene::new(view, materials, &c.lights, &Camera::new(&c.camera), &rt);
    if let Some(r) = &radiosity {
        sc.set_radiance(r.view().radiance);
    }
    if let Some(p) = &photons {
        let v = p.view();
        // An empty map (a scene without specular surfaces) adds nothing.
        if !v.photons.is_empty() {
            sc.caustics = Some(crate::caustic::Caustics::new(
                v.photons,
                radius,
                rt.caustic_k,
            ));
        }
    }
    f(&mut sc, rt.mode, key)
}

/// Render the config's camera view and write the images (the PNG first, then the EXR; both
/// carry the render's key). `progress` counts the CPU renderer's tiles.
pub fn run(
    cfg: &LoadedConfig,
    inputs: &Inputs,
    exr: &Path,
    backend: Backend,
    progress: &dyn Progress,
) -> Result<Summary, RenderError> {
    pc_stage::look_early(backend, pc_stage::Work::Render);
    let c = &cfg.config;
    with_scene(cfg, inputs, backend, |sc, mode, key| {
        let t = std::time::Instant::now();
        let mut renderer = Renderer::new(sc, backend)?;
        if renderer.device() == Device::Cpu {
            progress.phase("tiles");
            progress
                .total(sc.params.width.div_ceil(16) as u64 * sc.params.height.div_ceil(16) as u64);
        }
        let frame = renderer.render(sc, c.raytrace.aovs, &|| progress.advance(1))?;
        let (image, counts, refined) = (frame.image, frame.counts, frame.refined);
        let seconds = t.elapsed().as_secs_f64();
        // The PNG first: the EXR is the keyed file the next run checks first, so it lands last.
        let png = png_path(exr);
        write_png_keyed(&png, &image, c.raytrace.exposure, Some(&key))?;
        write_exr_keyed(exr, &image, Some(&key))?;
        Ok(Summary {
            mode,
            image,
            device: renderer.device(),
            device_name: renderer.device_name(),
            seconds,
            counts,
            refined,
            caustics: sc.caustics.is_some(),
            exr: exr.to_path_buf(),
            png,
        })
    })
}

/// pc-raytrace as its binary runs it.
pub struct RaytraceStage {
    pub cfg: LoadedConfig,
    pub inputs: Inputs,
    pub exr: PathBuf,
    pub backend: Backend,
}

impl Stage for RaytraceStage {
    const NAME: &'static str = STAGE;
    const DOING: &'static str = "rendering";
    const KIND: Option<pc_artifact::ArtifactKind> = None;
    type Made = Summary;
    type Error = RenderError;

    fn output(&self) -> &Path {
        &self.exr
    }

    fn outputs(&self) -> Vec<PathBuf> {
        vec![self.exr.clone(), png_path(&self.exr)]
    }

    fn key(&self) -> Result<Key, RenderError> {
        render_key(&self.cfg, &self.inputs, self.backend)
    }

    fn existing_key(&self) -> Option<Key> {
        crate::image::rendered_key(&self.exr)
    }

    fn run(&self, progress: &dyn Progress) -> Result<Summary, RenderError> {
        run(&self.cfg, &self.inputs, &self.exr, self.backend, progress)
    }

    fn summary(&self, s: &Summary, _seconds: f64) -> String {
        let p = &self.cfg.config.raytrace;
        let rate = s
            .counts
            .map(|c| {
                let rays = c.camera + c.bounce + c.shadow;
                format!(", {:.2} M rays/s", rays as f64 / s.seconds / 1e6)
            })
            .unwrap_or_default();
        let refined = match s.refined {
            0 => String::new(),
            n => format!(", {n} pixels refined at {}", p.refine_spp()),
        };
        format!(
            "pc-raytrace: wrote {} and {} ({}x{}, {} spp{refined}, {} shading{}) in {:.2} s on {}{rate}",
            s.exr.display(),
            s.png.display(),
            s.image.width,
            s.image.height,
            p.spp,
            format!("{:?}", s.mode).to_lowercase(),
            if s.caustics { " with caustics" } else { "" },
            s.seconds,
            s.device_name,
        )
    }

    /// The render's time and its work: camera samples (every pixel's `spp`, and the refined
    /// pixels' second pass), the rays where the CPU counted them.
    fn stats(&self, s: &Summary, seconds: f64) -> serde_json::Value {
        let p = &self.cfg.config.raytrace;
        let pixels = s.image.width as u64 * s.image.height as u64;
        let samples = pixels * p.spp as u64 + s.refined as u64 * p.refine_spp() as u64;
        let rays = s.counts.map(
            |c| serde_json::json!({ "camera": c.camera, "bounce": c.bounce, "shadow": c.shadow }),
        );
        serde_json::json!({
            "stage": "pc-raytrace",
            "width": s.image.width,
            "height": s.image.height,
            "spp": p.spp,
            "refined": s.refined,
            "refine_spp": p.refine_spp(),
            "camera_samples": samples,
            "rays": rays,
            "render_seconds": s.seconds,
            "total_seconds": seconds,
            "device": s.device_name,
        })
    }
}
