//! The pc-fmm stage: octree + V-map artifacts + config → `radiosity` artifact.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use pc_artifact::octree::MaterialRecord;
use pc_artifact::radiosity::Solver;
use pc_artifact::radiosity::{sections, FmmParams, RadiosityMeta};
use pc_artifact::vmap::{self as vs, Link};
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_scene::config::{Backend, LoadedConfig};
use pc_tree::OctreeView;

use crate::expansion::Basis;
use crate::plan::{self, PlanParams};
use crate::solve::{self, Operator, PointLight};
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
        emitter_probes: f.emitter_probes,
        solver: f.solver,
        relax: f.relax,
    }
}

/// The linear system's emission, albedo and source with the point lights' direct light (their
/// light lists from the V-map `tables` for shadows), before the emitters' direct light.
pub fn point_light_system(
    view: &OctreeView,
    materials: &[MaterialRecord],
    tree: &crate::tree::Tree,
    pts: &crate::tree::Points,
    tables: &vs::Tables,
    lights: &[[f32; 6]],
    caster: &dyn pc_tree::caster::Caster,
) -> anyhow::Result<solve::System> {
    let point_lights: Vec<PointLight> = lights
        .iter()
        .map(|l| PointLight {
            position: Vec3::new(l[0], l[1], l[2]),
            intensity: Vec3::new(l[3], l[4], l[5]),
        })
        .collect();
    let lists: Vec<&[Link]> = (0..lights.len()).map(|l| tables.light_list(l)).collect();
    let ranges = |s: u32| (tree.lo[s as usize], tree.hi[s as usize]);
    solve::system(
        view,
        materials,
        pts,
        &point_lights,
        &lists,
        &ranges,
        tables.meta.params.self_hit,
        caster,
    )
    .map_err(|e| anyhow::anyhow!("shadow rays: {e}"))
}

/// What one run made.
pub struct Summary {
    pub path: PathBuf,
    pub meta: RadiosityMeta,
    pub seconds: f64,
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
    photons_path: &Path,
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
    let octree_key = oct.header().key;
    let lights = cfg.light_records();
    let tables = vs::Tables::open(
        &vm,
        &octree_key,
        view.nodes.len(),
        view.splats.len(),
        &lights,
    )
    .map_err(|e| anyhow::anyhow!("{e} (octree {})", octree_path.display()))?;
    let vmeta = &tables.meta;
    let (link_offsets, links) = (tables.link_offsets, tables.links);
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
    let caster = pc_tree::caster::CpuCaster::new(&view);
    let mut sys = point_light_system(&view, &materials, &tree, &pts, &tables, &lights, &caster)?;
    let emitter = solve::emitter_direct(
        &view,
        &pts,
        &mut sys,
        solve::EmitterSampling {
            samples: p.emitter_samples,
            probes: p.emitter_probes,
            self_hit: vmeta.params.self_hit,
            shafts: true,
        },
        &caster,
    )
    .map_err(|e| anyhow::anyhow!("emitter shadow rays: {e}"))?;
    let (emitter_rays, emitter_samples) = (emitter.cast, emitter.samples);
    // Caustic energy (LS⁺D, seed §8.1): the photon map's first diffuse bounce feeds the later
    // ones. It is a source of the solve, and taken out of the stored radiance again, because
    // the renderer shows it from the photon map itself.
    let photons = if photons_path.exists() {
        Some(Artifact::open_kind(photons_path, ArtifactKind::Photons)?)
    } else {
        None
    };
    let mut caustic = vec![[0.0f32; 3]; view.splats.len()];
    if let Some(a) = &photons {
        let meta: pc_artifact::photons::PhotonsMeta = a.metadata()?;
        if meta.octree_key != octree_key.to_string() {
            anyhow::bail!(
                "{}: stale photon map: it was traced on another octree than {}: rerun pc-caustics",
                photons_path.display(),
                octree_path.display()
            );
        }
        let deposit: &[[f32; 3]] = a.section(pc_artifact::photons::sections::DEPOSIT)?;
        if deposit.len() != view.splats.len() || deposit.iter().flatten().any(|x| !x.is_finite()) {
            anyhow::bail!(
                "{}: the caustic deposit does not fit the octree {} ({} splats, {} deposits): rerun pc-caustics",
                photons_path.display(),
                octree_path.display(),
                view.splats.len(),
                deposit.len()
            );
        }
        for (i, d) in deposit.iter().enumerate() {
            let area = view.splat_area[i];
            if !pts.active[i] || area <= 0.0 || *d == [0.0; 3] {
                continue;
            }
            // Reflected radiance ρ E / π of the irradiance E = Φ / A.
            let c = Vec3::from(sys.albedo[i]) * Vec3::from(*d) / (std::f32::consts::PI * area);
            caustic[i] = c.into();
            sys.source[i] = (Vec3::from(sys.source[i]) + c).into();
        }
    }
    timings.push(("source term".to_string(), t.elapsed().as_secs_f64()));

