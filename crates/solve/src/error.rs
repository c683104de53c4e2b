//! The one error type of the solver crate. How a solve *ended* is a status, not an error.

/// Errors that prevent a solve from starting or finishing.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// Inputs of inconsistent sizes.
    #[error("{what}: expected length {expected}, got {got}")]
    DimensionMismatch {
        /// Which input.
        what: &'static str,
        /// The length the problem needs.
        expected: usize,
        /// The length given.
        got: usize,
    },
    /// A non-finite value in the problem data.
    #[error("non-finite {what} at index {index}: {value}")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// Where.
        index: usize,
        /// The value.
        value: f64,
    },
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
    /// The sparse factorization could not be set up (out of memory, index overflow).
    #[error("sparse factorization: {0}")]
    Factorization(String),
    /// The reference interior-point solver refused the problem.
    #[error("clarabel: {0}")]
    Clarabel(String),
}

/// The largest an iteration, pass, solve or update budget may be set to: `power_iterations =
/// 1e15` was taken and ran inside one solve until killed, deaf to SIGTERM (which a run checks
/// between steps). A million is far beyond any default (APGD's 20,000 iterations the largest).
pub const MAX_BUDGET: usize = 1_000_000;

/// Refuses each `(field, budget)` above [`MAX_BUDGET`] (the settings' own lower bounds are
/// checked beside it).
pub(crate) fn check_budgets(budgets: &[(&'static str, usize)]) -> Result<(), SolveError> {
    match budgets.iter().find(|&&(_, b)| b > MAX_BUDGET) {
        Some(&(field, b)) => Err(SolveError::InvalidSetting {
            field,
            value: b.to_string(),
            reason: "must be at most 10⁶ (MAX_BUDGET)",
        }),
        None => Ok(()),
    }
}
