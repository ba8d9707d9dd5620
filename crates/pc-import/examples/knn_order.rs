use kiddo::{ImmutableKdTree, SquaredEuclidean};
use pc_import::points::{read_points, PlyOptions};
use rayon::prelude::*;
use std::num::NonZeroUsize;
use std::time::Instant;

fn morton(p: [f32; 3], lo: [f32; 3], s: f32) -> u64 {
    let mut code = 0u64;
    let q: Vec<u64> = (0..3)
        .map(|k| (((p[k] - lo[k]) * s) as u64).min((1 << 21) - 1))
        .collect();
    for b in 0..21 {
        for k in 0..3 {
            code |= ((q[k] >> b) & 1) << (3 * b + k);
        }
    }
    code
}

fn main() {
    let f = std::env::args().nth(1).unwrap();
    let pts = read_points(std::path::Path::new(&f), &PlyOptions::default()).unwrap();
    let p: Vec<[f32; 3]> = pts.positions.iter().map(|v| v.to_array()).collect();
    let n = p.len();
    let t = Instant::now();
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&p).unwrap();
    println!("build {:.3}", t.elapsed().as_secs_f64());
    let run = |order: &[u32], k: usize, label: &str| {
        let t = Instant::now();
        let s: f64 = order
            .par_iter()
            .map(|&i| {
                let r = tree
                    .query(&p[i as usize])
                    .nearest_n::<SquaredEuclidean<f32>>(NonZeroUsize::new(k + 1).unwrap())
                    .execute();
                r.iter().map(|x| x.distance as f64).sum::<f64>()
            })
            .sum();
        println!("{label} k {k}: {:.3} s ({s:.3})", t.elapsed().as_secs_f64());
    };
    let ident: Vec<u32> = (0..n as u32).collect();
    let mut lo = [f32::MAX; 3];
    let mut hi = [f32::MIN; 3];
    for q in &p {
        for k in 0..3 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    let ext = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
    let s = ((1u64 << 21) - 1) as f32 / ext;
    let t = Instant::now();
    let mut mo: Vec<(u64, u32)> = p
        .iter()
        .enumerate()
        .map(|(i, q)| (morton(*q, lo, s), i as u32))
        .collect();
    mo.par_sort_unstable();
    let morder: Vec<u32> = mo.iter().map(|x| x.1).collect();
    println!("morton sort {:.3}", t.elapsed().as_secs_f64());
    run(&ident, 16, "file order");
    run(&morder, 16, "morton order");
    run(&ident, 8, "file order");
    run(&morder, 8, "morton order");
}
