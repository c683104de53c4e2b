//! A crowd run into its HDF5 run file: the observer ([`Record`]), the header
//! ([`header`]) and the summary ([`Summary`]) that `moreau run` and the Python module both
//! use, so that both write the same file.

use moreau_core::{RunStats, StepReport};
use moreau_crowd::{
    ContactKind, EntryRecord, ExitRecord, Frame, Observer, ObserverError, Simulation,
};
use moreau_io::{ContactRow, RunHeader, RunSink};
use serde::Serialize;

/// The version written into run files (`moreau_version`).
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The solver settings in force, as the run file's `solver` attribute says them.
pub fn solver_text(sim: &Simulation) -> String {
    let settings = toml::to_string(&sim.scene().solver).unwrap_or_default();
    let solver = sim.solver_kind().describe(2 * sim.max_people());
    format!(
        "{settings}# in force: ε_k = eps_kappa · μ³ (or tied to --tol), projection by {solver}, \
         broad phase {:?}, up to 8 redone steps per step\n",
        sim.broad_phase()
    )
}

/// The header of the run file of `sim` (not yet stepped); `command` is what made the file.
pub fn header(sim: &Simulation, command: String) -> RunHeader {
    let frame = sim.frame();
    RunHeader {
        version: VERSION.into(),
        scene_name: sim.scene().name.clone(),
        scene: sim.scene().to_toml(),
        seed: sim.scene().seed,
        solver: solver_text(sim),
        command,
        wkt_geometry: sim.scene().wkt(),
        fps: 1.0 / sim.scene().time.output_interval,
        radii: frame.radii.to_vec(),
        walls: sim
            .walls()
            .segments()
            .iter()
            .map(|w| [w.a[0], w.a[1], w.b[0], w.b[1]])
            .collect(),
        contacts: sim.scene().output.contacts,
        moving_names: sim.moving().names().to_vec(),
        moving_body: sim.moving().segment_bodies().collect(),
        exit_names: sim.scene().exits.iter().map(|e| e.name.clone()).collect(),
    }
}

/// What a run reports at its end (`moreau run --summary-json` and the file's `summary`).
#[derive(Debug, Serialize)]
pub struct Summary {
    /// Where the scene came from.
    pub scene: String,
    /// The run file, if any.
    pub output: Option<String>,
    /// `complete` or `failed: …`.
    pub status: String,
    /// Everyone in the run: the people at the start and those who entered.
    pub people: usize,
    /// People who passed an exit.
    pub passed_exit: usize,
    /// People who did not.
    pub not_yet_out: usize,
    /// Steps taken.
    pub steps: usize,
    /// Frames reported.
    pub frames: usize,
    /// The time reached (s).
    pub simulated_time: f64,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
    /// Wall-clock milliseconds per step.
    pub ms_per_step: f64,
    /// Steps per wall-clock second.
    pub steps_per_second: f64,
    /// Solver iterations per step.
    pub iterations_per_step: f64,
    /// Numeric factorizations per step (Newton-type solvers).
    pub factorizations_per_step: f64,
    /// The largest certified ε (m²).
    pub max_eps: f64,
    /// The largest violation (m).
    pub max_violation: f64,
    /// Steps redone with a wider margin.
    pub steps_redone: usize,
    /// Trial steps rejected (adaptive steps).
    pub steps_rejected: usize,
    /// The adaptive steps' tolerance, if any.
    pub tol: Option<f64>,
    /// The broad phase in use.
    pub broad_phase: String,
    /// How many steps each solver answered.
    pub solvers: Vec<(String, usize)>,
}

