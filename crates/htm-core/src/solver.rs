//! The stiff integrator: RODAS4 (Hairer & Wanner, Solving ODEs II, sec. IV.7), an L-stable,
//! stiffly accurate Rosenbrock method of order 4 with an embedded order-3 error estimate.
//! The step size is carried across calls to [`Rodas4::advance`], and every call ends exactly on
//! its end time, so a zero-order-hold input changes only at step boundaries (no restart).
use crate::error::{Error, Result};

/// A right-hand side with a constant (held) input.
pub trait OdeSystem<const N: usize> {
    fn rhs(&self, x: &[f64; N], dx: &mut [f64; N]);
    /// Error weight of each component: error_i is measured against
    /// rtol * (|x_i| * relative_i + scale_i).
    fn error_weights(&self) -> ([f64; N], [f64; N]);
    /// Components whose local error the step-size control judges (default all). A fast input
    /// state (a servo-valve's spool) may be left to the components it drives: an L-stable step
    /// across its transient gives its quasi-static effect, which those components then check.
    fn error_checked(&self) -> [bool; N] {
        [true; N]
    }
    /// Number of components the error norm averages over (default: the checked ones). A
    /// reduced form of a system may count a component it holds fixed (zero error) to take the
    /// same steps as the full form.
    fn error_count(&self) -> usize {
        self.error_checked().iter().filter(|c| **c).count()
    }
    /// Jacobian d(rhs)/dx at `x` (where rhs = `f0`); returns the number of rhs evaluations
    /// it spent. Forward differences unless the system overrides it with an analytic one.
    fn jacobian(&self, x: &[f64; N], f0: &[f64; N], jac: &mut [[f64; N]; N]) -> u64 {
        fd_jacobian(self, x, f0, jac)
    }
    /// Number of trailing components that form a decoupled block: their rates never depend on
    /// the leading components (a servo-valve's spool and lag, driven by the held command alone;
    /// the hydraulics do not act back on them). The iteration matrix is then block upper
    /// triangular, and each stage solves the trailing block first and the leading block after
    /// it, with the coupling moved to its right-hand side: the solution of one dense solve (to
    /// rounding) for much less work. Default 0 (one dense block).
    const DECOUPLED_TAIL: usize = 0;
}

/// Forward-difference Jacobian, step scaled per component.
pub fn fd_jacobian<const N: usize, S: OdeSystem<N> + ?Sized>(sys: &S, x: &[f64; N], f0: &[f64; N], jac: &mut [[f64; N]; N]) -> u64 {
    let (_, scale) = sys.error_weights();
    let mut xp = *x;
    let mut fp = [0.0; N];
    for j in 0..N {
        let dxj = 1e-7 * x[j].abs().max(scale[j] * 1e-2).max(1e-12);
        xp[j] = x[j] + dxj;
        sys.rhs(&xp, &mut fp);
        for i in 0..N {
            jac[i][j] = (fp[i] - f0[i]) / dxj;
        }
        xp[j] = x[j];
    }
    N as u64
}

const GAMMA: f64 = 0.25;
const A: [[f64; 5]; 6] = [
    [0.0; 5],
    [1.544, 0.0, 0.0, 0.0, 0.0],
    [0.9466785280815826, 0.2557011698983284, 0.0, 0.0, 0.0],
    [3.314825187068521, 2.896124015972201, 0.9986419139977817, 0.0, 0.0],
    [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 0.0],
    [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0],
];
const C: [[f64; 5]; 6] = [
    [0.0; 5],
    [-5.6688, 0.0, 0.0, 0.0, 0.0],
    [-2.430093356833875, -0.2063599157091915, 0.0, 0.0, 0.0],
    [-0.1073529058151375, -9.594562251023355, -20.47028614809616, 0.0, 0.0],
    [7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616, 0.0],
    [8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136, -6.058818238834054],
];
// The solution is the last stage (M = A[5] + [..,1]); the error estimate is the last K.

/// Work counters.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stats {
    pub accepted: u64,
    pub rejected: u64,
    pub rhs_evals: u64,
}

