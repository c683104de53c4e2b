//! Projection solvers for the velocity-form QP of the catching-up scheme.
//!
//! One problem format ([`ProjectionProblem`]: `min ½|v − w|² s.t. b + J v ≥ 0`), one trait
//! ([`ProjectionSolver`]), and every answer certified by the same [`certify`]: the duality gap
//! of the returned pair `(v, λ)` and the largest violation of `b + J v ≥ 0`. Solvers never
//! report an accuracy they have not proved.

mod apgd;
mod auto;
mod certificate;
mod clarabel_ref;
mod error;
mod interior;
mod problem;
mod products;
mod workers;

pub use apgd::{Apgd, ApgdSettings, ApgdSettingsBuilder};
pub use auto::{AutoSettings, AutoSolver};
pub use certificate::{Certificate, certify};
pub use clarabel_ref::{ClarabelReference, ClarabelSettings};
pub use error::SolveError;
pub use interior::{
    FactorizationCounts, InteriorPoint, InteriorPointSettings, InteriorPointSettingsBuilder,
};
pub use problem::{ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target};
