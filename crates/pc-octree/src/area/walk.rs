//! The leaves a leaf's splats look at, found by one walk of the tree that a few consecutive
//! leaves share. docs/octree.md, "Splat area", "One walk for a few leaves".
//!
//! Every per-leaf pass of [`AreaPass`] needs, for one leaf's splats, the leaves whose cells
//! meet a box around them (widened, for the cover counts, by the largest disk extent below each
//! node). A walk from the root for every leaf cost more per splat as the tree deepened: 226
//! nodes a walk at 4M points, 344 at 20M. A walk's answer is every leaf whose own test passes,
//! in depth-first order: a node's test passes whenever one below it does (its cell holds the
//! child's, its extent is at least the child's, and both sums round the same way, the cells'
//! corners being exact binary fractions). So one walk for the union of a few consecutive
//! leaves' boxes reaches a superset of each one's leaves, in the same order, and filtering it
//! with each leaf's own test gives that leaf's walk exactly: the areas are the same to the bit.

use std::ops::Range;

use glam::Vec3;
use pc_artifact::octree::node;
use rayon::prelude::*;

use super::{AreaPass, Scratch};
use crate::refs::push_children_in_box;

/// Which leaves a walk reaches.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(super) enum Reach {
    /// Those whose cell meets the box: the own splats around a leaf's splats (the
    /// neighbourhood passes: the slabs, the borders, the rows' lines).
    Cells,
    /// Those whose cell, widened by the box's radius and the largest cover box half extents
    /// below the node ([`AreaPass::node_extents`]), meets the box: every disk that can cover a point of
    /// the leaf's splats ([`AreaPass::near`]).
    Extents,
}

/// The box a leaf's walk looks around: in root coordinates for the walk; for
/// [`Reach::Extents`] the box of the splats' centres in world units with their largest radius,
/// for [`Reach::Cells`] the box in world units that holds every neighbour's centre.
#[derive(Clone, Copy, Debug)]
pub(super) struct QueryBox {
    pub lo: Vec3,
    pub hi: Vec3,
    pub radius: f32,
    pub centres: (Vec3, Vec3),
}

impl QueryBox {
    fn union(&self, o: &QueryBox) -> QueryBox {
        QueryBox {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
            radius: self.radius.max(o.radius),
            centres: (
                self.centres.0.min(o.centres.0),
                self.centres.1.max(o.centres.1),
            ),
        }
    }

    /// The longest edge of the box.
    fn edge(&self) -> f32 {
        (self.hi - self.lo).max_element()
    }
}

/// A leaf a walk reached: its slot in the node pool and its cell (root coordinates).
#[derive(Clone, Copy, Debug)]
pub(super) struct LeafCell {
    slot: u32,
    lo: Vec3,
    size: f32,
}

/// The most consecutive leaves that share one walk.
const SHARED_RUNS: usize = 8;
/// How much longer than the longest of its leaves' boxes the shared box's edge may grow:
/// consecutive leaves in Morton order are mostly neighbours, but a run of them can jump across
/// a cell wall, and a shared box that spans the jump would hand every leaf a long list to filter.
const SHARED_GROWTH: f32 = 2.0;

/// Consecutive runs of the leaves (their indices into `boxes`) that share a walk: at most
/// [`SHARED_RUNS`] leaves, their boxes' union no longer than [`SHARED_GROWTH`] times the
/// longest of them. A leaf without a box (nothing to do) joins any group.
fn shared_groups(boxes: &[Option<QueryBox>]) -> Vec<Range<usize>> {
    let mut groups = Vec::new();
    let mut start = 0;
    // The group's union so far, and the longest edge among its leaves' boxes.
    let mut union: Option<(QueryBox, f32)> = None;
    for (k, b) in boxes.iter().enumerate() {
        let fits = k - start < SHARED_RUNS
            && match (union, b) {
                (Some((u, longest)), Some(b)) => {
                    u.union(b).edge() <= SHARED_GROWTH * longest.max(b.edge())
                }
                _ => true,
            };
        if !fits {
            groups.push(start..k);
            start = k;
            union = None;
        }
        if let Some(b) = b {
            union = Some(match union {
                Some((u, longest)) => (u.union(b), longest.max(b.edge())),
                None => (*b, b.edge()),
            });
        }
    }
    if start < boxes.len() {
        groups.push(start..boxes.len());
    }
    groups
}

