//! The HDF5 run file of moreau: one file per run, written as the run goes.
//!
//! The layout (DESIGN §4) is the Pedestrian Dynamics Data Archive's, so that PedPy opens it
//! unchanged, plus dense arrays for numpy work and everything needed to reproduce the run:
//!
//! | path | what |
//! |---|---|
//! | `/trajectory` | compound rows `id` (int64), `frame` (int64), `x`, `y` (float64); attribute `fps`: PedPy reads a row's time as `frame / fps`, so a frame off that grid (the horizon's, where no output time reaches it or where an output time within 1 % of a step of it was merged into it) is in `/frames` only |
//! | `/frames/time`, `/frames/count` | time and number of people present, per output frame |
//! | `/frames/positions` | float64 `[frames, people, 2]`, indexed by person id, NaN when absent (before a person entered, after they left) |
//! | `/people/id`, `/people/radius` | everyone in the run, by id: the people at the start, then those who entered (from inflow sources), appended with the frame after they entered |
//! | `/people/entry_time` | time each person entered: 0 for those at the start, the step's end for those from sources (written with `/people/radius`; absent before 2026-11-28, NaN for the people of such a file a run resumed) |
//! | `/people/group` | int64: each person's group, the scene's `[[groups]]` by index, then one per `[[sources]]` (the number of groups plus the source's index); written with `/people/radius` (absent in files written before it was added, the evening of 2026-11-28; −1 for the people of such a file a run resumed) |
//! | `/people/exit_time` | time each person passed an exit, NaN if never (written when the run ends) |
//! | `/exits` | compound rows `id`, `exit` (int64, the exit's index in the scene's `[[exits]]`), `t`, appended as people pass exits (complete up to the last frame); attribute `names`, the exits' names in that order |
//! | `/steps` | one compound row per step: time, `μ`, certified `ε` and its target, violation, iterations, constraints, status, solver, stage timings (s) |
//! | `/walls` | float64 `[segments, 4]`: the wall segments `x0, y0, x1, y1` at the start |
//! | `/contacts` | only with `[output] contacts = true`: compound rows `frame`, `kind` (0 person–person, 1 person–wall, 2 person–moving wall), `a`, `b` (person ids; for a wall, its row in `/walls`; for a moving wall, its column in `/frames/moving_walls`), `lambda` (float64, m/s): the contacts with `λ > 10⁻⁶ m/s` of the step that ended at each frame, those of people an exit removed at its end included (absent from that frame: NaN position and pressure; their partners' pressure counts the row); attribute `units` |
//! | `/frames/pressure` | only with contacts: float64 `[frames, people]`, each person's `Σ λ` over its contacts (m/s), NaN when absent |
//! | `/frames/moving_walls` | only with moving bodies: float64 `[frames, segments, 4]`, each moving segment `x0, y0, x1, y1` where it is at the frame |
//! | `/moving/name`, `/moving/body` | only with moving bodies: the bodies' names (strings), and each segment's body (int64, its row in `/moving/name`) |
//!
//! | `/state/a`, `/state/b` | uint8: the run's state (moreau-crowd's `SimState`, its compact binary form) at the last output frame, written in turn into the two slots; the group's attributes `slot` (1: a, 2: b, 0: none yet), `people`, `frames`, `steps`, `exits`, `trajectory_rows`, `contact_rows` say which slot is whole and where the datasets stood: `moreau run --resume` continues from it |
//!
//! Format `moreau-run/4` added `/exits`' `exit` column and `names` attribute; files of
//! earlier formats read with exit −1 and no names. `/steps` rows written before 2026-11-21
//! (format `moreau-run/1`) have no `time_solve_analyse` or `time_solve_factorize`: they read as
//! NaN (not measured). Any other member a table's rows lack is an error naming it (HDF5 itself
//! would read it as 0 and say nothing).
//!
//! People who enter during the run (format `moreau-run/3`) extend the per-person datasets:
//! `/people/id` and `/people/radius` grow by a row each, and the people axis of
//! `/frames/positions` and `/frames/pressure` by a column, NaN in the frames before. Ids stay
//! `0..people` in order, so every per-person dataset keeps being indexed by id, the files of
//! earlier formats (`moreau-run/1`, `/2`: everyone from the start, fixed-size datasets) read
//! the same way, and `/trajectory` is unchanged: a person's rows simply start at a later
//! frame (what PedPy reads).
//!
//! Root attributes: `wkt_geometry` (the walkable area, WKT), `format`, `moreau_version`,
//! `scene` (the whole scene, TOML), `scene_name`, `seed`, `solver` (the settings in force),
//! `command`, `status` (`running`, then `complete`, `interrupted` or `failed: …`) and
//! `summary` (JSON).
//!
//! Crash safety: rows are buffered between output frames and every frame is written and
//! flushed in one go (a frame whose writing fails, as on a full disk, is taken back from every
//! dataset), so a run killed at any point leaves a file that reads back up to its last flushed
//! frame. The file is written under the temporary name [`partial_path`] (`.NAME.partial`
//! beside it) and moved to its name when the run ends: a killed run leaves its frames there
//! (`status` still `running`) and never touches an older file of the same name. One writer a
//! path ([`lock_path`]); files are opened without HDF5's file locking, so a run in progress
//! can be read.

mod background;
mod error;
mod layout;
mod reader;
mod writer;

pub use background::{BackgroundWriter, RunSink};
pub use error::IoError;
pub use layout::{ContactRow, ExitRow, FORMAT, FORMATS_READ, RunHeader, StepRow, TrajectoryRow};
pub use reader::RunFile;
pub use writer::{
    FailPoint, Overwrite, Resumed, RunWriter, check_output, lock_path, partial_path, same_file,
};
