//! A proximal augmented-Lagrangian method with semismooth Newton inner steps (QPALM's,
//! Hermans–Themelis–Patrinos) for the velocity-form projection, warm-started from the
//! previous step's multipliers; its Newton systems are [`NormalEquations`]'.
//!
//! For multipliers `λ ≥ 0` and penalties `ρ_i > 0` the augmented Lagrangian of
//! `min ½|v − w|² s.t. s = b + J v ≥ 0` is
//! `L(v) = ½|v − w|² + Σ_i ((λ_i − ρ_i s_i)₊² − λ_i²) / (2ρ_i)`: convex, piecewise quadratic,
//! with gradient `v − w − Jᵀŷ`, `ŷ = (λ − ρ∘s)₊`, and generalized Hessian `I + Jᵀ Σ_A J`,
//! `Σ_A = ρ` on the rows where `ŷ > 0` and 0 elsewhere. That matrix is at least the identity
//! however redundant the active rows are (the singular `J_A J_Aᵀ` of a dual active-set method
//! cannot occur), and its pattern is within that of `I + JᵀJ`, analysed once per structure of
//! `J`: between Newton steps only the values change, and not even those while the active set
//! and the penalties hold (then a step is one pair of triangular solves). When only a few rows
//! change (`max_updates`), the factor in hand is updated row by row, a rank-one update or
//! downdate along the elimination tree each, instead of factorized again.
//!
//! Each Newton direction is followed by the exact minimization of `L` along it (the roots of
//! a piecewise-linear derivative: its breakpoints are selected, not sorted). When the inner
//! problem is solved and its Newton matrix is the factorized one, conjugate gradients on the
//! dual of its active set (each iteration one pair of triangular solves) take the
//! multipliers where the fixed-point update `λ ← ŷ` of the method of multipliers would need
//! hundreds of updates on a jam's soft modes; then `λ ← ŷ`, and the penalty of each row whose
//! residual `(λ_i − ŷ_i)/ρ_i` did not shrink enough is raised (QPALM's rule). Every candidate
//! pair, `(w + Jᵀŷ, ŷ)` first and `(v, ŷ)` else, is judged by [`certify`] alone. The
//! caller's multipliers start it: the active set they imply is the first Newton matrix, and
//! when they already certify, nothing is factorized.
//!
//! Measured on evacuation halls (benches/README.md): it beats the interior point while
//! contacts are sparse; in a jam the active set moves by hundreds of rows a step, a few rows
//! per Newton step late in a solve, and the interior point wins. The updates take its
//! factorizations from 66 to 15 a step on a jammed 2,000 and from 16.7 to 5 on cromosim's
//! scene, but its 85 and 31 pairs of triangular solves a step (Newton directions and dual
//! conjugate gradients) remain: still 2.9× and 1.8× the interior point's time there.

use moreau_core::{ConstraintRows, Num, Parallelism, SolveStatus};

use crate::certificate::certify;
use crate::error::SolveError;
use crate::normal::{FactorizationCounts, NormalEquations};
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::products::row_dot;

/// Settings of [`Newton`]; build them with [`NewtonSettings::builder`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NewtonSettings {
    /// Numeric factorizations allowed per solve (the report's iterations).
    pub max_iterations: usize,
    /// Newton directions (pairs of triangular solves) allowed per solve.
    pub max_solves: usize,
    /// The initial penalty of a row, relative to its squared norm: `ρ_i = rho / |J_i|²`.
    pub rho: f64,
    /// The largest penalty of a row, relative to its squared norm.
    pub rho_max: f64,
    /// The factor by which a lagging row's penalty is raised.
    pub rho_increase: f64,
    /// A row lags when its residual did not shrink below this fraction of the last one.
    pub rho_theta: f64,
    /// Conjugate-gradient iterations on the dual of a solved inner problem's active set
    /// before the multiplier update (0: the plain update of the method of multipliers).
    pub dual_iterations: usize,
    /// When at most this many rows enter or leave the active set (or have their penalty
    /// raised) between two Newton matrices, the factor in hand is updated row by row
    /// (rank-one updates and downdates along the elimination tree, 2×2-block factors only)
    /// instead of factorized again; 0: always factorize.
    pub max_updates: usize,
    /// Threads for the factorization, the solves and the loops over rows and unknowns.
    #[serde(skip)]
    pub parallelism: Parallelism,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            max_solves: 400,
            rho: 1e3,
            rho_max: 1e10,
            rho_increase: 10.0,
            rho_theta: 0.25,
            dual_iterations: 50,
            max_updates: 32,
            parallelism: Parallelism::SEQUENTIAL,
        }
    }
}

