//! Reruns the splat-area pass on an existing octree artifact and reports its time and the sum
//! of the areas beside the artifact's: a harness for the pass's speed without the import
//! (docs/octree.md, "Splat area").
//!
//!     cargo run --release -p pc-octree --example area_pass -- OCTREE [SAMPLES] [ROUNDS]

use pc_artifact::octree::OctreeFile;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: area_pass OCTREE [SAMPLES] [ROUNDS]");
        std::process::exit(2);
    };
    let samples = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    let rounds = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    let f = match OctreeFile::open(path) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("area_pass: {path}: {e}");
            std::process::exit(1);
        }
    };
    let view = f.view();
    let stored: f64 = view.splat_area.iter().map(|&a| a as f64).sum();
    for _ in 0..rounds {
        let t = std::time::Instant::now();
        let (areas, _) = pc_octree::area::splat_areas(
            &view.frame,
            view.nodes,
            view.begin_end,
            view.splats,
            view.splat_leaf,
            samples,
        );
        let sum: f64 = areas.iter().map(|&a| a as f64).sum();
        println!(
            "{} splats: area {sum:.6} (stored {stored:.6}) in {:.3} s",
            areas.len(),
            t.elapsed().as_secs_f64()
        );
    }
}
