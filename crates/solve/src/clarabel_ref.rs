//! Clarabel's interior-point method on the same QP: the reference answer and the fallback.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use moreau_core::SolveStatus;

use crate::certificate::certify;
use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};

/// Settings of [`ClarabelReference`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClarabelSettings {
    /// Clarabel's absolute and relative gap and feasibility tolerances.
    pub tolerance: f64,
    /// Clarabel's iteration budget.
    pub max_iterations: u32,
}

impl Default for ClarabelSettings {
    fn default() -> Self {
        Self {
            tolerance: 1e-10,
            max_iterations: 200,
        }
    }
}

impl ClarabelSettings {
    /// Refuses a tolerance that is not a positive finite number and a budget of 0 or above
    /// [`MAX_BUDGET`](crate::MAX_BUDGET) (each was handed to Clarabel as it was).
    pub fn validate(&self) -> Result<(), SolveError> {
        if !(self.tolerance > 0.0 && self.tolerance.is_finite()) {
            return Err(SolveError::InvalidSetting {
                field: "tolerance",
                value: moreau_core::Num(self.tolerance).to_string(),
                reason: "must be a positive finite number",
            });
        }
        if self.max_iterations == 0 {
            return Err(SolveError::InvalidSetting {
                field: "max_iterations",
                value: "0".into(),
                reason: "must be at least 1",
            });
        }
        crate::error::check_budgets(&[("max_iterations", self.max_iterations as usize)])
    }
}

/// Clarabel on `min ½vᵀv − wᵀv  s.t. (−J)v + s = b, s ≥ 0`; its dual `z` is `λ`.
///
/// Its answer is certified by [`certify`] like any other: Clarabel's own status decides
/// nothing but infeasibility.
#[derive(Debug, Clone, Default)]
pub struct ClarabelReference {
    settings: ClarabelSettings,
}

impl ClarabelReference {
    /// A reference solver with `settings`.
    pub fn new(settings: ClarabelSettings) -> Self {
        Self { settings }
    }
}

impl ProjectionSolver for ClarabelReference {
    fn name(&self) -> &'static str {
        "clarabel"
    }

    fn solve(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        self.settings.validate()?;
        p.validate()?;
        target.validate()?;
        let (m, n) = (p.rows(), p.dim());
        sol.resize_for(p);
        if m == 0 {
            sol.v.copy_from_slice(p.w);
            return Ok(SolveReport {
                solver: self.name(),
                status: SolveStatus::Converged,
                ..SolveReport::default()
            });
        }
        let mut solver = clarabel_on(p, self.settings)?;
        solver.solve();
        let out = &solver.solution;
        sol.v.copy_from_slice(&out.x);
        for (l, z) in sol.lambda.iter_mut().zip(&out.z) {
            *l = z.max(0.0);
        }
        let (mut sm, mut sn) = (vec![0.0; m], vec![0.0; n]);
        let cert = certify(p, &sol.v, &sol.lambda, &mut sm, &mut sn);
        let status = match out.status {
            // (Clarabel said so of a feasible crowd of radii 1:100: checked, not taken.)
            SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible
                if checked_farkas(p, &out.z).is_some() =>
            {
                SolveStatus::Infeasible
            }
            _ if cert.gap <= target.gap && cert.violation <= target.violation => {
                SolveStatus::Converged
            }
            SolverStatus::MaxIterations | SolverStatus::MaxTime => SolveStatus::MaxIterations,
            _ => SolveStatus::NumericalError,
        };
        Ok(SolveReport {
            solver: self.name(),
            status,
            gap: cert.gap,
            violation: cert.violation,
            iterations: out.iterations as usize,
            active: cert.active,
            ..SolveReport::default()
        })
    }
}

