//! Times one FMM product against the exact sum over the same plan (every splat pair the
//! V-map's links connect, O(N²) in the worst case) on artifacts already made by the chain.
//!
//! `cargo run --release -p pc-fmm --example direct_speedup -- CONFIG [--fmm-only] [KEY=VALUE ...]` (after
//! pc-octree and pc-vmap ran on CONFIG; e.g. `fmm.order=5`). Prints both times, the speed-up and the relative L2 difference;
//! with `--fmm-only`, the plan's time and the best and median of five products.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use pc_artifact::octree::OctreeFile;
use pc_artifact::vmap::VmapFile;
use pc_fmm::cpu::{direct, PhaseTimes};
use pc_fmm::plan::{self, PlanParams};
use pc_fmm::{tree, Basis, CpuFmm};

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    // `--fmm-only`: time the product alone (the direct sum is out of reach at 1M splats).
    let fmm_only = args.iter().any(|a| a == "--fmm-only");
    args.retain(|a| a != "--fmm-only");
    let config = PathBuf::from(
        args.first()
            .context("usage: direct_speedup CONFIG [KEY=VALUE ...]")?,
    );
    let cfg = pc_config::load_config(&config, &args[1..])?;
    let oct = OctreeFile::open(cfg.octree_path())?;
    let view = oct.view();
    let vm = VmapFile::open(cfg.vmap_path(), &oct.id(), &cfg.config.lights)?;
    let (offsets, links) = (vm.view().link_offsets, vm.view().links);
    let materials = cfg.materials_for(&oct)?;
    let f = &cfg.config.fmm.params;
    let (t, p) = tree::build(&view, &materials);
    let start = Instant::now();
    let plan = plan::build(
        &t,
        &p,
        offsets,
        links,
        PlanParams {
            theta: f.theta,
            clamp_tol: f.clamp_tol,
        },
    );
    let t_plan = start.elapsed().as_secs_f64();
    let basis = Basis::new(f.order as usize);
    let fmm = CpuFmm::new(&basis, &t, &p, &plan);
    let radiance: Vec<[f32; 3]> = (0..p.pos.len())
        .map(|i| {
            let x = i as f32 * 0.618;
            [1.0 + 0.5 * x.sin(), 0.5 + 0.4 * (1.3 * x).cos(), 0.2]
        })
        .collect();
    let mut out = vec![[0.0f32; 3]; radiance.len()];
    let start = Instant::now();
    let mut phases = PhaseTimes::default();
    fmm.apply(&radiance, &mut out, &mut phases);
    let t_fmm = start.elapsed().as_secs_f64();
    println!("plan {:?}; product phases {phases:?}", plan.counts);
    if fmm_only {
        // Four more products: the machine's noise shows in the spread, the best is the figure.
        let mut times = vec![t_fmm];
        for _ in 0..4 {
            let start = Instant::now();
            fmm.apply(&radiance, &mut out, &mut PhaseTimes::default());
            times.push(start.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{} splats, order {}: plan {t_plan:.2} s; FMM product best {:.3} s, median {:.3} s of {}",
            p.pos.len(),
            f.order,
            times[0],
            times[times.len() / 2],
            times.len()
        );
        return Ok(());
    }
    let start = Instant::now();
    let exact = direct(&t, &p, &plan, &radiance);
    let t_direct = start.elapsed().as_secs_f64();
    let (mut e, mut n) = (0.0f64, 0.0f64);
    for (a, b) in out.iter().zip(&exact) {
        for c in 0..3 {
            e += ((a[c] - b[c]) as f64).powi(2);
            n += (b[c] as f64).powi(2);
        }
    }
    println!(
        "{} splats, order {}: FMM product {t_fmm:.2} s, direct sum over the same links {t_direct:.2} s, speed-up {:.1}x, relative L2 difference {:.2e}",
        p.pos.len(),
        f.order,
        t_direct / t_fmm,
        (e / n).sqrt()
    );
    Ok(())
}
