//! Ray traversal (pc-tree) against brute force: the nearest hit over every splat.

use glam::Vec3;
use pc_artifact::octree::class;
use pc_octree::OctreeParams;
use pc_tree::{intersect_splat, Ray, TraversalStats};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::{fine_octree, mixed_scene, BuildSoa, Soa};

fn brute(o: &pc_octree::Octree, ray: &Ray) -> Option<(f32, u32)> {
    let mut best: Option<(f32, u32)> = None;
    for (i, s) in o.splats.iter().enumerate() {
        if let Some(t) = intersect_splat(ray.origin, ray.dir, s) {
            if t >= ray.t_min && t <= ray.t_max && best.is_none_or(|b| t < b.0) {
                best = Some((t, i as u32));
            }
        }
    }
    best
}

fn random_dir(rng: &mut Pcg64) -> Vec3 {
    loop {
        let v = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    }
}

fn check_scene(o: &pc_octree::Octree, rays: &[Ray]) {
    let view = o.view();
    let mut stats = TraversalStats::default();
    let mut hits = 0;
    for (k, ray) in rays.iter().enumerate() {
        let got = pc_tree::intersect(&view, ray, &mut stats);
        let want = brute(o, ray);
        match (got, want) {
            (None, None) => {}
            (Some(g), Some(w)) => {
                hits += 1;
                assert!(
                    (g.t - w.0).abs() <= 1e-5 * w.0.abs().max(1.0),
                    "ray {k}: t {} vs brute force {}",
                    g.t,
                    w.0
                );
            }
            (g, w) => panic!("ray {k} {ray:?}: octree {g:?}, brute force {w:?}"),
        }
        assert_eq!(
            pc_tree::occluded(&view, ray, &mut stats),
            want.is_some(),
            "ray {k}: occlusion"
        );
    }
    assert!(hits > rays.len() / 4, "only {hits} hits");
    // Fewer splat tests than brute force by far.
    assert!(stats.splat_tests < (rays.len() * o.splats.len()) as u64 / 10);
}

#[test]
fn nearest_hits_agree_with_brute_force_from_inside_and_outside() {
    let (s, classes) = mixed_scene(0.06);
    for k in [1u32, 8, 32] {
        let o = s
            .build(
                &classes,
                OctreeParams {
                    max_leaf_points: k,
                    ..Default::default()
                },
            )
            .unwrap();
        let mut rng = Pcg64::seed_from_u64(k as u64);
        let mut rays = Vec::new();
        for _ in 0..1500 {
            // From inside the room, random directions.
            let origin = Vec3::new(
                rng.random_range(-0.9..0.9),
                rng.random_range(-0.9..0.9),
                rng.random_range(-0.9..0.9),
            );
            rays.push(Ray::new(origin, random_dir(&mut rng)));
            // From outside, aimed at the room.
            let far = random_dir(&mut rng) * 5.0;
            let target = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            rays.push(Ray::new(far, (target - far).normalize()));
        }
        // Axis-aligned rays (zero direction components, including -0.0) and limited intervals.
        for &d in &[
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            Vec3::new(-0.0, -1.0, 0.0),
        ] {
            rays.push(Ray::new(Vec3::new(0.1, 0.2, 0.3), d));
        }
        for r in rays.iter_mut().step_by(7) {
            r.t_min = 0.05;
            r.t_max = 1.5;
        }
        check_scene(&o, &rays);
    }
}

#[test]
fn tiny_cells_at_max_depth_are_not_skipped() {
    // A dense cluster forces deep, tiny cells; the exact step must not jump over them.
    let mut s = Soa::default();
    s.sphere(Vec3::ZERO, 1e-3, 500, 0);
    s.sphere(Vec3::new(0.5, 0.0, 0.0), 0.3, 500, 0);
    let o = s
        .build(
            &[class::DIFFUSE],
            OctreeParams {
                max_leaf_points: 2,
                ..Default::default()
            },
        )
        .unwrap();
    assert!(o.stats.depth >= 12, "depth {}", o.stats.depth);
    let mut rng = Pcg64::seed_from_u64(5);
    let rays: Vec<Ray> = (0..3000)
        .map(|_| {
            let origin = random_dir(&mut rng) * 2.0;
            let target = random_dir(&mut rng) * rng.random_range(0.0..1.2e-3);
            Ray::new(origin, (target - origin).normalize())
        })
        .collect();
    check_scene(&o, &rays);
}

