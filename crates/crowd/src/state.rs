//! `SimState`: everything the next step of a run depends on, as one serializable value
//! (saving, resuming, rolling back and pickling are the same operation).

use moreau_core::ConstraintKey;
use moreau_integrate::SteppingState;
use serde::{Deserialize, Serialize};

use crate::error::CrowdError;
use crate::events::InflowState;
use crate::people::{ExitRecord, People};
use crate::scene::Scene;

/// The state of a [`Simulation`](crate::Simulation) between two steps. Restored into a
/// simulation built from the same scene, the run goes on bit for bit as if never stopped.
///
/// What is *not* in it, because it is rebuilt from the scene: the geometry, the distance
/// fields, the solver's scratch and symbolic analyses (the same pattern gives the same
/// ordering). The random generator of the start is spent; each inflow source's own random
/// stream is saved with the source ([`InflowState`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimState {
    /// [`SimState::FORMAT`] when written.
    pub format: u32,
    /// [`SimState::hash_scene`] of the scene it was saved from.
    pub scene_hash: u64,
    /// Time (s).
    pub time: f64,
    /// Steps taken.
    pub steps: usize,
    /// Frames reported so far (the next is due at `frames × output_interval`).
    pub frames: usize,
    /// The people present.
    pub people: People,
    /// Everyone who passed an exit, in order.
    pub exits: Vec<ExitRecord>,
    /// Which exits are open.
    pub exits_open: Vec<bool>,
    /// Each inflow source's state (people placed, the radius of the first waiting, its random
    /// stream), in the scene's order.
    pub inflow: Vec<InflowState>,
    /// The factor on every desired speed.
    pub speed_factor: f64,
    /// How each moving body is driven (`None`: by its keyframes in time).
    pub moving: Vec<Option<crate::moving::Drive>>,
    /// Where the moving bodies were (keyframe parameters) when the distance fields were last
    /// solved around them (`None`: the scene does not ask for it).
    pub fields_built: Option<Vec<f64>>,
    /// How many `model.field_update` intervals had begun at the last check.
    pub fields_due: f64,
    /// The step controller's memory (adaptive steps).
    pub stepping: SteppingState,
    /// The last step's multipliers by contact key: the next step's warm start.
    pub multipliers: Vec<(ConstraintKey, f64)>,
    /// What the projection solver carries from one solve to the next
    /// ([`ProjectionSolver::memory`](moreau_solve::ProjectionSolver::memory): `auto`'s
    /// choices, the interior point's kept iterate and polish history).
    pub solver_memory: Vec<f64>,
}

impl SimState {
    /// The layout version; bumped whenever a field changes meaning (5: `solver_memory` holds
    /// the interior points' memory too; 4: `solver_memory`; 3: `inflow`, `moving`,
    /// `fields_built`; 2 was written by builds with only some of them).
    pub const FORMAT: u32 = 5;

    /// A 64-bit FNV-1a hash of the scene's TOML, its thread count left out (as if the
    /// default): a state restores only into a simulation of the scene it was saved from, on
    /// any number of threads (results do not depend on it; a killed run resumes on a smaller
    /// machine).
    pub fn hash_scene(scene: &Scene) -> u64 {
        let mut any_threads = scene.clone();
        any_threads.solver.threads = crate::scene::default_threads();
        Self::hash_scene_with_threads(&any_threads)
    }

    /// The hash of the whole TOML, thread count included, which states saved before
    /// 2026-11-28 hold (they still restore, at their own thread count).
    pub(crate) fn hash_scene_with_threads(scene: &Scene) -> u64 {
        scene
            .to_toml()
            .bytes()
            .fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
                (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
            })
    }

    /// The compact binary form (postcard).
    pub fn to_bytes(&self) -> Vec<u8> {
        postcard::to_stdvec(self).expect("a state serializes")
    }

    /// Reads [`to_bytes`](Self::to_bytes)' form.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, CrowdError> {
        postcard::from_bytes(bytes).map_err(|e| {
            CrowdError::invalid("state", format!("{} bytes", bytes.len()), e.to_string())
        })
    }
}
