//! Adaptive steps for the catching-up scheme: a local error estimate, step rejection, step
//! limits, and the projection accuracy `ε_k` tied to the one tolerance that sets them all.
//!
//! The scheme is first order and its solutions are only Lipschitz: where a contact starts the
//! velocity jumps and one step errs by `O(μ · |Δv|)`, elsewhere by `O(μ²)`. The controller
//! therefore bounds the error *per step* in the state's own unit (`tol`, metres for crowds):
//! an error per unit step would ask `|Δv| ≤ tol` at a jump, which no step size gives. Steps
//! grow by at most `grow`, shrink by at least `shrink` on a rejection, and stay in
//! `[mu_min, mu_max]`; a step that the solver cannot certify is rejected like one that errs,
//! except at the floor of `ε/μ²` (below): there a smaller step asks the same relative
//! accuracy of the same solver, so the third trial in a row that cannot be certified there
//! ends the step with the error instead of halving on to `mu_min` (a solver that stalls
//! above the floor would crawl through ~20 failing trials a step first).
//! On smooth stretches steps settle at `μ ~ √(tol/C)`, so the global error scales like `√tol`;
//! at equal error this costs what error-per-unit-step control costs there, without its
//! collapse to `mu_min` at every contact.
//!
//! `ε_k = max(θ² tol² (μ_k / μ_max)³, floor · μ_k²)`: above the floor the projection error
//! `√ε_k ≤ θ tol` stays a fraction of the step's error budget, and `ε_k / μ_k²` falls with
//! `μ_k` and with `tol`, down to the `floor` double precision certifies
//! ([`AdaptiveSettings::eps_policy`]): Definition 4.3 of `seeds/002` with `tol` as the
//! parameter that goes to zero. Where the floor binds (every step once
//! `θ² tol² μ / μ_max³ < floor`), `ε_k / μ_k²` is the floor whatever `tol`, and `√ε_k` exceeds
//! `θ tol` for `μ_k > θ tol / √floor`.

use moreau_core::{Field, Num, StepReport};
use serde::{Deserialize, Serialize};

use crate::Correction;
use crate::error::IntegrateError;
use crate::scheme::{EpsPolicy, Scheme};

/// How the local error of a step is estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ErrorEstimate {
    /// One step of `μ` against two of `μ/2` from the same state; the two half steps are kept.
    /// Three projections per accepted step.
    #[default]
    StepDoubling,
    /// `μ/2 · |v_k − v_{k−1}|_∞`, the change of velocity between consecutive steps (Euler's
    /// `μ²/2 |q''|`). One projection per accepted step, plus one per rejection.
    VelocityChange,
}

/// Settings of the step controller; build with [`AdaptiveSettings::new`], adjust the public
/// fields, then [`validate`](Self::validate) (the controller does).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdaptiveSettings {
    /// The local error allowed per step, in the unit of the state (> 0).
    pub tol: f64,
    /// Smallest step; a step this small is accepted whatever its estimate (reported).
    pub mu_min: f64,
    /// Largest step.
    pub mu_max: f64,
    /// The first step tried.
    pub mu_first: f64,
    /// Safety factor on the predicted step, in (0, 1].
    pub safety: f64,
    /// Largest growth factor between steps (> 1).
    pub grow: f64,
    /// Largest shrink factor on a rejection, in (0, 1).
    pub shrink: f64,
    /// Fraction `θ` of the step's error budget left to the projection, in (0, 1].
    pub theta: f64,
    /// The error estimate.
    pub estimate: ErrorEstimate,
    /// The smallest `ε/μ²` the projections are asked for (> 0; [`EpsPolicy::floor`]): where
    /// the solver's certificates stop in double precision. Below it a step the solver cannot
    /// certify is not helped by a smaller one (the floor scales with `μ²`), so a floor under
    /// what the solver reaches sends the controller down to `mu_min`.
    pub eps_floor: f64,
}

