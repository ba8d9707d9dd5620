//! Cartesian Taylor expansions of the form-factor tensor kernel (docs/fmm.md).
//!
//! Without its clamps, the point-to-point form factor kernel is
//! `K(x, nₓ, y, n_y) = −nₓᵀ G(y − x) n_y / π` with the tensor `G(d) = d dᵀ / |d|⁴`, smooth
//! away from `d = 0`. With `d = R + s − t` (`R` from the receiver node's centre to the source
//! node's, `s` a source's offset from its centre, `t` a receiver's), the Taylor series of `G`
//! about `R`, truncated at total degree `p`, separates into source moments and receiver
//! monomials:
//!
//! `G(R + s − t) ≈ Σ_{|α|+|β|≤p} (−1)^{|β|} (α+β)!/(α! β!) g_{α+β}(R) s^α t^β`
//!
//! with `g_γ = ∂^γ G(R) / γ!`, computed by the recurrence of [`kernel_coeffs`].
//!
//! Multi-indices are stored in graded order (every index of degree m before any of degree
//! m + 1), so an expansion of order q < p is a prefix of one of order p.

/// Coefficients per multi-index: the 3 normal components of each of the 3 colours,
/// `[colour * 3 + component]`.
pub type Coef = [f32; 9];

/// Symmetric 3×3 tensor: xx, xy, xz, yy, yz, zz.
pub type Sym = [f32; 6];

/// The multi-indices of one expansion order and the index tables of every translation.
#[derive(Clone, Debug)]
pub struct Basis {
    pub order: usize,
    /// Multi-indices in graded order.
    pub exps: Vec<[u8; 3]>,
    /// `lookup[(a * (p+1) + b) * (p+1) + c]`: index of (a, b, c), or `u16::MAX`.
    lookup: Vec<u16>,
    /// Per index: index of γ − e_k (or `NONE`).
    pub minus1: Vec<[u16; 3]>,
    /// Per index: index of γ − 2e_k (or `NONE`).
    pub minus2: Vec<[u16; 3]>,
    /// Per index: index of γ − e_i − e_j for the six tensor components (or `NONE`).
    pub minus_ij: Vec<[u16; 6]>,
    /// Per index: |γ|.
    pub degree: Vec<u8>,
    /// M2L terms (α, β, α+β, (−1)^{|β|} (α+β)!/(α!β!)) with |α| + |β| ≤ p, sorted by β.
    pub m2l: Vec<(u16, u16, u16, f32)>,
    /// Translation terms (big, small, big − small, big!/(small! (big − small)!)) with
    /// small ≤ big componentwise: M2M and L2L.
    pub shift: Vec<(u16, u16, u16, f32)>,
    /// [`kernel_coeffs`]'s recurrence per index, branch-free: a `NONE` index points at the
    /// zero slot `len()` of the scratch instead.
    pub(crate) recur: Vec<Recur>,
}

/// One step of [`kernel_coeffs`]: `a_γ = (c1 Σ_k R_k a[m1_k] + c2 Σ_k a[m2_k]) / |R|²` and the
/// six tensor components' lower indices.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Recur {
    pub(crate) m1: [u16; 3],
    pub(crate) m2: [u16; 3],
    pub(crate) mij: [u16; 6],
    pub(crate) c1: f32,
    pub(crate) c2: f32,
}

pub const NONE: u16 = u16::MAX;

/// The six (i, j) pairs of a symmetric tensor, in [`Sym`] order.
pub const SYM_IJ: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

fn binom(n: u32, k: u32) -> f64 {
    let mut r = 1.0f64;
    for i in 0..k {
        r = r * (n - i) as f64 / (i + 1) as f64;
    }
    r
}

impl Basis {
    /// Number of multi-indices of total degree at most `order`.
    pub fn size_of(order: usize) -> usize {
        (order + 1) * (order + 2) * (order + 3) / 6
    }

