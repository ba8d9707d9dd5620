//! The octree build: root cube, Morton sort, level-by-level adaptive split, node pool, leaf
//! references (§8.5.13), begin/end table, per-node statistics and normal fields.
//!
//! Every phase is a parallel pass (rayon) over splats or over the nodes of one level; the only
//! sequential work is a prefix sum per level to place the child groups. See docs/octree.md.

use std::time::Instant;

use glam::Vec3;
use pc_artifact::octree::{class, node, Frame, NodeInfo, OctreeStats, Splat};
use pc_artifact::params::OctreeParams;
use pc_tree::OctreeView;
use rayon::prelude::*;

use crate::area::splat_areas;
use crate::morton;
use crate::refs::{overlapped_cells, CellStack};
use crate::stats::node_info;

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
            walk: None,
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
    // The input lends its arrays: nothing to free early.
    build_from(*input, |i| *i, params, phase)
}

/// [`build`] from an input that `owner` holds (`input` lends it), freed as soon as the splats
/// are in the data pool: the rest of the build reads the pool alone. A scanned scene's arrays
/// are 44 bytes a splat, about a fifth of the build's peak.
pub fn build_from<T>(
    owner: T,
    input: for<'a> fn(&'a T) -> BuildInput<'a>,
    params: &OctreeParams,
    phase: &mut dyn FnMut(&str),
) -> Result<Octree, BuildError> {
    let tree = tree_from(owner, input, params, phase)?;
    let surfaces = tree.surfaces(params, phase);
    Ok(tree.finish(surfaces))
}

/// The first half of [`build_from`]: the [`Tree`], every section but those the splats' areas
/// decide. pc-octree writes its sections while [`Tree::surfaces`] runs.
pub fn tree_from<T>(
    owner: T,
    input: for<'a> fn(&'a T) -> BuildInput<'a>,
    params: &OctreeParams,
    phase: &mut dyn FnMut(&str),
) -> Result<Tree, BuildError> {
    let mut phases = Phases::new(phase);
    let pooled = pool(&input(&owner), params, &mut phases)?;
    drop(owner);
    tree(pooled, phases)
}

/// The build up to the data pool: what the rest of it reads.
struct Pooled {
    frame: Frame,
    split: Split,
    /// The splats in Morton order, and each one's leaf slot.
    splats: Vec<Splat>,
    splat_leaf: Vec<u32>,
    material_class: Vec<u32>,
}

/// Bounds, Morton order, the split into nodes and the data pool.
fn pool(
    input: &BuildInput,
    params: &OctreeParams,
    phases: &mut Phases,
) -> Result<Pooled, BuildError> {
    check_input(input, params)?;
    let n = input.positions.len();
    phases.start("bounds");
    let frame = root_frame(input, params)?;
    phases.start("morton sort");
    let sorted = morton_sort(input, &frame);
    phases.start("split");
    let mut split = split(&sorted, params)?;
    phases.start("data pool");
    let splats = data_pool(input, &sorted.order);
    let mut splat_leaf = vec![0u32; n];
    for l in &split.leaves {
        splat_leaf[l.lo as usize..l.hi as usize].fill(l.slot);
        // Marked now (the pointer is filled in with the table) so the reference walk can tell
        // leaves from internal nodes.
        split.nodes[l.slot as usize] = node::LEAF;
    }
    Ok(Pooled {
        frame,
        split,
        splats,
        splat_leaf,
        material_class: input.material_class.to_vec(),
    })
}

/// The octree before its splats' areas: the node pool, the begin/end table, the data pool
/// (border clips not yet set) and each splat's leaf, which is all the walk's packed copy reads
/// ([`Tree::walk_view`]). [`Tree::surfaces`] computes the rest without changing any of it, so
/// these sections can be written while it runs.
pub struct Tree {
    pub frame: Frame,
    split: Split,
    pub begin_end: Vec<u32>,
    /// Clips zero until [`Tree::finish`].
    splats: Vec<Splat>,
    pub splat_leaf: Vec<u32>,
    material_class: Vec<u32>,
    leaves: u64,
    ref_leaves: u64,
    extra_refs: u64,
    timings: Vec<(String, f64)>,
}

