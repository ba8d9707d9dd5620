//! The pc-fmm stage: octree + V-map artifacts + config → `radiosity` artifact.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use glam::Vec3;
use pc_artifact::radiosity::{sections, FmmParams, RadiosityMeta};
use pc_artifact::vmap::{sections as vs, Link, VmapMeta};
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_scene::config::{Backend, LoadedConfig};
use pc_tree::{OctreeView, Ray};

use crate::expansion::Basis;
use crate::plan::{self, PlanParams};
use crate::solve::{self, Operator, PointLight, ShadowTester};
use crate::{tree, CpuFmm, CpuOperator};

pub const STAGE: &str = "pc-fmm";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

pub fn params(cfg: &LoadedConfig) -> FmmParams {
    let f = &cfg.config.fmm;
    FmmParams {
        order: f.order,
        theta: f.theta,
        clamp_tol: f.clamp_tol,
        tolerance: f.tolerance,
        max_iterations: f.max_iterations,
        emitter_samples: f.emitter_samples,
    }
}

/// What one run made.
pub struct Summary {
    pub path: PathBuf,
    pub meta: RadiosityMeta,
    pub seconds: f64,
}

/// Shadow rays on the CPU, through the renderer's packed leaf lists.
struct Caster<'a> {
    view: &'a OctreeView<'a>,
    accel: pc_tree::accel::Accel,
}

impl ShadowTester for Caster<'_> {
    fn visible(&self, rays: &[Ray]) -> Result<Vec<bool>, String> {
        Ok(self.accel.visible(self.view, rays))
    }
}

/// Progress callbacks of a run.
pub trait Progress {
    fn phase(&mut self, what: &str);
    fn iteration(&mut self, it: u32, residual: f64);
}

