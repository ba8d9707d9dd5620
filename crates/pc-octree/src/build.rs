//! The octree build: root cube, Morton sort, level-by-level adaptive split, node pool, leaf
//! references (§8.5.13), begin/end table, per-node statistics and normal fields.
//!
//! Every phase is a parallel pass (rayon) over splats or over the nodes of one level; the only
//! sequential work is a prefix sum per level to place the child groups. See docs/octree.md.

use std::time::Instant;

use glam::Vec3;
use pc_artifact::octree::{class, node, tangent_frame, Frame, NodeInfo, OctreeStats, Splat};
use pc_artifact::params::OctreeParams;
use pc_tree::{locate_normalized, OctreeView};
use rayon::prelude::*;

use crate::morton;

/// Why a build failed.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    #[error("the scene has no splats")]
    Empty,
    #[error("splat {index}: {what} is not finite or not positive")]
    BadSplat { index: usize, what: &'static str },
    #[error("the octree needs {need} {what}, more than the 30-bit pointers of the node format allow ({max})")]
    TooLarge {
        what: &'static str,
        need: u64,
        max: u64,
    },
    #[error("invalid parameter: {0}")]
    Param(String),
    /// The splats' bounding box does not fit f32 arithmetic (its size or centre overflows).
    #[error(
        "the splats span {lo:?} to {hi:?}, beyond what f32 arithmetic holds: shift or scale the models"
    )]
    Extent { lo: [f32; 3], hi: [f32; 3] },
}

/// The splats to build over (structure of arrays, as the importer makes them).
#[derive(Clone, Copy, Debug)]
pub struct BuildInput<'a> {
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    pub radii: &'a [f32],
    pub albedo: &'a [Vec3],
    /// Material index per splat.
    pub material: &'a [u32],
    /// `class::*` of each material.
    pub material_class: &'a [u32],
}

/// A built octree, owning its sections.
#[derive(Clone, Debug)]
pub struct Octree {
    pub frame: Frame,
    pub nodes: Vec<u32>,
    pub begin_end: Vec<u32>,
    pub splats: Vec<Splat>,
    pub node_info: Vec<NodeInfo>,
    pub splat_area: Vec<f32>,
    pub splat_leaf: Vec<u32>,
    pub stats: OctreeStats,
}

impl Octree {
    pub fn view(&self) -> OctreeView<'_> {
        OctreeView {
            frame: self.frame,
            nodes: &self.nodes,
            begin_end: &self.begin_end,
            splats: &self.splats,
            node_info: &self.node_info,
            splat_area: &self.splat_area,
            splat_leaf: &self.splat_leaf,
        }
    }
}

/// A non-empty node found during the split: its slot, splat range in Morton order and depth.
#[derive(Clone, Copy, Debug)]
struct Span {
    slot: u32,
    lo: u32,
    hi: u32,
    depth: u32,
}

/// Purity key: 0 for every diffuse material, 1 + material index for specular and emitting ones,
/// so a leaf never mixes diffuse and specular splats, nor two different specular materials, nor
/// an emitter with anything else (a light mounted on a ceiling stays apart from the ceiling
/// behind it, which the V-map's visibility fractions need: docs/fmm.md).
fn purity_key(material: u32, material_class: &[u32]) -> u32 {
    let c = material_class[material as usize];
    if class::is_specular(c) || c == class::EMITTER {
        1 + material
    } else {
        0
    }
}

