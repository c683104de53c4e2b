//! The correction step: an ε-projection of the prediction onto the feasible set.

use std::time::Instant;

use moreau_core::{
    ConstraintKey, ConstraintRows, ConstraintSet, ConvexSet, Num, SolveStatus, StepReport,
};
use moreau_solve::{ProjectionProblem, ProjectionSolution, ProjectionSolver, Target};

use crate::error::IntegrateError;

/// Computes `q_next ∈ proj^ε(q + μ w)` onto the feasible set at `t_next` and records in the
/// report what it proved (ε, violation) and what it cost.
///
/// A correction is a pipeline: it holds its solver, scratch memory and warm start, never the
/// set it projects onto. The set ([`Correction::Set`]) is passed in at every step by whoever
/// owns the state (a crowd's people, an example's half-space), so that it can borrow that
/// state instead of copying it.
pub trait Correction {
    /// What the correction projects onto.
    type Set<'a>: ?Sized;

    /// Computes `q_next`. `report.step`, `report.t` and `report.mu` are already set.
    fn correct(
        &mut self,
        set: &mut Self::Set<'_>,
        q: &[f64],
        w: &[f64],
        eps_target: f64,
        q_next: &mut [f64],
        report: &mut StepReport,
    ) -> Result<(), IntegrateError>;
}

/// No constraint: `q_next = q + μ w`.
#[derive(Debug, Clone, Copy, Default)]
pub struct Unconstrained;

impl Correction for Unconstrained {
    type Set<'a> = ();

    fn correct(
        &mut self,
        _set: &mut (),
        q: &[f64],
        w: &[f64],
        _eps: f64,
        q_next: &mut [f64],
        report: &mut StepReport,
    ) -> Result<(), IntegrateError> {
        for i in 0..q.len() {
            q_next[i] = q[i] + report.mu * w[i];
        }
        report.solver = "none";
        Ok(())
    }
}

/// The exact projection (ε = 0) onto a convex set `S` passed in at every step.
#[derive(Debug, Clone)]
pub struct ExactProjection<S> {
    y: Vec<f64>,
    set: std::marker::PhantomData<fn(&S)>,
}

impl<S: ConvexSet> Default for ExactProjection<S> {
    fn default() -> Self {
        Self::new()
    }
}

impl<S: ConvexSet> ExactProjection<S> {
    /// Projects onto sets of type `S`.
    pub fn new() -> Self {
        Self {
            y: Vec::new(),
            set: std::marker::PhantomData,
        }
    }
}

impl<S: ConvexSet> Correction for ExactProjection<S> {
    type Set<'a> = S;

    fn correct(
        &mut self,
        set: &mut S,
        q: &[f64],
        w: &[f64],
        _eps: f64,
        q_next: &mut [f64],
        report: &mut StepReport,
    ) -> Result<(), IntegrateError> {
        let start = Instant::now();
        self.y.clear();
        self.y
            .extend(q.iter().zip(w).map(|(q, w)| q + report.mu * w));
        set.project(&self.y, q_next);
        report.solver = "exact";
        report.timings.solve = start.elapsed().as_secs_f64();
        Ok(())
    }
}

/// Settings of [`LinearizedProjection`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearizedSettings {
    /// Largest accepted violation of a linearized constraint, as a length (units of `g`).
    pub max_violation: f64,
    /// How often a step may be redone with a doubled margin when a constraint outside the
    /// assembled set was crossed.
    pub max_redo: usize,
}

impl Default for LinearizedSettings {
    fn default() -> Self {
        Self {
            max_violation: 1e-9,
            max_redo: 8,
        }
    }
}

/// The projection onto the linearized inner set
/// `Q~ = {z : g_i(t_{k+1}, q_k) + ∇g_i·(z − q_k) ≥ 0, g_i ≤ ρ}` solved in velocity form.
///
/// The constraint set is passed in at every step. Multipliers are warm-started from the
/// previous step by constraint key. A solve that misses its target fails the step (a solver
/// with a fallback, `moreau_solve::WithFallback`, has tried its fallback first).
#[derive(Debug)]
pub struct LinearizedProjection<S> {
    solver: S,
    settings: LinearizedSettings,
    rows: ConstraintRows,
    b: Vec<f64>,
    solution: ProjectionSolution,
    previous: Vec<(ConstraintKey, f64)>,
}

