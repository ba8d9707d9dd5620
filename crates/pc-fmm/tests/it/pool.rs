//! The final gather's footprints (`pc_fmm::pool`): which gathered splats share their rays.

use glam::Vec3;
use pc_fmm::pool::Footprints;

use crate::{box_scene, diffuse, scene};

/// Whether splat `o` lies in the footprint of splat `s` whose radius is scaled by `scale`: within
/// its disk, normals within 60°, its centre within half the radius of the plane.
fn in_footprint(
    s: &pc_artifact::octree::Splat,
    o: &pc_artifact::octree::Splat,
    scale: f32,
) -> bool {
    let (x, n, r) = (
        Vec3::from(s.position),
        Vec3::from(s.normal),
        s.radius * scale,
    );
    let d = Vec3::from(o.position) - x;
    d.length_squared() <= r * r && n.dot(Vec3::from(o.normal)) >= 0.5 && n.dot(d).abs() <= 0.5 * r
}

/// Every splat of the closed box with a cube on its floor gathered: each footprint holds
/// the listed splats of its disk on its own surface, as a brute-force search finds them (to the
/// rounding of the distance), so a floor splat never pools the walls it meets or the cube
/// standing on it; and the disks overlap, so footprints hold several splats.
#[test]
fn a_footprint_is_the_gathered_splats_of_its_disk_on_its_surface() {
    let sc = scene(&box_scene(0.05), vec![diffuse(0.5); 3], 16);
    let view = sc.octree.view();
    let splats: Vec<u32> = (0..view.splats.len() as u32).collect();
    let feet = Footprints::new(&view, &splats);
    assert_eq!(feet.len(), splats.len());
    let at = |k: usize| &view.splats[splats[k] as usize];
    for k in 0..splats.len() {
        let row = feet.of(k);
        assert!(
            row.contains(&(k as u32)),
            "splat {k} is in its own footprint"
        );
        for j in 0..splats.len() {
            let listed = row.contains(&(j as u32));
            if j == k {
                continue;
            }
            if in_footprint(at(k), at(j), 0.9999) {
                assert!(listed, "splat {j} lies in the footprint of {k}: {row:?}");
            }
            if !in_footprint(at(k), at(j), 1.0001) {
                assert!(!listed, "splat {j} is not in the footprint of {k}: {row:?}");
            }
        }
    }
    let mean = feet.mean_size();
    println!("{} splats, {mean:.2} in a footprint", splats.len());
    assert!(mean > 2.0, "{mean:.2} splats in a footprint");
}
