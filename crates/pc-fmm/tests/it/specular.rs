//! The specular links in the solve (issue 21): light between diffuse splats through mirrors and
//! glass. A furnace stays a furnace with mirror caps or a glass ball inside; a box with a mirror
//! wall is the doubled box without it (the image method).

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_caustics::emit::Leaves;
use pc_caustics::links::{self, Links};
use pc_caustics::stage::trace_all;
use pc_caustics::trace::Tracer;
use pc_fmm::solve::{self, Operator};
use pc_fmm::specular::{SpecularTransfer, WithSpecular};
use pc_fmm::{Basis, CpuFmm, CpuOperator};
use pc_tree::accel::Accel;
use rand::SeedableRng;
use rand_pcg::Pcg64;

use pc_testkit::material::{glass, mirror};

use crate::{diffuse, scene, tree_and_plan, Scene, Soa};

/// The specular links of a scene: `budget` paths, estimates of `gather` paths.
fn links_of(sc: &Scene, budget: u32, gather: u32) -> Links {
    let view = sc.octree.view();
    let v = sc.vmap();
    let leaves = Leaves::new(&view, &sc.materials);
    let rough = pc_tree::between::leaf_roughness(&view);
    let accel = Accel::new(&view).with_own_surfaces(&view);
    let scene = links::Scene {
        view: &view,
        accel: &accel,
        rough: &rough,
    };
    let aims = links::aims(scene, &leaves, &v, budget, 5);
    let tracer = Tracer {
        view: &view,
        accel: &accel,
        materials: &sc.materials,
        leaves: &leaves,
        max_bounces: 8,
        rough: &rough,
        seed: 5,
    };
    let traced = trace_all(&tracer, &aims, &|_| {});
    links::build(scene, &sc.materials, &leaves, &aims, &traced, gather, 5)
}

/// The classic solve `L = E + ρ (T + S) L` (all of L transported, emission in the source):
/// every non-specular splat emits `e[i]` and reflects `rho`.
fn solve_with(sc: &Scene, links: Option<&Links>, e: &dyn Fn(Vec3) -> f32, rho: f32) -> Vec<f32> {
    let view = sc.octree.view();
    solve_system(sc, links, &|p| {
        let n = view.splats.len();
        let mut sys = pc_fmm::System::zeros(n);
        for i in 0..n {
            if p.active[i] {
                sys.source[i] = [e(Vec3::from(view.splats[i].position)); 3];
                sys.albedo[i] = [rho; 3];
            }
        }
        sys
    })
}

/// GMRES on the system `system` builds over the scene's FMM points, with the specular links'
/// transfer when given: the red channel of the radiance.
pub(crate) fn solve_system(
    sc: &Scene,
    links: Option<&Links>,
    system: &dyn Fn(&pc_fmm::tree::Points) -> pc_fmm::System,
) -> Vec<f32> {
    solve_full(sc, links, system)
        .2
        .iter()
        .map(|l| l[0])
        .collect()
}

/// [`solve_system`], every channel, with the FMM's points and the system.
pub(crate) fn solve_full(
    sc: &Scene,
    links: Option<&Links>,
    system: &dyn Fn(&pc_fmm::tree::Points) -> pc_fmm::System,
) -> (pc_fmm::tree::Points, pc_fmm::System, Vec<[f32; 3]>) {
    let (t, p, plan) = tree_and_plan(sc, 0.5, 1e-4);
    let basis = Basis::new(4);
    let transfer = links.map(|l| SpecularTransfer::new(l.view(), &p, None).expect("links"));
    let mut op: Box<dyn Operator> = Box::new(CpuOperator {
        fmm: CpuFmm::new(&basis, &t, &p, &plan),
        times: Default::default(),
        applications: 0,
    });
    if let Some(transfer) = &transfer {
        op = Box::new(WithSpecular {
            inner: op,
            transfer,
        });
    }
    let sys = system(&p);
    let sol = solve::solve_gmres(
        op.as_mut(),
        &sys,
        &p,
        solve::Gmres {
            tolerance: 1e-5,
            max_iterations: 200,
            restart: solve::GMRES_RESTART,
            relaxed: false,
        },
        &mut |_, _| {},
    )
    .unwrap();
    assert!(sol.converged);
    drop(op);
    drop(transfer);
    (p, sys, sol.radiance)
}