/// Ray `k` of a mix over the scene of [`mixed_scene`]: from a random point inside it, every
/// third one a segment (from 0.03 to 1), and every third one a bounce ray leaving a random
/// splat half a radius out (the packed walk skips leaves by their slabs, which such rays cross
/// right at their start).
fn mixed_ray(view: &pc_tree::OctreeView, rng: &mut Pcg64, k: usize) -> Ray {
    let origin = Vec3::new(
        rng.random_range(-0.9..0.9),
        rng.random_range(-0.9..0.9),
        rng.random_range(-0.9..0.9),
    );
    let mut r = Ray::new(origin, random_dir(rng));
    if k.is_multiple_of(3) {
        r.t_min = 0.03;
        r.t_max = 1.0;
    }
    if k % 3 == 1 {
        let sp = &view.splats[rng.random_range(0..view.splats.len())];
        let n = Vec3::from(sp.normal);
        let d = random_dir(rng);
        r = Ray::new(Vec3::from(sp.position), if d.dot(n) < 0.0 { -d } else { d });
        r.t_min = 0.5 * sp.radius;
    }
    r
}

/// The slabs the GPU walks by, one a pool slot: each slot that has one holds every disk listed
/// in the leaves below its node (the CPU walk's slabs placed on the pool), and most internal
/// nodes of a flat-walled scene have one. A walk that does not follow the pool (another
/// tree's) places what it can and panics on nothing.
#[test]
fn pool_slabs_hold_every_disk_listed_below_their_node() {
    use pc_artifact::octree::node;
    let (s, classes) = mixed_scene(0.06);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    let slabs = pc_tree::accel::Accel::new(&view).pool_slabs(&view);
    assert_eq!(slabs.len(), view.nodes.len());
    let (mut internal, mut checked) = (0, 0);
    for (slot, words) in slabs.iter().enumerate() {
        if words[5] == 0 {
            continue;
        }
        let f = |k: usize| f32::from_bits(words[k]);
        let (axis, lo, hi) = (Vec3::new(f(0), f(1), f(2)), f(3), f(4));
        internal += !node::is_leaf(view.nodes[slot]) as usize;
        let mut below = vec![slot];
        while let Some(b) = below.pop() {
            let w = view.nodes[b];
            if node::is_leaf(w) {
                let (own, refs) = view.leaf(w);
                for j in own.chain(refs.iter().copied()) {
                    let d = &view.splats[j as usize];
                    let level = axis.dot(Vec3::from(d.position));
                    let sin = (1.0 - axis.dot(Vec3::from(d.normal)).powi(2))
                        .max(0.0)
                        .sqrt();
                    let reach = d.radius * sin;
                    assert!(
                        level - reach >= lo && level + reach <= hi,
                        "slot {slot}: disk {j} reaches {}..{} outside {lo}..{hi}",
                        level - reach,
                        level + reach
                    );
                    checked += 1;
                }
            } else if !node::is_empty(w) {
                below.extend((0..8).map(|c| (node::ptr(w) + c) as usize));
            }
        }
    }
    assert!(internal > 10, "{internal} internal nodes with a slab");
    assert!(checked > 10_000, "{checked} disks checked");
    // Another tree's walk on this pool.
    let (s2, classes2) = mixed_scene(0.09);
    let other = fine_octree(&s2, &classes2);
    let other_view = other.view();
    let placed = pc_tree::accel::Accel::new(&other_view).pool_slabs(&view);
    assert_eq!(placed.len(), view.nodes.len());
}

