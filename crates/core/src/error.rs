//! The one error type of the core crate.

/// Errors raised while describing or evaluating a problem.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CoreError {
    /// A vector had the wrong length for the problem.
    #[error("{what}: expected length {expected}, got {got}")]
    DimensionMismatch {
        /// Which quantity had the wrong length.
        what: &'static str,
        /// The length the problem needs.
        expected: usize,
        /// The length that was given.
        got: usize,
    },
    /// A parameter was out of its domain (NaN, negative where positive is needed, ...).
    #[error("invalid {field}: {value} ({reason})")]
    InvalidParameter {
        /// The parameter's name.
        field: &'static str,
        /// The offending value, printed.
        value: String,
        /// Why it is rejected.
        reason: &'static str,
    },
}
