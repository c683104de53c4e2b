//! How a run chooses its steps: fixed or adaptive, and the one place where "equal steps, the
//! last one shortened to land on the stop" is written.

use moreau_core::{Field, Num, StepReport};
use serde::{Deserialize, Serialize};

use crate::adaptive::{AdaptiveSettings, ControllerState, StepController};
use crate::correction::Correction;
use crate::error::IntegrateError;
use crate::scheme::Scheme;

/// The most steps one run may be asked for (a span over a step): 10⁹, hours of work even for
/// the smallest problems. Runs are stepped one step at a time (nothing is allocated per step
/// up front), so this bounds the time a run can take, not its memory.
pub const MAX_STEPS: f64 = 1e9;

/// The next of equal steps `h` that cover `remaining` with the last one shortened: `h` while
/// more than one step is left, then what is left (taken as `h` when within `10⁻⁹ h` of it:
/// rounding in the sum of the steps, so that spans that are multiples of `h` are covered by steps of exactly
/// `h`); `None` once what is left is below `10⁻⁹ h`. A last step shorter than
/// [`SHORTEST_LAST`]` × h` is not taken: the step before it takes what is left, at most 1 %
/// longer than `h` (so no step is shorter than `SHORTEST_LAST × h` unless the span is).
/// Callers pass an `h` no longer than the span they cover: of a span below `10⁻⁹ h` nothing
/// is taken.
pub fn fixed_step(h: f64, remaining: f64) -> Option<f64> {
    let n = (remaining / h - 1e-9).ceil();
    if !(n >= 1.0) {
        return None;
    }
    if n > 2.0 {
        return Some(h);
    }
    if n == 2.0 {
        return Some(if remaining - h < SHORTEST_LAST * h {
            remaining
        } else {
            h
        });
    }
    Some(if (remaining - h).abs() <= 1e-9 * h {
        h
    } else {
        remaining
    })
}

/// The shortest last step [`fixed_step`] takes, as a share of `h`. A stop just past a
/// multiple of the step (a host's communication time stored in single precision, 0.05 s as
/// 0.05000000074505806; a horizon of 0.700000001 s) left a last step of 10⁻⁹ s, whose
/// `ε = κ μ³` (~10⁻³⁰) no projection certifies in doubles: the run failed there, and at every
/// retry. (Stretching the step before, not halving the two last ones: such a host's every
/// communication step is one step, as with 0.05 exactly.)
pub const SHORTEST_LAST: f64 = 0.01;

/// How steps are chosen, with what the next step depends on.
#[derive(Debug, Clone)]
pub enum Stepping {
    /// Equal steps, the last one before each stop shortened ([`fixed_step`]).
    Fixed {
        /// The step (s).
        step: f64,
    },
    /// Chosen by an error-controlling [`StepController`].
    Adaptive(StepController),
}

/// What [`Stepping`] carries from one step to the next (serializable: part of the state of a
/// run).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum SteppingState {
    /// Fixed steps carry nothing.
    Fixed,
    /// The controller's next step and last velocity.
    Adaptive(ControllerState),
}

/// The smallest step, in rounding units of the time, a run takes (`Scheme::run`,
/// [`Stepping::step`] and the adaptive controller refuse shorter ones).
const RESOLVABLE: f64 = 100.0;

/// Refuses a step `h` (the setting `field`) that times between `t` and `t_stop` cannot resolve:
/// below [`RESOLVABLE`] rounding units of them.
pub(crate) fn check_resolution(
    field: &'static str,
    h: f64,
    t: f64,
    t_stop: f64,
) -> Result<(), IntegrateError> {
    let scale = t.abs().max(t_stop.abs());
    if h >= RESOLVABLE * f64::EPSILON * scale {
        return Ok(());
    }
    Err(IntegrateError::InvalidSetting {
        field,
        value: format!("{} at times near {}", Num(h), Num(scale)),
        reason: "below 100 rounding units of the time, which it would not advance exactly \
                 (measure times from the run's start)",
    })
}

impl Stepping {
    /// Fixed steps of `step`, checked.
    pub fn fixed(step: f64) -> Result<Self, IntegrateError> {
        if !(step > 0.0 && step.is_finite()) {
            return Err(IntegrateError::InvalidSetting {
                field: "step",
                value: Num(step).to_string(),
                reason: "must be finite and > 0",
            });
        }
        Ok(Self::Fixed { step })
    }

    /// Adaptive steps with validated `settings`.
    pub fn adaptive(settings: AdaptiveSettings) -> Result<Self, IntegrateError> {
        Ok(Self::Adaptive(StepController::new(settings)?))
    }

    /// The longest step it takes: the fixed step, or the adaptive controller's `mu_max`.
    pub fn largest_step(&self) -> f64 {
        match self {
            Stepping::Fixed { step } => *step,
            Stepping::Adaptive(c) => c.settings().mu_max,
        }
    }

    /// True once `t` is at `t_stop` (within a billionth of a step).
    pub fn reached(&self, t: f64, t_stop: f64) -> bool {
        let scale = match self {
            Stepping::Fixed { step } => *step,
            Stepping::Adaptive(c) => c.settings().mu_min,
        };
        t_stop - t <= 1e-9 * scale
    }

