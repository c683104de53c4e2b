//! `Simulation`: a crowd run as a value (its scene, people, geometry and pipelines) and
//! `advance_to`, the one loop over its steps, which reports steps, frames and exits to an
//! observer the caller passes.

use moreau_core::{ConstraintKey, ConstraintRows, Num, Parallelism, RunStats, StepReport};
use moreau_integrate::{LinearizedProjection, LinearizedSettings, Scheme, Stepping};
use moreau_solve::ProjectionSolver;

use crate::broad::{BroadPhaseKind, choose_broad_phase};
use crate::contacts::{ContactKind, ContactSources, CrowdContacts, PersonPairs, PersonWalls};
use crate::error::CrowdError;
use crate::events::{EntryRecord, Events};
use crate::exits::Exits;
use crate::field::DesiredVelocity;
use crate::geometry::Segment;
use crate::moving::{MovingBodies, PersonMovingWalls};
use crate::people::{ExitRecord, People, Place};
use crate::scene::{BroadPhaseChoice, ExitAction, Scene, SolverKind};
use crate::spawn::place_people;
use crate::state::SimState;
use crate::walls::Walls;

/// The shortest step moving bodies may ask for (s): a body whose speed `β` needs shorter steps
/// (`β μ ≤ r_min / 2`) stops the run with an error.
pub const MIN_MOVING_STEP: f64 = 1e-9;

/// One recorded configuration, borrowed from the people.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    /// Time.
    pub t: f64,
    /// Ids of the people present.
    pub ids: &'a [u32],
    /// Their positions `[x0, y0, x1, y1, ...]`.
    pub positions: &'a [f64],
    /// Their radii.
    pub radii: &'a [f64],
    /// The multipliers of the step that ended here, by contact key (every row it assembled,
    /// `λ = 0` for those not in contact; empty before the first step).
    pub multipliers: &'a [(ConstraintKey, f64)],
    /// The segments of the moving bodies at `t`, in [`MovingBodies`] order (empty without).
    pub moving_walls: &'a [Segment],
}

/// A contact that pushed in the step that ended at a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactForce {
    /// Person–person or person–wall.
    pub kind: ContactKind,
    /// The person (the smaller id of a pair).
    pub a: u32,
    /// The other person's id, or the wall segment's index in the scene's walls.
    pub b: u32,
    /// The multiplier `λ > 0` (m/s): the speed the contact removed along its normal,
    /// `v = w + Σ λ ∇g`.
    pub lambda: f64,
}

impl ContactForce {
    /// Multipliers at or below this (m/s) are not contact forces: an interior point leaves
    /// every row it did not activate a tiny positive multiplier (`λ_i s_i → 0`), and a
    /// micrometre per second is far below the velocity the step's certificate resolves
    /// (`√ε / μ`, millimetres per second and more).
    pub const FLOOR: f64 = 1e-6;
}

impl Frame<'_> {
    /// The contacts with `λ > ContactForce::FLOOR` of the step that ended at this frame, in
    /// key order.
    pub fn contact_forces(&self) -> impl Iterator<Item = ContactForce> + '_ {
        self.multipliers.iter().filter_map(|&(key, lambda)| {
            let (kind, a, b) = ContactKind::of(key);
            match kind {
                Some(kind) if lambda > ContactForce::FLOOR => {
                    Some(ContactForce { kind, a, b, lambda })
                }
                _ => None,
            }
        })
    }

    /// Each present person's pressure `Σ λ` over its [contact forces](Self::contact_forces) (m/s) into `out` at `id`: 0
    /// for a present person without contacts, NaN for ids not present.
    pub fn pressure_by_id(&self, out: &mut [f64]) {
        out.fill(f64::NAN);
        for &id in self.ids {
            if let Some(p) = out.get_mut(id as usize) {
                *p = 0.0;
            }
        }
        for c in self.contact_forces() {
            let mut add = |id: u32| {
                if let Some(p) = out.get_mut(id as usize).filter(|p| !p.is_nan()) {
                    *p += c.lambda;
                }
            };
            add(c.a);
            if c.kind == ContactKind::PersonPerson {
                add(c.b);
            }
        }
    }

    /// Writes the positions into `out` at `[2 id, 2 id + 1]`, NaN for ids not present (and
    /// ids beyond `out` skipped).
    pub fn positions_by_id(&self, out: &mut [f64]) {
        out.fill(f64::NAN);
        for (k, &id) in self.ids.iter().enumerate() {
            let i = 2 * id as usize;
            if i + 1 < out.len() {
                out[i] = self.positions[2 * k];
                out[i + 1] = self.positions[2 * k + 1];
            }
        }
    }

    /// Writes the radii into `out` at `id`, NaN for ids not present.
    pub fn radii_by_id(&self, out: &mut [f64]) {
        out.fill(f64::NAN);
        for (k, &id) in self.ids.iter().enumerate() {
            if let Some(r) = out.get_mut(id as usize) {
                *r = self.radii[k];
            }
        }
    }
}

/// An error an observer returns to stop the run (a file that cannot be written, say).
pub type ObserverError = Box<dyn std::error::Error + Send + Sync>;

