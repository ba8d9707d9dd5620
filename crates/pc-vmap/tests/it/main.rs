//! V-map tests: occlusion by a plate, visible form-factor sums against brute force, light lists
//! and shadows, CPU against GPU casting, links reused when only the lights move.

use glam::Vec3;
use pc_artifact::octree::class;
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::Link;
use pc_octree::{build, BuildInput, Octree, OctreeParams};
use pc_tree::{OctreeView, Ray, TraversalStats};
use pc_vmap::build::{build_links, csr, light_lists, vnodes, Caster, CpuCaster, VNode};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

mod rough;
mod stage;

pub use pc_testkit::Soa;

/// Building an octree (one diffuse material) straight from a test scene.
pub trait BuildSoa {
    fn build(&self, k: u32) -> Octree;
}

impl BuildSoa for Soa {
    fn build(&self, k: u32) -> Octree {
        let albedo = self.ones();
        let input = BuildInput {
            positions: &self.p,
            normals: &self.n,
            radii: &self.r,
            albedo: &albedo,
            material: &self.m,
            material_class: &[class::DIFFUSE],
        };
        let params = OctreeParams {
            max_leaf_points: k,
            area_samples: 8,
            ..Default::default()
        };
        build(&input, &params, &mut |_| {}).unwrap()
    }
}

pub fn params(rays: u32, leaf: u32) -> VmapParams {
    // 0 (the default here) refines every partial pair; VMAP_REFINE=0.001 tries the stage default.
    let refine_form_factor = std::env::var("VMAP_REFINE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0);
    VmapParams {
        theta: 0.5,
        rays,
        near_rays: 1024,
        leaf_splats: leaf,
        self_hit: 0.5,
        refine_form_factor,
        heavy_rays: 0,
        heavy_form_factor: 0.0,
        seed: 1,
        ..Default::default()
    }
}

/// Exact visibility of the segment between two splat centres.
fn visible(view: &OctreeView, a: usize, b: usize, st: &mut TraversalStats) -> bool {
    let (sa, sb) = (&view.splats[a], &view.splats[b]);
    let (pa, pb) = (Vec3::from(sa.position), Vec3::from(sb.position));
    let d = pb - pa;
    let len = d.length();
    let ray = Ray {
        origin: pa,
        dir: d / len,
        t_min: 0.5 * sa.radius,
        t_max: len - 0.5 * sb.radius,
    };
    ray.t_max <= ray.t_min || !pc_tree::occluded(view, &ray, st)
}

/// The point-to-point form-factor kernel times the source area: cos θi cos θj / (π r²) A_j,
/// zero unless the two front sides face each other.
fn kernel(view: &OctreeView, i: usize, j: usize) -> f64 {
    let (si, sj) = (&view.splats[i], &view.splats[j]);
    let d = Vec3::from(sj.position) - Vec3::from(si.position);
    let r2 = d.length_squared() as f64;
    let dir = d.normalize();
    let ci = Vec3::from(si.normal).dot(dir) as f64;
    let cj = -Vec3::from(sj.normal).dot(dir) as f64;
    if ci <= 0.0 || cj <= 0.0 || r2 <= 0.0 {
        return 0.0;
    }
    ci * cj / (std::f64::consts::PI * r2) * view.splat_area[j] as f64
}

/// Per splat, the visible form-factor sum Σ_j K(i,j) V(i,j): exact, and as the V-map links
/// give it (each link's fraction applied to every splat pair under the two nodes).
fn form_factor_sums(
    view: &OctreeView,
    vn: &[VNode],
    offsets: &[u32],
    links: &[Link],
) -> (Vec<f64>, Vec<f64>) {
    use rayon::prelude::*;
    let n = view.splats.len();
    let exact: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut st = TraversalStats::default();
            (0..n)
                .filter(|&j| j != i)
                .map(|j| {
                    let k = kernel(view, i, j);
                    if k > 0.0 && visible(view, i, j, &mut st) {
                        k
                    } else {
                        0.0
                    }
                })
                .sum()
        })
        .collect();
    let mut vmap = vec![0.0f64; n];
    for x in 0..vn.len() {
        let vx = &vn[x];
        for l in &links[offsets[x] as usize..offsets[x + 1] as usize] {
            let vy = &vn[l.slot() as usize];
            for i in vx.lo..vx.hi {
                let s: f64 = (vy.lo..vy.hi)
                    .filter(|&j| j != i)
                    .map(|j| kernel(view, i as usize, j as usize))
                    .sum();
                vmap[i as usize] += s * l.fraction as f64;
            }
        }
    }
    (exact, vmap)
}

