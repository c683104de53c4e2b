//! Projection solvers for the velocity-form QP of the catching-up scheme.
//!
//! One problem format ([`ProjectionProblem`]: `min ½|v − w|² s.t. b + J v ≥ 0`), one trait
//! ([`ProjectionSolver`]), and every answer certified by the same [`certify`]: the duality gap
//! of the returned pair `(v, λ)` and the largest violation of `b + J v ≥ 0`. Solvers never
//! report an accuracy they have not proved.
//!
//! Which solver a run uses is a [`SolverKind`] (the names scene files use), and
//! [`SolverKind::build`] is the one factory: the solver, its fallback chain and the rule of
//! `auto`. A new solver is one file and one line in the factory below.

mod apgd;
mod augmented;
mod auto;
mod blocked;
mod certificate;
mod chain;
mod clarabel_ref;
mod components;
mod dissection;
mod error;
mod frontal;
mod gauss_seidel;
mod interior;
mod newton;
mod normal;
mod problem;
mod products;
mod reorder;
mod supernodal;
mod workers;

pub use apgd::{Apgd, ApgdSettings, ApgdSettingsBuilder};
pub use auto::{AutoSettings, AutoSolver, Reach, ScreenReport};
pub use certificate::{Certificate, certify};
pub use chain::WithFallback;
pub use clarabel_ref::{ClarabelReference, ClarabelSettings, infeasibility_certificate};
pub use error::{MAX_BUDGET, SolveError};
pub use gauss_seidel::{GaussSeidel, GaussSeidelSettings, GaussSeidelSettingsBuilder, RowOrder};
pub use interior::{InteriorPoint, InteriorPointSettings, InteriorPointSettingsBuilder};
pub use newton::{Newton, NewtonSettings, NewtonSettingsBuilder};
pub use normal::FactorizationCounts;
pub use problem::{ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target};

use moreau_core::Parallelism;
use serde::{Deserialize, Serialize};

/// The settings of each of our solvers, as a scene gives them (`[solver.interior]`, …; each
/// absent: its defaults), for [`SolverKind::build_with`]: a kind uses its own, and `auto`
/// its own with the interior point's and Gauss–Seidel's (but for what `auto` chooses itself:
/// [`AutoSolver::with_solvers`]). Threads are not among them: they come with the build. In
/// TOML, the tables `[interior]`, `[newton]`, `[gauss_seidel]`, `[apgd]`, `[auto]` (each
/// absent: its defaults).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolverTuning {
    /// Our interior point's (`interior`, and inside `auto`).
    pub interior: InteriorPointSettings,
    /// The semismooth Newton method's (`newton`).
    pub newton: NewtonSettings,
    /// Projected Gauss–Seidel's (`gauss-seidel`, and inside `auto`).
    pub gauss_seidel: GaussSeidelSettings,
    /// APGD's (`apgd`, and the fallback of large problems).
    pub apgd: ApgdSettings,
    /// `auto`'s own.
    pub auto: AutoSettings,
}

impl SolverTuning {
    /// Checks every solver's settings: the error names the solver (as scene files do:
    /// `interior`, `newton`, `gauss_seidel`, `apgd`, `auto`) and the field.
    pub fn validate(&self) -> Result<(), (&'static str, SolveError)> {
        self.interior.validate().map_err(|e| ("interior", e))?;
        self.newton.validate().map_err(|e| ("newton", e))?;
        self.gauss_seidel
            .validate()
            .map_err(|e| ("gauss_seidel", e))?;
        self.apgd.validate().map_err(|e| ("apgd", e))?;
        self.auto.validate().map_err(|e| ("auto", e))
    }
}

/// Which projection solver; the serde names are the ones scene files use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum SolverKind {
    /// Accelerated projected gradient ([`Apgd`]), with our interior point, then Clarabel, as
    /// fallbacks.
    Apgd,
    /// Clarabel's interior point alone (the reference).
    Clarabel,
    /// Our interior point ([`InteriorPoint`]: sparse Cholesky normal equations, symbolic
    /// analysis reused while the contact pattern holds), with the large-problem fallback.
    Interior,
    /// Our proximal augmented-Lagrangian semismooth Newton ([`Newton`]: warm-started from
    /// the previous step's multipliers, the same normal equations as the interior point),
    /// with our interior point, then the large-problem fallback, as fallbacks.
    Newton,
    /// Projected Gauss–Seidel on the dual ([`GaussSeidel`]: one row at a time, the velocity
    /// kept alongside, warm-started from the previous step's multipliers), with our interior
    /// point, then the large-problem fallback, as fallbacks. `gauss_seidel`, the spelling of
    /// its settings table (`[solver.gauss_seidel]`), is taken too.
    #[serde(alias = "gauss_seidel")]
    GaussSeidel,
    /// Chosen for each part of each projection ([`AutoSolver`]): the projection split into
    /// its connected components, Gauss–Seidel on those it has been finishing within its
    /// budget, our interior point on the rest, with the interior point's fallback. Each
    /// report names the solver that answered. The default.
    #[default]
    Auto,
}