impl AdaptiveSettings {
    /// Defaults for tolerance `tol`: steps in `[1e-6, 0.5]`, first 0.01 (a `mu_max` set below
    /// it needs `mu_first` lowered too: `validate` refuses `mu_first > mu_max`), safety 0.9,
    /// growth ≤ 2, shrink ≥ 0.2, `θ = 0.1`, step doubling, the floor
    /// [`EpsPolicy::ADAPTIVE_FLOOR`].
    pub fn new(tol: f64) -> Self {
        Self {
            tol,
            mu_min: 1e-6,
            mu_max: 0.5,
            mu_first: 0.01,
            safety: 0.9,
            grow: 2.0,
            shrink: 0.2,
            theta: 0.1,
            estimate: ErrorEstimate::StepDoubling,
            eps_floor: EpsPolicy::ADAPTIVE_FLOOR,
        }
    }

    /// Checks every field; the error names the first one out of its domain.
    pub fn validate(&self) -> Result<(), IntegrateError> {
        let bad = |field: &'static str, value: f64, reason: &'static str| {
            Err(IntegrateError::InvalidSetting {
                field,
                value: Num(value).to_string(),
                reason,
            })
        };
        if !(self.tol > 0.0 && self.tol.is_finite()) {
            return bad("tol", self.tol, "must be finite and > 0");
        }
        if !(self.mu_min > 0.0 && self.mu_min.is_finite()) {
            return bad("mu_min", self.mu_min, "must be finite and > 0");
        }
        if !(self.mu_max >= self.mu_min && self.mu_max.is_finite()) {
            return bad("mu_max", self.mu_max, "must be finite and ≥ mu_min");
        }
        if !(self.mu_first >= self.mu_min && self.mu_first <= self.mu_max) {
            return bad("mu_first", self.mu_first, "must lie in [mu_min, mu_max]");
        }
        if !(self.safety > 0.0 && self.safety <= 1.0) {
            return bad("safety", self.safety, "must lie in (0, 1]");
        }
        if !(self.grow > 1.0 && self.grow.is_finite()) {
            return bad("grow", self.grow, "must be finite and > 1");
        }
        if !(self.shrink > 0.0 && self.shrink < 1.0) {
            return bad("shrink", self.shrink, "must lie in (0, 1)");
        }
        if !(self.theta > 0.0 && self.theta <= 1.0) {
            return bad("theta", self.theta, "must lie in (0, 1]");
        }
        if !(self.eps_floor > 0.0 && self.eps_floor.is_finite()) {
            return bad("eps_floor", self.eps_floor, "must be finite and > 0");
        }
        Ok(())
    }

    /// The projection accuracy policy tied to the tolerance: `ε = θ² tol² (μ / μ_max)³`, at
    /// least `eps_floor μ²`.
    pub fn eps_policy(&self) -> EpsPolicy {
        EpsPolicy {
            floor: self.eps_floor,
            ..EpsPolicy::tied_to_tolerance(self.theta * self.tol, self.mu_max)
        }
    }
}

/// What an accepted adaptive step reports.
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptiveStep {
    /// The accepted step (for step doubling: its second half; `mu` is the whole step), with
    /// the iterations of every trial and rejection added up.
    pub report: StepReport,
    /// The estimated local error of the accepted step.
    pub error: f64,
    /// Trials rejected before it.
    pub rejected: usize,
    /// The step the controller will try next.
    pub next_mu: f64,
}

/// What a [`StepController`] carries from one step to the next.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControllerState {
    /// The step it will try next.
    pub mu: f64,
    /// The velocity of the last accepted step (empty: none).
    pub v_prev: Vec<f64>,
    /// Steps accepted so far.
    pub accepted: usize,
    /// Trials rejected so far.
    pub rejected: usize,
}

/// The step-size controller; holds its scratch memory and the last step.
#[derive(Debug, Clone)]
pub struct StepController {
    settings: AdaptiveSettings,
    mu: f64,
    v_prev: Vec<f64>,
    saved: Vec<f64>,
    full: Vec<f64>,
    /// Steps accepted so far.
    pub accepted: usize,
    /// Trials rejected so far.
    pub rejected: usize,
}

