//! Integration tests of the octree build: structure invariants checked by brute force, point
//! location CPU vs brute force vs GPU, WGSL layouts, areas, normal fields, artifacts.

use glam::Vec3;
use pc_artifact::octree::{class, clip_lines, node, Frame, NodeInfo, Splat};
use pc_octree::{build, field_normal, BuildError, BuildInput, Octree, OctreeParams};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

mod artifact;
mod ray;

pub use pc_testkit::Soa;

/// Building an octree straight from a test scene.
pub trait BuildSoa {
    fn build(&self, classes: &[u32], params: OctreeParams) -> Result<Octree, BuildError>;
}

impl BuildSoa for Soa {
    fn build(&self, classes: &[u32], params: OctreeParams) -> Result<Octree, BuildError> {
        let albedo = self.ones();
        let input = BuildInput {
            positions: &self.p,
            normals: &self.n,
            radii: &self.r,
            albedo: &albedo,
            material: &self.m,
            material_class: classes,
        };
        build(&input, &params, &mut |_| {})
    }
}

/// Diffuse box room (5 planes) with a mirror sphere and a glass sphere: classes 0, 2, 3.
pub fn mixed_scene(h: f32) -> (Soa, Vec<u32>) {
    let mut rng = Pcg64::seed_from_u64(7);
    let mut s = Soa::default();
    s.rect(Vec3::new(0.0, -1.0, 0.0), Vec3::X, -Vec3::Z, h, 0, &mut rng);
    s.rect(Vec3::new(0.0, 0.0, -1.0), Vec3::X, Vec3::Y, h, 0, &mut rng);
    s.rect(Vec3::new(-1.0, 0.0, 0.0), Vec3::Y, Vec3::Z, h, 0, &mut rng);
    s.sphere(Vec3::new(-0.4, -0.6, -0.3), 0.4, 1500, 1);
    s.sphere(Vec3::new(0.45, -0.7, 0.2), 0.3, 900, 2);
    (s, vec![class::DIFFUSE, class::MIRROR, class::DIELECTRIC])
}

/// The octree of `s` with leaves of at most 8 splats (deep trees from small scenes).
pub fn fine_octree(s: &Soa, classes: &[u32]) -> Octree {
    s.build(
        classes,
        OctreeParams {
            max_leaf_points: 8,
            ..Default::default()
        },
    )
    .unwrap()
}

/// Every leaf and empty node with its integer cell, by an independent depth-first walk.
pub fn cells(o: &Octree) -> Vec<(u32, u32, [u32; 3])> {
    let mut out = Vec::new();
    let mut stack = vec![(0u32, 0u32, [0u32; 3])];
    while let Some((slot, depth, c)) = stack.pop() {
        let w = o.nodes[slot as usize];
        if node::is_leaf(w) || node::is_empty(w) {
            out.push((slot, depth, c));
            continue;
        }
        for k in 0..8u32 {
            let cc = [
                2 * c[0] + (k & 1),
                2 * c[1] + ((k >> 1) & 1),
                2 * c[2] + ((k >> 2) & 1),
            ];
            stack.push((node::ptr(w) + k, depth + 1, cc));
        }
    }
    out
}

fn cell_contains(frame: &Frame, depth: u32, c: [u32; 3], p: Vec3) -> bool {
    // Exact integer comparison on the 21-bit quantised coordinate.
    let q = (p - Vec3::from(frame.origin)) * frame.inv_size;
    if q.cmplt(Vec3::ZERO).any() || q.cmpge(Vec3::ONE).any() {
        return false;
    }
    let qi = [q.x, q.y, q.z].map(|x| ((x * (1u32 << 21) as f32) as u32) >> (21 - depth));
    qi == c
}

fn own_range(o: &Octree, slot: u32) -> (u32, u32, Vec<u32>) {
    let (r, refs) = o.view().leaf(o.nodes[slot as usize]);
    (r.start, r.end, refs.to_vec())
}

