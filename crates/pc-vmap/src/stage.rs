//! The pc-vmap stage: octree artifact + config → `vmap` artifact, reusing the links of the
//! previous artifact when only the lights changed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use pc_artifact::octree::{OctreeFile, OctreeView};
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::{sections, Link, Smear, VmapFile, VmapMeta};
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher, PointLight};
use pc_config::{Backend, LoadedConfig};
use pc_stage::{Progress, Stage};

use crate::build::{build_links, csr, light_lists, vnodes, Caster, CpuCaster, GpuCaster};
use crate::error::VmapError;

pub const STAGE: &str = "pc-vmap";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

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
pub fn vmap_key(links: &Key, lights: &[PointLight]) -> Key {
    let mut h = KeyHasher::new();
    h.update_key(links).update_serialize(lights);
    h.finish()
}

/// The key a run on `cfg` would give its artifact, from the octree artifact's header (nothing
/// is computed): [`vmap_key`] of [`links_key`] and the lights.
pub fn key(cfg: &LoadedConfig, octree_path: &Path) -> Result<Key, VmapError> {
    let octree = Artifact::input_key(octree_path, ArtifactKind::Octree)?;
    let lkey = links_key(&octree, &cfg.config.vmap.params);
    Ok(vmap_key(&lkey, &cfg.config.lights))
}

/// What one run made.
pub struct Summary {
    pub path: PathBuf,
    pub meta: VmapMeta,
    pub seconds: f64,
}

/// The link sections and counts of a run, computed or reused.
struct Links {
    offsets: Vec<u32>,
    links: Vec<Link>,
    smear: Vec<Smear>,
    far: u64,
    near: u64,
    pairs: u64,
    rays: u64,
    reused: bool,
}

/// The links of the previous artifact at `path` when its links key is `key` and it fits an
/// octree of `nodes` slots.
fn reusable(path: &Path, key: &Key, nodes: usize) -> Option<Links> {
    let f = VmapFile::open_alone(path).ok()?;
    let (meta, v) = (f.meta(), f.view());
    (meta.links_key == key.to_string() && v.node_range.len() == nodes).then(|| Links {
        offsets: v.link_offsets.to_vec(),
        links: v.links.to_vec(),
        smear: v.smear.to_vec(),
        far: meta.far_links,
        near: meta.near_links,
        pairs: meta.pairs_tested,
        rays: meta.rays_cast,
        reused: true,
    })
}

/// The caster of the device `backend` asks for ([`pc_stage::gpu_or_cpu`]).
fn caster<'v>(
    view: &'v OctreeView<'v>,
    backend: Backend,
) -> Result<Box<dyn Caster + 'v>, VmapError> {
    pc_stage::gpu_or_cpu(
        STAGE,
        backend,
        pc_stage::Work::Precompute,
        |ctx| {
            let caster = pc_tree::gpu::RayCaster::new(&ctx, view)?;
            Ok(Box::new(GpuCaster { ctx, caster }) as Box<dyn Caster>)
        },
        || Ok(Box::new(CpuCaster::new(view))),
    )
}

