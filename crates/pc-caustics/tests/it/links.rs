//! The specular links' paths (D S⁺ D) where a diffuse surface touches a specular one: the flux
//! they carry matches the analytic form factor, and no path weighs far more than the rest.

use glam::Vec3;
use pc_caustics::emit::Source;
use pc_caustics::stage::trace_all;
use pc_testkit::Soa;
use pc_tree::rng::rand;
use rand::SeedableRng;
use rand_pcg::Pcg64;

use super::{diffuse, mirror, with_setup};

/// `∫∫ R³ / (x² + y² + R²)^{3/2} dx dy` over the square |x|, |y| < a: the form factor from the
/// points of a floor to a sphere of radius R resting on it at the origin, integrated over the
/// floor (a sphere wholly above a point's horizon subtends F = cos θ R² / d², d the distance to
/// its centre).
fn floor_to_resting_sphere(a: f64, radius: f64) -> f64 {
    let n = 2000;
    let h = 2.0 * a / n as f64;
    let mut sum = 0.0;
    for i in 0..n {
        let x = -a + (i as f64 + 0.5) * h;
        for j in 0..n {
            let y = -a + (j as f64 + 0.5) * h;
            sum += radius.powi(3) / (x * x + y * y + radius * radius).powf(1.5);
        }
    }
    sum * h * h
}

/// A perfect mirror ball of radius 0.3 resting on the floor of a closed diffuse box (inward
/// faces, half-side 1). Every path from the floor into the ball lands on the box after one
/// reflection, so the floor's paths carry `π ∫ F dA` of the analytic form factor, contact
/// included: there the ball's underside lies closer to the floor than a splat's radius (the
/// own zone passes over the floor only), and the point-to-point geometry has no bound (the
/// direction strategy bounds it).
#[test]
fn links_at_a_contact_carry_the_form_factor_flux_with_bounded_weights() {
    floor_to_ball_flux(0.0);
}

/// The same with range noise on the floor (each floor splat moved along its normal by about a
/// quarter of the spacing and its normal tilted by up to 8°, as a scan's): paths leaving the
/// floor at a shallow angle meet the floor's own noise, which their own zone passes over, so
/// the flux into the ball is the flat floor's.
#[test]
fn links_from_a_noisy_floor_pass_over_its_own_noise() {
    floor_to_ball_flux(0.25);
}

/// The floor's flux into the mirror ball against the analytic form factor, the floor's splats
/// moved along their normals by `noise` spacings (standard deviation) and tilted.
fn floor_to_ball_flux(noise: f32) {
    let (a, radius) = (1.0f32, 0.3f32);
    let mut rng = Pcg64::seed_from_u64(21);
    let mut s = Soa::default();
    let h = 0.04;
    let (x, y, z) = (Vec3::X * a, Vec3::Y * a, Vec3::Z * a);
    s.rect(Vec3::ZERO, x, y, h, 0, &mut rng); // floor, normal +z
    let floor = s.len();
    s.rect(2.0 * z, y, x, h, 0, &mut rng); // ceiling, -z
    s.rect(z + x, z, y, h, 0, &mut rng); // -x
    s.rect(z - x, y, z, h, 0, &mut rng); // +x
    s.rect(z + y, x, z, h, 0, &mut rng); // -y
    s.rect(z - y, z, x, h, 0, &mut rng); // +y
    s.sphere(Vec3::Z * radius, radius, 20_000, 1);
    for k in (0..floor).filter(|_| noise > 0.0) {
        use rand::Rng;
        let g: f32 = (0..4).map(|_| rng.random_range(-1.0f32..1.0)).sum::<f32>() * 0.866;
        s.p[k].z += g * noise * h;
        let tilt = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            0.0,
        );
        s.n[k] = (s.n[k] + tilt * 0.1).normalize();
    }
    let light = (Vec3::new(0.0, 0.0, 1.8), Vec3::splat(1.0));
    let materials = [diffuse(0.5), mirror(1.0)];
    with_setup(&s, &materials, light, 2_400_000, |su| {
        let traced = trace_all(su.tracer, su.link_aims, &|_| {});
        let mut first = Vec::new();
        let mut total = 0u64;
        for a in su.link_aims {
            first.push(total);
            total += a.photons as u64;
        }
        // Whether path `id` left the floor: the splat of the tracer's draw 0 (seed 3).
        let from_floor = |id: u32| {
            let k = first.partition_point(|&f| f <= id as u64) - 1;
            match su.link_aims[k].source {
                Source::Area(l) => {
                    let j = su.leaves.pick(su.view, l, rand(3, id, 0, 0));
                    su.view.splats[j as usize].normal[2] > 0.9
                }
                Source::Point(_) => false,
            }
        };
        let weights: Vec<(f64, bool)> = traced
            .photons
            .iter()
            .zip(&traced.id)
            .map(|(p, &id)| (p.power[0] as f64, from_floor(id)))
            .collect();
        let floor: f64 = weights.iter().filter(|w| w.1).map(|w| w.0).sum();
        let expected = std::f64::consts::PI * floor_to_resting_sphere(a as f64, radius as f64);
        let mean = weights.iter().map(|w| w.0).sum::<f64>() / weights.len() as f64;
        let max = weights.iter().map(|w| w.0).fold(0.0, f64::max);
        let rel = floor / expected - 1.0;
        eprintln!(
            "noise {noise}: {} link paths stored; floor → ball flux {floor:.5} against \
             {expected:.5} ({:+.2} %); heaviest path {:.1} × the mean",
            weights.len(),
            rel * 100.0,
            max / mean
        );
        assert!(
            rel.abs() < 0.03,
            "floor → ball flux {:+.2} % off",
            rel * 100.0
        );
        assert!(
            max < 100.0 * mean,
            "a path weighs {:.0} × the mean",
            max / mean
        );
    });
}

