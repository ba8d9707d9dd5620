//! Camera rays start their walk at their pixel's bound (`pc_raytrace::camera_near`): the same
//! first hits as from the camera.

use glam::Vec3;
use pc_raytrace::scene::RenderScene;
use pc_tree::{Ray, TraversalStats};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::{camera, diffuse, params, BuildSoa, Soa};
use pc_config::ShadingMode;

/// Every camera ray of `sc` (four random ones a pixel) hits from its pixel's bound exactly what
/// it hits from the camera, never nearer than the bound. Returns the share of pixels with a
/// bound above 0 and the cells walked from the camera and from the bounds.
fn check(sc: &RenderScene, seed: u64) -> (f32, u64, u64) {
    let near = pc_raytrace::camera_near::near_bounds(&sc.view, &sc.camera());
    let (w, h) = (sc.params.width, sc.params.height);
    assert_eq!(near.len(), (w * h) as usize);
    let origin = Vec3::from(sc.params.cam_origin);
    let mut rng = Pcg64::seed_from_u64(seed);
    let (mut full, mut from) = (TraversalStats::default(), TraversalStats::default());
    for py in 0..h {
        for px in 0..w {
            let i = (py * w + px) as usize;
            for _ in 0..4 {
                let (u, v): (f32, f32) = (rng.random(), rng.random());
                let dir = sc.camera_dir((px as f32 + u) / w as f32, (py as f32 + v) / h as f32);
                let ray = Ray::new(origin, dir);
                let a = sc.intersect_in(&ray, &mut full);
                let b = sc.intersect_in(
                    &Ray {
                        t_min: near[i],
                        ..ray
                    },
                    &mut from,
                );
                assert_eq!(
                    a, b,
                    "pixel ({px}, {py}): from the camera and from {}",
                    near[i]
                );
                if let Some((hit, _)) = a {
                    assert!(
                        hit.t >= near[i],
                        "pixel ({px}, {py}): hit at {} before its bound {}",
                        hit.t,
                        near[i]
                    );
                }
            }
        }
    }
    let positive = near.iter().filter(|&&d| d > 0.0).count() as f32 / near.len() as f32;
    (positive, full.cells, from.cells)
}

#[test]
fn camera_rays_from_their_pixel_bound_hit_what_they_hit_from_the_camera() {
    let mut rng = Pcg64::seed_from_u64(7);
    let mut s = Soa::default();
    // A floor running under and behind the camera, a box, a sphere half hidden behind it, and
    // a wall beside the camera reaching past its plane.
    s.rect(
        Vec3::new(0.0, -0.5, 0.0),
        Vec3::X * 3.0,
        -Vec3::Z * 3.0,
        0.03,
        0,
        &mut rng,
    );
    s.cube(
        Vec3::new(0.2, -0.2, -1.0),
        Vec3::splat(0.3),
        0.02,
        0,
        &mut rng,
    );
    s.sphere(Vec3::new(-0.1, 0.0, -1.7), 0.35, 4000, 0);
    s.rect(
        Vec3::new(-0.8, 0.0, 0.5),
        Vec3::Z * 2.0,
        Vec3::Y * 0.6,
        0.03,
        0,
        &mut rng,
    );
    let mats = vec![diffuse(0.5)];
    let o = s.build(&mats);
    let views = [
        // Looking at the box and the sphere.
        (Vec3::new(0.0, 0.2, 1.0), Vec3::new(0.0, -0.1, -1.0)),
        // From 1 cm over the floor: its disks under the camera reach the camera's plane, so
        // every pixel's bound is at most the floor's 1 cm.
        (Vec3::new(0.3, -0.49, 0.8), Vec3::new(0.0, -0.45, -1.0)),
    ];
    for (k, (eye, target)) in views.into_iter().enumerate() {
        let cam = camera(eye, target, Vec3::Y, 60.0, 64, 48);
        let mut sc = RenderScene::new(
            o.view(),
            mats.clone(),
            &[],
            &cam,
            &params(4, ShadingMode::Stored),
        );
        sc.prepare_cpu();
        let (positive, cells_full, cells_from) = check(&sc, k as u64);
        if k == 0 {
            assert!(
                positive > 0.9,
                "only {positive} of the pixels start past the camera"
            );
            assert!(
                (cells_from as f64) < 0.8 * cells_full as f64,
                "cells walked: {cells_from} from the bounds, {cells_full} from the camera"
            );
        } else {
            let far = pc_raytrace::camera_near::near_bounds(&sc.view, &sc.camera())
                .into_iter()
                .fold(0.0f32, f32::max);
            assert!(
                far <= 0.0101,
                "a disk reaches the camera's plane in view, yet a bound is {far}"
            );
        }
    }
}

