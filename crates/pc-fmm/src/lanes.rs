//! Eight-lane kernels of the CPU product (docs/fmm.md, "The CPU product in lanes").
//!
//! The scalar form of every operation is in [`crate::expansion`]; here the same arithmetic runs
//! on eight interactions at once, one per lane: eight M2L, P2L or M2P tasks (their kernel
//! coefficients and translations), or one receiving splat against eight source splats in P2P.
//! Lanes are plain `[f32; 8]` arrays, which the compiler turns into vector instructions; on
//! x86-64 CPUs with AVX2 and FMA (detected at run time) every kernel is compiled a second time
//! for those instructions, with fused multiply-adds, and that build runs instead.

// Lane loops index several arrays by the lane on purpose: that is the shape the vectoriser
// turns into vector instructions.
#![allow(clippy::needless_range_loop)]

use crate::expansion::{Basis, Coef, SYM_IJ};
use crate::plan::{LeafTask, NodeTask, POINT};
use crate::tree::{Points, Tree};

/// Lanes per batch.
pub const W: usize = 8;
/// One value per lane.
pub type L = [f32; W];
const Z: L = [0.0; W];
const INV_PI: f32 = std::f32::consts::FRAC_1_PI;

/// How a multiply-add is done: rounded twice, or fused (the AVX2 + FMA build).
pub(crate) trait Isa {
    fn madd(a: f32, b: f32, c: f32) -> f32;
}

/// `a * b + c`, two roundings: any CPU.
pub(crate) struct Plain;

