//! The problem format, the solution buffers, the report and the solver trait.

use moreau_core::{ConstraintRows, SolveStatus};

use crate::error::SolveError;

/// `min ½|v − w|²  s.t.  s = b + J v ≥ 0`, with dual
/// `min_{λ≥0} ½ λᵀ(J Jᵀ)λ + λᵀ(b + J w)` and `v = w + Jᵀλ`.
#[derive(Debug, Clone, Copy)]
pub struct ProjectionProblem<'a> {
    /// The unconstrained velocity `w`.
    pub w: &'a [f64],
    /// The rows of `J` (their values `g` are not used: `b` carries them).
    pub jacobian: &'a ConstraintRows,
    /// The offsets `b` (for the scheme, `g_i / μ`).
    pub b: &'a [f64],
}

impl ProjectionProblem<'_> {
    /// Number of unknowns.
    pub fn dim(&self) -> usize {
        self.w.len()
    }

    /// Number of constraints.
    pub fn rows(&self) -> usize {
        self.b.len()
    }

    /// Checks sizes and finiteness; every solver calls it first.
    pub fn validate(&self) -> Result<(), SolveError> {
        if self.jacobian.dim() != self.w.len() {
            return Err(SolveError::DimensionMismatch {
                what: "jacobian columns",
                expected: self.w.len(),
                got: self.jacobian.dim(),
            });
        }
        if self.jacobian.len() != self.b.len() {
            return Err(SolveError::DimensionMismatch {
                what: "b",
                expected: self.jacobian.len(),
                got: self.b.len(),
            });
        }
        // The Jacobian's coefficients too (index: into `ConstraintRows::coefficients`): a row
        // of [NaN, 1] was certified as a perfect answer, the step ending inside the obstacle.
        let j = self.jacobian.coefficients();
        for (what, v) in [("w", self.w), ("b", self.b), ("jacobian coefficient", j)] {
            if let Some((index, &value)) = v.iter().enumerate().find(|(_, x)| !x.is_finite()) {
                return Err(SolveError::NonFinite { what, index, value });
            }
        }
        Ok(())
    }
}

/// What a solve must reach: a duality gap and a violation of `b + J v ≥ 0`, both in the
/// units of the velocity-form problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Largest accepted duality gap `½|v − w|² − ½|v* − w|²` bound.
    pub gap: f64,
    /// Largest accepted `max_i (−s_i)⁺`.
    pub violation: f64,
}

impl Target {
    /// Refuses a NaN or negative gap or violation (an infinite one asks nothing of it): a NaN
    /// target was never met, and a solve ran its whole budget before saying so.
    pub fn validate(&self) -> Result<(), SolveError> {
        for (field, value) in [
            ("target gap", self.gap),
            ("target violation", self.violation),
        ] {
            if !(value >= 0.0) {
                return Err(SolveError::InvalidSetting {
                    field,
                    value: moreau_core::Num(value).to_string(),
                    reason: "must be ≥ 0 (or infinite)",
                });
            }
        }
        Ok(())
    }
}

/// Caller-owned buffers for the answer; reused across solves.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ProjectionSolution {
    /// The velocity `v`.
    pub v: Vec<f64>,
    /// The multipliers `λ ≥ 0` (contact forces), one per row.
    pub lambda: Vec<f64>,
}

impl ProjectionSolution {
    /// Sizes the buffers for `problem`, keeping `lambda` when its length already matches
    /// (a warm start set by the caller).
    pub fn resize_for(&mut self, problem: &ProjectionProblem<'_>) {
        self.v.resize(problem.dim(), 0.0);
        if self.lambda.len() != problem.rows() {
            self.lambda.clear();
            self.lambda.resize(problem.rows(), 0.0);
        }
    }
}

/// How a solve ended, what it proved, and which solver answered.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolveReport {
    /// The solver whose answer this is (for a chain or an automatic choice, the one that
    /// answered, not the one first asked).
    pub solver: &'static str,
    /// How the solve ended.
    pub status: SolveStatus,
    /// The certified duality gap of the returned pair (velocity units squared).
    pub gap: f64,
    /// The largest violation `max_i (−s_i)⁺` of the returned `v`.
    pub violation: f64,
    /// Iterations spent.
    pub iterations: usize,
    /// Numeric factorizations spent (the Newton-type solvers' linear systems).
    pub factorizations: usize,
    /// Rows with `λ_i > 0`.
    pub active: usize,
    /// Seconds in orderings and symbolic analyses (sparse factorizations only).
    pub time_analyse: f64,
    /// Seconds in numeric factorizations and triangular solves.
    pub time_factorize: f64,
}

impl SolveReport {
    /// Adds the work of `earlier` (an attempt on the same problem before this one: a chain's
    /// first solver, auto's first choice): its iterations, factorizations and stage times.
    pub fn add_work(&mut self, earlier: &SolveReport) {
        self.iterations += earlier.iterations;
        self.factorizations += earlier.factorizations;
        self.time_analyse += earlier.time_analyse;
        self.time_factorize += earlier.time_factorize;
    }
}

/// A solver of [`ProjectionProblem`]s.
///
/// `solution.lambda`, when it has one entry per row on entry, is the warm start.
pub trait ProjectionSolver: std::fmt::Debug + Send {
    /// A short name for reports (what the solver is, not who answered a given solve: that is
    /// [`SolveReport::solver`]).
    fn name(&self) -> &'static str;
    /// Solves `problem` to `target`; the report's status says whether the target was met.
    fn solve(
        &mut self,
        problem: &ProjectionProblem<'_>,
        target: Target,
        solution: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError>;

    /// What the solver carries from one solve to the next that changes its answers (not
    /// scratch: e.g. `auto`'s choices), as numbers: part of the state of a run, so that a
    /// run restored with [`set_memory`](Self::set_memory) goes on bit for bit. Empty for a
    /// solver whose answers depend only on the problem and the warm start.
    fn memory(&self) -> Vec<f64> {
        Vec::new()
    }

    /// Takes back what [`memory`](Self::memory) gave (from a solver of the same kind); an
    /// empty or foreign memory leaves the solver as new.
    fn set_memory(&mut self, memory: &[f64]) {
        let _ = memory;
    }
}

impl<S: ProjectionSolver + ?Sized> ProjectionSolver for Box<S> {
    fn name(&self) -> &'static str {
        (**self).name()
    }
    fn solve(
        &mut self,
        problem: &ProjectionProblem<'_>,
        target: Target,
        solution: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        (**self).solve(problem, target, solution)
    }
    fn memory(&self) -> Vec<f64> {
        (**self).memory()
    }
    fn set_memory(&mut self, memory: &[f64]) {
        (**self).set_memory(memory)
    }
}