    pub fn new(order: usize) -> Basis {
        let p = order;
        let mut exps = Vec::new();
        for m in 0..=p {
            for a in (0..=m).rev() {
                for b in (0..=m - a).rev() {
                    exps.push([a as u8, b as u8, (m - a - b) as u8]);
                }
            }
        }
        let w = p + 1;
        let mut lookup = vec![NONE; w * w * w];
        for (i, e) in exps.iter().enumerate() {
            lookup[(e[0] as usize * w + e[1] as usize) * w + e[2] as usize] = i as u16;
        }
        let find = |e: [i32; 3]| -> u16 {
            if e.iter().any(|&x| x < 0) || e.iter().sum::<i32>() > p as i32 {
                NONE
            } else {
                lookup[(e[0] as usize * w + e[1] as usize) * w + e[2] as usize]
            }
        };
        let as_i = |e: [u8; 3]| [e[0] as i32, e[1] as i32, e[2] as i32];
        let mut minus1 = Vec::new();
        let mut minus2 = Vec::new();
        let mut minus_ij = Vec::new();
        for &e in &exps {
            let e = as_i(e);
            let mut m1 = [NONE; 3];
            let mut m2 = [NONE; 3];
            for k in 0..3 {
                let mut x = e;
                x[k] -= 1;
                m1[k] = find(x);
                x[k] -= 1;
                m2[k] = find(x);
            }
            let mut mij = [NONE; 6];
            for (c, &(i, j)) in SYM_IJ.iter().enumerate() {
                let mut x = e;
                x[i] -= 1;
                x[j] -= 1;
                mij[c] = find(x);
            }
            minus1.push(m1);
            minus2.push(m2);
            minus_ij.push(mij);
        }
        let degree: Vec<u8> = exps.iter().map(|e| e[0] + e[1] + e[2]).collect();
        let mut m2l = Vec::new();
        for (bi, &b) in exps.iter().enumerate() {
            for (ai, &a) in exps.iter().enumerate() {
                let g = [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
                let gi = find(as_i(g));
                if gi == NONE {
                    continue;
                }
                let mut c = 1.0f64;
                for k in 0..3 {
                    c *= binom(g[k] as u32, a[k] as u32);
                }
                let db: u32 = b.iter().map(|&x| x as u32).sum();
                if db % 2 == 1 {
                    c = -c;
                }
                m2l.push((ai as u16, bi as u16, gi, c as f32));
            }
        }
        let mut shift = Vec::new();
        for (bi, &big) in exps.iter().enumerate() {
            for (si, &small) in exps.iter().enumerate() {
                if (0..3).all(|k| small[k] <= big[k]) {
                    let d = [big[0] - small[0], big[1] - small[1], big[2] - small[2]];
                    let mut c = 1.0f64;
                    for k in 0..3 {
                        c *= binom(big[k] as u32, small[k] as u32);
                    }
                    shift.push((bi as u16, si as u16, find(as_i(d)), c as f32));
                }
            }
        }
        const NU: f32 = 2.0;
        let zero = exps.len() as u16;
        let z = |i: u16| if i == NONE { zero } else { i };
        let recur = (0..exps.len())
            .map(|i| {
                let m = degree[i] as f32;
                Recur {
                    m1: minus1[i].map(z),
                    m2: minus2[i].map(z),
                    mij: minus_ij[i].map(z),
                    c1: if m > 0.0 {
                        -(2.0 * m - 2.0 + 2.0 * NU) / m
                    } else {
                        0.0
                    },
                    c2: if m > 0.0 {
                        -(m - 2.0 + 2.0 * NU) / m
                    } else {
                        0.0
                    },
                }
            })
            .collect();
        Basis {
            recur,
            order,
            exps,
            lookup,
            minus1,
            minus2,
            minus_ij,
            degree,
            m2l,
            shift,
        }
    }

    pub fn len(&self) -> usize {
        self.exps.len()
    }

    pub fn is_empty(&self) -> bool {
        self.exps.is_empty()
    }

    /// Index of a multi-index, if within the order.
    pub fn index(&self, e: [u8; 3]) -> Option<usize> {
        let w = self.order + 1;
        if e.iter().map(|&x| x as usize).sum::<usize>() > self.order {
            return None;
        }
        let i = self.lookup[(e[0] as usize * w + e[1] as usize) * w + e[2] as usize];
        (i != NONE).then_some(i as usize)
    }

    /// All monomials `v^α` of the basis.
    #[inline]
    pub fn monomials(&self, v: [f32; 3], out: &mut [f32]) {
        out[0] = 1.0;
        for i in 1..self.exps.len() {
            // Each monomial is a lower one times one coordinate.
            let m = self.minus1[i];
            let k = if m[0] != NONE {
                0
            } else if m[1] != NONE {
                1
            } else {
                2
            };
            out[i] = out[m[k] as usize] * v[k];
        }
    }
}

/// Taylor coefficients `g_γ = ∂^γ G(R) / γ!` of `G(d) = d dᵀ / |d|⁴` about `R`, for every γ of
/// the basis. `a` is scratch of at least the basis size plus one (a zero slot).
///
/// `φ = |d|^{-2ν}` (ν = 2) obeys `s ∇φ = −ν φ ∇s` with `s = |d|²`; matching the coefficients of
/// `u^γ` in `s(R+u) · (u·∇φ) = −ν φ · (u·∇s)` gives, for `m = |γ| ≥ 1`,
/// `m |R|² a_γ = −(2m − 2 + 2ν) Σ_k R_k a_{γ−e_k} − (m − 2 + 2ν) Σ_k a_{γ−2e_k}`,
/// and `G_ij = (R_i + u_i)(R_j + u_j) φ` gives
/// `g^{ij}_γ = R_i R_j a_γ + R_i a_{γ−e_j} + R_j a_{γ−e_i} + a_{γ−e_i−e_j}`.
#[inline]
pub fn kernel_coeffs(basis: &Basis, r: [f32; 3], a: &mut [f32], g: &mut [Sym]) {
    let n = basis.len();
    assert!(
        a.len() > n && g.len() >= n,
        "kernel_coeffs: scratch too small"
    );
    let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    let inv_r2 = 1.0 / r2;
    a[0] = inv_r2 * inv_r2;
    a[n] = 0.0;
    // SAFETY (every `get_unchecked` below): `recur`'s indices are below `n` or the zero slot
    // `n`, and `a.len() > n` was asserted; `i < n <= g.len()`.
    let at = |a: &[f32], i: u16| unsafe { *a.get_unchecked(i as usize) };
    for i in 1..n {
        let t = unsafe { basis.recur.get_unchecked(i) };
        let s1 = r[0] * at(a, t.m1[0]) + r[1] * at(a, t.m1[1]) + r[2] * at(a, t.m1[2]);
        let s2 = at(a, t.m2[0]) + at(a, t.m2[1]) + at(a, t.m2[2]);
        a[i] = (t.c1 * s1 + t.c2 * s2) * inv_r2;
    }
    let rr = [
        r[0] * r[0],
        r[0] * r[1],
        r[0] * r[2],
        r[1] * r[1],
        r[1] * r[2],
        r[2] * r[2],
    ];
    for i in 0..n {
        let t = unsafe { basis.recur.get_unchecked(i) };
        let ai = at(a, i as u16);
        let b = [at(a, t.m1[0]), at(a, t.m1[1]), at(a, t.m1[2])];
        let out = unsafe { g.get_unchecked_mut(i) };
        for (c, &(p, q)) in SYM_IJ.iter().enumerate() {
            out[c] = rr[c] * ai + r[p] * b[q] + r[q] * b[p] + at(a, t.mij[c]);
        }
    }
}

/// `out += w · G q` for the 3 colours of `q`.
#[inline(always)]
pub fn sym_apply_add(g: &Sym, q: &Coef, w: f32, out: &mut Coef) {
    for c in 0..3 {
        let (x, y, z) = (q[c * 3], q[c * 3 + 1], q[c * 3 + 2]);
        out[c * 3] += w * (g[0] * x + g[1] * y + g[2] * z);
        out[c * 3 + 1] += w * (g[1] * x + g[3] * y + g[4] * z);
        out[c * 3 + 2] += w * (g[2] * x + g[4] * y + g[5] * z);
    }
}

/// M2L: `local += f · Σ terms` for source moments `m` about a centre `R` away.
#[inline]
pub fn m2l(basis: &Basis, g: &[Sym], m: &[Coef], f: f32, local: &mut [Coef]) {
    for &(a, b, gi, c) in &basis.m2l {
        sym_apply_add(
            &g[gi as usize],
            &m[a as usize],
            c * f,
            &mut local[b as usize],
        );
    }
}

/// M2M: add the moments `child` (about a centre `delta` from the parent's) to `parent`.
#[inline]
pub fn m2m(basis: &Basis, child: &[Coef], delta: [f32; 3], pow: &mut [f32], parent: &mut [Coef]) {
    crate::lanes::shift(basis, child, delta, pow, parent, true)
}

/// L2L: add the parent's local expansion, re-expanded about a child centre `delta` from the
/// parent's, to `child`.
#[inline]
pub fn l2l(basis: &Basis, parent: &[Coef], delta: [f32; 3], pow: &mut [f32], child: &mut [Coef]) {
    crate::lanes::shift(basis, parent, delta, pow, child, false)
}

/// Evaluate a local expansion at offset `t` from its centre: the field `F` (3 per colour).
#[inline]
pub fn l2p(basis: &Basis, local: &[Coef], t: [f32; 3], pow: &mut [f32]) -> Coef {
    crate::lanes::l2p(basis, local, t, pow)
}

/// P2M: add a source `q` at offset `s` from the centre to the moments.
#[inline]
pub fn p2m(basis: &Basis, q: &Coef, s: [f32; 3], pow: &mut [f32], m: &mut [Coef]) {
    crate::lanes::p2m(basis, q, s, pow, m)
}

/// Unclamped tensor `G(d) = d dᵀ / |d|⁴`.
#[inline]
pub fn g_exact(d: [f32; 3]) -> Sym {
    let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let i4 = 1.0 / (r2 * r2);
    [
        d[0] * d[0] * i4,
        d[0] * d[1] * i4,
        d[0] * d[2] * i4,
        d[1] * d[1] * i4,
        d[1] * d[2] * i4,
        d[2] * d[2] * i4,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval_taylor(basis: &Basis, r: [f32; 3], u: [f32; 3]) -> Sym {
        let mut a = vec![0.0; basis.len() + 1];
        let mut g = vec![[0.0; 6]; basis.len()];
        kernel_coeffs(basis, r, &mut a, &mut g);
        let mut pow = vec![0.0; basis.len()];
        basis.monomials(u, &mut pow);
        let mut out = [0.0f32; 6];
        for i in 0..basis.len() {
            for c in 0..6 {
                out[c] += g[i][c] * pow[i];
            }
        }
        out
    }

    #[test]
    fn basis_sizes_and_graded_order() {
        for p in 0..8 {
            let b = Basis::new(p);
            assert_eq!(b.len(), Basis::size_of(p));
            assert!(b.degree.windows(2).all(|w| w[0] <= w[1]));
            for (i, &e) in b.exps.iter().enumerate() {
                assert_eq!(b.index(e), Some(i));
            }
        }
    }

    #[test]
    fn taylor_series_converges_to_the_kernel() {
        let r = [0.7f32, -0.4, 0.5];
        let u = [0.08f32, 0.05, -0.06];
        let d = [r[0] + u[0], r[1] + u[1], r[2] + u[2]];
        let exact = g_exact(d);
        let norm = exact.iter().map(|x| x * x).sum::<f32>().sqrt();
        let mut last = f32::INFINITY;
        for p in 0..7 {
            let t = eval_taylor(&Basis::new(p), r, u);
            let err = t
                .iter()
                .zip(&exact)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f32>()
                .sqrt()
                / norm;
            assert!(err < last || err < 1e-6, "order {p}: {err} after {last}");
            last = err;
        }
        assert!(last < 1e-5, "order 6 error {last}");
    }

    #[test]
    fn first_derivatives_match_finite_differences() {
        let b = Basis::new(2);
        let r = [0.3f32, 0.9, -0.2];
        let mut a = vec![0.0; b.len() + 1];
        let mut g = vec![[0.0; 6]; b.len()];
        kernel_coeffs(&b, r, &mut a, &mut g);
        let h = 1e-3f32;
        for k in 0..3 {
            let mut rp = r;
            rp[k] += h;
            let mut rm = r;
            rm[k] -= h;
            let (gp, gm) = (g_exact(rp), g_exact(rm));
            let mut e = [0u8; 3];
            e[k] = 1;
            let i = b.index(e).unwrap();
            for c in 0..6 {
                let fd = (gp[c] - gm[c]) / (2.0 * h);
                assert!((fd - g[i][c]).abs() < 2e-3 * (1.0 + fd.abs()), "{k} {c}");
            }
        }
    }

    #[test]
    fn m2m_and_l2l_are_exact_shifts() {
        let b = Basis::new(4);
        let mut pow = vec![0.0; b.len()];
        // Moments of two sources about a child centre, shifted, equal moments about the parent.
        let q: Coef = [1.0, 0.5, -0.2, 0.3, 0.1, 0.9, -0.4, 0.2, 0.6];
        let child_c = [0.1f32, 0.2, -0.1];
        let srcs = [[0.12f32, 0.15, -0.05], [0.05, 0.22, -0.12]];
        let mut mc = vec![[0.0f32; 9]; b.len()];
        let mut mp = vec![[0.0f32; 9]; b.len()];
        for s in srcs {
            p2m(
                &b,
                &q,
                [s[0] - child_c[0], s[1] - child_c[1], s[2] - child_c[2]],
                &mut pow,
                &mut mc,
            );
            p2m(&b, &q, s, &mut pow, &mut mp);
        }
        let mut shifted = vec![[0.0f32; 9]; b.len()];
        m2m(&b, &mc, child_c, &mut pow, &mut shifted);
        for i in 0..b.len() {
            for k in 0..9 {
                assert!((shifted[i][k] - mp[i][k]).abs() < 1e-5, "{i} {k}");
            }
        }
        // A local expansion re-expanded about a child evaluates the same at any point.
        let local: Vec<Coef> = (0..b.len())
            .map(|i| {
                let mut c = [0.0f32; 9];
                for (k, x) in c.iter_mut().enumerate() {
                    *x = ((i * 9 + k) as f32 * 0.37).sin();
                }
                c
            })
            .collect();
        let mut lc = vec![[0.0f32; 9]; b.len()];
        l2l(&b, &local, child_c, &mut pow, &mut lc);
        let x = [0.13f32, 0.17, -0.08];
        let a = l2p(&b, &local, x, &mut pow);
        let c = l2p(
            &b,
            &lc,
            [x[0] - child_c[0], x[1] - child_c[1], x[2] - child_c[2]],
            &mut pow,
        );
        for k in 0..9 {
            assert!(
                (a[k] - c[k]).abs() < 1e-4 * (1.0 + a[k].abs()),
                "{k}: {} {}",
                a[k],
                c[k]
            );
        }
    }
}
