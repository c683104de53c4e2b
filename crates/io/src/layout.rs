//! The names and row types of the run file, shared by the writer and the reader.

use hdf5::H5Type;
use hdf5::types::FixedAscii;
use moreau_core::StepReport;

/// The value of the root attribute `format`; bumped when the layout changes (3: people who
/// enter during the run extend the per-person datasets; `/state` marks `people`; 4: `/exits`
/// says which exit, and its attribute `names` names them).
pub const FORMAT: &str = "moreau-run/4";
/// Earlier formats this moreau still reads (their layout is a subset of this one's: their
/// per-person datasets hold everyone from the start; their `/exits` rows name no exit, read
/// as exit −1).
pub const FORMATS_READ: &[&str] = &["moreau-run/1", "moreau-run/2", "moreau-run/3", FORMAT];
/// The formats read whose `/exits` rows are [`ExitRowV3`]s (no exit).
pub(crate) const FORMATS_WITHOUT_EXIT: &[&str] = &["moreau-run/1", "moreau-run/2", "moreau-run/3"];

pub(crate) const TRAJECTORY: &str = "trajectory";
pub(crate) const FRAME_TIME: &str = "frames/time";
pub(crate) const FRAME_COUNT: &str = "frames/count";
pub(crate) const FRAME_POSITIONS: &str = "frames/positions";
pub(crate) const PEOPLE_ID: &str = "people/id";
pub(crate) const PEOPLE_RADIUS: &str = "people/radius";
/// When each person entered the run (s): 0 for those there at the start (files written
/// before 2026-11-28 lack it).
pub(crate) const PEOPLE_ENTRY_TIME: &str = "people/entry_time";
/// Each person's group (int64; files written before the evening of 2026-11-28 lack it).
pub(crate) const PEOPLE_GROUP: &str = "people/group";
pub(crate) const PEOPLE_EXIT_TIME: &str = "people/exit_time";
pub(crate) const EXITS: &str = "exits";
pub(crate) const STEPS: &str = "steps";
pub(crate) const WALLS: &str = "walls";
pub(crate) const CONTACTS: &str = "contacts";
pub(crate) const FRAME_PRESSURE: &str = "frames/pressure";
/// The segments of the moving bodies at every frame: `(frames, segments, 4)`, `[x0, y0, x1, y1]`.
pub(crate) const FRAME_MOVING_WALLS: &str = "frames/moving_walls";
/// The names of the moving bodies.
pub(crate) const MOVING_NAME: &str = "moving/name";
/// The body of each moving segment (its row in `moving/name`).
pub(crate) const MOVING_BODY: &str = "moving/body";
/// The group of the saved run state (two slots written in turn, `a` and `b`).
pub(crate) const STATE: &str = "state";
/// Bytes per chunk of a state slot (64 KiB: a small run's state takes one).
pub(crate) const STATE_BYTES_PER_CHUNK: usize = 1 << 16;

/// Rows per chunk of the appended tables (32 bytes a trajectory row: 256 KiB chunks).
pub(crate) const ROWS_PER_CHUNK: usize = 8192;
/// Rows per chunk of the small appended tables (steps, exits, frame times and counts: 152 bytes
/// a step row, 152 KiB chunks).
pub(crate) const SMALL_ROWS_PER_CHUNK: usize = 1024;
/// People per chunk of `frames/positions` (one frame, 16 bytes a person: 512 KiB chunks).
pub(crate) const PEOPLE_PER_CHUNK: usize = 32768;
/// People per chunk of `frames/positions` at least: the people axis grows when people enter,
/// with chunks of the size chosen at the start (16 KiB; NaN padding deflates to nothing).
pub(crate) const MIN_PEOPLE_PER_CHUNK: usize = 1024;
/// Deflate level: shuffled float64 gain little above this and cost much more time.
pub(crate) const DEFLATE: u8 = 3;

/// One row of `/trajectory` (the Pedestrian Dynamics Data Archive columns).
#[derive(H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct TrajectoryRow {
    /// Person id.
    pub id: i64,
    /// Output frame, from 0.
    pub frame: i64,
    /// Position (m).
    pub x: f64,
    /// Position (m).
    pub y: f64,
}