/// What a run reports as it goes; every method defaults to doing nothing.
pub trait Observer {
    /// After every accepted step.
    fn step(&mut self, _report: &StepReport) -> Result<(), ObserverError> {
        Ok(())
    }
    /// At the start and at every output time (every `time.output_interval`, and the horizon).
    fn frame(&mut self, _frame: &Frame<'_>) -> Result<(), ObserverError> {
        Ok(())
    }
    /// When a person passes an exit (after the step's report).
    fn exit(&mut self, _record: &ExitRecord) -> Result<(), ObserverError> {
        Ok(())
    }
    /// When a person enters from an inflow source (after the step's exits).
    fn enter(&mut self, _record: &EntryRecord) -> Result<(), ObserverError> {
        Ok(())
    }
}

/// Observes nothing.
impl Observer for () {}

/// Adds up the step reports.
impl Observer for RunStats {
    fn step(&mut self, report: &StepReport) -> Result<(), ObserverError> {
        self.add(report);
        Ok(())
    }
}

type Projection = LinearizedProjection<Box<dyn ProjectionSolver>>;

/// What a step is made of, borrowed from a [`Simulation`].
struct Parts<'a> {
    scheme: &'a mut Scheme<Projection>,
    stepping: &'a mut Stepping,
    field: DesiredVelocity<'a>,
    contacts: CrowdContacts<'a>,
    q: &'a mut [f64],
}

/// A crowd run built from a [`Scene`]: the people (the one owner of their data), the walls,
/// exits and distance fields, and the pipelines that step them (scheme, solver, contact
/// sources), which hold only scratch memory and the warm start.
pub struct Simulation {
    scene: Scene,
    exits: Exits,
    /// The scene's walls, and those of closed exits.
    walls: Walls,
    /// Walls, panels and obstacles that move.
    moving: MovingBodies,
    /// Their segments at `t`.
    moving_now: Vec<Segment>,
    /// Where the moving bodies were (their keyframe parameters) when the distance fields were
    /// last solved around them (`None`: the fields see the fixed walls only).
    fields_built: Option<Vec<f64>>,
    /// How many `model.field_update` intervals had begun at the last check.
    fields_due: f64,
    /// Scratch: the bodies' parameters now.
    params: Vec<f64>,
    people: People,
    exit_log: Vec<ExitRecord>,
    /// Release times and inflow sources.
    events: Events,
    scheme: Scheme<Projection>,
    sources: ContactSources,
    stepping: Stepping,
    t: f64,
    steps: usize,
    frames: usize,
    speed_factor: f64,
    total: usize,
    broad: BroadPhaseKind,
    // the helper thread of the loops over people with threads (shared with the solver's)
    helper: Option<std::sync::Arc<moreau_core::Helper>>,
    // scratch
    near: std::sync::Mutex<Vec<Vec<u32>>>,
    keep: Vec<bool>,
    gap_rows: ConstraintRows,
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("t", &self.t)
            .field("people", &self.people.len())
            .finish_non_exhaustive()
    }
}

