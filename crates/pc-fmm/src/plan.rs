//! The interaction plan: the V-map's links, refined until every directed interaction is one
//! the expansions can carry within the error targets (docs/fmm.md, "Interaction plan").
//!
//! A cluster is a node-pool slot or a single splat. For a directed pair (receiver A, source B)
//! with the link's visible fraction f:
//! - A and B are well separated when `(r_A + r_B) < θ |c_B − c_A|`; then the Taylor series
//!   converges and its truncation error is about `(1/θ)^{−(p+1)}` relative.
//! - The kernel's cosine clamps are smooth only while no pair changes side. From the normal
//!   cones and the cone of directions between the two bounding spheres, each side's cosine lies
//!   in `[lo, hi]`. `hi ≤ 0` on either side: every pair faces away, the interaction is exactly
//!   zero. `lo ≥ 0` on both sides: the clamps are inactive, the expansion is exact up to
//!   truncation. Otherwise the clamp error is bounded by `clamp_err` (a form factor bound) and
//!   accepted below `clamp_tol`; else the straddling side is split (a leaf into its splats).
//! - Pairs that are not well separated split the larger internal node; two leaves (or splats)
//!   that are not separated interact point to point.
//!
//! Accepted pairs become M2L (node ← node), P2L (node ← splat), M2P (splat ← node) or P2P
//! (splat range ← splat range) tasks, grouped by receiver so each is applied without atomics.
//! The refinement itself runs receiver by receiver from the root down (`Refiner::visit`), so
//! each receiver's tasks come out together.

use glam::Vec3;
use pc_artifact::vmap::Link;
use rayon::prelude::*;

use crate::par::Disjoint;
use crate::tree::{Points, Tree, NONE};

/// Flag of a cluster that is a single splat.
pub const POINT: u32 = 1 << 31;

/// Pairs closer than this many area-equivalent disk radii are always near field.
pub const NEAR_DISKS: f32 = 4.0;

/// Largest number of splat pairs a far interaction sums directly instead of through the
/// expansions: a splat against a node (M2P, P2L) costs about as much as 50 pairs of the exact
/// kernel at order 3, a node against a node (M2L) about 200 (docs/fmm.md, "Interaction plan").
pub const DIRECT_ONE_SIDED: u64 = 32;
pub const DIRECT_M2L: u64 = 128;

/// How many of its leaf's last tasks a new P2P task may merge with.
const MERGE_BACK: usize = 4;

/// Plan parameters.
#[derive(Clone, Copy, Debug)]
pub struct PlanParams {
    /// Expansion separation: well separated when (r_A + r_B) < theta · distance.
    pub theta: f32,
    /// Largest accepted clamp error of one interaction, as a form factor.
    pub clamp_tol: f32,
}

/// A node-receiver task: M2L when `src` is a slot, P2L when it carries [`POINT`].
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct NodeTask {
    pub src: u32,
    pub fraction: f32,
}

/// A leaf-receiver task: M2P (`recv_hi == 0`: splat `recv_lo` from node `src_lo`) or P2P
/// (splats `[recv_lo, recv_hi)` from splats `[src_lo, src_hi)`, a splat never from itself).
/// 20 bytes, no padding: on a large scan these are most of the stage's memory (the GPU gets
/// them regrouped, `crate::gpu_work::splat_tasks`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LeafTask {
    pub recv_lo: u32,
    pub recv_hi: u32,
    pub src_lo: u32,
    pub src_hi: u32,
    pub fraction: f32,
}

impl LeafTask {
    pub fn is_m2p(&self) -> bool {
        self.recv_hi == 0
    }
}

/// The tasks, grouped by receiver.
#[derive(Clone, Debug, Default)]
pub struct Plan {
    /// CSR over compact node indices.
    pub node_offsets: Vec<u32>,
    pub node_tasks: Vec<NodeTask>,
    /// CSR over compact leaf indices.
    pub leaf_offsets: Vec<u32>,
    pub leaf_tasks: Vec<LeafTask>,
    pub counts: TaskCounts,
    /// The separation the plan was refined for ([`PlanParams::theta`]).
    pub theta: f32,
}

