//! Octree artifact schema: the GPU node pool of seed §8.5.10-§8.5.13 as plain little-endian sections.
//!
//! Every record here is `#[repr(C)]`, `Pod`, and laid out so that the section can be bound as a
//! WGSL storage buffer as it is (`vec3<f32>` followed by a scalar fills 16 bytes). The WGSL twins
//! live in `shaders/common/octree.wgsl`; a test in pc-octree checks the sizes and offsets match.
//!
//! Sections of an `octree` artifact:
//!
//! | name         | element        | meaning |
//! |--------------|----------------|---------|
//! | `nodes`      | `u32`          | node pool: 32-bit nodes, the 8 children of a node contiguous, in Morton (SFC) order |
//! | `begin_end`  | `u32`          | the begin/end table of §8.5.12-§8.5.13 (Fig. 27), see [`BeginEnd`] |
//! | `splats`     | [`Splat`]      | the data pool: splat records sorted by Morton code of their centre |
//! | `node_info`  | [`NodeInfo`]   | per node-pool slot: average disk, normal field, area, count, class |
//! | `splat_area` | `f32`          | per data-pool splat: the surface area the splat stands for |
//! | `splat_leaf` | `u32`          | per data-pool splat: node-pool index of the leaf that owns it |
//! | `materials`  | [`MaterialRecord`] | the material table that `Splat::material` indexes |
//! | `frame`      | [`Frame`]      | one record: the root cube and the tree parameters |

use std::path::Path;

use bytemuck::{Pod, Zeroable};

use crate::reader::{first_where, Checked};
use crate::{Artifact, ArtifactError, ArtifactKind, Key};

/// Section names of an octree artifact.
pub mod sections {
    pub const NODES: &str = "nodes";
    pub const BEGIN_END: &str = "begin_end";
    pub const SPLATS: &str = "splats";
    pub const NODE_INFO: &str = "node_info";
    pub const SPLAT_AREA: &str = "splat_area";
    pub const SPLAT_LEAF: &str = "splat_leaf";
    pub const MATERIALS: &str = "materials";
    pub const FRAME: &str = "frame";
}

/// Node pool encoding (seed §8.5.10, Fig. 21): 30 bits of pointer and 2 flag bits.
///
/// * internal node: flags `00`, pointer = node-pool index of the first of its 8 children;
/// * leaf: `LEAF` set, pointer = offset of the leaf's `beginP` entry in the begin/end table;
/// * empty node: `EMPTY` set, pointer 0. An empty cell that a splat disk reaches into is not
///   empty: it becomes a leaf with no own splats and only references (see docs/octree.md).
pub mod node {
    pub const LEAF: u32 = 1 << 31;
    pub const EMPTY: u32 = 1 << 30;
    pub const PTR_MASK: u32 = (1 << 30) - 1;
    /// Largest node-pool index or begin/end offset a node can hold.
    pub const MAX_PTR: u32 = PTR_MASK;

    #[inline]
    pub const fn internal(first_child: u32) -> u32 {
        first_child & PTR_MASK
    }
    #[inline]
    pub const fn leaf(begin_end_offset: u32) -> u32 {
        LEAF | (begin_end_offset & PTR_MASK)
    }
    pub const EMPTY_NODE: u32 = EMPTY;
    #[inline]
    pub const fn is_leaf(n: u32) -> bool {
        n & LEAF != 0
    }
    #[inline]
    pub const fn is_empty(n: u32) -> bool {
        n & EMPTY != 0
    }
    #[inline]
    pub const fn ptr(n: u32) -> u32 {
        n & PTR_MASK
    }
}

/// Reading the begin/end table (seed §8.5.13, Fig. 27).
///
/// For a leaf whose node holds offset `o`:
/// `table[o]` = beginP (first own splat in the data pool), `table[o + 1]` = E (number of
/// referenced splats from neighbouring leaves), `table[o + 2 .. o + 2 + E]` = their data-pool
/// indices, and `table[o + 2 + E]` = endP, which is also the next leaf's beginP. The table ends
/// with one sentinel entry holding the data-pool length. Leaves are laid out in SFC order, so
/// own splat ranges are contiguous and consecutive.
pub struct BeginEnd;