#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
pub struct Rodas4 {
    pub rtol: f64,
    /// step size proposed for the next step, carried across `advance` calls
    pub h: f64,
    pub h_min: f64,
    pub h_max: f64,
    /// when set, take steps of exactly this size without error control (for order tests)
    pub fixed_step: Option<f64>,
    pub stats: Stats,
    /// solve every stage as one dense system, ignoring a decoupled tail
    /// (`OdeSystem::DECOUPLED_TAIL`): the coupled form, the block solve's peer in benchmarks
    #[serde(skip)]
    pub dense_stages: bool,
}

impl Rodas4 {
    pub fn new(rtol: f64) -> Self {
        Rodas4 { rtol, h: 1e-5, h_min: 1e-14, h_max: 1e-2, fixed_step: None, stats: Stats::default(), dense_stages: false }
    }

    /// Integrate `x` forward by `dt` with the input held; ends exactly at dt.
    pub fn advance<const N: usize, S: OdeSystem<N>>(&mut self, sys: &S, x: &mut [f64; N], dt: f64) -> Result<()> {
        self.advance_with(sys, x, dt, |_| {})
    }

    /// [`advance`](Self::advance), handing the size of every accepted step to `follow`: systems
    /// that differ slightly from this one (finite-difference neighbours) take the same steps with
    /// [`Rodas4::follow`].
    pub fn advance_with<const N: usize, S: OdeSystem<N>>(&mut self, sys: &S, x: &mut [f64; N], dt: f64,
                                                         mut follow: impl FnMut(f64)) -> Result<()> {
        let (rel, scale) = sys.error_weights();
        let checked = sys.error_checked();
        let n_checked = sys.error_count().max(1) as f64;
        let mut t = 0.0;
        let mut f0 = [0.0; N];
        let mut jac = [[0.0; N]; N];
        let mut have_jac = false;
        while t < dt {
            let remaining = dt - t;
            let wanted = self.fixed_step.unwrap_or(self.h.min(self.h_max));
            // Land exactly on the sample boundary; stretch by <= 5 % rather than leave a sliver.
            let (h, clipped) = if wanted * 1.05 >= remaining { (remaining, wanted > remaining) } else { (wanted, false) };
            if !have_jac {
                sys.rhs(x, &mut f0);
                self.stats.rhs_evals += 1 + sys.jacobian(x, &f0, &mut jac);
                have_jac = true;
            }
            let (xn, err) = self.attempt(sys, x, &f0, &jac, h);
            let err_norm = error_norm(self.rtol, (&rel, &scale, &checked, n_checked), x, &xn, &err);
            let finite = err_norm.is_finite() && xn.iter().all(|v| v.is_finite());
            if self.fixed_step.is_some() {
                if !finite {
                    return Err(Error::Solver("non-finite state in fixed-step integration".into()));
                }
                follow(h);
                *x = xn;
                t += h;
                have_jac = false;
                self.stats.accepted += 1;
                continue;
            }
            // err^(-1/4) by two square roots (a pow costs several times more, once per step)
            let fac = if finite { (0.9 / err_norm.max(1e-10).sqrt().sqrt()).clamp(0.2, 6.0) } else { 0.1 };
            if finite && err_norm <= 1.0 {
                follow(h);
                *x = xn;
                t = if clipped || h == remaining { dt } else { t + h };
                have_jac = false;
                self.stats.accepted += 1;
                // A step shortened only to meet the boundary says nothing against the old size.
                let next = h * fac;
                self.h = if clipped { next.max(self.h) } else { next }.min(self.h_max);
            } else {
                self.stats.rejected += 1;
                self.h = h * fac.min(0.5);
                if self.h < self.h_min {
                    return Err(Error::Solver(format!(
                        "step size underflow (h = {:.3e} s) — the state became non-physical or a parameter is extreme", self.h)));
                }
            }
        }
        Ok(())
    }

    /// A follower's step: `sys` (a system close to a leader's) advanced from `x` by the leader's
    /// accepted step size `h`, with its own rates and Jacobian. Its difference to the leader is
    /// then free of step-size noise (both took the same steps). Where that step misses this
    /// solver's tolerance for the follower (a neighbour nearer a cavitating chamber than its
    /// leader), the follower crosses the same interval with its own step-size control instead.
    /// `x` turns non-finite if the follower cannot be carried.
    pub fn follow<const N: usize, S: OdeSystem<N>>(&mut self, sys: &S, x: &mut [f64; N], h: f64) {
        let mut f0 = [0.0; N];
        sys.rhs(x, &mut f0);
        let mut jac = [[0.0; N]; N];
        self.stats.rhs_evals += 1 + sys.jacobian(x, &f0, &mut jac);
        let (xn, err) = self.attempt(sys, x, &f0, &jac, h);
        let (rel, scale) = sys.error_weights();
        let norm = error_norm(self.rtol, (&rel, &scale, &sys.error_checked(), sys.error_count().max(1) as f64), x, &xn, &err);
        if norm <= 1.0 && xn.iter().all(|v| v.is_finite()) {
            *x = xn;
            self.stats.accepted += 1;
            return;
        }
        self.stats.rejected += 1;
        self.h = 0.5 * h;
        if self.advance(sys, x, h).is_err() {
            *x = [f64::NAN; N];
        }
    }

