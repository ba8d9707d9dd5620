//! pc-caustics tests: a flat mirror gives the mirror-image light's irradiance, no energy is
//! created (deposited power = emitted power × the reflectances along each path), and a glass
//! ball focuses a distant light at its paraxial focus nR / (2(n − 1)).

use glam::Vec3;
use pc_artifact::octree::MaterialRecord;
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::Link;
use pc_artifact::vmap::VmapView;
use pc_artifact::PointLight;
use pc_caustics::emit::{self, Aim, Leaves};
use pc_caustics::stage::{trace_all, Traced};
use pc_caustics::trace::Tracer;
use pc_octree::{build, BuildInput, OctreeParams};
use pc_testkit::Soa;
use pc_tree::accel::Accel;
use pc_tree::OctreeView;
use pc_vmap::build::{build_links, csr, light_lists, vnodes, CpuCaster};
use rand::SeedableRng;
use rand_pcg::Pcg64;

mod gpu;
mod links;

pub(crate) use pc_testkit::material::{diffuse, glass, mirror};

/// Octree, V-map and photons of `soa` under one point light.
struct Run {
    traced: Traced,
    aimed: Vec3,
    emitted: Vec3,
}

/// What the tracers need, built from a point set and one point light.
pub struct Setup<'a> {
    pub view: &'a OctreeView<'a>,
    pub leaves: &'a Leaves,
    pub aims: &'a [Aim],
    /// Aims of the specular links (from the diffuse leaves, per-sample geometry).
    pub link_aims: &'a [Aim],
    pub tracer: &'a Tracer<'a>,
    pub plan: &'a emit::Plan,
}

fn run(soa: &Soa, materials: &[MaterialRecord], light: (Vec3, Vec3), budget: u32) -> Run {
    with_setup(soa, materials, light, budget, |s| Run {
        traced: trace_all(s.tracer, s.aims, &|_| {}),
        aimed: s
            .aims
            .iter()
            .map(|a| Vec3::from(a.power) * a.photons as f32)
            .sum(),
        emitted: s.plan.emitted,
    })
}

/// Build the octree, the V-map links and light list, the emission plan and the aims of
/// `budget` photons (seed 3), and hand them to `f`.
pub fn with_setup<R>(
    soa: &Soa,
    materials: &[MaterialRecord],
    light: (Vec3, Vec3),
    budget: u32,
    f: impl FnOnce(&Setup) -> R,
) -> R {
    let albedo = soa.ones();
    let classes: Vec<u32> = materials.iter().map(|m| m.class).collect();
    let input = BuildInput {
        positions: &soa.p,
        normals: &soa.n,
        radii: &soa.r,
        albedo: &albedo,
        material: &soa.m,
        material_class: &classes,
    };
    let params = OctreeParams {
        max_leaf_points: 16,
        area_samples: 16,
        ..Default::default()
    };
    let octree = build(&input, &params, &mut |_| {}).unwrap();
    let view = octree.view();
    let p = VmapParams {
        theta: 0.5,
        rays: 16,
        near_rays: 64,
        leaf_splats: 64,
        self_hit: 0.5,
        refine_form_factor: 1e-3,
        heavy_rays: 64,
        heavy_form_factor: 3e-3,
        seed: 1,
        ..Default::default()
    };
    let vn = vnodes(&view, p.leaf_splats);
    let caster = CpuCaster::new(&view);
    let l = build_links(&view, &vn, &p, &caster, &mut |_, _| {}).unwrap();
    let (offsets, links) = csr(view.nodes.len(), l.pairs);
    let lists: Vec<Vec<Link>> = light_lists(&view, &vn, &[light.0], &p, &caster).unwrap();
    let node_range: Vec<[u32; 2]> = vn.iter().map(|v| [v.lo.min(v.hi), v.hi]).collect();
    let light_offsets = [0, lists[0].len() as u32];
    let cones: Vec<f32> = vn.iter().map(|v| v.cone_cos).collect();
    let vleaves: Vec<u32> = vn.iter().map(|v| v.vleaf as u32).collect();
    let input = VmapView {
        link_offsets: &offsets,
        links: &links,
        light_offsets: &light_offsets,
        light_links: &lists[0],
        node_range: &node_range,
        node_cone: &cones,
        vnode: &vleaves,
        smear: &vec![Default::default(); vn.len()],
    };
    let leaves = Leaves::new(&view, materials);
    let light = PointLight::new(light.0.into(), light.1.into());
    let plan = emit::plan(&view, materials, &leaves, &[light], &input);
    let aims = emit::aims(&plan, budget, 3);
    let rough = pc_tree::between::leaf_roughness(&view);
    let accel = Accel::new(&view).with_own_surfaces(&view);
    let scene = pc_caustics::links::Scene {
        view: &view,
        accel: &accel,
        rough: &rough,
    };
    let link_aims = pc_caustics::links::aims(scene, &leaves, &input, budget / 8, 3);
    let tracer = Tracer {
        view: &view,
        accel: &accel,
        materials,
        leaves: &leaves,
        max_bounces: 8,
        rough: &rough,
        seed: 3,
    };
    f(&Setup {
        view: &view,
        leaves: &leaves,
        aims: &aims,
        link_aims: &link_aims,
        tracer: &tracer,
        plan: &plan,
    })
}

