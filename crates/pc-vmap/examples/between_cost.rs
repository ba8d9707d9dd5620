//! What the own-zone rule costs per ray (pc_tree::between): `cargo run --release -p pc-vmap
//! --example between_cost -- OCTREE` casts 400,000 segments between random facing splats of an
//! octree, as plain rays and as segments between surfaces, twice each, and prints the times.

use pc_artifact::octree::OctreeFile;
use pc_tree::accel::Accel;
use pc_tree::{Between, Ray};
use rand::SeedableRng;

mod common;

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: between_cost OCTREE");
        std::process::exit(2);
    };
    let f = match OctreeFile::open(&path) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("between_cost: {e}");
            std::process::exit(1);
        }
    };
    let view = f.view();
    let accel = Accel::new(&view);
    let rough = pc_tree::between::leaf_roughness(&view);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let segs: Vec<Between> = (0..400_000)
        .map(|_| common::facing_segment(&view, &rough, &mut rng, 1e-6).2)
        .collect();
    let rays: Vec<Ray> = segs.iter().map(|s| s.ray).collect();
    for _ in 0..2 {
        let t = std::time::Instant::now();
        let v = accel.visible(&view, &rays);
        let a = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let w = accel.visible_between(&view, &segs);
        let b = t.elapsed().as_secs_f64();
        let (va, vb) = (
            v.iter().filter(|&&x| x).count(),
            w.iter().filter(|&&x| x).count(),
        );
        println!("plain {a:.2} s ({va} visible), between {b:.2} s ({vb} visible)");
    }
}
