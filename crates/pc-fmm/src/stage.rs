//! The pc-fmm stage: octree + V-map (+ photon map) artifacts + config → `radiosity` artifact.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use pc_artifact::octree::{MaterialRecord, OctreeFile, OctreeView};
use pc_artifact::params::{FmmParams, Solver};
use pc_artifact::photons::PhotonsFile;
use pc_artifact::radiosity::{sections, RadiosityMeta};
use pc_artifact::vmap::VmapFile;
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter, Key, KeyHasher, PointLight};
use pc_config::{Backend, LoadedConfig};
use pc_stage::{OptionalInput, Progress, Stage};
use pc_tree::accel::Accel;
use pc_tree::between::LazyRoughness;
use pc_tree::caster::{Caster, CpuCaster};
use rayon::prelude::*;

use crate::cluster::Clustering;
use crate::emitter::{self, EmitterRays, EmitterSampling};
use crate::error::FmmError;
use crate::expansion::Basis;
use crate::gather;
use crate::plan::{self, Plan, PlanParams};
use crate::solve::{self, Gmres, Operator, Solution};
use crate::specular::{SpecularTransfer, WithSpecular};
use crate::system::{self, LightLists, System};
use crate::tree::{self, Points, Tree};
use crate::{CpuFmm, CpuOperator};

pub const STAGE: &str = "pc-fmm";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// The artifacts a solve reads.
#[derive(Clone, Debug)]
pub struct Inputs {
    pub octree: PathBuf,
    pub vmap: PathBuf,
    /// Whose caustic energy feeds the solve.
    pub photons: OptionalInput,
}

impl Inputs {
    /// The config's default paths, replaced by those given.
    pub fn new(
        cfg: &LoadedConfig,
        octree: Option<PathBuf>,
        vmap: Option<PathBuf>,
        photons: Option<PathBuf>,
    ) -> Inputs {
        Inputs {
            octree: octree.unwrap_or_else(|| cfg.octree_path()),
            vmap: vmap.unwrap_or_else(|| cfg.vmap_path()),
            photons: OptionalInput::new(photons, cfg.photons_path()),
        }
    }
}

/// The linear system's emission, albedo and source with the point lights' direct light (their
/// light lists from the V-map `vmap` for shadows), before the emitters' direct light.
pub fn point_light_system(
    view: &OctreeView,
    materials: &[MaterialRecord],
    pts: &Points,
    vmap: &VmapFile,
    (lights, rough): (&[PointLight], &LazyRoughness),
    caster: &dyn Caster,
) -> Result<System, FmmError> {
    let v = vmap.view();
    let seen = LightLists {
        vmap: &v,
        self_hit: vmap.meta().params.self_hit,
        rough,
    };
    Ok(system::system(view, materials, pts, lights, seen, caster)?)
}

/// What one run made.
pub struct Summary {
    pub path: PathBuf,
    pub meta: RadiosityMeta,
    pub seconds: f64,
}

/// The source term: emission, the point lights' and the emitters' direct light, and the
/// caustic photons' first diffuse bounce; returns the system, the emitters' ray counts and the
/// caustic part of every splat's source (taken out of the stored radiance again, since the
/// renderer shows it from the photon map itself; seed §8.1).
fn source_term(
    view: &OctreeView,
    materials: &[MaterialRecord],
    pts: &Points,
    vmap: &VmapFile,
    photons: Option<&PhotonsFile>,
    (cfg, rough, caster): (&LoadedConfig, &LazyRoughness, &CpuCaster),
) -> Result<(System, EmitterRays, Vec<[f32; 3]>), FmmError> {
    let p = &cfg.config.fmm.params;
    let lights = (&cfg.config.lights[..], rough);
    let mut sys = point_light_system(view, materials, pts, vmap, lights, caster)?;
    let sampling = EmitterSampling {
        samples: p.emitter_samples,
        probes: p.emitter_probes,
        self_hit: vmap.meta().params.self_hit,
        shafts: true,
    };
    let emitter = emitter::emitter_direct(view, pts, &mut sys, sampling, caster)?;
    let mut caustic = vec![[0.0f32; 3]; view.splats.len()];
    if let Some(photons) = photons {
        for (i, d) in photons.view().deposit.iter().enumerate() {
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
    Ok((sys, emitter, caustic))
}

/// The transport operator on the device `backend` asks for ([`pc_stage::gpu_or_cpu`]).
fn operator<'a>(
    backend: Backend,
    basis: &'a Basis,
    tree: &'a Tree,
    pts: &'a Points,
    plan: &'a Plan,
) -> Result<Box<dyn Operator + 'a>, FmmError> {
    pc_stage::gpu_or_cpu(
        STAGE,
        backend,
        pc_stage::Work::Precompute,
        |ctx| {
            let g = crate::gpu::GpuFmm::new(ctx, basis, tree, pts, plan)?;
            Ok(Box::new(g) as Box<dyn Operator>)
        },
        || {
            Ok(Box::new(CpuOperator {
                fmm: CpuFmm::new(basis, tree, pts, plan),
                times: Default::default(),
                applications: 0,
            }))
        },
    )
}