/// The GPU's walk by the slabs (a node whose slab the ray misses passed whole, a jump to where
/// it enters one it meets, a leaf whose slab it misses not tested) finds the hits of its walk
/// through every cell, bit for bit: plain rays, bounce rays leaving a splat and segments,
/// nearest and any hit.
#[test]
fn the_gpu_walk_by_the_slabs_finds_the_hits_of_every_cell() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let (s, classes) = mixed_scene(0.06);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    assert!(pc_tree::accel::Accel::new(&view).slabbed_nodes() > 0);
    let mut rng = Pcg64::seed_from_u64(34);
    let rays: Vec<pc_tree::gpu::RayIn> = (0..6000)
        .map(|k| (&mixed_ray(&view, &mut rng, k)).into())
        .collect();
    let slabbed = pc_tree::gpu::RayCaster::new(&ctx, &view).unwrap();
    let plain = pc_tree::gpu::RayCaster::with_slabs(&ctx, &view, false).unwrap();
    for any in [false, true] {
        let (a, b) = (
            slabbed.cast(&ctx, &rays, any).unwrap(),
            plain.cast(&ctx, &rays, any).unwrap(),
        );
        let bits = |h: &[Option<(f32, u32)>]| -> Vec<_> {
            h.iter().map(|h| h.map(|(t, j)| (t.to_bits(), j))).collect()
        };
        assert_eq!(bits(&a), bits(&b), "any hit: {any}");
        assert!(a.iter().flatten().count() > 2000);
    }
}

#[test]
fn gpu_ray_casting_matches_the_cpu_walk() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let (s, classes) = mixed_scene(0.06);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    let mut rng = Pcg64::seed_from_u64(21);
    let mut rays = Vec::new();
    for _ in 0..4000 {
        let origin = Vec3::new(
            rng.random_range(-0.9..0.9),
            rng.random_range(-0.9..0.9),
            rng.random_range(-0.9..0.9),
        );
        let mut r = Ray::new(origin, random_dir(&mut rng));
        if rng.random::<f32>() < 0.3 {
            r.t_min = 0.02;
            r.t_max = rng.random_range(0.1..2.0);
        }
        rays.push(r);
    }
    let caster = pc_tree::gpu::RayCaster::new(&ctx, &view).unwrap();
    let input: Vec<pc_tree::gpu::RayIn> = rays.iter().map(Into::into).collect();
    let nearest = caster.cast(&ctx, &input, false).unwrap();
    let any = caster.cast(&ctx, &input, true).unwrap();
    let mut stats = TraversalStats::default();
    let (mut agree, mut hits) = (0, 0);
    for (k, r) in rays.iter().enumerate() {
        let cpu = pc_tree::intersect(&view, r, &mut stats);
        assert_eq!(
            any[k].is_some(),
            pc_tree::occluded(&view, r, &mut stats),
            "ray {k}: occlusion differs"
        );
        match (cpu, nearest[k]) {
            (None, None) => agree += 1,
            (Some(c), Some((t, splat))) => {
                hits += 1;
                assert!(
                    (c.t - t).abs() <= 1e-5 * c.t.max(1.0),
                    "ray {k}: t {} vs {t}",
                    c.t
                );
                if c.splat == splat {
                    agree += 1;
                }
            }
            (c, g) => panic!("ray {k}: CPU {c:?}, GPU {g:?} on {}", ctx.describe()),
        }
    }
    assert!(hits > 1000);
    // Same splat except where two overlapping disks are hit at the same t.
    assert!(agree >= rays.len() * 99 / 100, "{agree} of {}", rays.len());
}

