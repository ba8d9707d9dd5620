//! pc-raybench: rays per second of the octree traversal, CPU (rayon) and GPU, for coherent
//! primary rays and incoherent bounce rays (used by `cargo xtask bench`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Parser;
use glam::Vec3;
use pc_artifact::octree::tangent_frame;
use pc_artifact::octree::OctreeFile;
use pc_artifact::photons::PhotonMapFile;
use pc_raytrace::camera::Camera;
use pc_raytrace::sample::rand;
use pc_tree::{OctreeView, Ray, TraversalStats};
use rayon::prelude::*;

/// Measure traversal speed on an octree artifact.
#[derive(Parser)]
#[command(name = "pc-raybench", version)]
struct Args {
    /// The pipeline description (camera, output folder).
    #[arg(long, default_value = "pipeline.toml")]
    config: PathBuf,
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Primary rays: one per pixel centre of a WIDTH×WIDTH image from the config's camera.
    #[arg(long, default_value_t = 1024)]
    width: u32,
    /// Incoherent rays: from random splats, cosine-distributed about their normals.
    #[arg(long, default_value_t = 1_000_000)]
    incoherent: usize,
    /// Skip the GPU even when an adapter exists.
    #[arg(long)]
    cpu_only: bool,
    /// Also time the caustic lookup (pc-caustics' photon map, `<output.dir>/<caustics.file>`) at
    /// the diffuse hits of the primary rays: the CPU renderer's kd-tree (fixed radius and
    /// k-nearest) and the GPU renderer's hashed grid, on the CPU.
    #[arg(long)]
    caustics: bool,
    /// Write the results here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also write the disks, both ray sets and this traversal's first hits as raw little-endian
    /// arrays into this folder, for a peer ray tracer to trace the same rays (`cargo xtask bench
    /// --only rays --peer embree`; the layout is in xtask/peer/embree_rays.c).
    #[arg(long, value_name = "DIR")]
    dump: Option<PathBuf>,
}