impl BeginEnd {
    /// The offset of each leaf's entry, in table (SFC) order: the walk over a table that
    /// [`OctreeView::check`] has passed (the packed walk's leaves follow this order).
    pub fn offsets(table: &[u32]) -> impl Iterator<Item = u32> + '_ {
        let mut o = 0usize;
        std::iter::from_fn(move || {
            (o + 2 < table.len()).then(|| {
                let at = o;
                o += 2 + table[o + 1] as usize;
                at as u32
            })
        })
    }

    /// Own splat range `[begin, end)` and the referenced splats of the leaf at `offset`.
    /// Returns `None` when the offset or the counts run outside the table.
    #[inline]
    pub fn leaf(table: &[u32], offset: u32) -> Option<(u32, u32, &[u32])> {
        let o = offset as usize;
        let begin = *table.get(o)?;
        let extra = *table.get(o + 1)? as usize;
        let refs = table.get(o + 2..o + 2 + extra)?;
        let end = *table.get(o + 2 + extra)?;
        Some((begin, end, refs))
    }
}

/// Material classes. Diffuse and specular splats never share a leaf (§8.5.1).
pub mod class {
    pub const DIFFUSE: u32 = 0;
    pub const EMITTER: u32 = 1;
    pub const MIRROR: u32 = 2;
    pub const DIELECTRIC: u32 = 3;
    /// `NodeInfo::class` of an empty node.
    pub const NONE: u32 = 0xFF;
    /// `NodeInfo::class` of an internal node whose subtree mixes classes.
    pub const MIXED: u32 = 0xFE;

    /// Specular classes are traced by rays; the others hold radiosity.
    #[inline]
    pub const fn is_specular(c: u32) -> bool {
        c == MIRROR || c == DIELECTRIC
    }
}

/// One splat of the data pool: 64 bytes, four `vec4`s (seed §8.5.12 packs 44 bytes in 3 texels;
/// the fourth is the border clip, a departure described in docs/octree.md).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Splat {
    pub position: [f32; 3],
    pub radius: f32,
    /// Unit normal; the surface's front side.
    pub normal: [f32; 3],
    /// Index into the `materials` section.
    pub material: u32,
    /// Per-point linear RGB color from the PLY, or (1, 1, 1). The effective albedo /
    /// reflectance / tint is `MaterialRecord::color * albedo`, so a material's color can change
    /// without rebuilding the octree.
    pub albedo: [f32; 3],
    /// Index of the splat in the imported scene (models concatenated in config order).
    pub source: u32,
    /// Border clip: the splat stands for the points x of its disk with `(x − position) · o_k ≤
    /// clip.w` for its two clip lines o_1, o_2 ([`clip_lines`]). At a surface's open border (a
    /// wall's edge, a box's convex edge, the light's rim) `clip.w` is half the local sample
    /// spacing and `clip.xyz` points outward in the splat's plane: a unit vector on a straight
    /// stretch (the two lines coincide), and at a corner the corner's apex over `clip.w`, of
    /// length 1 / cos φ where ±φ turn the two lines' normals away from it. Elsewhere it is all
    /// zero (the whole disk). docs/octree.md, "Borders".
    pub clip: [f32; 4],
}

impl Splat {
    /// Whether the point `x` of the splat's plane lies on the splat's side of its border clip.
    #[inline]
    pub fn within_clip(&self, x: [f32; 3]) -> bool {
        within_clip(self.position, self.normal, self.clip, x)
    }

    /// A point of the disk's plane mirrored across the clip lines it lies beyond: a point
    /// sampled on the disk lands on the splat's kept part (a cut-off cap mirrors inside the
    /// disk, since each line is at least as far out as the centre). At a corner sharper than a
    /// right angle one fold can push the point past the other line, so the folds repeat (three
    /// rounds at most; the WGSL twin is `fold_into_clip` in shaders/common/octree.wgsl).
    #[inline]
    pub fn fold_into_clip(&self, x: [f32; 3]) -> [f32; 3] {
        let lines = clip_lines(self.normal, self.clip);
        let (c, g) = (self.position, self.clip[3]);
        let mut y = x;
        for _ in 0..3 {
            let mut moved = false;
            for o in lines {
                let e = dot3(sub3(y, c), o) - g;
                if e > 0.0 {
                    y = std::array::from_fn(|k| y[k] - 2.0 * e * o[k]);
                    moved = true;
                }
            }
            if !moved {
                break;
            }
        }
        y
    }
}