/// Build the octree. `phase` is called with the name of each phase as it starts.
pub fn build(
    input: &BuildInput,
    params: &OctreeParams,
    phase: &mut dyn FnMut(&str),
) -> Result<Octree, BuildError> {
    let n = input.positions.len();
    if n == 0 {
        return Err(BuildError::Empty);
    }
    if params.max_leaf_points == 0 || params.max_depth == 0 || params.max_depth > morton::BITS {
        return Err(BuildError::Param(format!(
            "max_leaf_points must be >= 1 and max_depth in 1..={} (got {} and {})",
            morton::BITS,
            params.max_leaf_points,
            params.max_depth
        )));
    }
    if n as u64 > node::MAX_PTR as u64 {
        return Err(BuildError::TooLarge {
            what: "splats",
            need: n as u64,
            max: node::MAX_PTR as u64,
        });
    }
    for (what, len) in [
        ("normals", input.normals.len()),
        ("radii", input.radii.len()),
        ("albedo", input.albedo.len()),
        ("material", input.material.len()),
    ] {
        if len != n {
            return Err(BuildError::Param(format!(
                "{what} has {len} entries for {n} positions"
            )));
        }
    }
    if let Some(i) = input
        .material
        .iter()
        .position(|&m| m as usize >= input.material_class.len())
    {
        return Err(BuildError::Param(format!(
            "splat {i} names material {} of {}",
            input.material[i],
            input.material_class.len()
        )));
    }
    let mut timings = Vec::new();
    let mut t0 = Instant::now();
    let lap = |name: &str, timings: &mut Vec<(String, f64)>, t0: &mut Instant| {
        timings.push((name.to_string(), t0.elapsed().as_secs_f64()));
        *t0 = Instant::now();
    };

    // ---- root cube -------------------------------------------------------------------------
    phase("bounds");
    if let Some(i) = (0..n).into_par_iter().find_first(|&i| {
        !input.positions[i].is_finite() || !(input.radii[i].is_finite() && input.radii[i] > 0.0)
    }) {
        let what = if input.positions[i].is_finite() {
            "radius"
        } else {
            "position"
        };
        return Err(BuildError::BadSplat { index: i, what });
    }
    let (lo, hi) = (0..n)
        .into_par_iter()
        .fold(
            || (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), i| {
                let r = Vec3::splat(input.radii[i]);
                (
                    lo.min(input.positions[i] - r),
                    hi.max(input.positions[i] + r),
                )
            },
        )
        .reduce(
            || (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        );
    let extent = (hi - lo).max_element();
    let center = (lo + hi) * 0.5;
    // A small margin keeps every normalised coordinate strictly inside [0, 1).
    let size = (extent * 1.002)
        .max(center.abs().max_element() * 1e-5)
        .max(f32::MIN_POSITIVE * 1e6);
    let origin = center - Vec3::splat(size * 0.5);
    let inv_size = 1.0 / size;
    if !(size.is_finite() && inv_size.is_finite() && origin.is_finite()) {
        return Err(BuildError::Extent {
            lo: lo.to_array(),
            hi: hi.to_array(),
        });
    }
    let mut frame = Frame {
        origin: origin.into(),
        size,
        inv_size,
        max_depth: params.max_depth,
        max_leaf_points: params.max_leaf_points,
        splat_count: n as u32,
        ..Default::default()
    };
    lap("bounds", &mut timings, &mut t0);

    // ---- Morton codes and parallel sort -----------------------------------------------------
    phase("morton sort");
    let mut keyed: Vec<(u64, u32)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let q = (input.positions[i] - origin) * inv_size;
            let code = morton::encode(
                morton::quantize(q.x),
                morton::quantize(q.y),
                morton::quantize(q.z),
            );
            (code, i as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    let codes: Vec<u64> = keyed.par_iter().map(|k| k.0).collect();
    let order: Vec<u32> = keyed.par_iter().map(|k| k.1).collect();
    drop(keyed);
    let purity: Vec<u32> = order
        .par_iter()
        .map(|&i| purity_key(input.material[i as usize], input.material_class))
        .collect();
    lap("morton sort", &mut timings, &mut t0);

    // ---- adaptive split, level by level -----------------------------------------------------
    phase("split");
    let k = params.max_leaf_points;
    let mut nodes: Vec<u32> = vec![0];
    let mut spans: Vec<Span> = Vec::new(); // every non-empty node
    let mut leaves: Vec<Span> = Vec::new();
    let mut empties: Vec<(u32, u32)> = Vec::new(); // (slot, position in Morton order)
    let mut level = vec![Span {
        slot: 0,
        lo: 0,
        hi: n as u32,
        depth: 0,
    }];
    let mut leaves_at_max_depth = 0u64;
    while !level.is_empty() {
        let splits: Vec<Option<[u32; 9]>> = level
            .par_iter()
            .map(|s| {
                let count = s.hi - s.lo;
                let range = s.lo as usize..s.hi as usize;
                let impure = count > 1 && {
                    let p0 = purity[s.lo as usize];
                    purity[range.clone()].iter().any(|&p| p != p0)
                };
                if s.depth >= params.max_depth || (count <= k && !impure) {
                    return None;
                }
                let c = &codes[range];
                let mut b = [s.lo; 9];
                for (child, slot) in b.iter_mut().enumerate().skip(1) {
                    *slot = s.lo
                        + c.partition_point(|&x| morton::child_at(x, s.depth) < child as u32)
                            as u32;
                }
                b[8] = s.hi;
                Some(b)
            })
            .collect();
        let mut next = Vec::new();
        for (s, split) in level.iter().zip(splits) {
            spans.push(*s);
            match split {
                None => {
                    let count = s.hi - s.lo;
                    if s.depth >= params.max_depth
                        && (count > k || {
                            let p0 = purity[s.lo as usize];
                            purity[s.lo as usize..s.hi as usize]
                                .iter()
                                .any(|&p| p != p0)
                        })
                    {
                        leaves_at_max_depth += 1;
                    }
                    leaves.push(*s);
                }
                Some(b) => {
                    let base = nodes.len() as u64;
                    if base + 8 > node::MAX_PTR as u64 {
                        return Err(BuildError::TooLarge {
                            what: "nodes",
                            need: base + 8,
                            max: node::MAX_PTR as u64,
                        });
                    }
                    nodes[s.slot as usize] = node::internal(base as u32);
                    nodes.extend_from_slice(&[0; 8]);
                    for c in 0..8 {
                        let slot = base as u32 + c as u32;
                        if b[c] == b[c + 1] {
                            nodes[slot as usize] = node::EMPTY_NODE;
                            empties.push((slot, b[c]));
                        } else {
                            next.push(Span {
                                slot,
                                lo: b[c],
                                hi: b[c + 1],
                                depth: s.depth + 1,
                            });
                        }
                    }
                }
            }
        }
        level = next;
    }
    lap("split", &mut timings, &mut t0);

    // ---- data pool in Morton order ------------------------------------------------------------
    phase("data pool");
    let mut splats: Vec<Splat> = order
        .par_iter()
        .map(|&i| {
            let i = i as usize;
            Splat {
                position: input.positions[i].into(),
                radius: input.radii[i],
                normal: input.normals[i].normalize_or(Vec3::Z).into(),
                material: input.material[i],
                albedo: input.albedo[i].into(),
                source: i as u32,
                clip: [0.0; 4],
            }
        })
        .collect();
    let mut splat_leaf = vec![0u32; n];
    for l in &leaves {
        splat_leaf[l.lo as usize..l.hi as usize].fill(l.slot);
    }
    // Leaves are marked now (pointer filled below) so the overlap pass can tell them apart.
    for l in &leaves {
        nodes[l.slot as usize] = node::LEAF;
    }
    lap("data pool", &mut timings, &mut t0);

    // ---- §8.5.13: every leaf a disk reaches references it -----------------------------------
    phase("leaf references");
    let mut refs: Vec<(u32, u32)> = (0..n as u32)
        .into_par_iter()
        .fold(Vec::new, |mut acc, s| {
            overlapped_cells(
                &frame,
                &nodes,
                &splats[s as usize],
                splat_leaf[s as usize],
                &mut |slot| acc.push((slot, s)),
            );
            acc
        })
        .reduce(Vec::new, |mut a, mut b| {
            if a.len() < b.len() {
                std::mem::swap(&mut a, &mut b);
            }
            a.extend_from_slice(&b);
            a
        });
    refs.par_sort_unstable();
    lap("leaf references", &mut timings, &mut t0);

    // ---- leaves in SFC order and the begin/end table ------------------------------------------
    phase("begin/end table");
    // Empty cells that a disk reaches into become leaves with references only.
    let mut all_leaves: Vec<(u32, u32, u32)> =
        leaves.iter().map(|l| (l.lo, l.hi, l.slot)).collect();
    let mut ref_leaves = 0u64;
    {
        let mut r = 0;
        let mut sorted_empties = empties.clone();
        sorted_empties.sort_unstable();
        for &(slot, at) in &sorted_empties {
            while r < refs.len() && refs[r].0 < slot {
                r += 1;
            }
            if r < refs.len() && refs[r].0 == slot {
                all_leaves.push((at, at, slot));
                ref_leaves += 1;
            }
        }
    }
    all_leaves.par_sort_unstable();
    let table_len = 2 * all_leaves.len() as u64 + refs.len() as u64 + 1;
    if table_len > node::MAX_PTR as u64 {
        return Err(BuildError::TooLarge {
            what: "begin/end entries",
            need: table_len,
            max: node::MAX_PTR as u64,
        });
    }
    let mut begin_end = Vec::with_capacity(table_len as usize);
    for &(lo, _hi, slot) in &all_leaves {
        let first = refs.partition_point(|r| r.0 < slot);
        let last = refs.partition_point(|r| r.0 <= slot);
        nodes[slot as usize] = node::leaf(begin_end.len() as u32);
        begin_end.push(lo);
        begin_end.push((last - first) as u32);
        begin_end.extend(refs[first..last].iter().map(|r| r.1));
    }
    begin_end.push(n as u32);
    lap("begin/end table", &mut timings, &mut t0);

    // ---- splat areas: partition of unity over overlapping disks ---------------------------------
    phase("splat areas");
    let mut leaf_depth = vec![0u8; nodes.len()];
    for l in &leaves {
        leaf_depth[l.slot as usize] = l.depth as u8;
    }
    let (splat_area, clips) = splat_areas(
        &frame,
        &nodes,
        &begin_end,
        &splats,
        &splat_leaf,
        &leaf_depth,
        params.area_samples,
    );
    for (s, clip) in splats.iter_mut().zip(clips) {
        s.clip = clip;
    }
    lap("splat areas", &mut timings, &mut t0);

    // ---- per-node average disk, normal, area, class; normal fields of leaves ------------------
    phase("node statistics");
    let infos: Vec<(u32, NodeInfo)> = spans
        .par_iter()
        .map(|s| {
            let range = s.lo as usize..s.hi as usize;
            (
                s.slot,
                node_info(
                    &splats[range.clone()],
                    &splat_area[range],
                    input.material_class,
                    node::is_leaf(nodes[s.slot as usize]),
                ),
            )
        })
        .collect();
    let mut node_info = vec![
        NodeInfo {
            class: class::NONE,
            ..Default::default()
        };
        nodes.len()
    ];
    for (slot, info) in infos {
        node_info[slot as usize] = info;
    }
    lap("node statistics", &mut timings, &mut t0);

    let depth = spans.iter().map(|s| s.depth).max().unwrap_or(0);
    let leaf_count = all_leaves.len() as u64;
    frame.depth = depth;
    frame.node_count = nodes.len() as u32;
    frame.leaf_count = leaf_count as u32;
    frame.ref_count = refs.len() as u32;
    let stats = OctreeStats {
        splats: n as u64,
        nodes: nodes.len() as u64,
        leaves: leaf_count,
        empty_nodes: empties.len() as u64 - ref_leaves,
        ref_leaves,
        extra_refs: refs.len() as u64,
        depth,
        leaves_at_max_depth,
        timings,
    };
    Ok(Octree {
        frame,
        nodes,
        begin_end,
        splats,
        node_info,
        splat_area,
        splat_leaf,
        stats,
    })
}

/// Half extents of a disk's exact axis-aligned bounding box: r·sqrt(1 − n_axis²).
#[inline]
pub fn disk_half_extent(n: Vec3, r: f32) -> Vec3 {
    (Vec3::ONE - n * n).max(Vec3::ZERO).sqrt() * r
}

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
    // A fixed-size stack: at most 7 pending siblings per level, 21 levels.
    let mut stack = [(0u32, Vec3::ZERO, 0.0f32); 8 * 22];
    let mut top = 0usize;
    stack[top] = (slot, lo, size);
    top += 1;
    while top > 0 {
        top -= 1;
        let (slot, lo, size) = stack[top];
        let w = nodes[slot as usize];
        if w & (node::LEAF | node::EMPTY) != 0 {
            if slot != owner && plane_crosses_cell(c, n, lo - Vec3::splat(eps), size + 2.0 * eps) {
                emit(slot);
            }
            continue;
        }
        push_children_in_box(w, lo, size, bmin, bmax, &mut stack, &mut top);
    }
}

/// Pushes the children of the internal node `w` (cell at `lo`, edge `size`) whose cells meet the
/// box `[bmin, bmax]` onto a traversal stack.
#[inline]
fn push_children_in_box(
    w: u32,
    lo: Vec3,
    size: f32,
    bmin: Vec3,
    bmax: Vec3,
    stack: &mut [(u32, Vec3, f32)],
    top: &mut usize,
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
            stack[*top] = (first + child, clo, half);
            *top += 1;
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

/// Points on the unit disk for the area estimate: a Fibonacci (golden-angle) spiral, area
/// uniform, deterministic.
fn disk_pattern(m: u32) -> impl Iterator<Item = (f32, f32)> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..m).map(move |k| {
        let r = ((k as f32 + 0.5) / m as f32).sqrt();
        let a = k as f32 * golden;
        (r * a.cos(), r * a.sin())
    })
}