/// How many tasks of each kind the plan holds, and how many splat pairs P2P covers.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct TaskCounts {
    pub m2l: u64,
    pub p2l: u64,
    pub m2p: u64,
    pub p2p: u64,
    pub p2p_pairs: u64,
    pub dropped_facing_away: u64,
}

/// What the refinement does with a pair ([`Refiner::verdict`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Verdict {
    /// One side faces away from the other whatever their points: no transfer.
    Drop,
    /// A task: the expansion (or, below a leaf, point to point) carries it.
    Accept,
    /// Hand the pair to the receiver's children.
    SplitReceiver,
    /// Refine against the source's children.
    SplitSource,
    /// Sum splat to splat.
    PointToPoint,
}

#[derive(Clone, Copy)]
struct Geo {
    c: Vec3,
    r: f32,
    /// Largest area-equivalent disk radius of the active splats.
    disk: f32,
    bmin: Vec3,
    bmax: Vec3,
    axis: Vec3,
    cone_cos: f32,
    /// `sin` of the normal cone's half-angle (`√(1 − cone_cos²)`, 1 past a hemisphere).
    cone_sin: f32,
    area: f32,
    /// Internal node (splits into children).
    internal: bool,
    point: bool,
}

/// Every slot's [`Geo`], packed: the refinement reads a node's geometry from one place
/// instead of nine arrays.
fn node_geos(t: &Tree, p: &Points) -> Vec<Geo> {
    (0..t.slots as u32)
        .into_par_iter()
        .map(|x| geo(t, p, x))
        .collect()
}

#[inline]
fn geo(t: &Tree, p: &Points, x: u32) -> Geo {
    if x & POINT != 0 {
        let i = (x & !POINT) as usize;
        Geo {
            c: Vec3::from(p.pos[i]),
            r: 0.0,
            disk: (p.area[i] * std::f32::consts::FRAC_1_PI).sqrt(),
            bmin: Vec3::from(p.pos[i]),
            bmax: Vec3::from(p.pos[i]),
            axis: Vec3::from(p.normal[i]),
            cone_cos: 1.0,
            cone_sin: 0.0,
            area: if p.active[i] { p.area[i] } else { 0.0 },
            internal: false,
            point: true,
        }
    } else {
        let s = x as usize;
        Geo {
            c: Vec3::from(t.center[s]),
            r: t.radius[s],
            disk: t.disk[s],
            bmin: Vec3::from(t.bmin[s]),
            bmax: Vec3::from(t.bmax[s]),
            axis: Vec3::from(t.axis[s]),
            cone_cos: t.cone_cos[s],
            cone_sin: {
                let c = t.cone_cos[s].clamp(-1.0, 1.0);
                (1.0 - c * c).max(0.0).sqrt()
            },
            area: t.area[s],
            internal: t.first_child[s] != NONE,
            point: false,
        }
    }
}

/// Range of splats of a cluster.
#[inline]
fn range(t: &Tree, x: u32) -> (u32, u32) {
    if x & POINT != 0 {
        let i = x & !POINT;
        (i, i + 1)
    } else {
        (t.lo[x as usize], t.hi[x as usize])
    }
}

/// Bounds `[lo, hi]` of `n · d̂` over a normal cone and a direction cone (axis `dir`, half-angle
/// with sine `spread_sin`, at most a right angle): `cos(max(0, ang − δ))` and
/// `cos(min(π, ang + δ))` with `ang` the angle between the axes and `δ` the two half-angles'
/// sum, by the angle-sum formulas (no trigonometric calls: the plan makes tens of millions).
/// `cone_sin` and `spread_cos` are the cosines' complements (`√(1 − c²)`), computed once per
/// node and per pair.
#[inline]
fn cos_bounds(
    axis: Vec3,
    cone_cos: f32,
    cone_sin: f32,
    dir: Vec3,
    spread_sin: f32,
    spread_cos: f32,
) -> (f32, f32) {
    if cone_cos <= -1.0 || axis == Vec3::ZERO {
        return (-1.0, 1.0);
    }
    let ca = axis.dot(dir).clamp(-1.0, 1.0);
    let sa = (1.0 - ca * ca).max(0.0).sqrt();
    let ch = cone_cos.clamp(-1.0, 1.0);
    let sh = cone_sin;
    let ss = spread_sin.clamp(0.0, 1.0);
    let cs = spread_cos;
    // δ = half + spread lies in [0, 3π/2]; past π every direction is possible.
    let cd = ch * cs - sh * ss;
    let sd = sh * cs + ch * ss;
    if sd < 0.0 {
        return (-1.0, 1.0);
    }
    let hi = if ca >= cd { 1.0 } else { ca * cd + sa * sd };
    let lo = if cd <= -ca { -1.0 } else { ca * cd - sa * sd };
    (lo, hi)
}