#[inline(always)]
fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
fn sub3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The unit outward normals of a splat's two clip lines, from its normal `n` and its `clip`
/// (`Splat::clip`): `clip.xyz = q`, |q| = 1 / cos φ, o_{1,2} = q̂ cos φ ± (n × q̂) sin φ. Zero
/// vectors for an interior splat (whose `clip.w` is zero too, so every point passes). The
/// WGSL twin is `clip_lines` in shaders/common/octree.wgsl.
#[inline(always)]
pub fn clip_lines(n: [f32; 3], clip: [f32; 4]) -> [[f32; 3]; 2] {
    let q = [clip[0], clip[1], clip[2]];
    let s2 = dot3(q, q);
    if s2 == 0.0 {
        return [[0.0; 3]; 2];
    }
    let cos = 1.0 / s2.sqrt();
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    // q̂ cos φ = q cos² φ and (n × q̂) sin φ = (n × q) cos φ sin φ.
    let t = [
        n[1] * q[2] - n[2] * q[1],
        n[2] * q[0] - n[0] * q[2],
        n[0] * q[1] - n[1] * q[0],
    ];
    let (a, b) = (cos * cos, cos * sin);
    [
        std::array::from_fn(|k| q[k] * a + t[k] * b),
        std::array::from_fn(|k| q[k] * a - t[k] * b),
    ]
}

/// The `clip` of a border splat whose two clip lines have the unit outward normals `o1` and
/// `o2` (in its plane; equal on a straight stretch) and the offset `gap`: the inverse of
/// [`clip_lines`]. The lines turn at most [`MAX_CLIP_TURN`] away from their middle.
pub fn encode_clip(o1: [f32; 3], o2: [f32; 3], gap: f32) -> [f32; 4] {
    let m = [o1[0] + o2[0], o1[1] + o2[1], o1[2] + o2[2]];
    let len = dot3(m, m).sqrt();
    if len == 0.0 || gap.is_nan() || gap <= 0.0 {
        return [0.0; 4];
    }
    let m = m.map(|x| x / len);
    let cos = dot3(m, o1).clamp(MAX_CLIP_TURN.cos(), 1.0);
    [m[0] / cos, m[1] / cos, m[2] / cos, gap]
}

/// The largest angle between a clip line's normal and the middle of the two (a corner of 10°).
pub const MAX_CLIP_TURN: f32 = 85.0 * std::f32::consts::PI / 180.0;

/// `(x − c) · o_k ≤ clip.w` for both clip lines ([`clip_lines`]) of the splat at `c` with
/// normal `n`: the border clip test shared by every CPU intersection.
#[inline(always)]
pub fn within_clip(c: [f32; 3], n: [f32; 3], clip: [f32; 4], x: [f32; 3]) -> bool {
    let [o1, o2] = clip_lines(n, clip);
    let d = sub3(x, c);
    dot3(d, o1) <= clip[3] && dot3(d, o2) <= clip[3]
}

/// Per node-pool slot: the average disk of Fig. 13 and the normal field of §8.5.5.
///
/// For empty slots everything is zero and `class == class::NONE`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct NodeInfo {
    /// Area-weighted centroid of the splat centres in the node (the average disk's centre).
    pub centroid: [f32; 3],
    /// Average-disk radius: max over the node's splats of |centroid - centre| + radius (Fig. 13).
    pub disk_radius: f32,
    /// Area-weighted average normal, normalised; zero when the normals cancel out.
    pub normal: [f32; 3],
    /// Sum of the splat areas (`splat_area`) of the node's own splats.
    pub area: f32,
    /// Normal-field tilt factors ν, ω of §8.5.5 (leaves only; zero elsewhere), along
    /// [`tangent_frame`]`(normal)` scaled by `disk_radius`.
    pub tilt: [f32; 2],
    /// Number of splats the node owns (its subtree's, for internal nodes).
    pub count: u32,
    /// Material class (`class::*`), `MIXED` for an internal node over several classes.
    pub class: u32,
}

/// A material as the renderer and solvers need it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MaterialRecord {
    /// Albedo (diffuse, emitter), reflectance (mirror) or tint (dielectric), linear RGB.
    pub color: [f32; 3],
    /// One of `class::*`.
    pub class: u32,
    /// Emitted radiance (emitters), linear RGB; zero for the others.
    pub radiance: [f32; 3],
    /// Index of refraction (dielectric); 1 otherwise.
    pub ior: f32,
    /// Phong highlight exponent of specular materials; 0 = no highlight.
    pub phong: f32,
    /// 1 when the albedo comes per point from the PLY colors.
    pub per_point_color: u32,
    pub _pad: [u32; 2],
}

