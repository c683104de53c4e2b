//! The model behind the FMU: a crowd scene stepped by the catching-up scheme between
//! communication points, its variables, parameters, inputs and outputs. No FMI here.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use moreau_core::{Num, StepReport};
use moreau_crowd::{Observer, ObserverError, Scene, SimState, Simulation, ToleranceWarning};
use serde::{Deserialize, Serialize};

use crate::FmuError;

/// The type of a variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Float64 (FMI 2 Real).
    Real,
    /// Int32 (FMI 2 Integer).
    Integer,
    /// Boolean.
    Boolean,
    /// String.
    String,
    /// UInt64 (FMI 3 only).
    UInt64,
    /// Float64 array (FMI 3 only).
    RealArray,
}

/// The role of a variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Causality {
    /// Sizes arrays (FMI 3): set in configuration mode (or, as fmpy does, when instantiated).
    StructuralParameter,
    /// Set before initialization.
    Parameter,
    /// Set at any communication point.
    Input,
    /// Computed.
    Output,
}

/// One model variable.
#[derive(Debug, Clone, Copy)]
pub struct Variable {
    /// Value reference.
    pub vr: u32,
    /// Name in the model description.
    pub name: &'static str,
    /// Type.
    pub kind: Kind,
    /// Role.
    pub causality: Causality,
}

/// Value references.
pub mod vr {
    /// `time`, the independent variable (FMI 3 declares it): read, never set.
    pub const TIME: u32 = 0;
    /// The scene file (empty: the room shipped in `resources/`).
    pub const SCENE: u32 = 1;
    /// People in the scene: the first dimension of the FMI 3 arrays (a structural parameter).
    pub const N_PEOPLE: u32 = 5;
    /// The internal step (s); 0: the scene's.
    pub const STEP: u32 = 2;
    /// κ in ε_k = κ μ³; 0: the scene's.
    pub const EPS_KAPPA: u32 = 3;
    /// A factor on every desired speed, fixed for the run.
    pub const DESIRED_SPEED_FACTOR: u32 = 4;
    /// A factor on every desired speed, over time.
    pub const SPEED_FACTOR: u32 = 10;
    /// Whether the first exit is open.
    pub const DOOR_OPEN: u32 = 11;
    /// People who have not passed an exit.
    pub const PEOPLE_INSIDE: u32 = 20;
    /// People who have passed an exit.
    pub const PEOPLE_EVACUATED: u32 = 21;
    /// Mean speed over the last communication step (m/s).
    pub const MEAN_SPEED: u32 = 22;
    /// Smallest gap between people or to a wall (m).
    pub const MIN_GAP: u32 = 23;
    /// Certified ε of the last internal step (m²).
    pub const EPS: u32 = 24;
    /// Internal steps taken.
    pub const INTERNAL_STEPS: u32 = 25;
    /// Positions `[nPeople][2]` by person id (FMI 3; NaN when gone).
    pub const POSITIONS: u32 = 31;
    /// Radii `[nPeople]` (FMI 3).
    pub const RADII: u32 = 32;
    /// The position of the scene's moving body `b` (its keyframe parameter) is the input
    /// `MOVING + b`, named `moving.<name>`, for the bodies in the order the scene lists them
    /// (see [`moving_body`](super::moving_body)).
    pub const MOVING: u32 = 1000;
    /// Whether the scene's exit `k` is open is the Boolean input `EXIT_OPEN + k`, named
    /// `exit_open.<name>`, for the exits in the order the scene lists them; exit 0's is
    /// `door_open` under another name (see [`exit_input`](super::exit_input)).
    pub const EXIT_OPEN: u32 = 2000;
    /// How many people passed the scene's exit `k` is the Integer output `EXIT_PASSED + k`,
    /// named `passed.<name>` (see [`exit_output`](super::exit_output)).
    pub const EXIT_PASSED: u32 = 3000;
    /// The end of the exits' outputs' range.
    pub const EXIT_END: u32 = 4000;
}

