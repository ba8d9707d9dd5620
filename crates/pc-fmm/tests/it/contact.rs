//! The shadow under a ball resting on a floor: the emitters' direct light on the floor against
//! the analytic occluded form factor.

use glam::Vec3;
use rand::SeedableRng;
use rand_pcg::Pcg64;

use crate::specular::solve_full;
use crate::{diffuse, emitter, scene, Soa};
use pc_fmm::{gather, tree};

/// A floor (z = 0, radius 1.95) under an emitting hemisphere of radius 2 (inward), with a black
/// ball of radius R = 0.3 resting on the floor at the origin. A floor point at distance r from
/// the contact sees the dome everywhere but where the ball hides it, so its reflected direct
/// light is `ρ Lₑ (1 − F)` with `F = R³ / (r² + R²)^{3/2}` (a sphere wholly above the
/// horizon subtends `cos θ R² / d²`).
/// The floor, the hemisphere (material 1) and the ball (material 2).
fn ball_on_floor(radius: f32) -> Soa {
    let mut rng = Pcg64::seed_from_u64(9);
    let mut floor = Soa::default();
    floor.rect(Vec3::ZERO, Vec3::X * 2.0, Vec3::Y * 2.0, 0.03, 0, &mut rng);
    let mut sky = Soa::default();
    sky.sphere(Vec3::ZERO, 2.0, 24_000, 1);
    let mut ball = Soa::default();
    ball.sphere(Vec3::Z * radius, radius, 4_000, 2);
    let mut soa = Soa::default();
    for i in 0..floor.len() {
        if floor.p[i].truncate().length() < 1.95 {
            soa.push(floor.p[i], floor.n[i], floor.r[i], 0);
        }
    }
    for i in 0..sky.len() {
        if sky.p[i].z > 0.0 {
            soa.push(sky.p[i], -sky.n[i], sky.r[i], 1);
        }
    }
    for i in 0..ball.len() {
        soa.push(ball.p[i], ball.n[i], ball.r[i], 2);
    }
    soa
}

/// The worst error over rings around the contact of the floor's light `light` (per splat)
/// against `ρ Lₑ (1 − F)`, in units of the open floor's `ρ Lₑ` (the shadow's depth; in the
/// core the light is 3 % of that, so a relative error there is mostly noise).
fn rings(view: &pc_tree::OctreeView, light: &[f32], radius: f32, rho_le: f64) -> f64 {
    let rings = [0.0f32, 0.06, 0.1, 0.15, 0.25, 0.4, 0.7, 1.2];
    let mut worst = 0.0f64;
    for w in rings.windows(2) {
        let (mut got, mut want, mut count) = (0.0f64, 0.0f64, 0);
        for (i, s) in view.splats.iter().enumerate() {
            let r = Vec3::from(s.position).truncate().length();
            if s.material != 0 || r < w[0] || r >= w[1] {
                continue;
            }
            let f = (radius as f64).powi(3) / ((r * r + radius * radius) as f64).powf(1.5);
            got += light[i] as f64;
            want += rho_le * (1.0 - f);
            count += 1;
        }
        let rel = got / want - 1.0;
        let depth = (got - want) / count as f64 / rho_le;
        println!(
            "r in [{:.2}, {:.2}): {count} splats, {:.4} against {:.4} ({:+.1} %, {:+.2} % of the open floor)",
            w[0],
            w[1],
            got / count as f64,
            want / count as f64,
            rel * 100.0,
            depth * 100.0
        );
        worst = worst.max(depth.abs());
    }
    worst
}

#[test]
fn the_shadow_under_a_resting_ball_is_the_occluded_form_factor() {
    let radius = 0.3f32;
    let soa = ball_on_floor(radius);
    let (le, rho) = (1.0f32, 0.5f32);
    let sc = scene(&soa, vec![diffuse(rho), emitter(le, 0.0), diffuse(0.0)], 16);
    let view = sc.octree.view();
    let (_, pts) = tree::build(&view, &sc.materials);
    let tester = pc_tree::caster::CpuCaster::new(&view);
    let mut sys = pc_fmm::System::zeros(view.splats.len());
    for (i, s) in view.splats.iter().enumerate() {
        match s.material {
            0 => sys.albedo[i] = [rho; 3],
            1 => sys.emission[i] = [le; 3],
            _ => {}
        }
    }
    let how = pc_fmm::emitter::EmitterSampling {
        samples: 1024,
        probes: 0,
        self_hit: 0.5,
        shafts: false,
    };
    pc_fmm::emitter::emitter_direct(&view, &pts, &mut sys, how, &tester).unwrap();
    let light: Vec<f32> = sys.source.iter().map(|l| l[0]).collect();
    let worst = rings(&view, &light, radius, (rho * le) as f64);
    assert!(
        worst < 0.01,
        "a ring is {:.2} % of the open floor off",
        worst * 100.0
    );
}