/// The root cube and tree parameters (one record).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Frame {
    /// Minimum corner of the root cube.
    pub origin: [f32; 3],
    /// Edge length of the root cube.
    pub size: f32,
    /// 1 / size, used for the point-location descent so CPU and GPU round the same way.
    pub inv_size: f32,
    /// Deepest level of any leaf (root = 0).
    pub depth: u32,
    /// Maximum depth the build allowed.
    pub max_depth: u32,
    /// k, the maximum number of own splats per leaf (unless at maximum depth).
    pub max_leaf_points: u32,
    pub node_count: u32,
    pub leaf_count: u32,
    pub splat_count: u32,
    pub ref_count: u32,
}

/// The tangent frame (u, v) of a unit normal used for the normal field and for the splat's
/// bounding square (§8.5.5, §8.5.13): deterministic, orthonormal, `v = n × u`.
///
/// Duff et al. 2017, "Building an Orthonormal Basis, Revisited" (branchless, continuous except
/// at n.z = -1 where the sign switches). The WGSL twin is `tangent_frame` in
/// `shaders/common/octree.wgsl`.
#[inline]
pub fn tangent_frame(n: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let sign = if n[2] >= 0.0 { 1.0f32 } else { -1.0 };
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    let u = [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]];
    // v = n × u
    let v = [
        n[1] * u[2] - n[2] * u[1],
        n[2] * u[0] - n[0] * u[2],
        n[0] * u[1] - n[1] * u[0],
    ];
    (u, v)
}

/// What an octree build produced, besides its sections (pc-octree's build returns it, the
/// artifact's metadata stores it, pc-inspect prints it).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct OctreeStats {
    pub splats: u64,
    pub nodes: u64,
    pub leaves: u64,
    pub empty_nodes: u64,
    /// Leaves without own splats that exist only because neighbouring disks reach into them.
    pub ref_leaves: u64,
    /// Splat references added to leaves other than the owner (§8.5.13).
    pub extra_refs: u64,
    pub depth: u32,
    /// Leaves at the maximum depth that still exceed k or mix classes.
    pub leaves_at_max_depth: u64,
    /// Wall-clock seconds per build phase, in order.
    pub timings: Vec<(String, f64)>,
}

/// Metadata stored with an octree artifact (MessagePack).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct OctreeMeta {
    /// The pipeline.toml that described the scene, as given.
    pub config: String,
    /// Input PLY files with their content hashes.
    pub inputs: Vec<InputFile>,
    pub params: crate::params::OctreeParams,
    pub stats: OctreeStats,
    pub material_names: Vec<String>,
    pub dropped_points: u64,
    /// The point of the models' own (georeferenced) frame at the scene's origin: a splat at
    /// `p` is at `origin + p` in the input files' coordinates, in f64.
    #[serde(default)]
    pub origin: [f64; 3],
}

/// One input file of a stage, for provenance.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct InputFile {
    pub path: String,
    pub bytes: u64,
    pub hash: String,
}

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

/// Borrowed sections of an octree (from a mapped artifact or built in memory). Every stage
/// that walks the tree reads it through this view; pc-tree adds the traversals.
///
/// Point location is the `p·N − int(p·N)` descent of seed §8.5.11, written so that the WGSL
/// twin in `shaders/common/octree.wgsl` rounds exactly the same way: the normalised coordinate
/// is `(p − origin) · inv_size` (one correctly rounded subtraction and multiplication per
/// axis), and each step `t = 2q; c = floor(t); q = t − c` is exact in binary floating point.
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
    /// The packed walk pc-octree wrote beside the tree, when the artifact holds one of this
    /// build's layout (crate::walk); `None` for a tree in memory.
    pub walk: Option<crate::walk::WalkView<'a>>,
}

