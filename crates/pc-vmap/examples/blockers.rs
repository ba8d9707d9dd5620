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

mod common;

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
    under_the_rule(&view, &accel, min_len);
}

/// The same kind of segments under the own-zone rule (pc_tree::between), as the V-map casts
/// them: how many stay blocked, and why the rule did not pass over their first blocker. Also
/// what feeds the rule: how far fitted normals tilt from the nearest axis (the hall's floor,
/// walls and ceiling are axis-aligned), and how many octree leaves get no roughness.
fn under_the_rule(view: &pc_artifact::octree::OctreeView, accel: &Accel, min_len: f32) {
    let rough = pc_tree::between::leaf_roughness(view);
    let mut tilt = [0u64; 7]; // degrees: < 2, 2-4, 4-8, 8-16, 16-32, 32-45, above
    for s in view.splats {
        let n = Vec3::from(s.normal).abs();
        let deg = n.max_element().min(1.0).acos().to_degrees();
        let bin = [2.0, 4.0, 8.0, 16.0, 32.0, 45.0]
            .iter()
            .take_while(|&&b| deg >= b)
            .count();
        tilt[bin] += 1;
    }
    println!("normal tilt from the nearest axis, degrees (< 2, 2-4, 4-8, 8-16, 16-32, 32-45, more): {tilt:?}");
    let mut is_leaf = vec![false; view.nodes.len()];
    for &l in view.splat_leaf {
        is_leaf[l as usize] = true;
    }
    let leaves: Vec<usize> = (0..view.nodes.len()).filter(|&i| is_leaf[i]).collect();
    let smooth = leaves.iter().filter(|&&i| rough[i] == 0.0).count();
    let mut r: Vec<f32> = leaves
        .iter()
        .map(|&i| rough[i])
        .filter(|&x| x > 0.0)
        .collect();
    r.sort_by(f32::total_cmp);
    let radii: f64 =
        view.splats.iter().map(|s| s.radius as f64).sum::<f64>() / view.splats.len() as f64;
    println!(
        "{} leaves, {smooth} with no roughness (edges or spread normals); median roughness {:.4}, mean splat radius {radii:.4}",
        leaves.len(),
        r.get(r.len() / 2).copied().unwrap_or(0.0)
    );
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2);
    let mut st = TraversalStats::default();
    let (mut cast, mut blocked) = (0u64, 0u64);
    // Why the first blocker counts: [beyond both zones, in a zone but turned past OWN_COS,
    // in a zone but another material]; and of those turned, how far (degrees: < 40, 40-60, more).
    let mut why = [0u64; 3];
    let mut turned = [0u64; 3];
    let mut beyond_rel = [0u64; 6]; // distance past the zone's end in zone lengths: < .25, .5, 1, 2, 4, more
    while cast < 100_000 {
        let (ia, ib, seg) = common::facing_segment(view, &rough, &mut rng, min_len);
        let len =
            (Vec3::from(view.splats[ib].position) - Vec3::from(view.splats[ia].position)).length();
        cast += 1;
        // The first hit the rule does not pass over.
        let mut ray = seg.ray;
        let hit = loop {
            match accel.intersect(view, &ray, &mut st) {
                None => break None,
                Some(h) => {
                    let s = &view.splats[h.splat as usize];
                    if seg.ignores(h.t, s.normal, s.material) {
                        ray.t_min = h.t * (1.0 + 1e-6) + 1e-7;
                    } else {
                        break Some((h, s));
                    }
                }
            }
        };
        let Some((h, s)) = hit else { continue };
        blocked += 1;
        let hn = Vec3::from(s.normal);
        let (in_a, in_b) = (h.t < seg.zones[0], h.t > seg.zones[1]);
        if !in_a && !in_b {
            why[0] += 1;
            let (past, zone) = if h.t < 0.5 * len {
                (h.t - seg.zones[0], seg.zones[0])
            } else {
                (seg.zones[1] - h.t, len - seg.zones[1])
            };
            let rel = past / zone.max(1e-9);
            beyond_rel[[0.25, 0.5, 1.0, 2.0, 4.0]
                .iter()
                .take_while(|&&b| rel >= b)
                .count()] += 1;
        } else {
            let end = if in_a { &seg.ends[0] } else { &seg.ends[1] };
            if s.material != end.material {
                why[2] += 1;
            } else {
                why[1] += 1;
                let deg = hn.dot(end.normal).clamp(-1.0, 1.0).acos().to_degrees();
                turned[[40.0, 60.0].iter().take_while(|&&b| deg >= b).count()] += 1;
            }
        }
    }
    println!(
        "under the rule: {cast} segments, {blocked} blocked ({:.1} %)",
        100.0 * blocked as f64 / cast as f64
    );
    println!("first blocker: beyond both zones {}, in a zone but turned {}, in a zone but another material {}", why[0], why[1], why[2]);
    println!("turned by (degrees < 40, 40-60, more): {turned:?}; beyond a zone by (zone lengths < .25, .5, 1, 2, 4, more): {beyond_rel:?}");
}