/// Clarabel set up on `p` (not yet solved): `min ½vᵀv − wᵀv  s.t. (−J)v + s = b, s ≥ 0`.
fn clarabel_on(
    p: &ProjectionProblem<'_>,
    settings: ClarabelSettings,
) -> Result<DefaultSolver, SolveError> {
    let (m, n) = (p.rows(), p.dim());
    // −J in compressed columns.
    let mut count = vec![0usize; n + 1];
    for i in 0..m {
        for &c in p.jacobian.row(i).0 {
            count[c + 1] += 1;
        }
    }
    for c in 0..n {
        count[c + 1] += count[c];
    }
    let nnz = count[n];
    let mut next = count.clone();
    let (mut rowval, mut nzval) = (vec![0usize; nnz], vec![0.0; nnz]);
    for i in 0..m {
        let (cols, coefs) = p.jacobian.row(i);
        for (&c, &a) in cols.iter().zip(coefs) {
            rowval[next[c]] = i;
            nzval[next[c]] = -a;
            next[c] += 1;
        }
    }
    // A column repeated within a row is one coefficient, the sum of its entries (as every
    // other solver reads it): Clarabel took the entries as they were, and failed on `2x ≥ 2`
    // written as `x + x`. A row's entries in a column are consecutive here.
    let (mut start, mut kept) = (vec![0usize; n + 1], 0);
    for c in 0..n {
        let mut k = count[c];
        while k < count[c + 1] {
            let (row, mut value) = (rowval[k], nzval[k]);
            k += 1;
            while k < count[c + 1] && rowval[k] == row {
                value += nzval[k];
                k += 1;
            }
            (rowval[kept], nzval[kept]) = (row, value);
            kept += 1;
        }
        start[c + 1] = kept;
    }
    rowval.truncate(kept);
    nzval.truncate(kept);
    let a = CscMatrix::new(m, n, start, rowval, nzval);
    let identity = CscMatrix::new(n, n, (0..=n).collect(), (0..n).collect(), vec![1.0; n]);
    let q: Vec<f64> = p.w.iter().map(|w| -w).collect();
    let tol = settings.tolerance;
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .max_iter(settings.max_iterations)
        .tol_gap_abs(tol)
        .tol_gap_rel(tol)
        .tol_feas(tol)
        .presolve_enable(false)
        .build()
        .map_err(|e| SolveError::Clarabel(e.to_string()))?;
    let cones = [SupportedConeT::NonnegativeConeT(m)];
    DefaultSolver::new(&identity, &q, &a, p.b, &cones, settings)
        .map_err(|e| SolveError::Clarabel(e.to_string()))
}

/// Why the rows of `p` admit no `v`: a Farkas certificate `y ≥ 0` with `Jᵀy = 0` and
/// `bᵀy < 0` (then `yᵀ(Jv + b) = bᵀy < 0` for every `v`: some row with `y_i > 0` is violated
/// whatever `v` is), scaled to `max y = 1`; `None` when Clarabel finds no such certificate.
/// The certificate is checked here, not taken from Clarabel's status: with `s = max(1, |w|∞,
/// |b|∞)`, it is returned only when `bᵀy < 0` and `n |Jᵀy|∞ s ≤ −bᵀy / 2`, so that no `v` with
/// `|v|∞ ≤ s` meets every row.
pub fn infeasibility_certificate(
    p: &ProjectionProblem<'_>,
) -> Result<Option<Vec<f64>>, SolveError> {
    p.validate()?;
    let m = p.rows();
    if m == 0 {
        return Ok(None);
    }
    let mut solver = clarabel_on(p, ClarabelSettings::default())?;
    solver.solve();
    if !matches!(
        solver.solution.status,
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible
    ) {
        return Ok(None);
    }
    Ok(checked_farkas(p, &solver.solution.z))
}

/// `z` (Clarabel's dual at a report of infeasibility) as a Farkas certificate of `p`, if it
/// is one (see [`infeasibility_certificate`]).
fn checked_farkas(p: &ProjectionProblem<'_>, z: &[f64]) -> Option<Vec<f64>> {
    let n = p.dim();
    let mut y: Vec<f64> = z.iter().map(|z| z.max(0.0)).collect();
    let top = y.iter().copied().fold(0.0, f64::max);
    if !(top > 0.0 && top.is_finite()) {
        return None;
    }
    y.iter_mut().for_each(|v| *v /= top);
    let mut jty = vec![0.0; n];
    p.jacobian.mul_transpose_add(&y, &mut jty);
    let residual = jty.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let by: f64 = p.b.iter().zip(&y).map(|(b, y)| b * y).sum();
    // yᵀ(Jv + b) ≤ n |Jᵀy|∞ |v|∞ + bᵀy < 0 for every |v|∞ ≤ scale.
    let scale = p.w.iter().chain(p.b).fold(1.0f64, |a, v| a.max(v.abs()));
    (by < 0.0 && residual * n as f64 * scale <= -0.5 * by).then_some(y)
}
