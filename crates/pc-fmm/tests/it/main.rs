//! pc-fmm tests: the FMM against the direct O(N²) sum over the same links, error falling with
//! the order, the closed-sphere furnace, CPU against GPU.

use glam::Vec3;
use pc_artifact::octree::MaterialRecord;
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::{Link, Smear, VmapView};
use pc_fmm::cpu::{direct, PhaseTimes};
use pc_fmm::plan::{self, PlanParams};
use pc_fmm::solve::{self, Operator};
use pc_fmm::{tree, Basis, CpuFmm, CpuOperator};
use pc_octree::{build, BuildInput, Octree, OctreeParams};
use pc_vmap::build::{build_links, csr, vnodes, CpuCaster};
use rand::SeedableRng;
use rand_pcg::Pcg64;

pub use pc_testkit::Soa;

mod contact;
mod gpu;
mod pool;
mod specular;

/// An octree with its V-map: the links and the per-node tables.
pub struct Scene {
    pub octree: Octree,
    pub offsets: Vec<u32>,
    pub links: Vec<Link>,
    pub materials: Vec<MaterialRecord>,
    range: Vec<[u32; 2]>,
    cone: Vec<f32>,
    vnode: Vec<u32>,
    smear: Vec<Smear>,
}

impl Scene {
    /// The V-map as pc-vmap would write it (no light lists).
    pub fn vmap(&self) -> VmapView<'_> {
        VmapView {
            link_offsets: &self.offsets,
            links: &self.links,
            light_offsets: &[0],
            light_links: &[],
            node_range: &self.range,
            node_cone: &self.cone,
            vnode: &self.vnode,
            smear: &self.smear,
        }
    }
}

pub use pc_testkit::material::{diffuse, emitter};

pub fn scene(soa: &Soa, materials: Vec<MaterialRecord>, k: u32) -> Scene {
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
        max_leaf_points: k,
        area_samples: 16,
        ..Default::default()
    };
    let octree = build(&input, &params, &mut |_| {}).unwrap();
    let view = octree.view();
    let p = VmapParams {
        theta: 0.5,
        rays: 16,
        near_rays: 256,
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
    let smear = l.smear.per_node(&vn, &l.contact);
    let (offsets, links) = csr(view.nodes.len(), l.pairs);
    Scene {
        octree,
        offsets,
        links,
        materials,
        range: vn.iter().map(|v| [v.lo, v.hi]).collect(),
        cone: vn.iter().map(|v| v.cone_cos).collect(),
        vnode: vn.iter().map(|v| v.vleaf as u32).collect(),
        smear,
    }
}

/// A closed box [-1, 1]³ seen from inside (normals inward) with a smaller box on the floor.
pub fn box_scene(h: f32) -> Soa {
    let mut rng = Pcg64::seed_from_u64(7);
    let mut s = Soa::default();
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    // Walls: normal u × v must point inward.
    s.rect(-y, z, x, h, 0, &mut rng); // floor, normal +y
    s.rect(y, x, z, h, 0, &mut rng); // ceiling, normal -y
    s.rect(-z, x, y, h, 1, &mut rng); // back, +z
    s.rect(z, y, x, h, 0, &mut rng); // front, -z
    s.rect(-x, y, z, h, 2, &mut rng); // left, +x
    s.rect(x, z, y, h, 0, &mut rng); // right, -x
    s.cube(Vec3::new(0.3, -0.7, 0.2), Vec3::splat(0.3), h, 0, &mut rng);
    s
}

/// The FMM tree, points and interaction plan of a test scene.
pub fn tree_and_plan(
    sc: &Scene,
    theta: f32,
    clamp_tol: f32,
) -> (tree::Tree, tree::Points, plan::Plan) {
    let view = sc.octree.view();
    let (t, p) = tree::build(&view, &sc.materials);
    let plan = plan::build(
        &t,
        &p,
        &sc.offsets,
        &sc.links,
        PlanParams { theta, clamp_tol },
    );
    (t, p, plan)
}