/// One row of `/exits`.
#[derive(H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct ExitRow {
    /// Person id.
    pub id: i64,
    /// The exit: its index in the scene's `[[exits]]` and in the attribute `names` (−1 in
    /// files of formats before `moreau-run/4`, which did not record it).
    pub exit: i64,
    /// Time the person passed the exit (s).
    pub t: f64,
}

/// One row of `/exits` in formats before `moreau-run/4`.
#[derive(H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub(crate) struct ExitRowV3 {
    pub id: i64,
    pub t: f64,
}

/// One row of `/contacts`: a contact that pushed (`λ > 10⁻⁶ m/s`) in the step that ended at an
/// output frame.
#[derive(H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct ContactRow {
    /// Output frame, from 0.
    pub frame: i64,
    /// 0: person–person; 1: person–wall; 2: person–moving wall.
    pub kind: i64,
    /// Person id (the smaller of a pair).
    pub a: i64,
    /// The other person's id, the wall's row in `/walls`, or the moving segment's column in
    /// `/frames/moving_walls`.
    pub b: i64,
    /// The multiplier `λ` (m/s): the speed the contact removed along its normal.
    pub lambda: f64,
}

impl ContactRow {
    /// `kind` of a contact between two people.
    pub const PERSON_PERSON: i64 = 0;
    /// `kind` of a contact between a person and a wall.
    pub const PERSON_WALL: i64 = 1;
    /// `kind` of a contact between a person and a segment of a moving body.
    pub const PERSON_MOVING_WALL: i64 = 2;
}

/// One row of `/steps`: a [`StepReport`] as stored.
#[derive(H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct StepRow {
    /// Step index from 0.
    pub step: i64,
    /// Time at the end of the step (s).
    pub t: f64,
    /// Step size `μ` (s).
    pub mu: f64,
    /// The `ε_k` asked for (m²).
    pub eps_target: f64,
    /// The certified `ε` of the accepted projection (m²).
    pub eps: f64,
    /// The worst violation of the linearized constraints (m).
    pub violation: f64,
    /// Solver iterations, over all attempts.
    pub iterations: i64,
    /// Constraint rows assembled.
    pub assembled: i64,
    /// Rows active at the answer.
    pub active: i64,
    /// Times the step was redone with a wider margin.
    pub redone: i64,
    /// How the solve ended (`converged`, ...).
    pub status: FixedAscii<16>,
    /// The solver whose answer was accepted.
    pub solver: FixedAscii<16>,
    /// Stage wall times (s).
    pub time_predict: f64,
    /// Broad phase and assembly (s).
    pub time_assemble: f64,
    /// Projection solve (s).
    pub time_solve: f64,
    /// Certificate and post-step check (s).
    pub time_verify: f64,
    /// Within `time_solve`: orderings and symbolic analyses (s).
    pub time_solve_analyse: f64,
    /// Within `time_solve`: numeric factorizations and triangular solves (s).
    pub time_solve_factorize: f64,
    /// The whole step (s).
    pub time_total: f64,
}

/// One row of `/steps` in files written before 2026-11-21 (format `moreau-run/1`), which did
/// not time the solve's analysis and factorization: [`StepRow`] without
/// `time_solve_analyse` and `time_solve_factorize`.
#[derive(H5Type, Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub(crate) struct StepRowUntimedSolve {
    pub step: i64,
    pub t: f64,
    pub mu: f64,
    pub eps_target: f64,
    pub eps: f64,
    pub violation: f64,
    pub iterations: i64,
    pub assembled: i64,
    pub active: i64,
    pub redone: i64,
    pub status: FixedAscii<16>,
    pub solver: FixedAscii<16>,
    pub time_predict: f64,
    pub time_assemble: f64,
    pub time_solve: f64,
    pub time_verify: f64,
    pub time_total: f64,
}

impl From<StepRowUntimedSolve> for StepRow {
    /// The two timings the file does not have are NaN: not measured, not 0 s.
    fn from(r: StepRowUntimedSolve) -> Self {
        Self {
            step: r.step,
            t: r.t,
            mu: r.mu,
            eps_target: r.eps_target,
            eps: r.eps,
            violation: r.violation,
            iterations: r.iterations,
            assembled: r.assembled,
            active: r.active,
            redone: r.redone,
            status: r.status,
            solver: r.solver,
            time_predict: r.time_predict,
            time_assemble: r.time_assemble,
            time_solve: r.time_solve,
            time_verify: r.time_verify,
            time_solve_analyse: f64::NAN,
            time_solve_factorize: f64::NAN,
            time_total: r.time_total,
        }
    }
}