    let basis = Basis::new(p.order as usize);
    let cpu_op = || CpuOperator {
        fmm: CpuFmm::new(&basis, &tree, &pts, &plan),
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
    let mut report = |it, r| progress.iteration(it, r);
    let sol = match p.solver {
        Solver::Gmres => solve::solve_gmres(
            op.as_mut(),
            &sys,
            &pts,
            p.tolerance as f64,
            p.max_iterations,
            solve::GMRES_RESTART,
            p.relax,
            &mut report,
        ),
        Solver::Jacobi => solve::solve(
            op.as_mut(),
            &sys,
            &pts,
            p.tolerance as f64,
            p.max_iterations,
            &mut report,
        ),
    }
    .map_err(|e| anyhow::anyhow!("FMM on {device}: {e}"))?;
    let solve_s = t.elapsed().as_secs_f64();
    timings.push(("solve".to_string(), solve_s));
    timings.push((
        "per iteration".to_string(),
        solve_s / sol.residuals.len().max(1) as f64,
    ));
    drop(op);

    let photons_key = photons.as_ref().map(|a| a.header().key);
    let key = radiosity_key(
        &octree_key,
        &vm.header().key,
        photons_key.as_ref(),
        &p,
        &materials,
        &lights,
    );
    let active = pts.active.iter().filter(|&&a| a).count() as u64;
    let radiance: Vec<[f32; 3]> = sol
        .radiance
        .iter()
        .zip(&pts.active)
        .zip(&caustic)
        .map(|((l, &a), c)| {
            if a {
                std::array::from_fn(|k| (l[k] - c[k]).max(0.0))
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let meta = RadiosityMeta {
        octree_key: octree_key.to_string(),
        vmap_key: vm.header().key.to_string(),
        photons_key: photons_key.map(|k| k.to_string()),
        params: p,
        iterations: sol.residuals.len() as u32,
        converged: sol.converged,
        residuals: sol.residuals.clone(),
        orders: sol.orders.clone(),
        active_splats: active,
        m2l: plan.counts.m2l,
        p2l: plan.counts.p2l,
        m2p: plan.counts.m2p,
        p2p: plan.counts.p2p,
        p2p_pairs: plan.counts.p2p_pairs,
        emitter_samples,
        emitter_rays,
        emitter_settled: emitter.settled,
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

/// The key a run on `cfg` would give its artifact, from the input artifacts' headers and the
/// config (nothing is solved). The photon map counts when it exists, as in [`run`].
pub fn key(
    cfg: &LoadedConfig,
    octree_path: &Path,
    vmap_path: &Path,
    photons_path: &Path,
) -> anyhow::Result<Key> {
    let oct = Artifact::open_kind(octree_path, ArtifactKind::Octree)
        .with_context(|| format!("run pc-octree first to make {}", octree_path.display()))?;
    let vm = Artifact::open_kind(vmap_path, ArtifactKind::Vmap)
        .with_context(|| format!("run pc-vmap first to make {}", vmap_path.display()))?;
    let photons = if photons_path.exists() {
        Some(Artifact::open_kind(photons_path, ArtifactKind::Photons)?.key())
    } else {
        None
    };
    let materials = pc_scene::cli::current_materials(cfg, &oct)?;
    Ok(radiosity_key(
        &oct.key(),
        &vm.key(),
        photons.as_ref(),
        &params(cfg),
        &materials,
        &cfg.light_records(),
    ))
}

/// The artifact key: stage, build, octree and V-map keys, parameters, materials and lights.
pub fn radiosity_key(
    octree: &Key,
    vmap: &Key,
    photons: Option<&Key>,
    p: &FmmParams,
    materials: &[pc_artifact::octree::MaterialRecord],
    lights: &[[f32; 6]],
) -> Key {
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(octree)
        .update_key(vmap);
    if let Some(k) = photons {
        h.update_key(k);
    }
    h.update_serialize(p)
        .update(bytemuck::cast_slice(materials))
        .update_serialize(&lights.to_vec());
    h.finish()
}