impl Summary {
    /// The summary of `sim` after a run that `record` observed, `wall` seconds long.
    pub fn new(
        sim: &Simulation,
        record: &Record<'_>,
        scene: String,
        output: Option<String>,
        status: String,
        wall: f64,
    ) -> Self {
        let (stats, people) = (&record.stats, sim.total_people());
        Summary {
            scene,
            output,
            status,
            people,
            passed_exit: sim.exit_records().len(),
            not_yet_out: people - sim.exit_records().len(),
            steps: stats.steps,
            frames: record.frames,
            simulated_time: sim.time(),
            wall_seconds: wall,
            ms_per_step: 1e3 * wall / stats.steps.max(1) as f64,
            steps_per_second: stats.steps as f64 / wall.max(1e-12),
            iterations_per_step: stats.iterations_per_step(),
            factorizations_per_step: stats.factorizations_per_step(),
            max_eps: stats.max_eps,
            max_violation: stats.max_violation,
            steps_redone: stats.redone,
            steps_rejected: stats.rejected,
            tol: sim.scene().time.tol,
            broad_phase: format!("{:?}", sim.broad_phase()),
            solvers: stats
                .solvers
                .iter()
                .map(|&(s, n)| (s.to_string(), n))
                .collect(),
        }
    }

    /// Pretty JSON (what the file's `summary` attribute holds).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("plain data")
    }
}

/// Steps `sim` to its horizon frame by frame through `record`, saving the run's state into its
/// file (what `moreau run --resume` goes on from) after the frames [`StateCadence`] picks:
/// every frame while the state is at most [`STATE_BYTES_PER_FRAME`]. What `moreau run` and
/// the Python module's `run` both do.
pub fn run_to_horizon(
    sim: &mut Simulation,
    record: &mut Record<'_>,
) -> Result<(), moreau_crowd::CrowdError> {
    let mut cadence = StateCadence::default();
    while let Some(t) = sim.next_frame_time() {
        sim.advance_to(t, record)?;
        if record.writer.is_some() && cadence.frame() {
            let bytes = sim.state().to_bytes();
            cadence.saved(bytes.len());
            record
                .save_state_bytes(bytes)
                .map_err(|e| moreau_crowd::CrowdError::Observer(Box::new(e)))?;
        }
    }
    Ok(())
}

/// The state's bytes a run writes per frame at most, on average: a larger state is saved every
/// `⌈size / this⌉` frames. At a million people the state is 55 MB, and saving it with every
/// frame cost ~10 % of the run (its serialization on the stepping thread, 0.1 s a frame, and
/// its write); a state of up to 8 MB (about 10⁵ people) is still saved with every frame.
pub const STATE_BYTES_PER_FRAME: usize = 8 << 20;

/// After which frames a run saves its state: the first, then each once the frames since the
/// last save carry [`STATE_BYTES_PER_FRAME`] for every byte of the last state saved. A run
/// killed outright goes on from the last state saved, so it redoes at most
/// `⌈size / STATE_BYTES_PER_FRAME⌉ − 1` frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StateCadence {
    since: usize,
    last: Option<usize>,
}

impl StateCadence {
    /// Counts a frame; true when the state is to be saved after it.
    pub fn frame(&mut self) -> bool {
        self.since += 1;
        self.last
            .is_none_or(|size| self.since.saturating_mul(STATE_BYTES_PER_FRAME) >= size)
    }

    /// The state saved after the frame was `size` bytes.
    pub fn saved(&mut self, size: usize) {
        self.since = 0;
        self.last = Some(size);
    }
}

/// Told of every step with the run's totals so far and the people not yet out; an error
/// stops the run (an interrupt, say).
pub type Progress<'a> =
    dyn FnMut(&StepReport, &RunStats, usize) -> Result<(), ObserverError> + Send + 'a;

/// What a run does as it goes: writes steps, exits and frames to the file (when there is
/// one), adds up the steps, and tells `progress`.
pub struct Record<'a> {
    writer: Option<&'a mut dyn RunSink>,
    progress: Option<&'a mut Progress<'a>>,
    /// The steps added up.
    pub stats: RunStats,
    /// Frames seen.
    pub frames: usize,
    /// Exits seen.
    pub exits: usize,
    /// Everyone so far: at the start, and every entry seen.
    people: usize,
    pressure: Vec<f64>,
    moving: Vec<[f64; 4]>,
}

impl std::fmt::Debug for Record<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Record")
            .field("frames", &self.frames)
            .field("exits", &self.exits)
            .finish_non_exhaustive()
    }
}