#[test]
fn every_splat_is_owned_by_exactly_one_leaf() {
    let (s, classes) = mixed_scene(0.05);
    let o = s.build(&classes, OctreeParams::default()).unwrap();
    o.view().check().unwrap();
    let mut owned = vec![0u32; o.splats.len()];
    for (slot, _, _) in cells(&o) {
        if node::is_leaf(o.nodes[slot as usize]) {
            let (b, e, _) = own_range(&o, slot);
            for i in b..e {
                owned[i as usize] += 1;
                assert_eq!(o.splat_leaf[i as usize], slot);
            }
        }
    }
    assert!(
        owned.iter().all(|&c| c == 1),
        "some splat owned by 0 or 2+ leaves"
    );
    // The data pool is a permutation of the input.
    let mut src: Vec<u32> = o.splats.iter().map(|s| s.source).collect();
    src.sort_unstable();
    assert!(src.iter().enumerate().all(|(i, &s)| i as u32 == s));
}

#[test]
fn leaves_respect_k_and_purity_and_own_their_cell() {
    let (s, classes) = mixed_scene(0.05);
    for k in [1u32, 4, 16, 64] {
        let o = s
            .build(
                &classes,
                OctreeParams {
                    max_leaf_points: k,
                    ..Default::default()
                },
            )
            .unwrap();
        assert_eq!(o.stats.leaves_at_max_depth, 0);
        for (slot, depth, c) in cells(&o) {
            if !node::is_leaf(o.nodes[slot as usize]) {
                continue;
            }
            let (b, e, _) = own_range(&o, slot);
            assert!(e - b <= k, "leaf with {} > k = {k} splats", e - b);
            let sp = &o.splats[b as usize..e as usize];
            let spec: Vec<bool> = sp
                .iter()
                .map(|x| class::is_specular(classes[x.material as usize]))
                .collect();
            assert!(
                spec.iter().all(|&x| x == spec[0]) || sp.is_empty(),
                "leaf mixes diffuse and specular"
            );
            for x in sp {
                assert!(
                    cell_contains(&o.frame, depth, c, Vec3::from(x.position)),
                    "splat outside its leaf's cell"
                );
            }
        }
    }
}

#[test]
fn node_pool_groups_are_contiguous_in_sfc_order() {
    let (s, classes) = mixed_scene(0.08);
    let o = s.build(&classes, OctreeParams::default()).unwrap();
    assert_eq!((o.nodes.len() - 1) % 8, 0);
    // The splats under child k of a node all lie in octant k of the node's cell.
    for (slot, depth, c) in cells(&o) {
        if node::is_leaf(o.nodes[slot as usize]) {
            let (b, e, _) = own_range(&o, slot);
            for i in b..e {
                assert!(cell_contains(
                    &o.frame,
                    depth,
                    c,
                    Vec3::from(o.splats[i as usize].position)
                ));
            }
        }
    }
    // Morton order of the data pool: codes non-decreasing.
    let codes: Vec<u64> = o
        .splats
        .iter()
        .map(|x| {
            let q = (Vec3::from(x.position) - Vec3::from(o.frame.origin)) * o.frame.inv_size;
            pc_octree::morton::encode(
                pc_octree::morton::quantize(q.x),
                pc_octree::morton::quantize(q.y),
                pc_octree::morton::quantize(q.z),
            )
        })
        .collect();
    assert!(codes.windows(2).all(|w| w[0] <= w[1]));
}

#[test]
fn duplicated_points_terminate_at_max_depth() {
    let mut s = Soa::default();
    for _ in 0..100 {
        s.push(Vec3::new(0.3, 0.3, 0.3), Vec3::Y, 0.01, 0);
    }
    s.push(Vec3::ZERO, Vec3::Y, 0.01, 0);
    let o = s
        .build(
            &[class::DIFFUSE],
            OctreeParams {
                max_leaf_points: 4,
                max_depth: 12,
                area_samples: 4,
            },
        )
        .unwrap();
    assert_eq!(o.stats.depth, 12);
    assert_eq!(o.stats.leaves_at_max_depth, 1);
    o.view().check().unwrap();
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let s = Soa::default();
    assert!(matches!(
        s.build(&[class::DIFFUSE], OctreeParams::default()),
        Err(BuildError::Empty)
    ));
    let mut s = Soa::default();
    s.push(Vec3::ZERO, Vec3::Y, 0.1, 0);
    s.push(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::Y, 0.1, 0);
    match s.build(&[class::DIFFUSE], OctreeParams::default()) {
        Err(BuildError::BadSplat {
            index: 1,
            what: "position",
        }) => {}
        other => panic!("{other:?}"),
    }
    let mut s = Soa::default();
    s.push(Vec3::ZERO, Vec3::Y, 0.0, 0);
    assert!(matches!(
        s.build(&[class::DIFFUSE], OctreeParams::default()),
        Err(BuildError::BadSplat {
            index: 0,
            what: "radius"
        })
    ));
    let mut s = Soa::default();
    s.push(Vec3::ZERO, Vec3::Y, 0.1, 3);
    assert!(matches!(
        s.build(&[class::DIFFUSE], OctreeParams::default()),
        Err(BuildError::Param(_))
    ));
    let mut s = Soa::default();
    s.push(Vec3::ZERO, Vec3::Y, 0.1, 0);
    assert!(matches!(
        s.build(
            &[class::DIFFUSE],
            OctreeParams {
                max_depth: 22,
                ..Default::default()
            }
        ),
        Err(BuildError::Param(_))
    ));
}

