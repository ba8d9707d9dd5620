//! What a render needs besides the octree: current materials, point lights, the emitter
//! sampling table, the camera and the parameters, as plain records the GPU can take as they are.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_artifact::PointLight;
use pc_config::{RaytraceConfig, ShadingMode};
use rayon::prelude::*;

use crate::camera::Camera;
use pc_tree::accel::PackedLeaf;
use pc_tree::OctreeView;

/// Emitter splats with a cumulative distribution proportional to their emitted power
/// (luminance of the radiance times the area the splat stands for), for direct lighting.
#[derive(Clone, Debug, Default)]
pub struct EmitterTable {
    /// Data-pool indices of the emitting splats.
    pub splats: Vec<u32>,
    /// Inclusive CDF, last entry 1.
    pub cdf: Vec<f32>,
    /// Sum of the weights (luminance · area).
    pub total: f32,
}

fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

impl EmitterTable {
    pub fn new(view: &OctreeView, materials: &[MaterialRecord]) -> EmitterTable {
        // In parallel, and not at all without an emitting material (a scan lit by point lights:
        // at 20M points the pass over the splats was 4 % of pc-raytrace, on one core).
        let (splats, weights): (Vec<u32>, Vec<f64>) =
            match materials.iter().any(|m| m.class == class::EMITTER) {
                false => (Vec::new(), Vec::new()),
                true => view
                    .splats
                    .par_iter()
                    .enumerate()
                    .filter_map(|(i, s)| {
                        let m = &materials[s.material as usize];
                        let w = luminance(m.radiance) * view.splat_area[i];
                        (m.class == class::EMITTER && w > 0.0).then_some((i as u32, w as f64))
                    })
                    .unzip(),
            };
        let total: f64 = weights.iter().sum();
        let mut acc = 0.0f64;
        let cdf = weights
            .iter()
            .map(|w| {
                acc += w;
                (acc / total) as f32
            })
            .collect::<Vec<f32>>();
        let mut t = EmitterTable {
            splats,
            cdf,
            total: total as f32,
        };
        if let Some(last) = t.cdf.last_mut() {
            *last = 1.0;
        }
        t
    }

    /// Index into `splats` for a uniform number u in [0, 1): the first CDF entry > u.
    #[inline]
    pub fn pick(&self, u: f32) -> usize {
        self.cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len() - 1)
    }

    /// Probability of picking entry `k`.
    #[inline]
    pub fn pdf(&self, k: usize) -> f32 {
        self.cdf[k] - if k == 0 { 0.0 } else { self.cdf[k - 1] }
    }
}

/// Render parameters and camera as one uniform record (WGSL twin `Params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Params {
    pub cam_origin: [f32; 3],
    pub width: u32,
    pub cam_forward: [f32; 3],
    pub height: u32,
    pub cam_right: [f32; 3],
    pub spp: u32,
    pub cam_up: [f32; 3],
    pub max_bounces: u32,
    pub background: [f32; 3],
    /// 0 = stored, 1 = direct.
    pub mode: u32,
    pub tan_half: [f32; 2],
    pub self_hit: f32,
    pub blend_thickness: f32,
    pub light_samples: u32,
    pub light_count: u32,
    pub emitter_count: u32,
    pub seed: u32,
    /// First image row this dispatch renders (the GPU renders in bands).
    pub row_offset: u32,
    pub rows: u32,
    /// 1 when diffuse hits show [`RenderScene::radiance`].
    pub stored_radiance: u32,
    /// The photon map's grid ([`crate::caustic::PhotonGrid`]); `photon_count` 0: none.
    pub caustic_radius: f32,
    pub grid_origin: [f32; 3],
    pub grid_mask: u32,
    pub photon_count: u32,
    pub grid_cell: f32,
    /// 1: the GPU kernel writes each pixel's AOVs too (48 bytes), 0: its colour alone (16).
    pub aovs: u32,
    /// 1: the second pass of refined pixels ([`crate::refine`]): the kernel renders only the
    /// pixels whose output word's fourth lane the host set to [`crate::refine::MARK`].
    pub refine: u32,
    /// Dielectric hits per sample that take both ways out (`raytrace.splits`).
    pub splits: u32,
    /// The GPU kernel's samples this dispatch: `sample_count` of them from `sample_offset`,
    /// added to the sums a dispatch before left (0, 0 on the CPU, which takes all `spp`).
    pub sample_offset: u32,
    pub sample_count: u32,
    pub _pad: u32,
}

