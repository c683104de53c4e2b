//! Accelerated projected gradient on the dual (FISTA with adaptive restart and backtracking).

use moreau_core::{Parallelism, SolveStatus};

use crate::certificate::gap_and_violation;
use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::products::{Transpose, row_dot_sum};
use crate::workers::Workers;

/// Settings of [`Apgd`]; build them with [`ApgdSettings::builder`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ApgdSettings {
    /// Iteration budget per solve.
    pub max_iterations: usize,
    /// Power iterations for the initial estimate of `‖J Jᵀ‖` (backtracking corrects it).
    pub power_iterations: usize,
    /// Restart the momentum when it points uphill (O'Donoghue–Candès gradient test).
    pub adaptive_restart: bool,
    /// Threads for the products and vector updates (the same bits on any count).
    #[serde(skip)]
    pub parallelism: Parallelism,
}

impl Default for ApgdSettings {
    fn default() -> Self {
        Self {
            max_iterations: 20_000,
            power_iterations: 12,
            adaptive_restart: true,
            parallelism: Parallelism::SEQUENTIAL,
        }
    }
}

impl ApgdSettings {
    /// A builder starting from the defaults.
    pub fn builder() -> ApgdSettingsBuilder {
        ApgdSettingsBuilder(Self::default())
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SolveError> {
        crate::error::check_budgets(&[
            ("max_iterations", self.max_iterations),
            ("power_iterations", self.power_iterations),
        ])?;
        if self.max_iterations == 0 {
            return Err(SolveError::InvalidSetting {
                field: "max_iterations",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        if self.power_iterations == 0 {
            return Err(SolveError::InvalidSetting {
                field: "power_iterations",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        Ok(())
    }
}

/// Builder of [`ApgdSettings`].
#[derive(Debug, Clone)]
pub struct ApgdSettingsBuilder(ApgdSettings);

impl ApgdSettingsBuilder {
    /// Iteration budget per solve.
    pub fn max_iterations(mut self, n: usize) -> Self {
        self.0.max_iterations = n;
        self
    }
    /// Power iterations for the step-size estimate.
    pub fn power_iterations(mut self, n: usize) -> Self {
        self.0.power_iterations = n;
        self
    }
    /// Adaptive restart on or off.
    pub fn adaptive_restart(mut self, on: bool) -> Self {
        self.0.adaptive_restart = on;
        self
    }
    /// Threads for the products and vector updates.
    pub fn parallelism(mut self, p: Parallelism) -> Self {
        self.0.parallelism = p;
        self
    }
    /// Validates and returns the settings.
    pub fn build(self) -> Result<ApgdSettings, SolveError> {
        self.0.validate()?;
        Ok(self.0)
    }
}

/// The accelerated projected gradient on the dual `min_{λ≥0} ½λᵀJJᵀλ + λᵀ(b + Jw)`.
///
/// The dual gradient is `s = b + J(w + Jᵀλ)`, the primal slack itself, so each iteration costs
/// one product with `Jᵀ` and one with `J`; the extrapolated point's `s` and `Jᵀy` follow by
/// linearity. Scratch memory is sized once and reused.
#[derive(Debug)]
pub struct Apgd {
    settings: ApgdSettings,
    workers: Workers,
    jt: Transpose,
    // per-row scratch
    lam_next: Vec<f64>,
    y: Vec<f64>,
    s: Vec<f64>,
    s_next: Vec<f64>,
    s_y: Vec<f64>,
    // per-unknown scratch: Jᵀλ, Jᵀλ_next, Jᵀy
    u: Vec<f64>,
    u_next: Vec<f64>,
    u_y: Vec<f64>,
}

impl Apgd {
    /// A solver with validated settings.
    pub fn new(settings: ApgdSettings) -> Result<Self, SolveError> {
        settings.validate()?;
        Ok(Self {
            workers: Workers::new(settings.parallelism)?,
            settings,
            jt: Transpose::default(),
            lam_next: Vec::new(),
            y: Vec::new(),
            s: Vec::new(),
            s_next: Vec::new(),
            s_y: Vec::new(),
            u: Vec::new(),
            u_next: Vec::new(),
            u_y: Vec::new(),
        })
    }

    fn size(&mut self, m: usize, n: usize) {
        for v in [
            &mut self.lam_next,
            &mut self.y,
            &mut self.s,
            &mut self.s_next,
            &mut self.s_y,
        ] {
            v.clear();
            v.resize(m, 0.0);
        }
        for v in [&mut self.u, &mut self.u_next, &mut self.u_y] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// `u = Jᵀλ`, `s = b + J(w + u)`.
    fn slack(
        w: &Workers,
        jt: &Transpose,
        p: &ProjectionProblem<'_>,
        lam: &[f64],
        u: &mut [f64],
        s: &mut [f64],
    ) {
        w.map(u, |c, _| jt.dot(lam, c));
        let u: &[f64] = u;
        w.map(s, |i, _| p.b[i] + row_dot_sum(p.jacobian, p.w, u, i));
    }

    /// A lower estimate of `‖J Jᵀ‖₂` by power iteration from a fixed start (deterministic).
    fn estimate_lipschitz(&mut self, p: &ProjectionProblem<'_>) -> f64 {
        let m = p.rows();
        let (x, jx) = (&mut self.y, &mut self.s_y);
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = 1.0 + 0.1 * ((i * 7919 % 13) as f64);
        }
        let mut est = 0.0;
        for _ in 0..self.settings.power_iterations {
            let norm = x.iter().map(|a| a * a).sum::<f64>().sqrt();
            if norm == 0.0 {
                break;
            }
            x.iter_mut().for_each(|a| *a /= norm);
            self.u_y.iter_mut().for_each(|a| *a = 0.0);
            p.jacobian.mul_transpose_add(x, &mut self.u_y);
            est = self.u_y.iter().map(|a| a * a).sum::<f64>(); // xᵀJJᵀx with |x| = 1
            p.jacobian.mul(&self.u_y, jx);
            x.copy_from_slice(&jx[..m]);
        }
        est
    }
}

impl Default for Apgd {
    /// Default settings, one thread.
    fn default() -> Self {
        Self::new(ApgdSettings::default()).expect("the default settings are valid")
    }
}

impl ProjectionSolver for Apgd {
    fn name(&self) -> &'static str {
        "apgd"
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
        sol.resize_for(p);
        self.size(m, n);
        let lam = &mut sol.lambda;
        lam.iter_mut()
            .for_each(|l| *l = if l.is_finite() { l.max(0.0) } else { 0.0 });

        // A row without gradient is a fixed number: b_i < 0 there cannot be repaired.
        let infeasible =
            (0..m).any(|i| p.jacobian.row_norm_sq(i) == 0.0 && p.b[i] < -target.violation);
        let mut lip = if m == 0 || infeasible {
            1.0
        } else {
            self.estimate_lipschitz(p).max(f64::MIN_POSITIVE)
        };

        self.jt.build(p.jacobian);
        let wk = &self.workers;
        Self::slack(wk, &self.jt, p, lam, &mut self.u, &mut self.s);
        let (mut gap, mut viol) = gap_and_violation(wk, lam, &self.s);
        let mut iterations = 0;
        let mut status = SolveStatus::MaxIterations;
        if infeasible {
            status = SolveStatus::Infeasible;
        } else if gap <= target.gap && viol <= target.violation {
            status = SolveStatus::Converged;
        } else {
            self.y.copy_from_slice(lam);
            self.s_y.copy_from_slice(&self.s);
            self.u_y.copy_from_slice(&self.u);
            let mut t = 1.0_f64;
            while iterations < self.settings.max_iterations {
                iterations += 1;
                // Projected gradient step from y, with backtracking on the quadratic bound
                // φ(λ⁺) ≤ φ(y) + ∇φ(y)ᵀd + L/2 |d|², i.e. |Jᵀd|² ≤ L |d|².
                loop {
                    let (y, s_y) = (&self.y, &self.s_y);
                    wk.map(&mut self.lam_next, |i, _| (y[i] - s_y[i] / lip).max(0.0));
                    Self::slack(
                        wk,
                        &self.jt,
                        p,
                        &self.lam_next,
                        &mut self.u_next,
                        &mut self.s_next,
                    );
                    let (ln, un, uy) = (&self.lam_next, &self.u_next, &self.u_y);
                    let d_sq = wk.sum(m, |i| (ln[i] - y[i]) * (ln[i] - y[i]));
                    let jd_sq = wk.sum(n, |c| (un[c] - uy[c]) * (un[c] - uy[c]));
                    // A NaN stops the search too (the test `jd_sq <= …` never held, and a
                    // one-row problem with coefficients of 1e80 doubled `lip` forever).
                    if !(jd_sq > lip * d_sq * (1.0 + 1e-12)) || d_sq == 0.0 {
                        break;
                    }
                    lip *= 2.0;
                    if !lip.is_finite() {
                        break;
                    }
                }
                if !lip.is_finite() {
                    status = SolveStatus::NumericalError;
                    break;
                }
                (gap, viol) = gap_and_violation(wk, &self.lam_next, &self.s_next);
                let (y, ln) = (&self.y, &self.lam_next);
                let lam_now: &[f64] = lam;
                let uphill = wk.sum(m, |i| (y[i] - ln[i]) * (ln[i] - lam_now[i]));
                if gap <= target.gap && viol <= target.violation {
                    lam.copy_from_slice(&self.lam_next);
                    self.s.copy_from_slice(&self.s_next);
                    self.u.copy_from_slice(&self.u_next);
                    status = SolveStatus::Converged;
                    break;
                }
                if self.settings.adaptive_restart && uphill > 0.0 {
                    t = 1.0;
                    self.y.copy_from_slice(&self.lam_next);
                    self.s_y.copy_from_slice(&self.s_next);
                    self.u_y.copy_from_slice(&self.u_next);
                } else {
                    let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
                    let beta = (t - 1.0) / t_next;
                    let (ln, sn, un) = (&self.lam_next, &self.s_next, &self.u_next);
                    let (l0, s0, u0): (&[f64], &[f64], &[f64]) = (lam, &self.s, &self.u);
                    wk.map(&mut self.y, |i, _| ln[i] + beta * (ln[i] - l0[i]));
                    wk.map(&mut self.s_y, |i, _| sn[i] + beta * (sn[i] - s0[i]));
                    wk.map(&mut self.u_y, |c, _| un[c] + beta * (un[c] - u0[c]));
                    t = t_next;
                }
                std::mem::swap(lam, &mut self.lam_next);
                std::mem::swap(&mut self.s, &mut self.s_next);
                std::mem::swap(&mut self.u, &mut self.u_next);
            }
        }
        for j in 0..n {
            sol.v[j] = p.w[j] + self.u[j];
        }
        let active = sol.lambda.iter().filter(|&&l| l > 0.0).count();
        Ok(SolveReport {
            solver: self.name(),
            status,
            gap,
            violation: viol,
            iterations,
            active,
            ..SolveReport::default()
        })
    }
}
