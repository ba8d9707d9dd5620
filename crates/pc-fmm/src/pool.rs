//! The final gather's rays pooled over each splat's footprint (docs/fmm.md, "Pooled rays"):
//! the gathered splats that lie within a splat's disk, on its surface, cast their rays for it
//! too, so that a splat among `n` gathered neighbours casts about `gather_rays / n` rays and
//! still takes its light from about `gather_rays`.
//!
//! Why this holds: a splat's radiance stands for the light over its disk (the renderer blends
//! each point of a surface from the disks that cover it), so rays from origins spread over the
//! disk estimate that light at least as well as rays from its centre alone. On a scan, whose
//! disks overlap several neighbours and whose gathered splats come in groups of neighbours
//! (crate::gather), the rays per unit of surface stay what `gather_rays` asks while the rays per
//! splat fall with the scan's density; on a sparse scene, where no neighbour is gathered within
//! a disk, every splat casts its `gather_rays` as before.

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use pc_tree::OctreeView;
use rayon::prelude::*;

use crate::gather::GatherRays;

/// Two splats share a surface when their normals agree within 60° ...
const SAME_SURFACE_COS: f32 = 0.5;
/// ... and the neighbour's centre lies within this share of the splat's radius of its plane.
const PLANE_TOLERANCE: f32 = 0.5;

/// The fewest rays a splat casts for its pool: a `MIN_STRATA × MIN_STRATA` grid.
const MIN_STRATA: u32 = 2;

/// For each of a list of gathered splats, the gathered splats within its disk on its surface
/// (itself included): indices into the list, in compressed rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Footprints {
    offsets: Vec<u32>,
    members: Vec<u32>,
}

impl Footprints {
    /// The footprints of `splats` (data-pool indices into `view.splats`).
    pub fn new(view: &OctreeView, splats: &[u32]) -> Footprints {
        let splat = |k: usize| &view.splats[splats[k] as usize];
        let points: Vec<[f32; 3]> = (0..splats.len()).map(|k| splat(k).position).collect();
        let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&points)
            .expect("kd-tree over at most u32::MAX gathered splats");
        let rows: Vec<Vec<u32>> = (0..splats.len())
            .into_par_iter()
            .map(|k| {
                let s = splat(k);
                let (x, n, r) = (Vec3::from(s.position), Vec3::from(s.normal), s.radius);
                let mut row = Vec::new();
                tree.query(&s.position)
                    .within::<SquaredEuclidean<f32>>(r * r)
                    .unsorted()
                    .visit(|it| {
                        let j = it.item as usize;
                        let o = splat(j);
                        let on_surface = n.dot(Vec3::from(o.normal)) >= SAME_SURFACE_COS
                            && n.dot(Vec3::from(o.position) - x).abs() <= PLANE_TOLERANCE * r;
                        if on_surface {
                            row.push(j as u32);
                        }
                    });
                // Itself (at distance 0, in its own plane) is always in the ball; the guard
                // keeps it there whatever the kd-tree's rounding of the radius.
                if !row.contains(&(k as u32)) {
                    row.push(k as u32);
                }
                row.sort_unstable();
                row
            })
            .collect();
        let mut offsets = Vec::with_capacity(rows.len() + 1);
        offsets.push(0u32);
        let mut members = Vec::with_capacity(rows.iter().map(Vec::len).sum());
        for row in rows {
            members.extend(row);
            offsets.push(members.len() as u32);
        }
        Footprints { offsets, members }
    }

    /// The splats listed.
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The gathered splats within splat `k`'s footprint, itself included (list indices).
    pub fn of(&self, k: usize) -> &[u32] {
        &self.members[self.offsets[k] as usize..self.offsets[k + 1] as usize]
    }

    /// The grid each splat casts so that its footprint's rays come to about `rays`: `rays`
    /// shared among the splats of its footprint (rounded up to a square), at least
    /// [`MIN_STRATA`]², at most `rays`.
    pub fn strata(&self, rays: GatherRays) -> Vec<u32> {
        let want = (rays.strata * rays.strata) as f64;
        (0..self.len())
            .map(|k| {
                let share = want / self.of(k).len() as f64;
                (share.sqrt().ceil() as u32).clamp(MIN_STRATA.min(rays.strata), rays.strata)
            })
            .collect()
    }

    /// Each splat's light from the rays of its footprint: the mean over every ray its members
    /// cast, of the members' mean gathered light `light` over `strata²` rays each.
    pub fn pool(&self, light: &[[f32; 3]], strata: &[u32]) -> Vec<[f32; 3]> {
        (0..self.len())
            .map(|k| {
                let (mut sum, mut count) = (Vec3::ZERO, 0.0f32);
                for &j in self.of(k) {
                    let n = (strata[j as usize] * strata[j as usize]) as f32;
                    sum += Vec3::from(light[j as usize]) * n;
                    count += n;
                }
                (sum / count.max(1.0)).into()
            })
            .collect()
    }

    /// The mean number of splats in a footprint.
    pub fn mean_size(&self) -> f64 {
        self.members.len() as f64 / self.len().max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strata_share_the_rays_among_a_footprint() {
        let f = Footprints {
            offsets: vec![0, 1, 5, 21],
            members: (0..21).map(|m| m % 3).collect(),
        };
        // Alone: all 256; among 4: 64 (8 x 8); among 16: 16 (4 x 4).
        assert_eq!(f.strata(GatherRays::new(256)), vec![16, 8, 4]);
        // Never under 2 x 2, never over the grid asked for.
        assert_eq!(f.strata(GatherRays::new(16)), vec![4, 2, 2]);
        assert_eq!(f.strata(GatherRays::new(1)), vec![1, 1, 1]);
    }

    #[test]
    fn the_pool_weights_each_member_by_its_rays() {
        let f = Footprints {
            offsets: vec![0, 2, 3],
            members: vec![0, 1, 1],
        };
        // Splat 0 cast 4 rays and found 1, splat 1 cast 16 and found 0.
        let pooled = f.pool(&[[1.0; 3], [0.0; 3]], &[2, 4]);
        assert_eq!(pooled, vec![[0.2; 3], [0.0; 3]]);
    }
}