/// Everything a render reads.
pub struct RenderScene<'a> {
    pub view: OctreeView<'a>,
    /// Packed leaf lists for the CPU walk (built by [`RenderScene::prepare_cpu`]).
    pub accel: Option<pc_tree::accel::Accel<'a>>,
    pub materials: Vec<MaterialRecord>,
    pub lights: Vec<PointLight>,
    pub emitters: EmitterTable,
    pub params: Params,
    /// Per-splat outgoing diffuse radiance (pc-fmm's radiosity artifact, mapped); when present,
    /// diffuse hits show it instead of the materials' emission.
    pub radiance: Option<&'a [[f32; 3]]>,
    /// pc-caustics' photon map: diffuse hits add its density estimate.
    pub caustics: Option<crate::caustic::Caustics<'a>>,
    /// Each octree leaf's roughness (`pc_tree::between::leaf_roughness`, per node-pool slot)
    /// in `direct` mode, for the shadow rays' own zones; empty otherwise.
    pub rough: Vec<f32>,
    /// The second pass over high-contrast pixels ([`crate::refine`]).
    pub refine: crate::refine::Refine,
    /// Where the CPU's camera rays through each pixel start ([`crate::camera_near`]): made on
    /// first use for the camera of the moment where it pays, dropped when the camera moves.
    camera_near: std::sync::OnceLock<Option<Vec<f32>>>,
}