/// Worst and mean relative deviation from `want` over the diffuse splats.
fn furnace_error(sc: &Scene, l: &[f32], want: f32) -> (f32, f64) {
    let view = sc.octree.view();
    let diffuse: Vec<f32> = view
        .splats
        .iter()
        .zip(l)
        .filter(|(s, _)| !class::is_specular(sc.materials[s.material as usize].class))
        .map(|(_, &x)| (x - want) / want)
        .collect();
    let worst = diffuse.iter().map(|d| d.abs()).fold(0.0, f32::max);
    let mean = diffuse.iter().map(|&d| d as f64).sum::<f64>() / diffuse.len() as f64;
    (worst, mean)
}

/// A furnace of ρ 0.5 and unit emission: the (worst, mean) deviation of its diffuse splats from
/// `E / (1 − ρ)` without and with the specular links, and the links.
fn furnace(soa: &Soa, specular: MaterialRecord) -> ((f32, f64), (f32, f64), Links) {
    let rho = 0.5;
    let sc = scene(soa, vec![diffuse(rho), specular], 16);
    let want = 1.0 / (1.0 - rho);
    let without = solve_with(&sc, None, &|_| 1.0, rho);
    let links = links_of(&sc, 400_000, 4000);
    let with = solve_with(&sc, Some(&links), &|_| 1.0, rho);
    (
        furnace_error(&sc, &without, want),
        furnace_error(&sc, &with, want),
        links,
    )
}

/// The inward unit sphere of 8,000 splats.
fn inward_sphere() -> Soa {
    let mut soa = Soa::default();
    soa.sphere(Vec3::ZERO, 1.0, 8000, 0);
    for n in soa.n.iter_mut() {
        *n = -*n;
    }
    soa
}

#[test]
fn a_furnace_with_mirror_caps_stays_a_furnace() {
    let mut soa = inward_sphere();
    for k in 0..soa.len() {
        if soa.p[k].y.abs() > 0.7 {
            soa.m[k] = 1;
        }
    }
    let ((_, m0), (w1, m1), links) = furnace(&soa, mirror(1.0));
    println!(
        "mirror caps: without links mean {m0:+.4}; with {} flux and {} gather links mean {m1:+.4} worst {w1:.4}",
        links.flux.len(),
        links.gather.len()
    );
    // The mean: the links carry what the caps reflect (within the 0.3 % that the caps' border
    // counts twice, where mirror and diffuse disks overlap); the worst splat: the estimate's
    // noise (about 1/√ of the gathered paths) on top.
    assert!(m0 < -0.05, "without the links the mirrors lose light: {m0}");
    assert!(m1.abs() < 0.005, "mean relative error {m1}");
    assert!(w1 < 0.015, "worst relative error {w1}");
}

#[test]
fn a_furnace_with_a_glass_ball_inside_stays_a_furnace() {
    let mut soa = inward_sphere();
    soa.sphere(Vec3::new(0.1, -0.2, 0.05), 0.35, 3000, 1);
    let ((w0, m0), (w1, m1), _) = furnace(&soa, glass(1.5));
    println!(
        "glass ball: without links mean {m0:+.4} worst {w0:.4}; with mean {m1:+.4} worst {w1:.4}"
    );
    assert!(w0 > 0.02, "without the links the ball casts a shadow: {w0}");
    assert!(m1.abs() < 0.005, "mean relative error {m1}");
    assert!(w1 < 0.015, "worst relative error {w1}");
}