/// Points densely sampled on a disk (for the brute-force overlap check).
fn disk_samples(x: &Splat, count: usize) -> Vec<Vec3> {
    let (u, v) = pc_artifact::octree::tangent_frame(x.normal);
    let (u, v, c) = (Vec3::from(u), Vec3::from(v), Vec3::from(x.position));
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..count)
        .map(|k| {
            let r = ((k as f32 + 0.5) / count as f32).sqrt() * x.radius * 0.9999;
            let a = k as f32 * golden;
            c + (u * a.cos() + v * a.sin()) * r
        })
        .collect()
}

#[test]
fn every_leaf_a_disk_overlaps_references_it() {
    let (s, classes) = mixed_scene(0.1);
    let o = s
        .build(
            &classes,
            OctreeParams {
                max_leaf_points: 4,
                ..Default::default()
            },
        )
        .unwrap();
    let all = cells(&o);
    let mut missing = 0;
    let mut checked = 0;
    for (i, x) in o.splats.iter().enumerate() {
        for p in disk_samples(x, 200) {
            // Brute force: the cell containing p, by testing every leaf and empty cell.
            let Some(&(slot, _, _)) = all
                .iter()
                .find(|(_, d, c)| cell_contains(&o.frame, *d, *c, p))
            else {
                continue;
            };
            checked += 1;
            let w = o.nodes[slot as usize];
            assert!(!node::is_empty(w), "splat {i}'s disk reaches an empty cell");
            let (b, e, refs) = own_range(&o, slot);
            if !((b..e).contains(&(i as u32)) || refs.contains(&(i as u32))) {
                missing += 1;
            }
        }
    }
    assert!(checked > 100_000);
    assert_eq!(
        missing, 0,
        "disk samples in leaves that do not reference the splat"
    );
    assert!(o.stats.extra_refs > 0);
}

#[test]
fn point_location_agrees_with_brute_force() {
    let (s, classes) = mixed_scene(0.05);
    let o = fine_octree(&s, &classes);
    let all = cells(&o);
    let view = o.view();
    let mut rng = Pcg64::seed_from_u64(3);
    let lo = Vec3::from(o.frame.origin);
    for _ in 0..3000 {
        let p = lo + Vec3::new(rng.random(), rng.random(), rng.random()) * o.frame.size;
        let got = view.locate(p).expect("inside the root cube");
        let want: Vec<_> = all
            .iter()
            .filter(|(_, d, c)| cell_contains(&o.frame, *d, *c, p))
            .collect();
        assert_eq!(want.len(), 1);
        assert_eq!(got.slot, want[0].0);
        assert_eq!(got.depth, want[0].1);
    }
    assert!(view.locate(lo - Vec3::ONE).is_none());
    assert!(view.locate(lo + Vec3::splat(o.frame.size * 1.01)).is_none());
}

#[test]
fn gpu_point_location_matches_cpu() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    let (s, classes) = mixed_scene(0.05);
    let o = fine_octree(&s, &classes);
    let view = o.view();
    let mut rng = Pcg64::seed_from_u64(11);
    let lo = Vec3::from(o.frame.origin);
    let mut pts: Vec<Vec3> = (0..20_000)
        .map(|_| {
            lo + Vec3::new(rng.random(), rng.random(), rng.random()) * o.frame.size * 1.1
                - Vec3::splat(0.05 * o.frame.size)
        })
        .collect();
    // Splat centres and points exactly on cell boundaries too.
    pts.extend(o.splats.iter().map(|x| Vec3::from(x.position)));
    pts.push(lo);
    pts.push(lo + Vec3::splat(o.frame.size * 0.5));
    let kernel = pc_octree::gpu::locate::LocateKernel::new(&ctx).unwrap();
    let gpu = kernel.run(&ctx, &view, &pts).unwrap();
    for (p, g) in pts.iter().zip(&gpu) {
        assert_eq!(*g, view.locate(*p), "point {p} on {}", ctx.describe());
    }
}

