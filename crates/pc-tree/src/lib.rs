//! Read-only view of an octree artifact and the queries every stage shares.
//!
//! The renderer, the V-map and the photon tracer all walk the same node pool; they do it
//! through this crate (shared code, not copies). Point location is the `p·N − int(p·N)` descent
//! of seed §8.5.11, written so that the WGSL twin in `shaders/common/octree.wgsl` rounds
//! exactly the same way: the normalised coordinate is `(p − origin) · inv_size` (one correctly
//! rounded subtraction and multiplication per axis), and each step `t = 2q; c = floor(t);
//! q = t − c` is exact in binary floating point.

use glam::Vec3;
use pc_artifact::octree::{node, sections, tangent_frame, BeginEnd, Frame, NodeInfo, Splat};
use pc_artifact::{Artifact, ArtifactError};

pub mod accel;
pub mod caster;
pub mod gpu;
pub mod optics;
pub mod ray;
pub mod rng;
pub use ray::{intersect_splat, Hit, Ray, TraversalStats};

/// The node a point falls in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Located {
    /// Node-pool index of the leaf or empty node.
    pub slot: u32,
    /// The node word itself.
    pub node: u32,
    /// Its depth (root = 0).
    pub depth: u32,
}

/// Borrowed sections of an octree (from a mapped artifact or built in memory).
#[derive(Clone, Copy, Debug)]
pub struct OctreeView<'a> {
    pub frame: Frame,
    pub nodes: &'a [u32],
    pub begin_end: &'a [u32],
    pub splats: &'a [Splat],
    pub node_info: &'a [NodeInfo],
    pub splat_area: &'a [f32],
    /// Node-pool index of the leaf that owns each splat.
    pub splat_leaf: &'a [u32],
}