impl NewtonSettings {
    /// A builder starting from the defaults.
    pub fn builder() -> NewtonSettingsBuilder {
        NewtonSettingsBuilder(Self::default())
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SolveError> {
        crate::error::check_budgets(&[
            ("max_iterations", self.max_iterations),
            ("max_solves", self.max_solves),
            ("dual_iterations", self.dual_iterations),
            ("max_updates", self.max_updates),
        ])?;
        let invalid = |field, value: String, reason| {
            Err(SolveError::InvalidSetting {
                field,
                value,
                reason,
            })
        };
        if self.max_iterations == 0 {
            return invalid("max_iterations", "0".into(), "must be ≥ 1");
        }
        if self.max_solves == 0 {
            return invalid("max_solves", "0".into(), "must be ≥ 1");
        }
        if !(self.rho > 0.0 && self.rho.is_finite()) {
            return invalid(
                "rho",
                Num(self.rho).to_string(),
                "must be positive and finite",
            );
        }
        if !(self.rho_max >= self.rho && self.rho_max.is_finite()) {
            return invalid(
                "rho_max",
                Num(self.rho_max).to_string(),
                "must be finite and ≥ rho",
            );
        }
        if !(self.rho_increase > 1.0 && self.rho_increase.is_finite()) {
            return invalid(
                "rho_increase",
                Num(self.rho_increase).to_string(),
                "must be finite and > 1",
            );
        }
        if !(self.rho_theta > 0.0 && self.rho_theta < 1.0) {
            return invalid(
                "rho_theta",
                Num(self.rho_theta).to_string(),
                "must be in (0, 1)",
            );
        }
        Ok(())
    }
}

/// Builder of [`NewtonSettings`].
#[derive(Debug, Clone)]
pub struct NewtonSettingsBuilder(NewtonSettings);

impl NewtonSettingsBuilder {
    /// Factorizations allowed per solve.
    pub fn max_iterations(mut self, n: usize) -> Self {
        self.0.max_iterations = n;
        self
    }
    /// Newton directions allowed per solve.
    pub fn max_solves(mut self, n: usize) -> Self {
        self.0.max_solves = n;
        self
    }
    /// Initial penalty relative to a row's squared norm.
    pub fn rho(mut self, rho: f64) -> Self {
        self.0.rho = rho;
        self
    }
    /// Largest penalty relative to a row's squared norm.
    pub fn rho_max(mut self, rho_max: f64) -> Self {
        self.0.rho_max = rho_max;
        self
    }
    /// Factor of a penalty increase.
    pub fn rho_increase(mut self, f: f64) -> Self {
        self.0.rho_increase = f;
        self
    }
    /// Residual reduction below which a row's penalty is kept.
    pub fn rho_theta(mut self, theta: f64) -> Self {
        self.0.rho_theta = theta;
        self
    }
    /// Dual conjugate-gradient iterations per multiplier update.
    pub fn dual_iterations(mut self, n: usize) -> Self {
        self.0.dual_iterations = n;
        self
    }
    /// Changed rows at most updated into the factor in hand (0: always factorize).
    pub fn max_updates(mut self, n: usize) -> Self {
        self.0.max_updates = n;
        self
    }
    /// Threads.
    pub fn parallelism(mut self, p: Parallelism) -> Self {
        self.0.parallelism = p;
        self
    }
    /// Validates and returns the settings.
    pub fn build(self) -> Result<NewtonSettings, SolveError> {
        self.0.validate()?;
        Ok(self.0)
    }
}

/// The proximal augmented-Lagrangian semismooth Newton solver (see the module). Its answers
/// are certified by [`certify`]; its report's iterations are numeric factorizations.
#[derive(Debug)]
pub struct Newton {
    settings: NewtonSettings,
    normal: NormalEquations,
    // per row
    s: Vec<f64>,
    y: Vec<f64>,
    yhat: Vec<f64>,
    lam: Vec<f64>,
    rho: Vec<f64>,
    norm_sq: Vec<f64>,
    d: Vec<f64>,
    d_factored: Vec<f64>,
    delta: Vec<f64>,
    residual: Vec<f64>,
    scratch_m: Vec<f64>,
    breaks: Vec<(f64, f64)>,
    dual_r: Vec<f64>,
    dual_p: Vec<f64>,
    dual_q: Vec<f64>,
    // per unknown
    v: Vec<f64>,
    g: Vec<f64>,
    dir: Vec<f64>,
    dual_u: Vec<f64>,
    scratch_n: Vec<f64>,
}

/// The minimizer `τ > 0` of a convex piecewise quadratic along a line, from its derivative
/// `f0 + a0 τ` before the first breakpoint and the breakpoints `(τ_k, change of slope)`;
/// also whether a breakpoint lies before it. Expected linear time: the breakpoints are
/// selected around medians, not sorted (their order in `breaks` is changed).
fn line_minimum(f0: f64, a0: f64, floor: f64, breaks: &mut [(f64, f64)]) -> (f64, bool) {
    // Invariant: every breakpoint in `rest` lies beyond `lo`, and the derivative is
    // `f + a (τ − lo)` from `lo` to the first of them.
    let (mut lo, mut f, mut a) = (0.0, f0, a0);
    let mut crossed = false;
    let mut rest = breaks;
    while !rest.is_empty() {
        let k = rest.len() / 2;
        let (left, pivot, right) = rest.select_nth_unstable_by(k, |x, y| x.0.total_cmp(&y.0));
        let (t, dt) = *pivot;
        let (mut sum, mut sum_t) = (0.0, 0.0);
        for &(tk, dk) in left.iter() {
            sum += dk;
            sum_t += dk * tk;
        }
        let at_pivot = f + a * (t - lo) + sum * t - sum_t;
        if at_pivot >= 0.0 {
            rest = left;
        } else {
            lo = t;
            f = at_pivot;
            a = (a + sum + dt).max(floor);
            crossed = true;
            rest = right;
        }
    }
    (lo - f / a, crossed)
}

impl Newton {
    /// A solver with validated settings.
    pub fn new(settings: NewtonSettings) -> Result<Self, SolveError> {
        settings.validate()?;
        Ok(Self {
            normal: NormalEquations::new(settings.parallelism)?,
            settings,
            s: Vec::new(),
            y: Vec::new(),
            yhat: Vec::new(),
            lam: Vec::new(),
            rho: Vec::new(),
            norm_sq: Vec::new(),
            d: Vec::new(),
            d_factored: Vec::new(),
            delta: Vec::new(),
            residual: Vec::new(),
            scratch_m: Vec::new(),
            breaks: Vec::new(),
            dual_r: Vec::new(),
            dual_p: Vec::new(),
            dual_q: Vec::new(),
            dual_u: Vec::new(),
            v: Vec::new(),
            g: Vec::new(),
            dir: Vec::new(),
            scratch_n: Vec::new(),
        })
    }

