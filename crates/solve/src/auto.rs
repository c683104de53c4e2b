//! The automatic choice of solver for each projection: APGD while contacts are sparse, the
//! interior point once they are dense, decided from the warm start.

use moreau_core::Parallelism;

use crate::apgd::{Apgd, ApgdSettings};
use crate::error::SolveError;
use crate::interior::{InteriorPoint, InteriorPointSettings};
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};

/// Settings of [`AutoSolver`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutoSettings {
    /// Below this fraction of rows active in the warm start (the previous step's answer),
    /// APGD is tried first. Measured on evacuation halls (benches/README.md): APGD is 1.4×
    /// faster with 18 % of the rows active, the interior point 4× faster with 58 %.
    pub sparse_contacts: f64,
    /// APGD's iteration budget before the interior point takes over (it needed ~75 at 18 %).
    pub apgd_iterations: usize,
    /// Threads for both.
    pub parallelism: Parallelism,
}

impl Default for AutoSettings {
    fn default() -> Self {
        Self {
            sparse_contacts: 0.3,
            apgd_iterations: 300,
            parallelism: Parallelism::SEQUENTIAL,
        }
    }
}

/// Picks APGD or the interior point for each projection from the warm start's share of
/// active rows (a multiplier above 10⁻⁶ of the largest); a solve APGD does not finish within
/// its budget goes on with the interior point. Each [`SolveReport::solver`] names the solver
/// whose answer it is.
#[derive(Debug)]
pub struct AutoSolver {
    settings: AutoSettings,
    apgd: Apgd,
    interior: InteriorPoint,
}

impl AutoSolver {
    /// Both solvers, with validated settings.
    pub fn new(settings: AutoSettings) -> Result<Self, SolveError> {
        if !(settings.sparse_contacts >= 0.0 && settings.sparse_contacts <= 1.0) {
            return Err(SolveError::InvalidSetting {
                field: "sparse_contacts",
                value: settings.sparse_contacts.to_string(),
                reason: "must be in [0, 1]",
            });
        }
        let apgd = Apgd::new(
            ApgdSettings::builder()
                .max_iterations(settings.apgd_iterations)
                .parallelism(settings.parallelism)
                .build()?,
        )?;
        let interior = InteriorPoint::new(
            InteriorPointSettings::builder()
                .parallelism(settings.parallelism)
                .build()?,
        )?;
        Ok(Self {
            settings,
            apgd,
            interior,
        })
    }

    /// The share of rows whose warm-start multiplier is active.
    fn warm_active_share(p: &ProjectionProblem<'_>, sol: &ProjectionSolution) -> f64 {
        let m = p.rows();
        if m == 0 || sol.lambda.len() != m {
            return 0.0;
        }
        let largest = sol.lambda.iter().fold(0.0f64, |a, &l| a.max(l));
        if !(largest > 0.0) {
            return 0.0;
        }
        let active = sol.lambda.iter().filter(|&&l| l > 1e-6 * largest).count();
        active as f64 / m as f64
    }
}

impl ProjectionSolver for AutoSolver {
    fn name(&self) -> &'static str {
        "auto"
    }

    fn solve(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        let mut spent = SolveReport::default();
        if Self::warm_active_share(p, sol) < self.settings.sparse_contacts {
            spent = self.apgd.solve(p, target, sol)?;
            if spent.status.is_converged() {
                return Ok(spent);
            }
        }
        let mut rep = self.interior.solve(p, target, sol)?;
        rep.add_work(&spent);
        Ok(rep)
    }
}