/// The moving body whose position input has value reference `vr` (`vr::MOVING + b`), if `vr`
/// is in that range; whether the scene has body `b` is the model's to say.
pub fn moving_body(vr: u32) -> Option<usize> {
    (vr::MOVING..vr::EXIT_OPEN)
        .contains(&vr)
        .then(|| (vr - vr::MOVING) as usize)
}

/// The exit whose input `exit_open.<name>` has value reference `vr` (`vr::EXIT_OPEN + k`), if
/// `vr` is in that range; whether the scene has exit `k` is the model's to say.
pub fn exit_input(vr: u32) -> Option<usize> {
    (vr::EXIT_OPEN..vr::EXIT_PASSED)
        .contains(&vr)
        .then(|| (vr - vr::EXIT_OPEN) as usize)
}

/// The exit whose output `passed.<name>` has value reference `vr` (`vr::EXIT_PASSED + k`).
pub fn exit_output(vr: u32) -> Option<usize> {
    (vr::EXIT_PASSED..vr::EXIT_END)
        .contains(&vr)
        .then(|| (vr - vr::EXIT_PASSED) as usize)
}

/// The name of the position input of the moving body `name`.
pub fn moving_name(name: &str) -> String {
    format!("moving.{name}")
}

/// Every variable, in the order of the model descriptions.
pub const VARIABLES: &[Variable] = &[
    Variable {
        vr: vr::SCENE,
        name: "scene",
        kind: Kind::String,
        causality: Causality::Parameter,
    },
    Variable {
        vr: vr::N_PEOPLE,
        name: "n_people",
        kind: Kind::UInt64,
        causality: Causality::StructuralParameter,
    },
    Variable {
        vr: vr::STEP,
        name: "step",
        kind: Kind::Real,
        causality: Causality::Parameter,
    },
    Variable {
        vr: vr::EPS_KAPPA,
        name: "eps_kappa",
        kind: Kind::Real,
        causality: Causality::Parameter,
    },
    Variable {
        vr: vr::DESIRED_SPEED_FACTOR,
        name: "desired_speed_factor",
        kind: Kind::Real,
        causality: Causality::Parameter,
    },
    Variable {
        vr: vr::SPEED_FACTOR,
        name: "speed_factor",
        kind: Kind::Real,
        causality: Causality::Input,
    },
    Variable {
        vr: vr::DOOR_OPEN,
        name: "door_open",
        kind: Kind::Boolean,
        causality: Causality::Input,
    },
    Variable {
        vr: vr::PEOPLE_INSIDE,
        name: "people_inside",
        kind: Kind::Integer,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::PEOPLE_EVACUATED,
        name: "people_evacuated",
        kind: Kind::Integer,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::MEAN_SPEED,
        name: "mean_speed",
        kind: Kind::Real,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::MIN_GAP,
        name: "min_gap",
        kind: Kind::Real,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::EPS,
        name: "eps",
        kind: Kind::Real,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::INTERNAL_STEPS,
        name: "internal_steps",
        kind: Kind::Integer,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::POSITIONS,
        name: "positions",
        kind: Kind::RealArray,
        causality: Causality::Output,
    },
    Variable {
        vr: vr::RADII,
        name: "radii",
        kind: Kind::RealArray,
        causality: Causality::Output,
    },
];

/// The variable with value reference `vr`.
pub fn variable(vr: u32) -> Option<&'static Variable> {
    VARIABLES.iter().find(|v| v.vr == vr)
}

/// Parameters and inputs, as the master set them.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// `scene`.
    pub scene: String,
    /// `n_people` when the master set it (a check: it must be the scene's count).
    pub people: Option<u64>,
    /// `step`.
    pub step: f64,
    /// `eps_kappa`.
    pub eps_kappa: f64,
    /// `desired_speed_factor`.
    pub desired_speed_factor: f64,
    /// `speed_factor`.
    pub speed_factor: f64,
    /// `door_open` (also `exit_open.<name of exit 0>`).
    pub door_open: bool,
    /// `exit_open.<name>` of the exits after the first, as the master set them, by exit (the
    /// others are as the scene has them: open).
    pub exits_open: BTreeMap<usize, bool>,
    /// `moving.<name>`: the positions (keyframe parameters) the master set, by body; a body
    /// not in it is held at its start value, its first keyframe's time.
    pub moving: BTreeMap<usize, f64>,
    /// The start time the master set up (not a variable).
    pub start_time: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            scene: String::new(),
            people: None,
            step: 0.0,
            eps_kappa: 0.0,
            desired_speed_factor: 1.0,
            speed_factor: 1.0,
            door_open: true,
            exits_open: BTreeMap::new(),
            moving: BTreeMap::new(),
            start_time: 0.0,
        }
    }
}