impl std::str::FromStr for SolverKind {
    type Err = String;

    /// The names scene files use (`apgd`, `clarabel`, `interior`, `newton`, `gauss-seidel`, `auto`).
    fn from_str(s: &str) -> Result<Self, String> {
        use serde::de::IntoDeserializer;
        Self::deserialize(s.into_deserializer()).map_err(|e: serde::de::value::Error| e.to_string())
    }
}

impl SolverKind {
    /// Every kind, in the order of the documentation.
    pub const ALL: [SolverKind; 6] = [
        SolverKind::Apgd,
        SolverKind::Clarabel,
        SolverKind::Interior,
        SolverKind::Newton,
        SolverKind::GaussSeidel,
        SolverKind::Auto,
    ];

    /// The largest problem (unknowns) whose factorizing solvers get Clarabel as fallback;
    /// APGD above: Clarabel's factorization took 253 MB at 100,000 people, 200,000 unknowns
    /// (benches/README.md), the largest size at which it was measured.
    pub const CLARABEL_FALLBACK_MAX_UNKNOWNS: usize = 200_000;

    /// The smallest `ε/μ²` (twice a velocity-space duality gap, (m/s)²) this kind's
    /// certificates reach on large crowds, where that is above what adaptive steps ask by
    /// default (`moreau_integrate::EpsPolicy::ADAPTIVE_FLOOR`, 2·10⁻⁷); `None` for the others.
    /// Clarabel's stop at 4–7·10⁻⁷ on 10,000 people (`data/scenes/dense-10k.toml`,
    /// `tol = 0.03`, past t = 2 s): with the default floor the step controller halved its
    /// steps to `μ_min` and the run failed. Ours certify far below the default.
    pub fn certified_floor(self) -> Option<f64> {
        match self {
            SolverKind::Clarabel => Some(2e-6),
            _ => None,
        }
    }

