//! The pc-caustics stage: octree + V-map artifacts + config → `photons` artifact.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use pc_artifact::octree::{class, OctreeFile};
use pc_artifact::params::CausticsParams;
use pc_artifact::photons::{sections, Photon, PhotonsFile, PhotonsMeta};
use pc_artifact::specular::{self as spec, SpecularMeta};
use pc_artifact::vmap::VmapFile;
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_config::{Backend, LoadedConfig};
use pc_stage::{Progress, Stage};
use pc_tree::accel::Accel;
use pc_tree::between::leaf_roughness;
use pc_tree::TraversalStats;
use rayon::prelude::*;

use crate::emit::{self, Aim, Leaves};
use crate::error::CausticsError;
use crate::links;
use crate::trace::{Fate, Tracer};

pub const STAGE: &str = "pc-caustics";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// What one run made.
pub struct Summary {
    pub path: PathBuf,
    pub meta: PhotonsMeta,
    pub seconds: f64,
}

/// The traced photons and their counts.
#[derive(Debug, Default)]
pub struct Traced {
    pub photons: Vec<Photon>,
    /// The id of each stored photon (its aim: the last whose first id is not above it).
    pub id: Vec<u32>,
    pub traced: u64,
    pub occluded: u64,
    pub lost: u64,
}

/// Trace every photon of `aims` (rayon across photons); photon `id`s run over the aims in
/// order, so the result does not depend on the thread count. `progress` gets the photons done.
pub fn trace_all(tracer: &Tracer, aims: &[Aim], progress: &(dyn Fn(u64) + Sync)) -> Traced {
    let first = emit::first_ids(aims);
    let total = first[aims.len()];
    const CHUNK: u64 = 1 << 14;
    // One chunk a task (rayon's default split leaves a quarter of the chunks to a task that
    // cannot be shared, and chunks of glass paths cost far more than others).
    let chunks: Vec<Traced> = (0..total.div_ceil(CHUNK) as usize)
        .into_par_iter()
        .with_max_len(1)
        .map(|c| {
            let c = c as u64;
            let mut out = Traced::default();
            let mut st = TraversalStats::default();
            let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(total));
            let mut a = first.partition_point(|&f| f <= lo) - 1;
            for id in lo..hi {
                while first[a + 1] <= id {
                    a += 1;
                }
                out.traced += 1;
                match tracer.photon(&aims[a], id as u32, &mut st) {
                    Fate::Stored(p) => {
                        out.photons.push(p);
                        out.id.push(id as u32);
                    }
                    Fate::Occluded => out.occluded += 1,
                    Fate::Lost | Fate::Absorbed => out.lost += 1,
                }
            }
            progress(hi - lo);
            out
        })
        .collect();
    let (photons, id): (Vec<_>, Vec<_>) =
        chunks.iter().map(|c| (&c.photons[..], &c.id[..])).unzip();
    Traced {
        photons: concat(&photons),
        id: concat(&id),
        traced: chunks.iter().map(|c| c.traced).sum(),
        occluded: chunks.iter().map(|c| c.occluded).sum(),
        lost: chunks.iter().map(|c| c.lost).sum(),
    }
}

/// The parts one after another in one vector, copied in parallel (a part a task): appended on
/// one thread, the millions of paths' records held the other core idle.
pub(crate) fn concat<T: Copy + Send + Sync>(parts: &[impl AsRef<[T]> + Sync]) -> Vec<T> {
    let total = parts.iter().map(|p| p.as_ref().len()).sum();
    let Some(fill) = parts.iter().find_map(|p| p.as_ref().first().copied()) else {
        return Vec::new();
    };
    let mut out = Vec::with_capacity(total);
    out.par_extend(rayon::iter::repeat_n(fill, total));
    let mut rest = &mut out[..];
    let mut pieces = Vec::with_capacity(parts.len());
    for p in parts {
        let (here, after) = rest.split_at_mut(p.as_ref().len());
        pieces.push((here, p.as_ref()));
        rest = after;
    }
    pieces
        .into_par_iter()
        .for_each(|(to, from)| to.copy_from_slice(from));
    out
}

/// Power deposited per splat (W, RGB).
pub fn deposit(splats: usize, photons: &[Photon]) -> Vec<[f32; 3]> {
    let mut d = vec![[0.0f32; 3]; splats];
    for p in photons {
        for (e, &w) in d[p.splat as usize].iter_mut().zip(&p.power) {
            *e += w;
        }
    }
    d
}