/// A small open room with a box on its floor: occlusion everywhere.
fn room(h: f32) -> Soa {
    let mut rng = Pcg64::seed_from_u64(5);
    let mut s = Soa::default();
    s.rect(Vec3::new(0.0, -1.0, 0.0), Vec3::X, -Vec3::Z, h, 0, &mut rng); // floor, up
    s.rect(Vec3::new(0.0, 0.0, -1.0), Vec3::X, Vec3::Y, h, 0, &mut rng); // back, +z
    s.rect(Vec3::new(-1.0, 0.0, 0.0), Vec3::Z, Vec3::Y, h, 0, &mut rng); // left, +x
    s.cube(
        Vec3::new(0.1, -0.7, -0.2),
        Vec3::new(0.3, 0.3, 0.3),
        h,
        0,
        &mut rng,
    );
    s
}

#[test]
fn visible_form_factor_sums_per_leaf_match_brute_force() {
    let s = room(0.085);
    assert!(s.p.len() > 1000 && s.p.len() < 3000, "{} splats", s.p.len());
    let o = s.build(8);
    let view = o.view();
    let rays: u32 = std::env::var("VMAP_RAYS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(32);
    let leaf: u32 = std::env::var("VMAP_LEAF")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(8);
    let p = params(rays, leaf);
    let vn = vnodes(&view, p.leaf_splats);
    let caster = CpuCaster::new(&view);
    let l = build_links(&view, &vn, &p, &caster, &mut |_, _| {}).unwrap();
    let (offsets, links) = csr(view.nodes.len(), l.pairs);
    let (exact, vmap) = form_factor_sums(&view, &vn, &offsets, &links);
    // Per octree leaf: Σ over its splats of area × form-factor sum.
    let mut worst = 0.0f64;
    let mut leaves = 0;
    for (slot, &w) in view.nodes.iter().enumerate() {
        if !pc_artifact::octree::node::is_leaf(w) {
            continue;
        }
        let (r, _) = view.leaf(w);
        if r.end - r.start < 4 {
            continue;
        }
        let sum = |v: &[f64]| {
            r.clone()
                .map(|i| v[i as usize] * view.splat_area[i as usize] as f64)
                .sum::<f64>()
        };
        let (e, m) = (sum(&exact), sum(&vmap));
        // Leaves hidden under the box (a mean form-factor sum under 1e-3: the floor beneath it
        // and the box's bottom face, coplanar with the floor) exchange next to nothing; their
        // relative error says nothing.
        if e < 1e-3 * sum(&vec![1.0; view.splats.len()]) {
            continue;
        }
        let rel = (m - e).abs() / e;
        if rel > 0.05 && std::env::var("VMAP_DEBUG").is_ok() {
            let c = Vec3::from(view.splats[r.start as usize].position);
            let nrm = Vec3::from(view.splats[r.start as usize].normal);
            eprintln!(
                "leaf {slot} at {c} n {nrm} ({} splats): exact {e:.5}, vmap {m:.5}, rel {rel:.3}",
                r.end - r.start
            );
        }
        worst = worst.max(rel);
        leaves += 1;
        let _ = slot;
    }
    let total_e: f64 = exact
        .iter()
        .zip(view.splat_area)
        .map(|(f, a)| f * *a as f64)
        .sum();
    let total_m: f64 = vmap
        .iter()
        .zip(view.splat_area)
        .map(|(f, a)| f * *a as f64)
        .sum();
    eprintln!("{} splats, {leaves} leaves, {} far + {} near links, {} rays; worst leaf error {:.4}, total {:.5} vs {:.5}", view.splats.len(), l.far, l.near, l.rays, worst, total_m, total_e);
    assert!(leaves > 50);
    assert!(
        (total_m - total_e).abs() / total_e < 0.01,
        "total {total_m} vs exact {total_e}"
    );
    assert!(worst < 0.02, "worst per-leaf relative error {worst}");
}

#[test]
fn no_link_crosses_an_occluding_plate() {
    // Two walls facing each other with a plate between them covering their middle.
    let mut rng = Pcg64::seed_from_u64(6);
    let mut s = Soa::default();
    s.rect(Vec3::ZERO, Vec3::X, Vec3::Y, 0.05, 0, &mut rng); // wall 1 at z=0, facing +z
    s.rect(
        Vec3::new(0.0, 0.0, 2.0),
        Vec3::Y,
        Vec3::X,
        0.05,
        0,
        &mut rng,
    ); // wall 2 at z=2, facing -z
    let wall = s.p.len();
    s.rect(
        Vec3::new(0.0, 0.0, 0.98),
        Vec3::Y * 0.5,
        Vec3::X * 0.5,
        0.05,
        0,
        &mut rng,
    ); // plate, facing -z
    s.rect(
        Vec3::new(0.0, 0.0, 1.02),
        Vec3::X * 0.5,
        Vec3::Y * 0.5,
        0.05,
        0,
        &mut rng,
    ); // plate, facing +z
    let o = s.build(8);
    let view = o.view();
    let p = params(16, 16);
    let vn = vnodes(&view, p.leaf_splats);
    let l = build_links(&view, &vn, &p, &CpuCaster::new(&view), &mut |_, _| {}).unwrap();
    let src: Vec<u32> = view.splats.iter().map(|x| x.source).collect();
    let on_wall = |v: &VNode, z: f32| {
        (v.lo..v.hi).all(|i| {
            (src[i as usize] as usize) < wall
                && (view.splats[i as usize].position[2] - z).abs() < 1e-3
        })
    };
    let (mut wall_links, mut crossing, mut beside) = (0, 0, 0);
    for &(x, link) in &l.pairs {
        let (vx, vy) = (&vn[x as usize], &vn[link.slot() as usize]);
        if !(on_wall(vx, 0.0) && on_wall(vy, 2.0)) {
            continue;
        }
        wall_links += 1;
        // Every segment between the two nodes' bounding spheres meets the plane z = 1 within
        // (R_x + R_y) / 2 of where the centre segment does: if that whole disc lies inside the
        // plate (half-width 0.5), every path between the nodes crosses the plate.
        let mid = (vx.center + vy.center) * 0.5;
        let reach = 0.5 * (vx.radius + vy.radius) + 0.05;
        if mid.x.abs() + reach < 0.5 && mid.y.abs() + reach < 0.5 {
            crossing += 1;
        }
        if mid.x.abs() > 0.7 || mid.y.abs() > 0.7 {
            beside += 1;
        }
    }
    assert!(wall_links > 20, "only {wall_links} wall-to-wall links");
    assert_eq!(
        crossing, 0,
        "{crossing} of {wall_links} wall-to-wall links cross the plate"
    );
    assert!(beside > 10, "only {beside} links pass beside the plate");
}

/// The light list of one light (16 rays per V-map leaf of 16 splats), as the fraction it
/// implies for each splat (entries are disjoint subtrees).
fn lit_fractions(view: &OctreeView, light: Vec3) -> Vec<f32> {
    let p = params(16, 16);
    let vn = vnodes(view, p.leaf_splats);
    let lists = light_lists(view, &vn, &[light], &p, &CpuCaster::new(view)).unwrap();
    let mut implied = vec![0.0f32; view.splats.len()];
    for l in &lists[0] {
        let v = &vn[l.slot() as usize];
        for i in v.lo..v.hi {
            implied[i as usize] = l.fraction;
        }
    }
    implied
}

#[test]
fn a_point_light_above_a_box_does_not_see_its_shadow() {
    let mut rng = Pcg64::seed_from_u64(7);
    let mut s = Soa::default();
    s.rect(Vec3::ZERO, Vec3::X * 1.5, -Vec3::Z * 1.5, 0.04, 0, &mut rng); // floor y=0, up
    let floor = s.p.len();
    let (lo, hi) = (Vec3::new(-0.3, 0.0, -0.3), Vec3::new(0.3, 0.6, 0.3));
    s.cube(
        (lo + hi) * 0.5 + Vec3::Y * 0.002,
        (hi - lo) * 0.5,
        0.04,
        0,
        &mut rng,
    );
    let o = s.build(8);
    let view = o.view();
    let light = Vec3::new(0.2, 2.0, 0.1);
    let implied = lit_fractions(&view, light);
    // Analytic shadow of the box on the floor, with a margin of two splat radii.
    let shadowed = |p: Vec3, margin: f32| {
        let d = light - p;
        let inv = d.recip();
        let a = (lo - Vec3::splat(margin) - p) * inv;
        let b = (hi + Vec3::splat(margin) - p) * inv;
        let t0 = a.min(b).max_element();
        let t1 = a.max(b).min_element();
        t0 <= t1 && t1 > 0.0 && t0 < 1.0
    };
    let (mut dark, mut lit) = (0, 0);
    for (i, sp) in view.splats.iter().enumerate() {
        if sp.source as usize >= floor {
            continue;
        }
        let pos = Vec3::from(sp.position);
        if shadowed(pos, -0.08) {
            dark += 1;
            assert_eq!(
                implied[i], 0.0,
                "floor splat at {pos} in the box's shadow is in the light list"
            );
        } else if !shadowed(pos, 0.08) {
            lit += 1;
            assert!(
                implied[i] > 0.0,
                "lit floor splat at {pos} is missing from the light list"
            );
        }
    }
    assert!(dark > 50 && lit > 1000, "{dark} shadowed, {lit} lit");
}

#[test]
fn gpu_casting_matches_the_cpu() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let s = room(0.06);
    let o = s.build(8);
    let view = o.view();
    let mut rng = Pcg64::seed_from_u64(8);
    let rays: Vec<Ray> = (0..20_000)
        .map(|_| {
            let a = rng.random_range(0..view.splats.len());
            let b = rng.random_range(0..view.splats.len());
            let (pa, pb) = (
                Vec3::from(view.splats[a].position),
                Vec3::from(view.splats[b].position),
            );
            let d = pb - pa;
            let len = d.length().max(1e-3);
            Ray {
                origin: pa,
                dir: d / len,
                t_min: 0.03,
                t_max: (len - 0.03).max(0.031),
            }
        })
        .collect();
    let cpu = CpuCaster::new(&view).visible(&rays).unwrap();
    let caster = pc_tree::gpu::RayCaster::new(&ctx, &view).unwrap();
    let gpu = pc_vmap::build::GpuCaster { ctx, caster }
        .visible(&rays)
        .unwrap();
    let same = cpu.iter().zip(&gpu).filter(|(a, b)| a == b).count();
    assert!(
        same as f64 >= 0.999 * rays.len() as f64,
        "{same} of {} agree",
        rays.len()
    );
    assert!(
        cpu.iter().filter(|&&v| v).count() > 1000 && cpu.iter().filter(|&&v| !v).count() > 1000
    );
}