#[test]
fn wgsl_records_match_rust_layouts() {
    let src = pc_octree::gpu::locate::source().unwrap();
    let module = pc_gpu::validate_wgsl(&src).unwrap();
    let (size, members) = pc_gpu::wgsl_struct_layout(&module, "Splat").unwrap();
    assert_eq!(size as usize, std::mem::size_of::<Splat>());
    let offsets: Vec<u32> = members.iter().map(|m| m.1).collect();
    assert_eq!(offsets, vec![0, 12, 16, 28, 32, 44, 48]);
    assert_eq!(std::mem::offset_of!(Splat, radius), 12);
    assert_eq!(std::mem::offset_of!(Splat, material), 28);
    assert_eq!(std::mem::offset_of!(Splat, source), 44);
    assert_eq!(std::mem::offset_of!(Splat, clip), 48);
    let (size, members) = pc_gpu::wgsl_struct_layout(&module, "NodeInfo").unwrap();
    assert_eq!(size as usize, std::mem::size_of::<NodeInfo>());
    let offsets: Vec<u32> = members.iter().map(|m| m.1).collect();
    assert_eq!(
        offsets,
        vec![
            std::mem::offset_of!(NodeInfo, centroid) as u32,
            std::mem::offset_of!(NodeInfo, disk_radius) as u32,
            std::mem::offset_of!(NodeInfo, normal) as u32,
            std::mem::offset_of!(NodeInfo, area) as u32,
            std::mem::offset_of!(NodeInfo, tilt) as u32,
            std::mem::offset_of!(NodeInfo, count) as u32,
            std::mem::offset_of!(NodeInfo, class) as u32,
        ]
    );
    let (size, members) = pc_gpu::wgsl_struct_layout(&module, "Frame").unwrap();
    assert_eq!(size as usize, std::mem::size_of::<Frame>());
    assert_eq!(members[1].1 as usize, std::mem::offset_of!(Frame, size));
    assert_eq!(
        members.last().unwrap().1 as usize,
        std::mem::offset_of!(Frame, ref_count)
    );
}

/// The octree of a unit sphere's splats (16 area samples a disk), the sum of its splat areas
/// and the sphere's area.
fn unit_sphere_areas(s: &Soa) -> (Octree, f32, f32) {
    let params = OctreeParams {
        area_samples: 16,
        ..Default::default()
    };
    let o = s.build(&[class::DIFFUSE], params).unwrap();
    let total: f32 = o.splat_area.iter().sum();
    (o, total, 4.0 * std::f32::consts::PI)
}

#[test]
fn splat_areas_sum_to_the_surface_area() {
    // A closed sphere has no boundary: the union of the disks is the sphere (plus the thin
    // shell the flat disks stick out by), so the areas must sum to 4πR² closely.
    for count in [2000usize, 8000] {
        let mut s = Soa::default();
        s.sphere(Vec3::ZERO, 1.0, count, 0);
        let (o, total, want) = unit_sphere_areas(&s);
        assert!(
            (total / want - 1.0).abs() < 0.02,
            "{count} splats: area {total} vs {want}"
        );
        // Disks overlap about three times: πr² is far from the area each splat stands for.
        let disks: f32 = o
            .splats
            .iter()
            .map(|x| std::f32::consts::PI * x.radius * x.radius)
            .sum();
        assert!(disks > 2.0 * want);
        // Node areas add up.
        assert!((o.node_info[0].area - total).abs() < 1e-3 * total);
    }
}

