//! CPU against GPU: the WGSL twin (shaders/fmm/fmm.wgsl, pc_fmm::gpu) applies the same operator
//! as the CPU FMM to f32 rounding, for one product and for a few Jacobi iterations. Skipped
//! without a GPU adapter unless `PC_REQUIRE_GPU=1`.

use std::time::Instant;

use pc_fmm::gpu::GpuFmm;

use super::*;

/// Relative L2 difference of two per-splat fields.
fn rel_l2(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut e, mut n) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            e += ((x[c] - y[c]) as f64).powi(2);
            n += (y[c] as f64).powi(2);
        }
    }
    (e / n).sqrt()
}

struct Fixture {
    tree: tree::Tree,
    points: tree::Points,
    plan: pc_fmm::Plan,
}

/// The ~5.5k-splat box with its tree and plan.
fn fixture() -> Fixture {
    let soa = box_scene(0.07);
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let (tree, points, plan) = super::tree_and_plan(&sc, 0.5, 1e-5);
    println!(
        "{} splats, {} nodes, {} leaves, {} levels, tasks {:?}",
        points.pos.len(),
        tree.nodes.len(),
        tree.leaves.len(),
        tree.levels.len(),
        plan.counts
    );
    Fixture { tree, points, plan }
}

#[test]
fn gpu_product_matches_the_cpu() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let f = fixture();
    let n = f.points.pos.len();
    let radiance = varied_radiance(n);
    let mut first = Some(ctx);
    // Order 6 passes too (1.7e-8) but compiles for a minute on llvmpipe.
    for order in [0usize, 2, 4] {
        let basis = Basis::new(order);
        let cpu = CpuFmm::new(&basis, &f.tree, &f.points, &f.plan);
        let mut want = vec![[0.0f32; 3]; n];
        let t = Instant::now();
        cpu.apply(&radiance, &mut want, &mut PhaseTimes::default());
        let cpu_s = t.elapsed().as_secs_f64();
        // GpuFmm owns its context: the first order takes the test's, later ones open their own.
        let ctx = first
            .take()
            .unwrap_or_else(|| pc_gpu::GpuContext::new().unwrap());
        let t = Instant::now();
        let mut gpu = GpuFmm::new(ctx, &basis, &f.tree, &f.points, &f.plan).unwrap();
        let setup_s = t.elapsed().as_secs_f64();
        let mut got = vec![[f32::NAN; 3]; n];
        // The first application also finishes llvmpipe's shader compilation: time the second.
        gpu.apply(&radiance, &mut got).unwrap();
        let t = Instant::now();
        gpu.apply(&radiance, &mut got).unwrap();
        let gpu_s = t.elapsed().as_secs_f64();
        let d = rel_l2(&got, &want);
        println!(
            "order {order}: CPU vs {}: relative L2 difference {d:.3e} (CPU {cpu_s:.3} s, GPU setup {setup_s:.2} s, apply {gpu_s:.3} s in {} dispatches; items {:?}, loop bounds {:?})",
            gpu.device(),
            gpu.dispatches,
            gpu.items,
            gpu.loop_bounds
        );
        assert!(got.iter().all(|v| v.iter().all(|x| x.is_finite())));
        assert!(
            d < 1e-4,
            "order {order}: CPU vs GPU relative L2 difference {d:.3e}"
        );
        // A second application with other radiance reuses the resident data.
        let other: Vec<[f32; 3]> = radiance.iter().map(|l| [l[2], 2.0 * l[0], l[1]]).collect();
        cpu.apply(&other, &mut want, &mut PhaseTimes::default());
        gpu.apply(&other, &mut got).unwrap();
        let d2 = rel_l2(&got, &want);
        assert!(d2 < 1e-4, "order {order}, second product: {d2:.3e}");
    }
}

#[test]
fn gpu_solve_matches_the_cpu() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let f = fixture();
    let n = f.points.pos.len();
    let basis = Basis::new(4);
    // A source term (reflected direct light, not emission) on the splats near the ceiling.
    let source: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            if f.points.pos[i][1] > 0.9 {
                [4.0, 3.0, 2.0]
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let albedo: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let x = i as f32 * 0.37;
            [0.6 + 0.2 * x.sin(), 0.5, 0.4 + 0.1 * x.cos()]
        })
        .collect();
    let sys = pc_fmm::System {
        source,
        emission: vec![[0.0; 3]; n],
        albedo,
    };
    let mut cpu = CpuOperator {
        fmm: CpuFmm::new(&basis, &f.tree, &f.points, &f.plan),
        times: Default::default(),
        applications: 0,
    };
    let iterations = 6;
    let t = Instant::now();
    let a = solve::solve(&mut cpu, &sys, &f.points, 0.0, iterations, &mut |_, _| {}).unwrap();
    let cpu_s = t.elapsed().as_secs_f64();
    let mut gpu = GpuFmm::new(ctx, &basis, &f.tree, &f.points, &f.plan).unwrap();
    let t = Instant::now();
    let b = solve::solve(&mut gpu, &sys, &f.points, 0.0, iterations, &mut |_, _| {}).unwrap();
    let gpu_s = t.elapsed().as_secs_f64();
    let d = rel_l2(&b.radiance, &a.radiance);
    println!(
        "{iterations} Jacobi iterations: CPU residuals {:?}, GPU residuals {:?}, radiance relative L2 difference {d:.3e} (CPU {cpu_s:.2} s, {} {gpu_s:.2} s)",
        a.residuals,
        b.residuals,
        gpu.device()
    );
    assert_eq!(gpu.applications, iterations);
    assert!(d < 1e-4, "solve: CPU vs GPU relative L2 difference {d:.3e}");
    for (x, y) in a.residuals.iter().zip(&b.residuals) {
        assert!(
            (x - y).abs() <= 1e-3 * x.abs(),
            "residuals {:?} vs {:?}",
            a.residuals,
            b.residuals
        );
    }
}

