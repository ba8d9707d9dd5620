//! Times the emitters' direct light (`emitter::emitter_direct`: sampling, shaft culling, shadow
//! tests) alone, on artifacts already made by the chain: three runs, best and all.
//!
//! `cargo run --release -p pc-fmm --example emitter_speed -- CONFIG [KEY=VALUE ...]` (after
//! pc-octree and pc-vmap ran on CONFIG; e.g. `fmm.emitter_samples=16`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use pc_artifact::octree::OctreeFile;
use pc_artifact::vmap::VmapFile;
use pc_fmm::emitter::{self, EmitterSampling};
use pc_fmm::tree;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = PathBuf::from(
        args.first()
            .context("usage: emitter_speed CONFIG [KEY=VALUE ...]")?,
    );
    let cfg = pc_config::load_config(&config, &args[1..])?;
    let oct = OctreeFile::open(cfg.octree_path())?;
    let view = oct.view();
    let lights = &cfg.config.lights;
    let vm = VmapFile::open(cfg.vmap_path(), &oct.id(), lights)?;
    let materials = cfg.materials_for(&oct)?;
    let f = &cfg.config.fmm.params;
    let (_, pts) = tree::build(&view, &materials);
    let caster = pc_tree::caster::CpuCaster::new(&view);
    let rough = pc_tree::between::LazyRoughness::new(&view);
    let lights = (&lights[..], &rough);
    let base = pc_fmm::stage::point_light_system(&view, &materials, &pts, &vm, lights, &caster)?;
    let self_hit = vm.meta().params.self_hit;
    let mut times = Vec::new();
    let mut rays = Default::default();
    for _ in 0..3 {
        let mut sys = base.clone();
        let start = Instant::now();
        rays = emitter::emitter_direct(
            &view,
            &pts,
            &mut sys,
            EmitterSampling {
                samples: f.emitter_samples,
                probes: f.emitter_probes,
                self_hit,
                shafts: true,
            },
            &caster,
        )?;
        times.push(start.elapsed().as_secs_f64());
    }
    let best = times.iter().copied().fold(f64::INFINITY, f64::min);
    println!(
        "{} splats: emitter direct light best {best:.3} s (runs {times:.3?}); {rays:?}",
        view.splats.len()
    );
    Ok(())
}
