//! Accelerated projected gradient on the dual (FISTA with adaptive restart and backtracking).

use moreau_core::SolveStatus;

use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};

/// Settings of [`Apgd`]; build them with [`ApgdSettings::builder`].
#[derive(Debug, Clone, PartialEq)]
pub struct ApgdSettings {
    /// Iteration budget per solve.
    pub max_iterations: usize,
    /// Power iterations for the initial estimate of `‖J Jᵀ‖` (backtracking corrects it).
    pub power_iterations: usize,
    /// Restart the momentum when it points uphill (O'Donoghue–Candès gradient test).
    pub adaptive_restart: bool,
}

impl Default for ApgdSettings {
    fn default() -> Self {
        Self {
            max_iterations: 20_000,
            power_iterations: 12,
            adaptive_restart: true,
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
#[derive(Debug, Clone, Default)]
pub struct Apgd {
    settings: ApgdSettings,
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
            settings,
            ..Self::default()
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
    fn slack(p: &ProjectionProblem<'_>, lam: &[f64], u: &mut [f64], s: &mut [f64]) {
        u.iter_mut().for_each(|x| *x = 0.0);
        p.jacobian.mul_transpose_add(lam, u);
        for (ui, wi) in u.iter_mut().zip(p.w) {
            *ui += wi; // temporarily v = w + Jᵀλ
        }
        p.jacobian.mul(u, s);
        for (si, bi) in s.iter_mut().zip(p.b) {
            *si += bi;
        }
        for (ui, wi) in u.iter_mut().zip(p.w) {
            *ui -= wi;
        }
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

fn gap_and_violation(lam: &[f64], s: &[f64]) -> (f64, f64) {
    let mut gap = 0.0;
    let mut viol: f64 = 0.0;
    for (&l, &s) in lam.iter().zip(s) {
        gap += l * s.max(0.0);
        viol = viol.max(-s);
    }
    (gap, viol)
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

        Self::slack(p, lam, &mut self.u, &mut self.s);
        let (mut gap, mut viol) = gap_and_violation(lam, &self.s);
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
                    for i in 0..m {
                        self.lam_next[i] = (self.y[i] - self.s_y[i] / lip).max(0.0);
                    }
                    Self::slack(p, &self.lam_next, &mut self.u_next, &mut self.s_next);
                    let d_sq: f64 = self
                        .lam_next
                        .iter()
                        .zip(&self.y)
                        .map(|(a, b)| (a - b) * (a - b))
                        .sum();
                    let jd_sq: f64 = self
                        .u_next
                        .iter()
                        .zip(&self.u_y)
                        .map(|(a, b)| (a - b) * (a - b))
                        .sum();
                    if jd_sq <= lip * d_sq * (1.0 + 1e-12) || d_sq == 0.0 {
                        break;
                    }
                    lip *= 2.0;
                }
                (gap, viol) = gap_and_violation(&self.lam_next, &self.s_next);
                let uphill: f64 = (0..m)
                    .map(|i| (self.y[i] - self.lam_next[i]) * (self.lam_next[i] - lam[i]))
                    .sum();
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
                    for i in 0..m {
                        self.y[i] = self.lam_next[i] + beta * (self.lam_next[i] - lam[i]);
                        self.s_y[i] = self.s_next[i] + beta * (self.s_next[i] - self.s[i]);
                    }
                    for j in 0..n {
                        self.u_y[j] = self.u_next[j] + beta * (self.u_next[j] - self.u[j]);
                    }
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
            status,
            gap,
            violation: viol,
            iterations,
            active,
            ..SolveReport::default()
        })
    }
}
