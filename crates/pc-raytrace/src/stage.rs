//! The pc-raytrace stage: config + octree artifact → image (EXR + PNG preview).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use pc_artifact::radiosity::{sections as rs, RadiosityMeta};
use pc_artifact::{Artifact, ArtifactKind, Key, KeyHasher};
use pc_scene::camera::Camera;
use pc_scene::config::ShadingMode;
use pc_scene::config::{Backend, LoadedConfig};
use pc_tree::OctreeView;

use crate::cpu::RayCounts;
use crate::image::{write_exr_keyed, write_png, Image};
use crate::scene::RenderScene;

pub use pc_scene::cli::current_materials;

/// Which backend runs, after `auto` is resolved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Device {
    Cpu,
    Gpu,
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
    /// Whether a photon map was shown.
    pub caustics: bool,
    pub exr: PathBuf,
    pub png: PathBuf,
}

/// The per-splat radiance of a radiosity artifact, checked against the octree it must match.
pub fn load_radiosity(path: &Path, octree: &Artifact) -> anyhow::Result<Vec<[f32; 3]>> {
    let a = Artifact::open_kind(path, ArtifactKind::Radiosity)?;
    let meta: RadiosityMeta = a.metadata()?;
    if meta.octree_key != octree.header().key.to_string() {
        bail!(
            "{}: stale radiosity: it was solved for another octree than {}: rerun pc-vmap and pc-fmm",
            path.display(),
            octree.path().display()
        );
    }
    let radiance: &[[f32; 3]] = a.section(rs::RADIANCE)?;
    let splats = octree
        .section::<pc_artifact::octree::Splat>("splats")?
        .len();
    if radiance.len() != splats {
        bail!(
            "{}: the radiosity holds {} splats but the octree {} has {splats}: rerun pc-fmm",
            path.display(),
            radiance.len(),
            octree.path().display()
        );
    }
    if let Some(i) = radiance
        .iter()
        .position(|c| c.iter().any(|x| !x.is_finite()))
    {
        bail!("{}: splat {i} has a non-finite radiance", path.display());
    }
    Ok(radiance.to_vec())
}

/// The photon map of a photons artifact, checked against the octree it must match: photons
/// that land on the octree's splats with finite positions and powers, and a valid kd-tree
/// over exactly those photons.
pub fn load_photons<'a>(
    a: &'a Artifact,
    octree: &Artifact,
    radius: f32,
    k: u32,
) -> anyhow::Result<crate::caustic::Caustics<'a>> {
    use pc_artifact::photons::{archived_tree, sections as ps, Photon, PhotonsMeta};
    let path = a.path();
    let meta: PhotonsMeta = a.metadata()?;
    if meta.octree_key != octree.header().key.to_string() {
        bail!(
            "{}: stale photon map: it was traced on another octree than {}: rerun pc-vmap and pc-caustics",
            path.display(),
            octree.path().display()
        );
    }
    let photons: &[Photon] = a.section(ps::PHOTONS)?;
    let splats = octree
        .section::<pc_artifact::octree::Splat>("splats")?
        .len();
    if let Some(i) = photons.iter().position(|p| {
        p.splat as usize >= splats
            || p.position
                .iter()
                .chain(&p.power)
                .chain(&p.dir)
                .any(|x| !x.is_finite())
    }) {
        bail!(
            "{}: photon {i} lies outside the octree {} or is not finite: rerun pc-caustics",
            path.display(),
            octree.path().display()
        );
    }
    let tree = archived_tree(a)?;
    if tree.size() as usize != photons.len() {
        bail!(
            "{}: the kd-tree holds {} photons but the map {}: rerun pc-caustics",
            path.display(),
            tree.size(),
            photons.len()
        );
    }
    Ok(crate::caustic::Caustics {
        photons,
        tree,
        radius,
        k,
    })
}

