//! The CPU renderer (rayon over 16×16 tiles): the reference twin of shaders/raytrace/render.wgsl.
//!
//! One path per pixel sample: the camera ray, then specular bounces (mirror reflection;
//! dielectric reflection and refraction, both at the first `splits` glass hits, weighted by
//! Fresnel, then one chosen by Fresnel; total internal reflection) up to `max_bounces`, each
//! branch ending at the first diffuse or emitting splat, whose blended stored radiance (and in
//! `direct` mode its direct lighting, with shadow rays) is its share of the sample's value. See
//! docs/raytrace.md.

use std::f32::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;
use pc_artifact::octree::class;
use pc_tree::{Ray, TraversalStats};
use rayon::prelude::*;

use crate::image::{Aovs, Image};
use crate::sample::{dim, pixel_offset, rand};
use crate::scene::RenderScene;

/// One traced sample: its radiance and what the first hit looked like.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SampleResult {
    pub rgb: Vec3,
    /// Distance to the first hit (0 when the camera ray leaves the scene).
    pub depth: f32,
    /// Shading normal at the first hit.
    pub normal: Vec3,
    /// Albedo / reflectance / tint at the first hit.
    pub albedo: Vec3,
    /// Source index of the first splat hit, `u32::MAX` for none.
    pub splat: u32,
}

/// Ray counts, for benchmarks.
#[derive(Clone, Copy, Debug, Default)]
pub struct RayCounts {
    pub camera: u64,
    pub bounce: u64,
    pub shadow: u64,
    pub traversal: TraversalStats,
}

pub use pc_tree::optics::{
    dielectric_split, fresnel, reflect, refract, shading_normal, specular_bounce,
};

/// Trace sample `k` of `spp` of a pixel (its position in the pixel from the pattern of `spp`
/// samples): the camera path, then the refracted branches of its splits at dielectrics, last
/// split first (docs/raytrace.md, "Splitting at glass"). `blend` is scratch for the splats
/// blended at a hit, reused from sample to sample.
#[inline]
pub fn trace_sample(
    sc: &RenderScene,
    (px, py, k, spp): (u32, u32, u32, u32),
    counts: &mut RayCounts,
    blend: &mut Vec<(u32, f32)>,
) -> SampleResult {
    let p = &sc.params;
    let pixel = py * p.width + px;
    let (ox, oy) = pixel_offset(p.seed, pixel, k, spp);
    let dir = sc.camera_dir(
        (px as f32 + ox) / p.width as f32,
        (py as f32 + oy) / p.height as f32,
    );
    let mut out = SampleResult {
        splat: u32::MAX,
        ..Default::default()
    };
    counts.camera += 1;
    let mut path = Path {
        at: SampleAt {
            pixel,
            k,
            bounce: 0,
        },
        pending: Branches::default(),
        splits: 0,
    };
    // The walk starts where a ray through this pixel can first meet a splat (the same hit).
    let camera_ray = Ray {
        t_min: sc.camera_near().map_or(0.0, |near| near[pixel as usize]),
        ..Ray::new(Vec3::from(p.cam_origin), dir)
    };
    path.pending.push((camera_ray, Vec3::ONE, 0));
    while let Some(branch) = path.pending.pop() {
        path.follow(sc, branch, &mut out, counts, blend);
    }
    out
}

/// One camera sample's paths: where its random numbers come from, the branches waiting and the
/// splits made.
struct Path {
    at: SampleAt,
    pending: Branches,
    splits: u32,
}

