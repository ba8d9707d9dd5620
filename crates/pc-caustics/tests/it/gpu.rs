//! The GPU photon tracer against its CPU twin: the same photons (ids, random numbers, aims) on
//! a scene with a glass ball, a mirror and an emitting panel besides the point light.

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_caustics::emit::Sampling;
use pc_caustics::gpu::GpuTracer;
use pc_caustics::trace::Fate;
use pc_testkit::Soa;
use pc_tree::TraversalStats;
use rand::SeedableRng;
use rand_pcg::Pcg64;

use super::{diffuse, glass, mirror, with_setup};

fn scene() -> (Soa, Vec<MaterialRecord>, (Vec3, Vec3)) {
    let mut rng = Pcg64::seed_from_u64(21);
    let mut s = Soa::default();
    // Floor (diffuse), a glass ball and a tilted mirror above it, an emitting panel overhead.
    s.rect(Vec3::ZERO, 3.0 * Vec3::X, 3.0 * Vec3::Y, 0.04, 0, &mut rng);
    s.sphere(Vec3::new(-0.8, 0.0, 1.0), 0.5, 8_000, 1);
    s.rect(
        Vec3::new(1.0, 0.0, 0.8),
        0.5 * Vec3::new(1.0, 0.0, 1.0).normalize(),
        0.5 * Vec3::Y,
        0.03,
        2,
        &mut rng,
    );
    s.rect(
        Vec3::new(0.0, 0.0, 3.0),
        0.4 * Vec3::Y,
        0.4 * Vec3::X,
        0.04,
        3,
        &mut rng,
    );
    let emitter = MaterialRecord {
        color: [0.0; 3],
        class: class::EMITTER,
        radiance: [20.0; 3],
        ior: 1.0,
        ..Default::default()
    };
    let light = (Vec3::new(0.3, 0.2, 2.5), Vec3::splat(30.0));
    (
        s,
        vec![diffuse(0.5), glass(1.5), mirror(0.8), emitter],
        light,
    )
}

#[test]
fn gpu_photons_match_the_cpu_twin() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let (s, materials, light) = scene();
    with_setup(&s, &materials, light, 600_000, |su| {
        let t = su.tracer;
        let gpu = GpuTracer::new(
            &ctx,
            (su.view, t.rough),
            &materials,
            su.leaves,
            t.max_bounces,
            t.seed,
        )
        .unwrap();
        let on_gpu = gpu.fates(&ctx, su.aims).unwrap();
        let mut on_cpu = Vec::with_capacity(on_gpu.len());
        let mut st = TraversalStats::default();
        let mut id = 0u32;
        for a in su.aims {
            for _ in 0..a.photons {
                on_cpu.push(t.photon(a, id, &mut st));
                id += 1;
            }
        }
        assert_eq!(on_gpu.len(), on_cpu.len(), "same photon count");
        let n = on_cpu.len();
        assert!(n > 20_000, "{n} photons traced");
        assert!(
            su.aims
                .iter()
                .any(|a| matches!(a.source, pc_caustics::emit::Source::Area(_))),
            "the emitting panel aims photons too"
        );
        // Photon by photon: the same fate, and where both stored it, the same landing point,
        // except for the few whose path rounding sends another way (a splat's edge, a Fresnel
        // choice on the threshold).
        let (mut same_fate, mut both_stored, mut same_place) = (0usize, 0usize, 0usize);
        let (mut p_cpu, mut p_gpu, mut n_cpu, mut n_gpu) = (0f64, 0f64, 0usize, 0usize);
        for (c, g) in on_cpu.iter().zip(&on_gpu) {
            if std::mem::discriminant(c) == std::mem::discriminant(g) {
                same_fate += 1;
            }
            if let Fate::Stored(p) = c {
                p_cpu += p.power[0] as f64;
                n_cpu += 1;
            }
            if let Fate::Stored(p) = g {
                p_gpu += p.power[0] as f64;
                n_gpu += 1;
            }
            if let (Fate::Stored(a), Fate::Stored(b)) = (c, g) {
                both_stored += 1;
                if (Vec3::from(a.position) - Vec3::from(b.position)).length() < 1e-3
                    && a.bounces == b.bounces
                    && (Vec3::from(a.power) - Vec3::from(b.power))
                        .abs()
                        .max_element()
                        <= 1e-5 * Vec3::from(a.power).max_element()
                {
                    same_place += 1;
                }
            }
        }
        eprintln!(
            "{n} photons: {same_fate} same fate; stored CPU {n_cpu} GPU {n_gpu}, \
             {same_place} of {both_stored} stored at the same place; power CPU {p_cpu:.5} GPU {p_gpu:.5}"
        );
        assert!(n_cpu > 2_000, "{n_cpu} photons stored");
        assert!(
            same_fate as f64 > 0.99 * n as f64,
            "{same_fate} of {n} same fate"
        );
        assert!(
            same_place as f64 > 0.98 * both_stored as f64,
            "{same_place} of {both_stored} at the same place"
        );
        // Statistically: the stored counts and powers agree within noise (4 σ of a binomial).
        let p = n_cpu as f64 / n as f64;
        let sigma = (n as f64 * p * (1.0 - p)).sqrt();
        assert!(
            (n_cpu as f64 - n_gpu as f64).abs() < 4.0 * sigma,
            "stored {n_cpu} vs {n_gpu} (σ {sigma:.1})"
        );
        assert!(
            (p_cpu / p_gpu - 1.0).abs() < 4.0 / (n_cpu as f64).sqrt(),
            "deposited power {p_cpu} vs {p_gpu}"
        );
        // And the stage's compacting driver keeps the stored photons in id order.
        let traced = gpu.trace_all(&ctx, su.aims, &|_| {}).unwrap();
        let stored: Vec<_> = on_gpu
            .iter()
            .filter_map(|f| match f {
                Fate::Stored(p) => Some(*p),
                _ => None,
            })
            .collect();
        assert_eq!(traced.photons, stored);
        assert_eq!(traced.traced, n as u64);

        // The specular links' paths: the same tracer, power scaled by each path's geometry.
        let on_gpu = gpu.fates(&ctx, su.link_aims).unwrap();
        let mut id = 0u32;
        let (mut same_fate, mut both, mut same_power, mut n) = (0usize, 0usize, 0usize, 0usize);
        for a in su.link_aims {
            assert!(matches!(
                a.sampling,
                Sampling::Area { .. } | Sampling::Direction { .. }
            ));
            for _ in 0..a.photons {
                let c = t.photon(a, id, &mut st);
                let g = on_gpu[id as usize];
                same_fate += (std::mem::discriminant(&c) == std::mem::discriminant(&g)) as usize;
                if let (Fate::Stored(a), Fate::Stored(b)) = (c, g) {
                    both += 1;
                    let (pa, pb) = (Vec3::from(a.power), Vec3::from(b.power));
                    same_power +=
                        ((pa - pb).abs().max_element() <= 1e-4 * pa.max_element()) as usize;
                }
                id += 1;
                n += 1;
            }
        }
        eprintln!("{n} link paths: {same_fate} same fate, {same_power} of {both} stored with the same power");
        assert!(both > 1_000, "{both} link paths stored on both");
        assert!(same_fate as f64 > 0.99 * n as f64, "{same_fate} of {n}");
        assert!(
            same_power as f64 > 0.98 * both as f64,
            "{same_power} of {both}"
        );
    });
}