/// A closed room lit only through a small skylight by a light far above it: the patch of
/// floor under the opening is in the light list, though the light's rays miss it from almost
/// every sample of a large node (before, a node whose samples all missed was dropped whole,
/// and such a sun lit nothing).
#[test]
fn a_distant_light_through_a_skylight_lights_the_floor_below() {
    let mut rng = Pcg64::seed_from_u64(11);
    let mut s = Soa::default();
    let h = 0.04;
    s.rect(Vec3::ZERO, Vec3::X, -Vec3::Z, h, 0, &mut rng); // floor y = 0, up
    let floor = s.p.len();
    let (c, w) = (0.15f32, 0.425f32); // hole half-width, strip half-width
    for (at, u, v) in [
        (Vec3::new(0.0, 2.0, 1.0 - w), Vec3::X, Vec3::Z * w),
        (Vec3::new(0.0, 2.0, -1.0 + w), Vec3::X, Vec3::Z * w),
        (Vec3::new(1.0 - w, 2.0, 0.0), Vec3::X * w, Vec3::Z * c),
        (Vec3::new(-1.0 + w, 2.0, 0.0), Vec3::X * w, Vec3::Z * c),
    ] {
        s.rect(at, u, v, h, 0, &mut rng); // ceiling around the hole, facing down
    }
    s.rect(Vec3::new(-1.0, 1.0, 0.0), Vec3::Y, Vec3::Z, h, 0, &mut rng);
    s.rect(Vec3::new(1.0, 1.0, 0.0), Vec3::Z, Vec3::Y, h, 0, &mut rng);
    s.rect(Vec3::new(0.0, 1.0, -1.0), Vec3::X, Vec3::Y, h, 0, &mut rng);
    s.rect(Vec3::new(0.0, 1.0, 1.0), Vec3::Y, Vec3::X, h, 0, &mut rng);
    let o = s.build(8);
    let view = o.view();
    let implied = lit_fractions(&view, Vec3::new(0.0, 60.0, 0.0));
    let (mut under, mut beside) = (0, 0);
    for (i, sp) in view.splats.iter().enumerate() {
        let pos = Vec3::from(sp.position);
        if (sp.source as usize) < floor && pos.x.abs() < 0.08 && pos.z.abs() < 0.08 {
            under += 1;
            assert!(
                implied[i] > 0.0,
                "floor splat at {pos} under the skylight is unlit"
            );
        }
        if (sp.source as usize) < floor && (pos.x.abs() > 0.4 || pos.z.abs() > 0.4) {
            beside += 1;
            assert_eq!(
                implied[i], 0.0,
                "floor splat at {pos} away from the opening is lit"
            );
        }
    }
    assert!(
        under > 10 && beside > 1000,
        "{under} under, {beside} beside"
    );
}