/// The same shadow through the FMM's transport and the V-map's links: the hemisphere a diffuse
/// surface of radiance 1 (in the source term, not an emitter), the floor `ρ (T L)`.
///
/// A link's visible fraction is one number for every splat of its V-map leaf, and the shadow
/// changes from 3 % to 30 % of the open floor's light within the 0.24 m a leaf of 64 floor
/// splats spans: through the links alone the core (r < 6 cm) gets +6.9 % of the open floor's
/// light (+270 %), 6-10 cm +3.8 %. The V-map's `smear` finds those leaves, and the final gather
/// gives their splats the light their own rays see (docs/fmm.md, "Final gather").
#[test]
fn the_transport_keeps_the_shadow_under_a_resting_ball() {
    let radius = 0.3f32;
    let soa = ball_on_floor(radius);
    let rho = 0.5f32;
    let sc = scene(&soa, vec![diffuse(rho), diffuse(0.0), diffuse(0.0)], 16);
    let view = sc.octree.view();
    let (pts, sys, mut radiance) = solve_full(&sc, None, &|_| {
        let mut sys = pc_fmm::System::zeros(view.splats.len());
        for (i, s) in view.splats.iter().enumerate() {
            match s.material {
                0 => sys.albedo[i] = [rho; 3],
                1 => sys.source[i] = [1.0; 3],
                _ => {}
            }
        }
        sys
    });
    let red = |l: &[[f32; 3]]| l.iter().map(|l| l[0]).collect::<Vec<f32>>();
    println!("the FMM alone:");
    let before = rings(&view, &red(&radiance), radius, rho as f64);
    assert!(before > 0.03, "the links alone smear the shadow: {before}");

    let p = pc_artifact::params::FmmParams::default();
    let reflected = gather::reflected(&radiance, &sys.emission, &pts.active);
    let solved = gather::Solved {
        radiance: &radiance,
        source: &sys.source,
        albedo: &sys.albedo,
        active: &pts.active,
    };
    let rough = pc_tree::between::leaf_roughness(&view);
    let accel = pc_tree::accel::Accel::new(&view).with_own_surfaces(&view);
    let gatherer = gather::Gatherer::cpu((&view, &accel), &rough, reflected);
    let rays = gather::GatherRays::new(p.gather_rays);
    let how = gather::Selection::of(&p);
    let leaves = gather::candidates(&view, &sc.vmap(), how);
    let g = gather::run(
        &view,
        &sc.vmap(),
        &leaves,
        solved,
        how,
        rays,
        &gatherer,
        &|_| None,
    )
    .unwrap();
    for (&i, l) in g.splats.iter().zip(&g.radiance) {
        radiance[i as usize] = *l;
    }
    let splats = &g.splats;
    println!("{} candidate splats piloted", g.piloted);
    println!("with the final gather of {} splats:", splats.len());
    let worst = rings(&view, &red(&radiance), radius, rho as f64);
    assert!(
        worst < 0.01,
        "a ring is {:.2} % of the open floor off",
        worst * 100.0
    );
    // The gather stays near the contact: far floor, the sky and most of the ball keep the solve.
    assert!(
        splats.len() * 10 < view.splats.len(),
        "{} splats gathered",
        splats.len()
    );
}