    /// Patterns, analyses and factorizations done so far.
    pub fn counts(&self) -> FactorizationCounts {
        self.normal.counts()
    }

    fn size(&mut self, m: usize, n: usize) {
        for v in [
            &mut self.s,
            &mut self.y,
            &mut self.yhat,
            &mut self.lam,
            &mut self.rho,
            &mut self.norm_sq,
            &mut self.d,
            &mut self.d_factored,
            &mut self.delta,
            &mut self.residual,
            &mut self.scratch_m,
            &mut self.dual_r,
            &mut self.dual_p,
            &mut self.dual_q,
        ] {
            v.clear();
            v.resize(m, 0.0);
        }
        self.breaks.clear();
        self.breaks.reserve(m);
        for v in [
            &mut self.v,
            &mut self.g,
            &mut self.dir,
            &mut self.dual_u,
            &mut self.scratch_n,
        ] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// At the current `v`: `s = b + J v`, `y = λ − ρ∘s`, `ŷ = y₊` (0 on zero rows), the
    /// gradient `g = v − w − Jᵀŷ`, and what [`certify`] will find for the pair `(v, ŷ)`:
    /// `(gap, violation)` with `gap = ½|g|² + Σ ŷ_i (s_i)₊` and `violation = max (−s_i)₊`.
    fn evaluate(&mut self, p: &ProjectionProblem<'_>) -> (f64, f64) {
        let j = p.jacobian;
        let w = self.normal.workers();
        let v = &self.v;
        w.map(&mut self.s, |i, _| p.b[i] + row_dot(j, v, i));
        let (s, lam, rho) = (&self.s, &self.lam, &self.rho);
        w.map(&mut self.y, |i, _| {
            if rho[i] > 0.0 {
                lam[i] - rho[i] * s[i]
            } else {
                0.0
            }
        });
        let y = &self.y;
        w.map(&mut self.yhat, |i, _| y[i].max(0.0));
        let (yhat, jt) = (&self.yhat, self.normal.transpose());
        w.map(&mut self.g, |c, _| v[c] - p.w[c] - jt.dot(yhat, c));
        let g = &self.g;
        let gap =
            0.5 * w.sum(g.len(), |c| g[c] * g[c]) + w.sum(s.len(), |i| yhat[i] * s[i].max(0.0));
        let violation = -w.min(s.len(), |i| s[i]).min(0.0);
        (gap, violation)
    }

    /// The pair `(w + Jᵀŷ, ŷ)` into `sol`, and its certificate.
    fn stationary_candidate(
        &mut self,
        p: &ProjectionProblem<'_>,
        sol: &mut ProjectionSolution,
    ) -> crate::certificate::Certificate {
        let (w, jt) = (self.normal.workers(), self.normal.transpose());
        let yhat = &self.yhat;
        w.map(&mut sol.v, |c, _| p.w[c] + jt.dot(yhat, c));
        sol.lambda.copy_from_slice(&self.yhat);
        certify(
            p,
            &sol.v,
            &sol.lambda,
            &mut self.scratch_m,
            &mut self.scratch_n,
        )
    }

    /// The pair `(v, ŷ)` into `sol`, and its certificate.
    fn candidate(
        &mut self,
        p: &ProjectionProblem<'_>,
        sol: &mut ProjectionSolution,
    ) -> crate::certificate::Certificate {
        sol.v.copy_from_slice(&self.v);
        sol.lambda.copy_from_slice(&self.yhat);
        certify(
            p,
            &sol.v,
            &sol.lambda,
            &mut self.scratch_m,
            &mut self.scratch_n,
        )
    }

    /// Conjugate gradients on the dual of the factorized active set `A`: the multipliers
    /// `λ_A` that zero the slacks `s_A(λ) = J_A v(λ) + b_A`, where `v(λ)` minimizes the
    /// augmented Lagrangian with `A` held, `H v = w + J_Aᵀ(λ − ρ∘b_A)`. The system is
    /// `J_A H⁻¹ J_Aᵀ λ = −c`, symmetric positive semidefinite (singular with redundant rows,
    /// but consistent), each product one pair of triangular solves with the factorization in
    /// hand; `v` follows `λ` along. The fixed-point update `λ ← ŷ` of the method of
    /// multipliers is Richardson's iteration on this system, and needs about `1/(ρσ)`
    /// updates for the dual's soft modes `σ` (long force chains of a jam); these need about
    /// `(1 + 1/(ρσ))^½`. Rows outside `A` keep `λ = 0`. True when a pair certified (it is
    /// then in `sol`); otherwise the state is the last iterate, evaluated.
    fn dual_cg(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
        max: usize,
        solves: &mut usize,
    ) -> bool {
        let j = p.jacobian;
        let m = self.lam.len();
        {
            let w = self.normal.workers();
            let (d, s) = (&self.d_factored, &self.s);
            w.map(&mut self.lam, |i, l| if d[i] > 0.0 { l } else { 0.0 });
            w.map(
                &mut self.dual_r,
                |i, _| if d[i] > 0.0 { -s[i] } else { 0.0 },
            );
        }
        self.dual_p.copy_from_slice(&self.dual_r);
        let mut rr = {
            let r = &self.dual_r;
            self.normal.workers().sum(m, |i| r[i] * r[i])
        };
        let small = (1e-3 * target.violation).powi(2);
        for _ in 0..max {
            if !(rr > small) {
                break;
            }
            {
                let (w, jt) = (self.normal.workers(), self.normal.transpose());
                let pr = &self.dual_p;
                w.map(&mut self.dual_u, |c, _| jt.dot(pr, c));
            }
            self.normal.solve_in_place(&mut self.dual_u);
            *solves += 1;
            let w = self.normal.workers();
            let (d, u, pr) = (&self.d_factored, &self.dual_u, &self.dual_p);
            w.map(&mut self.dual_q, |i, _| {
                if d[i] > 0.0 { row_dot(j, u, i) } else { 0.0 }
            });
            let q = &self.dual_q;
            let pq = w.sum(m, |i| pr[i] * q[i]);
            if !(pq > 0.0) {
                break;
            }
            // Within the face λ_A ≥ 0: a step that would take a multiplier below zero stops
            // there, and the active set is left to the Newton steps again.
            let lam = &self.lam;
            let to_bound = w.min(m, |i| {
                if pr[i] < 0.0 {
                    -lam[i] / pr[i]
                } else {
                    f64::INFINITY
                }
            });
            let full = rr / pq;
            let alpha = full.min(to_bound.max(0.0));
            w.map(&mut self.lam, |i, l| (l + alpha * pr[i]).max(0.0));
            w.map(&mut self.v, |c, x| x + alpha * u[c]);
            w.map(&mut self.dual_r, |i, r| r - alpha * q[i]);
            let (gap, violation) = self.evaluate(p);
            let bounded = alpha < full;
            if gap <= target.gap && violation <= target.violation {
                let c = self.stationary_candidate(p, sol);
                if c.gap <= target.gap && c.violation <= target.violation {
                    return true;
                }
                let c = self.candidate(p, sol);
                if c.gap <= target.gap && c.violation <= target.violation {
                    return true;
                }
            }
            if bounded {
                return false;
            }
            let w = self.normal.workers();
            let r = &self.dual_r;
            let rr_next = w.sum(m, |i| r[i] * r[i]);
            let beta = rr_next / rr;
            rr = rr_next;
            w.map(&mut self.dual_p, |i, x| r[i] + beta * x);
        }
        false
    }

    /// The multiplier update `λ ← ŷ`, raising the penalty of the rows whose residual
    /// `(λ_i − ŷ_i)/ρ_i` still matters and did not shrink by `rho_theta`.
    fn update_multipliers(&mut self, target: Target, active: usize) {
        let st = &self.settings;
        let (gap_row, viol) = (
            0.1 * target.gap / active.max(1) as f64,
            0.1 * target.violation,
        );
        for i in 0..self.lam.len() {
            let rho = self.rho[i];
            if rho == 0.0 {
                continue;
            }
            let e = (self.lam[i] - self.yhat[i]) / rho;
            let last = self.residual[i];
            let matters = self.yhat[i] * e.abs() > gap_row || -e > viol;
            if matters && e.abs() > st.rho_theta * last.abs() {
                self.rho[i] = (rho * st.rho_increase).min(st.rho_max / self.norm_sq[i]);
            }
            self.residual[i] = e;
            self.lam[i] = self.yhat[i];
        }
    }

    /// The exact minimization of the augmented Lagrangian along `dir`: the step, and whether
    /// the active set changed before it.
    fn line_search(&mut self, j: &ConstraintRows) -> Option<(f64, bool)> {
        let w = self.normal.workers();
        let dir = &self.dir;
        w.map(&mut self.delta, |i, _| row_dot(j, dir, i));
        let (g, n) = (&self.g, dir.len());
        let f0 = w.sum(n, |c| dir[c] * g[c]);
        let dd = w.sum(n, |c| dir[c] * dir[c]);
        if !(f0 < 0.0) || !(dd > 0.0) {
            return None;
        }
        let (y, rho, delta) = (&self.y, &self.rho, &self.delta);
        let a0 = dd
            + w.sum(y.len(), |i| {
                let (yi, di) = (y[i], delta[i]);
                if yi > 0.0 || (yi == 0.0 && di < 0.0) {
                    rho[i] * di * di
                } else {
                    0.0
                }
            });
        self.breaks.clear();
        for i in 0..y.len() {
            let (yi, di) = (y[i], delta[i]);
            let r = rho[i] * di;
            if r != 0.0 && yi != 0.0 && (yi > 0.0) == (r > 0.0) {
                let change = rho[i] * di * di;
                self.breaks
                    .push((yi / r, if di > 0.0 { -change } else { change }));
            }
        }
        let (tau, crossed) = line_minimum(f0, a0, dd, &mut self.breaks);
        tau.is_finite().then_some((tau, crossed))
    }
}

impl ProjectionSolver for Newton {
    fn name(&self) -> &'static str {
        "newton"
    }