#[test]
fn a_mirror_wall_is_the_doubled_room_without_it() {
    // The real room [-1, 1]³ with its wall x = 1 a mirror, lit by an emitting patch on its
    // ceiling; the unfolded room [-1, 3] × [-1, 1]² without the mirror, lit by the patch and its
    // mirror image. On the real half the two solves agree.
    let h = 0.05;
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    let build = |doubled: bool| {
        let mut rng = Pcg64::seed_from_u64(11);
        let mut s = Soa::default();
        let (sx, cx) = if doubled { (2.0, 1.0) } else { (1.0, 0.0) };
        let c = Vec3::new(cx, 0.0, 0.0);
        s.rect(c - y, z, x * sx, h, 0, &mut rng); // floor, normal +y
        s.rect(c + y, x * sx, z, h, 0, &mut rng); // ceiling, normal -y
        s.rect(c - z, x * sx, y, h, 0, &mut rng); // back, +z
        s.rect(c + z, y, x * sx, h, 0, &mut rng); // front, -z
        s.rect(-x, y, z, h, 0, &mut rng); // left, +x
        let far = if doubled { 3.0 } else { 1.0 };
        let m = if doubled { 0 } else { 1 };
        s.rect(x * far, z, y, h, m, &mut rng); // right, -x (the mirror in the real room)
        s
    };
    let lamp = |p: Vec3| {
        let near = |cx: f32| (p.x - cx).abs() < 0.3 && (p.z - 0.2).abs() < 0.3 && p.y > 0.99;
        if near(-0.2) || near(2.2) {
            20.0
        } else {
            0.0
        }
    };
    let rho = 0.6;
    let real = scene(&build(false), vec![diffuse(rho), mirror(1.0)], 16);
    let unfolded = scene(&build(true), vec![diffuse(rho)], 16);
    let links = links_of(&real, 400_000, 2000);
    let with = solve_with(&real, Some(&links), &lamp, rho);
    let without = solve_with(&real, None, &lamp, rho);
    let reference = solve_with(&unfolded, None, &lamp, rho);
    // Compare per wall and quadrant of the real half: the mean radiance of the splats within.
    let cells = |sc: &Scene, l: &[f32]| {
        let mut sum = std::collections::BTreeMap::<(i32, i32, i32, i32), (f64, f64)>::new();
        let view = sc.octree.view();
        for (s, &v) in view.splats.iter().zip(l) {
            let p = Vec3::from(s.position);
            let n = Vec3::from(s.normal);
            if p.x > 0.999 || class::is_specular(sc.materials[s.material as usize].class) {
                continue;
            }
            let wall = (n.x.round() as i32, n.y.round() as i32, n.z.round() as i32);
            let q = |a: f32| (a * 2.0).floor() as i32;
            let k = match wall {
                (_, 0, 0) => (wall.0, q(p.y), q(p.z), 0),
                (0, _, 0) => (wall.1 * 2, q(p.x), q(p.z), 0),
                _ => (wall.2 * 3, q(p.x), q(p.y), 0),
            };
            let e = sum.entry(k).or_default();
            e.0 += (s.radius * s.radius * v) as f64;
            e.1 += (s.radius * s.radius) as f64;
        }
        sum.into_iter()
            .map(|(k, (a, b))| (k, a / b))
            .collect::<std::collections::BTreeMap<_, _>>()
    };
    let (a, b, r) = (
        cells(&real, &with),
        cells(&real, &without),
        cells(&unfolded, &reference),
    );
    let (mut worst, mut sum, mut cells_compared) = ((0.0f64, 0.0f64), 0.0f64, 0usize);
    for (k, want) in &r {
        let Some(got) = a.get(k) else { continue };
        let err = ((got - want) / want).abs();
        let lost = ((b[k] - want) / want).abs();
        worst = (worst.0.max(err), worst.1.max(lost));
        sum += err;
        cells_compared += 1;
    }
    let mean = sum / cells_compared as f64;
    println!(
        "mirror wall, {cells_compared} cells: with links mean {mean:.4} worst {:.4}, without worst {:.4}",
        worst.0, worst.1
    );
    // The worst cells touch the mirror: the room's edge there (a corner the unfolded room does
    // not have) and the lamp's mirror image, which these links carry smoothed (pcgi traces it
    // as a caustic).
    assert!(worst.1 > 0.3, "without the links the mirror loses light");
    assert!(mean < 0.02, "mean cell error {mean:.4}");
    assert!(worst.0 < 0.05, "worst cell {:.4}", worst.0);
}