#[test]
fn noisy_splat_areas_sum_to_the_surface_area_at_every_density() {
    // A scanned wall's centres lie σ off it and its fitted normals tilt a little. Once the
    // disks are not several σ in radius (a dense scan), neighbours stand off each other's
    // planes by more than half a radius and must still count as covering each other, or the
    // surface's splats stand for more than the surface. The noise is fixed and the density
    // grows, from σ at 8 % of a disk's radius to 43 %: half-radius slabs gave 1.001, 1.027,
    // 1.34 and 1.62 times the sphere's area; the noise-aware slabs give within 0.4 %.
    let mut rng = Pcg64::seed_from_u64(5);
    let mut gauss = move || {
        let (u, v): (f32, f32) = (rng.random_range(1e-7..1.0), rng.random());
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    };
    let sigma = 0.006f32;
    let tilt = 1.5f32.to_radians();
    for count in [2000usize, 8000, 32000, 64000] {
        let mut clean = Soa::default();
        clean.sphere(Vec3::ZERO, 1.0, count, 0);
        let mut s = Soa::default();
        for k in 0..clean.len() {
            let n = clean.n[k];
            let (u, v) = n.any_orthonormal_pair();
            let tilted = (n + (u * gauss() + v * gauss()) * tilt).normalize();
            s.push(n * (1.0 + sigma * gauss()), tilted, clean.r[k], 0);
        }
        let (_, total, want) = unit_sphere_areas(&s);
        assert!(
            (total / want - 1.0).abs() < 0.01,
            "{count} splats, noise {:.2} radii: area {total} vs {want}",
            sigma / clean.r[0]
        );
    }
}

#[test]
fn splat_areas_stop_half_a_spacing_beyond_a_border() {
    // Open rectangles sampled as jittered grids (radius = one cell, so the disks overhang the
    // border by up to a cell): the shares must add up to the rectangle, not to the union of
    // the disks. Also two materials tiling one plane side by side (each has its own border at
    // the seam), and a small emitter 0.6 radii below a large panel of the same orientation (the
    // reference Cornell box's light under its ceiling: the panel is not the light's interior).
    let mut rng = Pcg64::seed_from_u64(11);
    let h = 0.02f32;
    let cases: [(&str, Soa, Vec<f32>); 3] = [
        (
            "square",
            {
                let mut s = Soa::default();
                s.rect(Vec3::ZERO, Vec3::X * 0.5, Vec3::Y * 0.5, h, 0, &mut rng);
                s
            },
            vec![1.0],
        ),
        (
            "two tiles",
            {
                let mut s = Soa::default();
                s.rect(
                    Vec3::new(-0.3, 0.0, 0.0),
                    Vec3::X * 0.3,
                    Vec3::Y * 0.4,
                    h,
                    0,
                    &mut rng,
                );
                s.rect(
                    Vec3::new(0.3, 0.0, 0.0),
                    Vec3::X * 0.3,
                    Vec3::Y * 0.4,
                    h,
                    1,
                    &mut rng,
                );
                s
            },
            vec![0.48, 0.48],
        ),
        (
            "light under a panel",
            {
                let mut s = Soa::default();
                s.rect(Vec3::ZERO, Vec3::X * 0.6, Vec3::Y * 0.6, h, 0, &mut rng);
                s.rect(
                    Vec3::new(0.0, 0.0, 0.6 * h),
                    Vec3::X * 0.2,
                    Vec3::Y * 0.15,
                    h,
                    1,
                    &mut rng,
                );
                s
            },
            vec![1.44, 0.12],
        ),
    ];
    for (name, soa, want) in cases {
        let o = soa
            .build(&[class::DIFFUSE, class::EMITTER], OctreeParams::default())
            .unwrap();
        for (m, &want) in want.iter().enumerate() {
            let (mut area, mut disks) = (0.0f32, 0.0f32);
            for (s, a) in o.splats.iter().zip(&o.splat_area) {
                if s.material == m as u32 {
                    area += a;
                    disks += std::f32::consts::PI * s.radius * s.radius;
                }
            }
            assert!(
                (area / want - 1.0).abs() < 0.01,
                "{name}, material {m}: areas sum to {area}, the surface is {want}"
            );
            assert!(disks > 2.5 * want, "{name}: the disks overlap");
        }
    }
}