    /// One step of size `h` from `x` (rate `f0`, Jacobian `jac`): the iteration matrix
    /// factorised, by blocks where the system has a decoupled tail (unless `dense_stages`), and
    /// the stages; the new state and the error estimate. The leading block's size is a constant
    /// in each branch, so that the factorisation's and the solves' loops unroll for it.
    #[inline(always)]
    fn attempt<const N: usize, S: OdeSystem<N>>(&mut self, sys: &S, x: &[f64; N], f0: &[f64; N], jac: &[[f64; N]; N], h: f64) -> ([f64; N], [f64; N]) {
        let tail = S::DECOUPLED_TAIL;
        if self.dense_stages || tail == 0 || tail >= N {
            self.stages(sys, x, f0, &Factored::new(jac, h, N), N)
        } else {
            self.stages(sys, x, f0, &Factored::new(jac, h, N - tail), N - tail)
        }
    }

    /// The six stages of one step of size `g.h` from `x` (where the rate is `f0`) with the
    /// factorised iteration matrix `g` (its leading block `lead`): the new state and the error estimate.
    #[inline(always)]
    fn stages<const N: usize, S: OdeSystem<N>>(&mut self, sys: &S, x: &[f64; N], f0: &[f64; N], fac: &Factored<N>, lead: usize) -> ([f64; N], [f64; N]) {
        let (g, piv) = (&fac.lu, &fac.perm);
        let inv_h = 1.0 / fac.h;
        let mut k = [[0.0; N]; 6];
        let mut y = [0.0; N];
        let mut f = [0.0; N];
        for s in 0..6 {
            if s == 0 {
                f = *f0;
            } else {
                for i in 0..N {
                    let mut acc = x[i];
                    for j in 0..s {
                        acc += A[s][j] * k[j][i];
                    }
                    y[i] = acc;
                }
                sys.rhs(&y, &mut f);
                self.stats.rhs_evals += 1;
            }
            let mut b = f;
            for j in 0..s {
                let c = C[s][j] * inv_h;
                for i in 0..N {
                    b[i] += c * k[j][i];
                }
            }
            lu_solve(g, piv, lead, &b, &mut k[s]);
        }
        let mut xn = [0.0; N];
        for i in 0..N {
            xn[i] = y[i] + k[5][i];
        }
        (xn, k[5])
    }
}

/// The step-size control's error norm of a step from `x` to `xn` with error estimate `err`:
/// the RMS over the checked components (weights `w` = relative, scale, checked, count) of the
/// error against rtol * (|x| * relative + scale).
fn error_norm<const N: usize>(rtol: f64, w: (&[f64; N], &[f64; N], &[bool; N], f64), x: &[f64; N], xn: &[f64; N], err: &[f64; N]) -> f64 {
    let (rel, scale, checked, n_checked) = w;
    let mut s = 0.0;
    for i in (0..N).filter(|i| checked[*i]) {
        let w = rtol * (x[i].abs().max(xn[i].abs()) * rel[i] + scale[i]);
        let e = err[i] / w;
        s += e * e;
    }
    (s / n_checked).sqrt()
}

/// A step's size and its factorised iteration matrix I/(h*gamma) - J: with `lead` < N, its
/// leading and trailing diagonal blocks factorised apart (the trailing rows' leading columns are
/// zero: `OdeSystem::DECOUPLED_TAIL`) and the coupling block kept as it is.
#[derive(Debug, Clone)]
struct Factored<const N: usize> {
    h: f64,
    lu: [[f64; N]; N],
    perm: [usize; N],
}