/// Directions in each splat's tangent plane in which its border status is tested.
const BORDER_DIRS: usize = 32;
/// The mask with every direction open.
const ALL_DIRS: u32 = u32::MAX >> (32 - BORDER_DIRS);

/// Where a splat's share of the surface ends (docs/octree.md, "Splat area").
#[derive(Clone, Copy, Debug, PartialEq)]
enum Border {
    /// Same-surface neighbours lie out every way: the whole disk.
    Interior,
    /// On a straight stretch of border, or a corner: up to half a spacing beyond the splat
    /// along the outward direction (a, b) of its tangent frame.
    Edge { a: f32, b: f32, gap: f32 },
    /// Open in several separate arcs (a strip one or two samples wide): up to half a spacing
    /// beyond the splat in every open direction (bit k of the mask).
    Open { mask: u32, gap: f32 },
}

/// Area each splat stands for: A_i = ∫_{disk i} [x ∈ S_i] / m(x) dA, where m(x) counts the
/// disks of the same surface that cover x and S_i is the part of the plane that splat i's
/// share can reach (all of it, except at a border). In the interior this is a partition of
/// unity: the A_i sum to the surface area whatever the overlap. Estimated with `samples`
/// points per disk. A disk covers x when x is within its radius in its plane, within half a
/// radius of its plane, and the two normals agree within 60° (so the two sides of a thin wall,
/// or the faces meeting at an edge, do not share area).
///
/// Border clip: the disks at a surface's open border (a wall's edge, the light's edge, a hole)
/// overhang the sampled surface by up to a radius, while a sampled surface ends about half a
/// sample spacing beyond its outermost samples. A splat is on the border in a direction of its
/// tangent plane when no same-surface neighbour lies more than half a spacing out that way;
/// its share then stops half a spacing beyond its own centre along the outward direction (the
/// middle of its open directions). Each border splat uses its own position rather than the
/// outermost of its neighbours, and a point's weight counts all covering disks, so the jitter
/// of the border row averages out instead of the extreme sample setting the edge. The half
/// spacing comes from the areas themselves: g_i = ½√(least unclipped area around i), the
/// least being an interior splat's (a second round from the clipped areas changed the
/// reference Cornell areas by under 0.1 % and was dropped).
///
/// Speed: the owner leaf's list (own + referenced splats) holds every disk that reaches the
/// owner cell, so for the samples that fall inside that cell it is enough to test the few disks
/// that overlap disk i at all (filtered once per splat); samples outside the cell locate their
/// own leaf and test its list.
///
/// Identical splats (the same position, normal, radius and material: duplicate points, as scans
/// of overlapping stations hold thousands of) share a disk exactly, so each gets the same
/// share; the pass computes one representative per group ([`Duplicates`]) and counts it as
/// many times as the group has members wherever it covers a point. Without this, m coincident
/// splats cost O(m²) (they cannot be split, and every list that holds one holds them all).
pub fn splat_areas(
    frame: &Frame,
    nodes: &[u32],
    begin_end: &[u32],
    splats: &[Splat],
    splat_leaf: &[u32],
    leaf_depth: &[u8],
    samples: u32,
) -> (Vec<f32>, Vec<[f32; 4]>) {
    let dups = Duplicates::new(splats, splat_leaf);
    let ctx = AreaPass {
        frame,
        nodes,
        begin_end,
        splats,
        splat_leaf,
        dups: &dups,
        pattern: disk_pattern(samples.max(1)).collect(),
        leaf_depth,
        dirs: std::array::from_fn(|k| {
            let a = k as f32 * std::f32::consts::TAU / BORDER_DIRS as f32;
            (a.cos(), a.sin())
        }),
    };
    let unclipped = dups.spread(ctx.run(None));
    let gap = dups.spread(ctx.spacing(&unclipped, |near, a| {
        near.iter()
            .map(|&j| a[j as usize])
            .fold(f32::INFINITY, f32::min)
    }));
    let borders = dups.spread(ctx.borders(&gap));
    let areas = dups.spread(ctx.run(Some(&borders)));
    let clips = borders
        .par_iter()
        .zip(splats)
        .map(|(b, s)| {
            let (a, b, gap) = match *b {
                Border::Interior => return [0.0; 4],
                Border::Edge { a, b, gap } => (a, b, gap),
                Border::Open { mask, gap } => match longest_arc(mask) {
                    Some(mid) => (mid.cos(), mid.sin(), gap),
                    None => return [0.0; 4],
                },
            };
            let (u, v) = tangent_frame(s.normal);
            let d = (Vec3::from(u) * a + Vec3::from(v) * b).normalize_or_zero();
            [d.x, d.y, d.z, gap]
        })
        .collect();
    (areas, clips)
}

