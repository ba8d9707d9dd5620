//! Times the emitters' direct light (`solve::emitter_direct`: sampling, shaft culling, shadow
//! tests) alone, on artifacts already made by the chain: three runs, best and all.
//!
//! `cargo run --release -p pc-fmm --example emitter_speed -- CONFIG [KEY=VALUE ...]` (after
//! pc-octree and pc-vmap ran on CONFIG; e.g. `fmm.emitter_samples=16`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use pc_artifact::vmap as vs;
use pc_artifact::{Artifact, ArtifactKind};
use pc_fmm::{solve, tree};
use pc_tree::OctreeView;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let config = PathBuf::from(
        args.first()
            .context("usage: emitter_speed CONFIG [KEY=VALUE ...]")?,
    );
    let cfg = pc_scene::config::load_config(&config, &args[1..])?;
    let oct = Artifact::open_kind(cfg.octree_path(), ArtifactKind::Octree)?;
    let view = OctreeView::from_artifact(&oct)?;
    let vm = Artifact::open_kind(cfg.vmap_path(), ArtifactKind::Vmap)?;
    let lights = cfg.light_records();
    let tables = vs::Tables::open(
        &vm,
        &oct.header().key,
        view.nodes.len(),
        view.splats.len(),
        &lights,
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    let materials = pc_scene::cli::current_materials(&cfg, &oct)?;
    let f = &cfg.config.fmm;
    let (t, pts) = tree::build(&view, &materials);
    let caster = pc_tree::caster::CpuCaster::new(&view);
    let base =
        pc_fmm::stage::point_light_system(&view, &materials, &t, &pts, &tables, &lights, &caster)?;
    let self_hit = tables.meta.params.self_hit;
    let mut times = Vec::new();
    let mut rays = Default::default();
    for _ in 0..3 {
        let mut sys = base.clone();
        let start = Instant::now();
        rays = solve::emitter_direct(
            &view,
            &pts,
            &mut sys,
            solve::EmitterSampling {
                samples: f.emitter_samples,
                probes: f.emitter_probes,
                self_hit,
                shafts: true,
            },
            &caster,
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?;
        times.push(start.elapsed().as_secs_f64());
    }
    let best = times.iter().copied().fold(f64::INFINITY, f64::min);
    println!(
        "{} splats: emitter direct light best {best:.3} s (runs {times:.3?}); {rays:?}",
        view.splats.len()
    );
    Ok(())
}
