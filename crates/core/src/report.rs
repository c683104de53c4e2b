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
    /// The target is below what double precision certifies for this problem: the progress
    /// stalled with the certified gap within a factor 100 of the certificate's rounding floor
    /// (`moreau_solve::Certificate::floor`: the unit roundoff times the magnitudes the gap
    /// sums, about `10⁻¹⁶ Σ λ_i |J_i| |v|` for the slacks). No answer certifies below the
    /// floor; a larger target does. A stall further above the floor is a `NumericalError`.
    RoundingFloor,
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
            SolveStatus::RoundingFloor => "rounding_floor",
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
    /// Before the step, rebuilding what the field `F` reads after the geometry changed (a
    /// crowd's distance fields when walls moved); 0 for most steps.
    pub field: f64,
    /// The whole step (including `field`).
    pub total: f64,
}

impl StageTimings {
    /// Adds `other`, stage by stage.
    pub fn add(&mut self, other: &StageTimings) {
        self.predict += other.predict;
        self.assemble += other.assemble;
        self.solve += other.solve;
        self.solve_analyse += other.solve_analyse;
        self.solve_factorize += other.solve_factorize;
        self.verify += other.verify;
        self.field += other.field;
        self.total += other.total;
    }
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
    /// Numeric factorizations of the projection solver (Newton-type solvers).
    pub factorizations: usize,
    /// Constraints assembled into the projection problem.
    pub assembled: usize,
    /// Constraints with a positive multiplier.
    pub active: usize,
    /// How often the step was redone because something outside the assembled set was crossed.
    pub redone: usize,
    /// Trial steps rejected before this one was accepted (adaptive steps).
    pub rejected: usize,
    /// The adaptive controller's estimate of this step's local error (the state's unit);
    /// `None` for fixed steps. Above the tolerance only for a step at the smallest size.
    pub local_error: Option<f64>,
    /// How the projection solve ended.
    pub status: SolveStatus,
    /// Which solver produced the accepted answer.
    pub solver: &'static str,
    /// Seconds per stage.
    pub timings: StageTimings,
}

/// The step reports of a run, added up.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunStats {
    /// Accepted steps.
    pub steps: usize,
    /// Trial steps rejected.
    pub rejected: usize,
    /// Steps redone with a wider margin.
    pub redone: usize,
    /// Solver iterations.
    pub iterations: usize,
    /// Numeric factorizations.
    pub factorizations: usize,
    /// The largest certified ε (squared length).
    pub max_eps: f64,
    /// The largest violation (length).
    pub max_violation: f64,
    /// Seconds per stage, summed over the steps.
    pub timings: StageTimings,
    /// How many steps each solver answered, in the order they first did.
    pub solvers: Vec<(&'static str, usize)>,
}

impl RunStats {
    /// Adds one step.
    pub fn add(&mut self, r: &StepReport) {
        self.steps += 1;
        self.rejected += r.rejected;
        self.redone += r.redone;
        self.iterations += r.iterations;
        self.factorizations += r.factorizations;
        self.max_eps = self.max_eps.max(r.eps);
        self.max_violation = self.max_violation.max(r.violation);
        self.timings.add(&r.timings);
        match self.solvers.iter_mut().find(|(s, _)| *s == r.solver) {
            Some((_, n)) => *n += 1,
            None => self.solvers.push((r.solver, 1)),
        }
    }

    /// Solver iterations per step.
    pub fn iterations_per_step(&self) -> f64 {
        self.iterations as f64 / self.steps.max(1) as f64
    }

    /// Numeric factorizations per step.
    pub fn factorizations_per_step(&self) -> f64 {
        self.factorizations as f64 / self.steps.max(1) as f64
    }
}