/// Relative L2 error of one FMM product against the direct sum.
fn product_error(sc: &Scene, order: usize, theta: f32, radiance: &[[f32; 3]]) -> (f64, f64) {
    let (t, p, plan) = tree_and_plan(
        sc,
        theta,
        pc_artifact::params::FmmParams::default().clamp_tol,
    );
    let basis = Basis::new(order);
    let fmm = CpuFmm::new(&basis, &t, &p, &plan);
    let mut out = vec![[0.0f32; 3]; radiance.len()];
    fmm.apply(radiance, &mut out, &mut PhaseTimes::default());
    let exact = direct(&t, &p, &plan, radiance);
    let (mut e, mut n) = (0.0f64, 0.0f64);
    for (a, b) in out.iter().zip(&exact) {
        for c in 0..3 {
            e += ((a[c] - b[c]) as f64).powi(2);
            n += (b[c] as f64).powi(2);
        }
    }
    ((e / n).sqrt(), n.sqrt())
}

pub fn varied_radiance(n: usize) -> Vec<[f32; 3]> {
    (0..n)
        .map(|i| {
            let x = i as f32 * 0.618;
            [1.0 + 0.5 * x.sin(), 0.5 + 0.4 * (1.3 * x).cos(), 0.2]
        })
        .collect()
}

#[test]
fn fmm_matches_the_direct_sum_and_improves_with_order() {
    let soa = box_scene(0.035);
    println!("{} splats", soa.len());
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let radiance = varied_radiance(soa.len());
    let mut errs = Vec::new();
    for order in [1usize, 2, 3, 4, 5, 6] {
        let (e, _) = product_error(&sc, order, 0.5, &radiance);
        println!("order {order}: relative L2 error {e:.3e}");
        errs.push(e);
    }
    let default = pc_artifact::params::FmmParams::default().order as usize;
    assert!(
        errs[default - 1] < 1e-3,
        "default order {default}: {}",
        errs[default - 1]
    );
    // The truncation error falls with the order until the accepted clamp error (clamp_tol)
    // is all that is left.
    for w in errs[..4].windows(2) {
        assert!(w[1] < w[0], "error must fall with the order: {errs:?}");
    }
    for w in errs[3..].windows(2) {
        assert!(
            w[1] < w[0] * 1.01,
            "error must not grow with the order: {errs:?}"
        );
    }
}

#[test]
fn the_plan_does_not_depend_on_the_workers() {
    // The refinement runs receivers side by side; each receiver's tasks, their order and the
    // merges of P2P tasks must come out the same on one thread as on several, so that the
    // products' sums do too.
    let soa = box_scene(0.035);
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| tree_and_plan(&sc, 0.5, 1e-4).2)
    };
    let one = on(1);
    assert!(one.counts.p2p > 0 && one.counts.m2p > 0 && one.counts.m2l > 0);
    for threads in [2, 3] {
        let many = on(threads);
        assert_eq!(many.counts, one.counts, "{threads} threads");
        assert_eq!(many.node_offsets, one.node_offsets);
        assert_eq!(many.node_tasks, one.node_tasks);
        assert_eq!(many.leaf_offsets, one.leaf_offsets);
        assert_eq!(many.leaf_tasks, one.leaf_tasks);
    }
}