/// Tighter bounds of `n · d̂` from the bounding boxes: `d = x_j − x_i` with `x_i` in the box of
/// `g` and `x_j` in `to`, `n` within `g`'s normal cone (half-angle cosine `cone_cos` about
/// `axis`), and `dmin ≤ |d| ≤ dmax`. The box difference `[to.min − from.max, to.max −
/// from.min]` bounds `axis · d` exactly; the cone adds at most `sin(half) |d|`.
#[inline]
fn box_cos_bounds(g: &Geo, to: (Vec3, Vec3), (dmin, dmax): (f32, f32)) -> (f32, f32) {
    let (axis, cone_cos, cone_sin, from) = (g.axis, g.cone_cos, g.cone_sin, (g.bmin, g.bmax));
    // A cone wider than a hemisphere (c < 0) gives no bound this way.
    if cone_cos <= 0.0 || axis == Vec3::ZERO || dmin <= 0.0 {
        return (-1.0, 1.0);
    }
    let lo_d = to.0 - from.1;
    let hi_d = to.1 - from.0;
    let a = axis * lo_d;
    let b = axis * hi_d;
    let smin = a.min(b).element_sum();
    let smax = a.max(b).element_sum();
    let (c, s) = (cone_cos.clamp(-1.0, 1.0), cone_sin);
    let nlo = c * smin - s * dmax;
    let nhi = c * smax + s * dmax;
    let lo = if nlo >= 0.0 { nlo / dmax } else { nlo / dmin };
    let hi = if nhi >= 0.0 { nhi / dmin } else { nhi / dmax };
    (lo.max(-1.0), hi.min(1.0))
}

/// Tasks one worker found, each receiver's together: the node tasks and their runs `(compact
/// index, start, length)`, the leaf tasks and their runs `(compact leaf index, start, length)`;
/// and the interactions dropped as facing away.
#[derive(Default)]
struct Out {
    node: Vec<NodeTask>,
    leaf: Vec<LeafTask>,
    node_runs: Vec<(u32, u32, u32)>,
    leaf_runs: Vec<(u32, u32, u32)>,
    dropped: u64,
}

/// A pair waiting at a receiver: the source cluster and the link's visible fraction.
#[derive(Clone, Copy, Debug)]
struct Pending {
    src: u32,
    fraction: f32,
}

/// The V-map's links: CSR offsets per node-pool slot and the links.
type Links<'a> = (&'a [u32], &'a [Link]);

struct Refiner<'a> {
    t: &'a Tree,
    p: &'a Points,
    params: PlanParams,
    geos: Vec<Geo>,
}