impl Simulation {
    /// Builds the run: distance fields, initial positions, solver. Every failure names the
    /// scene field at fault.
    pub fn new(scene: Scene) -> Result<Self, CrowdError> {
        scene.validate()?;
        let threads = scene.solver.threads;
        let most = crate::limits::max_threads();
        if threads > most {
            return Err(CrowdError::invalid(
                "solver.threads",
                threads,
                format!(
                    "more than this machine runs usefully: at most {most} (twice its {} cores; \
                     0: every core)",
                    most / 2
                ),
            ));
        }
        let walls = Walls::new(scene.walls());
        let moving = MovingBodies::new(&scene);
        let mut moving_now = Vec::new();
        moving.segments_at(0.0, &mut moving_now);
        let mut params = Vec::new();
        moving.params_at(0.0, &mut params);
        let fields_built =
            (!moving.is_empty() && scene.model.field_update.is_some()).then(|| params.clone());
        let exits = match &fields_built {
            None => Exits::build(&scene, &|p| scene.walkable(p))?,
            Some(at) => Exits::build(&scene, &walkable_with(&scene, &moving, &moving_now, at))?,
        };
        let mut exits = exits;
        // Exit panels follow the scene's own moving bodies, one segment each.
        let mut panel = moving.segment_count()
            - scene
                .exits
                .iter()
                .filter(|e| e.closes.is_some() || e.opens.is_some())
                .count();
        for (x, e) in exits.exits.iter_mut().zip(&scene.exits) {
            if e.closes.is_some() || e.opens.is_some() {
                x.panel = Some(panel);
                x.update_passage(&moving_now);
                panel += 1;
            }
        }
        let people = if moving.is_empty() {
            place_people(&scene, &walls, &moving, &exits)?
        } else {
            let all = Walls::new(
                walls
                    .segments()
                    .iter()
                    .chain(&moving_now)
                    .copied()
                    .collect(),
            );
            place_people(&scene, &all, &moving, &exits)?
        };
        let events = Events::build(&scene, &walls, &exits, &people)?;
        let n = people.len();
        let broad = match scene.solver.broad_phase {
            BroadPhaseChoice::Grid => BroadPhaseKind::Grid,
            BroadPhaseChoice::Bvh => BroadPhaseKind::Bvh,
            BroadPhaseChoice::Auto => choose_broad_phase(scene.min_radius(), scene.max_radius()),
        };
        let mut sources: Vec<Box<dyn crate::contacts::ContactSource>> = vec![
            Box::new(
                PersonPairs::new(broad.build_on(Parallelism::threads(threads)))
                    .on_threads(Parallelism::threads(threads)),
            ),
            Box::new(PersonWalls::on_threads(Parallelism::threads(threads))),
        ];
        if !moving.is_empty() {
            sources.push(Box::new(PersonMovingWalls::default()));
        }
        let sources = ContactSources::new(sources);
        let solver = scene
            .solver
            .kind
            .build_with(
                Parallelism::threads(scene.solver.threads),
                2 * (n + events.capacity()),
                &scene.solver.tuning(),
            )
            .map_err(moreau_integrate::IntegrateError::from)?;
        let settings = LinearizedSettings {
            max_violation: scene.solver.max_violation,
            max_redo: 8,
        };
        let correction = LinearizedProjection::new(solver, settings)?;
        let stepping = scene.time.stepping(scene.solver.kind)?;
        let scheme = Scheme::new(correction, scene.eps_policy(&stepping)?);
        let helper = crate::bands::helper_for(Parallelism::threads(scene.solver.threads));
        Ok(Self {
            scene,
            exits,
            walls,
            moving,
            moving_now,
            fields_built,
            fields_due: 0.0,
            params,
            people,
            exit_log: Vec::new(),
            events,
            scheme,
            sources,
            stepping,
            t: 0.0,
            steps: 0,
            frames: 0,
            speed_factor: 1.0,
            total: n,
            broad,
            helper,
            near: std::sync::Mutex::new(Vec::new()),
            keep: Vec::new(),
            gap_rows: ConstraintRows::default(),
        })
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Current time.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Steps taken.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Output frames reported so far, the first (at the start) included.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Everyone so far: the people at the start and those who entered since (every id is
    /// below it).
    pub fn total_people(&self) -> usize {
        self.total + self.events.emitted()
    }

    /// Each inflow source's people due by now and entered (in the scene's order): where they
    /// differ, people wait for room in the source's area.
    pub fn source_tallies(&self) -> Vec<crate::SourceTally> {
        self.events.tallies(self.time(), &self.scene)
    }

    /// The most people the run can hold: those at the start and all its sources can bring
    /// (the solver, and its fallback, are chosen for this many).
    pub fn max_people(&self) -> usize {
        self.total + self.events.capacity()
    }

    /// The people present.
    pub fn people(&self) -> &People {
        &self.people
    }

    /// The current configuration.
    pub fn frame(&self) -> Frame<'_> {
        Frame {
            t: self.t,
            ids: self.people.ids(),
            positions: self.people.positions(),
            radii: self.people.radii(),
            multipliers: self.scheme.correction().warm_start(),
            moving_walls: &self.moving_now,
        }
    }

    /// The moving bodies (walls, panels, obstacles with a prescribed motion).
    pub fn moving(&self) -> &MovingBodies {
        &self.moving
    }

    /// Drives moving body `body` from outside (a co-simulation input): its keyframe parameter
    /// goes linearly from where it is now to `param` at time `t_end`, then stays (the body
    /// moves continuously, so the sweeping stays a sweeping). Until the first call a body
    /// follows its keyframes in time.
    pub fn drive_moving(&mut self, body: usize, param: f64, t_end: f64) -> Result<(), CrowdError> {
        let count = self.moving.names().len();
        if body >= count {
            return Err(CrowdError::invalid(
                "moving",
                body,
                format!("the scene has {count} moving bodies"),
            ));
        }
        if !(param.is_finite() && t_end.is_finite() && t_end >= self.t) {
            return Err(CrowdError::invalid(
                format!("moving[{body}] position"),
                format!("{} at t = {}", Num(param), Num(t_end)),
                format!("must be finite, at a time ≥ the current {}", Num(self.t)),
            ));
        }
        self.moving.drive(body, self.t, t_end, param);
        Ok(())
    }

    /// Everyone who passed an exit so far, in order.
    pub fn exit_records(&self) -> &[ExitRecord] {
        &self.exit_log
    }

    /// The projection solver's kind (its fallback and `auto`'s rule:
    /// [`SolverKind::describe`]). Each step report names the solver that answered.
    pub fn solver_kind(&self) -> SolverKind {
        self.scene.solver.kind
    }

    /// The broad phase in use.
    pub fn broad_phase(&self) -> BroadPhaseKind {
        self.broad
    }

    /// How steps are chosen (fixed, or adaptive with its controller).
    pub fn stepping(&self) -> &Stepping {
        &self.stepping
    }

    /// The walls (the scene's and those of closed exits).
    pub fn walls(&self) -> &Walls {
        &self.walls
    }

    /// The projection problem of the last step (rows, offsets, prediction), to re-solve it.
    pub fn last_projection(&self) -> moreau_solve::ProjectionProblem<'_> {
        self.scheme
            .correction()
            .last_problem(self.scheme.prediction())
    }

    /// The multipliers of the last step, one per row of [`last_projection`](Self::last_projection).
    pub fn last_multipliers(&self) -> &[f64] {
        self.scheme.correction().multipliers()
    }

    /// The factor on every desired speed.
    pub fn set_speed_factor(&mut self, factor: f64) {
        self.speed_factor = factor;
    }

    /// The factor on every desired speed (1 unless [`set_speed_factor`](Self::set_speed_factor)
    /// or a restored state changed it).
    pub fn speed_factor(&self) -> f64 {
        self.speed_factor
    }

    /// The desired velocities at the current configuration, `[u0x, u0y, …]`, into `out`.
    pub fn desired_velocities(&mut self, out: &mut [f64]) {
        use moreau_core::Field;
        let t = self.t;
        let p = self.parts();
        p.field.eval(t, p.q, out);
    }