/// The density-estimate radius: `raytrace.caustic_radius`, or 1/100 of the root cube's edge
/// when it is 0.
pub fn caustic_radius(rt: &pc_scene::config::RaytraceConfig, view: &pc_tree::OctreeView) -> f32 {
    if rt.caustic_radius > 0.0 {
        rt.caustic_radius
    } else {
        view.frame.size / 100.0
    }
}

/// The producing stage's name and version (the render's key starts with them).
pub const STAGE: &str = "pc-raytrace";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Whether a render of `cfg` reads the radiosity artifact at `radiosity_path`.
fn reads_radiosity(cfg: &LoadedConfig, radiosity_path: &Path) -> bool {
    cfg.config.raytrace.mode != ShadingMode::Direct && radiosity_path.exists()
}

/// The render's key, written into the EXR: this stage's version and build, the keys of the
/// artifacts the render reads (octree; radiosity and photon map when it shows them), the
/// materials, lights, camera and every `raytrace` parameter, and the backend asked for. It
/// opens the input artifacts (validating them) but renders nothing.
pub fn render_key(
    cfg: &LoadedConfig,
    octree_path: &Path,
    radiosity_path: &Path,
    photons_path: &Path,
    backend: Backend,
) -> anyhow::Result<Key> {
    let art = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let c = &cfg.config;
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(&art.key());
    let input =
        |path: &Path, kind| -> anyhow::Result<Key> { Ok(Artifact::open_kind(path, kind)?.key()) };
    if reads_radiosity(cfg, radiosity_path) {
        h.update_str("radiosity")
            .update_key(&input(radiosity_path, ArtifactKind::Radiosity)?);
    }
    if photons_path.exists() {
        h.update_str("photons")
            .update_key(&input(photons_path, ArtifactKind::Photons)?);
    }
    h.update_serialize(&c.materials)
        .update_serialize(&c.lights)
        .update_serialize(&c.camera)
        .update_serialize(&c.raytrace)
        .update_serialize(&backend);
    Ok(h.finish())
}

/// The render scene of `cfg` (octree, materials, lights, camera, and the radiosity and photon
/// map it shows), handed to `f` with the shading mode (`auto` resolved); the artifacts stay
/// mapped while `f` runs.
///
/// Shading: `stored` shows the radiosity artifact at `radiosity_path` when it exists (else the
/// materials' emission alone); `auto` is `stored` when it exists and `direct` otherwise.
pub fn with_scene<R>(
    cfg: &LoadedConfig,
    octree_path: &Path,
    radiosity_path: &Path,
    photons_path: &Path,
    f: impl FnOnce(&mut RenderScene, ShadingMode) -> anyhow::Result<R>,
) -> anyhow::Result<R> {
    let art = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let view = OctreeView::from_artifact(&art)?;
    let materials = current_materials(cfg, &art)?;
    let c = &cfg.config;
    let camera = Camera::new(&c.camera);
    let mut rt = c.raytrace.clone();
    let radiance = match rt.mode {
        ShadingMode::Direct => None,
        ShadingMode::Stored | ShadingMode::Auto if reads_radiosity(cfg, radiosity_path) => {
            Some(load_radiosity(radiosity_path, &art)?)
        }
        ShadingMode::Stored | ShadingMode::Auto => None,
    };
    if rt.mode == ShadingMode::Auto {
        rt.mode = if radiance.is_some() {
            ShadingMode::Stored
        } else {
            ShadingMode::Direct
        };
    }
    let photons_art = if photons_path.exists() {
        Some(Artifact::open_kind(photons_path, ArtifactKind::Photons)?)
    } else {
        None
    };
    let radius = caustic_radius(&rt, &view);
    let mut sc = RenderScene::new(view, materials, &c.lights, &camera, &rt);
    if let Some(r) = &radiance {
        sc.set_radiance(r);
    }
    if let Some(a) = &photons_art {
        let c = load_photons(a, &art, radius, rt.caustic_k)?;
        // An empty map (a scene without specular surfaces) adds nothing.
        if !c.photons.is_empty() {
            sc.caustics = Some(c);
        }
    }
    f(&mut sc, rt.mode)
}