/// The bounds are made for the camera of the moment, and only where the frame has at least as
/// many camera samples as splats.
#[test]
fn a_moved_camera_gets_new_bounds() {
    let mut rng = Pcg64::seed_from_u64(3);
    let mut s = Soa::default();
    s.rect(
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::X,
        Vec3::Y,
        0.05,
        0,
        &mut rng,
    );
    let mats = vec![diffuse(0.5)];
    let o = s.build(&mats);
    let near_cam = camera(
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::Y,
        40.0,
        8,
        8,
    );
    let far_cam = camera(
        Vec3::new(0.0, 0.0, 2.0),
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::Y,
        40.0,
        8,
        8,
    );
    let splats = o.view().splats.len();
    assert!(splats > 4 * 64 && splats <= 8 * 8 * 32, "{splats} splats");
    let few = RenderScene::new(
        o.view(),
        mats.clone(),
        &[],
        &near_cam,
        &params(1, ShadingMode::Stored),
    );
    assert!(
        few.camera_near().is_none(),
        "64 samples over {splats} splats"
    );
    let mut sc = RenderScene::new(
        o.view(),
        mats,
        &[],
        &near_cam,
        &params(32, ShadingMode::Stored),
    );
    let centre = |sc: &RenderScene| sc.camera_near().expect("32 samples a pixel pay")[4 * 8 + 4];
    let d_near = centre(&sc);
    sc.set_camera(&far_cam);
    let d_far = centre(&sc);
    // The wall is 1 m and 4 m away; the bounds lie within a disk's radius (5 cm) of it.
    assert!((0.94..=1.0).contains(&d_near), "{d_near}");
    assert!((3.94..=4.0).contains(&d_far), "{d_far}");
}

/// The bounds against brute force: through every pixel (its corners, edges, centre and random
/// points), no ray meets a splat's disk nearer than the pixel's bound. Isolated splats a few
/// pixels wide, so each pixel's bound comes from one disk, and a footprint cut short by a
/// fraction of a pixel shows.
#[test]
fn no_ray_through_a_pixel_meets_a_splat_before_its_bound() {
    let mut rng = Pcg64::seed_from_u64(11);
    let mut s = Soa::default();
    for _ in 0..400 {
        let p = Vec3::new(
            rng.random_range(-1.2..1.2),
            rng.random_range(-0.9..0.9),
            rng.random_range(-3.0..-1.0),
        );
        let n = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            1.0,
        )
        .normalize();
        s.push(p, n, rng.random_range(0.01..0.03), 0);
    }
    let mats = vec![diffuse(0.5)];
    let o = s.build(&mats);
    let cam = camera(Vec3::ZERO, -Vec3::Z, Vec3::Y, 60.0, 96, 72);
    let sc = RenderScene::new(o.view(), mats, &[], &cam, &params(1, ShadingMode::Stored));
    let near = pc_raytrace::camera_near::near_bounds(&sc.view, &sc.camera());
    let (w, h) = (96u32, 72u32);
    let disks: Vec<(Vec3, Vec3, f32)> = o
        .view()
        .splats
        .iter()
        .map(|s| (Vec3::from(s.position), Vec3::from(s.normal), s.radius))
        .collect();
    let mut spots: Vec<(f32, f32)> = [0.0, 0.5, 0.9999]
        .iter()
        .flat_map(|&u| [0.0, 0.5, 0.9999].map(|v| (u, v)))
        .collect();
    spots.extend((0..8).map(|_| (rng.random::<f32>(), rng.random::<f32>())));
    let mut met = 0;
    for py in 0..h {
        for px in 0..w {
            let bound = near[(py * w + px) as usize];
            for &(u, v) in &spots {
                let d = sc.camera_dir((px as f32 + u) / w as f32, (py as f32 + v) / h as f32);
                for &(c, n, r) in &disks {
                    let t = c.dot(n) / d.dot(n);
                    if t > 0.0 && (d * t - c).length() <= r {
                        met += 1;
                        assert!(
                            bound <= t,
                            "pixel ({px}, {py}) at ({u}, {v}): a disk at {t}, the bound {bound}"
                        );
                    }
                }
            }
        }
    }
    assert!(met > 5000, "only {met} ray-disk meetings tested");
}
