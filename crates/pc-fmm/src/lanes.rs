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

    /// Transpose: `out[e][l] = rows[l][e]` for every element `e` of the (equally long) rows.
    #[inline(always)]
    fn gather(rows: &[&[f32]; W], out: &mut [L]) {
        for (e, o) in out.iter_mut().enumerate().take(rows[0].len()) {
            for l in 0..W {
                o[l] = rows[l][e];
            }
        }
    }
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

    #[inline(always)]
    fn gather(rows: &[&[f32]; W], out: &mut [L]) {
        let n = rows[0].len();
        assert!(rows.iter().all(|r| r.len() == n) && out.len() >= n);
        let mut e = 0;
        while e + W <= n {
            // SAFETY: Fused runs only inside functions compiled for AVX2 (and so AVX); the
            // rows hold `n ≥ e + 8` floats and `out` at least `n` lanes (asserted).
            unsafe { transpose8(rows, e, &mut out[e..e + W]) };
            e += W;
        }
        for (k, o) in out[e..n].iter_mut().enumerate() {
            for l in 0..W {
                o[l] = rows[l][e + k];
            }
        }
    }
}

/// `out[k][l] = rows[l][e + k]` for `k < 8`: an 8×8 transpose in AVX registers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
unsafe fn transpose8(rows: &[&[f32]; W], e: usize, out: &mut [L]) {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees 8 floats from `e` in every row and 8 lanes in `out`.
    unsafe {
        let r: [__m256; 8] = std::array::from_fn(|l| _mm256_loadu_ps(rows[l].as_ptr().add(e)));
        let t0 = _mm256_unpacklo_ps(r[0], r[1]);
        let t1 = _mm256_unpackhi_ps(r[0], r[1]);
        let t2 = _mm256_unpacklo_ps(r[2], r[3]);
        let t3 = _mm256_unpackhi_ps(r[2], r[3]);
        let t4 = _mm256_unpacklo_ps(r[4], r[5]);
        let t5 = _mm256_unpackhi_ps(r[4], r[5]);
        let t6 = _mm256_unpacklo_ps(r[6], r[7]);
        let t7 = _mm256_unpackhi_ps(r[6], r[7]);
        let s0 = _mm256_shuffle_ps::<0x44>(t0, t2);
        let s1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
        let s2 = _mm256_shuffle_ps::<0x44>(t1, t3);
        let s3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
        let s4 = _mm256_shuffle_ps::<0x44>(t4, t6);
        let s5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
        let s6 = _mm256_shuffle_ps::<0x44>(t5, t7);
        let s7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
        let c = [
            _mm256_permute2f128_ps::<0x20>(s0, s4),
            _mm256_permute2f128_ps::<0x20>(s1, s5),
            _mm256_permute2f128_ps::<0x20>(s2, s6),
            _mm256_permute2f128_ps::<0x20>(s3, s7),
            _mm256_permute2f128_ps::<0x31>(s0, s4),
            _mm256_permute2f128_ps::<0x31>(s1, s5),
            _mm256_permute2f128_ps::<0x31>(s2, s6),
            _mm256_permute2f128_ps::<0x31>(s3, s7),
        ];
        for (o, v) in out.iter_mut().zip(c) {
            _mm256_storeu_ps(o.as_mut_ptr(), v);
        }
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

/// A kernel as a function for any CPU and a twin compiled for AVX2 and FMA, picked at run time:
/// `dispatched!(pub fn name / name_fused / name_impl(args) -> ret { body })` makes the generic
/// `name_impl::<I: Isa>` with the body (which names the arithmetic `I`), its AVX2+FMA
/// instance `name_fused`, and `name`, which picks one.
macro_rules! dispatched {
    ($(#[$m:meta])* $vis:vis fn $name:ident / $fused:ident / $imp:ident
        ($($a:ident : $t:ty),* $(,)?) $(-> $r:ty)? $body:block) => {
        $(#[$m])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($a: $t),*) $(-> $r)? {
            #[cfg(target_arch = "x86_64")]
            if fused() {
                // SAFETY: the CPU has AVX2 and FMA.
                return unsafe { $fused($($a),*) };
            }
            $imp::<Plain>($($a),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn $fused($($a: $t),*) $(-> $r)? {
            $imp::<Fused>($($a),*)
        }

        #[inline(always)]
        #[allow(clippy::too_many_arguments)]
        fn $imp<I: Isa>($($a: $t),*) $(-> $r)? $body
    };
}

dispatched!(
    /// M2M (`up`: add the moments `src` of a child a `delta` from the parent's centre to the
    /// parent's `dst`) or L2L (add the parent's local expansion `src`, re-expanded about a
    /// child centre `delta` from the parent's, to the child's `dst`).
    pub fn shift / shift_fused / shift_impl(
        b: &Basis,
        src: &[Coef],
        delta: [f32; 3],
        pow: &mut [f32],
        dst: &mut [Coef],
        up: bool,
    ) {
    b.monomials(delta, pow);
    for &(big, small, d, c) in &b.shift {
        let w = c * pow[d as usize];
        let (from, to) = if up { (small, big) } else { (big, small) };
        let (x, y) = (&src[from as usize], &mut dst[to as usize]);
        for k in 0..9 {
            y[k] = I::madd(w, x[k], y[k]);
        }
    }
}
);

dispatched!(
    /// P2M: add a source `q` at offset `off` from the centre to the moments `m`.
    pub fn p2m / p2m_fused / p2m_impl(
        b: &Basis,
        q: &Coef,
        off: [f32; 3],
        pow: &mut [f32],
        m: &mut [Coef],
    ) {
    b.monomials(off, pow);
    for (mi, &w) in m.iter_mut().zip(pow.iter()) {
        for k in 0..9 {
            mi[k] = I::madd(w, q[k], mi[k]);
        }
    }
}
);

dispatched!(
    /// L2P: the field of a local expansion at offset `off` from its centre (3 per colour).
    pub fn l2p / l2p_fused / l2p_impl(
        b: &Basis,
        local: &[Coef],
        off: [f32; 3],
        pow: &mut [f32],
    ) -> Coef {
    b.monomials(off, pow);
    let mut out = [0.0f32; 9];
    for (l, &w) in local.iter().zip(pow.iter()) {
        for k in 0..9 {
            out[k] = I::madd(w, l[k], out[k]);
        }
    }
    out
}
);

/// Scratch of one worker: kernel coefficients, gathered source moments and accumulators, all
/// per lane.
pub struct Scratch {
    /// Zero moments for the lanes a batch leaves empty.
    zero: Vec<f32>,
    a: Vec<L>,
    g: Vec<[L; 6]>,
    ms: Vec<[L; 9]>,
    acc: Vec<[L; 9]>,
}

impl Scratch {
    pub fn new(b: &Basis) -> Scratch {
        Scratch {
            zero: vec![0.0; b.len() * 9],
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

    /// New source weights, in place.
    pub fn set_weights(&mut self, w: &[[f32; 3]]) {
        use rayon::prelude::*;
        for (c, col) in self.w.iter_mut().enumerate() {
            col[..w.len()]
                .par_iter_mut()
                .zip(w)
                .for_each(|(x, wi)| *x = wi[c]);
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
    let mut f = Z;
    let mut rows: [&[f32]; W] = [&s.zero; W];
    for l in 0..W {
        if let Some(&(src, fl)) = batch.get(l) {
            let c = t.center[src as usize];
            for k in 0..3 {
                r[k][l] = c[k] - ca[k];
            }
            let sc = t.compact[src as usize] as usize;
            rows[l] = m[sc * np..(sc + 1) * np].as_flattened();
            f[l] = fl;
        } else {
            r[0][l] = 1.0;
        }
    }
    I::gather(&rows, s.ms.as_flattened_mut());
    kernel_coeffs(b, &r, &mut s.a, &mut s.g);
    // The fractions scale the kernel (one vector per coefficient) instead of the moments.
    for gi in s.g.iter_mut() {
        for gc in gi.iter_mut() {
            for l in 0..W {
                gc[l] *= f[l];
            }
        }
    }
    // The terms come sorted by β: each β's sum stays in registers.
    let mut k = 0;
    while k < b.m2l.len() {
        let bb = b.m2l[k].1;
        let mut acc = s.acc[bb as usize];
        while k < b.m2l.len() && b.m2l[k].1 == bb {
            let (a, _, gi, c) = b.m2l[k];
            apply::<I>(c, &s.g[gi as usize], &s.ms[a as usize], &mut acc);
            k += 1;
        }
        s.acc[bb as usize] = acc;
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

dispatched!(
    /// M2L and P2L into one receiving node's local expansion (centre `ca`): eight tasks at a
    /// time.
    pub fn node / node_fused / node_impl(
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
);

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
    let mut rows: [&[f32]; W] = [&s.zero; W];
    for l in 0..W {
        if let Some(&(i, src, _)) = batch.get(l) {
            let (c, x) = (t.center[src as usize], p.pos[i as usize]);
            for k in 0..3 {
                r[k][l] = c[k] - x[k];
            }
            let sc = t.compact[src as usize] as usize;
            rows[l] = m[sc * np..(sc + 1) * np].as_flattened();
        } else {
            r[0][l] = 1.0;
        }
    }
    if !uniform {
        I::gather(&rows, s.ms.as_flattened_mut());
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
    n * W / (n.div_ceil(W) * W).max(1)
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

/// Positions and normals of the splats `at..at + W` (SplatLanes is padded with W splats, so a
/// batch never reads past its end).
#[inline(always)]
fn splat_lanes(sl: &SplatLanes, at: usize) -> ([L; 3], [L; 3]) {
    let lane = |v: &Vec<f32>| -> L { v[at..at + W].try_into().unwrap() };
    (sl.pos.each_ref().map(lane), sl.normal.each_ref().map(lane))
}

/// The near kernel of one pair from `d = x_j − x_i` ([`crate::cpu::kernel_near`]), or 0 where
/// `ok` fails or either side faces away.
#[inline(always)]
fn near_pair(d: [f32; 3], ni: [f32; 3], nj: [f32; 3], aj: f32, ok: bool) -> f32 {
    const PI: f32 = std::f32::consts::PI;
    let ci = ni[0] * d[0] + ni[1] * d[1] + ni[2] * d[2];
    let cj = -(nj[0] * d[0] + nj[1] * d[1] + nj[2] * d[2]);
    let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let v = ci * cj / (r2 * (PI * r2 + aj));
    if ok & (ci > 0.0) & (cj > 0.0) {
        v
    } else {
        0.0
    }
}

/// P2P with lanes over receivers: per source, eight receivers at a time.
#[inline(always)]
fn p2p_by_receivers<I: Isa>(sl: &SplatLanes, task: &LeafTask, lo: u32, o: &mut [[f32; 3]]) {
    let (ilo, ihi) = (task.recv_lo as usize, task.recv_hi as usize);
    let mut i0 = ilo;
    while i0 < ihi {
        let (x, n) = splat_lanes(sl, i0);
        let active: L = sl.active[i0..i0 + W].try_into().unwrap();
        let mut acc = [Z; 3];
        for j in task.src_lo as usize..task.src_hi as usize {
            let xj = [sl.pos[0][j], sl.pos[1][j], sl.pos[2][j]];
            let nj = [sl.normal[0][j], sl.normal[1][j], sl.normal[2][j]];
            let (aj, wj) = (sl.area[j], [sl.w[0][j], sl.w[1][j], sl.w[2][j]]);
            // No masks in the loop: a splat against itself has d = 0 and no positive cosine, an
            // inactive source has zero weight, and the lanes past the task's receivers or of
            // inactive ones are not written.
            let mut k = Z;
            for l in 0..W {
                let d = [xj[0] - x[0][l], xj[1] - x[1][l], xj[2] - x[2][l]];
                let ni = [n[0][l], n[1][l], n[2][l]];
                k[l] = near_pair(d, ni, nj, aj, true);
            }
            for c in 0..3 {
                for l in 0..W {
                    acc[c][l] = I::madd(k[l], wj[c], acc[c][l]);
                }
            }
        }
        for l in (0..W.min(ihi - i0)).filter(|&l| active[l] > 0.0) {
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
            let (x, n) = splat_lanes(sl, j0);
            let lane = |v: &Vec<f32>| -> L { v[j0..j0 + W].try_into().unwrap() };
            let area = lane(&sl.area);
            let w = sl.w.each_ref().map(lane);
            // Only the lanes past the task's sources are masked: a splat against itself has
            // d = 0 and no positive cosine, and an inactive source has zero weight.
            let full = j0 + W <= jhi;
            let mut k = Z;
            for l in 0..W {
                let d = [x[0][l] - xi[0], x[1][l] - xi[1], x[2][l] - xi[2]];
                let nj = [n[0][l], n[1][l], n[2][l]];
                k[l] = near_pair(d, ni, nj, area[l], full || j0 + l < jhi);
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

dispatched!(
    /// M2P and P2P into one leaf's splats `o` (first splat `lo`).
    pub fn leaf / leaf_fused / leaf_impl(
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
);

/// Every splat's disk as structure of arrays for [`blocked`] (centre, normal, squared radius,
/// border clip), in data-pool order, padded with [`W`] disks no ray meets.
pub struct DiskLanes {
    v: [Vec<f32>; 11],
}

impl DiskLanes {
    pub fn new(splats: &[pc_artifact::octree::Splat]) -> DiskLanes {
        use rayon::prelude::*;
        let n = splats.len();
        // Padding (and the start of every lane): a zero normal fails the parallel test, and a
        // negative squared radius the disk test.
        let mut v: [Vec<f32>; 11] =
            std::array::from_fn(|k| vec![if k == 6 { -1.0 } else { 0.0 }; n + W]);
        // Blocks of splats in parallel, each writing its stretch of the eleven lanes.
        const BLOCK: usize = 1 << 14;
        let mut blocks: Vec<Vec<&mut [f32]>> = (0..n.div_ceil(BLOCK))
            .map(|_| Vec::with_capacity(11))
            .collect();
        for lane in v.iter_mut() {
            for (b, part) in lane[..n].chunks_mut(BLOCK).enumerate() {
                blocks[b].push(part);
            }
        }
        blocks
            .into_par_iter()
            .zip(splats.par_chunks(BLOCK))
            .for_each(|(mut lanes, block)| {
                for (i, s) in block.iter().enumerate() {
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
                    for (lane, x) in lanes.iter_mut().zip(vals) {
                        lane[i] = x;
                    }
                }
            });
        DiskLanes { v }
    }
}

/// The octree leaves a shaft holds, for [`blocked`]: each leaf's splat range, slab and the box of
/// its disks, and a tree of boxes over them (level 0 the leaves' boxes, level `k + 1` the box
/// of each batch of [`W`] level-`k` boxes, up to a level of at most [`W`]). The leaves come in
/// the order the octree listed them, so a batch is compact.
#[derive(Default)]
pub struct LeafLanes {
    ranges: Vec<(u32, u32)>,
    /// Per level: min xyz, max xyz, padded to whole batches with empty boxes.
    levels: Vec<[Vec<f32>; 6]>,
    /// Per leaf (level 0's order and padding): the slab of its disks, normal xyz, lo, hi.
    slabs: [Vec<f32>; 5],
}

impl LeafLanes {
    /// Load the leaves `(splat range, disk box, disk slab)`.
    pub fn load(&mut self, leaves: &[((u32, u32), pc_tree::shaft::Aabb, pc_tree::shaft::Slab)]) {
        use pc_tree::shaft::Aabb;
        self.ranges.clear();
        self.ranges.extend(leaves.iter().map(|x| x.0));
        for v in self.slabs.iter_mut() {
            v.clear();
        }
        for (_, _, sl) in leaves {
            for (v, x) in self
                .slabs
                .iter_mut()
                .zip([sl.n.x, sl.n.y, sl.n.z, sl.lo, sl.hi])
            {
                v.push(x);
            }
        }
        while !self.slabs[0].len().is_multiple_of(W) {
            for (v, x) in self.slabs.iter_mut().zip([0.0, 0.0, 0.0, -1.0, 1.0]) {
                v.push(x);
            }
        }
        let mut boxes: Vec<Aabb> = leaves.iter().map(|x| x.1).collect();
        self.levels.clear();
        loop {
            let mut level: [Vec<f32>; 6] = Default::default();
            for bx in &boxes {
                for k in 0..3 {
                    level[k].push(bx.min[k]);
                    level[k + 3].push(bx.max[k]);
                }
            }
            while !level[0].len().is_multiple_of(W) {
                for (k, v) in level.iter_mut().enumerate() {
                    v.push(if k < 3 {
                        f32::INFINITY
                    } else {
                        f32::NEG_INFINITY
                    });
                }
            }
            self.levels.push(level);
            if boxes.len() <= W {
                break;
            }
            boxes = boxes
                .chunks(W)
                .map(|c| c.iter().fold(Aabb::EMPTY, |a, &b| a.union(b)))
                .collect();
        }
    }
}

/// Whether any disk of the leaves `c` blocks the ray (a hit in `[t_min, t_max]`): slab tests of
/// eight boxes at a time down the box tree, at a leaf also whether the ray's stretch in its box
/// reaches the slab of its disks ([`pc_tree::shaft::Slab`], widened past the rounding: a
/// conservative skip), then the ray-disk test of the octree walk (`pc_tree::accel`), the same
/// operations in the same order, eight disks at a time.
#[inline(always)]
fn any_hit_impl(c: &LeafLanes, d: &DiskLanes, ray: &pc_tree::Ray) -> bool {
    let Some(top) = c.levels.len().checked_sub(1) else {
        return false;
    };
    // A zero direction component gets a huge finite inverse, so no 0 · ∞ arises.
    let inv = ray.dir.to_array().map(|x| {
        if x.abs() < 1e-20 {
            1e20f32.copysign(x)
        } else {
            1.0 / x
        }
    });
    let o3 = ray.origin.to_array();
    // (level, first box of the batch): at most W − 1 entries per level wait at a time, and a
    // list of u32 leaves has at most 11 levels.
    let mut stack = [(0u32, 0u32); 12 * W];
    stack[0] = (top as u32, 0);
    let mut sp = 1;
    while sp > 0 {
        sp -= 1;
        let (lvl, b0) = stack[sp];
        let (lvl, b0) = (lvl as usize, b0 as usize);
        let level = &c.levels[lvl];
        let lb = |k: usize| -> [f32; W] { level[k][b0..b0 + W].try_into().unwrap() };
        let (lo, hi) = ([lb(0), lb(1), lb(2)], [lb(3), lb(4), lb(5)]);
        let mut meets = [false; W];
        let mut span = [(0.0f32, 0.0f32); W];
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
            span[l] = (near, far);
        }
        if lvl == 0 {
            // The ray's stretch inside a leaf's box must reach the slab of its disks.
            let sl = |k: usize| -> [f32; W] { c.slabs[k][b0..b0 + W].try_into().unwrap() };
            let (nx, ny, nz, slo, shi) = (sl(0), sl(1), sl(2), sl(3), sl(4));
            for l in 0..W {
                let a = nx[l] * o3[0] + ny[l] * o3[1] + nz[l] * o3[2];
                let b = nx[l] * ray.dir.x + ny[l] * ray.dir.y + nz[l] * ray.dir.z;
                let (s1, s2) = (a + b * span[l].0, a + b * span[l].1);
                meets[l] &= (s1.max(s2) >= slo[l]) & (s1.min(s2) <= shi[l]);
            }
        }
        for l in (0..W).filter(|&l| meets[l]) {
            if lvl == 0 {
                let (a, b) = c.ranges[b0 + l];
                if range_hit(d, a as usize, b as usize, ray) {
                    return true;
                }
            } else {
                stack[sp] = ((lvl - 1) as u32, ((b0 + l) * W) as u32);
                sp += 1;
            }
        }
    }
    false
}

/// The disks `lo..hi` of `d` against the ray, eight at a time.
#[inline(always)]
fn range_hit(d: &DiskLanes, lo: usize, hi: usize, ray: &pc_tree::Ray) -> bool {
    let (o, dir) = (ray.origin, ray.dir);
    let mut j0 = lo;
    while j0 < hi {
        // DiskLanes is padded with W disks, so a batch never reads past its end.
        let ld = |k: usize| -> [f32; W] { d.v[k][j0..j0 + W].try_into().unwrap() };
        let (px, py, pz) = (ld(0), ld(1), ld(2));
        let (nx, ny, nz) = (ld(3), ld(4), ld(5));
        let r2 = ld(6);
        let mut hit = [false; W];
        let mut at = [[0.0f32; 3]; W];
        for l in 0..W {
            let denom = dir.x * nx[l] + dir.y * ny[l] + dir.z * nz[l];
            let (cx, cy, cz) = (px[l] - o.x, py[l] - o.y, pz[l] - o.z);
            let th = (cx * nx[l] + cy * ny[l] + cz * nz[l]) / denom;
            let (xx, xy, xz) = (o.x + dir.x * th, o.y + dir.y * th, o.z + dir.z * th);
            let (dx, dy, dz) = (xx - px[l], xy - py[l], xz - pz[l]);
            let inside = dx * dx + dy * dy + dz * dz <= r2[l];
            at[l] = [xx, xy, xz];
            hit[l] = (denom.abs() >= 1e-8)
                & (th >= ray.t_min)
                & (th <= ray.t_max)
                & inside
                & (j0 + l < hi);
        }
        // The border clip only for the disks the ray meets (rare): the scalar test the octree
        // walk uses, so the answer stays the walk's bit for bit.
        for l in 0..W {
            if hit[l] {
                let j = j0 + l;
                let c = [d.v[0][j], d.v[1][j], d.v[2][j]];
                let n = [d.v[3][j], d.v[4][j], d.v[5][j]];
                let clip = [d.v[7][j], d.v[8][j], d.v[9][j], d.v[10][j]];
                if pc_artifact::octree::within_clip(c, n, clip, at[l]) {
                    return true;
                }
            }
        }
        j0 += W;
    }
    false
}

dispatched!(
    /// Whether a disk of the leaves `c` blocks the ray. No fused multiply-adds (the compiler
    /// never contracts without being asked): the answer is the octree walk's, bit for bit.
    pub fn blocked / blocked_fused / blocked_impl(
        c: &LeafLanes,
        d: &DiskLanes,
        ray: &pc_tree::Ray,
    ) -> bool {
    any_hit_impl(c, d, ray)
}
);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expansion;

    #[test]
    fn the_gather_transposes() {
        for n in [4, 8, 20, 180, 183] {
            let data: Vec<Vec<f32>> = (0..W)
                .map(|l| (0..n).map(|e| (l * 1000 + e) as f32).collect())
                .collect();
            let rows: [&[f32]; W] = std::array::from_fn(|l| data[l].as_slice());
            let mut want = vec![Z; n];
            Plain::gather(&rows, &mut want);
            for (e, o) in want.iter().enumerate() {
                for l in 0..W {
                    assert_eq!(o[l], (l * 1000 + e) as f32);
                }
            }
            #[cfg(target_arch = "x86_64")]
            if fused() {
                let mut got = vec![Z; n];
                Fused::gather(&rows, &mut got);
                assert_eq!(got, want, "{n} elements");
            }
        }
    }

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