/// Renders frames of one scene on the backend asked for, keeping the GPU's buffers between
/// frames. With `auto`, a GPU that cannot take the scene (too large for its buffers, too few
/// bindings) falls back to the CPU with a warning; with `gpu` it is an error.
pub struct Renderer {
    gpu: Option<(pc_gpu::GpuContext, crate::gpu::render::GpuRenderer)>,
    /// `auto`: a GPU failure falls back to the CPU instead of failing.
    fallback: bool,
}

impl Renderer {
    pub fn new(sc: &mut RenderScene, backend: Backend) -> anyhow::Result<Renderer> {
        let ctx = match backend {
            Backend::Cpu => None,
            Backend::Gpu => Some(pc_gpu::GpuContext::new()?),
            // `auto` means a real GPU: a software rasterizer (llvmpipe) is slower than the CPU.
            Backend::Auto => pc_gpu::GpuContext::new().ok().filter(|g| !g.is_software()),
        };
        let gpu = match ctx {
            Some(ctx) => match crate::gpu::render::GpuRenderer::new(&ctx, sc) {
                Ok(r) => Some((ctx, r)),
                Err(e) if backend == Backend::Auto => {
                    eprintln!(
                        "pc-raytrace: warning: rendering on the CPU: the GPU {} cannot: {e}",
                        ctx.describe()
                    );
                    None
                }
                Err(e) => return Err(e.into()),
            },
            None => None,
        };
        if gpu.is_none() {
            sc.prepare_cpu();
        }
        Ok(Renderer {
            gpu,
            fallback: backend == Backend::Auto,
        })
    }

    /// Which device renders.
    pub fn device(&self) -> Device {
        if self.gpu.is_some() {
            Device::Gpu
        } else {
            Device::Cpu
        }
    }

    /// The device, in words.
    pub fn device_name(&self) -> String {
        match &self.gpu {
            Some((ctx, _)) => ctx.describe(),
            None => format!("CPU, {} threads", rayon::current_num_threads()),
        }
    }

    /// Render the scene's camera view (ray counts on the CPU only). With `auto`, a GPU that
    /// fails here is dropped with a warning and this and later frames render on the CPU.
    pub fn render(
        &mut self,
        sc: &mut RenderScene,
        aovs: bool,
        tile_done: &(dyn Fn() + Sync),
    ) -> anyhow::Result<(Image, Option<RayCounts>)> {
        if let Some((ctx, r)) = &self.gpu {
            match r.render(ctx, sc, aovs) {
                Ok(img) => return Ok((img, None)),
                Err(e) if self.fallback => {
                    eprintln!(
                        "pc-raytrace: warning: rendering on the CPU: the GPU {} failed: {e}",
                        ctx.describe()
                    );
                    self.gpu = None;
                    sc.prepare_cpu();
                }
                Err(e) => return Err(e.into()),
            }
        }
        let (img, counts) = crate::cpu::render(sc, aovs, tile_done);
        Ok((img, Some(counts)))
    }
}

/// Render the config's camera view of the octree at `octree_path` and write the images, the
/// EXR carrying `key` (see [`with_scene`] for the shading).
#[allow(clippy::too_many_arguments)]
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    radiosity_path: &Path,
    photons_path: &Path,
    exr: &Path,
    backend: Backend,
    key: Option<&Key>,
    tile_done: &(dyn Fn() + Sync),
    total_tiles: &mut dyn FnMut(u64),
) -> anyhow::Result<Summary> {
    let c = &cfg.config;
    let (mode, image, device, device_name, seconds, counts, caustics) = with_scene(
        cfg,
        octree_path,
        radiosity_path,
        photons_path,
        |sc, mode| {
            let t = Instant::now();
            let mut renderer = Renderer::new(sc, backend)?;
            if renderer.device() == Device::Cpu {
                total_tiles(
                    sc.params.width.div_ceil(16) as u64 * sc.params.height.div_ceil(16) as u64,
                );
            }
            let (image, counts) = renderer.render(sc, c.raytrace.aovs, tile_done)?;
            Ok((
                mode,
                image,
                renderer.device(),
                renderer.device_name(),
                t.elapsed().as_secs_f64(),
                counts,
                sc.caustics.is_some(),
            ))
        },
    )?;
    // The PNG first: the EXR carries the key, so a run killed between the two is redone.
    let png = exr.with_extension("png");
    write_png(&png, &image, c.raytrace.exposure)?;
    write_exr_keyed(exr, &image, key)?;
    Ok(Summary {
        mode,
        image,
        device,
        device_name,
        seconds,
        counts,
        caustics,
        exr: exr.to_path_buf(),
        png,
    })
}