    /// One accepted step from `(t, q)` towards `t_stop`, never past it; `None` when `t_stop`
    /// is reached. The report's `rejected` counts the trials rejected before it.
    pub fn step<F: Field + ?Sized, C: Correction>(
        &mut self,
        scheme: &mut Scheme<C>,
        field: &F,
        set: &mut C::Set<'_>,
        k: usize,
        t: f64,
        q: &mut [f64],
        t_stop: f64,
    ) -> Result<Option<StepReport>, IntegrateError> {
        if self.reached(t, t_stop) {
            return Ok(None);
        }
        // A step the time cannot resolve: `t + μ` rounds back to (or near) `t`, and the state
        // moved while the time stood still (from t0 = 1.7e9 with steps of 1e-7, 30 million
        // steps at the same time). `Scheme::run` refused it; stepping did not. (The adaptive
        // controller checks its smallest step itself.)
        if let Stepping::Fixed { step } = self {
            check_resolution("step", *step, t, t_stop)?;
        }
        match self {
            Stepping::Fixed { step } => match fixed_step(*step, t_stop - t) {
                Some(mu) => scheme.step(field, set, k, t, q, mu).map(Some),
                None => Ok(None),
            },
            Stepping::Adaptive(c) => {
                let s = c.step(scheme, field, set, k, t, q, t_stop)?;
                let mut report = s.report;
                report.rejected = s.rejected;
                Ok(Some(report))
            }
        }
    }

    /// Forgets what depends on the size of the state (people left).
    pub fn state_resized(&mut self) {
        if let Stepping::Adaptive(c) = self {
            c.reset_history();
        }
    }

    /// What the next step depends on.
    pub fn state(&self) -> SteppingState {
        match self {
            Stepping::Fixed { .. } => SteppingState::Fixed,
            Stepping::Adaptive(c) => SteppingState::Adaptive(c.state()),
        }
    }

    /// Restores [`state`](Self::state); the kind of stepping must match.
    pub fn restore(&mut self, state: &SteppingState) -> Result<(), IntegrateError> {
        match (self, state) {
            (Stepping::Fixed { .. }, SteppingState::Fixed) => Ok(()),
            (Stepping::Adaptive(c), SteppingState::Adaptive(s)) => {
                c.restore(s);
                Ok(())
            }
            (me, _) => Err(IntegrateError::InvalidSetting {
                field: "stepping",
                value: format!("{state:?}"),
                reason: if matches!(me, Stepping::Fixed { .. }) {
                    "the state was saved with adaptive steps, this run has fixed steps"
                } else {
                    "the state was saved with fixed steps, this run has adaptive steps"
                },
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The steps `fixed_step` takes over `span`, and where they end.
    fn cover(h: f64, span: f64) -> (f64, Vec<f64>) {
        let (mut t, mut steps) = (0.0, Vec::new());
        while let Some(mu) = fixed_step(h, span - t) {
            steps.push(mu);
            t += mu;
        }
        (t, steps)
    }

    #[test]
    fn fixed_steps_cover_a_span_with_the_last_one_shortened() {
        let (t, steps) = cover(0.3, 1.0);
        assert_eq!(steps.len(), 4);
        assert_eq!(&steps[..3], &[0.3, 0.3, 0.3]);
        assert!((steps[3] - 0.1).abs() < 1e-12 && (t - 1.0).abs() < 1e-12);
        // A multiple of the step: every step exactly h, although 20 − 399·0.05 ≠ 0.05.
        let (_, steps) = cover(0.05, 20.0);
        assert_eq!(steps.len(), 400);
        assert!(steps.iter().all(|&mu| mu == 0.05));
        assert_eq!(fixed_step(0.1, 0.0), None);
        assert_eq!(fixed_step(0.1, 1e-12), None);
    }

    #[test]
    fn a_stop_1e_minus_9_s_past_a_multiple_of_the_step_left_a_step_of_1e_minus_9_s() {
        for (h, span) in [
            (0.05, 0.700000001),
            (0.05, 0.7 + 0.0004),
            (0.05, 0.05 + 1e-8),
        ] {
            let (t, steps) = cover(h, span);
            assert!((t - span).abs() < 1e-12, "{h} {span}: {steps:?}");
            let n = steps.len();
            assert_eq!(n, (span / h).floor() as usize, "{h} {span}: {steps:?}");
            assert!(
                steps[..n - 1].iter().all(|&mu| mu == h),
                "{h} {span}: {steps:?}"
            );
            // The last step takes what is left: at most 1 % longer than h.
            assert!(
                steps[n - 1] > h && steps[n - 1] < 1.01 * h,
                "{h} {span}: {steps:?}"
            );
        }
        // From 1 % of h the last step is what is left, as before.
        let (_, steps) = cover(0.05, 0.7 + 0.001);
        assert!((steps[steps.len() - 1] - 0.001).abs() < 1e-12, "{steps:?}");
        assert_eq!(steps[steps.len() - 2], 0.05);
    }
}
