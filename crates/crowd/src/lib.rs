//! Crowds as disks that never overlap (Maury–Venel, `seeds/000` §5), on the moreau core.
//!
//! A [`Scene`] (TOML) declares the walkable area, exits, groups, time and solver settings.
//! [`Simulation`] places the [`People`] (the one owner of every person's data) and steps them
//! with the catching-up scheme: the desired velocity ([`DesiredVelocity`], from geodesic
//! distances) and the feasible set ([`CrowdContacts`]: rows from the [`ContactSource`]s, pairs
//! of people through a [`BroadPhase`], people and walls through the [`Walls`] index) are
//! borrowed from the people at every step. Scheduled events (groups released at a time,
//! [`Inflow`] sources bringing people in) act between steps. [`Simulation::advance_to`] is the
//! one step loop; [`SimState`] is its state as a value. Only what the scene declares is built.

mod bands;
mod broad;
mod contacts;
mod error;
mod events;
mod exits;
mod field;
mod geometry;
mod hall;
mod moving;
mod people;
mod scene;
mod sim;
mod spawn;
mod state;
mod walls;
mod wkt;

pub use broad::{
    BroadPhase, BroadPhaseKind, BruteForce, CellGrid, TreeBroadPhase, VerletList,
    choose_broad_phase,
};
pub use contacts::{
    ContactKind, ContactQuery, ContactSource, ContactSources, CrowdContacts, PersonPairs,
    PersonWalls,
};
pub use error::{CrowdError, Infeasibility};
pub use events::{EntryRecord, Inflow, InflowState, SourceTally};
pub use field::{DesiredVelocity, DistanceField, ExitGoal, FieldError};
pub use geometry::{Polygon, Segment};
pub use hall::{Crush, Hall};
pub use moving::{Drive, MovingBodies, PersonMovingWalls};
pub use people::{ExitRecord, People, PeopleView, Place};
pub use scene::{
    BroadPhaseChoice, DesiredVelocityKind, ExitAction, Keyframe, Model, MovingBody, Output, Scene,
    SolverKind, SolverSettings, Time, ToleranceWarning, limits,
};
pub use sim::{ContactForce, Frame, Observer, ObserverError, Simulation};
pub use state::SimState;
pub use walls::Walls;
