//! The FMU state of FMI (`fmi2GetFMUstate`, `fmi3GetFMUState` …) as a value: a [`Snapshot`]
//! of an instance and its serialized form, which carries a format version and the scene's
//! hash in a fixed header so that a state of another scene or build is refused by name.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::FmuError;
use crate::model::ModelState;
use crate::runtime::State;

/// What an FMU state holds: the instance's FMI state, what the master set that is not a
/// parameter (start time, inputs), the fixed speed factor (checked on restore, not restored:
/// it is a parameter), and the model's state ([`ModelState`]: the simulation's `SimState`
/// and the outputs kept between communication points).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    /// The FMI state the instance was in.
    pub state: State,
    /// The start time the master set up.
    pub start_time: f64,
    /// The input `speed_factor`.
    pub speed_factor: f64,
    /// The input `door_open`.
    pub door_open: bool,
    /// The inputs `exit_open.<name>` of the exits after the first, as the master set them.
    pub exits_open: BTreeMap<usize, bool>,
    /// The moving bodies' position inputs the master set, by body (the others are at their
    /// start values); where the bodies are, and the drive they follow, is in the model's
    /// `SimState`.
    pub moving: BTreeMap<usize, f64>,
    /// The parameter `desired_speed_factor` (a restore checks it).
    pub desired_speed_factor: f64,
    /// The model.
    pub model: ModelState,
}

/// The first bytes of every serialized state.
const MAGIC: [u8; 8] = *b"moreauFS";
/// Magic, format (u32, little endian), scene hash (u64, little endian).
const HEADER: usize = 8 + 4 + 8;

impl Snapshot {
    /// The layout version of the serialized form (of the header and of what follows it);
    /// bumped whenever a field changes meaning (4: the exits' inputs; 3: the simulation's
    /// state format 5, whose solver memory holds the interior points'; 2: the moving bodies'
    /// inputs).
    pub const FORMAT: u32 = 4;

    /// The hash of the scene the state was taken from.
    pub fn scene_hash(&self) -> u64 {
        self.model.sim.scene_hash
    }

    /// The serialized form: the header (magic, [`FORMAT`](Self::FORMAT), scene hash), then
    /// the snapshot in postcard.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER + 64 * self.model.sim.people.len() + 256);
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&Self::FORMAT.to_le_bytes());
        out.extend_from_slice(&self.scene_hash().to_le_bytes());
        postcard::to_extend(self, out).expect("a snapshot serializes into a Vec")
    }

    /// Reads [`to_bytes`](Self::to_bytes)' form: refused (naming what is wrong) when it is
    /// not a state of this FMU, of another format, or damaged.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, FmuError> {
        let bad = |why: String| Err(FmuError::Setting(format!("serializedState: {why}")));
        if bytes.len() < HEADER || bytes[..8] != MAGIC {
            return bad(format!(
                "{} bytes that do not start as a state of this FMU does",
                bytes.len()
            ));
        }
        let format = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
        if format != Self::FORMAT {
            return bad(format!(
                "format {format}; this FMU reads format {}",
                Self::FORMAT
            ));
        }
        let hash = u64::from_le_bytes(bytes[12..HEADER].try_into().expect("8 bytes"));
        let (snapshot, rest): (Self, _) =
            postcard::take_from_bytes(&bytes[HEADER..]).map_err(|e| {
                FmuError::Setting(format!(
                    "serializedState: {} bytes, damaged ({e})",
                    bytes.len()
                ))
            })?;
        if !rest.is_empty() {
            return bad(format!(
                "{} bytes after the state's end (size must be what SerializedFMUStateSize said)",
                rest.len()
            ));
        }
        if snapshot.scene_hash() != hash {
            return bad(format!(
                "the header's scene hash {hash:016x} is not the state's {:016x}: damaged",
                snapshot.scene_hash()
            ));
        }
        Ok(snapshot)
    }
}