impl Path {
    /// Follows one branch (its ray, throughput and first bounce) through specular bounces to
    /// its end, adding what it sees to `out`; a split at a dielectric follows the reflection
    /// and leaves the refraction in `pending`. (Kept out of line, and [`trace_sample`] inlined
    /// into the pixel loop: the other way round the default scene rendered 10 % slower.)
    #[inline(never)]
    fn follow(
        &mut self,
        sc: &RenderScene,
        (mut ray, mut throughput, first): (Ray, Vec3, u32),
        out: &mut SampleResult,
        counts: &mut RayCounts,
        blend: &mut Vec<(u32, f32)>,
    ) {
        let p = &sc.params;
        let view = &sc.view;
        for bounce in first..=p.max_bounces {
            if bounce > 0 {
                counts.bounce += 1;
            }
            let Some(found) = sc.intersect_in(&ray, &mut counts.traversal) else {
                out.rgb += throughput * Vec3::from(p.background);
                return;
            };
            let hit = found.0;
            let s = &view.splats[hit.splat as usize];
            let m = &sc.materials[s.material as usize];
            let x = ray.origin + ray.dir * hit.t;
            let delta = p.self_hit * s.radius;
            if !class::is_specular(m.class) {
                let at = SampleAt { bounce, ..self.at };
                shade_diffuse(sc, (found, &ray, x), throughput, at, out, counts, blend);
                return;
            }
            let n = shading_normal(view, hit.splat, x);
            let color = Vec3::from(m.color) * Vec3::from(s.albedo);
            if bounce == 0 {
                out.depth = hit.t;
                out.normal = n;
                out.albedo = color;
                out.splat = s.source;
            }
            let nf = if ray.dir.dot(n) < 0.0 { n } else { -n };
            if m.phong > 0.0 {
                out.rgb += throughput * color * phong(sc, x, nf, -ray.dir, m.phong, delta, counts);
            }
            let leave = |dir| Ray {
                origin: x,
                dir,
                t_min: delta,
                t_max: f32::INFINITY,
            };
            let halves = match (m.class, self.splits < p.splits) {
                (class::DIELECTRIC, true) => dielectric_split(view, m, (hit.splat, n), ray.dir),
                _ => None,
            };
            let b = match halves {
                Some([reflected, refracted]) => {
                    self.splits += 1;
                    let branch = (
                        leave(refracted.dir),
                        throughput * refracted.tint,
                        bounce + 1,
                    );
                    self.pending.push(branch);
                    reflected
                }
                None => {
                    let u = match m.class {
                        class::MIRROR => 0.0,
                        _ => rand(p.seed, self.at.pixel, self.at.k, dim(bounce, 0)),
                    };
                    specular_bounce(view, m, (hit.splat, n), ray.dir, u)
                }
            };
            throughput *= b.tint;
            ray = leave(b.dir);
        }
    }
}