impl StepController {
    /// Trials in a row of one step that cannot be certified at the floor of `ε/μ²` (the
    /// step, its half and its quarter) before the step ends with the error.
    pub const UNCERTIFIED_AT_FLOOR: usize = 3;

    /// A controller with validated settings.
    pub fn new(settings: AdaptiveSettings) -> Result<Self, IntegrateError> {
        settings.validate()?;
        Ok(Self {
            settings,
            mu: settings.mu_first,
            v_prev: Vec::new(),
            saved: Vec::new(),
            full: Vec::new(),
            accepted: 0,
            rejected: 0,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &AdaptiveSettings {
        &self.settings
    }

    /// The step the controller will try next.
    pub fn next_mu(&self) -> f64 {
        self.mu
    }

    /// What the next step depends on.
    pub fn state(&self) -> ControllerState {
        ControllerState {
            mu: self.mu,
            v_prev: self.v_prev.clone(),
            accepted: self.accepted,
            rejected: self.rejected,
        }
    }

    /// Restores [`state`](Self::state).
    pub fn restore(&mut self, state: &ControllerState) {
        self.mu = state.mu;
        self.v_prev.clone_from(&state.v_prev);
        self.accepted = state.accepted;
        self.rejected = state.rejected;
    }

    /// Forgets the last velocity (after the state changed size or jumped).
    pub fn reset_history(&mut self) {
        self.v_prev.clear();
    }

    fn factor(&self, error: f64) -> f64 {
        let s = &self.settings;
        if error <= 0.0 {
            return s.grow;
        }
        (s.safety * (s.tol / error).sqrt()).clamp(s.shrink, s.grow)
    }

    /// One accepted step from `(t, q)`, never past `t_end`; `q` becomes the new state. Sets the
    /// scheme's `ε` policy to [`AdaptiveSettings::eps_policy`].
    pub fn step<F: Field + ?Sized, C: Correction>(
        &mut self,
        scheme: &mut Scheme<C>,
        field: &F,
        set: &mut C::Set<'_>,
        k: usize,
        t: f64,
        q: &mut [f64],
        t_end: f64,
    ) -> Result<AdaptiveStep, IntegrateError> {
        let s = self.settings;
        let remaining = t_end - t;
        if !(remaining > 0.0) {
            return Err(IntegrateError::InvalidSetting {
                field: "t_end",
                value: Num(t_end).to_string(),
                reason: "must be after the current time",
            });
        }
        // Its smallest step must move the time (from t0 = 10¹² with mu_min = 10⁻⁶, millions of
        // steps never reached the end).
        crate::stepping::check_resolution("mu_min", s.mu_min, t, t_end)?;
        let policy = s.eps_policy();
        scheme.set_eps(policy);
        let n = q.len();
        if self.v_prev.len() != n {
            self.v_prev.clear();
        }
        self.saved.clear();
        self.saved.extend_from_slice(q);
        let (mut rejected, mut iterations, mut redone) = (0usize, 0usize, 0usize);
        let mut uncertified_at_floor = 0usize;
        let mut factorizations = 0usize;
        loop {
            // Land on t_end rather than leave a sliver after it.
            let asked = self.mu.min(s.mu_max).max(s.mu_min);
            let mut mu = asked;
            if mu >= remaining || remaining - mu < 0.5 * s.mu_min.max(1e-3 * mu) {
                mu = remaining;
            }
            q.copy_from_slice(&self.saved);
            let trial = self.trial(scheme, field, set, k, t, q, mu);
            // No smaller trial follows this one: the floor was asked (landing may lengthen it
            // to what is left, up to 1.5 `mu_min`), or less than the floor is left. (Judged by
            // `mu` alone, a floor step lengthened to land was rejected and tried again forever.)
            let smallest = asked <= s.mu_min * (1.0 + 1e-12) || mu == remaining && mu < s.mu_min;
            match trial {
                Ok((mut report, error, (its, factors))) => {
                    iterations += its;
                    factorizations += factors;
                    redone += report.redone;
                    if error <= s.tol || smallest {
                        let grown = (mu * self.factor(error)).clamp(s.mu_min, s.mu_max);
                        // After a step cut short by t_end, do not mistake its size for a limit.
                        self.mu = if mu == remaining {
                            grown.max(self.mu)
                        } else {
                            grown
                        };
                        self.accepted += 1;
                        self.rejected += rejected;
                        if s.estimate == ErrorEstimate::VelocityChange {
                            self.v_prev.clear();
                            self.v_prev
                                .extend(q.iter().zip(&self.saved).map(|(a, b)| (a - b) / mu));
                        }
                        report.iterations = iterations;
                        report.factorizations = factorizations;
                        report.redone = redone;
                        report.local_error = Some(error);
                        report.mu = mu;
                        if mu == remaining {
                            report.t = t_end;
                        }
                        return Ok(AdaptiveStep {
                            report,
                            error,
                            rejected,
                            next_mu: self.mu,
                        });
                    }
                    // Rejected: at least halve (the factor is already ≥ shrink).
                    self.mu = mu * self.factor(error).min(0.5);
                }
                Err(e) if smallest => {
                    q.copy_from_slice(&self.saved);
                    return Err(e);
                }
                Err(e @ IntegrateError::NotCertified { .. }) => {
                    if policy.at_floor(mu) {
                        uncertified_at_floor += 1;
                        if uncertified_at_floor == Self::UNCERTIFIED_AT_FLOOR {
                            q.copy_from_slice(&self.saved);
                            return Err(e);
                        }
                    }
                    self.mu = mu * 0.5;
                }
                Err(IntegrateError::CrossedOutside { .. }) => {
                    self.mu = mu * 0.5;
                }
                Err(e) => {
                    q.copy_from_slice(&self.saved);
                    return Err(e);
                }
            }
            rejected += 1;
        }
    }

    /// One trial of size `mu` from `q` (which holds `saved`): the state it reaches, the report
    /// to keep, the error estimate and the iterations and factorizations spent.
    fn trial<F: Field + ?Sized, C: Correction>(
        &mut self,
        scheme: &mut Scheme<C>,
        field: &F,
        set: &mut C::Set<'_>,
        k: usize,
        t: f64,
        q: &mut [f64],
        mu: f64,
    ) -> Result<(StepReport, f64, (usize, usize)), IntegrateError> {
        match self.settings.estimate {
            ErrorEstimate::StepDoubling => {
                let whole = scheme.step(field, set, k, t, q, mu)?;
                self.full.clear();
                self.full.extend_from_slice(q);
                q.copy_from_slice(&self.saved);
                let first = scheme.step(field, set, k, t, q, 0.5 * mu)?;
                let mut second = scheme.step(field, set, k, t + 0.5 * mu, q, 0.5 * mu)?;
                let error = q
                    .iter()
                    .zip(&self.full)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                let its = (
                    whole.iterations + first.iterations + second.iterations,
                    whole.factorizations + first.factorizations + second.factorizations,
                );
                second.redone += whole.redone + first.redone;
                second.eps = second.eps.max(first.eps);
                second.violation = second.violation.max(first.violation);
                second.timings.add(&whole.timings);
                second.timings.add(&first.timings);
                Ok((second, error, its))
            }
            ErrorEstimate::VelocityChange => {
                let report = scheme.step(field, set, k, t, q, mu)?;
                let error = if self.v_prev.len() == q.len() {
                    0.5 * mu
                        * q.iter()
                            .zip(&self.saved)
                            .zip(&self.v_prev)
                            .map(|((a, b), v)| ((a - b) / mu - v).abs())
                            .fold(0.0, f64::max)
                } else {
                    0.0
                };
                let its = (report.iterations, report.factorizations);
                Ok((report, error, its))
            }
        }
    }
}