impl<'a> OctreeView<'a> {
    /// The sections of an octree artifact, cast but not yet checked ([`OctreeView::check`]).
    fn sections(a: &'a Artifact) -> Result<OctreeView<'a>, ArtifactError> {
        let frame = *a
            .section::<Frame>(sections::FRAME)?
            .first()
            .ok_or_else(|| a.invalid("the `frame` section is empty"))?;
        Ok(OctreeView {
            frame,
            nodes: a.section(sections::NODES)?,
            begin_end: a.section(sections::BEGIN_END)?,
            splats: a.section(sections::SPLATS)?,
            node_info: a.section(sections::NODE_INFO)?,
            splat_area: a.section(sections::SPLAT_AREA)?,
            splat_leaf: a.section(sections::SPLAT_LEAF)?,
            walk: crate::walk::WalkView::sections(a)?,
        })
    }

    /// Structural checks (every pointer in bounds, the begin/end table consistent, the frame
    /// finite), so traversals can index without panicking; the message says what is wrong.
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
        let f = &self.frame;
        if !(f.size > 0.0
            && f.size.is_finite()
            && f.inv_size.is_finite()
            && f.origin.iter().all(|x| x.is_finite()))
            || f.splat_count as u64 != n_splats
        {
            return Err("frame record disagrees with the sections".into());
        }
        if f.max_depth > 21 {
            return Err(format!("max depth {} exceeds 21", f.max_depth));
        }
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        // A clip is zero, or points outward at most MAX_CLIP_TURN from both lines, with a
        // positive offset (a looser bound for the rounding of the encoded length).
        let max_len = 1.001 / MAX_CLIP_TURN.cos();
        let splat_ok = |s: &Splat| {
            finite(&s.position)
                && finite(&s.normal)
                && finite(&s.albedo)
                && finite(&s.clip)
                && s.radius.is_finite()
                && s.radius > 0.0
        };
        let clip_ok = |s: &Splat| {
            let q2 = s.clip[0] * s.clip[0] + s.clip[1] * s.clip[1] + s.clip[2] * s.clip[2];
            s.clip == [0.0; 4] || (q2 >= 0.998 && q2 <= max_len * max_len && s.clip[3] > 0.0)
        };
        // (Each check over the records runs in parallel, one pass over the splats for both of
        // theirs; the first bad record is named.)
        if let Some(i) = first_where(self.splats, |_, s| !(splat_ok(s) && clip_ok(s))) {
            let s = &self.splats[i];
            return Err(match splat_ok(s) {
                false => {
                    format!("splat {i} has a non-finite value or a radius that is not positive")
                }
                true => format!(
                    "splat {i}'s border clip {:?} is neither zero nor an outward direction of \
                     length 1 to {max_len:.2} with a positive offset",
                    s.clip
                ),
            });
        }
        if let Some(i) = first_where(self.node_info, |_, n| {
            !(finite(&n.centroid)
                && finite(&n.normal)
                && finite(&n.tilt)
                && n.disk_radius.is_finite()
                && n.area.is_finite())
        }) {
            return Err(format!("node {i}'s statistics are not finite"));
        }
        if let Some(i) = first_where(self.splat_area, |_, a| !(a.is_finite() && *a >= 0.0)) {
            return Err(format!("splat {i}'s area is negative or not finite"));
        }
        let starts = self.leaf_table_starts()?;
        let bad_node = |i: usize, &w: &u32| {
            if node::is_empty(w) {
                // An empty node is exactly the empty word: no pointer, not also a leaf.
                return w != node::EMPTY_NODE;
            }
            if node::is_leaf(w) {
                return !starts.get(node::ptr(w) as usize).is_some_and(|&s| s);
            }
            let c = node::ptr(w) as usize;
            c == 0 || c + 8 > n_nodes || !(c - 1).is_multiple_of(8) || c <= i
        };
        if let Some(i) = first_where(self.nodes, bad_node) {
            let w = self.nodes[i];
            let c = node::ptr(w);
            return Err(match (node::is_empty(w), node::is_leaf(w)) {
                (true, _) => format!("node {i} is not a valid node word ({w:#010x})"),
                (_, true) => format!("leaf {i} does not point at a leaf of the begin/end table"),
                _ => format!("node {i} points at children {c}, outside the pool or not a group"),
            });
        }
        let stray = |s: usize, &l: &u32| {
            !self
                .nodes
                .get(l as usize)
                .is_some_and(|&w| node::is_leaf(w) && self.leaf(w).0.contains(&(s as u32)))
        };
        if let Some(s) = first_where(self.splat_leaf, stray) {
            let l = self.splat_leaf[s];
            return Err(format!(
                "splat_leaf names node {l} for splat {s}, not the leaf that owns it"
            ));
        }
        match &self.walk {
            Some(w) => w.check(self),
            None => Ok(()),
        }
    }

