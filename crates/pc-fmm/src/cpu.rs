//! The CPU operator (rayon): one application of the transport operator by the FMM, and the
//! direct O(N²) sum over the same links that tests hold it against. The GPU twin is
//! [`crate::gpu`] (shaders/fmm/*.wgsl).
//!
//! Both compute, for every active splat i,
//! `out_i = Σ_links f Σ_{j ∈ B, j ≠ i} K(i, j) A_j L_j` with
//! `K = max(0, n_i·d) max(0, −n_j·d) / (π |d|⁴)`, `d = x_j − x_i`.

use rayon::prelude::*;

use crate::expansion::{Basis, Coef};
use crate::lanes;
use crate::par::Disjoint;
use crate::plan::{Plan, POINT};
use crate::tree::{Points, Tree, NONE};

const INV_PI: f32 = std::f32::consts::FRAC_1_PI;

/// Least growth of the product error per expansion order taken away, whatever θ
/// ([`CpuFmm::order_within`]).
pub const RELAX_GROWTH_MIN: f64 = 8.0;

/// The source weights `w_j = A_j L_j` (zero for inactive splats).
pub fn weights(pts: &Points, radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let mut w = Vec::new();
    weights_into(pts, radiance, &mut w);
    w
}

/// [`weights`] into `w`, reusing its allocation.
pub fn weights_into(pts: &Points, radiance: &[[f32; 3]], w: &mut Vec<[f32; 3]>) {
    w.resize(pts.pos.len(), [0.0; 3]);
    w.par_iter_mut().enumerate().for_each(|(j, wj)| {
        *wj = if pts.active[j] {
            let a = pts.area[j];
            [a * radiance[j][0], a * radiance[j][1], a * radiance[j][2]]
        } else {
            [0.0; 3]
        }
    });
}

/// The source charges `q_j = n_j w_j`, into `q` (reusing its allocation).
pub fn charges_into(pts: &Points, w: &[[f32; 3]], q: &mut Vec<Coef>) {
    q.resize(pts.pos.len(), [0.0; 9]);
    q.par_iter_mut().enumerate().for_each(|(j, qj)| {
        let n = pts.normal[j];
        for c in 0..3 {
            for k in 0..3 {
                qj[c * 3 + k] = n[k] * w[j][c];
            }
        }
    });
}

/// Clamped point-to-point kernel of the far field,
/// `K(i, j) = max(0, n_i·d) max(0, −n_j·d) / (π |d|⁴)`.
#[inline(always)]
pub fn kernel(xi: [f32; 3], ni: [f32; 3], xj: [f32; 3], nj: [f32; 3]) -> f32 {
    // The near kernel of a source without area.
    kernel_near(xi, ni, xj, nj, 0.0)
}

/// Near-field kernel: the form factor of source disk j (area `A_j`) seen from point i,
/// `cos θ_i cos θ_j / (π r² + A_j)` per unit source area, the exact value for a coaxial disk and
/// the point kernel when `r² ≫ A_j`. It stays bounded where two surfaces meet (a crease), where
/// the point kernel's `1/r²` would let a handful of neighbours exchange more than all the light.
#[inline(always)]
pub fn kernel_near(xi: [f32; 3], ni: [f32; 3], xj: [f32; 3], nj: [f32; 3], aj: f32) -> f32 {
    let d = [xj[0] - xi[0], xj[1] - xi[1], xj[2] - xi[2]];
    let ci = ni[0] * d[0] + ni[1] * d[1] + ni[2] * d[2];
    let cj = -(nj[0] * d[0] + nj[1] * d[1] + nj[2] * d[2]);
    if ci <= 0.0 || cj <= 0.0 {
        return 0.0;
    }
    let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    ci * cj / (r2 * (std::f32::consts::PI * r2 + aj))
}

/// Scratch of one worker.
struct Scratch {
    pow: Vec<f32>,
}

