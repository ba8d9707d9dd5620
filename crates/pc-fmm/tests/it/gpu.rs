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
            "order {order}: CPU vs {}: relative L2 difference {d:.3e} (CPU {cpu_s:.3} s, GPU setup {setup_s:.2} s, apply {gpu_s:.3} s in {} dispatches, loop bound {:?})",
            gpu.device(),
            gpu.dispatches,
            gpu.loop_bound
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
    let sys = solve::System {
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

#[test]
fn gpu_refuses_a_plan_beyond_llvmpipes_loop_budget() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let f = fixture();
    // 70000 M2L tasks to the root (all from one leaf, at fraction 0): one invocation's loop.
    let mut plan = f.plan.clone();
    let src = f.tree.leaves[0];
    let extra = 70_000u32;
    plan.node_tasks.splice(
        0..0,
        (0..extra).map(|_| pc_fmm::plan::NodeTask { src, fraction: 0.0 }),
    );
    for o in plan.node_offsets.iter_mut().skip(1) {
        *o += extra;
    }
    let bound = pc_fmm::gpu::loop_bound(&f.tree, &f.points, &plan).unwrap();
    assert!(bound.0 >= 70_000, "{bound:?}");
    let software = ctx.is_software();
    match GpuFmm::new(ctx, &Basis::new(2), &f.tree, &f.points, &plan) {
        Err(e) => {
            println!("{e}");
            assert!(software && e.contains("65535"), "{e}");
        }
        Ok(_) => assert!(!software, "llvmpipe must refuse a plan of {bound:?}"),
    }
}