#[test]
fn corner_splats_keep_two_clip_lines() {
    // A square sampled on an exact grid (spacing h, radius h): every border splat sits half a
    // spacing inside the square's edge, so its clipped disk must end at the edge. A straight
    // stretch needs one line; a corner needs two, and with the single diagonal line of the
    // run's middle the corner disks overhung both edges by up to 0.37 h.
    let (h, n) = (0.02f32, 40);
    let half = 0.5 * h * n as f32;
    let mut soa = Soa::default();
    for i in 0..n {
        for j in 0..n {
            let at = |k: i32| -half + (k as f32 + 0.5) * h;
            soa.push(Vec3::new(at(i), at(j), 0.0), Vec3::Z, h, 0);
        }
    }
    let o = soa
        .build(&[class::DIFFUSE], OctreeParams::default())
        .unwrap();
    let corners: Vec<&Splat> = o
        .splats
        .iter()
        .filter(|s| s.clip[..3].iter().map(|x| x * x).sum::<f32>() > 1.01)
        .collect();
    assert_eq!(corners.len(), 4, "corner splats: {corners:?}");
    for s in &corners {
        let [o1, o2] = clip_lines(s.normal, s.clip);
        let c = Vec3::from(s.position);
        assert!(
            (c.x.abs() - (half - 0.5 * h)).abs() < 1e-5
                && (c.y.abs() - (half - 0.5 * h)).abs() < 1e-5
        );
        // The two lines face the two edges (±x and ±y), whatever their order.
        let (o1, o2) = (Vec3::from(o1), Vec3::from(o2));
        let want = [Vec3::X * c.x.signum(), Vec3::Y * c.y.signum()];
        let near = |a: Vec3, b: Vec3| a.angle_between(b) < 0.05;
        assert!(
            (near(o1, want[0]) && near(o2, want[1])) || (near(o1, want[1]) && near(o2, want[0])),
            "corner at {c}: lines {o1}, {o2}"
        );
    }
    // No kept point of any disk lies beyond the square (the clip offset is half a spacing).
    let mut beyond = 0.0f32;
    for s in &o.splats {
        let c = Vec3::from(s.position);
        for k in 0..400 {
            let (r, a) = (
                ((k as f32 + 0.5) / 400.0).sqrt() * s.radius,
                k as f32 * 2.399_963,
            );
            let x = c + Vec3::new(r * a.cos(), r * a.sin(), 0.0);
            if s.within_clip(x.into()) {
                beyond = beyond.max(x.x.abs().max(x.y.abs()) - half);
            }
            let y = Vec3::from(s.fold_into_clip(x.into()));
            assert!(s.within_clip(y.into()) && (y - c).length() <= s.radius * 1.0001);
        }
    }
    assert!(
        beyond < 0.03 * h,
        "a clipped disk reaches {beyond} beyond the square"
    );
}

#[test]
fn a_jittered_border_row_is_clipped_along_the_border() {
    // A square sampled on a fully jittered grid (one sample uniform in each h × h cell, radius
    // h), as the reference sets are: the border row's centres lie anywhere from 0 to h inside
    // the edge. A ray sees the union of the clipped disks, which reaches as far as the
    // outermost line among the two or three disks covering a point, so lines half a spacing
    // beyond each splat's own centre made the edge as ragged as the row's jitter (up to half a
    // spacing out). Clipped along their row's mean line, the border splats' lines lie on the
    // edge, and the union overhangs it less.
    let (h, n) = (0.02f32, 40);
    let half = 0.5 * h * n as f32;
    let mut rng = Pcg64::seed_from_u64(5);
    let mut soa = Soa::default();
    for i in 0..n {
        for j in 0..n {
            let mut at = |k: i32| -half + (k as f32 + rng.random_range(0.0..1.0)) * h;
            let (x, y) = (at(i), at(j));
            soa.push(Vec3::new(x, y, 0.0), Vec3::Z, h, 0);
        }
    }
    let o = soa
        .build(&[class::DIFFUSE], OctreeParams::default())
        .unwrap();
    // Each straight border splat's line (away from the corners): how far past the edge.
    let mut lines = Vec::new();
    for s in &o.splats {
        let [o1, o2] = clip_lines(s.normal, s.clip);
        let (o1, c) = (Vec3::from(o1), Vec3::from(s.position));
        if s.clip[3] == 0.0 || o1 != Vec3::from(o2) || c.x.abs().min(c.y.abs()) > half - 3.0 * h {
            continue;
        }
        let edge = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y]
            .into_iter()
            .find(|e| e.dot(o1) > 0.9)
            .expect("a border splat of the square faces one of its edges");
        lines.push(c.dot(edge) + s.clip[3] * edge.dot(o1) - half);
    }
    let stats = |x: &[f32]| {
        let mean = x.iter().sum::<f32>() / x.len() as f32;
        let rms = (x.iter().map(|d| d * d).sum::<f32>() / x.len() as f32).sqrt();
        (mean / h, rms / h)
    };
    let (mean, rms) = stats(&lines);
    assert!(lines.len() > 80, "{} border splats", lines.len());
    assert!(
        mean.abs() < 0.05 && rms < 0.24,
        "the border splats' lines lie {mean:.3} h past the edge on average, {rms:.3} h rms"
    );
    // How far past the edge the union reaches, at 400 points along each edge.
    let mut reach = Vec::new();
    for (out, along) in [
        (Vec3::X, Vec3::Y),
        (-Vec3::X, Vec3::Y),
        (Vec3::Y, Vec3::X),
        (-Vec3::Y, Vec3::X),
    ] {
        for k in 0..400 {
            let t = (k as f32 / 399.0 - 0.5) * (2.0 * half - 6.0 * h);
            let covered = |d: f32| {
                let x = out * (half + d) + along * t;
                o.splats.iter().any(|s| {
                    (x - Vec3::from(s.position)).length() <= s.radius && s.within_clip(x.into())
                })
            };
            let steps = (0..=200).map(|q| (q as f32 / 100.0 - 1.0) * h);
            reach.push(steps.filter(|&d| covered(d)).fold(-h, f32::max));
        }
    }
    reach.sort_by(f32::total_cmp);
    let (mean, _) = stats(&reach);
    let q95 = reach[reach.len() * 19 / 20] / h;
    assert!(
        mean.abs() < 0.1 && q95 < 0.4,
        "the clipped disks' union ends {mean:.3} h past the edge on average, {q95:.3} h at the 95th percentile"
    );
}