/// Solid angle of a square of half-side `a` seen on its axis from distance `d`.
fn square_solid_angle(a: f64, d: f64) -> f64 {
    4.0 * (a * a / (a * a + d * d)).asin()
}

/// A 2×2 mirror (reflectance 0.9) at z = 0 under a point light at height 1, and a large
/// diffuse receiver at z = 2 facing down: the light the mirror sends up is that of the mirror
/// image of the light at z = −1.
fn mirror_scene() -> (Soa, Vec<MaterialRecord>, (Vec3, Vec3)) {
    let mut rng = Pcg64::seed_from_u64(11);
    let mut s = Soa::default();
    let h = 0.02;
    s.rect(Vec3::ZERO, Vec3::X, Vec3::Y, h, 1, &mut rng); // mirror, normal +z
    s.rect(
        Vec3::new(0.0, 0.0, 2.0),
        4.0 * Vec3::Y,
        4.0 * Vec3::X,
        0.05,
        0,
        &mut rng,
    ); // receiver, normal -z
    let light = (Vec3::new(0.0, 0.0, 1.0), Vec3::splat(10.0));
    (s, vec![diffuse(0.5), mirror(0.9)], light)
}

#[test]
fn a_flat_mirror_shows_the_mirror_image_of_the_light() {
    let (s, materials, light) = mirror_scene();
    let r = run(&s, &materials, light, 4_000_000);
    let photons = &r.traced.photons;
    assert!(photons.len() > 500_000, "{} photons stored", photons.len());
    assert!(photons
        .iter()
        .all(|p| p.bounces == 1 && (p.position[2] - 2.0).abs() < 1e-3));
    // Power through the square |x|, |y| < 1.5 of the receiver: 0.9 I Ω of that square seen from
    // the image light, 3 below the receiver.
    let power: f64 = photons
        .iter()
        .filter(|p| p.position[0].abs() < 1.5 && p.position[1].abs() < 1.5)
        .map(|p| p.power[0] as f64)
        .sum();
    let expected = 0.9 * 10.0 * square_solid_angle(1.5, 3.0);
    let rel = power / expected - 1.0;
    assert!(
        rel.abs() < 0.03,
        "power {power} W, expected {expected} W ({:+.2} %)",
        rel * 100.0
    );
    // Irradiance at points of the receiver: photon power within 0.3 over the disk's area
    // against I cos θ / r² from the image light.
    for q in [[0.0f32, 0.0], [1.0, 0.5], [-1.5, 1.2]] {
        let rad = 0.3f32;
        let e: f64 = photons
            .iter()
            .filter(|p| (p.position[0] - q[0]).hypot(p.position[1] - q[1]) < rad)
            .map(|p| p.power[0] as f64)
            .sum::<f64>()
            / (std::f64::consts::PI * (rad * rad) as f64);
        let d = Vec3::new(q[0], q[1], 2.0) - Vec3::new(0.0, 0.0, -1.0);
        let exact = 0.9 * 10.0 * (d.z / d.length()) as f64 / d.length_squared() as f64;
        let rel = e / exact - 1.0;
        assert!(
            rel.abs() < 0.03,
            "irradiance at {q:?}: {e} against {exact} ({:+.2} %)",
            rel * 100.0
        );
    }
}

