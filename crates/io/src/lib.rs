//! The HDF5 run file of moreau: one file per run, written as the run goes.
//!
//! The layout (DESIGN §4) is the Pedestrian Dynamics Data Archive's, so that PedPy opens it
//! unchanged, plus dense arrays for numpy work and everything needed to reproduce the run:
//!
//! | path | what |
//! |---|---|
//! | `/trajectory` | compound rows `id` (int64), `frame` (int64), `x`, `y` (float64); attribute `fps` |
//! | `/frames/time`, `/frames/count` | time and number of people present, per output frame |
//! | `/frames/positions` | float64 `[frames, people, 2]`, indexed by person id, NaN when absent |
//! | `/people/id`, `/people/radius` | everyone at the start, by id |
//! | `/people/exit_time` | time each person passed an exit, NaN if never (written when the run ends) |
//! | `/exits` | compound rows `id`, `t`, appended as people pass exits (complete up to the last frame) |
//! | `/steps` | one compound row per step: time, `μ`, certified `ε` and its target, violation, iterations, constraints, status, solver, stage timings (s) |
//!
//! Root attributes: `wkt_geometry` (the walkable area, WKT), `format`, `moreau_version`,
//! `scene` (the whole scene, TOML), `scene_name`, `seed`, `solver` (the settings in force),
//! `command`, `status` (`running`, then `complete` or `failed: …`) and `summary` (JSON).
//!
//! Crash safety: rows are buffered between output frames and every frame is written and
//! flushed in one go, so a run killed at any point leaves a file that reads back up to its
//! last flushed frame (`status` then still says `running`).

mod error;
mod layout;
mod reader;
mod writer;

pub use error::IoError;
pub use layout::{ExitRow, FORMAT, RunHeader, StepRow, TrajectoryRow};
pub use reader::RunFile;
pub use writer::{Overwrite, RunWriter, check_output};