/// What the splats' areas decide: the areas, the border clips and the node statistics.
pub struct Surfaces {
    splat_area: Vec<f32>,
    clips: Vec<[f32; 4]>,
    node_info: Vec<NodeInfo>,
    timings: Vec<(String, f64)>,
}

/// Leaf references and the begin/end table: the [`Tree`] of the pooled splats.
fn tree(p: Pooled, mut phases: Phases) -> Result<Tree, BuildError> {
    let Pooled {
        mut frame,
        mut split,
        splats,
        splat_leaf,
        material_class,
    } = p;
    phases.start("leaf references");
    let refs = leaf_references(&frame, &split.nodes, &splats, &splat_leaf);
    phases.start("begin/end table");
    let table = begin_end_table(&mut split, &refs, splats.len())?;
    frame.depth = split.spans.iter().map(|s| s.depth).max().unwrap_or(0);
    frame.node_count = split.nodes.len() as u32;
    frame.leaf_count = table.leaves as u32;
    frame.ref_count = refs.len() as u32;
    Ok(Tree {
        frame,
        split,
        begin_end: table.begin_end,
        splats,
        splat_leaf,
        material_class,
        leaves: table.leaves,
        ref_leaves: table.ref_leaves,
        extra_refs: refs.len() as u64,
        timings: phases.finish(),
    })
}

impl Tree {
    /// The node pool (leaf words point at their begin/end entries).
    pub fn nodes(&self) -> &[u32] {
        &self.split.nodes
    }

    /// The tree as a view for building the walk's packed copy
    /// ([`pc_tree::accel::Accel::build`]), which reads the nodes, the table and the splats'
    /// centres, normals and radii alone: the view has no node statistics and no areas yet, and
    /// its splats no border clips.
    pub fn walk_view(&self) -> OctreeView<'_> {
        OctreeView {
            frame: self.frame,
            nodes: &self.split.nodes,
            begin_end: &self.begin_end,
            splats: &self.splats,
            node_info: &[],
            splat_area: &[],
            splat_leaf: &self.splat_leaf,
            walk: None,
        }
    }

    /// The splats' areas and border clips, then the node statistics (docs/octree.md, "Splat
    /// area"); `phase` hears of each.
    pub fn surfaces(&self, params: &OctreeParams, phase: &mut dyn FnMut(&str)) -> Surfaces {
        let mut phases = Phases::new(phase);
        phases.start("splat areas");
        let (splat_area, clips) = splat_areas(
            &self.frame,
            &self.split.nodes,
            &self.begin_end,
            &self.splats,
            &self.splat_leaf,
            params.area_samples,
        );
        phases.start("node statistics");
        // The statistics read the splats' centres, normals, radii and areas, not their clips.
        let node_info = node_statistics(
            &self.split,
            &self.begin_end,
            &self.splats,
            &splat_area,
            &self.material_class,
        );
        Surfaces {
            splat_area,
            clips,
            node_info,
            timings: phases.finish(),
        }
    }

    /// The octree: the tree with `surfaces` (made by [`Tree::surfaces`] of this tree).
    pub fn finish(self, surfaces: Surfaces) -> Octree {
        let Tree {
            frame,
            split,
            begin_end,
            mut splats,
            splat_leaf,
            mut timings,
            ..
        } = self;
        assert_eq!(
            (surfaces.clips.len(), surfaces.node_info.len()),
            (splats.len(), split.nodes.len()),
            "the surfaces of another tree"
        );
        for (s, clip) in splats.iter_mut().zip(surfaces.clips) {
            s.clip = clip;
        }
        timings.extend(surfaces.timings);
        let stats = OctreeStats {
            splats: splats.len() as u64,
            nodes: split.nodes.len() as u64,
            leaves: self.leaves,
            empty_nodes: split.empties.len() as u64 - self.ref_leaves,
            ref_leaves: self.ref_leaves,
            extra_refs: self.extra_refs,
            depth: frame.depth,
            leaves_at_max_depth: split.leaves_at_max_depth,
            timings,
        };
        Octree {
            frame,
            nodes: split.nodes,
            begin_end,
            splats,
            node_info: surfaces.node_info,
            splat_area: surfaces.splat_area,
            splat_leaf,
            stats,
        }
    }
}