/// The scene the FMU runs when the `scene` parameter is empty: the room, in the FMU built for
/// it (see [`default_scene`]).
pub const DEFAULT_SCENE: &str = "room-150.toml";

/// The scene file the FMU runs when the `scene` parameter is empty: `resources/room-150.toml`
/// when it is there (the room's FMU), else the one scene file (`*.toml`) in `resources/` (an
/// FMU that `fmu/package.py --scene` built for its scene).
pub fn default_scene(resources: &Path) -> Result<PathBuf, FmuError> {
    let room = resources.join(DEFAULT_SCENE);
    if room.is_file() {
        return Ok(room);
    }
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(resources)
        .map_err(|e| {
            FmuError::Setting(format!(
                "scene: empty, and the resources {} cannot be read ({e})",
                resources.display()
            ))
        })?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml") && p.is_file())
        .collect();
    scenes.sort();
    match scenes.as_slice() {
        [one] => Ok(one.clone()),
        _ => Err(FmuError::Setting(format!(
            "scene: empty, and the resources {} hold {} scene files but no {DEFAULT_SCENE} (one \
             is the default; set scene to choose)",
            resources.display(),
            scenes.len()
        ))),
    }
}

/// Refuses a scene (the `scene` parameter, at `path`) that does not have the exits and moving
/// bodies the FMU declares variables for: an FMU that `fmu/package.py --scene` built declares
/// `exit_open.<name>`, `passed.<name>` and `moving.<name>` for its default scene's (the one
/// scene file in `resources/`), by index, so another scene would answer them under the wrong
/// names. The room's FMU declares none and runs any scene.
fn check_declared(scene: &Scene, path: &Path, resources: &Path) -> Result<(), FmuError> {
    let Ok(built) = default_scene(resources) else {
        return Ok(());
    };
    if built.file_name().is_some_and(|f| f == DEFAULT_SCENE) {
        return Ok(());
    }
    let declared = Scene::from_file(&built)?;
    let names = |s: &Scene| {
        (
            s.exits.iter().map(|e| e.name.clone()).collect::<Vec<_>>(),
            s.moving.iter().map(|b| b.name.clone()).collect::<Vec<_>>(),
        )
    };
    let (exits, bodies) = names(scene);
    let (want_exits, want_bodies) = names(&declared);
    let mut differ = Vec::new();
    if exits != want_exits {
        differ.push(format!(
            "its exits are {exits:?}, the FMU declares exit_open/passed for {want_exits:?}"
        ));
    }
    if bodies != want_bodies {
        differ.push(format!(
            "its moving bodies are {bodies:?}, the FMU declares moving for {want_bodies:?}"
        ));
    }
    if differ.is_empty() {
        return Ok(());
    }
    Err(FmuError::Setting(format!(
        "scene = {}: {} (the variables of resources/{}, the scene this FMU was built for); \
         build the FMU of this scene with fmu/package.py --scene",
        path.display(),
        differ.join("; "),
        built
            .file_name()
            .map_or_else(String::new, |f| f.to_string_lossy().into_owned()),
    )))
}

/// The position input of one moving body: the body's keyframe parameter, between its first
/// and last keyframe times.
#[derive(Debug, Clone, PartialEq)]
pub struct MovingInput {
    /// The variable's name, `moving.<name>`.
    pub name: String,
    /// The first keyframe's time: the start value (the body where the scene puts it at the
    /// start, since keyframe times are ≥ 0 and a pose is held before the first) and the least
    /// value.
    pub min: f64,
    /// The last keyframe's time: the largest value.
    pub max: f64,
}

