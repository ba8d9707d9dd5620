//! The radiosity solve, by restarted GMRES ([`solve_gmres`], the default) or Jacobi
//! ([`solve`]); docs/fmm.md "Solver".
//!
//! Jacobi iteration `L ← E + ρ ∘ T (L − Lₑ)` runs until the relative residual
//! `‖L_{k+1} − L_k‖_A / ‖L_{k+1} − Lₑ‖_A` (area-weighted L2 over RGB) falls below the
//! tolerance. The norm leaves out the emitters' own radiance `Lₑ`: a light 100 times brighter
//! than the room would otherwise make the residual look converged long before the
//! inter-reflections are.
//!
//! Jacobi with an FMM product: every iteration is one application of the operator `T`, which is
//! what the FMM makes O(N). The error left after stopping is about `r λ / (1 − λ)` with `λ`
//! the convergence rate (`r_k / r_{k−1}`), which [`Solution::error_estimate`] reports.

use crate::error::FmmError;
use crate::system::System;
use crate::tree::Points;

/// Anything that applies the transport operator `out_i = Σ_j f K(i, j) A_j L_j`.
pub trait Operator {
    /// One application at the configured order.
    fn apply(&mut self, radiance: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<(), FmmError> {
        self.apply_relaxed(radiance, out, 1.0).map(|_| ())
    }
    /// An application whose error may be up to `relax` (≥ 1) times [`Operator::apply`]'s: an
    /// operator with cheaper, coarser forms takes the cheapest within it (relaxed products of
    /// inexact Krylov methods, docs/fmm.md). Returns the expansion order used.
    fn apply_relaxed(
        &mut self,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        relax: f64,
    ) -> Result<u32, FmmError>;
    /// The expansion order of [`Operator::apply`].
    fn order(&self) -> u32;
    /// What runs it, for reports.
    fn device(&self) -> String;
}

/// Result of a solve.
#[derive(Clone, Debug, Default)]
pub struct Solution {
    pub radiance: Vec<[f32; 3]>,
    /// Relative residual after each iteration.
    pub residuals: Vec<f64>,
    /// Expansion order of each iteration's product.
    pub orders: Vec<u32>,
    pub converged: bool,
}

impl Solution {
    /// Estimated relative error left: `r λ / (1 − λ)` with `λ` the last residual ratio.
    pub fn error_estimate(&self) -> f64 {
        let n = self.residuals.len();
        if n < 2 {
            return self.residuals.last().copied().unwrap_or(0.0);
        }
        let (a, b) = (self.residuals[n - 2], self.residuals[n - 1]);
        let lambda = (b / a.max(1e-300)).min(0.99);
        b * lambda / (1.0 - lambda)
    }
}

/// Jacobi iteration. `progress(iteration, residual)` is called after each iteration.
pub fn solve(
    op: &mut dyn Operator,
    sys: &System,
    pts: &Points,
    tolerance: f64,
    max_iterations: u32,
    progress: &mut dyn FnMut(u32, f64),
) -> Result<Solution, FmmError> {
    let n = sys.source.len();
    let mut l = sys.source.clone();
    let mut t = vec![[0.0f32; 3]; n];
    let mut reflected = vec![[0.0f32; 3]; n];
    let mut sol = Solution::default();
    for it in 1..=max_iterations {
        for i in 0..n {
            for c in 0..3 {
                reflected[i][c] = l[i][c] - sys.emission.get(i).map_or(0.0, |e| e[c]);
            }
        }
        op.apply(&reflected, &mut t)?;
        sol.orders.push(op.order());
        let (mut dn, mut nn) = (0.0f64, 0.0f64);
        for i in 0..n {
            if !pts.active[i] {
                continue;
            }
            let a = pts.area[i] as f64;
            let mut new = [0.0f32; 3];
            for c in 0..3 {
                new[c] = sys.source[i][c] + sys.albedo[i][c] * t[i][c];
                let d = (new[c] - l[i][c]) as f64;
                let lit = (new[c] - sys.emission.get(i).map_or(0.0, |e| e[c])) as f64;
                dn += a * d * d;
                nn += a * lit * lit;
            }
            l[i] = new;
        }
        let r = if nn > 0.0 { (dn / nn).sqrt() } else { 0.0 };
        check_residual(it, r)?;
        sol.residuals.push(r);
        progress(it, r);
        if r < tolerance {
            sol.converged = true;
            break;
        }
    }
    sol.radiance = l;
    Ok(sol)
}

/// Krylov vectors kept before GMRES restarts (each N RGB doubles: 24 MB per million splats).
pub const GMRES_RESTART: usize = 16;

/// How [`solve_gmres`] runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gmres {
    /// It stops once the relative residual falls below this.
    pub tolerance: f64,
    /// It stops after this many products even if not converged.
    pub max_iterations: u32,
    /// Krylov vectors kept before a restart ([`GMRES_RESTART`]).
    pub restart: usize,
    /// Relaxed products (below).
    pub relaxed: bool,
}