#[test]
fn a_panel_under_the_ceiling_keeps_the_mirror_light_off_the_ceiling_above_it() {
    // The room [-1, 1]³ with its wall x = 1 a mirror and a panel 1 cm thick hanging 3-4 cm
    // under the ceiling beside it (a lamp's housing). The ceiling above the panel sees the
    // mirror only through that gap, at grazing angles: the links must not smooth the open
    // ceiling's light from the mirror into it.
    let h = 0.05;
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    let mut rng = Pcg64::seed_from_u64(12);
    let mut s = Soa::default();
    s.rect(-y, z, x, h, 0, &mut rng); // floor, normal +y
    s.rect(y, x, z, h, 0, &mut rng); // ceiling, normal -y
    s.rect(-z, x, y, h, 0, &mut rng); // back, +z
    s.rect(z, y, x, h, 0, &mut rng); // front, -z
    s.rect(-x, y, z, h, 0, &mut rng); // left, +x
    s.rect(x, z, y, h, 1, &mut rng); // the mirror, -x
    let panel = Vec3::new(0.4, 0.96, 0.0);
    s.rect(panel - 0.005 * y, x * 0.3, z * 0.3, h, 0, &mut rng); // its underside, -y
    s.rect(panel + 0.005 * y, z * 0.3, x * 0.3, h, 0, &mut rng); // its top, +y
    let room = scene(&s, vec![diffuse(0.6), mirror(1.0)], 16);
    let links = links_of(&room, 400_000, 2000);
    let view = room.octree.view();
    // What the links carry to every splat when every diffuse splat sends radiance 1 (red).
    let (_, pts, _) = tree_and_plan(&room, 0.5, 1e-4);
    let transfer = SpecularTransfer::new(links.view(), &pts, None).expect("links");
    let density = transfer.density(&vec![[1.0; 3]; view.splats.len()]);
    let every: Vec<u32> = (0..view.splats.len() as u32).collect();
    let t: Vec<f32> = transfer
        .at_splats(&density, &every)
        .iter()
        .map(|e| e[0])
        .collect();
    let mean = |keep: &dyn Fn(Vec3) -> bool| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for (sp, &ti) in view.splats.iter().zip(&t) {
            if sp.position[1] > 0.99 && keep(Vec3::from(sp.position)) {
                sum += ti as f64;
                n += 1;
            }
        }
        assert!(n > 20, "{n} ceiling splats");
        sum / n as f64
    };
    // Above the panel, at least 0.1 inside its rim; the open ceiling on the far side.
    let inside = |p: Vec3| (p.x - 0.4).abs() < 0.2 && p.z.abs() < 0.2;
    let above = mean(&inside);
    let open = mean(&|p| p.x < -0.3);
    // The paths that landed there, over its area: the estimate without smoothing.
    let leaves = Leaves::new(&view, &room.materials);
    let v = links.view();
    let (mut flux, mut area) = (0.0f64, 0.0f64);
    for (b, leaf) in leaves.leaves.iter().enumerate() {
        let own = leaf.lo as usize..leaf.hi as usize;
        let at = |j: usize| Vec3::from(view.splats[j].position);
        if !own.clone().all(|j| at(j).y > 0.99 && inside(at(j))) || own.is_empty() {
            continue;
        }
        area += own.map(|j| view.splat_area[j] as f64).sum::<f64>();
        let rows = v.flux_offsets[b] as usize..v.flux_offsets[b + 1] as usize;
        flux += v.flux[rows].iter().map(|f| f.weight[0] as f64).sum::<f64>();
    }
    let landed = flux / (std::f64::consts::PI * area);
    assert!(
        open > 0.01,
        "the open ceiling gets {open} through the mirror"
    );
    assert!(landed < 0.1 * open, "{landed} landed above the panel");
    // Measured: 0.013 against 0.104 on the open ceiling and 0.0046 landed; 0.117 when the
    // smoothing took the open ceiling's bins.
    assert!(
        above < 0.2 * open,
        "above the panel {above}, the open ceiling {open}, landed there {landed}"
    );
}
