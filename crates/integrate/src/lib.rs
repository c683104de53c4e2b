//! Time drivers for Moreau's catching-up scheme (`seeds/002` Definition 4.3, `seeds/000` (11)).
//!
//! One step: predict `y = q_k + μ_k w_k` with `w_k` a selection of `F(t_k, q_k) − ∂ψ(q_k)`
//! (or the semi-implicit `y = prox_{μψ}(q_k + μ F)`), then correct `q_{k+1} ∈ proj^{ε_k}(y)` onto
//! the feasible set at `t_{k+1}` through a [`Correction`]. Steps are fixed or a given
//! sequence `μ_k`; `ε_k` follows an [`EpsPolicy`] with `ε_k/μ_k² → 0`. Every accepted step
//! yields a [`StepReport`](moreau_core::StepReport); a step whose certificate misses its
//! target is retried with the fallback solver or rejected with an error, never accepted.

pub mod adaptive;
mod correction;
mod error;
mod scheme;
mod stepping;

pub use adaptive::{
    AdaptiveSettings, AdaptiveStep, ControllerState, ErrorEstimate, StepController,
};
pub use correction::{
    Correction, ExactProjection, LinearizedProjection, LinearizedSettings, Unconstrained,
};
pub use error::IntegrateError;
pub use scheme::{EpsPolicy, Scheme, Selection, StepSequence};
pub use stepping::{MAX_STEPS, SHORTEST_LAST, Stepping, SteppingState, fixed_step};