impl Scratch {
    fn new(b: &Basis) -> Scratch {
        Scratch {
            pow: vec![0.0; b.len()],
        }
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Per-phase timings of one application, seconds.
#[derive(Clone, Copy, Debug, Default)]
pub struct PhaseTimes {
    pub upward: f64,
    pub m2l: f64,
    pub downward: f64,
}

/// The FMM on the CPU.
pub struct CpuFmm<'a> {
    /// The configured order's basis.
    pub basis: &'a Basis,
    /// The bases of orders 1 to `basis.order − 1`, for relaxed products
    /// ([`CpuFmm::apply_order`]).
    lower: Vec<Basis>,
    pub tree: &'a Tree,
    pub points: &'a Points,
    pub plan: &'a Plan,
    /// Weights, charges, moments, local expansions and splat lanes, kept from one application
    /// to the next.
    bufs: std::sync::Mutex<Buffers>,
}

#[derive(Default)]
struct Buffers {
    w: Vec<[f32; 3]>,
    q: Vec<Coef>,
    m: Vec<Coef>,
    l: Vec<Coef>,
    splats: Option<lanes::SplatLanes>,
}

/// The lowest order whose product error is at most `relax` (≥ 1) times order `order`'s, for
/// a plan of separation `theta` ([`CpuFmm::order_within`]; the GPU relaxes the same way).
pub fn order_within(order: usize, theta: f32, relax: f64) -> usize {
    let growth = (1.0 / (theta as f64).powi(3)).max(RELAX_GROWTH_MIN);
    let mut q = order;
    let mut err = 1.0;
    while q > 1 && err * growth <= relax {
        err *= growth;
        q -= 1;
    }
    q
}

impl<'a> CpuFmm<'a> {
    pub fn new(basis: &'a Basis, tree: &'a Tree, points: &'a Points, plan: &'a Plan) -> Self {
        CpuFmm {
            basis,
            lower: (1..basis.order).map(Basis::new).collect(),
            tree,
            points,
            plan,
            bufs: Default::default(),
        }
    }
}

impl CpuFmm<'_> {
    /// The basis of order `order` (at least 1, at most the configured one; the configured one
    /// when that is 0).
    pub fn basis_of(&self, order: usize) -> &Basis {
        if order >= self.basis.order || order == 0 {
            self.basis
        } else {
            &self.lower[order - 1]
        }
    }

    /// The lowest order whose product error is at most `relax` (≥ 1) times the configured
    /// order's, by the truncation model of docs/fmm.md ("Relaxed products"): each order less
    /// multiplies the error by `max(8, θ⁻³)`; never below order 1.
    pub fn order_within(&self, relax: f64) -> usize {
        order_within(self.basis.order, self.plan.theta, relax)
    }

    /// Upward pass: multipole moments of every node (P2M at leaves, M2M upward).
    pub fn upward(&self, b: &Basis, q: &[Coef], m: &mut Vec<Coef>) {
        let (t, p) = (self.tree, self.points);
        let np = b.len();
        zeroed(m, t.nodes.len() * np);
        let mp = Disjoint::new(m);
        t.leaves.par_iter().for_each_init(
            || Scratch::new(b),
            |s, &leaf| {
                let ci = t.compact[leaf as usize] as usize;
                // SAFETY: each leaf writes its own expansion block.
                let out = unsafe { mp.block_mut(ci * np..(ci + 1) * np) };
                let c = t.center[leaf as usize];
                for j in t.lo[leaf as usize]..t.hi[leaf as usize] {
                    if p.active[j as usize] {
                        lanes::p2m(
                            b,
                            &q[j as usize],
                            sub(p.pos[j as usize], c),
                            &mut s.pow,
                            out,
                        );
                    }
                }
            },
        );
        for level in t.levels.iter().rev() {
            level.par_iter().for_each_init(
                || Scratch::new(b),
                |s, &slot| {
                    if t.first_child[slot as usize] == NONE {
                        return;
                    }
                    let ci = t.compact[slot as usize] as usize;
                    let c = t.center[slot as usize];
                    // SAFETY: a parent writes its own block and reads its children's, which
                    // were finished by the previous level.
                    let out = unsafe { mp.block_mut(ci * np..(ci + 1) * np) };
                    for k in t.children(slot) {
                        let kc = t.compact[k as usize] as usize;
                        let child = unsafe { mp.block(kc * np..(kc + 1) * np) };
                        let delta = sub(t.center[k as usize], c);
                        lanes::shift(b, child, delta, &mut s.pow, out, true);
                    }
                },
            );
        }
    }