impl<'a> RenderScene<'a> {
    pub fn new(
        view: OctreeView<'a>,
        materials: Vec<MaterialRecord>,
        lights: &[PointLight],
        camera: &Camera,
        cfg: &RaytraceConfig,
    ) -> RenderScene<'a> {
        let emitters = EmitterTable::new(&view, &materials);
        let lights = lights.to_vec();
        let params = Params {
            cam_origin: camera.origin.into(),
            width: camera.width,
            cam_forward: camera.forward.into(),
            height: camera.height,
            cam_right: camera.right.into(),
            spp: cfg.spp,
            cam_up: camera.up.into(),
            max_bounces: cfg.max_bounces,
            splits: cfg.splits,
            background: cfg.background,
            mode: match cfg.mode {
                ShadingMode::Stored | ShadingMode::Auto => 0,
                ShadingMode::Direct => 1,
            },
            tan_half: [camera.tan_half.0, camera.tan_half.1],
            self_hit: cfg.self_hit,
            blend_thickness: cfg.blend_thickness,
            light_samples: cfg.light_samples,
            light_count: lights.len() as u32,
            emitter_count: emitters.splats.len() as u32,
            seed: cfg.seed,
            row_offset: 0,
            rows: camera.height,
            stored_radiance: 0,
            ..Default::default()
        };
        // The preview's shadow rays pass over their own surface's roughness, as pc-fmm's do.
        let rough = match params.mode {
            1 if !lights.is_empty() || params.emitter_count > 0 => {
                pc_tree::between::leaf_roughness(&view)
            }
            _ => Vec::new(),
        };
        RenderScene {
            view,
            accel: None,
            rough,
            materials,
            lights,
            emitters,
            params,
            radiance: None,
            caustics: None,
            refine: crate::refine::Refine {
                spp: cfg.refine_spp(),
                contrast: cfg.refine_contrast,
            },
            camera_near: std::sync::OnceLock::new(),
        }
    }

    /// Look through `camera` from now on (its size included).
    pub fn set_camera(&mut self, camera: &Camera) {
        let p = &mut self.params;
        p.cam_origin = camera.origin.into();
        p.cam_forward = camera.forward.into();
        p.cam_right = camera.right.into();
        p.cam_up = camera.up.into();
        p.tan_half = [camera.tan_half.0, camera.tan_half.1];
        p.width = camera.width;
        p.height = camera.height;
        p.rows = camera.height;
        self.camera_near = std::sync::OnceLock::new();
    }

    /// The least distance at which a camera ray through each pixel (row-major) can meet a
    /// splat ([`crate::camera_near::near_bounds`]), for the camera of the moment; None where
    /// the frame has too few camera samples for its splats ([`crate::camera_near::pays`]),
    /// whose rays start at the camera.
    pub fn camera_near(&self) -> Option<&[f32]> {
        self.camera_near
            .get_or_init(|| {
                let p = &self.params;
                let samples = u64::from(p.width) * u64::from(p.height) * u64::from(p.spp);
                crate::camera_near::pays(self.view.splats.len(), samples)
                    .then(|| crate::camera_near::near_bounds(&self.view, &self.camera()))
            })
            .as_deref()
    }

    /// The camera the parameters hold.
    pub fn camera(&self) -> Camera {
        let p = &self.params;
        Camera {
            origin: p.cam_origin.into(),
            forward: p.cam_forward.into(),
            right: p.cam_right.into(),
            up: p.cam_up.into(),
            tan_half: (p.tan_half[0], p.tan_half[1]),
            width: p.width,
            height: p.height,
        }
    }

    /// Show this per-splat radiance at diffuse hits (one RGB per data-pool splat).
    pub fn set_radiance(&mut self, radiance: &'a [[f32; 3]]) {
        self.radiance = Some(radiance);
        self.params.stored_radiance = 1;
    }

    /// Build the packed leaf lists the CPU renderer walks (same hits, faster).
    pub fn prepare_cpu(&mut self) {
        if self.accel.is_none() {
            self.accel = Some(pc_tree::accel::Accel::new(&self.view));
        }
    }

    /// Nearest hit, through the packed lists when prepared.
    #[inline]
    pub fn intersect(
        &self,
        ray: &pc_tree::Ray,
        st: &mut pc_tree::TraversalStats,
    ) -> Option<pc_tree::Hit> {
        match &self.accel {
            Some(a) => a.intersect(&self.view, ray, st),
            None => pc_tree::intersect(&self.view, ray, st),
        }
    }

    /// [`Self::intersect`], with where [`Self::covering`] finds the hit's leaf.
    #[inline]
    pub fn intersect_in(
        &self,
        ray: &pc_tree::Ray,
        st: &mut pc_tree::TraversalStats,
    ) -> Option<(pc_tree::Hit, Option<PackedLeaf>)> {
        match &self.accel {
            Some(a) => a
                .intersect_in(&self.view, ray, st)
                .map(|(h, l)| (h, Some(l))),
            None => pc_tree::intersect(&self.view, ray, st).map(|h| (h, None)),
        }
    }

    /// [`pc_tree::covering`] at a hit of [`Self::intersect_in`], through the packed lists when
    /// the hit came from them.
    #[inline]
    pub fn covering(
        &self,
        (hit, packed): (pc_tree::Hit, Option<PackedLeaf>),
        x: Vec3,
        n: Vec3,
        thickness: f32,
        out: &mut Vec<(u32, f32)>,
    ) {
        match (&self.accel, packed) {
            (Some(a), Some(l)) => a.covering(&self.view, l, x, n, thickness, out),
            _ => pc_tree::covering(&self.view, hit.leaf, x, n, thickness, out),
        }
    }

    /// Any hit, through the packed lists when prepared.
    #[inline]
    pub fn occluded(&self, ray: &pc_tree::Ray, st: &mut pc_tree::TraversalStats) -> bool {
        match &self.accel {
            Some(a) => a.occluded(&self.view, ray, st),
            None => pc_tree::occluded(&self.view, ray, st),
        }
    }

    /// A shadow ray leaving the surface of splat `own` (hit at the ray's origin): it passes
    /// over that surface's own roughness (`pc_tree::between`), through the packed lists when
    /// prepared. WGSL twin: `occluded_leaving` in shaders/raytrace/render.wgsl.
    #[inline]
    pub fn occluded_leaving(
        &self,
        ray: pc_tree::Ray,
        own: u32,
        st: &mut pc_tree::TraversalStats,
    ) -> bool {
        let seg =
            pc_tree::Between::leaving(ray, pc_tree::between::surface(&self.view, &self.rough, own));
        match &self.accel {
            Some(a) => a.occluded_between(&self.view, &seg, st),
            None => pc_tree::occluded_between(&self.view, &seg, st),
        }
    }

    /// The camera ray through film position (sx, sy) ∈ `[0, 1]²` (sx right, sy down).
    #[inline]
    pub fn camera_dir(&self, sx: f32, sy: f32) -> Vec3 {
        let p = &self.params;
        let x = (2.0 * sx - 1.0) * p.tan_half[0];
        let y = (1.0 - 2.0 * sy) * p.tan_half[1];
        (Vec3::from(p.cam_forward) + x * Vec3::from(p.cam_right) + y * Vec3::from(p.cam_up))
            .normalize()
    }
}
