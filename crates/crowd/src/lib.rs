//! Crowds as disks that never overlap (Maury–Venel, `seeds/000` §5), on the moreau core.
//!
//! A [`Scene`] (TOML) declares the walkable area, exits, groups, time and solver settings;
//! [`Simulation`] turns it into a field ([`DesiredVelocity`], from geodesic distances) and a
//! constraint set ([`CrowdConstraints`]: disk–disk and disk–wall rows found by a
//! [`BroadPhase`]) and steps the catching-up scheme. Only what the scene declares is built.

mod broad;
mod constraints;
mod error;
mod field;
mod geometry;
mod hall;
mod scene;
mod sim;

pub use broad::{
    BroadPhase, BroadPhaseKind, BruteForce, CellGrid, TreeBroadPhase, choose_broad_phase,
};
pub use constraints::CrowdConstraints;
pub use error::CrowdError;
pub use field::{DesiredVelocity, DistanceField};
pub use geometry::{Polygon, Segment};
pub use hall::Hall;
pub use scene::{BroadPhaseChoice, ExitAction, Scene, SolverKind, SolverSettings};
pub use sim::{Frame, Simulation};