    /// Every contact with `g ≤ margin` at the current configuration, as rows (cleared first).
    pub fn contacts(&mut self, margin: f64, rows: &mut ConstraintRows) {
        rows.clear(self.people.positions().len());
        let view = self.people.view();
        self.sources.assemble(
            self.t,
            self.people.positions(),
            view,
            &self.walls,
            &self.moving,
            margin,
            rows,
        );
    }

    /// The margin of the contacts assembled for a step of `mu` from the current configuration
    /// with predicted velocities `w` (every contact that can close within the step).
    pub fn contact_margin(&mut self, w: &[f64], mu: f64) -> f64 {
        use moreau_core::ConstraintSet;
        let p = self.parts();
        p.contacts.margin(p.q, w, mu)
    }

    /// How many constraints that are not in `assembled` are violated by more than `tol` at
    /// the current configuration (the check after every step).
    pub fn crossed_outside(&mut self, assembled: &ConstraintRows, tol: f64) -> usize {
        use moreau_core::ConstraintSet;
        let t = self.t;
        let mut p = self.parts();
        p.contacts.crossed_outside(t, p.q, assembled, tol)
    }

    /// Whether every contact left out of an assembly at the current configuration with
    /// `margin` is certainly violated by no more than `tol` at `q_next`: the bound on how far
    /// people moved that spares a step the check of [`crossed_outside`](Self::crossed_outside).
    pub fn left_out_stay_feasible(&mut self, q_next: &[f64], margin: f64, tol: f64) -> bool {
        use moreau_core::ConstraintSet;
        let t = self.t;
        let p = self.parts();
        p.contacts
            .left_out_stay_feasible(t, p.q, q_next, margin, tol)
    }

    /// Whether exit `e` is open.
    pub fn exit_open(&self, e: usize) -> Option<bool> {
        self.exits.exits.get(e).map(|x| x.open)
    }

    /// Opens or closes exit `e` (a scene change, from the next step on). A closed exit is a
    /// wall: its segment, or for an area its mid-line across the doorway
    /// (`exits::closure`); nobody passes it, and people standing in it are pushed out to the
    /// side their centre is on. Reopening removes the wall.
    pub fn set_exit_open(&mut self, e: usize, open: bool) -> Result<(), CrowdError> {
        let count = self.exits.exits.len();
        let Some(exit) = self.exits.exits.get_mut(e) else {
            return Err(CrowdError::invalid(
                "exit",
                e,
                format!("the scene has {count} exits"),
            ));
        };
        if exit.open == open {
            return Ok(());
        }
        exit.open = open;
        self.rebuild_walls();
        Ok(())
    }

    /// Removes the people for whom `remove(id, position)` is true (a scene change, from the
    /// next step on; they get no exit record) and returns how many were removed.
    pub fn remove_people(&mut self, mut remove: impl FnMut(u32, [f64; 2]) -> bool) -> usize {
        let keep: Vec<bool> = (0..self.people.len())
            .map(|i| !remove(self.people.ids()[i], self.people.position(i)))
            .collect();
        let removed = keep.iter().filter(|k| !**k).count();
        if removed > 0 {
            self.people.retain(&keep);
            self.stepping.state_resized();
        }
        removed
    }

    fn rebuild_walls(&mut self) {
        let mut walls = self.scene.walls();
        walls.extend(
            self.exits
                .exits
                .iter()
                .filter(|x| !x.open)
                .map(|x| x.closure()),
        );
        self.walls = Walls::new(walls);
    }

    /// The smallest gap between two people present, or between a person and a wall (closed
    /// exits included), at the current configuration (m); `+∞` when there is nothing to
    /// touch within `reach` (m).
    pub fn min_gap(&mut self, reach: f64) -> f64 {
        let mut rows = std::mem::take(&mut self.gap_rows);
        self.contacts(reach, &mut rows);
        let gap = rows.values().iter().copied().fold(f64::INFINITY, f64::min);
        self.gap_rows = rows;
        gap
    }