/// Run the stage; `progress` counts the photons traced.
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    vmap_path: &Path,
    out: &Path,
    backend: Backend,
    progress: &dyn Progress,
) -> Result<Summary, CausticsError> {
    pc_stage::look_early(backend, pc_stage::Work::Precompute);
    let started = Instant::now();
    let mut timings = Vec::new();
    let octree = OctreeFile::open(octree_path)?;
    let view = octree.view();
    let lights = &cfg.config.lights;
    let vmap = VmapFile::open(vmap_path, &octree.id(), lights)?;
    let materials = cfg.materials_for(&octree)?;
    let p = cfg.config.caustics.params;

    progress.phase("emission");
    let t = Instant::now();
    let leaves = Leaves::new(&view, &materials);
    let plan = emit::plan(&view, &materials, &leaves, lights, &vmap.view());
    let aims = emit::aims(&plan, p.photons, p.seed);
    let aimed: Vec3 = aims
        .iter()
        .map(|a| Vec3::from(a.power) * a.photons as f32)
        .sum();
    let total: u64 = aims.iter().map(|a| a.photons as u64).sum();
    timings.push(("emission".to_string(), t.elapsed().as_secs_f64()));

    let t = Instant::now();
    // Rays leaving a splat pass over its own rough surface within its own zone. Photons and
    // paths are traced toward specular surfaces only: a scene without any (a scan) needs
    // neither the roughness nor the leaves' surfaces, which read every splat.
    let specular = leaves.leaves.iter().any(|l| class::is_specular(l.class));
    let (rough, accel) = match specular {
        true => (
            leaf_roughness(&view),
            Accel::new(&view).with_own_surfaces(&view),
        ),
        false => (Vec::new(), Accel::new(&view)),
    };
    let scene = links::Scene {
        view: &view,
        accel: &accel,
        rough: &rough,
    };
    let spec_key = specular_key(&octree.key(), &vmap.meta().links_key, &p, &materials);
    let reused = reusable(out, &spec_key, view.splats.len());
    let spec_aims = match reused {
        Some(_) => Vec::new(),
        None => links::aims(scene, &leaves, &vmap.view(), p.specular_paths, p.seed),
    };
    let spec_total: u64 = spec_aims.iter().map(|a| a.photons as u64).sum();
    // Apart from the tracing, so that its rate counts the paths' time alone.
    timings.push(("setup".to_string(), t.elapsed().as_secs_f64()));
    let t = Instant::now();
    let start_tracing = || {
        progress.phase("photons and specular links");
        progress.total(total + spec_total);
    };
    let advance = |n| progress.advance(n);
    let ((traced, spec), device) = pc_stage::gpu_or_cpu(
        STAGE,
        backend,
        pc_stage::Work::Precompute,
        |ctx| {
            start_tracing();
            let g = crate::gpu::GpuTracer::new(
                &ctx,
                (&view, &rough),
                &materials,
                &leaves,
                p.max_bounces,
                p.seed,
            )?;
            let both = (
                g.trace_all(&ctx, &aims, &advance)?,
                g.trace_all(&ctx, &spec_aims, &advance)?,
            );
            Ok::<_, CausticsError>((both, ctx.describe()))
        },
        || {
            start_tracing();
            let tracer = Tracer {
                view: &view,
                accel: &accel,
                materials: &materials,
                leaves: &leaves,
                max_bounces: p.max_bounces,
                rough: &rough,
                seed: p.seed,
            };
            let both = (
                trace_all(&tracer, &aims, &advance),
                trace_all(&tracer, &spec_aims, &advance),
            );
            Ok((
                both,
                format!("CPU ({} threads)", rayon::current_num_threads()),
            ))
        },
    )?;
    timings.push(("trace".to_string(), t.elapsed().as_secs_f64()));

    let t = Instant::now();
    let (links, mut spec_meta) = match reused {
        Some(r) => r,
        None => {
            progress.phase("specular links");
            let l = links::build(
                scene,
                &materials,
                &leaves,
                &spec_aims,
                &spec,
                p.specular_gather,
                p.seed,
            );
            let m = SpecularMeta {
                key: spec_key.to_string(),
                paths: spec.traced,
                stored: spec.photons.len() as u64,
                occluded: spec.occluded,
                lost: spec.lost,
                ..Default::default()
            };
            (l, m)
        }
    };
    spec_meta.bins = links.flux_offsets.len().saturating_sub(1) as u64;
    spec_meta.flux_links = links.flux.len() as u64;
    spec_meta.smooth_links = links.smooth.len() as u64;
    spec_meta.gather_links = links.gather.len() as u64;
    spec_meta.seconds = t.elapsed().as_secs_f64();
    timings.push(("specular links".to_string(), spec_meta.seconds));

    let deposit = deposit(view.splats.len(), &traced.photons);

    let key = photons_key(&octree.key(), &vmap.key(), &p, &materials);
    let meta = PhotonsMeta {
        octree_key: octree.key().to_string(),
        vmap_key: vmap.key().to_string(),
        params: p,
        lights: lights.clone(),
        emitted_power: plan.emitted.as_dvec3().into(),
        aimed_power: aimed.as_dvec3().into(),
        traced: traced.traced,
        stored: traced.photons.len() as u64,
        occluded: traced.occluded,
        lost: traced.lost,
        device,
        timings,
        specular: spec_meta,
    };
    let mut w = ArtifactWriter::create(out, ArtifactKind::Photons, STAGE, STAGE_VERSION, key)?;
    w.section(sections::PHOTONS, &traced.photons)?;
    w.section(sections::DEPOSIT, &deposit)?;
    w.section(spec::sections::FLUX_OFFSETS, &links.flux_offsets)?;
    w.section(spec::sections::FLUX, &links.flux)?;
    w.section(spec::sections::SMOOTH_OFFSETS, &links.smooth_offsets)?;
    w.section(spec::sections::SMOOTH, &links.smooth)?;
    w.section(spec::sections::GATHER_OFFSETS, &links.gather_offsets)?;
    w.section(spec::sections::GATHER, &links.gather)?;
    w.metadata(&meta)?;
    w.finish()?;
    Ok(Summary {
        path: out.to_path_buf(),
        meta,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// The key a run on `cfg` would give its artifact, from the input artifacts' headers and the
/// config (nothing is traced).
pub fn key(cfg: &LoadedConfig, octree_path: &Path, vmap_path: &Path) -> Result<Key, CausticsError> {
    // The inputs' keys from their headers; a run checks the materials against the octree's.
    let octree = Artifact::input_key(octree_path, ArtifactKind::Octree)?;
    let vmap = Artifact::input_key(vmap_path, ArtifactKind::Vmap)?;
    let materials = cfg.material_records();
    Ok(photons_key(
        &octree,
        &vmap,
        &cfg.config.caustics.params,
        &materials,
    ))
}

/// The artifact key: stage, build, octree and V-map keys (the V-map key covers the lights),
/// parameters, and what of the materials a photon meets: every material's class, the
/// specular ones whole and the emitters' radiance. A diffuse albedo is left out: photons
/// stop at the first diffuse surface and store the power that arrives there, which the
/// albedo does not change (pc-fmm and pc-raytrace apply it), so recoloring a wall does not
/// retrace the photons.
pub fn photons_key(
    octree: &Key,
    vmap: &Key,
    p: &CausticsParams,
    materials: &[pc_artifact::octree::MaterialRecord],
) -> Key {
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(octree)
        .update_key(vmap)
        .update_serialize(p);
    for m in materials {
        let mut seen = *m;
        if m.class == pc_artifact::octree::class::DIFFUSE {
            seen.color = [0.0; 3];
        }
        h.update(bytemuck::bytes_of(&seen));
    }
    h.finish()
}

/// The key of the specular links alone: stage, build, octree, the V-map's links key (not its
/// light lists), the parameters that shape them, and the materials as a photon meets them
/// ([`photons_key`]): moving a light or recolouring a wall reuses them.
pub fn specular_key(
    octree: &Key,
    vmap_links: &str,
    p: &CausticsParams,
    materials: &[pc_artifact::octree::MaterialRecord],
) -> Key {
    let shape = CausticsParams { photons: 0, ..*p };
    let mut h = KeyHasher::new();
    h.update_str("specular links")
        .update_key(&photons_key(octree, &Key::default(), &shape, materials))
        .update_str(vmap_links);
    h.finish()
}

/// The links of the previous artifact at `path` when its links key is `key` and it fits a data
/// pool of `splats` splats.
fn reusable(path: &Path, key: &Key, splats: usize) -> Option<(links::Links, SpecularMeta)> {
    let f = PhotonsFile::open_alone(path).ok()?;
    let (meta, v) = (&f.meta().specular, f.view());
    if meta.key != key.to_string() || v.deposit.len() != splats {
        return None;
    }
    let s = v.specular;
    let links = links::Links {
        flux_offsets: s.flux_offsets.to_vec(),
        flux: s.flux.to_vec(),
        smooth_offsets: s.smooth_offsets.to_vec(),
        smooth: s.smooth.to_vec(),
        gather_offsets: s.gather_offsets.to_vec(),
        gather: s.gather.to_vec(),
    };
    Some((
        links,
        SpecularMeta {
            reused: true,
            ..meta.clone()
        },
    ))
}

/// pc-caustics as its binary runs it.
pub struct CausticsStage {
    pub cfg: LoadedConfig,
    pub octree: PathBuf,
    pub vmap: PathBuf,
    pub output: PathBuf,
    pub backend: Backend,
}

impl Stage for CausticsStage {
    const NAME: &'static str = STAGE;
    const DOING: &'static str = "tracing the photons";
    const KIND: Option<ArtifactKind> = Some(ArtifactKind::Photons);
    type Made = Summary;
    type Error = CausticsError;

    fn output(&self) -> &Path {
        &self.output
    }

    fn key(&self) -> Result<Key, CausticsError> {
        key(&self.cfg, &self.octree, &self.vmap)
    }

    fn run(&self, progress: &dyn Progress) -> Result<Summary, CausticsError> {
        run(
            &self.cfg,
            &self.octree,
            &self.vmap,
            &self.output,
            self.backend,
            progress,
        )
    }

    fn summary(&self, s: &Summary, _seconds: f64) -> String {
        let m = &s.meta;
        format!(
            "pc-caustics: wrote {} ({} photons stored of {} traced, {} hidden, {} lost; specular links: {} of {} paths kept{}, {} flux and {} gather links; {:.2} M paths/s) in {:.2} s on {}",
            s.path.display(),
            m.stored,
            m.traced,
            m.occluded,
            m.lost,
            m.specular.stored,
            m.specular.paths,
            if m.specular.reused { ", reused" } else { "" },
            m.specular.flux_links,
            m.specular.gather_links,
            paths_traced(m) as f64 / trace_seconds(m).max(1e-9) / 1e6,
            s.seconds,
            m.device
        )
    }

    fn stats(&self, s: &Summary, _seconds: f64) -> serde_json::Value {
        let m = &s.meta;
        let trace_s = trace_seconds(m);
        serde_json::json!({
            "budget": m.params.photons,
            "traced": m.traced,
            "stored": m.stored,
            "occluded": m.occluded,
            "lost": m.lost,
            "specular_paths": m.specular.paths,
            "specular_stored": m.specular.stored,
            "specular_reused": m.specular.reused,
            "specular_flux_links": m.specular.flux_links,
            "specular_gather_links": m.specular.gather_links,
            "trace_seconds": trace_s,
            "total_seconds": s.seconds,
            "paths_per_s": (paths_traced(m) as f64 / trace_s.max(1e-9)).round(),
            "device": m.device,
        })
    }
}

/// Photons and specular-link paths traced in the tracing phase (a reused link set traced none).
fn paths_traced(m: &PhotonsMeta) -> u64 {
    m.traced
        + if m.specular.reused {
            0
        } else {
            m.specular.paths
        }
}

/// The tracing phase's seconds.
fn trace_seconds(m: &PhotonsMeta) -> f64 {
    m.timings
        .iter()
        .find(|t| t.0 == "trace")
        .map_or(0.0, |t| t.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_concatenated_in_parallel_are_the_parts_in_order() {
        let parts: Vec<Vec<u32>> = (0..300u32)
            .map(|k| (0..k % 7).map(|i| k * 10 + i).collect())
            .collect();
        let want: Vec<u32> = parts.iter().flatten().copied().collect();
        assert_eq!(concat(&parts), want);
        assert!(concat::<u32>(&[Vec::new(), Vec::new()]).is_empty());
    }

    #[test]
    fn first_ids_are_the_running_photon_counts() {
        // Over more aims than one block of the parallel sum holds.
        let aim = |photons| Aim {
            source: emit::Source::Area(0),
            target: 0,
            photons,
            power: [1.0; 3],
            sampling: emit::Sampling::Whole,
        };
        let aims: Vec<Aim> = (0..40_000u32).map(|k| aim(k % 5)).collect();
        let first = emit::first_ids(&aims);
        let mut at = 0u64;
        for (a, &f) in aims.iter().zip(&first) {
            assert_eq!(f, at);
            at += a.photons as u64;
        }
        assert_eq!(first[aims.len()], at);
        assert_eq!(emit::first_ids(&[]), vec![0]);
    }
}