impl MovingInput {
    /// The start value: the first keyframe's time.
    pub fn start(&self) -> f64 {
        self.min
    }

    /// Why `value` is no position of this body, if it is not.
    pub fn refuse(&self, value: f64) -> Option<String> {
        if !value.is_finite() {
            Some("not a finite number".into())
        } else if !(self.min..=self.max).contains(&value) {
            Some(format!(
                "outside the body's keyframe times [{}, {}]",
                Num(self.min),
                Num(self.max)
            ))
        } else {
            None
        }
    }
}

/// A crowd stepped between communication points.
#[derive(Debug)]
pub struct CrowdModel {
    sim: Simulation,
    time: f64,
    eps: f64,
    mean_speed: f64,
    min_gap: Option<f64>,
    people: usize,
    /// The position inputs of the moving bodies, in the scene's order.
    moving: Vec<MovingInput>,
    /// Where each body is driven to at the end of the next communication step.
    targets: Vec<f64>,
    before: Vec<f64>,
    after: Vec<f64>,
    /// The one warning that adaptive steps miss `time.tol`.
    unmet: ToleranceWarning,
    /// What to log after this communication step, if anything.
    warning: Option<String>,
}

/// Everything a [`CrowdModel`] answers from besides its scene: the simulation's state and the
/// outputs it keeps between communication points, so that a restored model reports exactly
/// what the model it was saved from reported, and goes on exactly as it would have.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelState {
    /// The simulation (time, people, exits, step controller, warm start, step count).
    pub sim: SimState,
    /// The last communication point reached.
    pub time: f64,
    /// Certified ε of the last internal step.
    pub eps: f64,
    /// Mean speed over the last communication step.
    pub mean_speed: f64,
    /// The smallest gap, once computed for this configuration.
    pub min_gap: Option<f64>,
}

/// The most internal steps one communication step may take (about a minute of work for a
/// small scene); a longer one is refused before it starts.
pub const MAX_INTERNAL_STEPS: f64 = 1e6;

/// Keeps the certified ε of the last step, and the first step's word of an adaptive step
/// accepted above `time.tol` ([`ToleranceWarning`]).
struct StepWatch<'a> {
    eps: &'a mut f64,
    unmet: &'a mut ToleranceWarning,
    said: Option<String>,
}

impl Observer for StepWatch<'_> {
    fn step(&mut self, report: &StepReport) -> Result<(), ObserverError> {
        *self.eps = report.eps;
        if let Some(message) = self.unmet.first(report) {
            self.said = Some(message);
        }
        Ok(())
    }
}

impl CrowdModel {
    /// Loads the scene (`settings.scene`, or the default in `resources`), applies the
    /// parameters, and places the people.
    pub fn new(settings: &Settings, resources: Option<&Path>) -> Result<Self, FmuError> {
        let path: PathBuf = if settings.scene.is_empty() {
            let dir = resources.ok_or_else(|| {
                FmuError::Setting("scene: empty, and the FMU was given no resource location".into())
            })?;
            default_scene(dir)?
        } else {
            PathBuf::from(&settings.scene)
        };
        let mut scene = Scene::from_file(&path)?;
        if !settings.scene.is_empty()
            && let Some(dir) = resources
        {
            check_declared(&scene, &path, dir)?;
        }
        if settings.step != 0.0 {
            scene.time.step = settings.step;
        }
        if settings.eps_kappa != 0.0 {
            scene.solver.eps_kappa = settings.eps_kappa;
        }
        let check = |name: &str, x: f64| {
            if x > 0.0 && x.is_finite() {
                Ok(())
            } else {
                Err(FmuError::Setting(format!(
                    "{name} = {}: must be finite and > 0",
                    Num(x)
                )))
            }
        };
        check("step", scene.time.step)?;
        check("eps_kappa", scene.solver.eps_kappa)?;
        if !(settings.desired_speed_factor >= 0.0 && settings.desired_speed_factor.is_finite()) {
            return Err(FmuError::Setting(format!(
                "desired_speed_factor = {}: must be finite and ≥ 0",
                Num(settings.desired_speed_factor)
            )));
        }
        let sim = Simulation::new(scene)?;
        let people = sim.total_people();
        if let Some(n) = settings.people.filter(|&n| n != people as u64) {
            return Err(FmuError::Setting(format!(
                "n_people = {n}: the scene {} has {people} people (leave n_people unset to take the scene's)",
                path.display()
            )));
        }
        let moving: Vec<MovingInput> = sim
            .scene()
            .moving
            .iter()
            .map(|body| MovingInput {
                name: moving_name(&body.name),
                min: body.keyframes.first().map_or(0.0, |k| k.t),
                max: body.keyframes.last().map_or(0.0, |k| k.t),
            })
            .collect();
        let targets = moving.iter().map(MovingInput::start).collect();
        let unmet = ToleranceWarning::new(&sim.scene().time);
        let mut model = Self {
            sim,
            time: settings.start_time,
            eps: 0.0,
            mean_speed: 0.0,
            min_gap: None,
            people,
            moving,
            targets,
            before: Vec::new(),
            after: Vec::new(),
            unmet,
            warning: None,
        };
        model.apply(settings)?;
        Ok(model)
    }

