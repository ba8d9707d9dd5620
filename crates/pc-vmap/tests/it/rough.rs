//! Rough surfaces (pc_tree::between, docs/vmap.md "Rough surfaces"): a scanned floor's range
//! noise and tilted normals are not an occluder between it and a wall it faces.

use glam::Vec3;
use pc_tree::{Between, OctreeView, Ray, TraversalStats};
use pc_vmap::build::{build_links, csr, vnodes, Caster, CpuCaster};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::{params, BuildSoa, Soa};

/// A floor [0, 2] × [0, 1] (facing +y) and a low wall at x = 2.1 facing it, nothing between;
/// with `noise`, every splat moved along its normal by a Gaussian of `noise` spacings and its
/// normal tilted by up to 8° (a scan's range noise and the normals fitted to it). Returns the
/// splats and how many of them are the floor's.
fn floor_and_wall(noise: f32) -> (Soa, usize) {
    let h = 0.04;
    let mut rng = Pcg64::seed_from_u64(3);
    let mut s = Soa::default();
    s.rect(
        Vec3::new(1.0, 0.0, 0.5),
        Vec3::X,
        -Vec3::Z * 0.5,
        h,
        0,
        &mut rng,
    );
    let floor = s.len();
    s.rect(
        Vec3::new(2.1, 0.2, 0.5),
        Vec3::Z * 0.5,
        Vec3::Y * 0.2,
        h,
        0,
        &mut rng,
    );
    assert!(s.n[0].y > 0.99 && s.n[floor].x < -0.99, "orientations");
    for k in 0..s.len() {
        let g: f32 = (0..4).map(|_| rng.random_range(-1.0f32..1.0)).sum::<f32>() * 0.866;
        s.p[k] += s.n[k] * (g * noise * h);
        let tilt = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let t = tilt - s.n[k] * tilt.dot(s.n[k]);
        s.n[k] = (s.n[k] + t * (noise.min(1.0) * 0.14)).normalize();
    }
    (s, floor)
}

/// Cosine-weighted transfer `A_i cos θi cos θj A_j / (π r²)` from floor splat `i` to wall splat
/// `j`, zero unless they face each other.
fn transfer(view: &OctreeView, i: usize, j: usize) -> f64 {
    let (si, sj) = (&view.splats[i], &view.splats[j]);
    let d = Vec3::from(sj.position) - Vec3::from(si.position);
    let r2 = d.length_squared() as f64;
    let dir = d.normalize();
    let (ci, cj) = (
        Vec3::from(si.normal).dot(dir) as f64,
        -Vec3::from(sj.normal).dot(dir) as f64,
    );
    if ci <= 0.0 || cj <= 0.0 {
        return 0.0;
    }
    ci * cj / (std::f64::consts::PI * r2) * (view.splat_area[i] as f64 * view.splat_area[j] as f64)
}

/// The floor's transfer to the wall: all of it, as the V-map's links pass it, as plain shadow
/// rays between the centres would (every hit counts) and as segments between them do.
fn floor_to_wall(noise: f32) -> (f64, f64, f64, f64) {
    let (s, floor) = floor_and_wall(noise);
    let o = s.build(8);
    let view = o.view();
    let is_floor = |i: usize| (view.splats[i].source as usize) < floor;
    let p = params(16, 8);
    let vn = vnodes(&view, p.leaf_splats);
    let l = build_links(&view, &vn, &p, &CpuCaster::new(&view), &mut |_, _| {}).unwrap();
    let (offsets, links) = csr(view.nodes.len(), l.pairs);
    let n = view.splats.len();
    let (mut all, mut linked, mut plain) = (0.0, 0.0, 0.0);
    let mut st = TraversalStats::default();
    let accel = pc_tree::accel::Accel::new(&view);
    let rough = pc_tree::between::leaf_roughness(&view);
    let rough = |i: usize| rough[view.splat_leaf[i] as usize];
    let mut between = 0.0;
    for i in (0..n).filter(|&i| is_floor(i)) {
        for j in (0..n).filter(|&j| !is_floor(j)) {
            let t = transfer(&view, i, j);
            all += t;
            let (si, sj) = (&view.splats[i], &view.splats[j]);
            let d = Vec3::from(sj.position) - Vec3::from(si.position);
            let len = d.length();
            let ray = Ray {
                origin: si.position.into(),
                dir: d / len,
                t_min: 0.5 * si.radius,
                t_max: len - 0.5 * sj.radius,
            };
            if t > 0.0 && !pc_tree::occluded(&view, &ray, &mut st) {
                plain += t;
            }
            let (a, b) = ((si, rough(i)), (sj, rough(j)));
            let seg = Between::splats(a, b, d / len, len, ray.t_min, ray.t_max);
            if t > 0.0 && accel.visible_between(&view, &[seg])[0] {
                between += t;
            }
        }
    }
    for x in 0..vn.len() {
        for link in &links[offsets[x] as usize..offsets[x + 1] as usize] {
            let y = &vn[link.slot() as usize];
            for i in (vn[x].lo..vn[x].hi).filter(|&i| is_floor(i as usize)) {
                for j in (y.lo..y.hi).filter(|&j| !is_floor(j as usize)) {
                    linked += transfer(&view, i as usize, j as usize) * link.fraction as f64;
                }
            }
        }
    }
    (all, linked, plain, between)
}

