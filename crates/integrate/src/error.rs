//! The one error type of the integrator crate.

use moreau_core::{Num, SolveStatus};

/// Errors that stop a run.
#[derive(Debug, thiserror::Error)]
pub enum IntegrateError {
    /// A setting out of its domain.
    #[error("invalid setting {field} = {value}: {reason}")]
    InvalidSetting {
        /// The setting's name.
        field: &'static str,
        /// Its value, printed.
        value: String,
        /// Why it is rejected.
        reason: &'static str,
    },
    /// The projection could not be certified to its target, even by the fallback.
    #[error(
        "step {step} at t = {}: projection not certified ({status:?}): ε = {eps:e} for target {eps_target:e}, violation {violation:e} for target {max_violation:e}{}",
        Num(*t),
        below_floor(*status)
    )]
    NotCertified {
        /// Step index.
        step: usize,
        /// Time at the end of the step.
        t: f64,
        /// How the last solver ended.
        status: SolveStatus,
        /// Certified ε reached.
        eps: f64,
        /// ε asked for.
        eps_target: f64,
        /// Violation reached (length).
        violation: f64,
        /// Violation allowed (length).
        max_violation: f64,
    },
    /// Something outside the assembled constraints was still crossed after widening the margin.
    #[error(
        "step {step} at t = {}: {crossed} constraints outside the assembled set were crossed after {redone} wider margins",
        Num(*t)
    )]
    CrossedOutside {
        /// Step index.
        step: usize,
        /// Time at the end of the step.
        t: f64,
        /// How many constraints.
        crossed: usize,
        /// How many times the step was redone.
        redone: usize,
    },
    /// The state or the field became non-finite.
    #[error("step {step} at t = {}: non-finite {what} at index {index}", Num(*t))]
    NonFinite {
        /// Step index.
        step: usize,
        /// Time.
        t: f64,
        /// Which quantity.
        what: &'static str,
        /// Where.
        index: usize,
    },
    /// A solver refused the problem.
    #[error(transparent)]
    Solve(#[from] moreau_solve::SolveError),
}

/// What [`IntegrateError::NotCertified`]'s message adds when the target was below the
/// certificate's rounding floor.
fn below_floor(status: SolveStatus) -> &'static str {
    if status == SolveStatus::RoundingFloor {
        " (the target is below what double precision can certify for this problem: ask a larger ε)"
    } else {
        ""
    }
}