/// The octree of a mirror sphere of radius 2 (20,000 splats) with leaves of at most `k`.
fn mirror_sphere(k: u32) -> Octree {
    let mut s = Soa::default();
    s.sphere(Vec3::ZERO, 2.0, 20_000, 0);
    let params = OctreeParams {
        max_leaf_points: k,
        ..Default::default()
    };
    s.build(&[class::MIRROR], params).unwrap()
}

#[test]
fn small_leaves_fit_the_curvature_from_the_disks_they_reference() {
    // Leaves of one to three splats (k = 2) have no spread of their own to fit a tilt to; their
    // fields are fitted over the disks they reference of their own surface too, so the small
    // leaves of a sphere tilt as the large ones do (1/R), and no leaf shades flat.
    let o = mirror_sphere(2);
    let mut small = Vec::new();
    let (mut err_field, mut err_flat) = (0.0f64, 0.0f64);
    for (i, x) in o.splats.iter().enumerate() {
        let info = &o.node_info[o.splat_leaf[i] as usize];
        let p = Vec3::from(x.position);
        err_field += field_normal(info, p).angle_between(p.normalize()) as f64;
        err_flat += Vec3::from(info.normal).angle_between(p.normalize()) as f64;
        if info.count <= 3 {
            small.extend(info.tilt);
        }
    }
    assert!(small.len() > 10_000, "{} small-leaf tilts", small.len());
    small.sort_by(f32::total_cmp);
    let (low, median) = (small[small.len() / 20], small[small.len() / 2]);
    assert!(
        (median - 0.5).abs() < 0.05 && low > 0.3,
        "small leaves' tilt: median {median}, 5th percentile {low}, 1/R = 0.5"
    );
    assert!(
        err_field < 0.5 * err_flat,
        "field {err_field} vs flat {err_flat}"
    );
}

#[test]
fn normal_fields_follow_the_curvature() {
    let o = mirror_sphere(32);
    let (mut err_field, mut err_flat, mut count) = (0.0f64, 0.0f64, 0);
    let mut tilts = Vec::new();
    for (i, x) in o.splats.iter().enumerate() {
        let info = &o.node_info[o.splat_leaf[i] as usize];
        if info.count < 8 {
            continue;
        }
        let p = Vec3::from(x.position);
        let truth = p.normalize();
        err_field += field_normal(info, p).angle_between(truth) as f64;
        err_flat += Vec3::from(info.normal).angle_between(truth) as f64;
        count += 1;
        tilts.push(info.tilt[0]);
        tilts.push(info.tilt[1]);
    }
    assert!(count > 10_000);
    let (err_field, err_flat) = (err_field / count as f64, err_flat / count as f64);
    assert!(
        err_field < 0.25 * err_flat,
        "field {err_field} rad vs flat {err_flat} rad"
    );
    tilts.sort_by(f32::total_cmp);
    let median = tilts[tilts.len() / 2];
    assert!(
        (median - 0.5).abs() < 0.05,
        "tilt median {median}, 1/R = 0.5"
    );
}