    /// People at the start (the size of the array outputs).
    pub fn people(&self) -> usize {
        self.people
    }

    /// The model's time.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Moves the model's clock to the start time the host gave (before any step).
    pub fn set_start_time(&mut self, t: f64) {
        self.time = t;
    }

    /// The position inputs of the scene's moving bodies, in the scene's order (body `b`'s at
    /// value reference `vr::MOVING + b`).
    pub fn moving(&self) -> &[MovingInput] {
        &self.moving
    }

    /// The names of the scene's exits, in the scene's order (exit `k`'s input at value
    /// reference `vr::EXIT_OPEN + k`, its output at `vr::EXIT_PASSED + k`).
    pub fn exits(&self) -> impl ExactSizeIterator<Item = &str> {
        self.sim.scene().exits.iter().map(|e| e.name.as_str())
    }

    /// People who passed exit `k` so far.
    pub fn passed(&self, k: usize) -> i32 {
        let records = self.sim.exit_records();
        records.iter().filter(|r| r.exit as usize == k).count() as i32
    }

    /// Where moving body `b` is now: its keyframe parameter at the model's time (the input's
    /// value set before the last communication step, or the start value).
    pub fn moving_position(&self, b: usize) -> f64 {
        self.sim.moving().param(b, self.sim.time())
    }

    /// The simulation the model steps (read only: the FMU translates, the simulation runs).
    pub fn simulation(&self) -> &Simulation {
        &self.sim
    }

    /// The hash of the scene the model runs (with the `step` and `eps_kappa` it was built
    /// with): a saved state restores only into a model of the same hash.
    pub fn scene_hash(&self) -> u64 {
        SimState::hash_scene(self.sim.scene())
    }

    /// The model's state (see [`ModelState`]).
    pub fn save(&self) -> ModelState {
        ModelState {
            sim: self.sim.state(),
            time: self.time,
            eps: self.eps,
            mean_speed: self.mean_speed,
            min_gap: self.min_gap,
        }
    }

    /// Goes back to `state`, saved from a model of the same scene; refused (and nothing
    /// changes) for another scene or format.
    pub fn load(&mut self, state: &ModelState) -> Result<(), FmuError> {
        if !state.time.is_finite() {
            return Err(FmuError::Setting(format!(
                "state.time = {}: not a finite number",
                Num(state.time)
            )));
        }
        self.sim.restore(&state.sim)?;
        self.time = state.time;
        self.eps = state.eps;
        self.mean_speed = state.mean_speed;
        self.min_gap = state.min_gap;
        Ok(())
    }