fn main() -> ExitCode {
    match run(&Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pc-raybench: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn cpu_rate(view: &OctreeView, accel: &pc_tree::accel::Accel, rays: &[Ray]) -> (f64, u64) {
    let t = Instant::now();
    let hits: u64 = rays
        .par_iter()
        .map_init(TraversalStats::default, |st, r| {
            accel.intersect(view, r, st).is_some() as u64
        })
        .sum();
    (rays.len() as f64 / t.elapsed().as_secs_f64(), hits)
}

/// Mean cells visited and disks tested per ray (a separate, uncounted-time pass): the
/// renderer's packed walk (disk lanes of the leaves its slabs do not skip), and the artifact's
/// plain walk (every listed disk of every leaf crossed).
fn work(view: &OctreeView, accel: Option<&pc_tree::accel::Accel>, rays: &[Ray]) -> (f64, f64) {
    let mut st = TraversalStats::default();
    for r in rays.iter().step_by(16) {
        match accel {
            Some(a) => a.intersect(view, r, &mut st),
            None => pc_tree::intersect(view, r, &mut st),
        };
    }
    let n = rays.len().div_ceil(16) as f64;
    (st.cells as f64 / n, st.splat_tests as f64 / n)
}

fn run(args: &Args) -> anyhow::Result<()> {
    let mut set = args.set.clone();
    set.push(format!("camera.width={}", args.width));
    set.push(format!("camera.height={}", args.width));
    let cfg = pc_config::load_config(&args.config, &set)?;
    let art = OctreeFile::open(cfg.octree_path())?;
    let view = art.view();
    let cam = Camera::new(&cfg.config.camera);
    let primary = primary_rays(&cam, args.width);
    let incoherent = incoherent_rays(&view, args.incoherent);
    let shadow = shadow_rays(&view, args.incoherent);
    // The renderer's packed leaf lists (built once per render, not timed here).
    let t = Instant::now();
    let accel = pc_tree::accel::Accel::new(&view);
    eprintln!(
        "pc-raybench: packed leaf lists: {:.0} MiB in {:.2} s",
        accel.memory() as f64 / 1048576.0,
        t.elapsed().as_secs_f64()
    );
    // Warm up (page in the mapped artifact), then measure.
    let _ = cpu_rate(&view, &accel, &primary[..primary.len().min(10_000)]);
    let (cpu_primary, primary_hits) = cpu_rate(&view, &accel, &primary);
    let cpu_bounded = camera_rate(&view, &accel, &cam, &primary, cpu_primary)?;
    let (cpu_incoherent, incoherent_hits) = cpu_rate(&view, &accel, &incoherent);
    let t = Instant::now();
    let blocked = accel
        .visible(&view, &shadow)
        .iter()
        .filter(|v| !**v)
        .count();
    let cpu_shadow = shadow.len() as f64 / t.elapsed().as_secs_f64();
    report_work(&view, &accel, [&primary, &incoherent, &shadow]);
    if let Some(dir) = &args.dump {
        dump(dir, &view, &accel, [&primary, &incoherent, &shadow])?;
    }
    let caustic_json = match args.caustics {
        true => caustic_lookups(&cfg, &art, &view, &accel, &primary)?,
        false => "null".to_string(),
    };
    let (gpu, line) = match args.cpu_only {
        true => ("null".to_string(), String::new()),
        false => gpu_rates(&view, &primary, &incoherent),
    };
    let threads = rayon::current_num_threads();
    println!(
        "pc-raybench: {} splats, {} threads: CPU primary {:.2} M rays/s ({} of {} hit; from their pixel's bound {:.2} M rays/s with the bounds' pass, the same hits), incoherent {:.2} M rays/s ({} of {} hit), shadow {:.2} M rays/s ({blocked} of {} blocked){line}",
        view.splats.len(),
        threads,
        cpu_primary / 1e6,
        primary_hits,
        primary.len(),
        cpu_bounded / 1e6,
        cpu_incoherent / 1e6,
        incoherent_hits,
        incoherent.len(),
        cpu_shadow / 1e6,
        shadow.len()
    );
    if let Some(path) = &args.json {
        let json = format!(
            "{{\"splats\": {}, \"threads\": {threads}, \"primary_rays\": {}, \"cpu_primary_rays_per_s\": {cpu_primary:.0}, \"cpu_bounded_primary_rays_per_s\": {cpu_bounded:.0}, \"incoherent_rays\": {}, \"cpu_incoherent_rays_per_s\": {cpu_incoherent:.0}, \"shadow_rays\": {}, \"cpu_shadow_rays_per_s\": {cpu_shadow:.0}, \"gpu\": {gpu}, \"caustic\": {caustic_json}}}\n",
            view.splats.len(),
            primary.len(),
            incoherent.len(),
            shadow.len()
        );
        std::fs::write(path, json).with_context(|| path.display().to_string())?;
    }
    Ok(())
}

/// One ray through each pixel centre of a `width`×`width` image from `cam`.
fn primary_rays(cam: &Camera, width: u32) -> Vec<Ray> {
    (0..width * width)
        .map(|i| {
            Ray::new(
                cam.origin,
                cam.pixel_direction(i % width, i / width, 0.5, 0.5),
            )
        })
        .collect()
}

/// `count` bounce rays: each from a random splat, cosine-distributed about its normal.
fn incoherent_rays(view: &OctreeView, count: usize) -> Vec<Ray> {
    let n = view.splats.len() as u32;
    (0..count as u32)
        .map(|i| {
            let s = &view.splats[((rand(1, i, 0, 0) * n as f32) as u32).min(n - 1) as usize];
            let (u, v) = tangent_frame(s.normal);
            let (r1, r2) = (rand(1, i, 0, 1), rand(1, i, 0, 2));
            let (rr, phi) = (r1.sqrt(), std::f32::consts::TAU * r2);
            let d = Vec3::from(u) * rr * phi.cos()
                + Vec3::from(v) * rr * phi.sin()
                + Vec3::from(s.normal) * (1.0 - r1).max(0.0).sqrt();
            Ray {
                origin: Vec3::from(s.position),
                dir: d.normalize(),
                t_min: 0.5 * s.radius,
                t_max: f32::INFINITY,
            }
        })
        .collect()
}

/// `count` shadow rays: segments between two random splats that face each other (what the
/// V-map's links and the emitters' shadow rays test).
fn shadow_rays(view: &OctreeView, count: usize) -> Vec<Ray> {
    let n = view.splats.len() as u32;
    (0..count as u32)
        .map(|i| {
            let pick =
                |d: u32| &view.splats[((rand(2, i, 0, d) * n as f32) as u32).min(n - 1) as usize];
            let a = pick(0);
            let pa = Vec3::from(a.position);
            // The first of a few candidates in front of `a` and facing it (or the last).
            let b = (1..64)
                .map(pick)
                .find(|b| {
                    let d = Vec3::from(b.position) - pa;
                    d.dot(Vec3::from(a.normal)) > 0.0 && d.dot(Vec3::from(b.normal)) < 0.0
                })
                .unwrap_or_else(|| pick(64));
            let pb = Vec3::from(b.position);
            let len = (pb - pa).length();
            Ray {
                origin: pa,
                dir: (pb - pa) / len.max(1e-30),
                t_min: 0.5 * a.radius,
                t_max: (len - 0.5 * b.radius).max(0.0),
            }
        })
        .collect()
}

/// The renderer's camera rays per second: the `primary` rays from their pixel's bound, the
/// bounds' pass (once per frame) timed with them; where the pass would not pay, the renderer
/// casts them from the camera, at the primary rays' rate (`plain`). An error where any of them
/// hits elsewhere than from the camera.
fn camera_rate(
    view: &OctreeView,
    accel: &pc_tree::accel::Accel,
    cam: &Camera,
    primary: &[Ray],
    plain: f64,
) -> anyhow::Result<f64> {
    let pays = pc_raytrace::camera_near::pays(view.splats.len(), primary.len() as u64);
    let t = Instant::now();
    let near = pc_raytrace::camera_near::near_bounds(view, cam);
    let bounded: Vec<Ray> = primary
        .iter()
        .zip(&near)
        .map(|(r, &d)| Ray { t_min: d, ..*r })
        .collect();
    let bounds_s = t.elapsed().as_secs_f64();
    eprintln!(
        "pc-raybench: the camera rays' bounds: {:.3} s over {} splats{}",
        bounds_s,
        view.splats.len(),
        match pays {
            true => "",
            false => " (over four splats a ray: the renderer would not make them)",
        }
    );
    let (bounded_rate, _) = cpu_rate(view, accel, &bounded);
    let differ = primary
        .par_iter()
        .zip(&bounded)
        .filter(|(a, b)| {
            let mut st = TraversalStats::default();
            accel.intersect(view, a, &mut st) != accel.intersect(view, b, &mut st)
        })
        .count();
    anyhow::ensure!(
        differ == 0,
        "{differ} camera rays hit elsewhere from their pixel's bound than from the camera"
    );
    Ok(match pays {
        true => bounded.len() as f64 / (bounds_s + bounded.len() as f64 / bounded_rate),
        false => plain,
    })
}

/// Prints the cells and disks per ray of each ray set, for the plain and the packed walk.
fn report_work(
    view: &OctreeView,
    accel: &pc_tree::accel::Accel,
    [primary, incoherent, shadow]: [&[Ray]; 3],
) {
    let (pc, pt) = work(view, None, primary);
    let (ic, it) = work(view, None, incoherent);
    let (apc, apt) = work(view, Some(accel), primary);
    let (aic, ait) = work(view, Some(accel), incoherent);
    let (sc, st) = work(view, None, shadow);
    let (asc, ast) = work(view, Some(accel), shadow);
    eprintln!(
        "pc-raybench: per primary ray {pc:.1} cells, {pt:.1} listed disks ({apc:.1} cells, {apt:.1} \
         disk lanes tested by the packed walk); per incoherent ray {ic:.1} cells, {it:.1} listed \
         disks ({aic:.1}, {ait:.1}); per shadow ray {sc:.1} cells, {st:.1} listed disks ({asc:.1}, \
         {ast:.1}, to the nearest hit)"
    );
}

/// The GPU's primary and incoherent ray rates where wgpu finds an adapter: the JSON object
/// (`null` without an adapter) and the summary line's part.
fn gpu_rates(view: &OctreeView, primary: &[Ray], incoherent: &[Ray]) -> (String, String) {
    let Ok(ctx) = pc_gpu::GpuContext::new() else {
        return ("null".to_string(), String::new());
    };
    let measured = (|| -> anyhow::Result<[GpuRate; 2]> {
        let caster = pc_tree::gpu::RayCaster::new(&ctx, view)?;
        let time = |rays: &[Ray]| -> anyhow::Result<GpuRate> {
            let input: Vec<pc_tree::gpu::RayIn> = rays.iter().map(Into::into).collect();
            caster.cast(&ctx, &input[..input.len().min(4096)], false)?;
            let before = dispatch_seconds();
            let t = Instant::now();
            caster.cast(&ctx, &input, false)?;
            let n = rays.len() as f64;
            Ok(GpuRate {
                whole: n / t.elapsed().as_secs_f64(),
                kernel: n / (dispatch_seconds() - before).max(1e-9),
            })
        };
        Ok([time(primary)?, time(incoherent)?])
    })();
    let name = ctx.describe().replace('"', "'");
    match measured {
        Ok([p, i]) => (
            format!(
                "{{\"device\": \"{name}\", \"primary_rays_per_s\": {:.0}, \"incoherent_rays_per_s\": {:.0}, \"primary_kernel_rays_per_s\": {:.0}, \"incoherent_kernel_rays_per_s\": {:.0}}}",
                p.whole, i.whole, p.kernel, i.kernel
            ),
            format!(
                ", GPU {name} primary {:.2} M/s incoherent {:.2} M/s (kernels alone: {:.1} and {:.1} M/s)",
                p.whole / 1e6,
                i.whole / 1e6,
                p.kernel / 1e6,
                i.kernel / 1e6
            ),
        ),
        Err(e) => {
            let msg = format!("{e:#}").replace('"', "'");
            eprintln!("pc-raybench: GPU not measured: {msg}");
            (
                format!("{{\"device\": \"{name}\", \"error\": \"{msg}\"}}"),
                String::new(),
            )
        }
    }
}

/// The peer's input and pcgi's answer (`--dump`): `disks.f32` (per splat x y z r nx ny nz
/// clipped), `primary.f32` / `incoherent.f32` / `shadow.f32` (per ray ox oy oz t_min dx dy dz
/// t_max), `primary.pcgi` / `incoherent.pcgi` (per ray the hit distance, +inf for a miss, then
/// the splat index as f32 bits) and `shadow.pcgi` (per ray 1 where the segment is blocked,
/// else 0), all f32 little-endian.
fn dump(
    dir: &std::path::Path,
    view: &OctreeView,
    accel: &pc_tree::accel::Accel,
    [primary, incoherent, shadow]: [&[Ray]; 3],
) -> anyhow::Result<()> {
    let write = |name: &str, v: &[f32]| -> anyhow::Result<()> {
        let path = dir.join(name);
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        pc_artifact::atomic::write_file_atomically(&path, &bytes)
            .with_context(|| path.display().to_string())
    };
    std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    let disks: Vec<f32> = view
        .splats
        .iter()
        .flat_map(|s| {
            let [x, y, z] = s.position;
            let [a, b, c] = s.normal;
            let clipped = (s.clip != [0.0; 4]) as u32 as f32;
            [x, y, z, s.radius, a, b, c, clipped]
        })
        .collect();
    write("disks.f32", &disks)?;
    for (name, rays) in [
        ("primary", primary),
        ("incoherent", incoherent),
        ("shadow", shadow),
    ] {
        let r: Vec<f32> = rays
            .iter()
            .flat_map(|r| {
                let (o, d) = (r.origin, r.dir);
                [o.x, o.y, o.z, r.t_min, d.x, d.y, d.z, r.t_max]
            })
            .collect();
        write(&format!("{name}.f32"), &r)?;
    }
    for (name, rays) in [("primary", primary), ("incoherent", incoherent)] {
        let hits: Vec<f32> = rays
            .par_iter()
            .map_init(TraversalStats::default, |st, r| {
                match accel.intersect(view, r, st) {
                    Some(h) => [h.t, f32::from_bits(h.splat)],
                    None => [f32::INFINITY, f32::from_bits(u32::MAX)],
                }
            })
            .flatten_iter()
            .collect();
        write(&format!("{name}.pcgi"), &hits)?;
    }
    let blocked: Vec<f32> = accel
        .visible(view, shadow)
        .iter()
        .map(|&v| if v { 0.0 } else { 1.0 })
        .collect();
    write("shadow.pcgi", &blocked)
}

/// Time the caustic lookups at the primary rays' diffuse hits; returns the JSON object.
fn caustic_lookups(
    cfg: &pc_config::LoadedConfig,
    art: &OctreeFile,
    view: &OctreeView,
    accel: &pc_tree::accel::Accel,
    primary: &[Ray],
) -> anyhow::Result<String> {
    use pc_artifact::octree::class;
    use pc_raytrace::caustic::PhotonGrid;
    use pc_raytrace::photon_lanes::PhotonLanes;
    let path = cfg.photons_path();
    let pa = PhotonMapFile::open(&path, &art.id())?;
    let rt = &cfg.config.raytrace;
    let radius = pc_raytrace::stage::caustic_radius(rt, view);
    let pv = pa.view();
    let mut c = pc_raytrace::caustic::Caustics::new(pv.photons, radius, 0);
    let materials = cfg.materials_for(art)?;
    let hits: Vec<(Vec3, Vec3)> = primary
        .par_iter()
        .map_init(TraversalStats::default, |st, r| {
            let h = accel.intersect(view, r, st)?;
            let s = &view.splats[h.splat as usize];
            let n = Vec3::from(s.normal);
            (materials[s.material as usize].class == class::DIFFUSE && n.dot(r.dir) < 0.0)
                .then(|| (r.origin + r.dir * h.t, n))
        })
        .flatten()
        .collect();
    let threads = rayon::current_num_threads() as f64;
    // Nanoseconds per lookup per thread, and the lookups that found photons.
    let time = |f: &(dyn Fn(Vec3, Vec3) -> Vec3 + Sync)| -> (f64, usize) {
        let t = Instant::now();
        let lit = hits.par_iter().filter(|(x, n)| f(*x, *n).x > 0.0).count();
        (
            t.elapsed().as_secs_f64() * threads * 1e9 / hits.len().max(1) as f64,
            lit,
        )
    };
    // The fixed-radius estimate through the kd-tree (the renderers read the grid, timed below;
    // this is the baseline the grid replaced): the photons within the radius that count
    // (`caustic::accept`), under the Epanechnikov kernel.
    let tree = c.tree();
    let kd_fixed = |x: Vec3, n: Vec3| -> Vec3 {
        use kiddo::SquaredEuclidean;
        let r2 = radius * radius;
        let found = tree
            .query(&x.to_array())
            .within::<SquaredEuclidean<f32>>(r2)
            .unsorted()
            .execute();
        let mut e = Vec3::ZERO;
        for f in &found {
            let p = &c.photons[f.item as usize];
            let d = Vec3::from(p.position) - x;
            if Vec3::from(p.dir).dot(n) < 0.0 && d.dot(n).abs() <= 0.25 * radius {
                e += Vec3::from(p.power) * (1.0 - f.distance / r2).max(0.0);
            }
        }
        e * (2.0 / (std::f32::consts::PI * r2))
    };
    let (kd_ns, lit) = time(&kd_fixed);
    let k = if rt.caustic_k > 0 { rt.caustic_k } else { 50 };
    c.k = k;
    let (knn_ns, _) = time(&|x, n| c.irradiance(x, n));
    c.k = 0;
    let t = Instant::now();
    let grid = PhotonGrid::new(c.photons, radius);
    let grid_build = t.elapsed().as_secs_f64();
    let (grid_ns, _) = time(&|x, n| grid.irradiance(x, n));
    // The CPU renderer's scan of the same grid, four photons at a time.
    let lanes = PhotonLanes::new(&grid);
    let (lanes_ns, _) = time(&|x, n| lanes.irradiance(&grid, x, n));
    // What a lookup reads in the grid (photons and groups): the mean, and the most, which is
    // what a GPU thread in a caustic's focus holds its warp for (docs/gpu.md).
    let reads: Vec<usize> = hits.par_iter().map(|(x, n)| grid.reads(*x, *n)).collect();
    let reads_mean = reads.iter().sum::<usize>() as f64 / reads.len().max(1) as f64;
    let reads_max = reads.iter().copied().max().unwrap_or(0);
    println!(
        "pc-raybench: caustic lookup at {} diffuse primary hits ({:.0} % near photons), {} photons, \
         radius {radius:.4}: kd-tree {kd_ns:.0} ns, k-nearest (k {k}) {knn_ns:.0} ns, hashed grid \
         {grid_ns:.0} ns photon by photon, {lanes_ns:.0} ns four at a time per lookup per thread (grid built in {grid_build:.3} s, {} groups; a lookup \
         reads {reads_mean:.1} photons and groups, at most {reads_max})",
        hits.len(),
        100.0 * lit as f64 / hits.len().max(1) as f64,
        c.photons.len(),
        grid.groups.len()
    );
    Ok(format!(
        "{{\"photons\": {}, \"lookups\": {}, \"found\": {lit}, \"radius\": {radius}, \"kdtree_ns\": {kd_ns:.1}, \"k\": {k}, \"knn_ns\": {knn_ns:.1}, \"grid_ns\": {grid_ns:.1}, \"lanes_ns\": {lanes_ns:.1}, \"grid_build_s\": {grid_build:.4}, \"groups\": {}, \"reads_mean\": {reads_mean:.2}, \"reads_max\": {reads_max}}}",
        c.photons.len(),
        hits.len(),
        grid.groups.len()
    ))
}

/// A GPU ray rate: rays per second from the host's upload to its readback (`whole`), and per
/// second of dispatches alone (`kernel`, from [`pc_gpu::times`]).
struct GpuRate {
    whole: f64,
    kernel: f64,
}

/// The process's dispatch seconds so far.
fn dispatch_seconds() -> f64 {
    pc_gpu::times().map_or(0.0, |t| t.dispatch_seconds)
}