/// Run the stage; `progress` hears of each round of the link build.
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    out: &Path,
    backend: Backend,
    progress: &dyn Progress,
) -> Result<Summary, VmapError> {
    pc_stage::look_early(backend, pc_stage::Work::Precompute);
    let started = Instant::now();
    let octree = OctreeFile::open(octree_path)?;
    let view = octree.view();
    let p = &cfg.config.vmap.params;
    let lkey = links_key(&octree.key(), p);
    let lights = &cfg.config.lights;
    let key = vmap_key(&lkey, lights);
    let mut timings = Vec::new();
    let t = Instant::now();
    let leaf_splats = p.leaf_splats_for(view.splats.len());
    let vn = vnodes(&view, leaf_splats);
    timings.push(("nodes and cones".to_string(), t.elapsed().as_secs_f64()));
    let t = Instant::now();
    let device = caster(&view, backend)?;
    timings.push(("device setup".to_string(), t.elapsed().as_secs_f64()));
    let caster = pc_tree::caster::Timed::new(device.as_ref());
    let t = Instant::now();
    let links = match reusable(out, &lkey, view.nodes.len()) {
        Some(r) => r,
        None => {
            progress.phase("links");
            let mut round = |level: usize, frontier: usize| {
                progress.phase(&format!("links, round {level}: {frontier} node pairs next"))
            };
            let l = build_links(&view, &vn, p, &caster, &mut round)?;
            let smear = l.smear.per_node(&vn, &l.contact);
            let (offsets, links) = csr(view.nodes.len(), l.pairs);
            Links {
                offsets,
                links,
                smear,
                far: l.far,
                near: l.near,
                pairs: l.pairs_tested,
                rays: l.rays,
                reused: false,
            }
        }
    };
    timings.push((
        if links.reused {
            "links (reused)"
        } else {
            "links"
        }
        .to_string(),
        t.elapsed().as_secs_f64(),
    ));
    progress.phase("light lists");
    let t = Instant::now();
    let positions: Vec<Vec3> = lights.iter().map(|l| Vec3::from(l.position)).collect();
    let lists = light_lists(&view, &vn, &positions, p, &caster)?;
    let mut light_offsets = vec![0u32];
    let mut light_links = Vec::new();
    for l in &lists {
        light_links.extend_from_slice(l);
        light_offsets.push(light_links.len() as u32);
    }
    timings.push(("light lists".to_string(), t.elapsed().as_secs_f64()));
    // Of the links' and the lists' time, the casts' (the rest builds and decides the rays).
    timings.push(("casting".to_string(), caster.seconds()));
    let meta = VmapMeta {
        octree_key: octree.key().to_string(),
        links_key: lkey.to_string(),
        params: p.clone(),
        leaf_splats_used: leaf_splats,
        lights: lights.clone(),
        far_links: links.far,
        near_links: links.near,
        pairs_tested: links.pairs,
        rays_cast: links.rays,
        links_reused: links.reused,
        device: caster.name(),
        timings,
    };
    let range: Vec<[u32; 2]> = vn.iter().map(|v| [v.lo, v.hi]).collect();
    let cone: Vec<f32> = vn.iter().map(|v| v.cone_cos).collect();
    let vnode: Vec<u32> = vn.iter().map(|v| v.vleaf as u32).collect();
    let mut w = ArtifactWriter::create(out, ArtifactKind::Vmap, STAGE, STAGE_VERSION, key)?;
    w.section(sections::LINK_OFFSETS, &links.offsets)?;
    w.section(sections::LINKS, &links.links)?;
    w.section(sections::LIGHT_OFFSETS, &light_offsets)?;
    w.section(sections::LIGHT_LINKS, &light_links)?;
    w.section(sections::NODE_RANGE, &range)?;
    w.section(sections::NODE_CONE, &cone)?;
    w.section(sections::VNODE, &vnode)?;
    w.section(sections::SMEAR, &links.smear)?;
    w.metadata(&meta)?;
    w.finish()?;
    Ok(Summary {
        path: out.to_path_buf(),
        meta,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// pc-vmap as its binary runs it.
pub struct VmapStage {
    pub cfg: LoadedConfig,
    pub octree: PathBuf,
    pub output: PathBuf,
    pub backend: Backend,
}

impl Stage for VmapStage {
    const NAME: &'static str = STAGE;
    const DOING: &'static str = "computing the V-map";
    const KIND: Option<ArtifactKind> = Some(ArtifactKind::Vmap);
    type Made = Summary;
    type Error = VmapError;

    fn output(&self) -> &Path {
        &self.output
    }

    fn key(&self) -> Result<Key, VmapError> {
        key(&self.cfg, &self.octree)
    }

    fn run(&self, progress: &dyn Progress) -> Result<Summary, VmapError> {
        run(
            &self.cfg,
            &self.octree,
            &self.output,
            self.backend,
            progress,
        )
    }

    fn summary(&self, s: &Summary, _seconds: f64) -> String {
        let m = &s.meta;
        format!(
            "pc-vmap: wrote {} ({} far and {} near links{}, {} node pairs tested, {} rays, {} light lists{}) in {:.2} s on {}",
            s.path.display(),
            m.far_links,
            m.near_links,
            if m.links_reused { " reused" } else { "" },
            m.pairs_tested,
            m.rays_cast,
            m.lights.len(),
            match m.leaf_splats_used > m.params.leaf_splats {
                true => format!(", V-map leaves of up to {} splats", m.leaf_splats_used),
                false => String::new(),
            },
            s.seconds,
            m.device
        )
    }
}