impl<const N: usize> Factored<N> {
    #[inline(always)]
    fn new(jac: &[[f64; N]; N], h: f64, lead: usize) -> Self {
        let mut lu = [[0.0; N]; N];
        for i in 0..N {
            for j in 0..N {
                lu[i][j] = -jac[i][j];
            }
            lu[i][i] += 1.0 / (h * GAMMA);
        }
        let perm = lu_factor(&mut lu, lead);
        Factored { h, lu, perm }
    }
}



/// In-place LU with partial pivoting (U's diagonal stored as its reciprocals); singular pivots are replaced by a tiny value (the step
/// is then rejected by the error test rather than panicking). Returns the row permutation: row i
/// of the factors is row `perm[i]` of the matrix (the interchanges composed, applied by one gather).
/// With `lead` < N the matrix is block upper triangular (rows `lead..` are zero in columns
/// `..lead`): the blocks `..lead` and `lead..` are factorised apart, each pivoting within itself,
/// and the coupling block (rows `..lead`, columns `lead..`) stays as it is, its rows permuted with
/// the leading block's. `lead` = N is the one dense factorisation.
#[allow(clippy::needless_range_loop)] // row i is updated from row k of the same matrix: indices, as in the textbook
#[inline(always)]
fn lu_factor<const N: usize>(a: &mut [[f64; N]; N], lead: usize) -> [usize; N] {
    let mut perm = [0usize; N];
    for (i, p) in perm.iter_mut().enumerate() {
        *p = i;
    }
    for (lo, hi) in [(0, lead), (lead, N)] {
        for k in lo..hi {
            let mut p = k;
            for i in k + 1..hi {
                if a[i][k].abs() > a[p][k].abs() {
                    p = i;
                }
            }
            if p != k {
                a.swap(p, k);
                perm.swap(p, k);
            }
            if a[k][k] == 0.0 {
                a[k][k] = 1e-300;
            }
            for i in k + 1..hi {
                if a[i][k] == 0.0 {
                    continue; // the plant's matrix is sparse (decoupled spool states, y' = v)
                }
                let m = a[i][k] / a[k][k];
                a[i][k] = m;
                for j in k + 1..hi {
                    a[i][j] -= m * a[k][j];
                }
            }
        }
    }
    // the diagonal as reciprocals: the back substitution, a chain through every row, then
    // multiplies instead of dividing (a division's latency is 4–5 multiplications')
    for k in 0..N {
        a[k][k] = 1.0 / a[k][k];
    }
    perm
}