impl<'a> Record<'a> {
    /// Records a run of `people` people so far (at the start, or in the state a resumed run
    /// goes on from; those who enter are counted as they come) into `writer`, if any.
    pub fn new(writer: Option<&'a mut dyn RunSink>, people: usize) -> Self {
        Record {
            writer,
            progress: None,
            stats: RunStats::default(),
            frames: 0,
            exits: 0,
            people,
            pressure: Vec::new(),
            moving: Vec::new(),
        }
    }

    /// Saves a state's bytes ([`SimState::to_bytes`](moreau_crowd::SimState::to_bytes)) into
    /// the run file after its last frame (nothing without a file).
    pub fn save_state_bytes(&mut self, bytes: Vec<u8>) -> Result<(), moreau_io::IoError> {
        match self.writer.as_deref_mut() {
            Some(w) => w.save_state(bytes),
            None => Ok(()),
        }
    }

    /// Tells `progress` of every step.
    pub fn with_progress(mut self, progress: &'a mut Progress<'a>) -> Self {
        self.progress = Some(progress);
        self
    }
}

impl Observer for Record<'_> {
    fn step(&mut self, report: &StepReport) -> Result<(), ObserverError> {
        self.stats.add(report);
        if let Some(w) = self.writer.as_deref_mut() {
            w.step(report);
        }
        if let Some(progress) = self.progress.as_deref_mut() {
            progress(report, &self.stats, self.people - self.exits)?;
        }
        Ok(())
    }

    fn exit(&mut self, record: &ExitRecord) -> Result<(), ObserverError> {
        self.exits += 1;
        if let Some(w) = self.writer.as_deref_mut() {
            w.exit(record.id, record.exit, record.t)?;
        }
        Ok(())
    }

    fn enter(&mut self, record: &EntryRecord) -> Result<(), ObserverError> {
        self.people += 1;
        if let Some(w) = self.writer.as_deref_mut() {
            w.enter(record.id, record.radius)?;
        }
        Ok(())
    }

    fn frame(&mut self, f: &Frame<'_>) -> Result<(), ObserverError> {
        if let Some(w) = self.writer.as_deref_mut() {
            if w.records_contacts() {
                self.pressure.resize(self.people, f64::NAN);
                f.pressure_by_id(&mut self.pressure);
                let mut rows = f.contact_forces().map(|c| ContactRow {
                    frame: 0,
                    kind: match c.kind {
                        ContactKind::PersonPerson => ContactRow::PERSON_PERSON,
                        ContactKind::PersonWall => ContactRow::PERSON_WALL,
                        ContactKind::MovingWall => ContactRow::PERSON_MOVING_WALL,
                    },
                    a: c.a.into(),
                    b: c.b.into(),
                    lambda: c.lambda,
                });
                w.contact_rows(&mut rows, &self.pressure)?;
            }
            if !f.moving_walls.is_empty() {
                self.moving.clear();
                self.moving.extend(
                    f.moving_walls
                        .iter()
                        .map(|s| [s.a[0], s.a[1], s.b[0], s.b[1]]),
                );
                w.moving_walls(&self.moving)?;
            }
            w.frame(f.t, f.ids, f.positions)?;
        }
        self.frames += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{STATE_BYTES_PER_FRAME, StateCadence};

    /// The frames after which states of `size` bytes are saved, of the first `frames`.
    fn saves(size: usize, frames: usize) -> Vec<usize> {
        let mut cadence = StateCadence::default();
        (1..=frames)
            .filter(|_| {
                let due = cadence.frame();
                if due {
                    cadence.saved(size);
                }
                due
            })
            .collect()
    }

    #[test]
    fn a_small_state_is_saved_with_every_frame_a_large_one_by_its_size() {
        // The dense 2,000 scene's state (131 kB), and a state of exactly the budget.
        assert_eq!(saves(131_000, 5), vec![1, 2, 3, 4, 5]);
        assert_eq!(saves(STATE_BYTES_PER_FRAME, 5), vec![1, 2, 3, 4, 5]);
        // One byte more: every second frame. A million people's 55 MB: every seventh.
        assert_eq!(saves(STATE_BYTES_PER_FRAME + 1, 6), vec![1, 3, 5]);
        assert_eq!(saves(55_000_000, 16), vec![1, 8, 15]);
    }
}