#[test]
fn furnace_sphere_converges_to_e_over_one_minus_rho() {
    for &(count, rho) in &[(8000usize, 0.5f32), (8000, 0.8), (16000, 0.8)] {
        let mut soa = Soa::default();
        soa.sphere(Vec3::ZERO, 1.0, count, 0);
        for n in soa.n.iter_mut() {
            *n = -*n;
        }
        let e = 1.0f32;
        let sc = scene(&soa, vec![emitter(e, rho)], 16);
        let view = sc.octree.view();
        let (t, p, plan) = tree_and_plan(&sc, 0.5, 1e-4);
        let basis = Basis::new(4);
        let mut op = CpuOperator {
            fmm: CpuFmm::new(&basis, &t, &p, &plan),
            times: Default::default(),
            applications: 0,
        };
        // `emission` left zero: the operator transports all of L, the classic L = E + ρ T L.
        let sys = pc_fmm::System {
            source: vec![[e; 3]; soa.len()],
            emission: vec![[0.0; 3]; soa.len()],
            albedo: vec![[rho; 3]; soa.len()],
        };
        // Both solvers: Jacobi (one bounce per product) and GMRES, which needs far fewer
        // products for the same tolerance.
        let jacobi = solve::solve(&mut op, &sys, &p, 1e-5, 500, &mut |_, _| {}).unwrap();
        let gmres = solve::solve_gmres(
            &mut op,
            &sys,
            &p,
            solve::Gmres {
                tolerance: 1e-5,
                max_iterations: 500,
                restart: solve::GMRES_RESTART,
                relaxed: false,
            },
            &mut |_, _| {},
        )
        .unwrap();
        let want = e / (1.0 - rho);
        for (name, sol) in [("jacobi", &jacobi), ("gmres", &gmres)] {
            let worst = sol
                .radiance
                .iter()
                .map(|l| ((l[0] - want) / want).abs())
                .fold(0.0f32, f32::max);
            let mean = sol.radiance.iter().map(|l| l[0] as f64).sum::<f64>() / soa.len() as f64;
            let area: f64 =
                p.area.iter().map(|&a| a as f64).sum::<f64>() * (view.frame.size as f64).powi(2);
            println!(
                "furnace {count} splats, rho {rho}, {name}: {} iterations, mean {mean:.5} (want {want}), worst {worst:.4}, area {area:.4} (4π = {:.4}), device {}",
                sol.residuals.len(),
                4.0 * std::f64::consts::PI,
                op.device()
            );
            assert!(sol.converged, "{name}");
            assert!(
                worst < 0.005,
                "{count} splats, rho {rho}, {name}: worst relative error {worst}"
            );
        }
        assert!(
            gmres.residuals.len() * 3 < jacobi.residuals.len(),
            "GMRES {} products, Jacobi {}",
            gmres.residuals.len(),
            jacobi.residuals.len()
        );
    }
}

