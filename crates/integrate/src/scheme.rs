//! The catching-up scheme: prediction, correction, the ε policy and the step sequence.

use std::time::Instant;

use moreau_core::{ConvexPart, Field, Num, StepReport};

use crate::correction::Correction;
use crate::error::IntegrateError;
use crate::stepping::fixed_step;

/// How the set-valued part `∂ψ` enters the prediction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Selection {
    /// `w = ` the element of minimal norm of `F(t, q) − ∂ψ(q)`: `seeds/002` Definition 4.3
    /// takes any element of `F(x_k)`; the minimal norm is ours (it sticks only where `q_i` is
    /// exactly 0, which is the chattering the README reports for Example 8.2).
    #[default]
    Explicit,
    /// `y = prox_{μψ}(q + μ F(t, q))`: implicit in `ψ`, explicit in `F`.
    SemiImplicit,
}

/// The projection accuracy per step, `ε_k = max(κ μ_k^p, floor · μ_k²)` with `p > 2` so that
/// `ε_k/μ_k²` falls with `μ_k` (to `floor`, 0 for fixed steps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpsPolicy {
    /// The factor `κ > 0`.
    pub kappa: f64,
    /// The power `p > 2`.
    pub power: f64,
    /// The smallest `ε/μ²` asked for ((m/s)² for a crowd: twice the projection's duality gap in
    /// velocity units): below some size a certificate cannot be had in double precision.
    pub floor: f64,
}

impl Default for EpsPolicy {
    fn default() -> Self {
        Self {
            kappa: 1.0,
            power: 3.0,
            floor: 0.0,
        }
    }
}

impl EpsPolicy {
    /// `ε_k = κ μ^p`, checked.
    pub fn new(kappa: f64, power: f64) -> Result<Self, IntegrateError> {
        if !(kappa > 0.0 && kappa.is_finite()) {
            return Err(IntegrateError::InvalidSetting {
                field: "eps kappa",
                value: Num(kappa).to_string(),
                reason: "must be finite and > 0",
            });
        }
        if !(power > 2.0 && power.is_finite()) {
            return Err(IntegrateError::InvalidSetting {
                field: "eps power",
                value: Num(power).to_string(),
                reason: "must be > 2 so that ε/μ² → 0",
            });
        }
        Ok(Self {
            kappa,
            power,
            floor: 0.0,
        })
    }

    /// `ε = max(budget² (μ / μ_max)³, 2·10⁻⁷ μ²)` for an adaptive controller whose
    /// convergence parameter is its tolerance: `budget = θ tol` is the projection's share of a
    /// step's error (`√ε ≤ budget` for `μ ≤ μ_max` above the floor), and `ε/μ² = budget² μ /
    /// μ_max³` falls as the steps actually taken shrink, as Definition 4.3 of seeds/002 asks (`p = 3 > 2`; the power 1 used before
    /// made `ε/μ²` *grow* as `μ` shrank: 10 at `μ = 10⁻⁶`, tol = 0.01), down to
    /// [`Self::ADAPTIVE_FLOOR`]: a duality gap of 10⁻⁷ (m/s)², about where Clarabel's
    /// certificates stop in double precision on crowds (measured on room-60 at `μ = 10⁻⁶`,
    /// tol = 0.003: asked 3.6·10⁻¹³, then 10⁻⁹, it stopped at 9·10⁻⁹ with NumericalError).
    pub fn tied_to_tolerance(budget: f64, mu_max: f64) -> Self {
        Self {
            kappa: budget * budget / (mu_max * mu_max * mu_max),
            power: 3.0,
            floor: Self::ADAPTIVE_FLOOR,
        }
    }

    /// The floor of `ε/μ²` of adaptive runs: twice a velocity-space duality gap of 10⁻⁷.
    pub const ADAPTIVE_FLOOR: f64 = 2e-7;

    /// `ε` for a step `mu`.
    pub fn eps(&self, mu: f64) -> f64 {
        (self.kappa * mu.powf(self.power)).max(self.floor * mu * mu)
    }

    /// The shortest step whose `ε` is a normal double (`≥ f64::MIN_POSITIVE`): below it `ε`
    /// is rounded away, and no projection can be certified to it. (With `κ = ∞`, as a
    /// tolerance of 10³⁰⁰ gives, `κ μ^p` is NaN once `μ^p` underflows: only the floor counts
    /// below that.)
    pub fn shortest_certifiable(&self) -> f64 {
        let m = f64::MIN_POSITIVE;
        let by_kappa = if self.kappa.is_finite() {
            (m / self.kappa).powf(1.0 / self.power)
        } else {
            m.powf(1.0 / self.power)
        };
        if self.floor > 0.0 {
            by_kappa.min((m / self.floor).sqrt())
        } else {
            by_kappa
        }
    }