#[test]
fn no_energy_is_created() {
    let (s, materials, light) = mirror_scene();
    let r = run(&s, &materials, light, 1_000_000);
    // Every photon aimed at the mirror reaches it and lands on the receiver after one bounce,
    // carrying its emitted power times the mirror's reflectance.
    let stored: f64 = r.traced.photons.iter().map(|p| p.power[1] as f64).sum();
    let aimed = r.aimed.y as f64;
    let rel = stored / (0.9 * aimed) - 1.0;
    assert!(
        rel.abs() < 1e-3,
        "stored {stored} W of 0.9 × {aimed} W ({:+.3} %)",
        rel * 100.0
    );
    assert_eq!(
        r.traced.lost + r.traced.occluded,
        0,
        "{:?}",
        (r.traced.lost, r.traced.occluded)
    );
    // The aimed power is the light's power over the mirror's solid angle (4π I · Ω / 4π).
    let omega = square_solid_angle(1.0, 1.0);
    let rel = aimed / (10.0 * omega) - 1.0;
    assert!(
        rel.abs() < 0.01,
        "aimed {aimed} W, expected {} W",
        10.0 * omega
    );
    assert!((r.emitted.x as f64 - 40.0 * std::f64::consts::PI).abs() < 1e-3);
    // Through glass nothing is created either: what lands is at most what was aimed.
    let mut g = Soa::default();
    g.sphere(Vec3::ZERO, 1.0, 20_000, 1);
    let mut rng = Pcg64::seed_from_u64(5);
    g.rect(
        Vec3::new(0.0, 0.0, -3.0),
        4.0 * Vec3::X,
        4.0 * Vec3::Y,
        0.1,
        0,
        &mut rng,
    );
    let r = run(
        &g,
        &[diffuse(0.5), glass(1.5)],
        (Vec3::new(0.0, 0.0, 10.0), Vec3::splat(100.0)),
        400_000,
    );
    let stored: f64 = r.traced.photons.iter().map(|p| p.power[0] as f64).sum();
    assert!(
        stored > 0.5 * r.aimed.x as f64 && stored <= r.aimed.x as f64 * 1.0001,
        "stored {stored} of {}",
        r.aimed.x
    );
    assert!(r.traced.photons.iter().all(|p| p.bounces >= 1));
}

/// A ball lens's principal planes both pass through its centre, so a point source at distance
/// D from the centre images at v = f D / (D − f) from it, f = nR / (2(n − 1)): the paraxial
/// focus of a distant light (D → ∞) is f. The light is at D = 20 R (v = 1.08 f), close enough
/// that the ball takes a fair share of a photon budget that fits in u32.
#[test]
fn a_glass_ball_focuses_a_distant_light_at_its_paraxial_focus() {
    let (n, radius) = (1.5f32, 1.0f32);
    let mut s = Soa::default();
    s.sphere(Vec3::ZERO, radius, 60_000, 1);
    let mut rng = Pcg64::seed_from_u64(5);
    // A screen far behind the ball; the brightest deposit on a screen at depth z is found by
    // following each stored photon's last (straight) segment back to z.
    s.rect(
        Vec3::new(0.0, 0.0, -4.0),
        3.0 * Vec3::X,
        3.0 * Vec3::Y,
        0.1,
        0,
        &mut rng,
    );
    let dist = 20.0 * radius;
    let light = (Vec3::new(0.0, 0.0, dist), Vec3::splat(1e3));
    let r = run(&s, &[diffuse(0.5), glass(n)], light, 600_000_000);
    let photons: Vec<_> = r.traced.photons.iter().filter(|p| p.bounces == 2).collect();
    assert!(photons.len() > 200_000, "{} photons", photons.len());
    // The disk must be small: with spherical aberration every ray of entry height h crosses
    // the axis at z(h) ≈ f − c h², and a disk of radius ε catches the rays crossing within
    // about ε f / h of its depth, so the brightest disk sits short of f by about c (ε f / c)^⅔.
    // An exact ball traced analytically peaks at −5.6 % with ε = 0.01 R, −2.6 % with
    // 0.003 R and −1.0 % with 0.001 R (docs/caustics.md).
    let eps = 1e-3 * radius;
    let peak = |z: f32| -> f64 {
        photons
            .iter()
            .filter_map(|p| {
                let (x, d) = (Vec3::from(p.position), Vec3::from(p.dir));
                let q = x + d * ((-z - x.z) / d.z);
                (q.x.hypot(q.y) < eps).then_some(p.power[0] as f64)
            })
            .sum()
    };
    let (best, _) = (0..=80)
        .map(|i| 1.3 + i as f32 * 0.005)
        .map(|z| (z, peak(z)))
        .fold((0.0, -1.0), |a, b| if b.1 > a.1 { b } else { a });
    let f = n * radius / (2.0 * (n - 1.0));
    let focus = f * dist / (dist - f);
    let rel = best / focus - 1.0;
    eprintln!(
        "brightest at {best} R, paraxial focus {focus} R ({:+.2} %)",
        rel * 100.0
    );
    assert!(
        rel.abs() < 0.02,
        "brightest at {best} from the centre, paraxial focus {focus} ({:+.2} %)",
        rel * 100.0
    );
}
