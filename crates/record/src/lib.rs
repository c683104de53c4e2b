//! A crowd run into its HDF5 run file: the observer ([`Record`]), the header
//! ([`header`]) and the summary ([`Summary`]) that `moreau run` and the Python module both
//! use, so that both write the same file.

use moreau_core::{Num, RunStats, StepReport};
use moreau_crowd::{
    ContactKind, EntryRecord, ExitRecord, Frame, Observer, ObserverError, Simulation, SourceTally,
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
        groups: sim
            .people()
            .groups()
            .iter()
            .map(|&g| i64::from(g))
            .collect(),
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
    /// Each inflow source's people due by the time reached and entered (empty without
    /// sources): a source with no room in its area leaves the difference waiting.
    pub sources: Vec<SourceTally>,
}

impl Summary {
    /// The summary of `sim` after a run that `record` observed, `wall` seconds long (a resumed
    /// run's earlier parts, saved with its state, are added: its steps are the whole run's).
    pub fn new(
        sim: &Simulation,
        record: &Record<'_>,
        scene: String,
        output: Option<String>,
        status: String,
        wall: f64,
    ) -> Self {
        let (stats, people) = (&record.stats, sim.total_people());
        let wall = wall + record.wall_before;
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
            sources: sim.source_tallies(),
        }
    }

    /// The warning for sources that left people waiting, one line each (`None` when every
    /// source brought everyone due): what `moreau run` prints and the Python module warns.
    pub fn waiting_warning(&self) -> Option<String> {
        let lines: Vec<String> = self
            .sources
            .iter()
            .filter(|s| s.waiting() > 0)
            .map(|s| {
                format!(
                    "source '{}': {} of the {} people due by t = {} s did not enter (no room \
                     in its area: people or a moving body stood there)",
                    s.name,
                    s.waiting(),
                    s.due,
                    Num(self.simulated_time)
                )
            })
            .collect();
        (!lines.is_empty()).then(|| lines.join("\n"))
    }

    /// Pretty JSON (what the file's `summary` attribute holds).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("plain data")
    }
}

/// Steps `sim` to its horizon frame by frame through `record`, saving the run's state into its
/// file (what `moreau run --resume` goes on from) after the frames [`state_due`] picks: every
/// frame up to ~10⁵ people. What `moreau run` and the Python module's `run` both do.
pub fn run_to_horizon(
    sim: &mut Simulation,
    record: &mut Record<'_>,
) -> Result<(), moreau_crowd::CrowdError> {
    while let Some(t) = sim.next_frame_time() {
        if let Err(e) = sim.advance_to(t, record) {
            if record.stopped {
                // Stopped after a step (an interrupt): the frame that step reached is
                // written too. A SIGTERM at a step on an output time left the file a frame
                // short of its steps. A failure to write it is the writer's to report when
                // the file is finished; the run's error is the stop.
                let _ = sim.advance_step(sim.time(), record);
            }
            return Err(e);
        }
        if record.writer.is_some() && state_due(sim.frames(), sim.people().len()) {
            record
                .save_state_bytes(sim.state().to_bytes())
                .map_err(|e| moreau_crowd::CrowdError::Observer(Box::new(e)))?;
        }
    }
    Ok(())
}

/// The state's bytes a run writes per frame at most, on average (8 MiB).
pub const STATE_BYTES_PER_FRAME: usize = 8 << 20;

/// What a person's share of the state is taken to be, warm-start multipliers included (a
/// million people's state measured 55 MB; the dense 2,000's 131 kB).
pub const STATE_BYTES_PER_PERSON: usize = 64;

/// Whether the state is saved after output frame `frames` (counted from 1, the frame at the
/// start) of `people` present: after every `k`-th frame, `k = ⌈people ·`
/// [`STATE_BYTES_PER_PERSON`] `/` [`STATE_BYTES_PER_FRAME`]`⌉`: every frame up to 131,072
/// people, every eighth at a million, whose state took 0.1 s a frame to serialize on the
/// stepping thread (~8 % of a step). It depends on the frame and the crowd only, so a resumed
/// run saves after the same frames as an uninterrupted one; a run killed outright redoes at
/// most `k − 1` frames.
pub fn state_due(frames: usize, people: usize) -> bool {
    let k = people
        .saturating_mul(STATE_BYTES_PER_PERSON)
        .div_ceil(STATE_BYTES_PER_FRAME)
        .max(1);
    frames.is_multiple_of(k)
}

/// The error that stops a run on a signal (`SIGINT`, `SIGTERM`, Ctrl-C in Python): its run
/// file is finished with status `interrupted`, by `moreau run` and the Python module alike.
#[derive(Debug, Clone, Copy)]
pub struct Interrupted(pub &'static str);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted by {}", self.0)
    }
}