    fn solve(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        p.validate()?;
        target.validate()?;
        let (m, n) = (p.rows(), p.dim());
        let j = p.jacobian;
        sol.resize_for(p);
        self.size(m, n);
        for i in 0..m {
            self.norm_sq[i] = j.row_norm_sq(i);
        }
        let report = |status, c: crate::certificate::Certificate, iterations| SolveReport {
            solver: "newton",
            status,
            gap: c.gap,
            violation: c.violation,
            iterations,
            active: c.active,
            ..SolveReport::default()
        };

        let infeasible = (0..m).any(|i| self.norm_sq[i] == 0.0 && p.b[i] < -target.violation);
        if m == 0 || infeasible {
            sol.v.copy_from_slice(p.w);
            sol.lambda.iter_mut().for_each(|l| *l = 0.0);
            let c = certify(
                p,
                &sol.v,
                &sol.lambda,
                &mut self.scratch_m,
                &mut self.scratch_n,
            );
            let status = if infeasible {
                SolveStatus::Infeasible
            } else {
                SolveStatus::Converged
            };
            return Ok(report(status, c, 0));
        }
        // The caller's multipliers (zero rows have none): when they already certify, a
        // free-flowing crowd or a repeated projection costs no factorization.
        for (i, l) in sol.lambda.iter_mut().enumerate() {
            *l = if l.is_finite() && self.norm_sq[i] > 0.0 {
                l.max(0.0)
            } else {
                0.0
            };
        }
        sol.v.copy_from_slice(p.w);
        j.mul_transpose_add(&sol.lambda, &mut sol.v);
        let c = certify(
            p,
            &sol.v,
            &sol.lambda,
            &mut self.scratch_m,
            &mut self.scratch_n,
        );
        if c.gap <= target.gap && c.violation <= target.violation {
            return Ok(report(SolveStatus::Converged, c, 0));
        }

        let times = self.normal.times();
        self.normal.analyse(j)?;
        self.lam.copy_from_slice(&sol.lambda);
        self.v.copy_from_slice(&sol.v);
        let st = self.settings;
        for i in 0..m {
            let q = self.norm_sq[i];
            self.rho[i] = if q > 0.0 { st.rho / q } else { 0.0 };
            self.residual[i] = f64::INFINITY;
        }
        self.d_factored.iter_mut().for_each(|d| *d = f64::NAN);

        let (mut factorizations, mut solves) = (0, 0);
        let mut exact = false;
        // A multiplier update since the last Newton direction: the next pass takes a direction
        // first. Updates alone never move `v`, so where the gap's target is met and only the
        // violation is not (a target gap of 1e598 from `time.tol = 1e300`), every pass was an
        // update, counted by no budget, and the solve never ended.
        let mut after_update = false;
        let mut out_of_budget = false;
        let status = loop {
            let (gap, violation) = self.evaluate(p);
            out_of_budget |= solves >= st.max_solves;
            if (gap <= target.gap && violation <= target.violation) || out_of_budget {
                // The stationary pair (w + Jᵀŷ, ŷ) when it certifies (it is what a warm
                // start from ŷ finds again), else (v, ŷ), whose gap sees g only squared.
                let c = self.stationary_candidate(p, sol);
                if c.gap <= target.gap && c.violation <= target.violation {
                    break SolveStatus::Converged;
                }
                let c = self.candidate(p, sol);
                if c.gap <= target.gap && c.violation <= target.violation {
                    break SolveStatus::Converged;
                }
                if out_of_budget {
                    break SolveStatus::MaxIterations;
                }
            }
            // The inner problem is solved when the gradient's share of the gap is small (or
            // the last step was exact: the active set held along it).
            let g_sq = {
                let g = &self.g;
                self.normal.workers().sum(g.len(), |c| g[c] * g[c])
            };
            // The Newton matrix I + Jᵀ Σ_A J of the current active set.
            {
                let (y, rho) = (&self.y, &self.rho);
                self.normal
                    .workers()
                    .map(&mut self.d, |i, _| if y[i] > 0.0 { rho[i] } else { 0.0 });
            }
            if !after_update && (exact || 0.5 * g_sq <= 0.1 * target.gap) {
                // The inner problem is solved: when its Newton matrix is the factorized one,
                // conjugate gradients on the dual of its active set first (each iteration
                // one pair of triangular solves), then the multiplier update.
                if self.d == self.d_factored && st.dual_iterations > 0 {
                    let budget = st.dual_iterations.min(st.max_solves.saturating_sub(solves));
                    if self.dual_cg(p, target, sol, budget, &mut solves) {
                        break SolveStatus::Converged;
                    }
                }
                let active = self.yhat.iter().filter(|&&y| y > 0.0).count();
                self.update_multipliers(target, active);
                exact = false;
                after_update = true;
                continue;
            }
            // The rows whose weight is not the factor's, and whether a factor is in hand (a
            // NaN in `d_factored`: no factor of any weights), in one pass.
            let (changed, in_hand) = {
                let (d, df) = (&self.d, &self.d_factored);
                (0..m).fold((0usize, true), |(changed, in_hand), i| {
                    (
                        changed + usize::from(d[i] != df[i]),
                        in_hand && !df[i].is_nan(),
                    )
                })
            };
            if changed > 0 {
                // A few changed rows: rank-one updates and downdates of the factor in hand
                // (each a small part of a factorization on a crowd's thin factors).
                let mut updated = in_hand && changed <= st.max_updates;
                if updated {
                    for i in 0..m {
                        let delta = self.d[i] - self.d_factored[i];
                        if delta == 0.0 {
                            continue;
                        }
                        if !self.normal.update_row(j, i, delta) {
                            // Not in blocks, or a downdate failed: the factor is no longer
                            // that of any `d_factored`.
                            self.d_factored[0] = f64::NAN;
                            updated = false;
                            break;
                        }
                        self.d_factored[i] = self.d[i];
                    }
                }
                if !updated {
                    if factorizations == st.max_iterations {
                        out_of_budget = true;
                        continue;
                    }
                    factorizations += 1;
                    if !self.normal.factorize(j, 1.0, &self.d) {
                        break SolveStatus::NumericalError;
                    }
                    self.d_factored.copy_from_slice(&self.d);
                }
            }
            let g = &self.g;
            self.normal.workers().map(&mut self.dir, |c, _| -g[c]);
            self.normal.solve_in_place(&mut self.dir);
            solves += 1;
            after_update = false;
            if self.dir.iter().any(|x| !x.is_finite()) {
                break SolveStatus::NumericalError;
            }
            let Some((tau, crossed)) = self.line_search(j) else {
                // No descent left along the direction: the inner problem is solved to
                // rounding.
                exact = true;
                continue;
            };
            let dir = &self.dir;
            self.normal
                .workers()
                .map(&mut self.v, |c, x| x + tau * dir[c]);
            exact = !crossed;
        };
        let c = if status == SolveStatus::Converged || status == SolveStatus::MaxIterations {
            certify(
                p,
                &sol.v,
                &sol.lambda,
                &mut self.scratch_m,
                &mut self.scratch_n,
            )
        } else {
            self.candidate(p, sol)
        };
        let mut rep = report(status, c, factorizations);
        self.normal.times().since(times).report_into(&mut rep);
        Ok(rep)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TIGHT: Target = Target {
        gap: 1e-14,
        violation: 1e-12,
    };

    fn solve_with(
        newton: &mut Newton,
        rows: &ConstraintRows,
        w: &[f64],
        b: &[f64],
        sol: &mut ProjectionSolution,
    ) -> SolveReport {
        let p = ProjectionProblem {
            w,
            jacobian: rows,
            b,
        };
        newton.solve(&p, TIGHT, sol).unwrap()
    }

    fn solve(rows: &ConstraintRows, w: &[f64], b: &[f64]) -> (SolveReport, ProjectionSolution) {
        let mut newton = Newton::new(NewtonSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = solve_with(&mut newton, rows, w, b, &mut sol);
        (rep, sol)
    }

    #[test]
    fn projects_onto_a_half_plane_in_closed_form() {
        // v ≥ (1, ·) from w = (−1, 2): the projection is (1, 2) with λ = 2.
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, 1.0)]);
        let (rep, sol) = solve(&rows, &[-1.0, 2.0], &[-1.0]);
        assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
        assert_eq!(rep.solver, "newton");
        assert!((sol.v[0] - 1.0).abs() < 1e-9 && sol.v[1] == 2.0, "{sol:?}");
        assert!((sol.lambda[0] - 2.0).abs() < 1e-9, "{sol:?}");
        assert_eq!(rep.active, 1);
        assert!(rep.iterations >= 1);
    }