/// A diffuse or emitting hit ends its branch: one-sided, black from behind; from the front the
/// blend of every splat of its surface that covers the hit point `x` (§8.5.8), their stored
/// radiance or emission, the caustic estimate and in direct mode the direct light, times
/// `throughput`, added to `out` (and at bounce 0 its AOVs). WGSL twin: `shade_diffuse`.
fn shade_diffuse(
    sc: &RenderScene,
    (found, ray, x): (
        (pc_tree::Hit, Option<pc_tree::accel::PackedLeaf>),
        &Ray,
        Vec3,
    ),
    throughput: Vec3,
    at: SampleAt,
    out: &mut SampleResult,
    counts: &mut RayCounts,
    blend: &mut Vec<(u32, f32)>,
) {
    let p = &sc.params;
    let view = &sc.view;
    let hit = found.0;
    let s = &view.splats[hit.splat as usize];
    let m = &sc.materials[s.material as usize];
    let ns = Vec3::from(s.normal);
    if ray.dir.dot(ns) >= 0.0 {
        if at.bounce == 0 {
            out.depth = hit.t;
            out.normal = ns;
            out.splat = s.source;
        }
        return;
    }
    sc.covering(found, x, ns, p.blend_thickness, blend);
    if blend.is_empty() {
        blend.push((hit.splat, 1.0));
    }
    let (mut wsum, mut albedo, mut emit, mut nsum) = (0.0f32, Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
    for &(j, w) in blend.iter() {
        let sj = &view.splats[j as usize];
        let mj = &sc.materials[sj.material as usize];
        wsum += w;
        albedo += w * Vec3::from(mj.color) * Vec3::from(sj.albedo);
        if let Some(rad) = &sc.radiance {
            emit += w * Vec3::from_slice(&rad[j as usize][..3]);
        } else if mj.class == class::EMITTER {
            emit += w * Vec3::from(mj.radiance);
        }
        nsum += w * Vec3::from(sj.normal);
    }
    if wsum <= 0.0 {
        // Only possible exactly at the hit disk's rim: fall back to the hit splat.
        wsum = 1.0;
        albedo = Vec3::from(m.color) * Vec3::from(s.albedo);
        emit = if let Some(rad) = &sc.radiance {
            Vec3::from_slice(&rad[hit.splat as usize][..3])
        } else if m.class == class::EMITTER {
            Vec3::from(m.radiance)
        } else {
            Vec3::ZERO
        };
        nsum = ns;
    }
    albedo /= wsum;
    emit /= wsum;
    let n = nsum.normalize_or(ns);
    if at.bounce == 0 {
        out.depth = hit.t;
        out.normal = n;
        out.albedo = albedo;
        out.splat = s.source;
    }
    out.rgb += throughput * emit;
    if let Some(c) = &sc.caustics {
        out.rgb += throughput * albedo / PI * c.irradiance(x, n);
    }
    if p.mode == 1 {
        out.rgb += throughput * albedo / PI
            * direct(sc, (x, n, p.self_hit * s.radius, hit.splat), at, counts);
    }
}

/// A camera sample's branches waiting to be traced: the path, then the refracted branch of
/// each split (at most [`pc_config::MAX_SPLITS`] of them at once: the path is taken out before
/// its first split), last in first out. WGSL twin: `Slots`, shaders/raytrace/render.wgsl.
#[derive(Default)]
struct Branches {
    len: usize,
    items: [Option<(Ray, Vec3, u32)>; pc_config::MAX_SPLITS as usize],
}

impl Branches {
    fn push(&mut self, branch: (Ray, Vec3, u32)) {
        self.items[self.len] = Some(branch);
        self.len += 1;
    }

    fn pop(&mut self) -> Option<(Ray, Vec3, u32)> {
        self.len = self.len.checked_sub(1)?;
        self.items[self.len].take()
    }
}

/// Which of the sample pattern's random numbers a shading point draws: its pixel, the sample
/// within the pixel and the bounce it is at.
#[derive(Clone, Copy, Debug)]
pub struct SampleAt {
    pub pixel: u32,
    pub k: u32,
    pub bounce: u32,
}

/// Irradiance at `x` (normal `n`, on the splat `own`; shadow rays start `delta` from it and
/// pass over that splat's own rough surface, [`RenderScene::occluded_leaving`]) from the point
/// lights and the emitting splats, with shadow rays. Emitters are sampled in proportion to power; a point
/// uniform on the chosen disk stands for the splat's area (`splat_area`), so the estimator is
/// unbiased for the union of the disks.
pub fn direct(
    sc: &RenderScene,
    (x, n, delta, own): (Vec3, Vec3, f32, u32),
    at: SampleAt,
    counts: &mut RayCounts,
) -> Vec3 {
    let SampleAt { pixel, k, bounce } = at;
    let p = &sc.params;
    let view = &sc.view;
    let mut e = Vec3::ZERO;
    for l in &sc.lights {
        let to = Vec3::from(l.position) - x;
        let d2 = to.length_squared();
        let d = d2.sqrt();
        let dir = to / d;
        let cos = n.dot(dir);
        if cos > 0.0 {
            counts.shadow += 1;
            let shadow = Ray {
                origin: x,
                dir,
                t_min: delta,
                t_max: d * (1.0 - 1e-4),
            };
            if !sc.occluded_leaving(shadow, own, &mut counts.traversal) {
                e += Vec3::from(l.intensity) * cos / d2;
            }
        }
    }
    if p.emitter_count > 0 {
        let inv_n = 1.0 / p.light_samples as f32;
        for i in 0..p.light_samples {
            let u0 = rand(p.seed, pixel, k, dim(bounce, 1 + 3 * i));
            let u1 = rand(p.seed, pixel, k, dim(bounce, 2 + 3 * i));
            let u2 = rand(p.seed, pixel, k, dim(bounce, 3 + 3 * i));
            let ke = sc.emitters.pick(u0);
            let j = sc.emitters.splats[ke] as usize;
            let sj = &view.splats[j];
            let y = pc_tree::disk_point(sj, u1, u2);
            let to = y - x;
            let d2 = to.length_squared();
            let d = d2.sqrt();
            let dir = to / d;
            let cos_x = n.dot(dir);
            let cos_y = -Vec3::from(sj.normal).dot(dir);
            if cos_x > 0.0 && cos_y > 0.0 {
                counts.shadow += 1;
                let shadow = Ray {
                    origin: x,
                    dir,
                    t_min: delta,
                    t_max: d - p.self_hit * sj.radius,
                };
                if !sc.occluded_leaving(shadow, own, &mut counts.traversal) {
                    let pdf_area = sc.emitters.pdf(ke) / view.splat_area[j];
                    let radiance = Vec3::from(sc.materials[sj.material as usize].radiance);
                    e += radiance * (cos_x * cos_y / (d2 * pdf_area)) * inv_n;
                }
            }
        }
    }
    e
}

/// Normalised Phong highlight (exponent `exp`) of the point lights seen from `x`, towards `wo`.
fn phong(
    sc: &RenderScene,
    x: Vec3,
    n: Vec3,
    wo: Vec3,
    exp: f32,
    delta: f32,
    counts: &mut RayCounts,
) -> Vec3 {
    let mut out = Vec3::ZERO;
    for l in &sc.lights {
        let to = Vec3::from(l.position) - x;
        let d2 = to.length_squared();
        let d = d2.sqrt();
        let dir = to / d;
        let cos = n.dot(dir);
        if cos <= 0.0 {
            continue;
        }
        let spec = reflect(-dir, n).dot(wo).max(0.0).powf(exp) * (exp + 2.0) / (2.0 * PI);
        if spec <= 0.0 {
            continue;
        }
        counts.shadow += 1;
        let shadow = Ray {
            origin: x,
            dir,
            t_min: delta,
            t_max: d * (1.0 - 1e-4),
        };
        if !sc.occluded(&shadow, &mut counts.traversal) {
            out += Vec3::from(l.intensity) * spec * cos / d2;
        }
    }
    out
}

/// Render the whole image on the CPU. `tile_done` is called after each 16×16 tile.
pub fn render(
    sc: &RenderScene,
    with_aovs: bool,
    tile_done: &(dyn Fn() + Sync),
) -> (Image, RayCounts) {
    let (w, h) = (sc.params.width, sc.params.height);
    const TILE: u32 = 16;
    let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE))
        .flat_map(|ty| (0..w.div_ceil(TILE)).map(move |tx| (tx, ty)))
        .collect();
    let totals = Totals::default();
    // The camera rays' bounds before the tiles: made inside them, the pass would run on the
    // one worker that asked first while the others wait.
    sc.camera_near();
    let results: Vec<Vec<(u32, SampleResult)>> = tiles
        .par_iter()
        .with_max_len(1)
        .map(|&(tx, ty)| {
            let mut counts = RayCounts::default();
            let mut blend = Vec::new();
            let mut px = Vec::with_capacity((TILE * TILE) as usize);
            for y in ty * TILE..((ty + 1) * TILE).min(h) {
                for x in tx * TILE..((tx + 1) * TILE).min(w) {
                    let spp = sc.params.spp;
                    px.push((y * w + x, pixel(sc, (x, y, spp), &mut counts, &mut blend)));
                }
            }
            add_counts(&totals, &counts);
            tile_done();
            px
        })
        .collect();
    let mut img = Image::new(w, h);
    let mut aovs = with_aovs.then(|| Aovs {
        depth: vec![0.0; (w * h) as usize],
        normal: vec![[0.0; 3]; (w * h) as usize],
        albedo: vec![[0.0; 3]; (w * h) as usize],
        splat: vec![u32::MAX; (w * h) as usize],
    });
    for tile in results {
        for (i, r) in tile {
            img.rgb[i as usize] = r.rgb.into();
            if let Some(a) = aovs.as_mut() {
                a.depth[i as usize] = r.depth;
                a.normal[i as usize] = r.normal.into();
                a.albedo[i as usize] = r.albedo.into();
                a.splat[i as usize] = r.splat;
            }
        }
    }
    img.aovs = aovs;
    (img, total_counts(&totals))
}