/// Solve with the factors of [`lu_factor`] (same `lead`): the solution of `lu x = b` into `x`
/// (written in place, element by element: no copy of a just-written vector, whose reload would
/// stall). A block triangular matrix: the trailing block first, then the leading block with the
/// coupling times the trailing solution moved to its right-hand side.
#[allow(clippy::needless_range_loop)] // substitution by rows and columns: indices, as in the textbook
#[inline(always)]
fn lu_solve<const N: usize>(lu: &[[f64; N]; N], perm: &[usize; N], lead: usize, b: &[f64; N], x: &mut [f64; N]) {
    // the permuted right-hand side in one gather (not a chain of swaps through memory)
    for i in 0..N {
        x[i] = b[perm[i]];
    }
    for (lo, hi) in [(lead, N), (0, lead)] {
        if lo < lead {
            // the leading block's right-hand side less the coupling to the solved trailing block
            for i in lo..hi {
                for j in lead..N {
                    x[i] -= lu[i][j] * x[j];
                }
            }
        }
        for k in lo..hi {
            for i in k + 1..hi {
                x[i] -= lu[i][k] * x[k];
            }
        }
        for k in (lo..hi).rev() {
            for j in k + 1..hi {
                x[k] -= lu[k][j] * x[j];
            }
            x[k] *= lu[k][k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lu_solves_systems_that_need_pivoting() {
        let a0 = [[1e-3, 2.0, 3.0, 0.5], [4.0, 1e-4, 6.0, 1.0], [7.0, 8.0, 1e-5, 2.0], [1.0, 9.0, 2.0, 1e-6]];
        let x_true = [1.0, -2.0, 3.0, -4.0];
        let mut b = [0.0; 4];
        for i in 0..4 {
            for j in 0..4 {
                b[i] += a0[i][j] * x_true[j];
            }
        }
        let mut a = a0;
        let piv = lu_factor(&mut a, 4);
        let mut x = [0.0; 4];
        lu_solve(&a, &piv, 4, &b, &mut x);
        for i in 0..4 {
            assert!((x[i] - x_true[i]).abs() < 1e-9, "{x:?}");
        }
    }

    #[test]
    fn a_block_triangular_matrix_solved_by_blocks_matches_the_dense_solve() {
        // 4 leading rows coupled to a 3-row trailing block whose leading columns are zero
        let mut a0 = [[0.0; 7]; 7];
        let mut r = 0.37f64;
        for (i, row) in a0.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                r = (r * 9301.0 + 0.49297).fract();
                *v = if i >= 4 && j < 4 { 0.0 } else { (r - 0.5) * 10f64.powi((i + j) as i32 % 5 - 2) };
            }
            row[i] += if i == 1 { 1e-6 } else { 3.0 }; // row 1 needs a pivot from below
        }
        let b = [1.0, -2.0, 3.0, 0.5, -1.5, 2.5, 4.0];
        let (mut dense, mut block) = (a0, a0);
        let (pd, pb) = (lu_factor(&mut dense, 7), lu_factor(&mut block, 4));
        assert_ne!(pb, [0, 1, 2, 3, 4, 5, 6], "the leading block pivots");
        let (mut xd, mut xb) = ([0.0; 7], [0.0; 7]);
        lu_solve(&dense, &pd, 7, &b, &mut xd);
        lu_solve(&block, &pb, 4, &b, &mut xb);
        for i in 0..7 {
            let back: f64 = (0..7).map(|j| a0[i][j] * xb[j]).sum();
            assert!((back - b[i]).abs() < 1e-9, "row {i}: {back} vs {}", b[i]);
            assert!((xb[i] - xd[i]).abs() < 1e-9 * xd[i].abs().max(1.0), "{xb:?} vs {xd:?}");
        }
    }

    /// Van der Pol-like stiff test plus a harmonic oscillator: x'' = -w^2 x.
    struct Osc(f64);
    impl OdeSystem<2> for Osc {
        fn rhs(&self, x: &[f64; 2], dx: &mut [f64; 2]) {
            dx[0] = x[1];
            dx[1] = -self.0 * self.0 * x[0];
        }
        fn error_weights(&self) -> ([f64; 2], [f64; 2]) {
            ([1.0, 1.0], [1.0, 1.0])
        }
    }

    #[test]
    fn rodas4_converges_at_fourth_order() {
        let w = 2.0 * std::f64::consts::PI;
        let errs: Vec<f64> = [0.04, 0.02, 0.01]
            .iter()
            .map(|&h| {
                let mut s = Rodas4::new(1e-6);
                s.fixed_step = Some(h);
                let mut x = [1.0, 0.0];
                s.advance(&Osc(w), &mut x, 1.0).unwrap();
                (x[0] - 1.0).abs()
            })
            .collect();
        let order1 = (errs[0] / errs[1]).log2();
        let order2 = (errs[1] / errs[2]).log2();
        assert!(order1 > 3.5 && order2 > 3.5, "observed orders {order1} {order2}");
    }

    /// Stiff linear system with eigenvalues -1 and -1e6.
    struct Stiff;
    impl OdeSystem<2> for Stiff {
        fn rhs(&self, x: &[f64; 2], dx: &mut [f64; 2]) {
            dx[0] = -x[0];
            dx[1] = -1e6 * (x[1] - x[0]);
        }
        fn error_weights(&self) -> ([f64; 2], [f64; 2]) {
            ([1.0, 1.0], [1e-3, 1e-3])
        }
    }

    #[test]
    fn adaptive_steps_stay_large_on_a_stiff_problem_and_error_shrinks_with_tolerance() {
        let mut errs = vec![];
        for rtol in [1e-4, 1e-6, 1e-8] {
            let mut s = Rodas4::new(rtol);
            s.h_max = 1.0;
            let mut x = [1.0, 0.0];
            for _ in 0..10 {
                s.advance(&Stiff, &mut x, 0.1).unwrap();
            }
            let exact = (-1.0f64).exp();
            errs.push((x[0] - exact).abs());
            assert!(s.stats.accepted < 2000, "stiffness must not force tiny steps: {:?}", s.stats);
        }
        assert!(errs[1] < errs[0] && errs[2] < errs[1], "{errs:?}");
    }
}