/// Receivers far heavier than any the fixture's plan has, on both sides: 70,000 more M2L tasks
/// to the first node and 3,000 more P2P tasks to the whole first leaf. One invocation per
/// receiver would loop past llvmpipe's budget (its shaders end after 65535 iterations per
/// invocation group); cut into work items, the product runs and still matches the CPU.
#[test]
fn gpu_cuts_heavy_receivers_into_items() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let f = fixture();
    let mut plan = f.plan.clone();
    let src = f.tree.leaves[0];
    let extra = 70_000u32;
    plan.node_tasks.splice(
        0..0,
        (0..extra).map(|_| pc_fmm::plan::NodeTask {
            src,
            fraction: 1e-5,
        }),
    );
    for o in plan.node_offsets.iter_mut().skip(1) {
        *o += extra;
    }
    let (recv, from) = (f.tree.leaves[0] as usize, f.tree.leaves[1] as usize);
    let extra = 3_000u32;
    plan.leaf_tasks.splice(
        0..0,
        (0..extra).map(|_| pc_fmm::plan::LeafTask {
            recv_lo: f.tree.lo[recv],
            recv_hi: f.tree.hi[recv],
            src_lo: f.tree.lo[from],
            src_hi: f.tree.hi[from],
            fraction: 1e-4,
        }),
    );
    for o in plan.leaf_offsets.iter_mut().skip(1) {
        *o += extra;
    }
    let work = pc_fmm::gpu_work::Work::new(&f.tree, &f.points, &plan).unwrap();
    let bounds = work.loop_bounds(&f.tree, 8);
    println!(
        "{} splat items, {} node items, {} spare expansions; loop bounds {bounds:?}",
        work.splat_items.len(),
        work.node_items.len(),
        work.spares
    );
    assert!(work.spares as usize >= 70_000 / 128, "{}", work.spares);
    let heavy = (f.tree.hi[recv] - f.tree.lo[recv]) as usize;
    let active = f.points.active.iter().filter(|&&a| a).count();
    assert!(work.splat_items.len() > active + heavy);
    assert!(bounds.iter().all(|b| b.1 <= 65_535), "{bounds:?}");

    let basis = Basis::new(2);
    let n = f.points.pos.len();
    let radiance = varied_radiance(n);
    let cpu = CpuFmm::new(&basis, &f.tree, &f.points, &plan);
    let mut want = vec![[0.0f32; 3]; n];
    cpu.apply(&radiance, &mut want, &mut PhaseTimes::default());
    let mut gpu = GpuFmm::new(ctx, &basis, &f.tree, &f.points, &plan).unwrap();
    let mut got = vec![[f32::NAN; 3]; n];
    gpu.apply(&radiance, &mut got).unwrap();
    let d = rel_l2(&got, &want);
    println!("CPU vs {}: relative L2 difference {d:.3e}", gpu.device());
    assert!(got.iter().all(|v| v.iter().all(|x| x.is_finite())));
    assert!(d < 1e-4, "CPU vs GPU relative L2 difference {d:.3e}");
}

/// Task arrays larger than one binding (the 1M plan's splat tasks on llvmpipe, 128 MiB) are
/// bound in windows, one dispatch per window: windows of 64 KiB on the fixture give the same
/// output, bit for bit, as one window.
#[test]
fn gpu_binds_task_arrays_in_windows() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let f = fixture();
    let basis = Basis::new(2);
    let n = f.points.pos.len();
    let radiance = varied_radiance(n);
    let mut whole = GpuFmm::new(ctx, &basis, &f.tree, &f.points, &f.plan).unwrap();
    let mut a = vec![[f32::NAN; 3]; n];
    whole.apply(&radiance, &mut a).unwrap();
    let ctx = pc_gpu::GpuContext::new().unwrap();
    let mut windowed =
        GpuFmm::with_task_window(ctx, &basis, &f.tree, &f.points, &f.plan, 1 << 16).unwrap();
    let mut b = vec![[f32::NAN; 3]; n];
    windowed.apply(&radiance, &mut b).unwrap();
    println!(
        "{} dispatches in one window, {} in 64 KiB windows",
        whole.dispatches, windowed.dispatches
    );
    assert!(windowed.dispatches > whole.dispatches + 10);
    assert!(a.iter().flatten().all(|x| x.is_finite()));
    assert_eq!(a, b);
}