/// The solve by the configured method; `progress` hears of each iteration.
fn solve(
    op: &mut dyn Operator,
    sys: &System,
    pts: &Points,
    p: &FmmParams,
    progress: &dyn Progress,
) -> Result<Solution, FmmError> {
    let mut report = |it: u32, r: f64| {
        progress.phase(&format!("solve: iteration {it}, residual {r:.3e}"));
        progress.note(&format!("  iteration {it:3}: residual {r:.3e}"));
    };
    match p.solver {
        Solver::Gmres => solve::solve_gmres(
            op,
            sys,
            pts,
            Gmres {
                tolerance: p.tolerance as f64,
                max_iterations: p.max_iterations,
                restart: solve::GMRES_RESTART,
                relaxed: p.relax,
            },
            &mut report,
        ),
        Solver::Jacobi => solve::solve(
            op,
            sys,
            pts,
            p.tolerance as f64,
            p.max_iterations,
            &mut report,
        ),
    }
}

/// The final gather (crate::gather): the splats of the V-map leaves whose links misstate their
/// light take it from rays of their own, in `radiance` (per splat, solved); `specular` is the
/// specular links' transfer with its bins' density of the solution, which carries light to them
/// through mirrors and glass.
#[allow(clippy::too_many_arguments)]
fn final_gather(
    (view, rough, accel): (&OctreeView, &LazyRoughness, &Accel),
    vmap: &VmapFile,
    pts: &Points,
    sys: &System,
    radiance: &mut [[f32; 3]],
    specular: Option<(&SpecularTransfer, Vec<Vec3>)>,
    p: &FmmParams,
    backend: Backend,
) -> Result<gather::Gathered, FmmError> {
    let rays = gather::GatherRays::new(p.gather_rays);
    let how = gather::Selection::of(p);
    let leaves = match rays.strata {
        0 => Vec::new(),
        _ => gather::candidates(view, &vmap.view(), how),
    };
    if leaves.is_empty() {
        return Ok(Default::default());
    }
    let reflected = gather::reflected(radiance, &sys.emission, &pts.active);
    // The gather's rays pass over their own rough surface, as the V-map's do.
    let rough = rough.get();
    let gatherer = pc_stage::gpu_or_cpu(
        STAGE,
        backend,
        pc_stage::Work::Precompute,
        |ctx| {
            let g = gather::GpuGather::new(ctx, view, rough, &reflected)?;
            Ok::<_, FmmError>(gather::Gatherer::Gpu(Box::new(g)))
        },
        || {
            Ok(gather::Gatherer::cpu(
                (view, accel),
                rough,
                reflected.clone(),
            ))
        },
    )?;
    drop(reflected);
    let solved = gather::Solved {
        radiance,
        source: &sys.source,
        albedo: &sys.albedo,
        active: &pts.active,
    };
    let through = |splats: &[u32]| {
        specular
            .as_ref()
            .map(|(s, density)| s.at_splats(density, splats))
    };
    let g = gather::run(
        view,
        &vmap.view(),
        &leaves,
        solved,
        how,
        rays,
        &gatherer,
        &through,
    )?;
    for (&i, l) in g.splats.iter().zip(&g.radiance) {
        radiance[i as usize] = *l;
    }
    Ok(g)
}