#[test]
fn relaxed_products_lower_the_order_and_keep_the_answer() {
    let sci = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.2e}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let soa = box_scene(0.035);
    let sc = scene(&soa, vec![diffuse(0.7), diffuse(0.5), diffuse(0.3)], 16);
    let view = sc.octree.view();
    let (t, p, plan) = tree_and_plan(&sc, 0.5, 1e-4);
    let order = pc_artifact::params::FmmParams::default().order as usize;
    let basis = Basis::new(order);
    let mut op = CpuOperator {
        fmm: CpuFmm::new(&basis, &t, &p, &plan),
        times: Default::default(),
        applications: 0,
    };
    let albedo: Vec<[f32; 3]> = (0..soa.len())
        .map(|i| sc.materials[view.splats[i].material as usize].color)
        .collect();
    // A lamp: the ceiling's middle emits.
    let source: Vec<[f32; 3]> = view
        .splats
        .iter()
        .map(|s| {
            let x = Vec3::from(s.position);
            let n = Vec3::from(s.normal);
            let lamp = n.y < -0.9 && x.x.abs() < 0.3 && x.z.abs() < 0.3;
            [if lamp { 10.0 } else { 0.0 }; 3]
        })
        .collect();
    let sys = pc_fmm::System {
        source: source.clone(),
        emission: vec![[0.0; 3]; soa.len()],
        albedo,
    };
    // The configured order's own product error against the direct sum.
    let (err_p, _) = product_error(&sc, order, 0.5, &varied_radiance(soa.len()));
    // The default tolerance, and one below what the order can deliver.
    for tol in [
        pc_artifact::params::FmmParams::default().tolerance as f64,
        1e-5,
    ] {
        let run = |op: &mut CpuOperator, relaxed| {
            solve::solve_gmres(
                op,
                &sys,
                &p,
                solve::Gmres {
                    tolerance: tol,
                    max_iterations: 100,
                    restart: solve::GMRES_RESTART,
                    relaxed,
                },
                &mut |_, _| {},
            )
            .unwrap()
        };
        let full = run(&mut op, false);
        let relaxed = run(&mut op, true);
        println!(
            "tolerance {tol:.0e}: full: orders {:?} residuals {}; relaxed: orders {:?} residuals {}",
            full.orders,
            sci(&full.residuals),
            relaxed.orders,
            sci(&relaxed.residuals)
        );
        assert!(full.converged && relaxed.converged);
        assert!(full.orders.iter().all(|&o| o as usize == order));
        assert_eq!(relaxed.orders[0] as usize, order);
        assert!(relaxed.orders.windows(2).all(|w| w[1] <= w[0]));
        assert!(relaxed.orders.iter().all(|&o| o >= 1));
        assert!(
            relaxed.orders.last().is_some_and(|&o| (o as usize) < order),
            "the last products are cheaper: {:?}",
            relaxed.orders
        );
        // Distance between the answers in the residual's norm (relative to the source), and
        // relative to the light the operator carried.
        let (mut d, mut ind, mut src) = (0.0f64, 0.0f64, 0.0f64);
        for (i, s) in source.iter().enumerate() {
            let a = if p.active[i] { p.area[i] as f64 } else { 0.0 };
            for (c, &s) in s.iter().enumerate() {
                d += a * ((relaxed.radiance[i][c] - full.radiance[i][c]) as f64).powi(2);
                ind += a * ((full.radiance[i][c] - s) as f64).powi(2);
                src += a * (s as f64).powi(2);
            }
        }
        let (dist, dist_carried) = ((d / src).sqrt(), (d / ind).sqrt());
        // The true residual of the relaxed answer, with a full-order product.
        let mut tl = vec![[0.0f32; 3]; soa.len()];
        op.apply(&relaxed.radiance, &mut tl).unwrap();
        let (mut r2, mut b2) = (0.0f64, 0.0f64);
        for i in 0..soa.len() {
            let a = if p.active[i] { p.area[i] as f64 } else { 0.0 };
            for c in 0..3 {
                let l = relaxed.radiance[i][c] as f64;
                let r = source[i][c] as f64 - (l - sys.albedo[i][c] as f64 * tl[i][c] as f64);
                r2 += a * r * r;
                b2 += a * (source[i][c] as f64).powi(2);
            }
        }
        let true_residual = (r2 / b2).sqrt();
        println!(
            "  order {order} product error {err_p:.2e}; relaxed vs full answer {dist:.2e} ({dist_carried:.2e} of the carried light); true residual {true_residual:.2e}"
        );
        // Relaxation assumes the tolerance is no tighter than the order: the relaxed answer is
        // as good as whichever is larger.
        let bound = tol.max(err_p);
        assert!(true_residual < bound, "true residual {true_residual:.3e}");
        assert!(dist < bound, "{dist:.3e} vs {bound:.3e}");
    }
}