/// Groups of identical splats: each splat's representative (the group's first splat) and, for
/// a representative, how many splats its group holds. Identical splats have the same Morton
/// code, so a group lies in one leaf's own range.
struct Duplicates {
    rep: Vec<u32>,
    count: Vec<u32>,
}

impl Duplicates {
    fn new(splats: &[Splat], splat_leaf: &[u32]) -> Duplicates {
        let n = splats.len();
        let key = |s: &Splat| -> [u32; 8] {
            let b = |x: f32| x.to_bits();
            [
                b(s.position[0]),
                b(s.position[1]),
                b(s.position[2]),
                b(s.normal[0]),
                b(s.normal[1]),
                b(s.normal[2]),
                b(s.radius),
                s.material,
            ]
        };
        // The leaves' own ranges: runs of the same owner (the data pool is in leaf order).
        let mut runs = Vec::new();
        let mut start = 0;
        for i in 1..=n {
            if i == n || splat_leaf[i] != splat_leaf[start] {
                runs.push(start..i);
                start = i;
            }
        }
        let groups: Vec<Vec<(u32, u32)>> = runs
            .into_par_iter()
            .filter(|r| r.len() > 1)
            .map(|r| {
                let mut idx: Vec<u32> = (r.start as u32..r.end as u32).collect();
                idx.sort_by_key(|&i| (key(&splats[i as usize]), i));
                let mut out = Vec::new();
                let mut g = 0;
                while g < idx.len() {
                    let k = key(&splats[idx[g] as usize]);
                    let mut e = g + 1;
                    while e < idx.len() && key(&splats[idx[e] as usize]) == k {
                        e += 1;
                    }
                    for &i in &idx[g + 1..e] {
                        out.push((i, idx[g]));
                    }
                    g = e;
                }
                out
            })
            .collect();
        let mut rep: Vec<u32> = (0..n as u32).collect();
        let mut count = vec![1u32; n];
        for (i, r) in groups.into_iter().flatten() {
            rep[i as usize] = r;
            count[r as usize] += 1;
        }
        Duplicates { rep, count }
    }

