//! The pc-vmap stage: octree artifact + config → `vmap` artifact, reusing the links of the
//! previous artifact when only the lights changed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use pc_artifact::octree::OctreeMeta;
use pc_artifact::vmap::{sections, Link, VmapMeta, VmapParams};
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_scene::config::{Backend, LoadedConfig};
use pc_tree::OctreeView;

use crate::build::{build_links, csr, light_lists, vnodes, Caster, CpuCaster, GpuCaster};

pub const STAGE: &str = "pc-vmap";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

pub fn params(cfg: &LoadedConfig) -> VmapParams {
    let v = &cfg.config.vmap;
    VmapParams {
        theta: v.theta,
        rays: v.rays,
        near_rays: v.near_rays,
        leaf_splats: v.leaf_splats,
        self_hit: v.self_hit,
        refine_form_factor: v.refine_form_factor,
        heavy_rays: v.heavy_rays,
        heavy_form_factor: v.heavy_form_factor,
        seed: v.seed,
    }
}

/// The key of the links: this stage's version, the octree's key and the V-map parameters.
pub fn links_key(octree_key: &Key, p: &VmapParams) -> Key {
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(octree_key)
        .update_serialize(p);
    h.finish()
}

/// The artifact's key: the links key and the point lights.
pub fn vmap_key(links: &Key, lights: &[[f32; 6]]) -> Key {
    let mut h = KeyHasher::new();
    h.update_key(links).update_serialize(&lights.to_vec());
    h.finish()
}

/// What one run made.
pub struct Summary {
    pub path: PathBuf,
    pub meta: VmapMeta,
    pub seconds: f64,
}

/// The key a run on `cfg` would give its artifact, from the octree artifact's header (nothing
/// is computed): [`vmap_key`] of [`links_key`] and the lights.
pub fn key(cfg: &LoadedConfig, octree_path: &Path) -> anyhow::Result<Key> {
    let art = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let lkey = links_key(&art.key(), &params(cfg));
    Ok(vmap_key(&lkey, &cfg.light_records()))
}

/// The link sections of a previous artifact whose links key matches, if any.
struct Reused {
    offsets: Vec<u32>,
    links: Vec<Link>,
    far: u64,
    near: u64,
    pairs: u64,
    rays: u64,
}

fn reusable(path: &Path, key: &Key, nodes: usize) -> Option<Reused> {
    let a = Artifact::open_kind(path, ArtifactKind::Vmap).ok()?;
    let meta: VmapMeta = a.metadata().ok()?;
    if meta.links_key != key.to_string() {
        return None;
    }
    let offsets: &[u32] = a.section(sections::LINK_OFFSETS).ok()?;
    let links: &[Link] = a.section(sections::LINKS).ok()?;
    (offsets.len() == nodes + 1 && *offsets.last()? as usize == links.len()).then(|| Reused {
        offsets: offsets.to_vec(),
        links: links.to_vec(),
        far: meta.far_links,
        near: meta.near_links,
        pairs: meta.pairs_tested,
        rays: meta.rays_cast,
    })
}

/// Run the stage. `round(level, frontier)` reports progress of the link build.
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    out: &Path,
    backend: Backend,
    round: &mut dyn FnMut(usize, usize),
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    let art = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let view = OctreeView::from_artifact(&art)?;
    let _: OctreeMeta = art.metadata()?;
    let p = params(cfg);
    let octree_key = art.header().key;
    let lkey = links_key(&octree_key, &p);
    let lights = cfg.light_records();
    let key = vmap_key(&lkey, &lights);
    let mut timings = Vec::new();
    let t = Instant::now();
    let vn = vnodes(&view, p.leaf_splats);
    timings.push(("nodes and cones".to_string(), t.elapsed().as_secs_f64()));
    let gpu = match backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(pc_gpu::GpuContext::new()?),
        Backend::Auto => pc_gpu::GpuContext::new().ok().filter(|g| !g.is_software()),
    };
    let caster: Box<dyn Caster> = match gpu {
        Some(ctx) => match pc_tree::gpu::RayCaster::new(&ctx, &view) {
            Ok(caster) => Box::new(GpuCaster { ctx, caster }),
            Err(e) if backend == Backend::Auto => {
                eprintln!("pc-vmap: warning: casting on the CPU: the GPU cannot: {e}");
                Box::new(CpuCaster::new(&view))
            }
            Err(e) => return Err(e.into()),
        },
        None => Box::new(CpuCaster::new(&view)),
    };
    let t = Instant::now();
    let (offsets, links, far, near, pairs, rays, reused) =
        match reusable(out, &lkey, view.nodes.len()) {
            Some(r) => (r.offsets, r.links, r.far, r.near, r.pairs, r.rays, true),
            None => {
                let l = build_links(&view, &vn, &p, caster.as_ref(), round)
                    .map_err(|e| anyhow::anyhow!("casting visibility rays: {e}"))?;
                let (o, k) = csr(view.nodes.len(), l.pairs);
                (o, k, l.far, l.near, l.pairs_tested, l.rays, false)
            }
        };
    timings.push((
        if reused { "links (reused)" } else { "links" }.to_string(),
        t.elapsed().as_secs_f64(),
    ));
    let t = Instant::now();
    let positions: Vec<Vec3> = lights.iter().map(|l| Vec3::new(l[0], l[1], l[2])).collect();
    let lists = light_lists(&view, &vn, &positions, &p, caster.as_ref())
        .map_err(|e| anyhow::anyhow!("casting light rays: {e}"))?;
    let mut light_offsets = vec![0u32];
    let mut light_links = Vec::new();
    for l in &lists {
        light_links.extend_from_slice(l);
        light_offsets.push(light_links.len() as u32);
    }
    timings.push(("light lists".to_string(), t.elapsed().as_secs_f64()));
    let meta = VmapMeta {
        octree_key: octree_key.to_string(),
        links_key: lkey.to_string(),
        params: p,
        lights,
        far_links: far,
        near_links: near,
        pairs_tested: pairs,
        rays_cast: rays,
        links_reused: reused,
        device: caster.name(),
        timings,
    };
    let range: Vec<[u32; 2]> = vn.iter().map(|v| [v.lo.min(v.hi), v.hi]).collect();
    let cone: Vec<f32> = vn.iter().map(|v| v.cone_cos).collect();
    let vnode: Vec<u32> = vn.iter().map(|v| v.vleaf as u32).collect();
    let mut w = ArtifactWriter::create(out, ArtifactKind::Vmap, STAGE, STAGE_VERSION, key)?;
    w.section(sections::LINK_OFFSETS, &offsets)?;
    w.section(sections::LINKS, &links)?;
    w.section(sections::LIGHT_OFFSETS, &light_offsets)?;
    w.section(sections::LIGHT_LINKS, &light_links)?;
    w.section(sections::NODE_RANGE, &range)?;
    w.section(sections::NODE_CONE, &cone)?;
    w.section(sections::VNODE, &vnode)?;
    w.metadata(&meta)?;
    w.finish()?;
    Ok(Summary {
        path: out.to_path_buf(),
        meta,
        seconds: started.elapsed().as_secs_f64(),
    })
}