/// Restarted GMRES on the same equation, written for the reflected part `x = L − Lₑ`:
/// `(I − ρ ∘ T) x = E − Lₑ`, one Krylov process per color channel, the three in lockstep so
/// that each step costs one application of `T` (the FMM product) for all three. Inner products
/// are area-weighted over the active splats, so the residual it reports,
/// `‖b − (I − ρT) x‖_A / ‖b‖_A` over RGB, is the norm Jacobi reports (Jacobi's update
/// `L_{k+1} − L_k` is exactly the residual of `L_k`), relative to the source instead of the
/// solution, which is stricter. Radiosity's operator has a spectrum clustered near 0 with a
/// few eigenvalues out to the scene's mean albedo, where Krylov methods converge much faster
/// than Jacobi's fixed rate (docs/fmm.md). `restart` bounds the stored basis (`restart` + 1
/// vectors of N RGB doubles).
///
/// `relaxed`: the product of Arnoldi step k may be `1 / ‖r_{k−1}‖` times less accurate than the
/// configured order's (‖r‖ the largest channel's relative residual so far in the cycle): an
/// error in that product moves the answer by about its size times `‖r_{k−1}‖`, so late products
/// at a lower order add no more error than each full one carries (Bouras & Frayssé 2005,
/// Simoncini & Szyld 2003; docs/fmm.md, "Relaxed products"). A restart's residual is always
/// computed at the full order.
pub fn solve_gmres(
    op: &mut dyn Operator,
    sys: &System,
    pts: &Points,
    how: Gmres,
    progress: &mut dyn FnMut(u32, f64),
) -> Result<Solution, FmmError> {
    let Gmres {
        tolerance,
        max_iterations,
        restart,
        relaxed,
    } = how;
    let n = sys.source.len();
    let m = restart.max(1);
    let emit = |i: usize, c: usize| sys.emission.get(i).map_or(0.0, |e| e[c]) as f64;
    let weight: Vec<f64> = (0..n)
        .map(|i| {
            if pts.active[i] {
                pts.area[i] as f64
            } else {
                0.0
            }
        })
        .collect();
    let b: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            if weight[i] == 0.0 {
                return [0.0; 3];
            }
            std::array::from_fn(|c| sys.source[i][c] as f64 - emit(i, c))
        })
        .collect();
    let dot = |u: &[[f64; 3]], v: &[[f64; 3]], c: usize| -> f64 {
        (0..n).map(|i| weight[i] * u[i][c] * v[i][c]).sum()
    };
    // y = (I − ρT) v on the active splats.
    let mut v32 = vec![[0.0f32; 3]; n];
    let mut t = vec![[0.0f32; 3]; n];
    let mut apply =
        |v: &[[f64; 3]], out: &mut Vec<[f64; 3]>, relax: f64| -> Result<u32, FmmError> {
            for i in 0..n {
                v32[i] = v[i].map(|x| x as f32);
            }
            // (At 1, every operator's configured order.)
            let order = op.apply_relaxed(&v32, &mut t, relax)?;
            out.clear();
            out.extend((0..n).map(|i| {
                if weight[i] == 0.0 {
                    [0.0; 3]
                } else {
                    std::array::from_fn(|c| v[i][c] - sys.albedo[i][c] as f64 * t[i][c] as f64)
                }
            }));
            Ok(order)
        };
    let b_norm = (0..3).map(|c| dot(&b, &b, c)).sum::<f64>().sqrt();
    check_residual(0, b_norm)?;
    let b_channel: [f64; 3] = std::array::from_fn(|c| dot(&b, &b, c).sqrt());
    // x0 = 0, so the first cycle starts from r0 = b without a product; a restart costs one
    // product more (not counted as an iteration: it adds no Krylov vector).
    let mut x = vec![[0.0f64; 3]; n];
    let mut sol = Solution::default();
    let mut w = Vec::with_capacity(n);
    let mut it = 0u32;
    'outer: while it < max_iterations && b_norm > 0.0 {
        let r0: Vec<[f64; 3]> = if it == 0 {
            b.clone()
        } else {
            apply(&x, &mut w, 1.0)?;
            (0..n)
                .map(|i| std::array::from_fn(|c| b[i][c] - w[i][c]))
                .collect()
        };
        let mut basis: Vec<Vec<[f64; 3]>> = Vec::with_capacity(m + 1);
        let beta: [f64; 3] = std::array::from_fn(|c| dot(&r0, &r0, c).sqrt());
        let scale = beta.map(|s| if s > 0.0 { 1.0 / s } else { 0.0 });
        basis.push(
            r0.iter()
                .map(|r| std::array::from_fn(|c| r[c] * scale[c]))
                .collect(),
        );
        // Per channel: Hessenberg columns (rotated), Givens rotations, the rotated rhs g.
        let mut h: Vec<[Vec<f64>; 3]> = vec![std::array::from_fn(|_| vec![0.0f64; m + 1]); m];
        let mut rot = vec![[(1.0f64, 0.0f64); 3]; m];
        let mut g: Vec<[f64; 3]> = vec![[0.0; 3]; m + 1];
        g[0] = beta;
        let mut k = 0;
        while k < m && it < max_iterations {
            // The largest channel's relative residual before this step.
            let r_prev = (0..3)
                .filter(|&c| b_channel[c] > 0.0)
                .map(|c| g[k][c].abs() / b_channel[c])
                .fold(0.0f64, f64::max);
            let relax = if relaxed && r_prev > 0.0 {
                (1.0 / r_prev).max(1.0)
            } else {
                1.0
            };
            sol.orders.push(apply(&basis[k], &mut w, relax)?);
            it += 1;
            for c in 0..3 {
                // Modified Gram-Schmidt.
                for (j, v) in basis.iter().enumerate() {
                    let hj = dot(&w, v, c);
                    h[k][c][j] = hj;
                    for i in 0..n {
                        w[i][c] -= hj * v[i][c];
                    }
                }
                h[k][c][k + 1] = dot(&w, &w, c).sqrt();
            }
            let next: Vec<[f64; 3]> = w
                .iter()
                .map(|x| {
                    std::array::from_fn(|c| {
                        let s = h[k][c][k + 1];
                        if s > 0.0 {
                            x[c] / s
                        } else {
                            0.0
                        }
                    })
                })
                .collect();
            for c in 0..3 {
                let col = &mut h[k][c];
                for (j, r) in rot.iter().enumerate().take(k) {
                    let (cs, sn) = r[c];
                    let (a, bb) = (col[j], col[j + 1]);
                    col[j] = cs * a + sn * bb;
                    col[j + 1] = -sn * a + cs * bb;
                }
                let (a, bb) = (col[k], col[k + 1]);
                let d = a.hypot(bb);
                let (cs, sn) = if d > 0.0 { (a / d, bb / d) } else { (1.0, 0.0) };
                rot[k][c] = (cs, sn);
                col[k] = d;
                col[k + 1] = 0.0;
                g[k + 1][c] = -sn * g[k][c];
                g[k][c] *= cs;
            }
            basis.push(next);
            k += 1;
            let r = (0..3).map(|c| g[k][c] * g[k][c]).sum::<f64>().sqrt() / b_norm;
            check_residual(it, r)?;
            sol.residuals.push(r);
            progress(it, r);
            if r < tolerance {
                sol.converged = true;
            }
            if sol.converged || it == max_iterations {
                update(&mut x, &basis, &h, &g, k);
                break 'outer;
            }
        }
        update(&mut x, &basis, &h, &g, k);
    }
    if b_norm == 0.0 {
        sol.converged = true;
    }
    sol.radiance = (0..n)
        .map(|i| {
            if weight[i] == 0.0 {
                sys.source[i]
            } else {
                std::array::from_fn(|c| (x[i][c] + emit(i, c)) as f32)
            }
        })
        .collect();
    Ok(sol)
}

/// `x += V y` with `y` solving the `k`×`k` upper triangular system `H y = g`, per channel.
fn update(
    x: &mut [[f64; 3]],
    basis: &[Vec<[f64; 3]>],
    h: &[[Vec<f64>; 3]],
    g: &[[f64; 3]],
    k: usize,
) {
    for c in 0..3 {
        let mut y = vec![0.0f64; k];
        for j in (0..k).rev() {
            let mut s = g[j][c];
            for l in j + 1..k {
                s -= h[l][c][j] * y[l];
            }
            y[j] = if h[j][c][j] != 0.0 {
                s / h[j][c][j]
            } else {
                0.0
            };
        }
        for (j, yj) in y.iter().enumerate() {
            for (xi, v) in x.iter_mut().zip(&basis[j]) {
                xi[c] += yj * v[c];
            }
        }
    }
}

/// A residual that is not a finite number: the solve diverged or met a NaN, which only bad
/// input makes (a radius or area of 1e30, an absurd emitter), and is an error rather than
/// iterations to the limit.
fn check_residual(iteration: u32, r: f64) -> Result<(), FmmError> {
    if r.is_finite() {
        return Ok(());
    }
    Err(FmmError::Diverged {
        iteration,
        residual: r,
    })
}