    /// The begin/end table is a chain of leaves, `begin, extra, refs…` each, closed by the
    /// last leaf's end: each leaf's end is the next one's begin, so the own ranges partition
    /// the data pool in order (the first begins at 0, the last ends at the splat count) and
    /// references name splats. Returns which table offsets start a leaf (the packed lists of
    /// pc-tree's `Accel` are indexed by them).
    fn leaf_table_starts(&self) -> Result<Vec<bool>, String> {
        let t = self.begin_end;
        let n_splats = self.splats.len() as u64;
        let bad = |o: usize, what: &str| Err(format!("begin/end table at {o}: {what}"));
        let mut starts = vec![false; t.len()];
        if t.first() != Some(&0) {
            return bad(0, "the first leaf does not begin at splat 0");
        }
        let mut o = 0usize;
        while o + 2 < t.len() {
            let next = o + 2 + t[o + 1] as usize;
            if next >= t.len() {
                return bad(o, "the references run past the table");
            }
            if t[o] > t[next] {
                return bad(o, "the leaf ends before it begins");
            }
            starts[o] = true;
            o = next;
        }
        if o + 1 != t.len() || t[o] as u64 != n_splats {
            return bad(o, "the table does not close with the splat count");
        }
        // Each leaf's references name splats (checked in parallel; the first leaf is named).
        let foreign = first_where(&starts, |o, &start| {
            start && {
                let next = o + 2 + t[o + 1] as usize;
                t[o + 2..next].iter().any(|&r| r as u64 >= n_splats)
            }
        });
        if let Some(o) = foreign {
            return bad(o, "a reference names no splat");
        }
        Ok(starts)
    }

    /// Normalised coordinate of `p` in the root cube, `None` outside `[0, 1)³`.
    #[inline]
    pub fn normalized(&self, p: [f32; 3]) -> Option<[f32; 3]> {
        let q: [f32; 3] =
            std::array::from_fn(|k| (p[k] - self.frame.origin[k]) * self.frame.inv_size);
        q.iter().all(|c| (0.0..1.0).contains(c)).then_some(q)
    }

    /// The leaf or empty node containing `p` (seed §8.5.11); `None` outside the root cube.
    #[inline]
    pub fn locate(&self, p: impl Into<[f32; 3]>) -> Option<Located> {
        let q = self.normalized(p.into())?;
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
pub fn locate_normalized(nodes: &[u32], q: impl Into<[f32; 3]>) -> Located {
    descend_normalized(nodes, q, u32::MAX)
}

/// [`locate_normalized`], stopping at depth `max_depth` where the node there is internal.
#[inline]
pub fn descend_normalized(nodes: &[u32], q: impl Into<[f32; 3]>, max_depth: u32) -> Located {
    let mut q = q.into();
    let mut slot = 0u32;
    let mut depth = 0u32;
    loop {
        let w = nodes[slot as usize];
        if w & (node::LEAF | node::EMPTY) != 0 || depth == max_depth {
            return Located {
                slot,
                node: w,
                depth,
            };
        }
        let mut child = 0u32;
        for (k, c) in q.iter_mut().enumerate() {
            let t = *c * 2.0;
            let f = t.floor();
            *c = t - f;
            child |= (f as u32) << k;
        }
        slot = node::ptr(w) + child;
        depth += 1;
    }
}

/// The octree a downstream artifact must have been made from: what the readers of the V-map,
/// the photon map and the radiosity check their own artifact against.
#[derive(Clone, Copy, Debug)]
pub struct OctreeId<'a> {
    pub path: &'a Path,
    pub key: Key,
    pub nodes: usize,
    pub splats: usize,
}

/// An opened octree artifact, checked once: the kind, every section's size and structure
/// ([`OctreeView::check`]), the metadata and the material table.
pub type OctreeFile = Checked<OctreeMeta>;

impl Checked<OctreeMeta> {
    /// Open and check the octree artifact at `path`. A missing file is
    /// [`ArtifactError::MissingInput`] (run pc-octree).
    pub fn open(path: impl AsRef<Path>) -> Result<OctreeFile, ArtifactError> {
        OctreeFile::from_artifact(Artifact::open_input(path, ArtifactKind::Octree)?)
    }