impl AreaPass<'_> {
    /// `per_leaf(sc, run)` for every leaf's own range `run`, in order, with `sc` holding the
    /// leaf's candidates ([`Self::gather`]) when `boxes` gives it a box (a leaf without one has
    /// nothing to look up). The leaves share walks ([`shared_groups`]).
    pub(super) fn per_leaf<T: Send>(
        &self,
        reach: Reach,
        boxes: &[Option<QueryBox>],
        per_leaf: impl Fn(&mut Scratch, Range<usize>) -> Vec<T> + Sync,
    ) -> Vec<T> {
        shared_groups(boxes)
            .par_iter()
            .map_init(Scratch::default, |sc, group| {
                let union = boxes[group.clone()]
                    .iter()
                    .flatten()
                    .copied()
                    .reduce(|a, b| a.union(&b));
                if let Some(u) = union {
                    self.walk_leaves(reach, &u, sc);
                }
                let mut out = Vec::new();
                for k in group.clone() {
                    if let Some(b) = &boxes[k] {
                        self.gather(reach, b, sc);
                    }
                    out.extend(per_leaf(sc, self.runs[k].clone()));
                }
                out
            })
            .flatten_iter()
            .collect()
    }

    /// Every leaf the box `q` reaches, depth first, in `sc.reached`.
    fn walk_leaves(&self, reach: Reach, q: &QueryBox, sc: &mut Scratch) {
        sc.reached.clear();
        sc.stack.clear();
        sc.stack.push((0, Vec3::ZERO, 1.0));
        while let Some((slot, lo, size)) = sc.stack.pop() {
            let w = self.nodes[slot as usize];
            if w & node::EMPTY != 0 {
                continue;
            }
            if reach == Reach::Extents && !self.widened_cell_meets(slot, lo, size, q) {
                continue;
            }
            if w & node::LEAF != 0 {
                sc.reached.push(LeafCell { slot, lo, size });
                continue;
            }
            match reach {
                Reach::Cells => push_children_in_box(w, lo, size, q.lo, q.hi, &mut sc.stack),
                Reach::Extents => {
                    let half = size * 0.5;
                    for child in 0..8u32 {
                        let off = Vec3::new(
                            (child & 1) as f32,
                            ((child >> 1) & 1) as f32,
                            ((child >> 2) & 1) as f32,
                        );
                        sc.stack.push((node::ptr(w) + child, lo + off * half, half));
                    }
                }
            }
        }
    }

    /// Whether a walk for `q` alone would reach the leaf `cell`: the test of
    /// [`Self::walk_leaves`] (for [`Reach::Cells`], [`push_children_in_box`]'s), whose
    /// ancestors pass whenever it does.
    fn reaches(&self, reach: Reach, cell: &LeafCell, q: &QueryBox) -> bool {
        match reach {
            // The root is pushed without a test.
            Reach::Cells => {
                cell.slot == 0
                    || (q.lo.cmple(cell.lo + Vec3::splat(cell.size)) & q.hi.cmpge(cell.lo)).all()
            }
            Reach::Extents => self.widened_cell_meets(cell.slot, cell.lo, cell.size, q),
        }
    }

    /// Whether the cell (`lo`, `size`) of node `slot`, widened by `q`'s radius and the largest
    /// cover box half extents below it, meets `q`.
    #[inline]
    fn widened_cell_meets(&self, slot: u32, lo: Vec3, size: f32, q: &QueryBox) -> bool {
        let e = (Vec3::splat(q.radius) + self.node_extents[slot as usize]) * self.frame.inv_size;
        ((lo - e).cmple(q.hi) & (lo + Vec3::splat(size) + e).cmpge(q.lo)).all()
    }

    /// One leaf's candidates from its group's `sc.reached`: for [`Reach::Cells`] the own
    /// splats of the leaves its box meets, in `sc.cands` and, lane for lane, `sc.disks`; for
    /// [`Reach::Extents`] the disks that can cover a point of its splats, in `sc.disks`
    /// ([`super::Disks::extend_reaching`]).
    fn gather(&self, reach: Reach, q: &QueryBox, sc: &mut Scratch) {
        sc.cands.clear();
        sc.disks.clear();
        for cell in &sc.reached {
            if !self.reaches(reach, cell, q) {
                continue;
            }
            let (own, _) = self.leaf_list(self.nodes[cell.slot as usize]);
            match reach {
                Reach::Cells => {
                    sc.disks
                        .extend_within(&mut sc.cands, &self.disks, own, q.centres);
                }
                Reach::Extents => {
                    let halves = &self.cover_halves;
                    sc.disks
                        .extend_reaching(&self.disks, own, q.centres, q.radius, halves);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box(x: f32) -> Option<QueryBox> {
        let lo = Vec3::new(x, 0.0, 0.0);
        Some(QueryBox {
            lo,
            hi: lo + Vec3::ONE,
            radius: 0.0,
            centres: (lo, lo + Vec3::ONE),
        })
    }

    #[test]
    fn neighbouring_leaves_share_a_walk_and_a_jump_starts_a_new_one() {
        // Three touching unit boxes, then one far off, then more than a group holds.
        let mut boxes = vec![
            unit_box(0.0),
            unit_box(0.5),
            None,
            unit_box(1.0),
            unit_box(9.0),
        ];
        boxes.extend((0..SHARED_RUNS + 1).map(|_| unit_box(9.0)));
        let groups = shared_groups(&boxes);
        assert_eq!(groups[0], 0..4, "{groups:?}");
        assert_eq!(groups[1], 4..4 + SHARED_RUNS);
        assert_eq!(groups[2], 4 + SHARED_RUNS..boxes.len());
        // Every leaf is in exactly one group, in order.
        let flat: Vec<usize> = groups.iter().flat_map(|g| g.clone()).collect();
        assert_eq!(flat, (0..boxes.len()).collect::<Vec<_>>());
    }

    #[test]
    fn leaves_without_boxes_are_grouped_too() {
        let boxes = vec![None; 2 * SHARED_RUNS + 3];
        let groups = shared_groups(&boxes);
        let flat: Vec<usize> = groups.iter().flat_map(|g| g.clone()).collect();
        assert_eq!(flat, (0..boxes.len()).collect::<Vec<_>>());
        assert!(groups.iter().all(|g| g.len() <= SHARED_RUNS));
    }
}