impl Refiner<'_> {
    #[inline]
    fn geo(&self, x: u32) -> Geo {
        if x & POINT != 0 {
            geo(self.t, self.p, x)
        } else {
            self.geos[x as usize]
        }
    }

    /// Receiving splats of a cluster that take part (a cluster with none is skipped).
    fn receives(&self, x: u32) -> bool {
        if x & POINT != 0 {
            self.p.active[(x & !POINT) as usize]
        } else {
            self.t.active[x as usize] > 0
        }
    }

    fn split(&self, x: u32, out: &mut Vec<u32>) {
        out.clear();
        if x & POINT != 0 {
            return;
        }
        if self.t.first_child[x as usize] != NONE {
            out.extend(self.t.children(x));
        } else {
            let (lo, hi) = range(self.t, x);
            out.extend((lo..hi).map(|i| i | POINT));
        }
    }

    fn p2p(&self, a: u32, b: u32, f: f32, out: &mut Out) {
        let (rlo, rhi) = range(self.t, a);
        let (slo, shi) = range(self.t, b);
        let leaf = self.p.leaf[rlo as usize];
        // The same pairs as one task with one of the leaf's last few (a leaf split splat by
        // splat against one source, or one receiver against sibling leaves): fewer and fuller
        // tasks. (A leaf's tasks come in an order of their own, whatever the workers do.)
        let n = out.leaf.len();
        for q in out.leaf[n.saturating_sub(MERGE_BACK)..].iter_mut().rev() {
            let same_leaf = self.p.leaf[q.recv_lo as usize] == leaf;
            if same_leaf && !q.is_m2p() && q.fraction.to_bits() == f.to_bits() {
                if (q.src_lo, q.src_hi) == (slo, shi) {
                    if q.recv_hi == rlo {
                        q.recv_hi = rhi;
                        return;
                    }
                    if rhi == q.recv_lo {
                        q.recv_lo = rlo;
                        return;
                    }
                } else if (q.recv_lo, q.recv_hi) == (rlo, rhi) {
                    if q.src_hi == slo {
                        q.src_hi = shi;
                        return;
                    }
                    if shi == q.src_lo {
                        q.src_lo = slo;
                        return;
                    }
                }
            }
        }
        out.leaf.push(LeafTask {
            recv_lo: rlo,
            recv_hi: rhi,
            src_lo: slo,
            src_hi: shi,
            fraction: f,
        });
    }

    /// An accepted pair: an expansion task, or, when it is small and `a` receives as one leaf
    /// (or splat), point to point. Only there: a small pair at an internal receiver would become
    /// one task per leaf below it, and on a scan solved on clusters (leaves of a few elements)
    /// that multiplied the plan twentyfold (docs/fmm.md, "Interaction plan").
    fn accept(&self, a: u32, b: u32, f: f32, at_leaf: bool, out: &mut Out) {
        // An expansion costs about as much as summing a few dozen splat pairs exactly: small
        // far pairs are summed point to point instead.
        let count = |x: u32| {
            let (lo, hi) = range(self.t, x);
            (hi - lo) as u64
        };
        let limit = match (a & POINT != 0, b & POINT != 0) {
            (true, true) => 0,
            (true, false) | (false, true) => DIRECT_ONE_SIDED,
            (false, false) => DIRECT_M2L,
        };
        if at_leaf && count(a) * count(b) <= limit {
            self.p2p(a, b, f, out);
            return;
        }
        match (a & POINT != 0, b & POINT != 0) {
            (false, _) => out.node.push(NodeTask {
                src: b,
                fraction: f,
            }),
            (true, false) => out.leaf.push(LeafTask {
                recv_lo: a & !POINT,
                recv_hi: 0,
                src_lo: b,
                src_hi: 0,
                fraction: f,
            }),
            (true, true) => self.p2p(a, b, f, out),
        }
    }

    /// Refine every pair whose receiver is `a`: the pairs `inherited` from its parent (those
    /// that split the receiver) and its own links. Each pair is accepted as a task of `a`,
    /// dropped, split on the source side (refined here again), or handed to `a`'s children;
    /// then the children, in order. The tasks of one receiver come out together and in an order
    /// that does not depend on the workers: no sort by receiver afterwards.
    fn visit(&self, a: u32, inherited: &[Pending], links: Links, out: &mut Out) {
        let leaf0 = out.leaf.len();
        let Some(down) = self.refine_at(a, inherited, links, out) else {
            return;
        };
        // The children: the internal node's always (they have links of their own), a leaf's
        // splats only when pairs came down to them.
        let (internal, point) = (self.is_internal(a), a & POINT != 0);
        if internal || (!down.is_empty() && !point) {
            let mut kids = Vec::new();
            self.split(a, &mut kids);
            for &c in &kids {
                self.visit(c, &down, links, out);
            }
        }
        if !internal && !point {
            let n = out.leaf.len() - leaf0;
            if n > 0 {
                out.leaf_runs
                    .push((self.t.leaf_index[a as usize], leaf0 as u32, n as u32));
            }
        }
    }

    fn is_internal(&self, a: u32) -> bool {
        a & POINT == 0 && self.t.first_child[a as usize] != NONE
    }

    /// The pairs of receiver `a` (see [`Refiner::visit`]) refined: its tasks into `out`, and the
    /// pairs for its children returned (`None`: `a` receives nothing).
    fn refine_at(
        &self,
        a: u32,
        inherited: &[Pending],
        links: Links,
        out: &mut Out,
    ) -> Option<Vec<Pending>> {
        if !self.receives(a) {
            return None;
        }
        let node0 = out.node.len();
        let mut down: Vec<Pending> = Vec::new();
        let mut stack: Vec<Pending> = inherited.to_vec();
        if a & POINT == 0 {
            let (s, e) = (
                links.0[a as usize] as usize,
                links.0[a as usize + 1] as usize,
            );
            stack.extend(links.1[s..e].iter().rev().map(|l| Pending {
                src: l.slot(),
                fraction: l.fraction,
            }));
        }
        let mut kids = Vec::new();
        let ga = self.geo(a);
        let at_leaf = !ga.internal;
        while let Some(pd) = stack.pop() {
            let (b, f) = (pd.src, pd.fraction);
            let gb = self.geo(b);
            if gb.area <= 0.0 {
                continue;
            }
            if a == b {
                if ga.internal {
                    self.split(a, &mut kids);
                    down.extend(kids.iter().map(|&y| Pending {
                        src: y,
                        fraction: f,
                    }));
                } else {
                    self.p2p(a, b, f, out);
                }
                continue;
            }
            match self.verdict(&ga, &gb) {
                Verdict::Drop => out.dropped += 1,
                Verdict::Accept => self.accept(a, b, f, at_leaf, out),
                Verdict::SplitReceiver => down.push(pd),
                Verdict::SplitSource => {
                    self.split(b, &mut kids);
                    stack.extend(kids.iter().map(|&y| Pending { src: y, ..pd }));
                }
                Verdict::PointToPoint => self.p2p(a, b, f, out),
            }
        }
        if a & POINT == 0 {
            let n = out.node.len() - node0;
            if n > 0 {
                out.node_runs
                    .push((self.t.compact[a as usize], node0 as u32, n as u32));
            }
        }
        Some(down)
    }

    /// What to do with the pair (receiver `ga`, source `gb`), two distinct clusters of
    /// positive area.
    ///
    /// Not separated for the expansion (or too near a source disk for the point kernel to
    /// stand for it): split the larger internal side, else point to point. Separated: bound the
    /// cosines on both sides (their normal cones and the directions between the clusters, and
    /// their boxes); a side that faces away whatever the other drops the pair; both facing
    /// each other, or a clamp error within tolerance, accepts it; else split the side that
    /// straddles (below).
    fn verdict(&self, ga: &Geo, gb: &Geo) -> Verdict {
        let d = gb.c - ga.c;
        let dist = d.length();
        let sum_r = ga.r + gb.r;
        let far =
            sum_r < self.params.theta * dist && dist - sum_r >= NEAR_DISKS * ga.disk.max(gb.disk);
        if !far || dist <= 0.0 {
            return if ga.internal && (!gb.internal || ga.r >= gb.r) {
                Verdict::SplitReceiver
            } else if gb.internal {
                Verdict::SplitSource
            } else {
                Verdict::PointToPoint
            };
        }
        let dir = d / dist;
        let spread_sin = (sum_r / dist).min(1.0);
        let spread_cos = (1.0 - spread_sin * spread_sin).max(0.0).sqrt();
        let (dmin, dmax) = (dist - sum_r, dist + sum_r);
        let (ba, bb) = ((ga.bmin, ga.bmax), (gb.bmin, gb.bmax));
        let (lo_a, hi_a) = cos_bounds(
            ga.axis,
            ga.cone_cos,
            ga.cone_sin,
            dir,
            spread_sin,
            spread_cos,
        );
        let (lo_a2, hi_a2) = box_cos_bounds(ga, bb, (dmin, dmax));
        let (lo_a, hi_a) = (lo_a.max(lo_a2), hi_a.min(hi_a2));
        if hi_a <= 0.0 {
            // The receivers face away whatever the source: no need for its side.
            return Verdict::Drop;
        }
        let (lo_b, hi_b) = cos_bounds(
            gb.axis,
            gb.cone_cos,
            gb.cone_sin,
            -dir,
            spread_sin,
            spread_cos,
        );
        let (lo_b2, hi_b2) = box_cos_bounds(gb, ba, (dmin, dmax));
        let (lo_b, hi_b) = (lo_b.max(lo_b2), hi_b.min(hi_b2));
        if hi_b <= 0.0 {
            return Verdict::Drop;
        }
        if lo_a >= 0.0 && lo_b >= 0.0 {
            return Verdict::Accept;
        }
        let gap = (dist - sum_r).max(1e-30);
        let err = ((-lo_a).max(0.0) * hi_b + (-lo_b).max(0.0) * hi_a) * gb.area
            / (std::f32::consts::PI * gap * gap);
        if err <= self.params.clamp_tol {
            return Verdict::Accept;
        }
        // What to split. A side straddles through its own normal spread (a corner leaf
        // mixing two faces: splitting it separates the faces) or through the spread of
        // directions between the two clusters (a flat face whose plane cuts the other
        // cluster: splitting the flat side changes nothing, splitting the larger one
        // narrows the directions). Split a side of the first kind, the more straddling one
        // first; else the larger cluster.
        // (A half-angle above the spread's: a cosine below its cosine.)
        let a_mixed = lo_a < 0.0 && !ga.point && ga.cone_cos < spread_cos;
        let b_mixed = lo_b < 0.0 && !gb.point && gb.cone_cos < spread_cos;
        let split_a = if a_mixed && b_mixed {
            -lo_a * hi_b >= -lo_b * hi_a
        } else if a_mixed || b_mixed {
            a_mixed
        } else {
            !ga.point && (gb.point || ga.r >= gb.r)
        };
        if split_a && !ga.point {
            Verdict::SplitReceiver
        } else if !gb.point {
            Verdict::SplitSource
        } else {
            Verdict::PointToPoint
        }
    }

    /// [`Refiner::visit`] with the subtrees of more than `grain` splats run in parallel: the
    /// workers' outputs in the receivers' order.
    fn visit_par(&self, a: u32, inherited: &[Pending], links: Links, grain: u32) -> Vec<Out> {
        let big = self.is_internal(a) && {
            let (lo, hi) = range(self.t, a);
            hi - lo > grain
        };
        if !big {
            let mut out = Out::default();
            self.visit(a, inherited, links, &mut out);
            return vec![out];
        }
        // The node's own pairs, then its children side by side.
        let mut own = Out::default();
        let Some(down) = self.refine_at(a, inherited, links, &mut own) else {
            return Vec::new();
        };
        let mut kids = Vec::new();
        self.split(a, &mut kids);
        let rest: Vec<Vec<Out>> = kids
            .par_iter()
            .map(|&c| self.visit_par(c, &down, links, grain))
            .collect();
        let mut outs = vec![own];
        outs.extend(rest.into_iter().flatten());
        outs
    }
}

