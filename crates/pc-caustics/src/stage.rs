//! The pc-caustics stage: octree + V-map artifacts + config → `photons` artifact.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use pc_artifact::photons::{sections, tree_bytes, CausticsParams, Photon, PhotonTree, PhotonsMeta};
use pc_artifact::vmap::Tables;
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_scene::config::{Backend, LoadedConfig};
use pc_tree::accel::Accel;
use pc_tree::{OctreeView, TraversalStats};
use rayon::prelude::*;

use crate::emit::{self, Aim, Leaves, VmapInput};
use crate::trace::{Fate, Tracer};

pub const STAGE: &str = "pc-caustics";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

pub fn params(cfg: &LoadedConfig) -> CausticsParams {
    let c = &cfg.config.caustics;
    CausticsParams {
        photons: c.photons,
        max_bounces: c.max_bounces,
        self_hit: c.self_hit,
        seed: c.seed,
    }
}

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
    pub traced: u64,
    pub occluded: u64,
    pub lost: u64,
}

/// Trace every photon of `aims` (rayon across photons); photon `id`s run over the aims in
/// order, so the result does not depend on the thread count. `progress` gets the photons done.
pub fn trace_all(tracer: &Tracer, aims: &[Aim], progress: &(dyn Fn(u64) + Sync)) -> Traced {
    let mut first = Vec::with_capacity(aims.len() + 1);
    let mut total = 0u64;
    for a in aims {
        first.push(total);
        total += a.photons as u64;
    }
    first.push(total);
    const CHUNK: u64 = 1 << 14;
    let chunks: Vec<Traced> = (0..total.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
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
                    Fate::Stored(p) => out.photons.push(p),
                    Fate::Occluded => out.occluded += 1,
                    Fate::Lost | Fate::Absorbed => out.lost += 1,
                }
            }
            progress(hi - lo);
            out
        })
        .collect();
    let mut out = Traced::default();
    for c in chunks {
        out.photons.extend(c.photons);
        out.traced += c.traced;
        out.occluded += c.occluded;
        out.lost += c.lost;
    }
    out
}

/// Power deposited per splat (W, RGB).
pub fn deposit(splats: usize, photons: &[Photon]) -> Vec<[f32; 3]> {
    let mut d = vec![[0.0f32; 3]; splats];
    for p in photons {
        let e = &mut d[p.splat as usize];
        for k in 0..3 {
            e[k] += p.power[k];
        }
    }
    d
}