/// Pixel (x, y): the mean of its `spp` samples, with the first sample's AOVs.
fn pixel(
    sc: &RenderScene,
    (x, y, spp): (u32, u32, u32),
    counts: &mut RayCounts,
    blend: &mut Vec<(u32, f32)>,
) -> SampleResult {
    let mut acc = Vec3::ZERO;
    let mut first = SampleResult::default();
    for k in 0..spp {
        let r = trace_sample(sc, (x, y, k, spp), counts, blend);
        acc += r.rgb;
        if k == 0 {
            first = r;
        }
    }
    first.rgb = acc / spp as f32;
    first
}

/// The colours of `pixels` (row-major indices) at `spp` samples each (the pattern of `spp`): the
/// second pass of [`crate::refine`], in parallel over runs of pixels.
pub fn render_pixels(sc: &RenderScene, pixels: &[u32], spp: u32) -> (Vec<[f32; 3]>, RayCounts) {
    let totals = Totals::default();
    sc.camera_near(); // before the workers, as in [`render`]
    let w = sc.params.width;
    let rgb = pixels
        .par_chunks(64)
        .flat_map_iter(|run| {
            let (mut counts, mut blend) = (RayCounts::default(), Vec::new());
            let out: Vec<[f32; 3]> = run
                .iter()
                .map(|&i| {
                    pixel(sc, (i % w, i / w, spp), &mut counts, &mut blend)
                        .rgb
                        .into()
                })
                .collect();
            add_counts(&totals, &counts);
            out
        })
        .collect();
    (rgb, total_counts(&totals))
}

