//! The linear system of the radiosity solve, `L = E + ρ ∘ T (L − Lₑ)`: per splat its albedo,
//! its emission and the source term E with the point lights' direct light (shadows from the
//! V-map's light lists and shadow rays where a node is partly lit). The emitting splats' direct
//! light is added by [`crate::emitter`].

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_artifact::vmap::VmapView;
use pc_artifact::PointLight;
use pc_gpu::GpuError;
use pc_tree::caster::Caster;
use pc_tree::{Between, OctreeView, Ray};
use rayon::prelude::*;

use crate::tree::Points;

/// The per-splat terms of the equation `L = E + ρ ∘ T (L − Lₑ)`.
///
/// `E = Lₑ + D`: the emitted radiance and the reflected direct light `D` of the point lights
/// and of the emitting splats (shadow rays), and of caustic photons when given. The operator
/// transports only the reflected part `L − Lₑ`: the first bounce off the emitters is already
/// in `D`, resolved per splat by rays rather than by the V-map's node-level fractions. With
/// `D = ρ T Lₑ` exactly, this is `L = Lₑ + ρ T L`.
#[derive(Clone, Debug, Default)]
pub struct System {
    /// Source term E.
    pub source: Vec<[f32; 3]>,
    /// Emitted radiance Lₑ.
    pub emission: Vec<[f32; 3]>,
    /// Diffuse reflectance ρ per splat (zero for specular splats).
    pub albedo: Vec<[f32; 3]>,
}

impl System {
    /// `n` splats with no source, no emission and no albedo.
    pub fn zeros(n: usize) -> System {
        System {
            source: vec![[0.0; 3]; n],
            emission: vec![[0.0; 3]; n],
            albedo: vec![[0.0; 3]; n],
        }
    }
}

/// What the point lights' direct light takes from the V-map: which nodes each light sees.
#[derive(Clone, Copy, Debug)]
pub struct LightLists<'a> {
    /// The V-map's lists (`light_list(l)`: `(slot, fraction)` for each V-map leaf that sees
    /// light `l`) and the nodes' splat ranges.
    pub vmap: &'a VmapView<'a>,
    /// Shadow rays ignore hits within this many radii of the splat they leave (the V-map's).
    pub self_hit: f32,
    /// Each octree leaf's roughness, for the shadow rays' own zones.
    pub rough: &'a pc_tree::between::LazyRoughness<'a>,
}

/// Shadow rays cast at once (a batch is large enough to keep a GPU busy).
const SHADOW_BATCH: usize = 1 << 20;

/// Build the system: albedo from the materials, E from emission and the point lights' direct
/// light.
///
/// A splat outside every node of a light's list is in its shadow; one in a node seen whole is
/// lit; one in a partly seen node casts its own shadow ray (from its centre, ignoring hits
/// within `self_hit` radii).
pub fn system(
    view: &OctreeView,
    materials: &[MaterialRecord],
    pts: &Points,
    lights: &[PointLight],
    seen: LightLists,
    tester: &dyn Caster,
) -> Result<System, GpuError> {
    let n = view.splats.len();
    let mut sys = System::zeros(n);
    sys.albedo
        .par_iter_mut()
        .zip(sys.source.par_iter_mut())
        .zip(sys.emission.par_iter_mut())
        .zip(view.splats.par_iter().zip(&pts.active))
        .for_each(|(((albedo, source), emission), (s, &active))| {
            if !active {
                return;
            }
            let m = &materials[s.material as usize];
            *albedo = (Vec3::from(m.color) * Vec3::from(s.albedo)).into();
            if m.class == class::EMITTER {
                (*source, *emission) = (m.radiance, m.radiance);
            }
        });
    for (l, light) in lights.iter().enumerate() {
        let rough = seen.rough.get();
        let light_position = Vec3::from(light.position);
        let list = seen.vmap.light_list(l);
        let mut partial: Vec<u32> = Vec::new();
        let mut lit: Vec<u32> = Vec::new();
        for link in list {
            let [lo, hi] = seen.vmap.node_range[link.slot() as usize];
            if link.fraction >= 1.0 {
                lit.extend(lo..hi);
            } else if link.fraction > 0.0 {
                partial.extend(lo..hi);
            }
        }
        // In batches: a 20M-splat scan's rays for one light took 0.7 GB at once.
        for batch in partial.chunks(SHADOW_BATCH) {
            // The shadow rays made in parallel, in the batch's order.
            let (rays, who): (Vec<Between>, Vec<u32>) = batch
                .par_iter()
                .filter_map(|&i| {
                    let s = &view.splats[i as usize];
                    let x = Vec3::from(s.position);
                    let d = light_position - x;
                    let len = d.length();
                    if len <= 0.0 || !pts.active[i as usize] || Vec3::from(s.normal).dot(d) <= 0.0 {
                        return None;
                    }
                    let ray = Ray {
                        origin: x,
                        dir: d / len,
                        t_min: seen.self_hit * s.radius,
                        t_max: len * (1.0 - 1e-4),
                    };
                    // Past the splat's own rough surface, like the V-map's light lists.
                    let seg = Between::leaving(ray, pc_tree::between::surface(view, rough, i));
                    Some((seg, i))
                })
                .unzip();
            let vis = tester.visible_between(&rays)?;
            lit.extend(who.iter().zip(&vis).filter(|(_, &v)| v).map(|(&i, _)| i));
        }
        // Each lit splat's share worked out in parallel, then added in the same order.
        let adds: Vec<(u32, Vec3)> = lit
            .par_iter()
            .filter_map(|&i| {
                let iu = i as usize;
                if !pts.active[iu] {
                    return None;
                }
                let s = &view.splats[iu];
                let d = light_position - Vec3::from(s.position);
                let r2 = d.length_squared();
                let cos = Vec3::from(s.normal).dot(d) / r2.sqrt();
                if cos <= 0.0 || r2 <= 0.0 {
                    return None;
                }
                // Reflected radiance ρ E / π with irradiance E = I cos / r².
                let e = Vec3::from(light.intensity) * (cos / r2) * std::f32::consts::FRAC_1_PI;
                Some((i, Vec3::from(sys.albedo[iu]) * e))
            })
            .collect();
        for (i, add) in adds {
            let iu = i as usize;
            sys.source[iu] = (Vec3::from(sys.source[iu]) + add).into();
        }
    }
    Ok(sys)
}