/// Relaxed products (GMRES's later iterations) run kernels of lower orders on the GPU too: the
/// orders the CPU picks, with the CPU's results.
#[test]
fn gpu_relaxed_products_match_the_cpus() {
    use pc_fmm::Operator as _;
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let f = fixture();
    let basis = Basis::new(3);
    let n = f.points.pos.len();
    let radiance = varied_radiance(n);
    let mut cpu = CpuOperator {
        fmm: CpuFmm::new(&basis, &f.tree, &f.points, &f.plan),
        times: Default::default(),
        applications: 0,
    };
    let mut gpu = GpuFmm::new(ctx, &basis, &f.tree, &f.points, &f.plan).unwrap();
    let mut orders = Vec::new();
    for relax in [1.0, 10.0, 100.0, 1e4] {
        let mut want = vec![[0.0f32; 3]; n];
        let mut got = vec![[f32::NAN; 3]; n];
        let a = cpu.apply_relaxed(&radiance, &mut want, relax).unwrap();
        let b = gpu.apply_relaxed(&radiance, &mut got, relax).unwrap();
        let d = rel_l2(&got, &want);
        println!("relax {relax}: order {b}, CPU vs GPU relative L2 difference {d:.3e}");
        assert_eq!(a, b);
        assert!(d < 1e-4, "relax {relax}, order {b}: {d:.3e}");
        orders.push(b);
    }
    // θ = 0.5: each order less multiplies the error by 8.
    assert_eq!(orders, vec![3, 2, 1, 1]);
    assert_eq!(gpu.applications, 4);
}

/// The final gather's WGSL twin (shaders/fmm/gather.wgsl) casts the same rays from the same
/// random numbers as the CPU's: on the box scene with radiance varying over its surfaces, every
/// splat gathered by both, splat by splat.
///
/// The radiance is a smooth function of where a splat lies, not of its index. A face's disks
/// overlap in one plane, so where a ray meets two of them their distances tie to rounding, and
/// which one wins depends on whether the device fuses multiply-adds (NVIDIA's Vulkan driver
/// does; the CPU and llvmpipe do not). On the H100, radiance by index made 90 of 1844 splats
/// differ (relative L2 2.6e-3) from such ties alone; by place, two tied disks see nearly the
/// same light, as in any real solution.
#[test]
fn gpu_gather_matches_the_cpu() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let soa = box_scene(0.07);
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let view = sc.octree.view();
    let n = view.splats.len();
    let radiance: Vec<[f32; 3]> = view
        .splats
        .iter()
        .map(|s| {
            let p = glam::Vec3::from(s.position);
            [
                1.0 + 0.5 * (2.0 * p.x + p.z).sin(),
                0.5 + 0.4 * (1.5 * p.y - p.z).cos(),
                0.2,
            ]
        })
        .collect();
    let splats: Vec<u32> = (0..n as u32).step_by(3).collect();
    // The stage's default count: llvmpipe, which ends a shader's loops after 65535 iterations per
    // invocation group, dropped most of 256 rays in one dispatch (1801 of 1844 splats wrong,
    // relative L2 0.44) while 64 passed; a software adapter now casts 8 a dispatch.
    let per_splat = pc_artifact::params::FmmParams::default().gather_rays;
    let rays = pc_fmm::gather::GatherRays::new(per_splat);
    let accel = pc_tree::accel::Accel::new(&view);
    let rough = pc_tree::between::leaf_roughness(&view);
    let cpu = pc_fmm::gather::gather_cpu((&view, &accel, &rough), &radiance, rays, &splats);
    let gpu = pc_fmm::gather::GpuGather::new(ctx, &view, &rough, &radiance)
        .unwrap()
        .gather(rays, &splats)
        .unwrap();
    assert_eq!(cpu.len(), gpu.len());
    // A tie moves a splat's value by a fraction of one ray's share, a ray that grazes a disk's
    // rim and hits on one side but misses on the other by up to one share: few splats may
    // differ by half a share or more.
    let share = 1.0 / per_splat as f32;
    let differ = cpu
        .iter()
        .zip(&gpu)
        .filter(|(c, g)| (0..3).any(|k| (c[k] - g[k]).abs() > 0.5 * share * (0.1 + c[k].abs())))
        .count();
    let e = rel_l2(&gpu, &cpu);
    println!(
        "{} splats gathered, {differ} differ, relative L2 {e:.2e}",
        splats.len()
    );
    assert!(e < 2e-3, "relative L2 {e}");
    assert!(differ * 50 < splats.len(), "{differ} splats differ");
    // Every ray of the cube's bottom meets the floor's back (nothing); the rest see light.
    assert!(cpu
        .iter()
        .all(|c| c.iter().all(|v| v.is_finite() && *v >= 0.0)));
    let lit = cpu.iter().filter(|c| c[2] > 0.0).count();
    assert!(lit * 10 > splats.len() * 9, "{lit} splats see light");
}