impl<S: ProjectionSolver> LinearizedProjection<S> {
    /// Projects onto linearized constraint sets with `solver`.
    pub fn new(solver: S, settings: LinearizedSettings) -> Result<Self, IntegrateError> {
        if !(settings.max_violation > 0.0) {
            return Err(IntegrateError::InvalidSetting {
                field: "max_violation",
                value: Num(settings.max_violation).to_string(),
                reason: "must be > 0",
            });
        }
        Ok(Self {
            solver,
            settings,
            rows: ConstraintRows::new(0),
            b: Vec::new(),
            solution: ProjectionSolution::default(),
            previous: Vec::new(),
        })
    }

    /// The solver.
    pub fn solver(&self) -> &S {
        &self.solver
    }

    /// The solver, to restore its memory ([`ProjectionSolver::set_memory`]).
    pub fn solver_mut(&mut self) -> &mut S {
        &mut self.solver
    }

    /// The rows assembled in the last step.
    pub fn rows(&self) -> &ConstraintRows {
        &self.rows
    }

    /// The last step's projection problem, `min ½|v − w|²` s.t. `b + J v ≥ 0` with its rows
    /// and offsets `b = g/μ`, for the prediction `w` it was solved with (to re-solve it with
    /// another solver).
    pub fn last_problem<'a>(&'a self, w: &'a [f64]) -> ProjectionProblem<'a> {
        ProjectionProblem {
            w,
            jacobian: &self.rows,
            b: &self.b,
        }
    }

    /// The multipliers of the last step, one per assembled row.
    pub fn multipliers(&self) -> &[f64] {
        &self.solution.lambda
    }

    /// The multipliers the next step starts from, by constraint key (sorted by key): the
    /// last accepted step's. Part of the state of a run.
    pub fn warm_start(&self) -> &[(ConstraintKey, f64)] {
        &self.previous
    }

    /// Replaces the warm start (restoring a saved run); sorted by key here.
    pub fn set_warm_start(&mut self, multipliers: &[(ConstraintKey, f64)]) {
        self.previous.clear();
        self.previous.extend_from_slice(multipliers);
        self.previous.sort_unstable_by_key(|e| e.0);
    }

    fn start_from_previous(&mut self) {
        let (keys, previous) = (self.rows.keys(), &self.previous);
        let lam = &mut self.solution.lambda;
        lam.clear();
        if keys.is_sorted() {
            // Both in key order (a crowd's rows are): one merge, memory read in order.
            let mut j = 0;
            lam.extend(keys.iter().map(|&k| {
                while j < previous.len() && previous[j].0 < k {
                    j += 1;
                }
                match previous.get(j) {
                    Some(&(key, l)) if key == k => l,
                    _ => 0.0,
                }
            }));
        } else {
            lam.extend(
                keys.iter()
                    .map(|k| match previous.binary_search_by_key(k, |e| e.0) {
                        Ok(j) => previous[j].1,
                        Err(_) => 0.0,
                    }),
            );
        }
    }

    fn remember(&mut self) {
        self.previous.clear();
        self.previous.extend(
            self.rows
                .keys()
                .iter()
                .copied()
                .zip(self.solution.lambda.iter().copied()),
        );
        self.previous.sort_unstable_by_key(|e| e.0);
    }
}

impl<S: ProjectionSolver> Correction for LinearizedProjection<S> {
    type Set<'a> = dyn ConstraintSet + 'a;