impl<'a> OctreeView<'a> {
    /// View the sections of an opened octree artifact and check the structure (every pointer
    /// in bounds, the begin/end table consistent) so traversals can index without panicking.
    pub fn from_artifact(a: &'a Artifact) -> Result<OctreeView<'a>, ArtifactError> {
        let frame = *a
            .section::<Frame>(sections::FRAME)?
            .first()
            .ok_or_else(|| a.invalid("the `frame` section is empty"))?;
        let view = OctreeView {
            frame,
            nodes: a.section(sections::NODES)?,
            begin_end: a.section(sections::BEGIN_END)?,
            splats: a.section(sections::SPLATS)?,
            node_info: a.section(sections::NODE_INFO)?,
            splat_area: a.section(sections::SPLAT_AREA)?,
            splat_leaf: a.section(sections::SPLAT_LEAF)?,
        };
        view.check().map_err(|m| a.invalid(m))?;
        Ok(view)
    }

    /// Structural checks; the message says what is wrong.
    pub fn check(&self) -> Result<(), String> {
        let n_nodes = self.nodes.len();
        let n_splats = self.splats.len() as u64;
        if n_nodes == 0 || !(n_nodes - 1).is_multiple_of(8) {
            return Err(format!("node pool has {n_nodes} nodes; expected 1 + 8·m"));
        }
        if self.node_info.len() != n_nodes {
            return Err(format!(
                "node_info has {} records for {n_nodes} nodes",
                self.node_info.len()
            ));
        }
        if self.splat_area.len() as u64 != n_splats || self.splat_leaf.len() as u64 != n_splats {
            return Err("splat_area / splat_leaf lengths differ from the data pool".into());
        }
        if !(self.frame.size > 0.0 && self.frame.size.is_finite())
            || self.frame.splat_count as u64 != n_splats
        {
            return Err("frame record disagrees with the sections".into());
        }
        if self.frame.max_depth > 21 {
            return Err(format!("max depth {} exceeds 21", self.frame.max_depth));
        }
        for (i, &w) in self.nodes.iter().enumerate() {
            if node::is_empty(w) {
                continue;
            }
            if node::is_leaf(w) {
                let (b, e, refs) = BeginEnd::leaf(self.begin_end, node::ptr(w))
                    .ok_or_else(|| format!("leaf {i} points outside the begin/end table"))?;
                if b > e || e as u64 > n_splats || refs.iter().any(|&r| r as u64 >= n_splats) {
                    return Err(format!("leaf {i} has an invalid splat range or reference"));
                }
            } else {
                let c = node::ptr(w) as usize;
                if c == 0 || c + 8 > n_nodes || !(c - 1).is_multiple_of(8) || c <= i {
                    return Err(format!(
                        "node {i} points at children {c}, outside the pool or not a group"
                    ));
                }
            }
        }
        if self
            .splat_leaf
            .iter()
            .any(|&s| s as usize >= n_nodes || !node::is_leaf(self.nodes[s as usize]))
        {
            return Err("splat_leaf names a node that is not a leaf".into());
        }
        Ok(())
    }

    /// Normalised coordinate of `p` in the root cube, `None` outside `[0, 1)³`.
    #[inline]
    pub fn normalized(&self, p: Vec3) -> Option<Vec3> {
        let q = (p - Vec3::from(self.frame.origin)) * self.frame.inv_size;
        (q.cmpge(Vec3::ZERO).all() && q.cmplt(Vec3::ONE).all()).then_some(q)
    }

    /// The leaf or empty node containing `p` (seed §8.5.11); `None` outside the root cube.
    #[inline]
    pub fn locate(&self, p: Vec3) -> Option<Located> {
        let q = self.normalized(p)?;
        Some(locate_normalized(self.nodes, q))
    }

    /// Own splat range and referenced splats of a leaf node word.
    #[inline]
    pub fn leaf(&self, node_word: u32) -> (std::ops::Range<u32>, &'a [u32]) {
        match BeginEnd::leaf(self.begin_end, node::ptr(node_word)) {
            Some((b, e, refs)) => (b..e, refs),
            None => (0..0, &[]),
        }
    }
}

/// The descent of §8.5.11 on a normalised coordinate `q ∈ [0,1)³`.
#[inline]
pub fn locate_normalized(nodes: &[u32], mut q: Vec3) -> Located {
    let mut slot = 0u32;
    let mut depth = 0u32;
    loop {
        let w = nodes[slot as usize];
        if w & (node::LEAF | node::EMPTY) != 0 {
            return Located {
                slot,
                node: w,
                depth,
            };
        }
        let t = q * 2.0;
        let c = t.floor();
        q = t - c;
        let child = c.x as u32 + 2 * c.y as u32 + 4 * c.z as u32;
        slot = node::ptr(w) + child;
        depth += 1;
    }
}

/// Axis-aligned box of the cell at `depth` with integer coordinates `cell` in the root frame.
pub fn cell_box(frame: &Frame, depth: u32, cell: [u32; 3]) -> (Vec3, Vec3) {
    let size = frame.size / (1u64 << depth) as f32;
    let lo =
        Vec3::from(frame.origin) + Vec3::new(cell[0] as f32, cell[1] as f32, cell[2] as f32) * size;
    (lo, lo + Vec3::splat(size))
}

/// The normal of a leaf's linear normal field (§8.5.5) at `x`, unit length. See
/// docs/octree.md: n(x) = normalize(n̄ + ν ((x − c)·û) û + ω ((x − c)·v̂) v̂).
pub fn field_normal(info: &NodeInfo, x: Vec3) -> Vec3 {
    let n = Vec3::from(info.normal);
    let (u, v) = tangent_frame(info.normal);
    let (u, v) = (Vec3::from(u), Vec3::from(v));
    let d = x - Vec3::from(info.centroid);
    (n + u * (info.tilt[0] * d.dot(u)) + v * (info.tilt[1] * d.dot(v))).normalize_or(n)
}

/// A point uniform on splat `s`'s disk for the random numbers `u1`, `u2` ∈ [0, 1), folded into
/// its border clip (so it lands on the part of the disk the splat stands for).
#[inline]
pub fn disk_point(s: &Splat, u1: f32, u2: f32) -> Vec3 {
    let (tu, tv) = tangent_frame(s.normal);
    let r = u1.sqrt() * s.radius;
    let phi = std::f32::consts::TAU * u2;
    let y = Vec3::from(s.position) + (Vec3::from(tu) * phi.cos() + Vec3::from(tv) * phi.sin()) * r;
    Vec3::from(s.fold_into_clip(y.into()))
}