impl Isa for Plain {
    #[inline(always)]
    fn madd(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
}

/// Fused multiply-add: only inside functions compiled with the `fma` target feature.
#[cfg(target_arch = "x86_64")]
pub(crate) struct Fused;

#[cfg(target_arch = "x86_64")]
impl Isa for Fused {
    #[inline(always)]
    fn madd(a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
}

/// Whether this CPU runs the AVX2 + FMA build of the kernels.
pub fn fused() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Scratch of one worker: kernel coefficients, gathered source moments and accumulators, all
/// per lane.
pub struct Scratch {
    a: Vec<L>,
    g: Vec<[L; 6]>,
    ms: Vec<[L; 9]>,
    acc: Vec<[L; 9]>,
}

impl Scratch {
    pub fn new(b: &Basis) -> Scratch {
        Scratch {
            a: vec![Z; b.len() + 1],
            g: vec![[Z; 6]; b.len()],
            ms: vec![[Z; 9]; b.len()],
            acc: vec![[Z; 9]; b.len()],
        }
    }
}

/// The splats as structure of arrays for P2P, padded with [`W`] zero splats so that a batch
/// may read past the last one: positions, normals, areas and the source weights `A_j L_j` of
/// one product (zero for inactive splats).
pub struct SplatLanes {
    pub pos: [Vec<f32>; 3],
    pub normal: [Vec<f32>; 3],
    pub area: Vec<f32>,
    /// 1 for splats that take part, 0 for the others.
    pub active: Vec<f32>,
    pub w: [Vec<f32>; 3],
}

impl SplatLanes {
    pub fn new(p: &Points, w: &[[f32; 3]]) -> SplatLanes {
        let n = p.pos.len() + W;
        let col = |f: &dyn Fn(usize) -> f32| -> Vec<f32> {
            let mut v: Vec<f32> = (0..p.pos.len()).map(f).collect();
            v.resize(n, 0.0);
            v
        };
        SplatLanes {
            pos: [0, 1, 2].map(|k| col(&|i| p.pos[i][k])),
            normal: [0, 1, 2].map(|k| col(&|i| p.normal[i][k])),
            area: col(&|i| p.area[i]),
            active: col(&|i| if p.active[i] { 1.0 } else { 0.0 }),
            w: [0, 1, 2].map(|c| col(&|i| w[i][c])),
        }
    }
}

/// Eight lanes of [`crate::expansion::kernel_coeffs`]: the Taylor coefficients of `G` about
/// `r` (one vector per lane). `a` has the zero slot `len()`.
#[inline(always)]
fn kernel_coeffs(b: &Basis, r: &[L; 3], a: &mut [L], g: &mut [[L; 6]]) {
    let n = b.len();
    let mut inv = Z;
    for l in 0..W {
        inv[l] = 1.0 / (r[0][l] * r[0][l] + r[1][l] * r[1][l] + r[2][l] * r[2][l]);
    }
    for l in 0..W {
        a[0][l] = inv[l] * inv[l];
    }
    a[n] = Z;
    for i in 1..n {
        let t = &b.recur[i];
        let m1 = t.m1.map(|k| a[k as usize]);
        let m2 = t.m2.map(|k| a[k as usize]);
        let mut o = Z;
        for l in 0..W {
            let s1 = r[0][l] * m1[0][l] + r[1][l] * m1[1][l] + r[2][l] * m1[2][l];
            let s2 = m2[0][l] + m2[1][l] + m2[2][l];
            o[l] = (t.c1 * s1 + t.c2 * s2) * inv[l];
        }
        a[i] = o;
    }
    let mut rr = [Z; 6];
    for (c, &(p, q)) in SYM_IJ.iter().enumerate() {
        for l in 0..W {
            rr[c][l] = r[p][l] * r[q][l];
        }
    }
    for i in 0..n {
        let t = &b.recur[i];
        let ai = a[i];
        let m1 = t.m1.map(|k| a[k as usize]);
        for (c, &(p, q)) in SYM_IJ.iter().enumerate() {
            let aij = a[t.mij[c] as usize];
            let gi = &mut g[i][c];
            for l in 0..W {
                gi[l] = rr[c][l] * ai[l] + r[p][l] * m1[q][l] + r[q][l] * m1[p][l] + aij[l];
            }
        }
    }
}

/// `acc += c · G m` per lane, for the 3 colours of `m`.
#[inline(always)]
fn apply<I: Isa>(c: f32, g: &[L; 6], m: &[L; 9], acc: &mut [L; 9]) {
    let mut cg = [Z; 6];
    for k in 0..6 {
        for l in 0..W {
            cg[k][l] = c * g[k][l];
        }
    }
    for col in 0..3 {
        let (x, y, z) = (&m[col * 3], &m[col * 3 + 1], &m[col * 3 + 2]);
        for (row, (i0, i1, i2)) in [(0, 1, 2), (1, 3, 4), (2, 4, 5)].into_iter().enumerate() {
            let o = &mut acc[col * 3 + row];
            for l in 0..W {
                o[l] = I::madd(
                    cg[i0][l],
                    x[l],
                    I::madd(cg[i1][l], y[l], I::madd(cg[i2][l], z[l], o[l])),
                );
            }
        }
    }
}

/// `acc += G m` per lane, for moments `m` shared by every lane.
#[inline(always)]
fn apply_uniform<I: Isa>(g: &[L; 6], m: &Coef, acc: &mut [L; 9]) {
    for col in 0..3 {
        let (x, y, z) = (m[col * 3], m[col * 3 + 1], m[col * 3 + 2]);
        for (row, (i0, i1, i2)) in [(0, 1, 2), (1, 3, 4), (2, 4, 5)].into_iter().enumerate() {
            let o = &mut acc[col * 3 + row];
            for l in 0..W {
                o[l] = I::madd(
                    g[i0][l],
                    x,
                    I::madd(g[i1][l], y, I::madd(g[i2][l], z, o[l])),
                );
            }
        }
    }
}

/// M2L of up to eight source nodes `(slot, fraction)` into the lane accumulators.
#[inline(always)]
fn m2l_batch<I: Isa>(
    b: &Basis,
    t: &Tree,
    m: &[Coef],
    batch: &[(u32, f32)],
    ca: [f32; 3],
    s: &mut Scratch,
) {
    let np = b.len();
    let mut r = [Z; 3];
    for l in 0..W {
        if let Some(&(src, f)) = batch.get(l) {
            let c = t.center[src as usize];
            for k in 0..3 {
                r[k][l] = c[k] - ca[k];
            }
            let sc = t.compact[src as usize] as usize;
            for (a, mm) in m[sc * np..(sc + 1) * np].iter().enumerate() {
                for k in 0..9 {
                    s.ms[a][k][l] = mm[k] * f;
                }
            }
        } else {
            r[0][l] = 1.0;
            for ma in s.ms.iter_mut() {
                for mk in ma.iter_mut() {
                    mk[l] = 0.0;
                }
            }
        }
    }
    kernel_coeffs(b, &r, &mut s.a, &mut s.g);
    for &(a, bb, gi, c) in &b.m2l {
        apply::<I>(
            c,
            &s.g[gi as usize],
            &s.ms[a as usize],
            &mut s.acc[bb as usize],
        );
    }
}

/// P2L of up to eight source splats `(splat, fraction)`: the M2L terms of the charge alone.
#[inline(always)]
fn p2l_batch<I: Isa>(
    b: &Basis,
    p: &Points,
    q: &[Coef],
    batch: &[(u32, f32)],
    ca: [f32; 3],
    s: &mut Scratch,
) {
    let mut r = [Z; 3];
    for l in 0..W {
        if let Some(&(j, f)) = batch.get(l) {
            let x = p.pos[j as usize];
            for k in 0..3 {
                r[k][l] = x[k] - ca[k];
            }
            for k in 0..9 {
                s.ms[0][k][l] = q[j as usize][k] * f;
            }
        } else {
            r[0][l] = 1.0;
            for k in 0..9 {
                s.ms[0][k][l] = 0.0;
            }
        }
    }
    kernel_coeffs(b, &r, &mut s.a, &mut s.g);
    for &(a, bb, gi, c) in b.m2l.iter().filter(|t| t.0 == 0) {
        apply::<I>(
            c,
            &s.g[gi as usize],
            &s.ms[a as usize],
            &mut s.acc[bb as usize],
        );
    }
}

/// Everything one receiving node takes in: M2L from nodes and P2L from splats, added to its
/// local expansion `local` (centre `ca`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn node_impl<I: Isa>(
    b: &Basis,
    t: &Tree,
    p: &Points,
    m: &[Coef],
    q: &[Coef],
    tasks: &[NodeTask],
    ca: [f32; 3],
    s: &mut Scratch,
    local: &mut [Coef],
) {
    for acc in s.acc.iter_mut() {
        *acc = [Z; 9];
    }
    let mut batch = [(0u32, 0.0f32); W];
    let mut nb = 0;
    for task in tasks.iter().filter(|x| x.src & POINT == 0) {
        batch[nb] = (task.src, task.fraction);
        nb += 1;
        if nb == W {
            m2l_batch::<I>(b, t, m, &batch, ca, s);
            nb = 0;
        }
    }
    if nb > 0 {
        m2l_batch::<I>(b, t, m, &batch[..nb], ca, s);
    }
    nb = 0;
    for task in tasks.iter().filter(|x| x.src & POINT != 0) {
        batch[nb] = (task.src & !POINT, task.fraction);
        nb += 1;
        if nb == W {
            p2l_batch::<I>(b, p, q, &batch, ca, s);
            nb = 0;
        }
    }
    if nb > 0 {
        p2l_batch::<I>(b, p, q, &batch[..nb], ca, s);
    }
    for (out, acc) in local.iter_mut().zip(&s.acc) {
        for k in 0..9 {
            out[k] += acc[k].iter().sum::<f32>();
        }
    }
}

/// M2L and P2L into one receiving node's local expansion (centre `ca`): eight tasks at a time.
#[allow(clippy::too_many_arguments)]
pub fn node(
    b: &Basis,
    t: &Tree,
    p: &Points,
    m: &[Coef],
    q: &[Coef],
    tasks: &[NodeTask],
    ca: [f32; 3],
    s: &mut Scratch,
    local: &mut [Coef],
) {
    #[cfg(target_arch = "x86_64")]
    if fused() {
        // SAFETY: the CPU has AVX2 and FMA.
        return unsafe { node_fused(b, t, p, m, q, tasks, ca, s, local) };
    }
    node_impl::<Plain>(b, t, p, m, q, tasks, ca, s, local)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn node_fused(
    b: &Basis,
    t: &Tree,
    p: &Points,
    m: &[Coef],
    q: &[Coef],
    tasks: &[NodeTask],
    ca: [f32; 3],
    s: &mut Scratch,
    local: &mut [Coef],
) {
    node_impl::<Fused>(b, t, p, m, q, tasks, ca, s, local)
}

/// M2P of up to eight `(splat, source node, fraction)`: the far field of each node's moments at
/// its splat, added to `o` (indexed from the leaf's first splat `lo`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn m2p_batch<I: Isa>(
    b: &Basis,
    t: &Tree,
    p: &Points,
    m: &[Coef],
    batch: &[(u32, u32, f32)],
    lo: u32,
    s: &mut Scratch,
    o: &mut [[f32; 3]],
) {
    let np = b.len();
    let src0 = batch[0].1;
    // The tasks of a crease leaf's splats against one node come together: then every lane
    // reads the same moments, and they need no gathering.
    let uniform = batch.iter().all(|x| x.1 == src0);
    let mut r = [Z; 3];
    for l in 0..W {
        if let Some(&(i, src, _)) = batch.get(l) {
            let (c, x) = (t.center[src as usize], p.pos[i as usize]);
            for k in 0..3 {
                r[k][l] = c[k] - x[k];
            }
            if !uniform {
                let sc = t.compact[src as usize] as usize;
                for (a, mm) in m[sc * np..(sc + 1) * np].iter().enumerate() {
                    for k in 0..9 {
                        s.ms[a][k][l] = mm[k];
                    }
                }
            }
        } else {
            r[0][l] = 1.0;
            if !uniform {
                for ma in s.ms.iter_mut() {
                    for mk in ma.iter_mut() {
                        mk[l] = 0.0;
                    }
                }
            }
        }
    }
    kernel_coeffs(b, &r, &mut s.a, &mut s.g);
    let mut field = [Z; 9];
    if uniform {
        let sc = t.compact[src0 as usize] as usize;
        for (g, mm) in s.g.iter().zip(&m[sc * np..(sc + 1) * np]) {
            apply_uniform::<I>(g, mm, &mut field);
        }
    } else {
        for a in 0..np {
            apply::<I>(1.0, &s.g[a], &s.ms[a], &mut field);
        }
    }
    for (l, &(i, _, f)) in batch.iter().enumerate() {
        let n = p.normal[i as usize];
        let v = &mut o[(i - lo) as usize];
        for (col, vc) in v.iter_mut().enumerate() {
            *vc -= f
                * INV_PI
                * (n[0] * field[col * 3][l]
                    + n[1] * field[col * 3 + 1][l]
                    + n[2] * field[col * 3 + 2][l]);
        }
    }
}

/// Share of the lanes a run of `n` keeps busy, in eighths.
#[inline(always)]
fn busy(n: usize) -> usize {
    n * W / (n.div_ceil(W) * W)
}

/// P2P of one task with the near kernel [`crate::cpu::kernel_near`]: eight sources at a time
/// per receiver, or eight receivers at a time per source where that fills more lanes (a task
/// with a single source, typical of small far pairs, would keep one lane of eight busy).
#[inline(always)]
fn p2p<I: Isa>(p: &Points, sl: &SplatLanes, task: &LeafTask, lo: u32, o: &mut [[f32; 3]]) {
    let (s, r) = (task.src_hi - task.src_lo, task.recv_hi - task.recv_lo);
    if busy(r as usize) > busy(s as usize) {
        p2p_by_receivers::<I>(sl, task, lo, o)
    } else {
        p2p_by_sources::<I>(p, sl, task, lo, o)
    }
}

/// P2P with lanes over receivers: per source, eight receivers at a time.
#[inline(always)]
fn p2p_by_receivers<I: Isa>(sl: &SplatLanes, task: &LeafTask, lo: u32, o: &mut [[f32; 3]]) {
    const PI: f32 = std::f32::consts::PI;
    let (ilo, ihi) = (task.recv_lo as usize, task.recv_hi as usize);
    let mut i0 = ilo;
    while i0 < ihi {
        // SplatLanes is padded with W splats, so a batch never reads past its end.
        let lane = |v: &Vec<f32>| -> [f32; W] { v[i0..i0 + W].try_into().unwrap() };
        let (px, py, pz) = (lane(&sl.pos[0]), lane(&sl.pos[1]), lane(&sl.pos[2]));
        let (nx, ny, nz) = (
            lane(&sl.normal[0]),
            lane(&sl.normal[1]),
            lane(&sl.normal[2]),
        );
        let active = lane(&sl.active);
        let mut acc = [Z; 3];
        for j in task.src_lo as usize..task.src_hi as usize {
            let xj = [sl.pos[0][j], sl.pos[1][j], sl.pos[2][j]];
            let nj = [sl.normal[0][j], sl.normal[1][j], sl.normal[2][j]];
            let (aj, wj) = (sl.area[j], [sl.w[0][j], sl.w[1][j], sl.w[2][j]]);
            let mut k = Z;
            for l in 0..W {
                let (dx, dy, dz) = (xj[0] - px[l], xj[1] - py[l], xj[2] - pz[l]);
                let ci = nx[l] * dx + ny[l] * dy + nz[l] * dz;
                let cj = -(nj[0] * dx + nj[1] * dy + nj[2] * dz);
                let r2 = dx * dx + dy * dy + dz * dz;
                let i = i0 + l;
                let ok = (ci > 0.0) & (cj > 0.0) & (i < ihi) & (i != j) & (active[l] > 0.0);
                let v = ci * cj / (r2 * (PI * r2 + aj));
                k[l] = if ok { v } else { 0.0 };
            }
            for c in 0..3 {
                for l in 0..W {
                    acc[c][l] = I::madd(k[l], wj[c], acc[c][l]);
                }
            }
        }
        for l in 0..W.min(ihi - i0) {
            let v = &mut o[i0 + l - lo as usize];
            for c in 0..3 {
                v[c] += task.fraction * acc[c][l];
            }
        }
        i0 += W;
    }
}

/// P2P with lanes over sources: per receiver, eight sources at a time.
#[inline(always)]
fn p2p_by_sources<I: Isa>(
    p: &Points,
    sl: &SplatLanes,
    task: &LeafTask,
    lo: u32,
    o: &mut [[f32; 3]],
) {
    const PI: f32 = std::f32::consts::PI;
    let (jlo, jhi) = (task.src_lo as usize, task.src_hi as usize);
    for i in task.recv_lo..task.recv_hi {
        let iu = i as usize;
        if !p.active[iu] {
            continue;
        }
        let (xi, ni) = (p.pos[iu], p.normal[iu]);
        let mut acc = [Z; 3];
        let mut j0 = jlo;
        while j0 < jhi {
            // SplatLanes is padded with W splats, so a batch never reads past its end.
            let lane = |v: &Vec<f32>| -> [f32; W] { v[j0..j0 + W].try_into().unwrap() };
            let (px, py, pz) = (lane(&sl.pos[0]), lane(&sl.pos[1]), lane(&sl.pos[2]));
            let (nx, ny, nz) = (
                lane(&sl.normal[0]),
                lane(&sl.normal[1]),
                lane(&sl.normal[2]),
            );
            let area = lane(&sl.area);
            let w = [lane(&sl.w[0]), lane(&sl.w[1]), lane(&sl.w[2])];
            let mut k = Z;
            for l in 0..W {
                let (dx, dy, dz) = (px[l] - xi[0], py[l] - xi[1], pz[l] - xi[2]);
                let ci = ni[0] * dx + ni[1] * dy + ni[2] * dz;
                let cj = -(nx[l] * dx + ny[l] * dy + nz[l] * dz);
                let r2 = dx * dx + dy * dy + dz * dz;
                let j = j0 + l;
                let ok = (ci > 0.0) & (cj > 0.0) & (j < jhi) & (j != iu);
                let v = ci * cj / (r2 * (PI * r2 + area[l]));
                k[l] = if ok { v } else { 0.0 };
            }
            for c in 0..3 {
                for l in 0..W {
                    acc[c][l] = I::madd(k[l], w[c][l], acc[c][l]);
                }
            }
            j0 += W;
        }
        let v = &mut o[(i - lo) as usize];
        for c in 0..3 {
            v[c] += task.fraction * acc[c].iter().sum::<f32>();
        }
    }
}

/// The tasks of one receiving leaf (first splat `lo`): M2P eight at a time, P2P per task.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn leaf_impl<I: Isa>(
    b: &Basis,
    t: &Tree,
    p: &Points,
    sl: &SplatLanes,
    m: &[Coef],
    tasks: &[LeafTask],
    lo: u32,
    s: &mut Scratch,
    o: &mut [[f32; 3]],
) {
    let mut batch = [(0u32, 0u32, 0.0f32); W];
    let mut nb = 0;
    for task in tasks {
        if task.is_m2p() {
            batch[nb] = (task.recv_lo, task.src_lo, task.fraction);
            nb += 1;
            if nb == W {
                m2p_batch::<I>(b, t, p, m, &batch, lo, s, o);
                nb = 0;
            }
        } else {
            p2p::<I>(p, sl, task, lo, o);
        }
    }
    if nb > 0 {
        m2p_batch::<I>(b, t, p, m, &batch[..nb], lo, s, o);
    }
}

