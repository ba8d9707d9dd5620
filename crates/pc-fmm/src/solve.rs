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
        // A NaN norm must stay NaN (`nn > 0.0` would call it zero and the solve converged).
        let r = if nn == 0.0 { 0.0 } else { (dn / nn).sqrt() };
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
    let space = Weighted::new(pts);
    let b: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            if space.weight[i] == 0.0 {
                return [0.0; 3];
            }
            std::array::from_fn(|c| sys.source[i][c] as f64 - emit(i, c))
        })
        .collect();
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
                if space.weight[i] == 0.0 {
                    [0.0; 3]
                } else {
                    std::array::from_fn(|c| v[i][c] - sys.albedo[i][c] as f64 * t[i][c] as f64)
                }
            }));
            Ok(order)
        };
    let b_norm = (0..3).map(|c| space.dot(&b, &b, c)).sum::<f64>().sqrt();
    check_residual(0, b_norm)?;
    let b_channel: [f64; 3] = std::array::from_fn(|c| space.dot(&b, &b, c).sqrt());
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
        let mut cycle = Cycle::new(&space, r0, m);
        check_residual(it, cycle.g[0].iter().sum::<f64>())?;
        let mut k = 0;
        while k < m && it < max_iterations {
            // The largest channel's relative residual before this step.
            let r_prev = (0..3)
                .filter(|&c| b_channel[c] > 0.0)
                .map(|c| cycle.g[k][c].abs() / b_channel[c])
                .fold(0.0f64, f64::max);
            let relax = if relaxed && r_prev > 0.0 {
                (1.0 / r_prev).max(1.0)
            } else {
                1.0
            };
            sol.orders.push(apply(&cycle.basis[k], &mut w, relax)?);
            it += 1;
            cycle.step(&space, &mut w, k, it)?;
            k += 1;
            let r = cycle.residual(k) / b_norm;
            check_residual(it, r)?;
            sol.residuals.push(r);
            progress(it, r);
            if r < tolerance {
                sol.converged = true;
            }
            if sol.converged || it == max_iterations {
                cycle.update(&mut x, k);
                break 'outer;
            }
        }
        cycle.update(&mut x, k);
    }
    if b_norm == 0.0 {
        sol.converged = true;
    }
    sol.radiance = (0..n)
        .map(|i| {
            if space.weight[i] == 0.0 {
                sys.source[i]
            } else {
                std::array::from_fn(|c| (x[i][c] + emit(i, c)) as f32)
            }
        })
        .collect();
    Ok(sol)
}

/// The inner product of the solve: area-weighted over the active splats, per color channel.
struct Weighted {
    weight: Vec<f64>,
}

impl Weighted {
    fn new(pts: &Points) -> Weighted {
        let weight = (0..pts.area.len())
            .map(|i| {
                if pts.active[i] {
                    pts.area[i] as f64
                } else {
                    0.0
                }
            })
            .collect();
        Weighted { weight }
    }

    fn dot(&self, u: &[[f64; 3]], v: &[[f64; 3]], c: usize) -> f64 {
        (0..self.weight.len())
            .map(|i| self.weight[i] * u[i][c] * v[i][c])
            .sum()
    }
}

/// One GMRES cycle (between restarts), per channel: the Krylov basis, the Hessenberg columns
/// (rotated), the Givens rotations and the rotated right-hand side `g`.
struct Cycle {
    basis: Vec<Vec<[f64; 3]>>,
    h: Vec<[Vec<f64>; 3]>,
    rot: Vec<[(f64, f64); 3]>,
    g: Vec<[f64; 3]>,
}

impl Cycle {
    /// A cycle from the residual `r0`, keeping at most `m` Krylov vectors; `g[0]` is `‖r0‖`
    /// per channel.
    fn new(space: &Weighted, r0: Vec<[f64; 3]>, m: usize) -> Cycle {
        let beta: [f64; 3] = std::array::from_fn(|c| space.dot(&r0, &r0, c).sqrt());
        let scale = beta.map(|s| if s > 0.0 { 1.0 / s } else { 0.0 });
        let mut basis = Vec::with_capacity(m + 1);
        basis.push(
            r0.iter()
                .map(|r| std::array::from_fn(|c| r[c] * scale[c]))
                .collect(),
        );
        let mut g = vec![[0.0; 3]; m + 1];
        g[0] = beta;
        Cycle {
            basis,
            h: vec![std::array::from_fn(|_| vec![0.0f64; m + 1]); m],
            rot: vec![[(1.0f64, 0.0f64); 3]; m],
            g,
        }
    }