/// pc-vmap's `smear` (crates/pc-vmap/src/smear.rs) against brute force on the room with a box,
/// at V-map leaves of 64 splats: per V-map leaf, what the links' shared fractions misstate of
/// its area-weighted visible form-factor sum, `Σ A_i (exact_i − links_i)`, and what they give
/// (`Σ A_i links_i`), from the rays the links were decided on alone.
#[test]
fn the_smear_estimates_what_shared_fractions_misstate() {
    let s = room(0.085);
    let o = s.build(8);
    let view = o.view();
    let p = VmapParams {
        refine_form_factor: 1e-3,
        ..params(16, 64)
    };
    let vn = vnodes(&view, p.leaf_splats);
    let caster = CpuCaster::new(&view);
    let l = build_links(&view, &vn, &p, &caster, &mut |_, _| {}).unwrap();
    let smear = l.smear.per_node(&vn, &l.contact);
    let (offsets, links) = csr(view.nodes.len(), l.pairs);
    let (exact, vmap) = form_factor_sums(&view, &vn, &offsets, &links);
    let area = |i: u32| view.splat_area[i as usize] as f64;
    let leaves = top_vleaves(&view, &vn);
    let (mut z_big, mut flagged, mut caught) = (0, 0, 0);
    let (mut err_sum, mut truth_sum, mut given_sum, mut transfer_sum) = (0.0, 0.0, 0.0, 0.0);
    for &a in &leaves {
        let v = &vn[a as usize];
        let truth: f64 = (v.lo..v.hi)
            .map(|i| area(i) * (exact[i as usize] - vmap[i as usize]))
            .sum();
        let given: f64 = (v.lo..v.hi).map(|i| area(i) * vmap[i as usize]).sum();
        let m = smear[a as usize];
        let sd = (m.variance as f64).sqrt();
        let z = (m.error as f64 - truth) / (sd + 1e-3 * given.abs() + 1e-12);
        z_big += (z.abs() > 4.0) as usize;
        err_sum += m.error as f64;
        truth_sum += truth;
        given_sum += given;
        transfer_sum += m.transfer as f64;
        if truth.abs() > 0.05 * given {
            flagged += 1;
            caught += m.exceeds(0.02, 3.0) as usize;
        }
    }
    println!(
        "{} V-map leaves: {z_big} estimates more than 4 deviations off; misstated by over 5 %: {flagged}, of them {caught} significant; \
         error {err_sum:.4e} (truth {truth_sum:.4e}), transfer {transfer_sum:.4e} (links give {given_sum:.4e})",
        leaves.len()
    );
    assert!(leaves.len() > 20);
    // What the links give: the smear's transfer is an estimate of the same sum.
    assert!(
        (transfer_sum / given_sum - 1.0).abs() < 0.05,
        "{transfer_sum} vs {given_sum}"
    );
    assert!(
        z_big * 10 <= leaves.len(),
        "{z_big} of {} leaves off",
        leaves.len()
    );
    let _ = (flagged, caught);
}

