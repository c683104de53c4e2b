//! What one step of the scheme reports: time, step, certified accuracy, work and stage timings.

/// How a projection solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SolveStatus {
    /// The certificate meets the requested gap and violation.
    #[default]
    Converged,
    /// The iteration budget ran out before the certificate met its target.
    MaxIterations,
    /// The constraints admit no feasible point (for example a zero row with `b < 0`).
    Infeasible,
    /// The solver reported a numerical failure.
    NumericalError,
}

impl SolveStatus {
    /// True when the result may be accepted.
    pub fn is_converged(self) -> bool {
        self == SolveStatus::Converged
    }

    /// A short lower-case name for tables and files.
    pub fn as_str(self) -> &'static str {
        match self {
            SolveStatus::Converged => "converged",
            SolveStatus::MaxIterations => "max_iterations",
            SolveStatus::Infeasible => "infeasible",
            SolveStatus::NumericalError => "numerical_error",
        }
    }
}

/// Wall-clock seconds spent in each named stage of a step.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimings {
    /// Evaluating the field `F` (and the selection or prox of `ψ`).
    pub predict: f64,
    /// Finding and assembling the constraints near the state.
    pub assemble: f64,
    /// The projection solve (all of it, including the two sub-stages below).
    pub solve: f64,
    /// Within `solve`: orderings and symbolic analyses of sparse factorizations.
    pub solve_analyse: f64,
    /// Within `solve`: numeric factorizations and triangular solves.
    pub solve_factorize: f64,
    /// The check after the step that nothing outside the assembled set was crossed.
    pub verify: f64,
    /// The whole step.
    pub total: f64,
}

/// The record of one accepted step of the catching-up scheme.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepReport {
    /// Index of the step (0 for the first).
    pub step: usize,
    /// Time at the end of the step, `t_{k+1}`.
    pub t: f64,
    /// Step size `μ_k`.
    pub mu: f64,
    /// The projection accuracy asked for, `ε_k` (squared length).
    pub eps_target: f64,
    /// The certified `ε`: the new state is an `ε`-projection of the prediction (squared length).
    pub eps: f64,
    /// The largest violation of an assembled linearized constraint (a length, in units of `g`).
    pub violation: f64,
    /// Iterations of the projection solver.
    pub iterations: usize,
    /// Constraints assembled into the projection problem.
    pub assembled: usize,
    /// Constraints with a positive multiplier.
    pub active: usize,
    /// How often the step was redone because something outside the assembled set was crossed.
    pub redone: usize,
    /// How the projection solve ended.
    pub status: SolveStatus,
    /// Which solver produced the accepted answer.
    pub solver: &'static str,
    /// Seconds per stage.
    pub timings: StageTimings,
}