/// A closed box whose every splat is moved along its normal by range noise and tilted by up to
/// about 8° (a scan's noise and the normals fitted to it), all reflecting `L − Lₑ = 1`: every
/// gather ray of a floor splat meets the front of some wall, so the floor gathers 1. Rays that
/// counted the floor's own noise as a surface (the Δ rule alone) brought nothing back from the
/// disks they hit from behind; each ray now passes over its own zone, as the V-map's do.
#[test]
fn a_noisy_floor_gathers_the_room_not_its_own_noise() {
    let h = 0.05;
    let mut soa = crate::box_scene(h);
    let mut rng = Pcg64::seed_from_u64(5);
    for k in 0..soa.len() {
        use rand::Rng;
        let g: f32 = (0..4).map(|_| rng.random_range(-1.0f32..1.0)).sum::<f32>() * 0.866;
        soa.p[k] += soa.n[k] * (g * 0.4 * h);
        let tilt = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let t = tilt - soa.n[k] * tilt.dot(soa.n[k]);
        soa.n[k] = (soa.n[k] + t * 0.14).normalize();
    }
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let view = sc.octree.view();
    let ones = vec![[1.0f32; 3]; view.splats.len()];
    // Floor splats away from the walls and the cube.
    let floor: Vec<u32> = (0..view.splats.len() as u32)
        .filter(|&i| {
            let s = &view.splats[i as usize];
            let p = Vec3::from(s.position);
            s.normal[1] > 0.9 && p.x.abs() < 0.8 && p.z.abs() < 0.8 && p.x.min(p.z) < -0.1
        })
        .collect();
    assert!(floor.len() > 100, "{} floor splats", floor.len());
    let accel = pc_tree::accel::Accel::new(&view);
    let rough = pc_tree::between::leaf_roughness(&view);
    let rays = gather::GatherRays::new(64);
    let got = gather::gather_cpu((&view, &accel, &rough), &ones, rays, &floor);
    let mean = got.iter().map(|g| g[0] as f64).sum::<f64>() / got.len() as f64;
    // The same rays with the Δ rule alone: a hit within half a radius on a splat facing like
    // the floor passed over, any other hit taken.
    let mut st = pc_tree::TraversalStats::default();
    let (mut front, mut all) = (0usize, 0usize);
    for &i in &floor {
        let s = &view.splats[i as usize];
        for k in 0..64 {
            let u = |c: u32| pc_tree::rng::rand(0x6761_7468, i, k, c);
            let ray = pc_tree::Ray {
                origin: s.position.into(),
                dir: pc_tree::cosine_dir(s.normal, u(0), u(1)),
                t_min: 1e-3 * s.radius,
                t_max: f32::INFINITY,
            };
            let n = Vec3::from(s.normal);
            let hit = delta_rule(&view, &accel, ray, n, 0.5 * s.radius, &mut st);
            all += 1;
            front += hit.is_some_and(|h| {
                Vec3::from(view.splats[h.splat as usize].normal).dot(ray.dir) < 0.0
            }) as usize;
        }
    }
    let delta = front as f64 / all as f64;
    println!(
        "{} floor splats gather {mean:.4}; the Δ rule alone {delta:.4}",
        floor.len()
    );
    assert!(
        delta < 0.9,
        "the noise must matter: the Δ rule alone gathers {delta:.4}"
    );
    assert!(
        mean > 0.97,
        "a noisy floor gathers {mean:.4} of its closed room's light"
    );
}

/// The nearest hit of `ray` leaving a surface of normal `normal` under the Δ rule: hits within
/// `skip` on splats facing like the origin (normals within 60°) passed over, any other taken.
fn delta_rule(
    view: &pc_tree::OctreeView,
    accel: &pc_tree::accel::Accel,
    mut ray: pc_tree::Ray,
    normal: Vec3,
    skip: f32,
    st: &mut pc_tree::TraversalStats,
) -> Option<pc_tree::Hit> {
    loop {
        let hit = accel.intersect(view, &ray, st)?;
        let own = Vec3::from(view.splats[hit.splat as usize].normal).dot(normal) > 0.5;
        if hit.t >= skip || !own {
            return Some(hit);
        }
        ray.t_min = hit.t * (1.0 + 1e-6) + f32::MIN_POSITIVE;
    }
}

/// The CPU gather casts its rays sorted by direction across splats (`gather_cpu`) and sums each
/// splat's rays in the splat's own order: every splat's light is, to the bit, what it gathers
/// alone (`gather_splat`), with light that differs from splat to splat so that a ray credited
/// to the wrong splat would show. Over more rays than one sorted batch holds.
#[test]
fn the_sorted_gather_is_each_splat_gathered_alone() {
    let soa = crate::box_scene(0.025);
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let view = sc.octree.view();
    let light: Vec<[f32; 3]> = (0..view.splats.len())
        .map(|i| [i as f32 * 1e-3, 1.0 / (1.0 + i as f32), (i % 7) as f32])
        .collect();
    let splats: Vec<u32> = (0..view.splats.len() as u32).collect();
    let accel = pc_tree::accel::Accel::new(&view);
    let rough = pc_tree::between::leaf_roughness(&view);
    let rays = gather::GatherRays::new(64);
    assert!(
        splats.len() * 64 > 1 << 21,
        "{} splats: one batch",
        splats.len()
    );
    let sorted = gather::gather_cpu((&view, &accel, &rough), &light, rays, &splats);
    let mut st = pc_tree::TraversalStats::default();
    for (&i, got) in splats.iter().zip(&sorted) {
        let alone = gather::gather_splat((&view, &accel, &rough), &light, rays, i, &mut st);
        assert_eq!(got.map(f32::to_bits), alone.map(f32::to_bits), "splat {i}");
    }
    assert!(sorted.iter().any(|g| g[0] > 0.0), "no ray found light");
}