    /// Like [`open`](Self::open) for a reader that casts no rays (pc-bake): the packed walk's
    /// sections (crate::walk) are neither checksummed nor handed out, the view has no walk.
    /// At the 100M-point scan they are 8 of the file's 14 GB.
    pub fn open_without_walk(path: impl AsRef<Path>) -> Result<OctreeFile, ArtifactError> {
        let tree = [
            sections::FRAME,
            sections::NODES,
            sections::BEGIN_END,
            sections::SPLATS,
            sections::NODE_INFO,
            sections::SPLAT_AREA,
            sections::SPLAT_LEAF,
            sections::MATERIALS,
        ];
        let art = Artifact::open_input_sections(path, ArtifactKind::Octree, &tree)?;
        OctreeFile::from_artifact(art)
    }

    /// Check an artifact opened already (of any kind: another is [`ArtifactError::WrongKind`]).
    pub fn from_artifact(art: Artifact) -> Result<OctreeFile, ArtifactError> {
        art.ensure_kind(ArtifactKind::Octree)?;
        OctreeView::sections(&art)?
            .check()
            .map_err(|m| art.invalid(m))?;
        let meta: OctreeMeta = art.metadata()?;
        let materials: &[MaterialRecord] = art.section(sections::MATERIALS)?;
        if materials.len() != meta.material_names.len() {
            return Err(art.invalid(format!(
                "{} material records for {} material names",
                materials.len(),
                meta.material_names.len()
            )));
        }
        if let Some(i) = materials.iter().position(|m| {
            let finite = m.color.iter().chain(&m.radiance).all(|x| x.is_finite());
            let known = matches!(
                m.class,
                class::DIFFUSE | class::EMITTER | class::MIRROR | class::DIELECTRIC
            );
            !(finite && m.ior.is_finite() && m.ior > 0.0 && m.phong.is_finite() && known)
        }) {
            return Err(art.invalid(format!("material {i} is not a valid material record")));
        }
        let view = OctreeView::sections(&art)?;
        if let Some(i) = view
            .splats
            .iter()
            .position(|s| s.material as usize >= materials.len())
        {
            return Err(art.invalid(format!(
                "splat {i} names material {} of {}",
                view.splats[i].material,
                materials.len()
            )));
        }
        Ok(OctreeFile { art, meta })
    }

    /// The checked sections.
    pub fn view(&self) -> OctreeView<'_> {
        OctreeView::sections(&self.art).expect("the sections were checked when the file was opened")
    }

    /// The material table the octree was built with (one record per `meta().material_names`).
    pub fn materials(&self) -> &[MaterialRecord] {
        self.art
            .section(sections::MATERIALS)
            .expect("the materials were checked when the file was opened")
    }

    /// What downstream artifacts must have been made from.
    pub fn id(&self) -> OctreeId<'_> {
        let v = self.view();
        OctreeId {
            path: self.path(),
            key: self.key(),
            nodes: v.nodes.len(),
            splats: v.splats.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_sizes_are_gpu_friendly() {
        assert_eq!(std::mem::size_of::<Splat>(), 64);
        assert_eq!(std::mem::size_of::<NodeInfo>(), 48);
        assert_eq!(std::mem::size_of::<MaterialRecord>(), 48);
        assert_eq!(std::mem::size_of::<Frame>(), 48);
    }

    #[test]
    fn tangent_frame_is_orthonormal() {
        for n in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, 0.0],
            [0.6, 0.0, -0.8],
            [0.0, -1.0, 0.0],
        ] {
            let (u, v) = tangent_frame(n);
            let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            assert!(dot(u, n).abs() < 1e-6 && dot(v, n).abs() < 1e-6 && dot(u, v).abs() < 1e-6);
            assert!((dot(u, u) - 1.0).abs() < 1e-6 && (dot(v, v) - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn begin_end_reads_fig27_layout() {
        // leaf A: own [0,3), refs {7, 9}; leaf B: own [3,5), no refs; sentinel 5.
        let t = [0, 2, 7, 9, 3, 0, 5];
        assert_eq!(BeginEnd::leaf(&t, 0), Some((0, 3, &[7u32, 9][..])));
        assert_eq!(BeginEnd::leaf(&t, 4), Some((3, 5, &[][..])));
        assert_eq!(BeginEnd::leaf(&t, 6), None);
    }
}