/// Run the stage: `progress(done, total)` as photons are traced.
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    vmap_path: &Path,
    out: &Path,
    backend: Backend,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    let mut timings = Vec::new();
    let oct = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let view = OctreeView::from_artifact(&oct)?;
    let vm = Artifact::open_kind(vmap_path, ArtifactKind::Vmap)
        .with_context(|| format!("run pc-vmap first to make {}", vmap_path.display()))?;
    let octree_key = oct.header().key;
    let lights = cfg.light_records();
    let tables = Tables::open(
        &vm,
        &octree_key,
        view.nodes.len(),
        view.splats.len(),
        &lights,
    )
    .map_err(|e| anyhow::anyhow!("{e} (octree {})", octree_path.display()))?;
    let materials = pc_scene::cli::current_materials(cfg, &oct)?;
    let p = params(cfg);

    let t = Instant::now();
    let leaves = Leaves::new(&view, &materials);
    let point_lights: Vec<(Vec3, Vec3)> = lights
        .iter()
        .map(|l| (Vec3::new(l[0], l[1], l[2]), Vec3::new(l[3], l[4], l[5])))
        .collect();
    let input = VmapInput {
        node_range: tables.node_range,
        link_offsets: tables.link_offsets,
        links: tables.links,
        light_lists: (0..lights.len()).map(|l| tables.light_list(l)).collect(),
    };
    let plan = emit::plan(&view, &materials, &leaves, &point_lights, &input);
    let aims = emit::aims(&plan, p.photons, p.seed);
    let aimed: Vec3 = aims
        .iter()
        .map(|a| Vec3::from(a.power) * a.photons as f32)
        .sum();
    let total: u64 = aims.iter().map(|a| a.photons as u64).sum();
    timings.push(("emission".to_string(), t.elapsed().as_secs_f64()));

    let t = Instant::now();
    let done = std::sync::atomic::AtomicU64::new(0);
    let step = |n: u64| {
        let d = done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n;
        progress(d, total);
    };
    let gpu = match backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(pc_gpu::GpuContext::new()?),
        Backend::Auto => pc_gpu::GpuContext::new().ok().filter(|g| !g.is_software()),
    };
    let gpu_traced = match &gpu {
        None => None,
        Some(ctx) => {
            let traced = crate::gpu::GpuTracer::new(
                ctx,
                &view,
                &materials,
                &leaves,
                p.max_bounces,
                p.self_hit,
                p.seed,
            )
            .and_then(|g| g.trace_all(ctx, &aims, &step));
            match traced {
                Ok(t) => Some((t, ctx.describe())),
                Err(e) if backend == Backend::Auto => {
                    eprintln!("pc-caustics: warning: tracing on the CPU: the GPU cannot: {e}");
                    done.store(0, std::sync::atomic::Ordering::Relaxed);
                    None
                }
                Err(e) => return Err(anyhow::anyhow!("{e}")),
            }
        }
    };
    let (traced, device) = match gpu_traced {
        Some(t) => t,
        None => {
            let accel = Accel::new(&view);
            let tracer = Tracer {
                view: &view,
                accel: &accel,
                materials: &materials,
                leaves: &leaves,
                max_bounces: p.max_bounces,
                self_hit: p.self_hit,
                seed: p.seed,
            };
            let t = trace_all(&tracer, &aims, &step);
            (t, format!("CPU ({} threads)", rayon::current_num_threads()))
        }
    };
    timings.push(("trace".to_string(), t.elapsed().as_secs_f64()));

    let t = Instant::now();
    let positions: Vec<[f32; 3]> = traced.photons.iter().map(|p| p.position).collect();
    let tree = PhotonTree::new_from_slice(&positions)
        .map_err(|e| anyhow::anyhow!("building the photon kd-tree: {e:?}"))?;
    let tree_bytes = tree_bytes(&tree).map_err(|e| anyhow::anyhow!(e))?;
    let deposit = deposit(view.splats.len(), &traced.photons);
    timings.push(("kd-tree".to_string(), t.elapsed().as_secs_f64()));

    let key = photons_key(&octree_key, &vm.header().key, &p, &materials);
    let meta = PhotonsMeta {
        octree_key: octree_key.to_string(),
        vmap_key: vm.header().key.to_string(),
        params: p,
        lights,
        emitted_power: plan.emitted.as_dvec3().into(),
        aimed_power: aimed.as_dvec3().into(),
        traced: traced.traced,
        stored: traced.photons.len() as u64,
        occluded: traced.occluded,
        lost: traced.lost,
        device,
        timings,
    };
    let mut w = ArtifactWriter::create(out, ArtifactKind::Photons, STAGE, STAGE_VERSION, key)?;
    w.section(sections::PHOTONS, &traced.photons)?;
    w.section_aligned(
        sections::KDTREE,
        pc_artifact::photons::TREE_ALIGN,
        &tree_bytes,
    )?;
    w.section(sections::DEPOSIT, &deposit)?;
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
pub fn key(cfg: &LoadedConfig, octree_path: &Path, vmap_path: &Path) -> anyhow::Result<Key> {
    let oct = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let vm = Artifact::open_kind(vmap_path, ArtifactKind::Vmap)
        .with_context(|| format!("run pc-vmap first to make {}", vmap_path.display()))?;
    let materials = pc_scene::cli::current_materials(cfg, &oct)?;
    Ok(photons_key(&oct.key(), &vm.key(), &params(cfg), &materials))
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
