//! Reflected and refracted directions on point-sampled spheres against analytic ones (Snell,
//! total internal reflection), within the error of the normal field (§8.5.5, §8.5.6).

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_raytrace::cpu::{fresnel, reflect, refract, shading_normal};
use pc_tree::{Ray, TraversalStats};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::{diffuse, BuildSoa, Soa};

#[test]
fn snell_and_total_internal_reflection_are_exact() {
    let n = Vec3::Y;
    for deg in [0.0f32, 10.0, 30.0, 45.0, 60.0, 80.0] {
        let th = deg.to_radians();
        let d = Vec3::new(th.sin(), -th.cos(), 0.0);
        // Air to glass: sin θt = sin θi / 1.5.
        let t = refract(d, n, 1.0 / 1.5).unwrap();
        assert!((t.length() - 1.0).abs() < 1e-5);
        let sin_t = t.x;
        assert!((sin_t - th.sin() / 1.5).abs() < 1e-6, "{deg}°");
        assert!(t.y < 0.0);
        // Reflection keeps the angle.
        let r = reflect(d, n);
        assert!((r - Vec3::new(th.sin(), th.cos(), 0.0)).length() < 1e-6);
    }
    // Glass to air: TIR beyond the critical angle asin(1/1.5) = 41.81°.
    let crit = (1.0f32 / 1.5).asin().to_degrees();
    for deg in [30.0f32, 41.0, 42.0, 60.0] {
        let th = deg.to_radians();
        let d = Vec3::new(th.sin(), -th.cos(), 0.0);
        let t = refract(d, Vec3::Y, 1.5);
        assert_eq!(t.is_none(), deg > crit, "{deg}° vs critical {crit}°");
        assert_eq!(fresnel(th.cos(), 1.5) == 1.0, deg > crit);
    }
    // Fresnel at normal incidence: ((n1 - n2) / (n1 + n2))² = 0.04.
    assert!((fresnel(1.0, 1.0 / 1.5) - 0.04).abs() < 1e-6);
}

#[test]
fn directions_off_point_sampled_spheres_match_the_analytic_sphere() {
    // A mirror sphere and a glass sphere of radius R in front of a wall.
    let (r_sphere, c_mirror, c_glass) =
        (0.5f32, Vec3::new(-0.6, 0.0, 0.0), Vec3::new(0.6, 0.0, 0.0));
    let mut rng = Pcg64::seed_from_u64(4);
    let mut s = Soa::default();
    s.rect(
        Vec3::new(0.0, 0.0, -1.5),
        Vec3::X * 2.0,
        Vec3::Y * 2.0,
        0.05,
        0,
        &mut rng,
    );
    s.sphere(c_mirror, r_sphere, 8000, 1);
    s.sphere(c_glass, r_sphere, 8000, 2);
    let mats = vec![
        diffuse(0.5),
        MaterialRecord {
            color: [1.0; 3],
            class: class::MIRROR,
            ior: 1.0,
            ..Default::default()
        },
        MaterialRecord {
            color: [1.0; 3],
            class: class::DIELECTRIC,
            ior: 1.5,
            ..Default::default()
        },
    ];
    let o = s.build(&mats);
    let view = o.view();
    let mut stats = TraversalStats::default();
    let (mut field_sum, mut flat_sum, mut n_tested) = (0.0f64, 0.0f64, 0);
    for _ in 0..2000 {
        let (center, glass) = if rng.random::<bool>() {
            (c_mirror, false)
        } else {
            (c_glass, true)
        };
        // Rays from the camera side at the sphere, avoiding the grazing rim.
        let a = rng.random_range(0.0..std::f32::consts::TAU);
        let rr = rng.random_range(0.0..0.8) * r_sphere;
        let target = center + Vec3::new(a.cos() * rr, a.sin() * rr, 0.0);
        let origin = Vec3::new(target.x, target.y, 3.0);
        let ray = Ray::new(origin, (target - origin).normalize());
        let hit = pc_tree::intersect(&view, &ray, &mut stats).expect("ray aimed at a sphere");
        let x = ray.origin + ray.dir * hit.t;
        let truth = (x - center).normalize();
        let n = shading_normal(&view, hit.splat, x);
        let ns = Vec3::from(view.splats[hit.splat as usize].normal);
        let normal_err = n.angle_between(truth);
        field_sum += normal_err as f64;
        flat_sum += ns.angle_between(truth) as f64;
        let want = if glass {
            refract(ray.dir, truth, 1.0 / 1.5).unwrap()
        } else {
            reflect(ray.dir, truth)
        };
        let got = if glass {
            refract(ray.dir, n, 1.0 / 1.5).unwrap()
        } else {
            reflect(ray.dir, n)
        };
        let err = got.angle_between(want);
        // A reflected direction turns by at most twice the normal's error; a refracted one
        // (air to glass) by less than the normal's error.
        let bound = if glass { normal_err } else { 2.0 * normal_err };
        assert!(
            err <= bound + 2e-3,
            "{} ray: direction off by {err} rad, normal off by {normal_err} rad",
            if glass { "glass" } else { "mirror" }
        );
        n_tested += 1;
    }
    assert!(n_tested > 1000);
    let (field, flat) = (field_sum / n_tested as f64, flat_sum / n_tested as f64);
    // The normal field (§8.5.5) is closer to the true sphere than the splats' own normals.
    assert!(
        field < 0.25 * flat && field.to_degrees() < 0.3,
        "mean normal error: field {:.3}°, splat normals {:.3}°",
        field.to_degrees(),
        flat.to_degrees()
    );
}