/// Run the stage.
pub fn run(
    cfg: &LoadedConfig,
    octree_path: &Path,
    vmap_path: &Path,
    out: &Path,
    backend: Backend,
    progress: &mut dyn Progress,
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    let mut timings = Vec::new();
    let oct = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let view = OctreeView::from_artifact(&oct)?;
    let vm = Artifact::open_kind(vmap_path, ArtifactKind::Vmap)
        .with_context(|| format!("run pc-vmap first to make {}", vmap_path.display()))?;
    let vmeta: VmapMeta = vm.metadata()?;
    let octree_key = oct.header().key;
    if vmeta.octree_key != octree_key.to_string() {
        bail!(
            "{}: stale V-map: it was computed for another octree than {}: rerun pc-vmap",
            vmap_path.display(),
            octree_path.display()
        );
    }
    let lights = cfg.light_records();
    if vmeta.lights != lights {
        bail!(
            "{}: stale V-map: its light lists are for other point lights than {} defines: rerun pc-vmap (it reuses the links)",
            vmap_path.display(),
            cfg.path.display()
        );
    }
    let link_offsets: &[u32] = vm.section(vs::LINK_OFFSETS)?;
    let links: &[Link] = vm.section(vs::LINKS)?;
    let light_offsets: &[u32] = vm.section(vs::LIGHT_OFFSETS)?;
    let light_links: &[Link] = vm.section(vs::LIGHT_LINKS)?;
    if link_offsets.len() != view.nodes.len() + 1
        || *link_offsets.last().unwrap_or(&0) as usize != links.len()
        || light_offsets.len() != lights.len() + 1
        || *light_offsets.last().unwrap_or(&0) as usize != light_links.len()
        || links
            .iter()
            .chain(light_links)
            .any(|l| l.slot() as usize >= view.nodes.len())
        || link_offsets.windows(2).any(|w| w[0] > w[1])
        || light_offsets.windows(2).any(|w| w[0] > w[1])
    {
        bail!(
            "{}: the link tables do not fit the octree {}: rerun pc-vmap",
            vmap_path.display(),
            octree_path.display()
        );
    }
    let materials = pc_scene::cli::current_materials(cfg, &oct)?;
    let p = params(cfg);

    progress.phase("tree");
    let t = Instant::now();
    let (tree, pts) = tree::build(&view, &materials);
    timings.push(("tree".to_string(), t.elapsed().as_secs_f64()));

    progress.phase("interaction plan");
    let t = Instant::now();
    let plan = plan::build(
        &tree,
        &pts,
        link_offsets,
        links,
        PlanParams {
            theta: p.theta,
            clamp_tol: p.clamp_tol,
        },
    );
    timings.push(("plan".to_string(), t.elapsed().as_secs_f64()));

    progress.phase("direct light");
    let t = Instant::now();
    let point_lights: Vec<PointLight> = lights
        .iter()
        .map(|l| PointLight {
            position: Vec3::new(l[0], l[1], l[2]),
            intensity: Vec3::new(l[3], l[4], l[5]),
        })
        .collect();
    let lists: Vec<&[Link]> = light_offsets
        .windows(2)
        .map(|w| &light_links[w[0] as usize..w[1] as usize])
        .collect();
    let ranges = |s: u32| (tree.lo[s as usize], tree.hi[s as usize]);
    let caster = Caster {
        view: &view,
        accel: pc_tree::accel::Accel::new(&view),
    };
    let sys = solve::system(
        &view,
        &materials,
        &pts,
        &point_lights,
        &lists,
        &ranges,
        vmeta.params.self_hit,
        &caster,
    )
    .map_err(|e| anyhow::anyhow!("shadow rays: {e}"))?;
    let mut sys = sys;
    solve::emitter_direct(
        &view,
        &pts,
        &mut sys,
        cfg.config.fmm.emitter_samples,
        vmeta.params.self_hit,
        &caster,
    )
    .map_err(|e| anyhow::anyhow!("emitter shadow rays: {e}"))?;
    timings.push(("source term".to_string(), t.elapsed().as_secs_f64()));

    let basis = Basis::new(p.order as usize);
    let cpu_op = || CpuOperator {
        fmm: CpuFmm {
            basis: &basis,
            tree: &tree,
            points: &pts,
            plan: &plan,
        },
        times: Default::default(),
        applications: 0,
    };
    let gpu = match backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(pc_gpu::GpuContext::new()?),
        Backend::Auto => pc_gpu::GpuContext::new().ok().filter(|g| !g.is_software()),
    };
    let mut op: Box<dyn Operator + '_> = match gpu {
        None => Box::new(cpu_op()),
        Some(ctx) => match crate::gpu::GpuFmm::new(ctx, &basis, &tree, &pts, &plan) {
            Ok(g) => Box::new(g),
            Err(e) if backend == Backend::Auto => {
                eprintln!("pc-fmm: warning: solving on the CPU: the GPU cannot: {e}");
                Box::new(cpu_op())
            }
            Err(e) => return Err(anyhow::anyhow!("{e}")),
        },
    };
    let device = op.device();

    progress.phase("solve");
    let t = Instant::now();
    let sol = solve::solve(
        op.as_mut(),
        &sys,
        &pts,
        p.tolerance as f64,
        p.max_iterations,
        &mut |it, r| progress.iteration(it, r),
    )
    .map_err(|e| anyhow::anyhow!("FMM on {device}: {e}"))?;
    let solve_s = t.elapsed().as_secs_f64();
    timings.push(("solve".to_string(), solve_s));
    timings.push((
        "per iteration".to_string(),
        solve_s / sol.residuals.len().max(1) as f64,
    ));
    drop(op);

    let key = radiosity_key(&octree_key, &vm.header().key, &p, &materials, &lights);
    let active = pts.active.iter().filter(|&&a| a).count() as u64;
    let radiance: Vec<[f32; 3]> = sol
        .radiance
        .iter()
        .zip(&pts.active)
        .map(|(l, &a)| if a { *l } else { [0.0; 3] })
        .collect();
    let meta = RadiosityMeta {
        octree_key: octree_key.to_string(),
        vmap_key: vm.header().key.to_string(),
        photons_key: None,
        params: p,
        iterations: sol.residuals.len() as u32,
        converged: sol.converged,
        residuals: sol.residuals.clone(),
        active_splats: active,
        m2l: plan.counts.m2l,
        p2l: plan.counts.p2l,
        m2p: plan.counts.m2p,
        p2p: plan.counts.p2p,
        p2p_pairs: plan.counts.p2p_pairs,
        device,
        timings,
    };
    let mut w = ArtifactWriter::create(out, ArtifactKind::Radiosity, STAGE, STAGE_VERSION, key)?;
    w.section(sections::RADIANCE, &radiance)?;
    w.section(sections::SOURCE, &sys.source)?;
    w.section(sections::RESIDUALS, &sol.residuals)?;
    w.metadata(&meta)?;
    w.finish()?;
    Ok(Summary {
        path: out.to_path_buf(),
        meta,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// The artifact key: stage, build, octree and V-map keys, parameters, materials and lights.
pub fn radiosity_key(
    octree: &Key,
    vmap: &Key,
    p: &FmmParams,
    materials: &[pc_artifact::octree::MaterialRecord],
    lights: &[[f32; 6]],
) -> Key {
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(octree)
        .update_key(vmap)
        .update_serialize(p)
        .update(bytemuck::cast_slice(materials))
        .update_serialize(&lights.to_vec());
    h.finish()
}