/// The packed walk (in its AVX2 build where the CPU has one, and without it) finds the artifact
/// walk's hits, and blends the same disks at them.
#[test]
fn packed_leaf_lists_give_identical_hits() {
    let (s, classes) = mixed_scene(0.06);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    let accel = pc_tree::accel::Accel::new(&view);
    // The walk without its AVX2 build, where this CPU has one (else the same walk).
    let portable = pc_tree::accel::Accel::new(&view).portable();
    let mut rng = Pcg64::seed_from_u64(33);
    let mut st = TraversalStats::default();
    let mut covered = 0;
    for k in 0..5000 {
        let r = mixed_ray(&view, &mut rng, k);
        let hit = accel.intersect(&view, &r, &mut st);
        assert_eq!(hit, pc_tree::intersect(&view, &r, &mut st), "ray {k}");
        assert_eq!(hit, portable.intersect(&view, &r, &mut st), "ray {k}");
        assert_eq!(
            accel.occluded(&view, &r, &mut st),
            pc_tree::occluded(&view, &r, &mut st),
            "ray {k}"
        );
        // The blend at the hit from the packed lanes: the same disks, weights bit for bit.
        if let Some((hit, leaf)) = accel.intersect_in(&view, &r, &mut st) {
            let x = r.origin + r.dir * hit.t;
            let n = Vec3::from(view.splats[hit.splat as usize].normal);
            let (mut a, mut b) = (Vec::new(), Vec::new());
            accel.covering(&view, leaf, x, n, 0.5, &mut a);
            pc_tree::covering(&view, hit.leaf, x, n, 0.5, &mut b);
            assert_eq!(a, b, "ray {k}");
            covered += !a.is_empty() as usize;
        }
    }
    assert!(covered > 1000, "{covered} hits with a blend");
}

/// Two walls meeting at a right angle, their normals tilted towards each other by rounding
/// (10⁻⁶, as transformed scans and the reference sets carry): a hit on one wall within the
/// blend's thickness of the corner blends that wall's splats alone. (While the test was
/// "facing the same way", the other wall's disks took part and carried their light into the
/// corner's pixels.)
#[test]
fn a_hit_beside_a_corner_blends_its_own_wall_alone() {
    let (h, n) = (0.02f32, 40);
    let mut soa = Soa::default();
    let (floor_n, wall_n) = (
        Vec3::new(1e-6, 1.0, 0.0).normalize(),
        Vec3::new(1.0, 1e-6, 0.0).normalize(),
    );
    assert!(floor_n.dot(wall_n) > 0.0);
    for i in 0..n {
        for j in 0..n {
            let (a, b) = ((i as f32 + 0.5) * h, (j as f32 + 0.5) * h);
            soa.push(Vec3::new(a, 0.0, b), floor_n, h, 0);
            soa.push(Vec3::new(0.0, a, b), wall_n, h, 1);
        }
    }
    let o = soa
        .build(&[class::DIFFUSE, class::DIFFUSE], OctreeParams::default())
        .unwrap();
    let view = o.view();
    let accel = pc_tree::accel::Accel::new(&view);
    let mut st = TraversalStats::default();
    for k in 0..20 {
        // Straight down onto the floor, a fifth of a radius from the wall.
        let r = Ray::new(Vec3::new(0.2 * h, 0.5, 0.1 + 0.03 * k as f32), -Vec3::Y);
        let (hit, leaf) = accel.intersect_in(&view, &r, &mut st).expect("the floor");
        let x = r.origin + r.dir * hit.t;
        let (mut a, mut b) = (Vec::new(), Vec::new());
        accel.covering(&view, leaf, x, floor_n, 0.5, &mut a);
        pc_tree::covering(&view, hit.leaf, x, floor_n, 0.5, &mut b);
        assert_eq!(a, b, "ray {k}");
        assert!(!a.is_empty(), "ray {k}: no floor splat covers its hit");
        for (j, _) in a {
            assert_eq!(
                view.splats[j as usize].material, 0,
                "ray {k}: the wall blends in"
            );
        }
    }
}