#[test]
fn a_rough_floor_sees_the_wall_it_faces_whole() {
    for noise in [0.0, 0.15, 0.3] {
        let (all, linked, plain, between) = floor_to_wall(noise);
        println!(
            "noise {noise}: links pass {:.4} of the transfer, segments {:.4}, plain shadow rays {:.4}",
            linked / all,
            between / all,
            plain / all
        );
        assert!(
            between / all > 0.985,
            "noise {noise}: segments {}",
            between / all
        );
        assert!(
            (linked / all - 1.0).abs() < 0.02,
            "noise {noise}: {}",
            linked / all
        );
        if noise > 0.0 {
            // The test has teeth: the noise blocks what plain rays find.
            assert!(
                plain / all < 0.9,
                "plain rays lose only {}",
                1.0 - plain / all
            );
        }
    }
}

#[test]
fn a_leaf_smaller_than_its_noise_reads_the_noise_of_its_surface() {
    // A floor whose range noise (1.5 spacings) is deeper than its leaves of up to 8 splats
    // are wide: a leaf holds the slab of the noise its cube cuts, and a leaf of a few splats
    // reads less still (one splat: none). Every splat's leaf reads the floor's noise, from the
    // smallest node above it that spans it.
    let (h, sigma) = (0.01, 0.015);
    let mut rng = Pcg64::seed_from_u64(5);
    let mut s = Soa::default();
    s.rect(Vec3::ZERO, Vec3::X * 0.5, -Vec3::Z * 0.5, h, 0, &mut rng);
    for k in 0..s.len() {
        let g: f32 = (0..4).map(|_| rng.random_range(-1.0f32..1.0)).sum::<f32>() * 0.866;
        s.p[k] += s.n[k] * (g * sigma);
    }
    let o = s.build(8);
    let view = o.view();
    let rough = pc_tree::between::leaf_roughness(&view);
    let mut read: Vec<f32> = view
        .splat_leaf
        .iter()
        .map(|&l| rough[l as usize] / sigma)
        .collect();
    read.sort_by(f32::total_cmp);
    let (p10, median) = (read[read.len() / 10], read[read.len() / 2]);
    println!("roughness over the noise: median {median}, 10th percentile {p10}");
    assert!(
        (0.85..1.15).contains(&median) && p10 > 0.7,
        "roughness over the noise: median {median}, 10th percentile {p10}"
    );
}