#[test]
fn form_factor_rows_of_a_closed_room_sum_to_one() {
    // Inside a closed room every splat's form factors to everything it sees add up to 1
    // (Σ_j K_ij A_j = 1), whatever blocks the view: a floating cube hides parts of the walls
    // but shows its own faces instead. This holds the V-map fractions, the near-field kernel
    // and the splat areas together. The cube's convex edges are the hard part: unclipped disks
    // overhang each edge and block the neighbouring face's grazing view while facing away
    // (their light never arrives); the border clip (docs/octree.md) removes that lip.
    let h = 0.035f32;
    let mut rng = Pcg64::seed_from_u64(7);
    let mut s = Soa::default();
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    s.rect(-y, z, x, h, 0, &mut rng);
    s.rect(y, x, z, h, 0, &mut rng);
    s.rect(-z, x, y, h, 0, &mut rng);
    s.rect(z, y, x, h, 0, &mut rng);
    s.rect(-x, y, z, h, 0, &mut rng);
    s.rect(x, z, y, h, 0, &mut rng);
    let (centre, half) = (Vec3::new(0.3, -0.3, 0.2), 0.3f32);
    s.cube(centre, Vec3::splat(half), h, 0, &mut rng);
    let sc = scene(&s, vec![diffuse(0.7)], 16);
    let (t, p, plan) = tree_and_plan(&sc, 0.5, 1e-4);
    let rows = direct(&t, &p, &plan, &vec![[1.0f32; 3]; s.len()]);
    let (mut all, mut cube, mut edge) = ((0.0f64, 0usize), (0.0f64, 0usize), (0.0f64, 0usize));
    for (sp, row) in sc.octree.splats.iter().zip(&rows) {
        let r = row[0] as f64;
        all = (all.0 + r, all.1 + 1);
        let q = Vec3::from(sp.position) - centre;
        if q.abs().max_element() <= half + 1e-3 {
            cube = (cube.0 + r, cube.1 + 1);
            // Distance to the face's nearest edge.
            let n = Vec3::from(sp.normal);
            let d = (0..3)
                .filter(|&a| n[a].abs() < 0.5)
                .map(|a| half - q[a].abs())
                .fold(f32::MAX, f32::min);
            if d < h {
                edge = (edge.0 + r, edge.1 + 1);
            }
        }
    }
    let mean = |(s, n): (f64, usize)| s / n as f64;
    println!(
        "row sums: all {:.4}, cube {:.4}, cube edge rows {:.4} ({} splats)",
        mean(all),
        mean(cube),
        mean(edge),
        edge.1
    );
    assert!((mean(all) - 1.0).abs() < 0.005, "all: {}", mean(all));
    assert!((mean(cube) - 1.0).abs() < 0.01, "cube: {}", mean(cube));
    assert!(
        (mean(edge) - 1.0).abs() < 0.015,
        "cube edges: {}",
        mean(edge)
    );
}

/// Form factor from a differential area to a parallel rectangle `[x0, x1] × [z0, z1]` at
/// height `c` above it (the receiver at the origin, facing it): the corner formula summed with
/// signs over the four quadrants.
fn parallel_rect_form_factor(x0: f64, x1: f64, z0: f64, z1: f64, c: f64) -> f64 {
    let corner = |a: f64, b: f64| {
        let (sa, sb) = (a.signum(), b.signum());
        let (a, b) = (a.abs() / c, b.abs() / c);
        let (ra, rb) = ((1.0 + a * a).sqrt(), (1.0 + b * b).sqrt());
        sa * sb * (a / ra * (b / ra).atan() + b / rb * (a / rb).atan())
            / (2.0 * std::f64::consts::PI)
    };
    corner(x1, z1) - corner(x0, z1) - corner(x1, z0) + corner(x0, z0)
}

