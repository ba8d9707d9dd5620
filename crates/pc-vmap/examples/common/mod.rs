//! What the diagnostic examples share.

use glam::Vec3;
use pc_artifact::octree::OctreeView;
use pc_tree::Between;
use rand::Rng;

/// A segment between the centres of two random splats at least `min_len` apart that face each
/// other, as the V-map casts it (each end's own zone from its leaf's roughness `rough`, the
/// ends half a radius off the disks): the two splats and the segment.
pub fn facing_segment(
    view: &OctreeView,
    rough: &[f32],
    rng: &mut impl Rng,
    min_len: f32,
) -> (usize, usize, Between) {
    let n = view.splats.len();
    loop {
        let (ia, ib) = (rng.random_range(0..n), rng.random_range(0..n));
        let (sa, sb) = (&view.splats[ia], &view.splats[ib]);
        let d = Vec3::from(sb.position) - Vec3::from(sa.position);
        let len = d.length();
        if len < min_len {
            continue;
        }
        let dir = d / len;
        if Vec3::from(sa.normal).dot(dir) <= 0.0 || Vec3::from(sb.normal).dot(-dir) <= 0.0 {
            continue;
        }
        let seg = Between::splats(
            (sa, rough[view.splat_leaf[ia] as usize]),
            (sb, rough[view.splat_leaf[ib] as usize]),
            dir,
            len,
            0.5 * sa.radius,
            len - 0.5 * sb.radius,
        );
        return (ia, ib, seg);
    }
}