#[test]
fn gpu_segments_match_the_cpu() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    // With a box on the floor, so that segments are blocked too.
    let (mut s, _) = floor_and_wall(0.3);
    let mut rng = Pcg64::seed_from_u64(4);
    s.cube(
        Vec3::new(1.0, 0.15, 0.5),
        Vec3::splat(0.15),
        0.04,
        0,
        &mut rng,
    );
    let o = s.build(8);
    let view = o.view();
    let mut rng = Pcg64::seed_from_u64(9);
    let n = view.splats.len();
    let rough = pc_tree::between::leaf_roughness(&view);
    let rough = |i: usize| rough[view.splat_leaf[i] as usize];
    let segs: Vec<Between> = (0..20_000)
        .filter_map(|_| {
            let (i, j) = (rng.random_range(0..n), rng.random_range(0..n));
            let (a, b, ra, rb) = (&view.splats[i], &view.splats[j], rough(i), rough(j));
            let d = Vec3::from(b.position) - Vec3::from(a.position);
            let len = d.length();
            (len > 1e-3).then(|| {
                Between::splats(
                    (a, ra),
                    (b, rb),
                    d / len,
                    len,
                    0.5 * a.radius,
                    len - 0.5 * b.radius,
                )
            })
        })
        .collect();
    let cpu = CpuCaster::new(&view).visible_between(&segs).unwrap();
    let caster = pc_tree::gpu::RayCaster::new(&ctx, &view).unwrap();
    let gpu = pc_vmap::build::GpuCaster { ctx, caster }
        .visible_between(&segs)
        .unwrap();
    let same = cpu.iter().zip(&gpu).filter(|(a, b)| a == b).count();
    assert!(
        same as f64 >= 0.999 * segs.len() as f64,
        "{same} of {} agree",
        segs.len()
    );
    // Both answers occur, and the rule matters on these segments.
    let plain: Vec<Ray> = segs.iter().map(|s| s.ray).collect();
    let plain = CpuCaster::new(&view).visible(&plain).unwrap();
    let (seen, seen_plain) = (
        cpu.iter().filter(|&&v| v).count(),
        plain.iter().filter(|&&v| v).count(),
    );
    println!(
        "{seen} of {} segments visible, {seen_plain} as plain rays",
        segs.len()
    );
    assert!(seen > 1000 && seen < segs.len() - 1000);
    assert!(seen > seen_plain + 500);
}

/// The nearest hit a ray leaving a rough floor meets past its own zone
/// (`Accel::intersect_between`, the final gather's walk) is the one a walk from hit to hit finds,
/// passing over each hit [`Between::ignores`]: the same splat at the same distance, ray for ray,
/// and the same again where the walk passes whole over the leaves of the own zone.
#[test]
fn the_nearest_hit_past_the_own_zone_is_the_first_one_not_ignored() {
    let (s, floor) = floor_and_wall(0.3);
    let o = s.build(8);
    let view = o.view();
    let accel = pc_tree::accel::Accel::new(&view);
    let skipping = pc_tree::accel::Accel::new(&view).with_own_surfaces(&view);
    let rough = pc_tree::between::leaf_roughness(&view);
    let mut rng = Pcg64::seed_from_u64(11);
    let mut st = TraversalStats::default();
    let (mut hits, mut passed) = (0, 0);
    let floor_rays = (0..view.splats.len())
        .filter(|&i| (view.splats[i].source as usize) < floor)
        .flat_map(|i| [i; 4]);
    for i in floor_rays {
        let sp = &view.splats[i];
        let ray = Ray {
            origin: sp.position.into(),
            dir: pc_tree::cosine_dir(sp.normal, rng.random(), rng.random()),
            t_min: 1e-3 * sp.radius,
            t_max: f32::INFINITY,
        };
        let seg = Between::leaving(ray, (sp, rough[view.splat_leaf[i] as usize]));
        let got = accel.intersect_between(&view, &seg, &mut st);
        // Passing whole over the leaves of the floor's own zone changes nothing.
        let skipping = skipping.intersect_between(&view, &seg, &mut st);
        assert_eq!(
            skipping.map(|h| (h.splat, h.t)),
            got.map(|h| (h.splat, h.t))
        );
        let mut r = ray;
        let want = loop {
            match accel.intersect(&view, &r, &mut st) {
                Some(h) => {
                    let hs = &view.splats[h.splat as usize];
                    if !seg.ignores(h.t, hs.normal, hs.material) {
                        break Some(h);
                    }
                    passed += 1;
                    r.t_min = h.t * (1.0 + 1e-6) + f32::MIN_POSITIVE;
                }
                None => break None,
            }
        };
        assert_eq!(
            got.map(|h| (h.splat, h.t)),
            want.map(|h| (h.splat, h.t)),
            "splat {i}"
        );
        hits += got.is_some() as usize;
    }
    println!("{hits} hits; {passed} hits on the floor's own noise passed over");
    assert!(
        hits > 100 && passed > 100,
        "{hits} hits, {passed} passed over"
    );
}