/// Contact probes: the floor's V-map leaves under a ball resting on it find it close over them;
/// the leaves far from it find nothing.
#[test]
fn contact_probes_find_a_ball_resting_on_the_floor() {
    let mut rng = Pcg64::seed_from_u64(3);
    let mut s = Soa::default();
    s.rect(Vec3::ZERO, Vec3::X * 2.0, Vec3::Z * -2.0, 0.04, 0, &mut rng); // floor, normal +y
    s.sphere(Vec3::Y * 0.3, 0.3, 3000, 0);
    let o = s.build(8);
    let view = o.view();
    let p = params(16, 64);
    let vn = vnodes(&view, p.leaf_splats);
    let caster = CpuCaster::new(&view);
    let l = build_links(&view, &vn, &p, &caster, &mut |_, _| {}).unwrap();
    let (mut near, mut far) = (Vec::new(), Vec::new());
    for slot in top_vleaves(&view, &vn) {
        let v = &vn[slot as usize];
        let slot = slot as usize;
        let on_floor = (v.lo..v.hi)
            .filter(|&i| view.splats[i as usize].position[1] < 0.01)
            .count();
        let floor = on_floor * 2 > v.count() as usize;
        let r = Vec3::new(v.center.x, 0.0, v.center.z).length();
        match (floor, r) {
            (true, r) if r < 0.2 => near.push(l.contact[slot]),
            (true, r) if r > 0.8 && r < 1.6 => far.push(l.contact[slot]),
            _ => {}
        }
    }
    println!(
        "contact shares of the floor's V-map leaves within 0.2 of the contact {near:?}; of {} far ones: max {:?}",
        far.len(),
        far.iter().copied().reduce(f32::max)
    );
    assert!(
        !near.is_empty() && near.iter().all(|&c| c >= 0.5),
        "{near:?}"
    );
    assert!(far.len() > 10 && far.iter().all(|&c| c == 0.0));
}