impl std::error::Error for Interrupted {}

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
    /// Whether `progress` stopped the run after a step.
    stopped: bool,
    pressure: Vec<f64>,
    moving: Vec<[f64; 4]>,
    /// Wall-clock seconds of the run before this record began (a resumed run's earlier
    /// parts, as saved with its state).
    wall_before: f64,
    /// When this record began.
    started: std::time::Instant,
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
            stopped: false,
            pressure: Vec::new(),
            moving: Vec::new(),
            wall_before: 0.0,
            started: std::time::Instant::now(),
        }
    }

    /// Wall-clock seconds of the whole run so far: those saved with the state a resumed run
    /// goes on from, and this record's.
    pub fn wall_seconds(&self) -> f64 {
        self.wall_before + self.started.elapsed().as_secs_f64()
    }

    /// Saves a state's bytes ([`SimState::to_bytes`](moreau_crowd::SimState::to_bytes)) into
    /// the run file after its last frame (nothing without a file).
    pub fn save_state_bytes(&mut self, bytes: Vec<u8>) -> Result<(), moreau_io::IoError> {
        let totals = Totals::of(self).to_json();
        match self.writer.as_deref_mut() {
            Some(w) => w.save_state_noted(bytes, totals),
            None => Ok(()),
        }
    }

    /// Goes on from the totals saved with the state a run resumes from
    /// ([`moreau_io::Resumed::note`]): its summary then counts the whole run (it counted only
    /// the steps after the resume, and the frames as if the first were the resumed one). A
    /// note that is not such totals (a file written before 2026-11-28) leaves the totals at
    /// zero, as before.
    pub fn resuming(mut self, note: &str) -> Self {
        if let Ok(t) = serde_json::from_str::<Totals>(note) {
            t.into(&mut self);
        }
        self
    }

    /// Tells `progress` of every step.
    pub fn with_progress(mut self, progress: &'a mut Progress<'a>) -> Self {
        self.progress = Some(progress);
        self
    }
}

/// What a [`Record`] has added up, as saved beside each state (JSON).
#[derive(Debug, Serialize, serde::Deserialize)]
struct Totals {
    steps: usize,
    rejected: usize,
    redone: usize,
    iterations: usize,
    factorizations: usize,
    max_eps: f64,
    max_violation: f64,
    /// `predict, assemble, solve, solve_analyse, solve_factorize, verify, field, total` (s).
    timings: [f64; 8],
    solvers: Vec<(String, usize)>,
    frames: usize,
    exits: usize,
    people: usize,
    /// Wall-clock seconds so far (absent in files written before the evening of 2026-11-28:
    /// 0).
    #[serde(default)]
    wall_seconds: f64,
}

impl Totals {
    fn of(r: &Record<'_>) -> Self {
        let (s, t) = (&r.stats, &r.stats.timings);
        Totals {
            steps: s.steps,
            rejected: s.rejected,
            redone: s.redone,
            iterations: s.iterations,
            factorizations: s.factorizations,
            max_eps: s.max_eps,
            max_violation: s.max_violation,
            timings: [
                t.predict,
                t.assemble,
                t.solve,
                t.solve_analyse,
                t.solve_factorize,
                t.verify,
                t.field,
                t.total,
            ],
            solvers: s.solvers.iter().map(|&(n, k)| (n.to_string(), k)).collect(),
            frames: r.frames,
            exits: r.exits,
            people: r.people,
            wall_seconds: r.wall_seconds(),
        }
    }

    fn to_json(&self) -> String {
        serde_json::to_string(self).expect("plain data")
    }

    fn into(self, r: &mut Record<'_>) {
        let [
            predict,
            assemble,
            solve,
            solve_analyse,
            solve_factorize,
            verify,
            field,
            total,
        ] = self.timings;
        r.stats = RunStats {
            steps: self.steps,
            rejected: self.rejected,
            redone: self.redone,
            iterations: self.iterations,
            factorizations: self.factorizations,
            max_eps: self.max_eps,
            max_violation: self.max_violation,
            timings: moreau_core::StageTimings {
                predict,
                assemble,
                solve,
                solve_analyse,
                solve_factorize,
                verify,
                field,
                total,
            },
            solvers: self
                .solvers
                .iter()
                .map(|(n, k)| (solver_name(n), *k))
                .collect(),
        };
        (r.frames, r.exits, r.people) = (self.frames, self.exits, self.people);
        r.wall_before = self.wall_seconds;
    }
}

/// The `&'static str` a step report names solver `name` with: the names a run saw are few
/// (the solver kinds and their pairings), each kept once for the process.
fn solver_name(name: &str) -> &'static str {
    static NAMES: std::sync::Mutex<Vec<&'static str>> = std::sync::Mutex::new(Vec::new());
    let mut names = NAMES.lock().unwrap_or_else(|e| e.into_inner());
    match names.iter().find(|&&n| n == name) {
        Some(&n) => n,
        None => {
            let n: &'static str = Box::leak(name.to_string().into_boxed_str());
            names.push(n);
            n
        }
    }
}

impl Observer for Record<'_> {
    fn step(&mut self, report: &StepReport) -> Result<(), ObserverError> {
        self.stats.add(report);
        if let Some(w) = self.writer.as_deref_mut() {
            w.step(report);
        }
        if let Some(progress) = self.progress.as_deref_mut() {
            let told = progress(report, &self.stats, self.people - self.exits);
            self.stopped = told.is_err();
            told?;
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
            w.enter(record.id, record.radius, record.t, record.group)?;
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
    use super::state_due;

    /// The frames of the first `frames` after which a state of `people` is saved.
    fn saves(people: usize, frames: usize) -> Vec<usize> {
        (1..=frames).filter(|&f| state_due(f, people)).collect()
    }

    #[test]
    fn a_small_crowds_state_is_saved_with_every_frame_a_large_ones_by_its_size() {
        assert_eq!(saves(0, 4), vec![1, 2, 3, 4]);
        assert_eq!(saves(2_000, 4), vec![1, 2, 3, 4]);
        // 2¹⁷ people: 8 MiB exactly; one more, every second frame.
        assert_eq!(saves(131_072, 4), vec![1, 2, 3, 4]);
        assert_eq!(saves(131_073, 6), vec![2, 4, 6]);
        // A million: every eighth.
        assert_eq!(saves(1_000_000, 24), vec![8, 16, 24]);
    }
}