/// M2P and P2P into one leaf's splats `o` (first splat `lo`).
#[allow(clippy::too_many_arguments)]
pub fn leaf(
    b: &Basis,
    t: &Tree,
    p: &Points,
    sl: &SplatLanes,
    m: &[Coef],
    tasks: &[LeafTask],
    lo: u32,
    s: &mut Scratch,
    o: &mut [[f32; 3]],
) {
    #[cfg(target_arch = "x86_64")]
    if fused() {
        // SAFETY: the CPU has AVX2 and FMA.
        return unsafe { leaf_fused(b, t, p, sl, m, tasks, lo, s, o) };
    }
    leaf_impl::<Plain>(b, t, p, sl, m, tasks, lo, s, o)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn leaf_fused(
    b: &Basis,
    t: &Tree,
    p: &Points,
    sl: &SplatLanes,
    m: &[Coef],
    tasks: &[LeafTask],
    lo: u32,
    s: &mut Scratch,
    o: &mut [[f32; 3]],
) {
    leaf_impl::<Fused>(b, t, p, sl, m, tasks, lo, s, o)
}

/// Disks as structure of arrays for [`any_hit`], padded to whole batches with disks no ray
/// meets: centre, normal, squared radius, border clip.
#[derive(Default)]
pub struct DiskLanes {
    v: [Vec<f32>; 11],
    /// Per batch of [`W`] disks, the box of their disks (min xyz, max xyz), padded to whole
    /// batches of boxes with empty ones.
    b: [Vec<f32>; 6],
}

impl DiskLanes {
    /// Load the splats `ids` of `splats`.
    pub fn load(&mut self, splats: &[pc_artifact::octree::Splat], ids: &[u32]) {
        for v in self.v.iter_mut() {
            v.clear();
        }
        for &i in ids {
            let s = &splats[i as usize];
            let vals = [
                s.position[0],
                s.position[1],
                s.position[2],
                s.normal[0],
                s.normal[1],
                s.normal[2],
                s.radius * s.radius,
                s.clip[0],
                s.clip[1],
                s.clip[2],
                s.clip[3],
            ];
            for (v, x) in self.v.iter_mut().zip(vals) {
                v.push(x);
            }
        }
        // Padding: a zero normal fails the parallel test, and a negative squared radius the
        // disk test.
        while !self.v[0].len().is_multiple_of(W) {
            for (k, v) in self.v.iter_mut().enumerate() {
                v.push(if k == 6 { -1.0 } else { 0.0 });
            }
        }
        for v in self.b.iter_mut() {
            v.clear();
        }
        for batch in ids.chunks(W) {
            let mut bx = crate::shaft::Aabb::EMPTY;
            for &i in batch {
                let s = &splats[i as usize];
                bx = bx.union(crate::shaft::Aabb::of_disk(
                    s.position.into(),
                    s.normal.into(),
                    s.radius,
                ));
            }
            for k in 0..3 {
                self.b[k].push(bx.min[k]);
                self.b[k + 3].push(bx.max[k]);
            }
        }
        while !self.b[0].len().is_multiple_of(W) {
            for (k, v) in self.b.iter_mut().enumerate() {
                v.push(if k < 3 {
                    f32::INFINITY
                } else {
                    f32::NEG_INFINITY
                });
            }
        }
    }
}

/// Whether any disk of `d` blocks the ray (a hit in `[t_min, t_max]`): the ray-disk test of the
/// octree walk (`pc_tree::accel`), the same operations in the same order, eight disks at a time.
#[inline(always)]
fn any_hit_impl(d: &DiskLanes, ray: &pc_tree::Ray) -> bool {
    let (o, dir) = (ray.origin, ray.dir);
    // Slab test of eight batch boxes at a time (a zero direction component gets a huge finite
    // inverse, so no 0 · ∞ arises), then the disks of the boxes the ray meets.
    let inv = dir.to_array().map(|x| {
        if x.abs() < 1e-20 {
            1e20f32.copysign(x)
        } else {
            1.0 / x
        }
    });
    let o3 = o.to_array();
    let nb = d.b[0].len();
    let mut b0 = 0;
    while b0 < nb {
        let lb = |k: usize| -> [f32; W] { d.b[k][b0..b0 + W].try_into().unwrap() };
        let (lo, hi) = ([lb(0), lb(1), lb(2)], [lb(3), lb(4), lb(5)]);
        let mut meets = [false; W];
        for l in 0..W {
            let (mut near, mut far) = (ray.t_min, ray.t_max);
            for k in 0..3 {
                let t1 = (lo[k][l] - o3[k]) * inv[k];
                let t2 = (hi[k][l] - o3[k]) * inv[k];
                near = near.max(t1.min(t2));
                far = far.min(t1.max(t2));
            }
            // (Padding boxes are empty: min above max.)
            meets[l] = (near <= far) & (lo[0][l] <= hi[0][l]);
        }
        for (l, _) in meets.iter().enumerate().filter(|(_, &m)| m) {
            if batch_hit(d, (b0 + l) * W, ray) {
                return true;
            }
        }
        b0 += W;
    }
    false
}

/// The disks `j0..j0 + W` of `d` against the ray.
#[inline(always)]
fn batch_hit(d: &DiskLanes, j0: usize, ray: &pc_tree::Ray) -> bool {
    let (o, dir) = (ray.origin, ray.dir);
    {
        let ld = |k: usize| -> [f32; W] { d.v[k][j0..j0 + W].try_into().unwrap() };
        let (px, py, pz) = (ld(0), ld(1), ld(2));
        let (nx, ny, nz) = (ld(3), ld(4), ld(5));
        let r2 = ld(6);
        let (kx, ky, kz, kw) = (ld(7), ld(8), ld(9), ld(10));
        let mut hit = [false; W];
        for l in 0..W {
            let denom = dir.x * nx[l] + dir.y * ny[l] + dir.z * nz[l];
            let (cx, cy, cz) = (px[l] - o.x, py[l] - o.y, pz[l] - o.z);
            let th = (cx * nx[l] + cy * ny[l] + cz * nz[l]) / denom;
            let (xx, xy, xz) = (o.x + dir.x * th, o.y + dir.y * th, o.z + dir.z * th);
            let (dx, dy, dz) = (xx - px[l], xy - py[l], xz - pz[l]);
            let inside = dx * dx + dy * dy + dz * dz <= r2[l];
            let kept = dx * kx[l] + dy * ky[l] + dz * kz[l] <= kw[l];
            hit[l] = (denom.abs() >= 1e-8) & (th >= ray.t_min) & (th <= ray.t_max) & inside & kept;
        }
        hit.iter().any(|&h| h)
    }
}

/// For each ray, whether a disk of `d` blocks it, into `out` (cleared first). No fused
/// multiply-adds: the answers are those of the octree walk, bit for bit.
pub fn any_hit(d: &DiskLanes, rays: &mut dyn Iterator<Item = &pc_tree::Ray>, out: &mut Vec<bool>) {
    out.clear();
    #[cfg(target_arch = "x86_64")]
    if fused() {
        // SAFETY: the CPU has AVX2.
        return unsafe { any_hit_avx2(d, rays, out) };
    }
    out.extend(rays.map(|r| any_hit_impl(d, r)));
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn any_hit_avx2(
    d: &DiskLanes,
    rays: &mut dyn Iterator<Item = &pc_tree::Ray>,
    out: &mut Vec<bool>,
) {
    out.extend(rays.map(|r| any_hit_impl(d, r)));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expansion;

    #[test]
    fn lane_kernel_coeffs_match_the_scalar_ones() {
        for order in [0, 1, 3, 5] {
            let b = Basis::new(order);
            let mut r = [Z; 3];
            for l in 0..W {
                let x = l as f32;
                r[0][l] = 0.3 + 0.1 * x;
                r[1][l] = -0.2 + 0.05 * x * x;
                r[2][l] = 0.7 - 0.13 * x;
            }
            let mut a = vec![Z; b.len() + 1];
            let mut g = vec![[Z; 6]; b.len()];
            kernel_coeffs(&b, &r, &mut a, &mut g);
            let mut sa = vec![0.0; b.len() + 1];
            let mut sg = vec![[0.0; 6]; b.len()];
            for l in 0..W {
                expansion::kernel_coeffs(&b, [r[0][l], r[1][l], r[2][l]], &mut sa, &mut sg);
                for i in 0..b.len() {
                    for c in 0..6 {
                        assert_eq!(g[i][c][l], sg[i][c], "order {order} lane {l} index {i}");
                    }
                }
            }
        }
    }
}