    /// Arnoldi step `k` with `w` the product of basis vector `k` (product number `it`):
    /// orthogonalize `w` against the basis (modified Gram-Schmidt), append it normalized,
    /// and rotate the new Hessenberg column into triangular form.
    fn step(
        &mut self,
        space: &Weighted,
        w: &mut [[f64; 3]],
        k: usize,
        it: u32,
    ) -> Result<(), FmmError> {
        let h = &mut self.h[k];
        for c in 0..3 {
            for (j, v) in self.basis.iter().enumerate() {
                let hj = space.dot(w, v, c);
                h[c][j] = hj;
                for (wi, vi) in w.iter_mut().zip(v) {
                    wi[c] -= hj * vi[c];
                }
            }
            h[c][k + 1] = space.dot(w, w, c).sqrt();
        }
        // A product that is not a number must stop the solve here: the branches below that
        // guard against zero norms would turn it into a zero residual.
        let worst = (0..3)
            .flat_map(|c| h[c][..=k + 1].iter().copied())
            .find(|x| !x.is_finite());
        check_residual(it, worst.unwrap_or(0.0))?;
        let next: Vec<[f64; 3]> = w
            .iter()
            .map(|x| {
                std::array::from_fn(|c| {
                    let s = h[c][k + 1];
                    if s > 0.0 {
                        x[c] / s
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        for c in 0..3 {
            let col = &mut h[c];
            for (j, r) in self.rot.iter().enumerate().take(k) {
                let (cs, sn) = r[c];
                let (a, bb) = (col[j], col[j + 1]);
                col[j] = cs * a + sn * bb;
                col[j + 1] = -sn * a + cs * bb;
            }
            let (a, bb) = (col[k], col[k + 1]);
            let d = a.hypot(bb);
            let (cs, sn) = if d > 0.0 { (a / d, bb / d) } else { (1.0, 0.0) };
            self.rot[k][c] = (cs, sn);
            col[k] = d;
            col[k + 1] = 0.0;
            self.g[k + 1][c] = -sn * self.g[k][c];
            self.g[k][c] *= cs;
        }
        self.basis.push(next);
        Ok(())
    }

    /// The residual norm over RGB after `k` steps (unscaled).
    fn residual(&self, k: usize) -> f64 {
        (0..3)
            .map(|c| self.g[k][c] * self.g[k][c])
            .sum::<f64>()
            .sqrt()
    }

    /// `x += V y` with `y` solving the `k`×`k` upper triangular system `H y = g`, per channel.
    fn update(&self, x: &mut [[f64; 3]], k: usize) {
        for c in 0..3 {
            let mut y = vec![0.0f64; k];
            for j in (0..k).rev() {
                let mut s = self.g[j][c];
                for (l, yl) in y.iter().enumerate().take(k).skip(j + 1) {
                    s -= self.h[l][c][j] * yl;
                }
                y[j] = if self.h[j][c][j] != 0.0 {
                    s / self.h[j][c][j]
                } else {
                    0.0
                };
            }
            for (j, yj) in y.iter().enumerate() {
                for (xi, v) in x.iter_mut().zip(&self.basis[j]) {
                    xi[c] += yj * v[c];
                }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `out = ½ (mean of the radiance)` on every splat, until product `poison_at`, which
    /// returns NaN (what a splat of area 1e30 or an absurd emitter does to a real product).
    struct Poisoned {
        products: u32,
        poison_at: u32,
    }

    impl Operator for Poisoned {
        fn apply_relaxed(
            &mut self,
            radiance: &[[f32; 3]],
            out: &mut [[f32; 3]],
            _relax: f64,
        ) -> Result<u32, FmmError> {
            self.products += 1;
            let n = radiance.len() as f32;
            for c in 0..3 {
                let mean = radiance.iter().map(|l| l[c]).sum::<f32>() / n;
                let v = if self.products >= self.poison_at {
                    f32::NAN
                } else {
                    0.5 * mean
                };
                out.iter_mut().for_each(|o| o[c] = v);
            }
            Ok(4)
        }
        fn order(&self) -> u32 {
            4
        }
        fn device(&self) -> String {
            "test".into()
        }
    }

    fn system(n: usize) -> (System, Points) {
        let sys = System {
            source: (0..n).map(|i| [1.0 + i as f32, 1.0, 0.5]).collect(),
            emission: vec![[0.0; 3]; n],
            albedo: vec![[0.8; 3]; n],
        };
        let pts = Points {
            pos: vec![[0.0; 3]; n],
            normal: vec![[0.0, 1.0, 0.0]; n],
            area: vec![1.0; n],
            active: vec![true; n],
            leaf: vec![0; n],
        };
        (sys, pts)
    }

    fn gmres(max_iterations: u32) -> Gmres {
        Gmres {
            tolerance: 1e-12,
            max_iterations,
            restart: GMRES_RESTART,
            relaxed: false,
        }
    }

    #[test]
    fn a_nan_product_is_an_error_naming_the_iteration_in_both_solvers() {
        let (sys, pts) = system(5);
        let mut op = Poisoned {
            products: 0,
            poison_at: 3,
        };
        let jacobi = solve(&mut op, &sys, &pts, 1e-12, 50, &mut |_, _| {});
        assert!(
            matches!(jacobi, Err(FmmError::Diverged { iteration: 3, residual }) if residual.is_nan()),
            "{jacobi:?}"
        );
        // GMRES solves this system in two products: the second is the poisoned one.
        let mut op = Poisoned {
            products: 0,
            poison_at: 2,
        };
        let g = solve_gmres(&mut op, &sys, &pts, gmres(50), &mut |_, _| {});
        assert!(
            matches!(g, Err(FmmError::Diverged { iteration: 2, residual }) if residual.is_nan()),
            "{g:?}"
        );
        let msg = g.unwrap_err().to_string();
        assert!(msg.contains("the radiosity solve diverged"), "{msg}");
    }

    #[test]
    fn the_same_operator_without_the_nan_converges() {
        let (sys, pts) = system(5);
        let mut op = Poisoned {
            products: 0,
            poison_at: u32::MAX,
        };
        let sol = solve_gmres(&mut op, &sys, &pts, gmres(50), &mut |_, _| {}).unwrap();
        assert!(sol.converged);
        // L = E + ρ · ½ mean(L): the mean m solves m = mean(E) + 0.4 m.
        let mean_e = [3.0f32, 1.0, 0.5];
        for (i, l) in sol.radiance.iter().enumerate() {
            for c in 0..3 {
                let want = sys.source[i][c] + 0.4 * mean_e[c] / 0.6;
                assert!(
                    (l[c] - want).abs() < 1e-4 * want,
                    "splat {i}: {l:?}, want {want}"
                );
            }
        }
    }
}