    /// M2L and P2L into every receiving node's local expansion.
    pub fn interact(&self, b: &Basis, m: &[Coef], q: &[Coef], l: &mut Vec<Coef>) {
        let (t, p, plan) = (self.tree, self.points, self.plan);
        let np = b.len();
        zeroed(l, t.nodes.len() * np);
        l.par_chunks_mut(np).enumerate().for_each_init(
            || lanes::Scratch::new(b),
            |s, (ci, local)| {
                let (lo, hi) = (
                    plan.node_offsets[ci] as usize,
                    plan.node_offsets[ci + 1] as usize,
                );
                if lo < hi {
                    let ca = t.center[t.nodes[ci] as usize];
                    lanes::node(b, t, p, m, q, &plan.node_tasks[lo..hi], ca, s, local);
                }
            },
        );
    }

    /// Downward pass (L2L) and the leaf phase (L2P, M2P, P2P): the operator's output per splat.
    pub fn downward(
        &self,
        b: &Basis,
        l: &mut [Coef],
        m: &[Coef],
        sl: &lanes::SplatLanes,
        out: &mut [[f32; 3]],
    ) {
        let (t, p, plan) = (self.tree, self.points, self.plan);
        let np = b.len();
        let lp = Disjoint::new(l);
        for level in t.levels.iter().skip(1) {
            level.par_iter().for_each_init(
                || Scratch::new(b),
                |s, &slot| {
                    let parent = t.parent[slot as usize] as usize;
                    let pc = t.compact[parent] as usize;
                    let ci = t.compact[slot as usize] as usize;
                    // SAFETY: each node writes its own block; parents are finished.
                    let src = unsafe { lp.block(pc * np..(pc + 1) * np) };
                    let dst = unsafe { lp.block_mut(ci * np..(ci + 1) * np) };
                    let delta = sub(t.center[slot as usize], t.center[parent]);
                    lanes::shift(b, src, delta, &mut s.pow, dst, false);
                },
            );
        }
        let l: &[Coef] = l;
        let op = Disjoint::new(out);
        t.leaves.par_iter().enumerate().for_each_init(
            || (Scratch::new(b), lanes::Scratch::new(b)),
            |s, (li, &leaf)| {
                let ci = t.compact[leaf as usize] as usize;
                let local = &l[ci * np..(ci + 1) * np];
                let c = t.center[leaf as usize];
                let (lo, hi) = (t.lo[leaf as usize], t.hi[leaf as usize]);
                // SAFETY: a leaf writes only its own splats' outputs.
                let o = unsafe { op.block_mut(lo as usize..hi as usize) };
                for i in lo..hi {
                    let iu = i as usize;
                    let mut v = [0.0f32; 3];
                    if p.active[iu] {
                        let f = lanes::l2p(b, local, sub(p.pos[iu], c), &mut s.0.pow);
                        let n = p.normal[iu];
                        for (k, vk) in v.iter_mut().enumerate() {
                            *vk = -INV_PI
                                * (n[0] * f[k * 3] + n[1] * f[k * 3 + 1] + n[2] * f[k * 3 + 2]);
                        }
                    }
                    o[(i - lo) as usize] = v;
                }
                let (tl, th) = (
                    plan.leaf_offsets[li] as usize,
                    plan.leaf_offsets[li + 1] as usize,
                );
                if tl < th {
                    let tasks = &plan.leaf_tasks[tl..th];
                    lanes::leaf(b, t, p, sl, m, tasks, lo, &mut s.1, o);
                }
            },
        );
    }

    /// One application: `out_i = Σ_j f K(i, j) A_j L_j` for the radiance `L`.
    pub fn apply(&self, radiance: &[[f32; 3]], out: &mut [[f32; 3]], times: &mut PhaseTimes) {
        self.apply_order(self.basis.order, radiance, out, times)
    }