    /// Whether splat `i` is its group's representative (computed, not copied).
    #[inline]
    fn is_rep(&self, i: u32) -> bool {
        self.rep[i as usize] == i
    }

    /// How many splats splat `j`'s group counts where it covers a point (0 for a member that is
    /// not its group's representative, so that a list counts each group once).
    #[inline]
    fn weight(&self, j: u32) -> u32 {
        if self.is_rep(j) {
            self.count[j as usize]
        } else {
            0
        }
    }

    /// `per_splat` (computed for the representatives) with every member given its
    /// representative's value.
    fn spread<T: Copy>(&self, mut per_splat: Vec<T>) -> Vec<T> {
        for (i, &r) in self.rep.iter().enumerate() {
            if r as usize != i {
                per_splat[i] = per_splat[r as usize];
            }
        }
        per_splat
    }
}

/// What one partition-of-unity pass over the disks needs.
struct AreaPass<'a> {
    frame: &'a Frame,
    nodes: &'a [u32],
    begin_end: &'a [u32],
    splats: &'a [Splat],
    splat_leaf: &'a [u32],
    dups: &'a Duplicates,
    leaf_depth: &'a [u8],
    pattern: Vec<(f32, f32)>,
    dirs: [(f32, f32); BORDER_DIRS],
}