/// The packed walk skips whole internal nodes whose disks all lie in a thin slab the ray's
/// stretch misses: the hits stay identical, on the rays the V-map casts most (segments between
/// two splats, which leave one wall and end just before another) and on the others, and the
/// walk visits fewer cells.
#[test]
fn node_slabs_skip_cells_without_changing_a_hit() {
    // Walls and a densely sampled ball: curved nodes get slabs too, thicker ones.
    let (mut s, classes) = mixed_scene(0.025);
    s.sphere(Vec3::new(0.3, 0.2, -0.4), 0.35, 12000, 0);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    let accel = pc_tree::accel::Accel::new(&view);
    assert!(
        accel.slabbed_nodes() >= 1000,
        "{} node slabs",
        accel.slabbed_nodes()
    );
    accel.verify_slabs().unwrap();
    let mut rng = Pcg64::seed_from_u64(34);
    let (mut packed, mut plain) = (TraversalStats::default(), TraversalStats::default());
    let n = view.splats.len();
    let mut blocked = 0;
    for k in 0..20000 {
        let a = &view.splats[rng.random_range(0..n)];
        let r = if k % 2 == 0 {
            // A V-map ray: from one splat to another, its self-hit distance off either end.
            let b = &view.splats[rng.random_range(0..n)];
            let (pa, pb) = (Vec3::from(a.position), Vec3::from(b.position));
            let len = (pb - pa).length();
            if len < 1e-3 {
                continue;
            }
            let mut r = Ray::new(pa, (pb - pa) / len);
            r.t_min = 0.5 * a.radius;
            r.t_max = (len - 0.5 * b.radius).max(r.t_min);
            r
        } else {
            // A bounce ray leaving a splat.
            let n = Vec3::from(a.normal);
            let d = random_dir(&mut rng);
            let mut r = Ray::new(Vec3::from(a.position), if d.dot(n) < 0.0 { -d } else { d });
            r.t_min = 0.5 * a.radius;
            r
        };
        let occluded = pc_tree::occluded(&view, &r, &mut plain);
        blocked += occluded as usize;
        assert_eq!(accel.occluded(&view, &r, &mut packed), occluded, "ray {k}");
        assert_eq!(
            accel.intersect(&view, &r, &mut packed),
            pc_tree::intersect(&view, &r, &mut plain),
            "ray {k}"
        );
    }
    assert!(blocked > 2000, "{blocked} blocked");
    assert!(
        packed.cells * 4 < plain.cells * 3,
        "cells: packed {} vs plain {}",
        packed.cells,
        plain.cells
    );
}

/// Camera rays end on a surface, so the node slabs cannot skip the nodes around their hits; the
/// packed walk instead jumps, in each node with a slab, straight to where the ray enters the
/// slab (no disk listed below the node lies before it). Rays from outside the walls to their
/// splats, at grazing angles too: the hits stay those of the artifact's walk, in far fewer cells.
#[test]
fn slab_entries_take_camera_rays_to_their_surfaces_without_changing_a_hit() {
    let (s, classes) = mixed_scene(0.02);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    let accel = pc_tree::accel::Accel::new(&view);
    let mut rng = Pcg64::seed_from_u64(35);
    let (mut packed, mut plain) = (TraversalStats::default(), TraversalStats::default());
    let n = view.splats.len();
    let mut hits = 0;
    for k in 0..20000 {
        // An eye in front of the walls, or one far off to the side (grazing rays).
        let eye = if k % 2 == 0 {
            Vec3::new(0.8, 0.8, 0.8)
        } else {
            Vec3::new(rng.random_range(-0.95..0.95), 0.95, -0.97)
        };
        let target = Vec3::from(view.splats[rng.random_range(0..n)].position);
        let jitter = Vec3::new(
            rng.random_range(-0.01..0.01),
            rng.random_range(-0.01..0.01),
            rng.random_range(-0.01..0.01),
        );
        let d = (target + jitter - eye).normalize();
        let r = Ray::new(eye, d);
        let hit = pc_tree::intersect(&view, &r, &mut plain);
        hits += hit.is_some() as usize;
        assert_eq!(accel.intersect(&view, &r, &mut packed), hit, "ray {k}");
        assert_eq!(
            accel.occluded(&view, &r, &mut packed),
            pc_tree::occluded(&view, &r, &mut plain),
            "ray {k}"
        );
    }
    assert!(hits > 15000, "{hits} hits");
    // 271k cells against 886k (387k with the node slabs alone, before the jumps).
    assert!(
        packed.cells * 3 < plain.cells,
        "cells: packed {} vs plain {}",
        packed.cells,
        plain.cells
    );
}