/// The camera of frame `i` of `frames` on the walkthrough path: the config's camera orbiting
/// its target about its up axis, from −`orbit_deg`/2 to +`orbit_deg`/2, at the same distance
/// and field of view (the seed's interactive walkthrough, §10, as a fixed path).
pub fn walkthrough_camera(
    base: &pc_scene::config::CameraConfig,
    i: usize,
    frames: usize,
    orbit_deg: f32,
) -> pc_scene::config::CameraConfig {
    use glam::{Quat, Vec3};
    let t = if frames > 1 {
        i as f32 / (frames - 1) as f32
    } else {
        0.5
    };
    let angle = (t - 0.5) * orbit_deg.to_radians();
    let target = Vec3::from(base.target);
    let up = Vec3::from(base.up).normalize_or_zero();
    let offset = Vec3::from(base.origin) - target;
    let origin = target + Quat::from_axis_angle(up, angle) * offset;
    pc_scene::config::CameraConfig {
        origin: origin.into(),
        ..base.clone()
    }
}

/// What a walkthrough made.
pub struct Walkthrough {
    pub frames: Vec<PathBuf>,
    pub device: Device,
    pub device_name: String,
    /// Time spent rendering the frames (loading and GPU setup excluded).
    pub render_seconds: f64,
    /// Time spent writing the PNGs.
    pub write_seconds: f64,
    /// Loading the artifacts and setting up the renderer.
    pub setup_seconds: f64,
}

/// Render `frames` frames along [`walkthrough_camera`]'s path on the cached solution (the
/// artifacts are loaded once; the GPU keeps its buffers between frames) into
/// `dir/frame_00000.png`, ... (each written atomically); `frame_done` hears of each frame.
#[allow(clippy::too_many_arguments)]
pub fn walkthrough(
    cfg: &LoadedConfig,
    octree_path: &Path,
    radiosity_path: &Path,
    photons_path: &Path,
    dir: &Path,
    frames: usize,
    orbit_deg: f32,
    backend: Backend,
    frame_done: &mut dyn FnMut(usize),
) -> anyhow::Result<Walkthrough> {
    if frames == 0 {
        bail!("a walkthrough needs at least one frame");
    }
    let c = &cfg.config;
    let started = Instant::now();
    with_scene(cfg, octree_path, radiosity_path, photons_path, |sc, _| {
        let mut renderer = Renderer::new(sc, backend)?;
        let setup_seconds = started.elapsed().as_secs_f64();
        let (mut render_seconds, mut write_seconds) = (0.0, 0.0);
        let mut paths = Vec::with_capacity(frames);
        for i in 0..frames {
            let cam = walkthrough_camera(&c.camera, i, frames, orbit_deg);
            sc.set_camera(&Camera::new(&cam));
            let t = Instant::now();
            let (image, _) = renderer.render(sc, false, &|| {})?;
            render_seconds += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let path = dir.join(format!("frame_{i:05}.png"));
            write_png(&path, &image, c.raytrace.exposure)?;
            write_seconds += t.elapsed().as_secs_f64();
            paths.push(path);
            frame_done(i);
        }
        Ok(Walkthrough {
            frames: paths,
            device: renderer.device(),
            device_name: renderer.device_name(),
            render_seconds,
            write_seconds,
            setup_seconds,
        })
    })
}