impl AreaPass<'_> {
    fn leaf_list(&self, w: u32) -> (std::ops::Range<u32>, &[u32]) {
        match pc_artifact::octree::BeginEnd::leaf(self.begin_end, node::ptr(w)) {
            Some((b, e, r)) => (b..e, r),
            None => (0..0, &[]),
        }
    }

    /// The disks of the same surface that can cover some point of disk i (i included).
    fn near(&self, i: usize, near: &mut Vec<u32>) {
        let s = &self.splats[i];
        let c = Vec3::from(s.position);
        let n = Vec3::from(s.normal);
        let (own, refs) = self.leaf_list(self.nodes[self.splat_leaf[i] as usize]);
        near.clear();
        for j in own.chain(refs.iter().copied()) {
            if !self.dups.is_rep(j) {
                continue;
            }
            let o = &self.splats[j as usize];
            let reach = s.radius + o.radius;
            if o.material == s.material
                && Vec3::from(o.normal).dot(n) >= 0.5
                && (Vec3::from(o.position) - c).length_squared() <= reach * reach * 1.25
            {
                near.push(j);
            }
        }
    }

    /// The same-surface splats whose centres lie within √1.25 · 2r_i of splat i (i included):
    /// the own splats of every leaf the query box reaches (a leaf's reference list only holds
    /// the disks that reach that leaf's cell, which would cut neighbourhoods at cell walls).
    fn neighbourhood(&self, i: usize, out: &mut Vec<u32>) {
        let s = &self.splats[i];
        let c = Vec3::from(s.position);
        let n = Vec3::from(s.normal);
        let reach = 2.0 * s.radius * 1.25f32.sqrt();
        let q = |p: Vec3| (p - Vec3::from(self.frame.origin)) * self.frame.inv_size;
        let (bmin, bmax) = (q(c - Vec3::splat(reach)), q(c + Vec3::splat(reach)));
        out.clear();
        let mut stack = [(0u32, Vec3::ZERO, 0.0f32); 8 * 22];
        stack[0] = (0, Vec3::ZERO, 1.0);
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let (slot, lo, size) = stack[top];
            let w = self.nodes[slot as usize];
            if w & node::EMPTY != 0 {
                continue;
            }
            if w & node::LEAF != 0 {
                let (own, _) = self.leaf_list(w);
                for j in own.filter(|&j| self.dups.is_rep(j)) {
                    let o = &self.splats[j as usize];
                    let d = Vec3::from(o.position) - c;
                    if o.material == s.material
                        && Vec3::from(o.normal).dot(n) >= 0.5
                        && d.length_squared() <= reach * reach
                        && d.dot(n).abs() <= 0.5 * reach
                    {
                        out.push(j);
                    }
                }
                continue;
            }
            push_children_in_box(w, lo, size, bmin, bmax, &mut stack, &mut top);
        }
    }

    /// Half the local sample spacing, g_i = ½√(estimate of the area per splat around i).
    fn spacing(&self, areas: &[f32], estimate: impl Fn(&[u32], &[f32]) -> f32 + Sync) -> Vec<f32> {
        (0..self.splats.len())
            .into_par_iter()
            .map_init(Vec::new, |near: &mut Vec<u32>, i| {
                if !self.dups.is_rep(i as u32) {
                    return 0.0; // the representative's, spread afterwards
                }
                self.neighbourhood(i, near);
                0.5 * estimate(near, areas).max(0.0).sqrt()
            })
            .collect()
    }

    /// Each splat's border status. Direction k is open when no same-surface neighbour's
    /// offset projects more than the half spacing onto it (a smaller offset is the jitter of
    /// the border row, not more surface). One arc of open directions is a stretch of border
    /// (or a corner) whose outward direction is the arc's middle.
    fn borders(&self, gap: &[f32]) -> Vec<Border> {
        (0..self.splats.len())
            .into_par_iter()
            .map_init(Vec::new, |near: &mut Vec<u32>, i| {
                if !self.dups.is_rep(i as u32) {
                    return Border::Interior; // the representative's, spread afterwards
                }
                self.neighbourhood(i, near);
                let s = &self.splats[i];
                let (u, v) = tangent_frame(s.normal);
                let (u, v, c) = (Vec3::from(u), Vec3::from(v), Vec3::from(s.position));
                let mut reach = [0.0f32; BORDER_DIRS];
                for &j in near.iter() {
                    let d = Vec3::from(self.splats[j as usize].position) - c;
                    let (a, b) = (d.dot(u), d.dot(v));
                    for (hk, &(ck, sk)) in reach.iter_mut().zip(&self.dirs) {
                        *hk = hk.max(a * ck + b * sk);
                    }
                }
                let g = gap[i];
                let mask = reach
                    .iter()
                    .enumerate()
                    .filter(|(_, &h)| h < g)
                    .fold(0u32, |m, (k, _)| m | 1 << k);
                border_from_mask(mask, g)
            })
            .collect()
    }

    /// Whether a splat's share reaches the point at (p, q) in its own tangent frame.
    #[inline]
    fn accepts(&self, border: Border, p: f32, q: f32) -> bool {
        match border {
            Border::Interior => true,
            Border::Edge { a, b, gap } => p * a + q * b <= gap,
            Border::Open { mask, gap } => (0..BORDER_DIRS)
                .filter(|k| mask >> k & 1 != 0)
                .all(|k| p * self.dirs[k].0 + q * self.dirs[k].1 <= gap),
        }
    }

    /// One partition-of-unity pass; `borders` clips the border splats' shares.
    fn run(&self, borders: Option<&[Border]>) -> Vec<f32> {
        let origin = Vec3::from(self.frame.origin);
        let inv_size = self.frame.inv_size;
        (0..self.splats.len())
            .into_par_iter()
            .map_init(Vec::new, |near: &mut Vec<u32>, i| {
                if !self.dups.is_rep(i as u32) {
                    return 0.0; // the representative's, spread afterwards
                }
                let s = &self.splats[i];
                let c = Vec3::from(s.position);
                let n = Vec3::from(s.normal);
                let owner = self.splat_leaf[i];
                let depth = self.leaf_depth[owner as usize] as u32;
                let scale = (1u32 << depth) as f32;
                let cell = ((c - origin) * inv_size * scale).floor();
                self.near(i, near);
                let (u, v) = tangent_frame(s.normal);
                let (u, v) = (Vec3::from(u), Vec3::from(v));
                let border = borders.map_or(Border::Interior, |b| b[i]);
                let mut acc = 0.0f32;
                for &(a, b) in &self.pattern {
                    let x = c + (u * a + v * b) * s.radius;
                    // The sample's tangent coordinates are (a, b) · radius by construction.
                    if !self.accepts(border, a * s.radius, b * s.radius) {
                        continue;
                    }
                    let q = (x - origin) * inv_size;
                    let weight = |j: u32| {
                        if covers(&self.splats[j as usize], x, n, s.material) {
                            self.dups.weight(j)
                        } else {
                            0
                        }
                    };
                    let cover: u32 = if (q * scale).floor() == cell {
                        near.iter().map(|&j| weight(j)).sum()
                    } else if q.cmpge(Vec3::ZERO).all() && q.cmplt(Vec3::ONE).all() {
                        let loc = locate_normalized(self.nodes, q);
                        if node::is_leaf(loc.node) {
                            let (own, refs) = self.leaf_list(loc.node);
                            own.chain(refs.iter().copied()).map(weight).sum()
                        } else {
                            0
                        }
                    } else {
                        0
                    };
                    acc += 1.0 / cover.max(1) as f32;
                }
                std::f32::consts::PI * s.radius * s.radius * acc / self.pattern.len() as f32
            })
            .collect()
    }
}