/// The emitters' direct light against the analytic form factor of a square light, and the
/// probed estimate against casting every shadow ray, on a floor under a square light with a
/// plate casting a penumbra.
#[test]
fn emitter_direct_light_is_analytic_where_open_and_probing_keeps_the_shadows() {
    let mut rng = Pcg64::seed_from_u64(3);
    let mut soa = Soa::default();
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    soa.rect(Vec3::ZERO, z, x, 0.03, 0, &mut rng); // floor [-1, 1]², normal +y
    soa.rect(y, x * 0.25, z * 0.25, 0.02, 1, &mut rng); // light at y = 1, normal −y
    soa.rect(
        Vec3::new(0.5, 0.5, 0.0),
        z * 0.15,
        x * 0.15,
        0.02,
        0,
        &mut rng,
    ); // plate
    let (le, rho) = (2.0f32, 0.5f32);
    let sc = scene(&soa, vec![diffuse(rho), emitter(le, 0.0)], 16);
    let view = sc.octree.view();
    let (_, pts) = tree::build(&view, &sc.materials);
    let tester = pc_tree::caster::CpuCaster::new(&view);
    let base = || {
        let mut sys = pc_fmm::System::zeros(view.splats.len());
        for (i, s) in view.splats.iter().enumerate() {
            if s.material == 1 {
                sys.emission[i] = [le; 3];
            } else {
                sys.albedo[i] = [rho; 3];
            }
        }
        sys
    };
    let direct = |probes: u32, shafts: bool| {
        let mut sys = base();
        let how = pc_fmm::emitter::EmitterSampling {
            samples: 64,
            probes,
            self_hit: 0.5,
            shafts,
        };
        let r = pc_fmm::emitter::emitter_direct(&view, &pts, &mut sys, how, &tester).unwrap();
        (sys.source, r)
    };
    let (every, all) = direct(0, false);
    let (probed, with_probes) = direct(16, false);
    let (culled, with_shafts) = direct(0, true);
    let (both, with_both) = direct(16, true);
    let (samples, rays_all, rays_probed) = (all.samples, all.cast, with_probes.cast);
    assert_eq!(rays_all, samples, "probes 0 casts every sample");
    assert_eq!(with_probes.samples, samples);
    // Shaft culling is exact: the same light on every splat, bit for bit, with rays cast only
    // where a leaf's shaft holds too many disks (here none: the plate is small).
    assert_eq!(culled, every, "shaft culling changed the direct light");
    assert_eq!(with_shafts.settled + with_shafts.cast, samples);
    assert!(with_shafts.settled > samples / 2, "{with_shafts:?}");
    println!(
        "shaft culling settled {} of {samples} samples; with probes too: {with_both:?}",
        with_shafts.settled
    );
    let pen = |v: &[[f32; 3]]| -> f64 {
        view.splats
            .iter()
            .zip(v)
            .filter(|(s, _)| s.material == 0 && s.position[1].abs() < 1e-3)
            .map(|(_, x)| x[0] as f64)
            .sum()
    };
    assert!((pen(&both) - pen(&every)).abs() < 1e-3 * pen(&every));
    // Floor splats: open ones (x < 0.3, outside the plate's penumbra) against the analytic
    // value ρ Lₑ F; the penumbra (0.45 < x < 1.55 under the plate's z-extent) by both methods.
    let (mut err, mut open_n) = (0.0f64, 0);
    let (mut pen_all, mut pen_probed, mut pen_n) = (0.0f64, 0.0f64, 0);
    for (i, s) in view.splats.iter().enumerate() {
        let p = Vec3::from(s.position);
        if s.material != 0 || p.y.abs() > 1e-3 {
            continue;
        }
        if p.x < 0.3 && p.x.abs() < 0.9 && p.z.abs() < 0.9 {
            let f = parallel_rect_form_factor(
                -0.25 - p.x as f64,
                0.25 - p.x as f64,
                -0.25 - p.z as f64,
                0.25 - p.z as f64,
                1.0,
            );
            let want = (rho * le) as f64 * f;
            // Open: probing casts no extra ray and must agree exactly with every ray.
            assert_eq!(probed[i], every[i], "open splat {i} at {p}");
            err += ((every[i][0] as f64 - want) / want).abs();
            open_n += 1;
        } else if p.x > 0.5 && p.x < 1.0 && p.z.abs() < 0.3 {
            pen_all += every[i][0] as f64;
            pen_probed += probed[i][0] as f64;
            pen_n += 1;
        }
    }
    let mean_err = err / open_n as f64;
    let pen_diff = (pen_probed - pen_all).abs() / pen_all;
    let share = rays_probed as f64 / rays_all as f64;
    println!(
        "open floor: {open_n} splats, mean |error| against the analytic form factor {:.3} %; \
         penumbra: {pen_n} splats, probed vs every ray {:.3} %; probing cast {:.1} % of the rays",
        100.0 * mean_err,
        100.0 * pen_diff,
        100.0 * share
    );
    assert!(open_n > 1000 && pen_n > 100);
    assert!(mean_err < 0.01, "mean error {mean_err}");
    assert!(pen_diff < 0.01, "penumbra differs by {pen_diff}");
    assert!(share < 0.6, "probing cast {share} of the rays");
}

mod cluster;