/// Build the plan from the V-map's links (CSR per node-pool slot, both directions stored).
pub fn build(
    t: &Tree,
    p: &Points,
    link_offsets: &[u32],
    links: &[Link],
    params: PlanParams,
) -> Plan {
    let r = Refiner {
        t,
        p,
        params,
        geos: node_geos(t, p),
    };
    // Receiver by receiver from the root down, subtrees of more than 1/256 of the splats side
    // by side: each receiver's tasks come out together, in an order of their own.
    let grain = (p.pos.len() as u32 / 256).max(1024);
    let parts: Vec<Out> = if t.slots == 0 {
        Vec::new()
    } else {
        r.visit_par(0, &[], (link_offsets, links), grain)
    };
    // Each receiver's run into its place in one allocation per kind, then a node's tasks M2L
    // before P2L and a leaf's sorted by source (M2P batches that share moments).
    // (Counted part by part in parallel: integer sums, the same in any order.)
    let counts = parts
        .par_iter()
        .map(|o| {
            let mut counts = TaskCounts {
                dropped_facing_away: o.dropped,
                ..Default::default()
            };
            for task in &o.node {
                if task.src & POINT != 0 {
                    counts.p2l += 1;
                } else {
                    counts.m2l += 1;
                }
            }
            for task in &o.leaf {
                if task.is_m2p() {
                    counts.m2p += 1;
                } else {
                    counts.p2p += 1;
                    counts.p2p_pairs +=
                        (task.recv_hi - task.recv_lo) as u64 * (task.src_hi - task.src_lo) as u64;
                }
            }
            counts
        })
        .reduce(TaskCounts::default, |a, b| TaskCounts {
            m2l: a.m2l + b.m2l,
            p2l: a.p2l + b.p2l,
            m2p: a.m2p + b.m2p,
            p2p: a.p2p + b.p2p,
            p2p_pairs: a.p2p_pairs + b.p2p_pairs,
            dropped_facing_away: a.dropped_facing_away + b.dropped_facing_away,
        });
    // The workers' lists grew by doubling: give the slack back before the copy (on a large
    // scan the leaf tasks are most of the stage's memory, and the copy holds both).
    let mut parts = parts;
    parts.par_iter_mut().for_each(|o| {
        o.node.shrink_to_fit();
        o.leaf.shrink_to_fit();
    });
    let (node_offsets, mut node_tasks) =
        gather(&parts, |o| (o.node.as_slice(), &o.node_runs), t.nodes.len());
    parts.iter_mut().for_each(|o| o.node = Vec::new());
    let (leaf_offsets, mut leaf_tasks) = gather(
        &parts,
        |o| (o.leaf.as_slice(), &o.leaf_runs),
        t.leaves.len(),
    );
    drop(parts);
    // M2L before P2L (the GPU's kernels take them in that order), each in the order found.
    for_each_run(&node_offsets, &mut node_tasks, |run| {
        run.sort_by_key(|x| x.src & POINT != 0)
    });
    // By source within a leaf: a crease leaf's splats against one node come together (M2P
    // batches that share the moments, crate::lanes).
    for_each_run(&leaf_offsets, &mut leaf_tasks, |run| {
        run.sort_unstable_by_key(|x| {
            (
                x.src_lo,
                x.recv_lo,
                x.src_hi,
                x.recv_hi,
                x.fraction.to_bits(),
            )
        })
    });
    Plan {
        node_offsets,
        node_tasks,
        leaf_offsets,
        leaf_tasks,
        counts,
        theta: params.theta,
    }
}