/// A path drawn by direction skips its walk where it misses its target node's ball
/// (`pc_caustics::trace::may_meet`): no ray that misses the ball meets one of the node's disks.
/// Rays aimed at points around each target node's centroid (up to 1.3 times its ball's radius
/// off), from anywhere in the box, against every disk of the node by brute force; the ball's
/// edge is crossed both ways, and most rays are ruled out.
#[test]
fn a_ray_that_misses_a_node_s_ball_meets_none_of_its_disks() {
    use pc_caustics::emit::Sampling;
    use pc_caustics::trace::may_meet;
    use pc_tree::{intersect_splat, Ray};
    use rand::Rng;

    let mut rng = Pcg64::seed_from_u64(8);
    let mut s = Soa::default();
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    s.rect(Vec3::ZERO, x, y, 0.05, 0, &mut rng); // floor
    s.rect(2.0 * z, y, x, 0.05, 0, &mut rng); // ceiling
    s.sphere(Vec3::new(-0.4, 0.0, 0.3), 0.3, 6_000, 1); // mirror ball
    s.rect(
        Vec3::new(0.6, 0.0, 0.8),
        0.4 * (x + z).normalize(),
        0.4 * y,
        0.04,
        1,
        &mut rng,
    ); // tilted mirror
    let light = (Vec3::new(0.0, 0.0, 1.8), Vec3::splat(1.0));
    let materials = [diffuse(0.5), mirror(1.0)];
    with_setup(&s, &materials, light, 200_000, |su| {
        let mut targets: Vec<(u32, u32, u32)> = su
            .link_aims
            .iter()
            .filter_map(|a| match a.sampling {
                Sampling::Direction { lo, hi, node, .. } => Some((node, lo, hi)),
                _ => None,
            })
            .collect();
        targets.sort_unstable();
        targets.dedup();
        assert!(targets.len() >= 20, "{} target nodes", targets.len());
        let (mut cast, mut ruled_out, mut hits, mut hits_near_edge) = (0, 0, 0, 0);
        for &(node, lo, hi) in &targets {
            let info = su.view.node_info[node as usize];
            let (c, reach) = (Vec3::from(info.centroid), info.disk_radius);
            for _ in 0..200 {
                let origin = Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(0.0..2.0),
                );
                let off = Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                let dir = (c + off.normalize_or_zero() * rng.random_range(0.0..1.3) * reach
                    - origin)
                    .normalize();
                let ray = Ray::new(origin, dir);
                let met = (lo..hi).any(|j| {
                    intersect_splat(origin, dir, &su.view.splats[j as usize])
                        .is_some_and(|t| t >= 0.0)
                });
                let may = may_meet(su.view, node, &ray);
                assert!(
                    may || !met,
                    "a ray from {origin} along {dir} meets a disk of node {node} outside its ball"
                );
                cast += 1;
                ruled_out += usize::from(!may);
                hits += usize::from(met);
                // A hit whose ray passes the centroid at more than 0.7 of the ball's radius.
                let to = c - origin;
                let miss = (to - dir * to.dot(dir)).length();
                hits_near_edge += usize::from(met && miss > 0.7 * reach);
            }
        }
        eprintln!(
            "{cast} rays at {} nodes: {ruled_out} ruled out, {hits} meet a disk of theirs \
             ({hits_near_edge} past 0.7 of the ball's radius)",
            targets.len()
        );
        assert!(hits_near_edge > 0, "no hit tests the ball's edge");
        assert!(ruled_out > cast / 10, "{ruled_out} of {cast} ruled out");
    });
}