    /// Whether `ε` is the floor's at step `mu` (then, and at every smaller step, `ε/μ²` is the
    /// floor: a smaller step asks the same relative accuracy).
    pub fn at_floor(&self, mu: f64) -> bool {
        self.floor > 0.0 && self.floor * mu * mu >= self.kappa * mu.powf(self.power)
    }
}

/// The steps `μ_k` of a run.
#[derive(Debug, Clone, PartialEq)]
pub enum StepSequence {
    /// Equal steps `h` from `t0` to `t_end`, the last one shortened to land on `t_end`
    /// ([`fixed_step`](crate::fixed_step())).
    Fixed {
        /// The step.
        h: f64,
        /// The end time.
        t_end: f64,
    },
    /// The given steps, in order.
    Given(Vec<f64>),
}

fn check_step(mu: f64) -> Result<(), IntegrateError> {
    if mu > 0.0 && mu.is_finite() {
        Ok(())
    } else {
        Err(IntegrateError::InvalidSetting {
            field: "step",
            value: Num(mu).to_string(),
            reason: "must be finite and > 0",
        })
    }
}

/// The catching-up scheme for `q' ∈ F(t, q) − ∂ψ(q) − N(Q(t), q)`: a pipeline that holds
/// the correction (solver, warm start) and scratch memory. The field `F` and the set the
/// correction projects onto belong to the caller and are passed in at every step.
pub struct Scheme<C> {
    convex: Option<Box<dyn ConvexPart>>,
    selection: Selection,
    correction: C,
    eps: EpsPolicy,
    f: Vec<f64>,
    w: Vec<f64>,
    q_next: Vec<f64>,
}

impl<C> std::fmt::Debug for Scheme<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scheme")
            .field("selection", &self.selection)
            .field("eps", &self.eps)
            .finish_non_exhaustive()
    }
}

impl<C: Correction> Scheme<C> {
    /// The scheme with correction `correction`.
    pub fn new(correction: C, eps: EpsPolicy) -> Self {
        Self {
            convex: None,
            selection: Selection::Explicit,
            correction,
            eps,
            f: Vec::new(),
            w: Vec::new(),
            q_next: Vec::new(),
        }
    }

    /// Adds the set-valued part `∂ψ` and how the prediction treats it.
    pub fn with_convex_part(mut self, psi: Box<dyn ConvexPart>, selection: Selection) -> Self {
        self.convex = Some(psi);
        self.selection = selection;
        self
    }

    /// The correction (to reach its constraint set or multipliers).
    pub fn correction(&self) -> &C {
        &self.correction
    }

    /// The correction, mutably.
    pub fn correction_mut(&mut self) -> &mut C {
        &mut self.correction
    }

    /// The `ε_k` policy in force.
    pub fn eps_policy(&self) -> EpsPolicy {
        self.eps
    }

    /// Replaces the `ε_k` policy (an adaptive controller ties it to its tolerance).
    pub fn set_eps(&mut self, eps: EpsPolicy) {
        self.eps = eps;
    }

    /// The prediction velocity `w_k` of the last step.
    pub fn prediction(&self) -> &[f64] {
        &self.w
    }

    /// One step of size `mu` from `(t, q)` with field `field`, projecting onto `set`; `q`
    /// becomes `q_{k+1}`. `step` indexes the report.
    pub fn step<F: Field + ?Sized>(
        &mut self,
        field: &F,
        set: &mut C::Set<'_>,
        step: usize,
        t: f64,
        q: &mut [f64],
        mu: f64,
    ) -> Result<StepReport, IntegrateError> {
        let start = Instant::now();
        let n = q.len();
        if !(mu > 0.0 && mu.is_finite()) {
            return Err(IntegrateError::InvalidSetting {
                field: "mu",
                value: Num(mu).to_string(),
                reason: "the step must be finite and > 0",
            });
        }
        if let Some(index) = q.iter().position(|x| !x.is_finite()) {
            return Err(IntegrateError::NonFinite {
                step,
                t,
                what: "state",
                index,
            });
        }
        self.f.resize(n, 0.0);
        self.w.resize(n, 0.0);
        self.q_next.resize(n, 0.0);
        field.eval(t, q, &mut self.f);
        match (&self.convex, self.selection) {
            (None, _) => self.w.copy_from_slice(&self.f),
            (Some(psi), Selection::Explicit) => psi.min_norm_selection(q, &self.f, &mut self.w),
            (Some(psi), Selection::SemiImplicit) => {
                // y = prox_{μψ}(q + μF), w = (y − q)/μ.
                for i in 0..n {
                    self.q_next[i] = q[i] + mu * self.f[i];
                }
                psi.prox(mu, &self.q_next, &mut self.w);
                for i in 0..n {
                    self.w[i] = (self.w[i] - q[i]) / mu;
                }
            }
        }
        if let Some(index) = self.w.iter().position(|x| !x.is_finite()) {
            return Err(IntegrateError::NonFinite {
                step,
                t,
                what: "field",
                index,
            });
        }
        let eps_target = self.eps.eps(mu);
        let mut report = StepReport {
            step,
            t: t + mu,
            mu,
            eps_target,
            ..StepReport::default()
        };
        report.timings.predict = start.elapsed().as_secs_f64();
        self.correction
            .correct(set, q, &self.w, eps_target, &mut self.q_next, &mut report)?;
        q.copy_from_slice(&self.q_next);
        report.timings.total = start.elapsed().as_secs_f64();
        Ok(report)
    }