    #[test]
    fn a_target_gap_of_infinity_updated_the_multipliers_forever() {
        // `time.tol = 1e300` asks a gap of (0.1 tol)² (μ/μ_max)³ = ∞: the inner problem was
        // always "solved", every pass a multiplier update that moves no velocity, and the
        // solve (of a round in `auto`) never ended. On a thread, so that the old code fails
        // here instead of hanging the suite.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut rows = ConstraintRows::new(2);
            rows.push(0, 0.0, [(0, 1.0)]);
            rows.push(0, 0.0, [(0, 1.0), (1, 1.0)]);
            let p = ProjectionProblem {
                w: &[-1.0, 2.0],
                jacobian: &rows,
                b: &[-1.0, -4.0],
            };
            let target = Target {
                gap: f64::INFINITY,
                violation: 1e-9,
            };
            let mut sol = ProjectionSolution::default();
            let rep = Newton::new(NewtonSettings::default())
                .unwrap()
                .solve(&p, target, &mut sol)
                .unwrap();
            let _ = tx.send((rep, sol));
        });
        let (rep, sol) = rx
            .recv_timeout(std::time::Duration::from_secs(20))
            .expect("the solve ended");
        assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
        assert!(rep.violation <= 1e-9, "{rep:?}");
        // Feasible: v0 ≥ 1 and v0 + v1 ≥ 4.
        assert!(
            sol.v[0] >= 1.0 - 1e-9 && sol.v[0] + sol.v[1] >= 4.0 - 1e-9,
            "{sol:?}"
        );
    }

    #[test]
    fn redundant_rows_keep_the_newton_matrix_definite() {
        // The same constraint three times plus a parallel weaker one: J Jᵀ is singular.
        let mut rows = ConstraintRows::new(2);
        for k in 0..3 {
            rows.push(k, 0.0, [(0, 1.0), (1, 1.0)]);
        }
        rows.push(3, 0.0, [(0, 2.0), (1, 2.0)]);
        let b = [-2.0, -2.0, -2.0, -1.0];
        let (rep, sol) = solve(&rows, &[0.0, 0.0], &b);
        assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
        // The projection of 0 onto x + y ≥ 2 is (1, 1), whatever the split of λ.
        assert!((sol.v[0] - 1.0).abs() < 1e-9 && (sol.v[1] - 1.0).abs() < 1e-9);
        let total = sol.lambda[0] + sol.lambda[1] + sol.lambda[2] + 2.0 * sol.lambda[3];
        assert!((total - 1.0).abs() < 1e-9, "{sol:?}");
    }

    #[test]
    fn a_feasible_prediction_costs_no_factorization() {
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, 1.0)]);
        let w = [0.3, -0.7];
        let mut newton = Newton::new(NewtonSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = solve_with(&mut newton, &rows, &w, &[0.0], &mut sol);
        assert_eq!((rep.iterations, rep.active), (0, 0));
        assert_eq!(sol.v, w);
        assert_eq!(newton.counts(), FactorizationCounts::default());
    }

    #[test]
    fn the_answer_as_warm_start_costs_no_factorization() {
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, 1.0)]);
        rows.push(1, 0.0, [(1, 1.0)]);
        let (w, b) = ([-1.0, -3.0], [-1.0, -1.0]);
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        // (At 1e-12 the stationary pair w + Jᵀŷ misses by ρ times a rounding of s, and the
        // answer is (v, ŷ) instead, which a warm start does not see.)
        let t = Target {
            gap: 1e-10,
            violation: 1e-9,
        };
        let mut newton = Newton::new(NewtonSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let cold = newton.solve(&p, t, &mut sol).unwrap();
        assert!(
            cold.status.is_converged() && cold.iterations > 0,
            "{cold:?}"
        );
        let warm = newton.solve(&p, t, &mut sol).unwrap();
        assert!(
            warm.status.is_converged() && warm.iterations == 0,
            "{warm:?}"
        );
    }

    #[test]
    fn the_line_search_finds_the_minimum_past_breakpoints() {
        // φ'(τ) = −3 + τ, slope +2 from τ = 1, −1 from τ = 2: −2 at 1, 1 at 2 → root 5/3.
        let mut breaks = [(2.0, -1.0), (1.0, 2.0)];
        let (tau, crossed) = line_minimum(-3.0, 1.0, 1.0, &mut breaks);
        assert!((tau - 5.0 / 3.0).abs() < 1e-15 && crossed, "{tau}");
        // Before the first breakpoint.
        let mut breaks = [(4.0, 1.0)];
        assert_eq!(line_minimum(-3.0, 1.0, 1.0, &mut breaks), (3.0, false));
    }

    #[test]
    fn a_zero_row_that_cannot_hold_is_infeasible() {
        let mut rows = ConstraintRows::new(1);
        rows.push(0, 0.0, []);
        let (rep, _) = solve(&rows, &[0.0], &[-1.0]);
        assert_eq!(rep.status, SolveStatus::Infeasible);
    }

    #[test]
    fn bad_settings_name_the_field() {
        for (b, field) in [
            (NewtonSettings::builder().rho(0.0), "rho"),
            (NewtonSettings::builder().rho_max(1.0), "rho_max"),
            (NewtonSettings::builder().rho_increase(1.0), "rho_increase"),
            (NewtonSettings::builder().rho_theta(1.0), "rho_theta"),
            (
                NewtonSettings::builder().max_iterations(0),
                "max_iterations",
            ),
            (NewtonSettings::builder().max_solves(0), "max_solves"),
        ] {
            let e = b.build().unwrap_err();
            assert!(e.to_string().contains(field), "{e}");
        }
    }
}