/// A mirror cube: the leaves along its edges hold splats of two faces at right angles, whose
/// one linear field would tilt every normal there towards the other face (a mirror box's edge
/// then reflected the walls where a path tracer shows its black open front). Such leaves get a
/// flat field, and the renderer's shading normal anywhere on any splat of the cube is the
/// splat's own (within 0.08°: a flat face's mean normal rounds).
#[test]
fn sharp_edges_shade_with_the_splats_own_normals() {
    let mut rng = Pcg64::seed_from_u64(5);
    let mut s = Soa::default();
    s.cube(Vec3::ZERO, Vec3::splat(0.5), 0.02, 0, &mut rng);
    let o = s
        .build(
            &[class::MIRROR],
            OctreeParams {
                max_leaf_points: 32,
                ..Default::default()
            },
        )
        .unwrap();
    let view = o.view();
    let mut on_edges = 0;
    for (i, sp) in o.splats.iter().enumerate() {
        let info = &o.node_info[o.splat_leaf[i] as usize];
        let ns = Vec3::from(sp.normal);
        if Vec3::from(info.normal).dot(ns) < 0.99 {
            on_edges += 1; // its leaf mixes faces
        }
        let (u, v) = pc_artifact::octree::tangent_frame(sp.normal);
        for (a, b) in [(0.0, 0.0), (0.9, 0.0), (-0.9, 0.0), (0.0, 0.9), (0.0, -0.9)] {
            let x = Vec3::from(sp.position) + (Vec3::from(u) * a + Vec3::from(v) * b) * sp.radius;
            let n = pc_tree::optics::shading_normal(&view, i as u32, x);
            assert!(
                n.dot(ns) > 0.999_999,
                "splat {i} at ({a}, {b}) of its radius: shading normal {n}, its own {ns}"
            );
        }
    }
    assert!(
        on_edges > 100,
        "only {on_edges} splats in leaves that mix faces"
    );
}

#[test]
fn node_statistics_describe_the_subtree() {
    let (s, classes) = mixed_scene(0.05);
    let o = s.build(&classes, OctreeParams::default()).unwrap();
    let root = &o.node_info[0];
    assert_eq!(root.count as usize, o.splats.len());
    assert_eq!(root.class, class::MIXED);
    for (slot, _, _) in cells(&o) {
        let w = o.nodes[slot as usize];
        let info = &o.node_info[slot as usize];
        if node::is_empty(w) {
            assert_eq!(info.class, class::NONE);
            continue;
        }
        let (b, e, _) = own_range(&o, slot);
        assert_eq!(info.count, e - b);
        let c = Vec3::from(info.centroid);
        for x in &o.splats[b as usize..e as usize] {
            // Fig. 13: the average disk reaches every splat's far edge.
            assert!((Vec3::from(x.position) - c).length() + x.radius <= info.disk_radius * 1.0001);
        }
    }
}

#[test]
fn a_build_that_frees_its_input_early_builds_the_same_octree() {
    let (s, classes) = mixed_scene(0.02);
    let params = OctreeParams::default();
    let a = s.build(&classes, params).unwrap();
    let albedo = s.ones();
    let owned = (s, albedo, classes);
    let b = pc_octree::build_from(
        owned,
        |(s, albedo, classes)| BuildInput {
            positions: &s.p,
            normals: &s.n,
            radii: &s.r,
            albedo,
            material: &s.m,
            material_class: classes,
        },
        &params,
        &mut |_| {},
    )
    .unwrap();
    let bytes = |o: &Octree| {
        [
            bytemuck::cast_slice::<_, u8>(std::slice::from_ref(&o.frame)).to_vec(),
            bytemuck::cast_slice(&o.nodes).to_vec(),
            bytemuck::cast_slice(&o.begin_end).to_vec(),
            bytemuck::cast_slice(&o.splats).to_vec(),
            bytemuck::cast_slice(&o.node_info).to_vec(),
            bytemuck::cast_slice(&o.splat_area).to_vec(),
            bytemuck::cast_slice(&o.splat_leaf).to_vec(),
        ]
    };
    assert!(a.splats.len() > 10_000);
    assert_eq!(bytes(&a), bytes(&b));
    assert_eq!(a.stats.extra_refs, b.stats.extra_refs);
}