    /// Applies the inputs (and the fixed speed factor).
    pub fn apply(&mut self, settings: &Settings) -> Result<(), FmuError> {
        let factor = settings.desired_speed_factor * settings.speed_factor;
        if !(factor >= 0.0 && factor.is_finite()) {
            return Err(FmuError::Setting(format!(
                "speed_factor = {}: the desired-speed factor must be finite and ≥ 0",
                Num(settings.speed_factor)
            )));
        }
        let mut targets: Vec<f64> = self.moving.iter().map(MovingInput::start).collect();
        for (&b, &value) in &settings.moving {
            let input = self.moving.get(b).ok_or_else(|| {
                FmuError::Setting(format!(
                    "value reference {} set to {}: the scene has {} moving bodies",
                    vr::MOVING as usize + b,
                    Num(value),
                    self.moving.len()
                ))
            })?;
            if let Some(why) = input.refuse(value) {
                return Err(FmuError::Setting(format!(
                    "{} = {}: {why}",
                    input.name,
                    Num(value)
                )));
            }
            targets[b] = value;
        }
        if let Some((&k, _)) = settings
            .exits_open
            .range(self.sim.scene().exits.len()..)
            .next()
        {
            return Err(FmuError::Setting(format!(
                "value reference {} set: the scene has {} exits",
                vr::EXIT_OPEN as usize + k,
                self.sim.scene().exits.len()
            )));
        }
        self.sim.set_speed_factor(factor);
        if self.sim.exit_open(0).is_some() {
            self.sim.set_exit_open(0, settings.door_open)?;
        }
        for (&k, &open) in &settings.exits_open {
            self.sim.set_exit_open(k, open)?;
        }
        self.targets = targets;
        self.min_gap = None;
        Ok(())
    }

    /// Steps from `t` to `t + h` as the native driver steps (the scene's fixed step, the last
    /// one before each output time or communication point shortened, or adaptive steps when
    /// the scene sets `time.tol`), so that communication steps that are multiples of the step
    /// give the internal steps of a native run.
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<(), FmuError> {
        // Rounding only (a host's sum of its steps drifts from ours by ~10⁻¹² |t|), and never
        // 1 % of a step: 10⁻⁹ |t| alone let a host at t = 1.7·10⁹ s skip 1.5 s unnoticed.
        let step = self.sim.stepping().largest_step();
        if (t - self.time).abs() > (1e-9 * t.abs().max(1.0)).min(0.01 * step) {
            return Err(FmuError::Setting(format!(
                "currentCommunicationPoint = {}, but the model is at t = {}",
                Num(t),
                Num(self.time)
            )));
        }
        // Bounded work: a communication step the scene's steps cannot cover in reasonable
        // work is refused before any step is taken (the host would wait forever).
        let time = self.sim.scene().time;
        let largest = match time.tol {
            None => time.step.min(time.output_interval),
            Some(_) => time.output_interval.min(0.5),
        };
        let steps = h / largest;
        if !(steps <= MAX_INTERNAL_STEPS) {
            return Err(FmuError::Setting(format!(
                "communicationStepSize = {}: it takes {steps:.3e} internal steps of at most {} s, \
                 more than the limit of {MAX_INTERNAL_STEPS:e} a communication step (use \
                 shorter communication steps)",
                Num(h),
                Num(largest)
            )));
        }
        // By id over everyone so far: people from sources count too (sized by the people at
        // the start, they were left out of the mean speed).
        self.before.resize(2 * self.sim.total_people(), 0.0);
        self.sim.frame().positions_by_id(&mut self.before);
        self.min_gap = None;
        // The moving bodies follow their inputs, not the clock: each goes linearly from where
        // it is to its input's value at the end of this communication step (the FMU
        // translates the input into a drive; the simulation moves the body). A body is driven
        // at the first step (never driven, it would follow its keyframes in time) and then
        // only when its input moved: a drive to where the body already is would hold it just
        // the same, but would replace the drive that last moved it, and the simulation tells
        // from that one whether the body moved since it last solved the distance fields
        // around the bodies (`model.field_update`).
        let t_end = self.sim.time() + h;
        for (b, &target) in self.targets.iter().enumerate() {
            let bodies = self.sim.moving();
            if bodies.drives()[b].is_none() || bodies.param(b, self.sim.time()) != target {
                self.sim.drive_moving(b, target, t_end)?;
            }
        }
        let mut watch = StepWatch {
            eps: &mut self.eps,
            unmet: &mut self.unmet,
            said: None,
        };
        self.sim.advance_to(t_end, &mut watch)?;
        if watch.said.is_some() {
            self.warning = watch.said;
        }
        self.time = t + h;
        // Mean speed of the people present before and after the communication step.
        self.after.resize(2 * self.sim.total_people(), 0.0);
        self.sim.frame().positions_by_id(&mut self.after);
        let (mut sum, mut count) = (0.0, 0usize);
        for (b, a) in self.before.chunks_exact(2).zip(self.after.chunks_exact(2)) {
            if b[0].is_finite() && a[0].is_finite() {
                sum += ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
                count += 1;
            }
        }
        self.mean_speed = if count > 0 {
            sum / count as f64 / h
        } else {
            0.0
        };
        Ok(())
    }