/// The middle (an angle in the tangent frame) of the longest run of open directions, or None
/// when every direction is open (an isolated splat) or none is.
fn longest_arc(mask: u32) -> Option<f32> {
    if mask == 0 || mask == ALL_DIRS {
        return None;
    }
    let (mut best, mut best_len) = (0usize, 0usize);
    for start in 0..BORDER_DIRS {
        let prev = (start + BORDER_DIRS - 1) % BORDER_DIRS;
        if mask >> start & 1 == 0 || mask >> prev & 1 != 0 {
            continue;
        }
        let len = (0..BORDER_DIRS)
            .take_while(|k| mask >> ((start + k) % BORDER_DIRS) & 1 != 0)
            .count();
        if len > best_len {
            (best, best_len) = (start, len);
        }
    }
    Some((best as f32 + (best_len as f32 - 1.0) * 0.5) * std::f32::consts::TAU / BORDER_DIRS as f32)
}

/// Border status from the mask of open directions (bit k: direction k is open).
fn border_from_mask(mask: u32, gap: f32) -> Border {
    if mask == 0 {
        return Border::Interior;
    }
    // One run of open directions (an open direction whose predecessor is closed starts a run):
    // a stretch of border or a corner, whose outward direction is the run's middle.
    let starts = mask & !mask.rotate_left(1);
    match longest_arc(mask) {
        Some(mid) if starts.count_ones() == 1 => Border::Edge {
            a: mid.cos(),
            b: mid.sin(),
            gap,
        },
        // Several runs (a strip one or two samples wide) or all open (an isolated splat).
        _ => Border::Open { mask, gap },
    }
}