    /// The name scene files use.
    pub fn as_str(self) -> &'static str {
        match self {
            SolverKind::Apgd => "apgd",
            SolverKind::Clarabel => "clarabel",
            SolverKind::Interior => "interior",
            SolverKind::Newton => "newton",
            SolverKind::GaussSeidel => "gauss-seidel",
            SolverKind::Auto => "auto",
        }
    }

    /// The solver of this kind, with its fallback, for problems of about `unknowns` unknowns,
    /// with every solver's default settings.
    pub fn build(
        self,
        parallelism: Parallelism,
        unknowns: usize,
    ) -> Result<Box<dyn ProjectionSolver>, SolveError> {
        self.build_with(parallelism, unknowns, &SolverTuning::default())
    }

    /// The solver of this kind, with its fallback, for problems of about `unknowns` unknowns,
    /// each with its settings in `tuning` (and `parallelism`'s threads).
    pub fn build_with(
        self,
        parallelism: Parallelism,
        unknowns: usize,
        tuning: &SolverTuning,
    ) -> Result<Box<dyn ProjectionSolver>, SolveError> {
        let apgd = || SolverKind::Apgd.build_alone_with(parallelism, tuning);
        let clarabel = || -> Box<dyn ProjectionSolver> {
            Box::new(ClarabelReference::new(ClarabelSettings::default()))
        };
        let large = unknowns > Self::CLARABEL_FALLBACK_MAX_UNKNOWNS;
        let last = || if large { apgd() } else { Ok(clarabel()) };
        // A first-order or Newton solver that misses its target hands the projection to our
        // interior point before the last fallback: on a crush Gauss–Seidel runs out of passes
        // and Clarabel stops above the target (benches/README.md, session 22), where our
        // interior point certifies. Without the warm polish and the kept iterate it keeps no
        // state from solve to solve (fallbacks keep no memory: a restored run stays bit for
        // bit).
        let through_interior = |last: Box<dyn ProjectionSolver>| -> Result<_, SolveError> {
            let interior = InteriorPoint::new(InteriorPointSettings {
                parallelism,
                polish_penalty: 0.0,
                warm_iterate: 0.0,
                ..tuning.interior
            })?;
            Ok(Box::new(WithFallback::new(Box::new(interior), last)) as Box<dyn ProjectionSolver>)
        };
        let (primary, fallback): (Box<dyn ProjectionSolver>, _) = match self {
            SolverKind::Clarabel => return Ok(clarabel()),
            SolverKind::Apgd => (apgd()?, through_interior(clarabel())?),
            SolverKind::Newton | SolverKind::GaussSeidel => (
                self.build_alone_with(parallelism, tuning)?,
                through_interior(last()?)?,
            ),
            SolverKind::Interior | SolverKind::Auto => {
                (self.build_alone_with(parallelism, tuning)?, last()?)
            }
        };
        Ok(Box::new(WithFallback::new(primary, fallback)))
    }

    /// The solver of this kind alone, without the fallback [`build`](Self::build) adds (for
    /// measuring one solver: its answer may miss the target, and its report says so).
    pub fn build_alone(
        self,
        parallelism: Parallelism,
    ) -> Result<Box<dyn ProjectionSolver>, SolveError> {
        self.build_alone_with(parallelism, &SolverTuning::default())
    }

    /// [`build_alone`](Self::build_alone) with each solver's settings in `tuning`.
    pub fn build_alone_with(
        self,
        parallelism: Parallelism,
        tuning: &SolverTuning,
    ) -> Result<Box<dyn ProjectionSolver>, SolveError> {
        Ok(match self {
            SolverKind::Clarabel => Box::new(ClarabelReference::new(ClarabelSettings::default())),
            SolverKind::Apgd => Box::new(Apgd::new(ApgdSettings {
                parallelism,
                ..tuning.apgd
            })?),
            SolverKind::Interior => Box::new(InteriorPoint::new(InteriorPointSettings {
                parallelism,
                ..tuning.interior
            })?),
            SolverKind::Newton => Box::new(Newton::new(NewtonSettings {
                parallelism,
                ..tuning.newton
            })?),
            SolverKind::GaussSeidel => Box::new(GaussSeidel::new(GaussSeidelSettings {
                parallelism,
                ..tuning.gauss_seidel
            })?),
            SolverKind::Auto => Box::new(AutoSolver::with_solvers(
                AutoSettings {
                    parallelism,
                    ..tuning.auto
                },
                tuning.interior,
                tuning.gauss_seidel,
            )?),
        })
    }

    /// What [`build`](Self::build) makes, in words (for run files and `--help`).
    pub fn describe(self, unknowns: usize) -> &'static str {
        let large = unknowns > Self::CLARABEL_FALLBACK_MAX_UNKNOWNS;
        match (self, large) {
            (SolverKind::Clarabel, _) => "Clarabel alone",
            (SolverKind::Apgd, _) => "APGD, then our interior point, then Clarabel as fallbacks",
            (SolverKind::Interior, false) => "our interior point with Clarabel as fallback",
            (SolverKind::Interior, true) => "our interior point with APGD as fallback",
            (SolverKind::Newton, false) => {
                "our semismooth Newton, then our interior point, then Clarabel as fallbacks"
            }
            (SolverKind::Newton, true) => {
                "our semismooth Newton, then our interior point, then APGD as fallbacks"
            }
            (SolverKind::GaussSeidel, false) => {
                "our projected Gauss–Seidel, then our interior point, then Clarabel as fallbacks"
            }
            (SolverKind::GaussSeidel, true) => {
                "our projected Gauss–Seidel, then our interior point, then APGD as fallbacks"
            }
            (SolverKind::Auto, false) => {
                "per connected component: Gauss–Seidel where it finishes within its budget, our interior point elsewhere, Clarabel as fallback"
            }
            (SolverKind::Auto, true) => {
                "per connected component: Gauss–Seidel where it finishes within its budget, our interior point elsewhere, APGD as fallback"
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solver_kind_names_are_the_scene_file_names() {
        #[derive(Serialize)]
        struct S {
            kind: SolverKind,
        }
        for kind in SolverKind::ALL {
            let text = toml::to_string(&S { kind }).unwrap();
            assert_eq!(text.trim(), format!("kind = \"{}\"", kind.as_str()));
            assert_eq!(kind.as_str().parse::<SolverKind>(), Ok(kind));
            let solver = kind.build(Parallelism::SEQUENTIAL, 10).unwrap();
            assert_eq!(
                solver.name(),
                if kind == SolverKind::Clarabel {
                    "clarabel"
                } else {
                    kind.as_str()
                }
            );
            let alone = kind.build_alone(Parallelism::SEQUENTIAL).unwrap();
            assert_eq!(alone.name(), solver.name());
        }
        // Accepted: `[solver.gauss_seidel]` is how its settings table is spelt (it was refused).
        assert_eq!(
            "gauss_seidel".parse::<SolverKind>(),
            Ok(SolverKind::GaussSeidel)
        );
        assert!(
            "simplex"
                .parse::<SolverKind>()
                .unwrap_err()
                .contains("simplex")
        );
    }
}
