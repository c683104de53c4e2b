//! A solver with a fallback: the second answers when the first misses its target.

use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};

/// Asks `primary`; when its answer is not certified to the target, asks `fallback` from the
/// same warm start. The report is the answering solver's, with the iterations and the
/// factorization times of both added up.
#[derive(Debug)]
pub struct WithFallback {
    primary: Box<dyn ProjectionSolver>,
    fallback: Box<dyn ProjectionSolver>,
    warm: Vec<f64>,
}

impl WithFallback {
    /// `primary`, then `fallback` when it misses.
    pub fn new(primary: Box<dyn ProjectionSolver>, fallback: Box<dyn ProjectionSolver>) -> Self {
        Self {
            primary,
            fallback,
            warm: Vec::new(),
        }
    }
}

impl ProjectionSolver for WithFallback {
    fn name(&self) -> &'static str {
        self.primary.name()
    }

    fn solve(
        &mut self,
        problem: &ProjectionProblem<'_>,
        target: Target,
        solution: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        self.warm.clear();
        self.warm.extend_from_slice(&solution.lambda);
        let first = self.primary.solve(problem, target, solution)?;
        if first.status.is_converged() {
            return Ok(first);
        }
        solution.lambda.clear();
        solution.lambda.extend_from_slice(&self.warm);
        let mut rep = self.fallback.solve(problem, target, solution)?;
        rep.add_work(&first);
        Ok(rep)
    }

    /// The primary's (the fallbacks keep none).
    fn memory(&self) -> Vec<f64> {
        self.primary.memory()
    }

    fn set_memory(&mut self, memory: &[f64]) {
        self.primary.set_memory(memory);
    }
}