#[inline]
fn covers(o: &Splat, x: Vec3, n: Vec3, material: u32) -> bool {
    if o.material != material {
        return false;
    }
    let d = x - Vec3::from(o.position);
    let d2 = d.length_squared();
    let r2 = o.radius * o.radius;
    // |h| <= r/2 and in-plane distance <= r imply |d|² <= 1.25 r²: the cheap test first.
    if d2 > 1.25 * r2 {
        return false;
    }
    let on = Vec3::from(o.normal);
    if on.dot(n) < 0.5 {
        return false;
    }
    let h = d.dot(on);
    h.abs() <= 0.5 * o.radius && d2 - h * h <= r2
}

/// Average disk (Fig. 13), normal, area, count and class of the splats of one node, and for
/// leaves the normal field of §8.5.5.
fn node_info(splats: &[Splat], areas: &[f32], material_class: &[u32], is_leaf: bool) -> NodeInfo {
    let total: f32 = areas.iter().sum();
    let weight = |i: usize| if total > 0.0 { areas[i] } else { 1.0 };
    let wsum: f32 = (0..splats.len()).map(weight).sum();
    let centroid = splats
        .iter()
        .enumerate()
        .map(|(i, s)| Vec3::from(s.position) * weight(i))
        .sum::<Vec3>()
        / wsum;
    let nsum = splats
        .iter()
        .enumerate()
        .map(|(i, s)| Vec3::from(s.normal) * weight(i))
        .sum::<Vec3>();
    let normal = if nsum.length() > 1e-3 * wsum {
        nsum.normalize()
    } else {
        Vec3::ZERO
    };
    let disk_radius = splats
        .iter()
        .map(|s| (Vec3::from(s.position) - centroid).length() + s.radius)
        .fold(0.0f32, f32::max);
    let c0 = material_class[splats[0].material as usize];
    let cls = if splats
        .iter()
        .all(|s| material_class[s.material as usize] == c0)
    {
        c0
    } else {
        class::MIXED
    };
    let tilt = if is_leaf && normal != Vec3::ZERO {
        normal_field(splats, centroid, normal)
    } else {
        [0.0; 2]
    };
    NodeInfo {
        centroid: centroid.into(),
        disk_radius,
        normal: normal.into(),
        area: total,
        tilt,
        count: splats.len() as u32,
        class: cls,
    }
}

/// Least-squares tilt factors (ν, ω) of the linear normal field n(x) = n̄ + ν ((x − c)·û) û +
/// ω ((x − c)·v̂) v̂ over a leaf's average disk (§8.5.5 with u_j = r û, v_j = r v̂, the disk
/// radius cancels). Each axis is an independent one-unknown least-squares problem:
/// ν = Σ d_u (n_l·û) / (Σ d_u² + λ), d_u = (p_l − c)·û, with a small ridge term λ (below).
/// For a sphere of radius R, ν = ω ≈ 1/R.
pub fn normal_field(splats: &[Splat], c: Vec3, n: Vec3) -> [f32; 2] {
    let (u, v) = tangent_frame(n.into());
    let (u, v) = (Vec3::from(u), Vec3::from(v));
    let (mut nu_num, mut nu_den, mut om_num, mut om_den) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for s in splats {
        let d = Vec3::from(s.position) - c;
        let nl = Vec3::from(s.normal);
        let (du, dv) = (d.dot(u) as f64, d.dot(v) as f64);
        nu_num += du * nl.dot(u) as f64;
        nu_den += du * du;
        om_num += dv * nl.dot(v) as f64;
        om_den += dv * dv;
    }
    // Ridge regularisation towards a flat field: a leaf whose points spread along one direction
    // only (a row of splats) leaves the other factor undetermined, and a plain quotient of two
    // tiny sums would tilt the normal arbitrarily. λ is 2 % of the splats' mean squared
    // radius per splat: negligible once the points spread over a few radii.
    let mean_r2 = splats
        .iter()
        .map(|s| (s.radius as f64).powi(2))
        .sum::<f64>()
        / splats.len().max(1) as f64;
    let lambda = 0.02 * mean_r2 * splats.len() as f64;
    let solve = |num: f64, den: f64| {
        if den + lambda > 1e-30 {
            (num / (den + lambda)) as f32
        } else {
            0.0
        }
    };
    [solve(nu_num, nu_den), solve(om_num, om_den)]
}
