//! Leaf references (§8.5.13): the leaves and empty cells other than its own that a splat's disk
//! reaches, found by a box-then-plane walk of the node pool. docs/octree.md, "Build, phase by phase".

use glam::Vec3;
use pc_artifact::octree::{node, Frame, Splat};

/// Half extents of a disk's exact axis-aligned bounding box: r·sqrt(1 − n_axis²).
#[inline]
pub fn disk_half_extent(n: Vec3, r: f32) -> Vec3 {
    (Vec3::ONE - n * n).max(Vec3::ZERO).sqrt() * r
}

/// The pending cells of a walk over the node pool (node slot, cell corner, edge), reused from
/// splat to splat: a fresh fixed-size stack per splat cost a 3.5 KB fill each time.
pub(crate) type CellStack = Vec<(u32, Vec3, f32)>;

/// Leaves and empty cells, other than `owner`, that the splat's disk may overlap: the nested
/// test of §8.5.13, box first (the disk's exact bounding box against the cell, pruning whole
/// subtrees), then plane (the cell against the splat's plane: a cell entirely on one side cannot
/// touch the disk). Both tests are conservative, so there are no false negatives; cells are
/// inflated by a tiny epsilon against rounding. Each hit is passed to `emit`.
///
/// The walk starts at the deepest node whose cell holds the whole bounding box (found by
/// descending while the box stays inside one child), so the upper levels cost no box tests.
pub fn overlapped_cells(
    frame: &Frame,
    nodes: &[u32],
    s: &Splat,
    owner: u32,
    stack: &mut CellStack,
    emit: &mut impl FnMut(u32),
) {
    let c = Vec3::from(s.position);
    let n = Vec3::from(s.normal);
    let half = disk_half_extent(n, s.radius);
    let eps = frame.size * 1e-6;
    let (bmin, bmax) = (c - half - Vec3::splat(eps), c + half + Vec3::splat(eps));
    // Descend while the (inflated) box lies inside a single child.
    let (mut slot, mut lo, mut size) = (0u32, Vec3::from(frame.origin), frame.size);
    loop {
        let w = nodes[slot as usize];
        if w & (node::LEAF | node::EMPTY) != 0 {
            break;
        }
        let mid = lo + Vec3::splat(size * 0.5);
        let lo_side = bmin.cmpge(mid);
        let hi_side = bmax.cmpge(mid);
        if lo_side != hi_side {
            break;
        }
        let bits = hi_side.bitmask();
        let off = Vec3::new(
            (bits & 1) as f32,
            ((bits >> 1) & 1) as f32,
            ((bits >> 2) & 1) as f32,
        );
        slot = node::ptr(w) + bits;
        size *= 0.5;
        lo += off * size;
    }
    stack.clear();
    stack.push((slot, lo, size));
    while let Some((slot, lo, size)) = stack.pop() {
        let w = nodes[slot as usize];
        if w & (node::LEAF | node::EMPTY) != 0 {
            if slot != owner && plane_crosses_cell(c, n, lo - Vec3::splat(eps), size + 2.0 * eps) {
                emit(slot);
            }
            continue;
        }
        push_children_in_box(w, lo, size, bmin, bmax, stack);
    }
}

/// Pushes the children of the internal node `w` (cell at `lo`, edge `size`) whose cells meet the
/// box `[bmin, bmax]` onto a traversal stack.
#[inline]
pub(crate) fn push_children_in_box(
    w: u32,
    lo: Vec3,
    size: f32,
    bmin: Vec3,
    bmax: Vec3,
    stack: &mut CellStack,
) {
    let half = size * 0.5;
    let first = node::ptr(w);
    for child in 0..8u32 {
        let off = Vec3::new(
            (child & 1) as f32,
            ((child >> 1) & 1) as f32,
            ((child >> 2) & 1) as f32,
        );
        let clo = lo + off * half;
        if (bmin.cmple(clo + Vec3::splat(half)) & bmax.cmpge(clo)).all() {
            stack.push((first + child, clo, half));
        }
    }
}

/// True unless all 8 corners of the cell lie strictly on one side of the plane (c, n).
#[inline]
fn plane_crosses_cell(c: Vec3, n: Vec3, lo: Vec3, size: f32) -> bool {
    // Signed distance range of the box to the plane: centre distance ± projected half extent.
    let half = Vec3::splat(size * 0.5);
    let center = lo + half;
    let d = (center - c).dot(n);
    let reach = half.dot(n.abs());
    d.abs() <= reach
}