/// Run the stage.
pub fn run(
    cfg: &LoadedConfig,
    inputs: &Inputs,
    out: &Path,
    backend: Backend,
    progress: &dyn Progress,
) -> Result<Summary, FmmError> {
    pc_stage::look_early(backend, pc_stage::Work::Precompute);
    let started = Instant::now();
    let mut timings = Vec::new();
    let mut time =
        |what: &str, t: Instant| timings.push((what.to_string(), t.elapsed().as_secs_f64()));
    let octree = OctreeFile::open(&inputs.octree)?;
    let view = octree.view();
    // Each octree leaf's roughness, when the point lights' shadow rays or the final gather first
    // need it.
    let rough = LazyRoughness::new(&view);
    // The CPU walk with its own surfaces, for the emitters' and point lights' shadow rays and
    // the final gather's rays (built once: at 20M points a pass over 2 GB of listed disks).
    let caster = CpuCaster::new(&view);
    let lights = &cfg.config.lights;
    let vmap = VmapFile::open(&inputs.vmap, &octree.id(), lights)?;
    let photons = match inputs.photons.wanted() {
        true => Some(PhotonsFile::open(inputs.photons.path(), &octree.id())?),
        false => None,
    };
    let materials = cfg.materials_for(&octree)?;
    let p = cfg.config.fmm.params;

    progress.phase("tree");
    let t = Instant::now();
    let (tree, pts) = tree::build(&view, &materials);
    time("tree", t);

    progress.phase("direct light");
    let t = Instant::now();
    let (sys, emitter, caustic) = source_term(
        &view,
        &materials,
        &pts,
        &vmap,
        photons.as_ref(),
        (cfg, &rough, &caster),
    )?;
    time("source term", t);

    // On a large scan the unknowns are clusters of splats (crate::cluster).
    let v = vmap.view();
    let t = Instant::now();
    let clusters = Clustering::new(&view, &tree, &pts, v.vnode, p.max_elements);
    let elements = clusters.as_ref().map_or(0, |c| c.points.pos.len() as u64);
    if elements > p.max_elements {
        progress.note(&format!(
            "pc-fmm: {elements} elements, more than fmm.max_elements = {}: the solve goes no \
             coarser than the V-map's leaves (a lower vmap.full_resolution_splats makes them larger)",
            p.max_elements
        ));
    }
    let (s_tree, s_pts, s_sys) = match &clusters {
        Some(c) => {
            time("clusters", t);
            (&c.tree, &c.points, Cow::Owned(c.system(&sys, &pts)))
        }
        None => (&tree, &pts, Cow::Borrowed(&sys)),
    };

    progress.phase("interaction plan");
    let t = Instant::now();
    let plan_params = PlanParams {
        theta: p.theta,
        clamp_tol: p.clamp_tol,
    };
    let plan = plan::build(s_tree, s_pts, v.link_offsets, v.links, plan_params);
    time("plan", t);

    // Light through mirrors and glass between diffuse splats: pc-caustics' specular links.
    let links = photons
        .as_ref()
        .map(|f| f.view().specular)
        .unwrap_or_default();
    let specular = SpecularTransfer::new(links, &pts, clusters.as_ref());
    let basis = Basis::new(p.order as usize);
    let mut op = operator(backend, &basis, s_tree, s_pts, &plan)?;
    if let Some(transfer) = &specular {
        op = Box::new(WithSpecular {
            inner: op,
            transfer,
        });
    }
    let device = op.device();
    progress.phase("solve");
    let t = Instant::now();
    let mut sol = solve(op.as_mut(), &s_sys, s_pts, &p, progress)?;
    // What the links carry of the solution, for the final gather's splats.
    let specular = specular.as_ref().map(|s| {
        let unknowns = gather::reflected(&sol.radiance, &s_sys.emission, &s_pts.active);
        (s, s.density(&unknowns))
    });
    let mut solved = match &clusters {
        Some(c) => c.radiance(op.as_mut(), &sol, &s_sys, &sys)?,
        None => std::mem::take(&mut sol.radiance),
    };
    let solve_s = t.elapsed().as_secs_f64();
    time("solve", t);
    if let Some(why) = below_source(&solved, &sys.source, &pts.active, p.tolerance) {
        eprintln!(
            "pc-fmm: warning: the solution is not physical: {why}. The solve diverged: the \
             transport gains energy (splat areas that sum to more than the surface) or has \
             negative terms, and the render will be wrong; docs/fmm.md, \"A solve that is \
             not physical\""
        );
    }
    // The operator and its plan (GBs at 20M splats) make room for the final gather's walk.
    drop(op);
    let counts = plan.counts;
    drop(plan);

    progress.phase("final gather");
    let t = Instant::now();
    let scene = (&view, &rough, &caster.accel);
    let gathered = final_gather(scene, &vmap, &pts, &sys, &mut solved, specular, &p, backend)?;
    time("final gather", t);
    timings.push((
        "per iteration".to_string(),
        solve_s / sol.residuals.len().max(1) as f64,
    ));

    let key = radiosity_key(
        &octree.key(),
        &vmap.key(),
        photons.as_ref().map(|p| p.key()).as_ref(),
        &p,
        &materials,
        lights,
    );
    // The stored radiance: every bounce but the caustic energy's first (shown from the photon
    // map), zero for inactive splats.
    let radiance: Vec<[f32; 3]> = solved
        .iter()
        .zip(&pts.active)
        .zip(&caustic)
        .map(|((l, &a), c)| match a {
            true => std::array::from_fn(|k| (l[k] - c[k]).max(0.0)),
            false => [0.0; 3],
        })
        .collect();
    let meta = RadiosityMeta {
        octree_key: octree.key().to_string(),
        vmap_key: vmap.key().to_string(),
        photons_key: photons.as_ref().map(|a| a.key().to_string()),
        params: p,
        iterations: sol.residuals.len() as u32,
        converged: sol.converged,
        residuals: sol.residuals.clone(),
        orders: sol.orders.clone(),
        active_splats: pts.active.iter().filter(|&&a| a).count() as u64,
        elements,
        m2l: counts.m2l,
        p2l: counts.p2l,
        m2p: counts.m2p,
        p2p: counts.p2p,
        p2p_pairs: counts.p2p_pairs,
        emitter_samples: emitter.samples,
        emitter_rays: emitter.cast,
        emitter_settled: emitter.settled,
        gather_candidates: gathered.candidates,
        gather_piloted: gathered.piloted,
        gathered_splats: gathered.splats.len() as u64,
        gather_rays_cast: gathered.rays,
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
/// config (nothing is solved). The photon map counts when it is read, as in [`run`].
pub fn key(cfg: &LoadedConfig, inputs: &Inputs) -> Result<Key, FmmError> {
    // The inputs' keys from their headers; a run checks the materials against the octree's.
    let octree = Artifact::input_key(&inputs.octree, ArtifactKind::Octree)?;
    let vmap = Artifact::input_key(&inputs.vmap, ArtifactKind::Vmap)?;
    let photons = match inputs.photons.wanted() {
        true => Some(Artifact::input_key(
            inputs.photons.path(),
            ArtifactKind::Photons,
        )?),
        false => None,
    };
    let materials = cfg.material_records();
    Ok(radiosity_key(
        &octree,
        &vmap,
        photons.as_ref(),
        &cfg.config.fmm.params,
        &materials,
        &cfg.config.lights,
    ))
}

/// The artifact key: stage, build, octree and V-map keys, parameters, materials and lights.
pub fn radiosity_key(
    octree: &Key,
    vmap: &Key,
    photons: Option<&Key>,
    p: &FmmParams,
    materials: &[MaterialRecord],
    lights: &[PointLight],
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
        .update_serialize(lights);
    h.finish()
}

/// Where a solve is not physical: the light a splat sends back out, `L = E + ρ T (L − Lₑ)`, is
/// at least its source `E` when `T` and `ρ` are not negative, so a channel in which more than
/// [`BELOW_SOURCE_SHARE`] of the active splats come out below their source has diverged. Below
/// means by more than 1 % of the splat's source and `tolerance` (the solve's relative residual)
/// times the channel's RMS source over the active splats: a solve that stopped at that residual,
/// with an operator that is itself approximate, may leave each splat off by about that much, and
/// the splats in the dark (under a box, a box's bottom face) come out a little either side of
/// zero (the full-resolution 1M Cornell box: 1.2 % of its splats at −8.6·10⁻⁴ to 0, its RMS
/// source 1.4; a diverged channel is off by its whole scale). Returns what it found, channel by
/// channel.
pub fn below_source(
    radiance: &[[f32; 3]],
    source: &[[f32; 3]],
    active: &[bool],
    tolerance: f32,
) -> Option<String> {
    let active_count = active.iter().filter(|a| **a).count().max(1);
    let found: Vec<String> = (0..3)
        .filter_map(|k| {
            let squares: f64 = source
                .par_iter()
                .zip(active)
                .filter(|(_, a)| **a)
                .map(|(e, _)| (e[k] as f64).powi(2))
                .sum();
            let allowance = tolerance * (squares / active_count as f64).sqrt() as f32;
            let below = radiance
                .par_iter()
                .zip(source)
                .zip(active)
                .filter(|((l, e), a)| **a && l[k] < e[k] - 1e-2 * e[k].abs() - allowance - 1e-12)
                .count();
            let share = below as f64 / active_count as f64;
            (share > BELOW_SOURCE_SHARE).then(|| {
                format!(
                    "{} radiance below its own source at {:.1} % of the splats",
                    ["red", "green", "blue"][k],
                    100.0 * share
                )
            })
        })
        .collect();
    (!found.is_empty()).then(|| found.join(", "))
}

/// The share of splats below their source past which [`below_source`] reports a channel.
pub const BELOW_SOURCE_SHARE: f64 = 0.01;

/// pc-fmm as its binary runs it.
pub struct FmmStage {
    pub cfg: LoadedConfig,
    pub inputs: Inputs,
    pub output: PathBuf,
    pub backend: Backend,
}

impl Stage for FmmStage {
    const NAME: &'static str = STAGE;
    const DOING: &'static str = "solving the radiosity";
    const KIND: Option<ArtifactKind> = Some(ArtifactKind::Radiosity);
    type Made = Summary;
    type Error = FmmError;

    fn output(&self) -> &Path {
        &self.output
    }

    fn key(&self) -> Result<Key, FmmError> {
        key(&self.cfg, &self.inputs)
    }

    fn run(&self, progress: &dyn Progress) -> Result<Summary, FmmError> {
        run(
            &self.cfg,
            &self.inputs,
            &self.output,
            self.backend,
            progress,
        )
    }

    fn summary(&self, s: &Summary, _seconds: f64) -> String {
        let m = &s.meta;
        let per_it = m
            .timings
            .iter()
            .find(|t| t.0 == "per iteration")
            .map_or(0.0, |t| t.1);
        format!(
            "pc-fmm: wrote {} ({} splats{}, {} iterations{}, residual {:.2e}, {:.3} s per iteration; tasks: {} M2L, {} P2L, {} M2P, {} P2P over {} pairs; {} splats gathered) in {:.2} s on {}",
            s.path.display(),
            m.active_splats,
            match m.elements {
                0 => String::new(),
                e => format!(" solved as {e} clusters"),
            },
            m.iterations,
            if m.converged { "" } else { " (not converged)" },
            m.residuals.last().copied().unwrap_or(0.0),
            per_it,
            m.m2l,
            m.p2l,
            m.m2p,
            m.p2p,
            m.p2p_pairs,
            m.gathered_splats,
            s.seconds,
            m.device
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_channel_below_its_source_is_reported_and_a_physical_one_is_not() {
        let source = vec![[0.2f32, 0.1, 0.0]; 1000];
        let mut radiance = vec![[0.3f32, 0.15, 0.0]; 1000];
        let active = vec![true; 1000];
        let tol = 1e-3;
        assert_eq!(below_source(&radiance, &source, &active, tol), None);
        // The solve's own tolerance below the source is not reported.
        radiance[0] = [0.1995, 0.0999, 0.0];
        assert_eq!(below_source(&radiance, &source, &active, tol), None);
        // A diverged red channel (negative, as the 20M hall's was) is.
        for l in &mut radiance[..500] {
            l[0] = -0.4;
        }
        let why = below_source(&radiance, &source, &active, tol).unwrap();
        assert_eq!(
            why,
            "red radiance below its own source at 50.0 % of the splats"
        );
        // Inactive splats do not count.
        let inactive: Vec<bool> = (0..1000).map(|i| i >= 500).collect();
        assert_eq!(below_source(&radiance, &source, &inactive, tol), None);
    }

    #[test]
    fn dark_splats_a_little_below_zero_are_within_the_solves_tolerance() {
        // A lit half (source 1) and a dark half (source 0), as under a box: the dark splats'
        // radiance comes out a little either side of zero. The RMS source is √½, so the
        // allowance at tolerance 10⁻³ is 7.1·10⁻⁴.
        let source: Vec<[f32; 3]> = (0..1000).map(|i| [(i < 500) as u32 as f32; 3]).collect();
        let active = vec![true; 1000];
        let mut radiance: Vec<[f32; 3]> = source.iter().map(|e| e.map(|x| 1.5 * x)).collect();
        for l in &mut radiance[500..] {
            *l = [-5e-4; 3];
        }
        assert_eq!(below_source(&radiance, &source, &active, 1e-3), None);
        // Ten times further below is more than the solve's tolerance explains.
        for l in &mut radiance[500..] {
            *l = [-5e-3; 3];
        }
        let why = below_source(&radiance, &source, &active, 1e-3).unwrap();
        assert!(
            why.starts_with("red radiance below its own source at 50.0 %"),
            "{why}"
        );
    }
}