    /// The pipelines and the views of the people they step (the positions mutably, the rest
    /// borrowed): what every step is made of.
    fn parts(&mut self) -> Parts<'_> {
        let (q, people) = self.people.split_mut();
        Parts {
            scheme: &mut self.scheme,
            stepping: &mut self.stepping,
            field: DesiredVelocity {
                fields: &self.exits.fields,
                goals: &self.exits.goals,
                walls: &self.walls,
                people,
                stand_until: &self.events.stand_until,
                speed_factor: self.speed_factor,
                kind: self.scene.model.desired_velocity,
                near: &self.near,
                parallelism: Parallelism::threads(self.scene.solver.threads),
                helper: self.helper.as_deref(),
            },
            contacts: CrowdContacts {
                people,
                walls: &self.walls,
                moving: &self.moving,
                sources: &mut self.sources,
            },
            q,
        }
    }

    /// One step of size `mu` (whatever the scene's stepping says); then applies exits. For
    /// tests and tools that choose each step; runs call [`advance_to`](Self::advance_to).
    pub fn step(&mut self, mu: f64) -> Result<StepReport, CrowdError> {
        let field = self.update_fields();
        let (k, t) = (self.steps, self.t);
        let p = self.parts();
        let mut report = p
            .scheme
            .step(&p.field, &mut { p.contacts }, k, t, p.q, mu)
            .map_err(|e| self.diagnose(e.into()))?;
        report.timings.field = field;
        report.timings.total += field;
        self.accept(&report);
        Ok(report)
    }

    /// The end of the next step towards `t_stop` allowed by the moving bodies: none may move
    /// more than half the smallest radius in one step, so none passes a person's centre within
    /// a step (the linearization at `t_{k+1}` would put the person on the wrong side).
    ///
    /// A step that would have to be shorter than [`MIN_MOVING_STEP`] (a body far faster than
    /// the people are small) is an error naming the speed, not a run that never ends.
    fn moving_stop(&self, t_stop: f64) -> Result<f64, CrowdError> {
        if self.moving.is_empty() {
            return Ok(t_stop);
        }
        let beta = self.moving.max_speed(self.t, t_stop);
        if beta == 0.0 {
            return Ok(t_stop);
        }
        let r_min = self
            .people
            .radii()
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let largest = 0.5 * r_min / beta;
        let fixed_within = matches!(self.stepping, Stepping::Fixed { step } if step <= largest);
        if fixed_within || self.t + largest >= t_stop {
            return Ok(t_stop);
        }
        if !(largest >= MIN_MOVING_STEP) {
            return Err(CrowdError::invalid(
                "moving",
                format!("β = {beta:e} m/s at t = {}", Num(self.t)),
                format!(
                    "a moving body this fast would need steps of {largest:.3e} s (half the \
                     smallest radius, {} m, per step), below the {MIN_MOVING_STEP:e} s \
                     a run allows",
                    Num(r_min)
                ),
            ));
        }
        // Whole fractions of the way to t_stop: the steps stay equal.
        let parts = ((t_stop - self.t) / largest).ceil();
        Ok(self.t + (t_stop - self.t) / parts)
    }

    /// At the first step from every `model.field_update` seconds on, solves the distance
    /// fields again around the moving bodies where they are now, if any is elsewhere than at
    /// the last solve; returns the seconds it took.
    fn update_fields(&mut self) -> f64 {
        let (Some(built), Some(every)) = (&self.fields_built, self.scene.model.field_update) else {
            return 0.0;
        };
        let due = (self.t / every * (1.0 + 1e-9)).floor() > self.fields_due;
        if !due {
            return 0.0;
        }
        self.fields_due = (self.t / every * (1.0 + 1e-9)).floor();
        self.moving.params_at(self.t, &mut self.params);
        if self.params == *built {
            return 0.0;
        }
        let start = std::time::Instant::now();
        let params = std::mem::take(&mut self.params);
        self.build_fields_with(params);
        start.elapsed().as_secs_f64()
    }

    /// The distance fields around the moving bodies at keyframe parameters `params`.
    fn build_fields_with(&mut self, params: Vec<f64>) {
        let mut segments = Vec::new();
        self.moving.segments_with(&params, &mut segments);
        {
            let walkable = walkable_with(&self.scene, &self.moving, &segments, &params);
            self.exits.rebuild_fields(&self.scene, &walkable);
        }
        self.fields_built = Some(params);
    }

    /// One step of the scene's stepping towards `t_stop`, or `None` once it is reached. When
    /// `t_stop` is an output frame's time, the step that reaches it ends on it: the sum of the
    /// steps misses it in its last bits (15.000000000000078 s for 300 steps of 0.05 s), which
    /// every frame time and exit time after it would carry. Other stops (a caller's `t_end`, a
    /// communication point) are not landed on, so that a run stopped and resumed there takes
    /// the same steps, bit for bit, as one that was not.
    fn step_towards(&mut self, t_stop: f64, frame: bool) -> Result<Option<StepReport>, CrowdError> {
        let frame_at = frame.then_some(t_stop);
        let t_stop = self.moving_stop(t_stop)?;
        if self.stepping.reached(self.t, t_stop) {
            return Ok(None);
        }
        let field = self.update_fields();
        let (k, t) = (self.steps, self.t);
        let p = self.parts();
        let report = p
            .stepping
            .step(p.scheme, &p.field, &mut { p.contacts }, k, t, p.q, t_stop)
            .map_err(|e| self.diagnose(e.into()))?;
        Ok(report.map(|mut r| {
            if let Some(frame) = frame_at
                && self.stepping.reached(r.t, frame)
            {
                r.t = frame;
            }
            r.timings.field = field;
            r.timings.total += field;
            self.accept(&r);
            r
        }))
    }

    /// A step that failed to certify: when its constraints admit no velocity at all (checked by
    /// a Farkas certificate, [`moreau_solve::infeasibility_certificate`]), the error names the
    /// constraints, people and moving bodies at fault; otherwise it says how fast the step's
    /// desired velocities were ([`CrowdError::NotCertified`]). Other errors pass as they are.
    fn diagnose(&self, error: CrowdError) -> CrowdError {
        use moreau_integrate::IntegrateError;
        let t = match &error {
            CrowdError::Integrate(IntegrateError::NotCertified { t, .. }) => *t,
            _ => return error,
        };
        let problem = self.last_projection();
        let Ok(Some(y)) = moreau_solve::infeasibility_certificate(&problem) else {
            let fastest = problem
                .w
                .chunks_exact(2)
                .map(|u| u[0].hypot(u[1]))
                .fold(0.0, f64::max);
            let CrowdError::Integrate(error) = error else {
                return error;
            };
            return CrowdError::NotCertified {
                error,
                fastest,
                speed_factor: self.speed_factor,
            };
        };
        let mut contacts: Vec<(ContactKind, u32, u32, f64)> = problem
            .jacobian
            .keys()
            .iter()
            .zip(&y)
            .filter(|(_, y)| **y > 1e-6)
            .filter_map(|(&key, &y)| match ContactKind::of(key) {
                (Some(kind), a, b) => Some((kind, a, b, y)),
                _ => None,
            })
            .collect();
        contacts.sort_by(|x, y| y.3.total_cmp(&x.3));
        let mut people: Vec<u32> = contacts
            .iter()
            .flat_map(|&(kind, a, b, _)| {
                std::iter::once(a).chain((kind == ContactKind::PersonPerson).then_some(b))
            })
            .collect();
        people.sort_unstable();
        people.dedup();
        let bodies: Vec<u32> = self.moving.segment_bodies().collect();
        let mut moving: Vec<u32> = contacts
            .iter()
            .filter(|c| c.0 == ContactKind::MovingWall)
            .filter_map(|c| bodies.get(c.2 as usize).copied())
            .collect();
        moving.sort_unstable();
        moving.dedup();
        CrowdError::Infeasible(Box::new(crate::error::Infeasibility {
            t,
            contacts,
            people,
            moving: moving
                .iter()
                .map(|&b| self.moving.names()[b as usize].clone())
                .collect(),
        }))
    }

    fn accept(&mut self, report: &StepReport) {
        self.t = report.t;
        self.steps += 1;
        self.moving.segments_at(self.t, &mut self.moving_now);
        for x in &mut self.exits.exits {
            x.update_passage(&self.moving_now);
        }
        let people = self.people.len();
        self.apply_exits();
        let left = self.people.len() != people;
        let (moving, now, t) = (&self.moving, &self.moving_now, self.t);
        let blocked =
            |p: [f64; 2], r: f64| moving.inside(t, p) || now.iter().any(|s| s.distance(p) < r);
        let entered = self.events.after_step(
            t,
            &mut self.people,
            &self.scene,
            &self.walls,
            &self.exits,
            &blocked,
        );
        if left || entered > 0 {
            self.stepping.state_resized();
        }
    }

    /// The time of the next frame [`advance_to`](Self::advance_to) will report (every output
    /// interval, and the horizon; the first at the start), or `None` once the horizon's frame
    /// was reported.
    pub fn next_frame_time(&self) -> Option<f64> {
        let horizon = self.scene.time.horizon;
        if self.frames > 0 && self.stepping.reached(self.t, horizon) {
            return None;
        }
        Some(self.next_output().min(horizon))
    }

    /// The next time a frame is due: frame `k` at `k × output_interval`, and a frame at the
    /// horizon where no such time reaches it (a last frame cut short); past the horizon the
    /// output times go on. It depends on the frames written only, so a restored run has the
    /// same frames. (Until session 37 the horizon's frame was due only until the horizon was
    /// reached, so it was never written: a horizon of 0.25 or 0.3 s with frames every 0.1 s
    /// lost its last frame, as 3 × 0.1 = 0.30000000000000004 lies past 0.3.)
    fn next_output(&self) -> f64 {
        let time = &self.scene.time;
        let (horizon, interval) = (time.horizon, time.output_interval);
        let at = |k: usize| k as f64 * interval;
        // `n`: the first frame whose output time lies past the horizon by more than rounding.
        let past = |k: usize| !self.stepping.reached(horizon, at(k));
        let mut n = (horizon / interval).floor() as usize;
        while !past(n) {
            n += 1;
        }
        while n > 0 && past(n - 1) {
            n -= 1;
        }
        // An output time within the shortest step of the horizon (before it, or past it by
        // rounding) is the horizon's frame: a frame 10⁻⁹ s before it (0.7 s for a horizon of
        // 0.700000001 s) left a last step too short to certify.
        let near = |k: usize| k > 0 && horizon - at(k) <= self.shortest_span();
        // Whether frame `n` is the horizon's, the output times before it falling short of it.
        let cut = n > 0 && !near(n - 1);
        let k = self.frames;
        if k < n {
            if near(k) { horizon } else { at(k) }
        } else if k == n && cut {
            horizon
        } else {
            at(k - usize::from(cut))
        }
    }

    /// The shortest span between two stops the driver makes a step of:
    /// [`SHORTEST_LAST`](moreau_integrate::SHORTEST_LAST) of the longest step. A frame closer
    /// than that to the stop after it is taken at that stop (a step of 10⁻⁹ s, between a frame
    /// and a host's time stored in single precision, cannot be certified in doubles).
    fn shortest_span(&self) -> f64 {
        moreau_integrate::SHORTEST_LAST * self.stepping.largest_step()
    }

    /// Steps to `t_end` (fixed or adaptive, as the scene says), telling `observer` of every
    /// step, every exit and every frame due on the way (the first frame, at the start, on the
    /// first call). The first error, of a step or of the observer, stops the run there and is
    /// returned: the simulation stays at its last accepted step.
    pub fn advance_to<O: Observer + ?Sized>(
        &mut self,
        t_end: f64,
        observer: &mut O,
    ) -> Result<(), CrowdError> {
        self.check_t_end(t_end)?;
        while self.advance_step(t_end, observer)?.is_some() {}
        Ok(())
    }

    /// Whether [`advance_to`](Self::advance_to)`(t_end)` may be asked: `t_end` finite, not
    /// before the current time, and at most [`limits::MAX_STEPS`](crate::limits::MAX_STEPS)
    /// of the longest steps away (the bound a scene's horizon has; `t_end = 1e300` asked
    /// ~10³⁰¹ steps of a call, which ran until killed).
    pub fn check_t_end(&self, t_end: f64) -> Result<(), CrowdError> {
        // (Before it by rounding only is the current time: `advance_to(2.4)` twice, the first
        // having stepped to the frame at 2.4000000000000004.)
        if !(t_end.is_finite() && (t_end >= self.t || self.stepping.reached(t_end, self.t))) {
            return Err(CrowdError::invalid(
                "t_end",
                Num(t_end),
                format!("must be finite and ≥ the current time {}", Num(self.t)),
            ));
        }
        let largest = self.stepping.largest_step();
        let steps = (t_end - self.t) / largest;
        if !(steps <= crate::limits::MAX_STEPS) {
            return Err(CrowdError::invalid(
                "t_end",
                Num(t_end),
                format!(
                    "from the current time {} it takes {steps:.3e} steps of at most {} s, more \
                     than the limit of {:e} steps a call",
                    Num(self.t),
                    Num(largest),
                    crate::limits::MAX_STEPS
                ),
            ));
        }
        Ok(())
    }

    /// At most one step of [`advance_to`](Self::advance_to)`(t_end, observer)`: the frames due
    /// before it, then the step (its report returned); `None`, after the frames due at
    /// `t_end`, once `t_end` is reached (at once for a `t_end` at or before the current time).
    /// Calling it until `None` is `advance_to`, step for step and bit for bit; callers use it
    /// to look at the people between steps.
    pub fn advance_step<O: Observer + ?Sized>(
        &mut self,
        t_end: f64,
        observer: &mut O,
    ) -> Result<Option<StepReport>, CrowdError> {
        if !t_end.is_finite() {
            return Err(CrowdError::invalid("t_end", t_end, "must be finite"));
        }
        if self.frames == 0 {
            observer
                .frame(&self.frame())
                .map_err(CrowdError::Observer)?;
            self.frames = 1;
        }
        loop {
            let output = self.next_output();
            // A `t_end` short of the next frame by rounding alone (`advance_to(2.4)` with the
            // frame at 24 × 0.1 = 2.4000000000000004) is that frame's time: the step ended at
            // `t_end`, 1 ulp before the frame a run to the horizon steps to, and the steps
            // after it differed from that run's in their last bits.
            let t_end = if t_end < output && self.stepping.reached(t_end, output) {
                output
            } else {
                t_end
            };
            // A `t_end` past the frame by more than rounding but less than the shortest span
            // is where that frame is taken: the step after the frame would be too short to
            // certify.
            let merged = output < t_end
                && !self.stepping.reached(output, t_end)
                && t_end - output < self.shortest_span();
            let (stop, at_frame) = if merged {
                (t_end, true)
            } else {
                let stop = output.min(t_end);
                (stop, stop == output)
            };
            let seen = self.exit_log.len();
            match self.step_towards(stop, at_frame)? {
                Some(report) => {
                    // The step is taken: its exits and entries are told even when the
                    // observer stops the run at the step (an interrupt), or a file would
                    // hold people gone from its frames with no exit, or present with no
                    // entry.
                    let told = observer.step(&report);
                    for record in &self.exit_log[seen..] {
                        observer.exit(record).map_err(CrowdError::Observer)?;
                    }
                    for record in self.events.entered() {
                        observer.enter(record).map_err(CrowdError::Observer)?;
                    }
                    told.map_err(CrowdError::Observer)?;
                    return Ok(Some(report));
                }
                None => {
                    // The frame is due when the step reached its time, or `t_end` reached it
                    // by rounding (`advance_to(0.6)` with 6 × 0.1 = 0.6000000000000001: the
                    // frame came one call late).
                    if at_frame || self.stepping.reached(self.t, output) {
                        observer
                            .frame(&self.frame())
                            .map_err(CrowdError::Observer)?;
                        self.frames += 1;
                    }
                    if stop == t_end {
                        return Ok(None);
                    }
                }
            }
        }
    }

    /// Runs to the scene's horizon: [`advance_to`](Self::advance_to)`(horizon, observer)`.
    pub fn run<O: Observer + ?Sized>(&mut self, observer: &mut O) -> Result<(), CrowdError> {
        self.advance_to(self.scene.time.horizon, observer)
    }

    /// Records who passed an exit or reached a target in the last step, and removes those
    /// who leave.
    fn apply_exits(&mut self) {
        let mut leaving = false;
        for i in 0..self.people.len() {
            let p = self.people.position(i);
            let r = self.people.radii()[i];
            match self.people.places()[i] {
                Place::ToExit(e) if self.exits.exits[e as usize].reached(p, r) => {
                    let exit = &self.exits.exits[e as usize];
                    self.exit_log.push(ExitRecord {
                        id: self.people.ids()[i],
                        exit: e,
                        t: self.t,
                    });
                    match (exit.action, &exit.target) {
                        (ExitAction::Continue, Some(_)) => {
                            self.people.set_place(i, Place::ToTarget(e))
                        }
                        _ => {
                            if !leaving {
                                leaving = true;
                                self.keep.clear();
                                self.keep.resize(self.people.len(), true);
                            }
                            self.keep[i] = false;
                        }
                    }
                }
                Place::ToTarget(e)
                    if self.exits.exits[e as usize]
                        .target
                        .as_ref()
                        .is_some_and(|t| t.contains(p)) =>
                {
                    self.people.set_place(i, Place::Arrived(e));
                }
                _ => {}
            }
        }
        if leaving {
            self.people.retain(&self.keep);
        }
    }

    /// Everything the next step depends on, as a value ([`SimState`]).
    pub fn state(&self) -> SimState {
        SimState {
            format: SimState::FORMAT,
            scene_hash: SimState::hash_scene(&self.scene),
            time: self.t,
            steps: self.steps,
            frames: self.frames,
            people: self.people.clone(),
            exits: self.exit_log.clone(),
            exits_open: self.exits.exits.iter().map(|x| x.open).collect(),
            inflow: self.events.state(),
            speed_factor: self.speed_factor,
            moving: self.moving.drives().to_vec(),
            fields_built: self.fields_built.clone(),
            fields_due: self.fields_due,
            stepping: self.stepping.state(),
            multipliers: self.scheme.correction().warm_start().to_vec(),
            solver_memory: self.scheme.correction().solver().memory(),
        }
    }

    /// Continues from `state`, saved from a simulation of the same scene: what follows is
    /// what would have followed the save, bit for bit. A state of another scene or format is
    /// refused, and nothing changes.
    pub fn restore(&mut self, state: &SimState) -> Result<(), CrowdError> {
        let refuse = |field: &str, value: String, reason: String| {
            Err(CrowdError::invalid(format!("state.{field}"), value, reason))
        };
        if state.format != SimState::FORMAT {
            return refuse(
                "format",
                state.format.to_string(),
                format!("this build reads format {}", SimState::FORMAT),
            );
        }
        let hash = SimState::hash_scene(&self.scene);
        if state.scene_hash != hash
            && state.scene_hash != SimState::hash_scene_with_threads(&self.scene)
        {
            return refuse(
                "scene_hash",
                format!("{:016x}", state.scene_hash),
                format!("saved from another scene (this one hashes to {hash:016x})"),
            );
        }
        if let Err(why) = state.people.check() {
            return refuse("people", format!("{} people", state.people.len()), why);
        }
        let exits = self.exits.exits.len();
        if let Some(place) = state.people.places().iter().find(|p| {
            let (Place::ToExit(e) | Place::ToTarget(e) | Place::Arrived(e)) = **p;
            e as usize >= exits
        }) {
            return refuse(
                "people",
                format!("{place:?}"),
                format!("the scene has {exits} exits"),
            );
        }
        if state.exits_open.len() != self.exits.exits.len() {
            return refuse(
                "exits_open",
                format!("{:?}", state.exits_open),
                format!("the scene has {} exits", self.exits.exits.len()),
            );
        }
        if state.moving.len() != self.moving.names().len() {
            return refuse(
                "moving",
                format!("{} drives", state.moving.len()),
                format!("the scene has {} moving bodies", self.moving.names().len()),
            );
        }
        if let Err((field, value, reason)) = self.events.check(&state.inflow, &state.people) {
            return refuse(field, value, reason);
        }
        if !(state.time.is_finite() && state.time >= 0.0) {
            return refuse(
                "time",
                Num(state.time).to_string(),
                "must be finite and ≥ 0 (a run starts at 0)".into(),
            );
        }
        if !(state.speed_factor.is_finite() && state.speed_factor >= 0.0) {
            return refuse(
                "speed_factor",
                Num(state.speed_factor).to_string(),
                "must be finite and ≥ 0".into(),
            );
        }
        let mut stepping = self.stepping.clone();
        stepping.restore(&state.stepping)?;
        self.stepping = stepping;
        self.t = state.time;
        self.steps = state.steps;
        self.frames = state.frames;
        self.people = state.people.clone();
        self.exit_log = state.exits.clone();
        for (x, &open) in self.exits.exits.iter_mut().zip(&state.exits_open) {
            x.open = open;
        }
        self.rebuild_walls();
        self.moving.set_drives(&state.moving);
        if let Some(built) = state
            .fields_built
            .clone()
            .filter(|_| self.fields_built.is_some())
        {
            self.build_fields_with(built);
        }
        self.fields_due = state.fields_due;
        self.moving.segments_at(self.t, &mut self.moving_now);
        for x in &mut self.exits.exits {
            x.update_passage(&self.moving_now);
        }
        self.events.restore(&state.inflow);
        self.speed_factor = state.speed_factor;
        self.scheme
            .correction_mut()
            .set_warm_start(&state.multipliers);
        self.scheme
            .correction_mut()
            .solver_mut()
            .set_memory(&state.solver_memory);
        Ok(())
    }
}

/// Whether the grid cell centred at `p` is walkable with the moving bodies at keyframe
/// parameters `params`: in the scene's area, outside every closed moving body, and not
/// crossed by a moving segment (`segments`, where the bodies are then: within half a cell
/// diagonal).
fn walkable_with<'a>(
    scene: &'a Scene,
    moving: &'a MovingBodies,
    segments: &'a [Segment],
    params: &'a [f64],
) -> impl Fn([f64; 2]) -> bool + 'a {
    let reach = 0.5 * std::f64::consts::SQRT_2 * scene.solver.grid_cell;
    move |p| {
        scene.walkable(p)
            && !moving.inside_with(params, p)
            && segments.iter().all(|s| s.distance(p) > reach)
    }
}
