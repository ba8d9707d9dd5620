//! Reader speed: `cargo run --release -p pc-import --example read_speed -- FILE... [--runs N]`
//! reads each file (any format pcgi reads) N times (default 3) and prints the best time and
//! points per second. The numbers in BENCHMARKS.md ("Import") come from here.

use std::path::PathBuf;
use std::time::Instant;

use pc_import::points::{read_points, Format, PlyOptions};

fn main() {
    let mut runs = 3usize;
    let mut files = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--runs" {
            runs = args.next().and_then(|v| v.parse().ok()).unwrap_or(3);
        } else {
            files.push(PathBuf::from(a));
        }
    }
    for f in files {
        let mut best = f64::INFINITY;
        let mut n = 0;
        for _ in 0..runs.max(1) {
            let t = Instant::now();
            match read_points(&f, &PlyOptions::default()) {
                Ok(p) => n = p.len(),
                Err(e) => {
                    eprintln!("read_speed: {e}");
                    std::process::exit(1);
                }
            }
            best = best.min(t.elapsed().as_secs_f64());
        }
        let bytes = std::fs::metadata(&f).map(|m| m.len()).unwrap_or(0);
        let format = Format::of(&f).map(|x| x.name()).unwrap_or("?");
        println!(
            "{} ({format}, {:.1} MB): {n} points in {best:.3} s, {:.2} M points/s",
            f.display(),
            bytes as f64 / 1e6,
            n as f64 / best / 1e6
        );
    }
}