    /// What the last communication step has to tell the host, once: an adaptive step
    /// accepted above `time.tol` (the run goes on at the smallest step).
    pub fn take_warning(&mut self) -> Option<String> {
        self.warning.take()
    }

    /// A Real output (the smallest gap is computed once per configuration, at its first read).
    pub fn real(&mut self, vr: u32) -> Option<f64> {
        Some(match vr {
            vr::MEAN_SPEED => self.mean_speed,
            vr::MIN_GAP => {
                let sim = &mut self.sim;
                let gap = *self.min_gap.get_or_insert_with(|| sim.min_gap(1.0));
                if gap.is_finite() { gap } else { 1.0 }
            }
            vr::EPS => self.eps,
            _ => return None,
        })
    }

    /// An Integer output.
    pub fn integer(&self, vr: u32) -> Option<i32> {
        let passed = self.sim.exit_records().len();
        Some(match vr {
            // Everyone so far less those out: the people at the start less those out went
            // negative (and wrapped) once people from sources had left.
            vr::PEOPLE_INSIDE => self.sim.total_people().saturating_sub(passed) as i32,
            vr::PEOPLE_EVACUATED => passed as i32,
            vr::INTERNAL_STEPS => self.sim.steps() as i32,
            _ => return None,
        })
    }

    /// Positions `[x0, y0, x1, y1, ...]` by person id (NaN when gone) into `out`.
    pub fn positions(&self, out: &mut [f64]) {
        self.sim.frame().positions_by_id(out);
    }

    /// Radii by person id (NaN when gone) into `out`.
    pub fn radii(&self, out: &mut [f64]) {
        self.sim.frame().radii_by_id(out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The room, with its scene file rewritten into a scratch directory (one per name,
    /// emptied first: nothing piles up in the temporary directory).
    fn model(edit: impl Fn(&mut Scene), name: &str) -> CrowdModel {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/scenes/room-150.toml");
        let mut scene = Scene::from_file(root).unwrap();
        edit(&mut scene);
        let dir = std::env::temp_dir().join(format!("moreau-fmu-test-{name}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("scene.toml");
        std::fs::write(&path, scene.to_toml()).unwrap();
        let settings = Settings {
            scene: path.display().to_string(),
            ..Settings::default()
        };
        CrowdModel::new(&settings, None).unwrap()
    }

    #[test]
    fn the_fmu_steps_adaptively_when_its_scene_asks_for_it() {
        let mut fixed = model(|_| {}, "fixed");
        fixed.do_step(0.0, 1.0).unwrap();
        assert_eq!(
            fixed.integer(vr::INTERNAL_STEPS),
            Some(20),
            "1 s of 0.05 s steps"
        );
        let mut adaptive = model(|s| s.time.tol = Some(0.05), "adaptive");
        adaptive.do_step(0.0, 1.0).unwrap();
        let steps = adaptive.integer(vr::INTERNAL_STEPS).unwrap();
        // Free flow at the start: the controller grows the step up to the output interval.
        assert!((10..20).contains(&steps), "{steps} adaptive steps in 1 s");
        assert!((adaptive.time() - 1.0).abs() < 1e-12);
        let eps = adaptive.real(vr::EPS).unwrap();
        assert!(eps >= 0.0 && eps.is_finite());
    }
}