/// `s` in the run file's 16 bytes: its ASCII characters, and a name too long for them cut
/// to 15 and marked `~` (not cut without a word: a reader would take the cut name for a
/// whole one).
fn ascii16(s: &str) -> FixedAscii<16> {
    let mut s: String = s.chars().filter(char::is_ascii).collect();
    if s.len() > 16 {
        s.truncate(15);
        s.push('~');
    }
    FixedAscii::from_ascii(&s).expect("ASCII, at most 16 bytes")
}

impl From<&StepReport> for StepRow {
    fn from(r: &StepReport) -> Self {
        Self {
            step: r.step as i64,
            t: r.t,
            mu: r.mu,
            eps_target: r.eps_target,
            eps: r.eps,
            violation: r.violation,
            iterations: r.iterations as i64,
            assembled: r.assembled as i64,
            active: r.active as i64,
            redone: r.redone as i64,
            status: ascii16(r.status.as_str()),
            solver: ascii16(r.solver),
            time_predict: r.timings.predict,
            time_assemble: r.timings.assemble,
            time_solve: r.timings.solve,
            time_verify: r.timings.verify,
            time_solve_analyse: r.timings.solve_analyse,
            time_solve_factorize: r.timings.solve_factorize,
            time_total: r.timings.total,
        }
    }
}

/// What a run file says about its run, written when it is created.
#[derive(Debug, Clone, PartialEq)]
pub struct RunHeader {
    /// `moreau_version`: the version of the program that wrote the file.
    pub version: String,
    /// `scene_name`.
    pub scene_name: String,
    /// `scene`: the whole scene (TOML); running it again reproduces the file.
    pub scene: String,
    /// `seed`: the seed of the random placement.
    pub seed: u64,
    /// `solver`: the solver settings in force (text).
    pub solver: String,
    /// `command`: the command line that made the file.
    pub command: String,
    /// `wkt_geometry`: the walkable area (WKT).
    pub wkt_geometry: String,
    /// `trajectory.fps`: output frames per second.
    pub fps: f64,
    /// `people/radius`: the radius of person `id`, for every id `0..n` (written: the people at
    /// the start; read back: everyone the file holds, those who entered later too).
    pub radii: Vec<f64>,
    /// `people/group`: the group of person `id` (the scene's `[[groups]]` by index, then one
    /// per `[[sources]]`), as `radii` (empty: not stored, −1 for everyone written; −1 for a
    /// person: not stored, in files written before the evening of 2026-11-28).
    pub groups: Vec<i64>,
    /// `walls`: the wall segments `[x0, y0, x1, y1]` at the start (contacts name them by row).
    pub walls: Vec<[f64; 4]>,
    /// Whether the file records contact forces (`/contacts`, `/frames/pressure`).
    pub contacts: bool,
    /// `moving/name`: the names of the moving bodies (none: no `/moving`, no
    /// `/frames/moving_walls`).
    pub moving_names: Vec<String>,
    /// `moving/body`: for each moving segment (a column of `/frames/moving_walls`), its body.
    pub moving_body: Vec<u32>,
    /// `exits.names`: the exits' names, in the scene's order (an `/exits` row's `exit` indexes
    /// them; none in files of formats before `moreau-run/4`).
    pub exit_names: Vec<String>,
}

#[cfg(test)]
mod tests {
    use super::ascii16;

    /// A name longer than the run file's 16 bytes is marked as cut, not cut silently (a
    /// solver name of 18 bytes was once written as 16 that read as a whole name).
    #[test]
    fn a_name_too_long_for_its_field_is_marked_as_cut() {
        assert_eq!(ascii16("gs+interior").as_str(), "gs+interior");
        assert_eq!(ascii16("sixteen-bytes-ok").as_str(), "sixteen-bytes-ok");
        assert_eq!(ascii16("gs+interior+newton").as_str(), "gs+interior+new~");
        assert_eq!(ascii16("ε-gap").as_str(), "-gap");
    }
}
