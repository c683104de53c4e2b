//! A solver with a fallback: the second answers when the first misses its target.

use moreau_core::SolveStatus;

use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};

/// Asks `primary`; when its answer is not certified to the target, asks `fallback` from the
/// same warm start. The report is the answering solver's, with the iterations and the
/// factorization times of both added up. When the primary found the target below the
/// certificate's rounding floor ([`SolveStatus::RoundingFloor`]) the fallback is not asked:
/// every answer is certified by the same certificate, which no solver takes below that floor.
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
        if first.status.is_converged() || first.status == SolveStatus::RoundingFloor {
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

#[cfg(test)]
mod tests {
    use super::*;
    use moreau_core::ConstraintRows;

    /// A solver that answers with a given status and counts its calls.
    #[derive(Debug)]
    struct Scripted(SolveStatus, std::sync::Arc<std::sync::atomic::AtomicUsize>);

    impl ProjectionSolver for Scripted {
        fn name(&self) -> &'static str {
            "scripted"
        }

        fn solve(
            &mut self,
            p: &ProjectionProblem<'_>,
            _: Target,
            sol: &mut ProjectionSolution,
        ) -> Result<SolveReport, SolveError> {
            self.1.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            sol.resize_for(p);
            Ok(SolveReport {
                status: self.0,
                iterations: 1,
                ..SolveReport::default()
            })
        }
    }

    /// The fallback answers what the primary misses, except a target below the rounding
    /// floor, which it could not certify either.
    #[test]
    fn the_fallback_is_asked_unless_the_target_is_below_the_rounding_floor() {
        let rows = ConstraintRows::new(1);
        let p = ProjectionProblem {
            w: &[0.0],
            jacobian: &rows,
            b: &[],
        };
        let target = Target {
            gap: 1e-9,
            violation: 1e-9,
        };
        for (first, asked) in [
            (SolveStatus::Converged, 0),
            (SolveStatus::MaxIterations, 1),
            (SolveStatus::NumericalError, 1),
            (SolveStatus::RoundingFloor, 0),
        ] {
            let calls = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
            let mut chain = WithFallback::new(
                Box::new(Scripted(
                    first,
                    std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0)),
                )),
                Box::new(Scripted(SolveStatus::Converged, calls.clone())),
            );
            let rep = chain
                .solve(&p, target, &mut ProjectionSolution::default())
                .unwrap();
            assert_eq!(
                calls.load(std::sync::atomic::Ordering::Relaxed),
                asked,
                "{first:?}"
            );
            let want = if asked == 1 {
                SolveStatus::Converged
            } else {
                first
            };
            assert_eq!(rep.status, want);
            assert_eq!(rep.iterations, 1 + asked);
        }
    }
}