/// The build's phases: announces each as it starts and times it.
struct Phases<'a> {
    announce: &'a mut dyn FnMut(&str),
    current: Option<(String, Instant)>,
    timings: Vec<(String, f64)>,
}

impl<'a> Phases<'a> {
    fn new(announce: &'a mut dyn FnMut(&str)) -> Phases<'a> {
        Phases {
            announce,
            current: None,
            timings: Vec::new(),
        }
    }

    /// Ends the running phase, if any, and starts `name`.
    fn start(&mut self, name: &str) {
        self.end();
        (self.announce)(name);
        self.current = Some((name.to_string(), Instant::now()));
    }

    fn end(&mut self) {
        if let Some((name, t)) = self.current.take() {
            self.timings.push((name, t.elapsed().as_secs_f64()));
        }
    }

    /// Ends the running phase; each phase's seconds, in order.
    fn finish(&mut self) -> Vec<(String, f64)> {
        self.end();
        std::mem::take(&mut self.timings)
    }
}

/// The input's arrays agree in length, name existing materials, and fit the node format; the
/// parameters are in range.
fn check_input(input: &BuildInput, params: &OctreeParams) -> Result<(), BuildError> {
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
    Ok(())
}

/// The root cube: the splats' disks' bounding box, made a cube with a small margin so every
/// normalised coordinate lies strictly inside [0, 1). Non-finite positions, radii that are not
/// positive, and boxes beyond f32 arithmetic are errors.
fn root_frame(input: &BuildInput, params: &OctreeParams) -> Result<Frame, BuildError> {
    let n = input.positions.len();
    if let Some(i) = (0..n).into_par_iter().find_first(|&i| {
        !(input.positions[i].is_finite() && input.radii[i].is_finite() && input.radii[i] > 0.0)
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
    Ok(Frame {
        origin: origin.into(),
        size,
        inv_size,
        max_depth: params.max_depth,
        max_leaf_points: params.max_leaf_points,
        splat_count: n as u32,
        ..Default::default()
    })
}

/// The splats in Morton order: their codes, their input indices, their purity keys.
struct Sorted {
    codes: Vec<u64>,
    order: Vec<u32>,
    purity: Vec<u32>,
}

fn morton_sort(input: &BuildInput, frame: &Frame) -> Sorted {
    let (origin, inv_size) = (Vec3::from(frame.origin), frame.inv_size);
    let mut keyed: Vec<(u64, u32)> = (0..input.positions.len())
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
    Sorted {
        codes,
        order,
        purity,
    }
}

/// The node pool after the adaptive split: internal nodes point at their children; leaves and
/// empty nodes are marked later.
struct Split {
    nodes: Vec<u32>,
    /// Every non-empty node.
    spans: Vec<Span>,
    leaves: Vec<Span>,
    /// Empty cells: (slot, position in Morton order).
    empties: Vec<(u32, u32)>,
    /// Leaves that still hold more than k splats or mix materials, stopped by the depth limit.
    leaves_at_max_depth: u64,
}

/// Whether the splats of `s` mix purity keys (a leaf must not, §8.5.1).
fn impure(purity: &[u32], s: &Span) -> bool {
    let p = &purity[s.lo as usize..s.hi as usize];
    p.iter().any(|&x| x != p[0])
}

/// The adaptive split, level by level (§8.5.1): a node is split while it holds more than k
/// splats or mixes purity keys, down to the depth limit. The children of one level are found
/// in parallel by binary search in the Morton codes; placing their groups in the pool is a
/// sequential pass per level.
fn split(sorted: &Sorted, params: &OctreeParams) -> Result<Split, BuildError> {
    let (codes, purity) = (&sorted.codes, &sorted.purity);
    let k = params.max_leaf_points;
    let mut out = Split {
        nodes: vec![0],
        spans: Vec::new(),
        leaves: Vec::new(),
        empties: Vec::new(),
        leaves_at_max_depth: 0,
    };
    let mut level = vec![Span {
        slot: 0,
        lo: 0,
        hi: codes.len() as u32,
        depth: 0,
    }];
    while !level.is_empty() {
        let splits: Vec<Option<[u32; 9]>> = level
            .par_iter()
            .map(|s| {
                let count = s.hi - s.lo;
                if s.depth >= params.max_depth || (count <= k && !impure(purity, s)) {
                    return None;
                }
                let c = &codes[s.lo as usize..s.hi as usize];
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
            out.spans.push(*s);
            let Some(b) = split else {
                if s.depth >= params.max_depth && (s.hi - s.lo > k || impure(purity, s)) {
                    out.leaves_at_max_depth += 1;
                }
                out.leaves.push(*s);
                continue;
            };
            let base = out.nodes.len() as u64;
            if base + 8 > node::MAX_PTR as u64 {
                return Err(BuildError::TooLarge {
                    what: "nodes",
                    need: base + 8,
                    max: node::MAX_PTR as u64,
                });
            }
            out.nodes[s.slot as usize] = node::internal(base as u32);
            out.nodes.extend_from_slice(&[0; 8]);
            for c in 0..8 {
                let slot = base as u32 + c as u32;
                if b[c] == b[c + 1] {
                    out.nodes[slot as usize] = node::EMPTY_NODE;
                    out.empties.push((slot, b[c]));
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
        level = next;
    }
    Ok(out)
}

/// The data pool: the splats in Morton order (clips are filled in by the area pass).
fn data_pool(input: &BuildInput, order: &[u32]) -> Vec<Splat> {
    order
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
        .collect()
}

/// §8.5.13: every leaf or empty cell a disk reaches, other than its own leaf, references it.
/// (cell slot, splat) pairs, sorted.
fn leaf_references(
    frame: &Frame,
    nodes: &[u32],
    splats: &[Splat],
    splat_leaf: &[u32],
) -> Vec<(u32, u32)> {
    // Each block of splats' (cell, splat) pairs, in splat order.
    const BLOCK: usize = 1 << 14;
    let blocks: Vec<Vec<(u32, u32)>> = (0..splats.len().div_ceil(BLOCK))
        .into_par_iter()
        .map_init(CellStack::new, |stack, b| {
            let mut acc = Vec::new();
            for s in (b * BLOCK) as u32..((b + 1) * BLOCK).min(splats.len()) as u32 {
                overlapped_cells(
                    frame,
                    nodes,
                    &splats[s as usize],
                    splat_leaf[s as usize],
                    stack,
                    &mut |slot| acc.push((slot, s)),
                );
            }
            acc
        })
        .collect();
    by_cell(&blocks, nodes.len())
}

/// The pairs of `blocks` (each block's in splat order, the blocks in order) sorted by cell and
/// then splat: a counting sort by cell that keeps the splat order, the same vector a sort of
/// the pairs gives (a comparison sort of the 45M pairs of the 20M hall scan took most of the
/// phase).
fn by_cell(blocks: &[Vec<(u32, u32)>], cells: usize) -> Vec<(u32, u32)> {
    let mut start = vec![0u32; cells + 1];
    for &(slot, _) in blocks.iter().flatten() {
        start[slot as usize + 1] += 1;
    }
    for c in 0..cells {
        start[c + 1] += start[c];
    }
    let total = start[cells] as usize;
    let mut out = vec![(0u32, 0u32); total];
    for &(slot, s) in blocks.iter().flatten() {
        let at = &mut start[slot as usize];
        out[*at as usize] = (slot, s);
        *at += 1;
    }
    out
}

/// The begin/end table and how many leaves it lists.
struct Table {
    begin_end: Vec<u32>,
    /// Leaves in the table: the split's, and the empty cells that became leaves.
    leaves: u64,
    /// Empty cells a disk reaches into, now leaves with references only.
    ref_leaves: u64,
}

/// The begin/end table (§8.5.12-13): the leaves in SFC order, each `begin, count, refs…`, the
/// last closed by the splat count; leaf node words now point at their entry. Empty cells that a
/// disk reaches into become leaves with references only.
fn begin_end_table(split: &mut Split, refs: &[(u32, u32)], n: usize) -> Result<Table, BuildError> {
    // (begin, end, slot): sorted, a reference-only leaf comes before the leaf that owns the
    // splats from its position on.
    let mut all_leaves: Vec<(u32, u32, u32)> =
        split.leaves.iter().map(|l| (l.lo, l.hi, l.slot)).collect();
    let mut sorted_empties = split.empties.clone();
    sorted_empties.sort_unstable();
    let mut r = 0;
    let mut ref_leaves = 0u64;
    for &(slot, at) in &sorted_empties {
        while r < refs.len() && refs[r].0 < slot {
            r += 1;
        }
        if r < refs.len() && refs[r].0 == slot {
            all_leaves.push((at, at, slot));
            ref_leaves += 1;
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
    // Each cell's run of references, from one pass over the sorted pairs (two binary searches
    // per leaf, each a chain of cache misses, took a second at 20M points).
    // (The table's length, refs included, fits a node pointer: checked above.)
    let mut runs = vec![(0u32, 0u32); split.nodes.len()];
    let mut start = 0;
    for k in 1..=refs.len() {
        if k == refs.len() || refs[k].0 != refs[start].0 {
            runs[refs[start].0 as usize] = (start as u32, k as u32);
            start = k;
        }
    }
    let mut begin_end = Vec::with_capacity(table_len as usize);
    for &(lo, _, slot) in &all_leaves {
        let (first, last) = runs[slot as usize];
        let (first, last) = (first as usize, last as usize);
        split.nodes[slot as usize] = node::leaf(begin_end.len() as u32);
        begin_end.push(lo);
        begin_end.push((last - first) as u32);
        begin_end.extend(refs[first..last].iter().map(|r| r.1));
    }
    begin_end.push(n as u32);
    Ok(Table {
        begin_end,
        leaves: all_leaves.len() as u64,
        ref_leaves,
    })
}

/// Per-node average disk, normal, area and class; normal fields of leaves (§8.5.5), fitted
/// over each leaf's listed disks (`begin_end`: its own, then those it references). Empty nodes
/// get class `NONE`.
fn node_statistics(
    split: &Split,
    begin_end: &[u32],
    splats: &[Splat],
    splat_area: &[f32],
    material_class: &[u32],
) -> Vec<NodeInfo> {
    let infos: Vec<(u32, NodeInfo)> = split
        .spans
        .par_iter()
        .map(|s| {
            let range = s.lo as usize..s.hi as usize;
            let word = split.nodes[s.slot as usize];
            let referenced = match node::is_leaf(word) {
                true => pc_artifact::octree::BeginEnd::leaf(begin_end, node::ptr(word))
                    .map_or(&[][..], |(_, _, refs)| refs),
                false => &[],
            };
            let info = node_info(
                (&splats[range.clone()], referenced, splats),
                &splat_area[range],
                material_class,
                node::is_leaf(word),
            );
            (s.slot, info)
        })
        .collect();
    let mut node_info = vec![
        NodeInfo {
            class: class::NONE,
            ..Default::default()
        };
        split.nodes.len()
    ];
    for (slot, info) in infos {
        node_info[slot as usize] = info;
    }
    node_info
}
