//! What blocks the V-map's rays: `cargo run --release -p pc-vmap --example blockers -- OCTREE
//! [MIN_LEN]` casts 200,000 plain rays between random splat centres that face each other (at
//! least MIN_LEN apart, default 0.3) and sorts the blocked ones by where they were blocked: how
//! far from the nearer end (in its radii), and how high the hit stands above the tangent plane
//! of an end facing like the splat hit. On a noisy scan most blocks are the ends' own surfaces
//! within a radius of their plane (pc_tree::between, docs/vmap.md "Rough surfaces").

use glam::Vec3;
use pc_artifact::octree::OctreeFile;
use pc_tree::accel::Accel;
use pc_tree::{Ray, TraversalStats};
use rand::{Rng, SeedableRng};

fn main() {
    let mut args = std::env::args().skip(1);
    let Some(path) = args.next() else {
        eprintln!("usage: blockers OCTREE [MIN_LEN]");
        std::process::exit(2);
    };
    let min_len: f32 = args.next().and_then(|s| s.parse().ok()).unwrap_or(0.3);
    let f = match OctreeFile::open(&path) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("blockers: {e}");
            std::process::exit(1);
        }
    };
    let view = f.view();
    let accel = Accel::new(&view);
    let n = view.splats.len();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let mut st = TraversalStats::default();
    let (mut cast, mut blocked, mut own_a, mut own_b) = (0u64, 0u64, 0u64, 0u64);
    // Heights in radii: < 1/8, 1/8-1/4, ..., 8-16, 16 and up or no end faces like the hit.
    let mut heights = [0u64; 9];
    // Distance from the nearer end in its radii: < 1, 1-2, 2-4, ..., 1024 and up.
    let mut distances = [0u64; 12];
    while cast < 200_000 {
        let (si, sj) = (
            &view.splats[rng.random_range(0..n)],
            &view.splats[rng.random_range(0..n)],
        );
        let (xa, na, ra) = (Vec3::from(si.position), Vec3::from(si.normal), si.radius);
        let (xb, nb, rb) = (Vec3::from(sj.position), Vec3::from(sj.normal), sj.radius);
        let d = xb - xa;
        let len = d.length();
        if len < min_len {
            continue;
        }
        let dir = d / len;
        if na.dot(dir) <= 0.0 || nb.dot(-dir) <= 0.0 {
            continue;
        }
        let ray = Ray {
            origin: xa,
            dir,
            t_min: 0.5 * ra,
            t_max: len - 0.5 * rb,
        };
        cast += 1;
        let Some(h) = accel.intersect(&view, &ray, &mut st) else {
            continue;
        };
        blocked += 1;
        let hn = Vec3::from(view.splats[h.splat as usize].normal);
        let (ta, tb) = (h.t / ra, (len - h.t) / rb);
        if ta < 10.0 && hn.dot(na) > 0.5 {
            own_a += 1;
        } else if tb < 10.0 && hn.dot(nb) > 0.5 {
            own_b += 1;
        }
        let x = xa + dir * h.t;
        let (ha, hb) = ((x - xa).dot(na).abs() / ra, (x - xb).dot(nb).abs() / rb);
        let (like_a, like_b) = (hn.dot(na) > 0.5, hn.dot(nb) > 0.5);
        let height = match (like_a, like_b) {
            (true, true) => ha.min(hb),
            (true, false) => ha,
            (false, true) => hb,
            (false, false) => f32::INFINITY,
        };
        let bin = |v: f32, lo: f32, last: usize| {
            if v < lo {
                0
            } else {
                ((v / lo).log2() as usize + 1).min(last)
            }
        };
        heights[bin(height, 0.125, 8)] += 1;
        distances[bin(ta.min(tb), 1.0, 11)] += 1;
    }
    println!(
        "{cast} rays, {blocked} blocked ({:.1} %)",
        100.0 * blocked as f64 / cast as f64
    );
    println!("blocked within 10 radii of an end by a splat facing like it: {own_a} at the first, {own_b} at the second");
    println!("height above the plane of an end facing like the hit, in its radii (< 1/8, doubling, 16 and up or none): {heights:?}");
    println!("distance from the nearer end, in its radii (< 1, doubling): {distances:?}");
}