/// The workers' runs of tasks (one run per receiver key below `n`, at most) into one allocation
/// in key order: the CSR offsets and the tasks, copied in parallel.
#[allow(clippy::type_complexity)]
fn gather<T: Copy + Send + Sync + bytemuck::Zeroable>(
    parts: &[Out],
    list: impl Fn(&Out) -> (&[T], &[(u32, u32, u32)]) + Sync,
    n: usize,
) -> (Vec<u32>, Vec<T>) {
    let mut offsets = vec![0u32; n + 1];
    for o in parts {
        for &(key, _, len) in list(o).1 {
            let c = &mut offsets[key as usize + 1];
            assert_eq!(*c, 0, "plan: receiver {key} refined twice");
            *c = len;
        }
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut tasks = vec![T::zeroed(); offsets[n] as usize];
    let out = Disjoint::new(&mut tasks);
    parts.par_iter().for_each(|o| {
        let (list, runs) = list(o);
        for &(key, start, len) in runs {
            let at = offsets[key as usize] as usize;
            let run = &list[start as usize..(start + len) as usize];
            for (k, e) in run.iter().enumerate() {
                // SAFETY: a key's run is written by the one worker that holds it (checked
                // above), into its own range of the allocation.
                unsafe { out.write(at + k, *e) };
            }
        }
    });
    (offsets, tasks)
}

/// `f` on every CSR run of `tasks`, in parallel.
fn for_each_run<T: Send>(offsets: &[u32], tasks: &mut [T], f: impl Fn(&mut [T]) + Sync) {
    let mut runs = Vec::with_capacity(offsets.len().saturating_sub(1));
    let mut rest = tasks;
    for w in offsets.windows(2) {
        let (a, b) = rest.split_at_mut((w[1] - w[0]) as usize);
        runs.push(a);
        rest = b;
    }
    runs.into_par_iter().for_each(&f);
}