    /// [`CpuFmm::apply`] with the expansions truncated at `order` (clamped to
    /// `1..=basis.order`): the same plan, cheaper and less accurate below the configured order
    /// (graded bases: a lower order's coefficients are a prefix of a higher one's).
    pub fn apply_order(
        &self,
        order: usize,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        times: &mut PhaseTimes,
    ) {
        let b = self.basis_of(order);
        // A poisoned lock only means an earlier application panicked; the buffers are
        // rewritten in full.
        let mut guard = self.bufs.lock().unwrap_or_else(|e| e.into_inner());
        let bufs = &mut *guard;
        let t0 = std::time::Instant::now();
        weights_into(self.points, radiance, &mut bufs.w);
        charges_into(self.points, &bufs.w, &mut bufs.q);
        match &mut bufs.splats {
            Some(sl) => sl.set_weights(&bufs.w),
            None => bufs.splats = Some(lanes::SplatLanes::new(self.points, &bufs.w)),
        }
        self.upward(b, &bufs.q, &mut bufs.m);
        let t1 = std::time::Instant::now();
        self.interact(b, &bufs.m, &bufs.q, &mut bufs.l);
        let t2 = std::time::Instant::now();
        let sl = bufs.splats.as_ref().expect("set above");
        self.downward(b, &mut bufs.l, &bufs.m, sl, out);
        times.upward += (t1 - t0).as_secs_f64();
        times.m2l += (t2 - t1).as_secs_f64();
        times.downward += t2.elapsed().as_secs_f64();
    }
}

/// `v` as `n` zero coefficients, reusing its pages (a fresh zeroed allocation faults on every
/// first write, and with threads each fault costs a TLB shootdown); products of a lower order
/// keep the larger allocation.
fn zeroed(v: &mut Vec<Coef>, n: usize) {
    if v.capacity() >= n {
        v.truncate(n);
        v.par_iter_mut().for_each(|x| *x = [0.0; 9]);
        // (Within the capacity: pages the larger order touched.)
        v.resize(n, [0.0; 9]);
    } else {
        v.clear();
        v.resize(n, [0.0; 9]);
    }
}

/// The direct sum of the same operator: every task of the plan evaluated exactly, pair by pair
/// (far-field tasks with the point kernel instead of expansions, near-field ones as in P2P).
/// What the FMM approximates, so the difference is the expansions' error alone. O(N²); tests
/// only.
pub fn direct(tree: &Tree, pts: &Points, plan: &Plan, radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let w = weights(pts, radiance);
    let n = pts.pos.len();
    let range = |x: u32| {
        if x & POINT != 0 {
            (x & !POINT, (x & !POINT) + 1)
        } else {
            (tree.lo[x as usize], tree.hi[x as usize])
        }
    };
    // (receivers, sources, fraction, near) of every task.
    type Span = (u32, u32);
    let mut tasks: Vec<(Span, Span, f32, bool)> = Vec::new();
    for (ci, win) in plan.node_offsets.windows(2).enumerate() {
        let a = tree.nodes[ci];
        for t in &plan.node_tasks[win[0] as usize..win[1] as usize] {
            tasks.push((range(a), range(t.src), t.fraction, false));
        }
    }
    for t in &plan.leaf_tasks {
        if t.is_m2p() {
            tasks.push((
                (t.recv_lo, t.recv_lo + 1),
                range(t.src_lo),
                t.fraction,
                false,
            ));
        } else {
            tasks.push((
                (t.recv_lo, t.recv_hi),
                (t.src_lo, t.src_hi),
                t.fraction,
                true,
            ));
        }
    }
    // Receiver-major for parallel accumulation: per splat, the tasks that cover it.
    let mut by_recv: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (k, t) in tasks.iter().enumerate() {
        for i in t.0 .0..t.0 .1 {
            by_recv[i as usize].push(k);
        }
    }
    (0..n)
        .into_par_iter()
        .map(|i| {
            let mut acc = [0.0f64; 3];
            if !pts.active[i] {
                return [0.0; 3];
            }
            for &k in &by_recv[i] {
                let (_, (lo, hi), f, near) = tasks[k];
                for j in lo..hi {
                    let ju = j as usize;
                    if ju == i || !pts.active[ju] {
                        continue;
                    }
                    let kk = if near {
                        kernel_near(
                            pts.pos[i],
                            pts.normal[i],
                            pts.pos[ju],
                            pts.normal[ju],
                            pts.area[ju],
                        )
                    } else {
                        kernel(pts.pos[i], pts.normal[i], pts.pos[ju], pts.normal[ju])
                    } as f64
                        * f as f64;
                    for c in 0..3 {
                        acc[c] += kk * w[ju][c] as f64;
                    }
                }
            }
            [acc[0] as f32, acc[1] as f32, acc[2] as f32]
        })
        .collect()
}

/// Sum of a vector's squares, f64.
pub fn norm2(v: &[[f32; 3]]) -> f64 {
    v.iter()
        .map(|x| x.iter().map(|&y| (y as f64) * (y as f64)).sum::<f64>())
        .sum()
}
