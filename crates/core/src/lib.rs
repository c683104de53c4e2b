//! The problem traits of moreau: what a first-order nonsmooth system must tell the scheme.
//!
//! A problem `q' ∈ F(t, q) − ∂ψ(q) − N(Q(t), q)` is given by
//! - a [`Field`] `F(t, q)`,
//! - optionally a separable [`ConvexPart`] `ψ` (its minimal-norm selection and its proximal map),
//! - the feasible set, either a [`ConstraintSet`] that reports constraints `g_i(t, q) ≥ 0`
//!   near a state as sparse rows ([`ConstraintRows`]), or a [`ConvexSet`] with an exact projection.
//!
//! Nothing here knows what the unknowns mean: the same traits carry a 1-D test, a friction
//! box and a crowd.

mod error;
mod helper;
mod num;
mod parallel;
mod report;
mod rows;
mod sets;
mod traits;

pub use error::CoreError;
pub use helper::Helper;
pub use num::Num;
pub use parallel::Parallelism;
pub use report::{RunStats, SolveStatus, StageTimings, StepReport};
pub use rows::{ConstraintKey, ConstraintRows};
pub use sets::{Ball, BoxSet, HalfSpace, HalfSpaces, SeparableAbs};
pub use traits::{ConstraintSet, ConvexPart, ConvexSet, Field, FnField, count_outside};