    /// Runs from `(t0, q)` through `steps`; `observe(report, q)` sees every accepted step.
    /// Returns the final time.
    pub fn run<F: Field + ?Sized>(
        &mut self,
        field: &F,
        set: &mut C::Set<'_>,
        t0: f64,
        q: &mut [f64],
        steps: &StepSequence,
        mut observe: impl FnMut(&StepReport, &[f64]),
    ) -> Result<f64, IntegrateError> {
        // Every setting is checked before the first step (a NaN t0 was blamed on t_end).
        if !t0.is_finite() {
            return Err(IntegrateError::InvalidSetting {
                field: "t0",
                value: Num(t0).to_string(),
                reason: "must be finite",
            });
        }
        match steps {
            StepSequence::Fixed { h, t_end } => {
                check_step(*h)?;
                if !(t_end.is_finite() && *t_end >= t0) {
                    return Err(IntegrateError::InvalidSetting {
                        field: "t_end",
                        value: Num(*t_end).to_string(),
                        reason: "must be finite and ≥ t0",
                    });
                }
                // A step the time cannot resolve: t + h rounded back to t, and a run from
                // t0 = 1.7e9 (a Unix time) with h = 1e-7 stepped forever at the same time.
                crate::stepping::check_resolution("h", *h, t0, *t_end)?;
                let steps = (t_end - t0) / h;
                if !(steps <= crate::MAX_STEPS) {
                    return Err(IntegrateError::InvalidSetting {
                        field: "t_end",
                        value: format!(
                            "{} with steps h = {} ({steps:.3e} steps)",
                            Num(*t_end),
                            Num(*h)
                        ),
                        reason: "more than the 10⁹ steps a run may take",
                    });
                }
            }
            StepSequence::Given(v) => v.iter().try_for_each(|&mu| check_step(mu))?,
        }
        let (mut t, mut k) = (t0, 0);
        // A step longer than the span is one step of the span: `fixed_step` takes what is
        // left below a billionth of `h` for rounding, which `h = 1e300` made the whole span
        // (no step at all).
        let next = |k: usize, t: f64| match steps {
            StepSequence::Fixed { h, t_end } => fixed_step(h.min(t_end - t0), t_end - t),
            StepSequence::Given(v) => v.get(k).copied(),
        };
        while let Some(mu) = next(k, t) {
            let report = self.step(field, set, k, t, q, mu)?;
            t = report.t;
            k += 1;
            observe(&report, q);
        }
        Ok(t)
    }
}

#[cfg(test)]
mod tests {
    use super::EpsPolicy;

    /// `ε(shortest_certifiable)` is a normal double and `ε` a little below is not, for a fixed
    /// `κ μ³`, an adaptive policy's floor, and the `κ = ∞` of a tolerance of 10³⁰⁰.
    #[test]
    fn the_shortest_certifiable_step_is_where_eps_leaves_the_normal_doubles() {
        let m = f64::MIN_POSITIVE;
        let normal = |x: f64| x >= m;
        for policy in [
            EpsPolicy::new(1e-3, 3.0).unwrap(),
            EpsPolicy::new(1.0, 3.0).unwrap(),
            EpsPolicy::new(1e6, 4.0).unwrap(),
            EpsPolicy::tied_to_tolerance(1e-3, 0.5),
            EpsPolicy::tied_to_tolerance(1e-3, 1e-120),
        ] {
            let s = policy.shortest_certifiable();
            assert!(s > 0.0 && s.is_finite(), "{policy:?}: {s}");
            assert!(normal(policy.eps(s * (1.0 + 1e-6))), "{policy:?}: {s}");
            assert!(!normal(policy.eps(s * 0.999)), "{policy:?}: {s}");
        }
        // (m / 10⁻³)^⅓: the crowd's default room.
        let s = EpsPolicy::new(1e-3, 3.0).unwrap().shortest_certifiable();
        assert!((s / 2.8126e-102 - 1.0).abs() < 1e-4, "{s}");
        // κ = ∞ (budget² overflowed): κ μ³ is NaN once μ³ underflows, so only the floor's
        // 2·10⁻⁷ μ² counts below (m)^⅓.
        let huge = EpsPolicy::tied_to_tolerance(1e300, 0.5);
        let s = huge.shortest_certifiable();
        assert!(
            (s / (m / EpsPolicy::ADAPTIVE_FLOOR).sqrt() - 1.0).abs() < 1e-12,
            "{s}"
        );
        assert!(!normal(huge.eps(s * 0.999)), "{s}");
    }
}