/// Ray counts summed over threads.
type Totals = [AtomicU64; 5];

fn add_counts(totals: &Totals, counts: &RayCounts) {
    for (t, v) in totals.iter().zip([
        counts.camera,
        counts.bounce,
        counts.shadow,
        counts.traversal.cells,
        counts.traversal.splat_tests,
    ]) {
        t.fetch_add(v, Ordering::Relaxed);
    }
}

fn total_counts(totals: &Totals) -> RayCounts {
    RayCounts {
        camera: totals[0].load(Ordering::Relaxed),
        bounce: totals[1].load(Ordering::Relaxed),
        shadow: totals[2].load(Ordering::Relaxed),
        traversal: TraversalStats {
            cells: totals[3].load(Ordering::Relaxed),
            splat_tests: totals[4].load(Ordering::Relaxed),
        },
    }
}

impl RayCounts {
    /// Both passes' counts.
    pub fn plus(self, o: RayCounts) -> RayCounts {
        RayCounts {
            camera: self.camera + o.camera,
            bounce: self.bounce + o.bounce,
            shadow: self.shadow + o.shadow,
            traversal: TraversalStats {
                cells: self.traversal.cells + o.traversal.cells,
                splat_tests: self.traversal.splat_tests + o.traversal.splat_tests,
            },
        }
    }
}