/// The topmost V-map leaves (no link goes below them).
fn top_vleaves(view: &OctreeView, vn: &[VNode]) -> Vec<u32> {
    let mut leaves = Vec::new();
    let mut stack = vec![0u32];
    while let Some(a) = stack.pop() {
        match vn[a as usize].vleaf {
            true => leaves.push(a),
            false => stack.extend(pc_vmap::build::children(view, vn, a)),
        }
    }
    leaves
}

/// Shaft culling (docs/vmap.md, "Empty shafts") settles a far pair without rays only where
/// casting them finds every one visible: in a room with a box and a plate hung in it, every
/// pair of V-map leaves whose shaft it calls empty has all its rays seen by the walk; and the
/// test has teeth: it settles many pairs, and some pairs with blocked rays are not settled.
#[test]
fn an_empty_shaft_settles_only_pairs_whose_rays_all_pass() {
    let mut rng = Pcg64::seed_from_u64(12);
    let mut s = room(0.085);
    let c = Vec3::new(0.5, -0.4, -0.5);
    s.rect(c, Vec3::X * 0.25, Vec3::Z * 0.25, 0.04, 0, &mut rng); // a plate, facing down
    let up = c + Vec3::Y * 0.02;
    s.rect(up, Vec3::Z * 0.25, Vec3::X * 0.25, 0.04, 0, &mut rng); // its top, facing up
    let o = s.build(8);
    let view = o.view();
    let p = params(16, 16);
    let vn = vnodes(&view, p.leaf_splats);
    let shafts = pc_tree::shaft::DiskBoxes::new(&view);
    let leaves: Vec<u32> = (0..vn.len() as u32)
        .filter(|&i| vn[i as usize].vleaf && vn[i as usize].count() > 0)
        .collect();
    let caster = CpuCaster::new(&view);
    let (mut open, mut tried, mut blocked_closed) = (0, 0, 0);
    for (k, &a) in leaves.iter().enumerate() {
        for &b in leaves.iter().skip(k + 1).step_by(3) {
            let (settled, rays) = pc_vmap::build::far_pair_shaft(&view, &vn, &shafts, &p, (a, b));
            if rays.is_empty() {
                continue;
            }
            tried += 1;
            let seen = caster.visible_between(&rays).unwrap();
            if settled {
                open += 1;
                assert!(
                    seen.iter().all(|&v| v),
                    "pair ({a}, {b}): its shaft is empty, yet a ray is blocked"
                );
            } else if seen.iter().any(|&v| !v) {
                blocked_closed += 1;
            }
        }
    }
    eprintln!("{open} of {tried} facing pairs settled by their shafts, {blocked_closed} with blocked rays");
    assert!(
        open * 5 > tried,
        "only {open} of {tried} facing pairs settled by their shafts"
    );
    assert!(
        blocked_closed > 0,
        "no pair with a blocked ray among {tried}"
    );
}