    fn correct(
        &mut self,
        constraints: &mut (dyn ConstraintSet + '_),
        q: &[f64],
        w: &[f64],
        eps_target: f64,
        q_next: &mut [f64],
        report: &mut StepReport,
    ) -> Result<(), IntegrateError> {
        let (mu, t_next) = (report.mu, report.t);
        // ε = 2μ²·gap and violation (length) = μ·max(−s)⁺.
        let target = Target {
            gap: eps_target / (2.0 * mu * mu),
            violation: self.settings.max_violation / mu,
        };
        let mut margin = constraints.margin(q, w, mu);
        // NaN or a negative margin assembles no row and checks nothing after the step (a
        // half-line crossed to −2 was a certified run): the set's estimate is wrong.
        if !(margin >= 0.0) {
            return Err(IntegrateError::InvalidSetting {
                field: "margin",
                value: Num(margin).to_string(),
                reason: "ConstraintSet::margin must be ≥ 0 (or +∞: assemble every row)",
            });
        }
        loop {
            let start = Instant::now();
            self.rows.clear(q.len());
            constraints.assemble(t_next, q, margin, &mut self.rows);
            self.b.clear();
            self.b.extend(self.rows.values().iter().map(|g| g / mu));
            self.start_from_previous();
            let solve_start = Instant::now();
            report.timings.assemble += (solve_start - start).as_secs_f64();

            let problem = ProjectionProblem {
                w,
                jacobian: &self.rows,
                b: &self.b,
            };
            let rep = self.solver.solve(&problem, target, &mut self.solution)?;
            report.solver = rep.solver;
            report.timings.solve += solve_start.elapsed().as_secs_f64();
            report.iterations += rep.iterations;
            report.factorizations += rep.factorizations;
            report.timings.solve_analyse += rep.time_analyse;
            report.timings.solve_factorize += rep.time_factorize;
            report.status = rep.status;
            report.eps = 2.0 * mu * mu * rep.gap;
            report.violation = mu * rep.violation;
            report.assembled = self.rows.len();
            report.active = rep.active;
            if rep.status != SolveStatus::Converged {
                return Err(IntegrateError::NotCertified {
                    step: report.step,
                    t: t_next,
                    status: rep.status,
                    eps: report.eps,
                    eps_target,
                    violation: report.violation,
                    max_violation: self.settings.max_violation,
                });
            }
            for i in 0..q.len() {
                q_next[i] = q[i] + mu * self.solution.v[i];
            }
            let verify_start = Instant::now();
            let tol = self.settings.max_violation;
            let crossed = if margin.is_finite()
                && !constraints.left_out_stay_feasible(t_next, q, q_next, margin, tol)
            {
                constraints.crossed_outside(t_next, q_next, &self.rows, tol)
                    + constraints.passed_through(t_next, q, q_next, &self.rows)
            } else {
                0
            };
            report.timings.verify += verify_start.elapsed().as_secs_f64();
            if crossed == 0 {
                self.remember();
                return Ok(());
            }
            if report.redone == self.settings.max_redo {
                return Err(IntegrateError::CrossedOutside {
                    step: report.step,
                    t: t_next,
                    crossed,
                    redone: report.redone,
                });
            }
            report.redone += 1;
            // Wider: twice the margin, and at least as far as any coordinate moved in the
            // step (a margin of 0, at rest, stayed 0 through every redo).
            let moved = q
                .iter()
                .zip(q_next.iter())
                .map(|(a, b)| (b - a).abs())
                .fold(0.0, f64::max);
            margin = (2.0 * margin).max(2.0 * moved);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use moreau_solve::InteriorPoint;

    /// The warm start finds each row's multiplier by key whether the rows come in key order
    /// (the merge) or not (the search), and starts new rows at zero.
    #[test]
    fn the_warm_start_reads_each_rows_multiplier_by_key_in_either_order() {
        let solver = InteriorPoint::new(Default::default()).unwrap();
        let settings = LinearizedSettings {
            max_violation: 1e-6,
            max_redo: 1,
        };
        let mut correction = LinearizedProjection::new(solver, settings).unwrap();
        correction.set_warm_start(&[(2, 0.5), (5, 1.5), (9, 2.5), (11, 3.5)]);
        for keys in [[1u64, 2, 5, 10, 11], [11, 1, 5, 10, 2]] {
            correction.rows = ConstraintRows::new(1);
            for &k in &keys {
                correction.rows.push(k, 0.0, [(0, 1.0)]);
            }
            correction.start_from_previous();
            let expected: Vec<f64> = keys
                .iter()
                .map(|k| match k {
                    2 => 0.5,
                    5 => 1.5,
                    11 => 3.5,
                    _ => 0.0,
                })
                .collect();
            assert_eq!(correction.solution.lambda, expected, "{keys:?}");
        }
    }
}
