//! The small generic runtime under both FMI layers: an instance, its state machine, its
//! settings, logging, stepping the model to the communication point, and its FMU states
//! (taking and restoring a [`Snapshot`]).

use std::path::PathBuf;

use moreau_core::Num;
use serde::{Deserialize, Serialize};

use crate::FmuError;
use crate::model::{
    Causality, CrowdModel, Kind, Settings, exit_input, exit_output, moving_body, variable, vr,
};
use crate::snapshot::Snapshot;

/// What the runtime checks a value reference against: the variable's name, type and role. The
/// model's variables are fixed ([`crate::model::VARIABLES`]); the moving bodies' position
/// inputs (`moving.<name>`, Real inputs) and the exits' inputs and outputs
/// (`exit_open.<name>`, Boolean; `passed.<name>`, Integer) are the scene's.
#[derive(Debug, Clone)]
struct Described {
    name: String,
    kind: Kind,
    causality: Causality,
    /// Whose variable it is, for the scene's.
    of: Option<SceneVariable>,
}

/// A variable of the scene's, by what it belongs to.
#[derive(Debug, Clone, Copy)]
enum SceneVariable {
    /// The position input of moving body `b`.
    Body(usize),
    /// Whether exit `k` is open.
    ExitOpen(usize),
    /// How many passed exit `k`.
    Passed(usize),
}

/// The states of a co-simulation instance (FMI 2 names in brackets).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum State {
    /// After instantiation: parameters may be set.
    Instantiated,
    /// FMI 3 configuration mode: structural parameters may be set.
    Configuration,
    /// Initialization mode.
    Initialization,
    /// Stepping (slaveInitialized / stepMode).
    Stepping,
    /// After terminate.
    Terminated,
    /// A call failed; only reset and free are allowed.
    Error,
}

/// How bad a log message is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// Information (only when logging is on).
    Info,
    /// A warning: the call succeeded, but the host should know (always logged).
    Warning,
    /// An error (always logged).
    Error,
}

/// Sends a message to the host.
pub type LogFn = Box<dyn Fn(Level, &str)>;

/// One FMU instance.
pub struct Instance {
    /// The instance name given by the host.
    pub name: String,
    /// The current state.
    pub state: State,
    /// Parameters and inputs.
    pub settings: Settings,
    /// The unpacked `resources/` directory.
    pub resources: Option<PathBuf>,
    /// Whether informational messages go to the host.
    pub logging_on: bool,
    model: Option<CrowdModel>,
    stale: bool,
    /// The stop time the master set up, if it gave one: no step may end after it.
    stop_time: Option<f64>,
    log: LogFn,
}

impl std::fmt::Debug for Instance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Instance")
            .field("name", &self.name)
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

impl Instance {
    /// Sets the start time (`fmi2SetupExperiment`, `fmi3EnterInitializationMode`, both in
    /// Instantiated, before any step). A model already built (by reading `n_people` or setting
    /// an input first) starts there too: it kept the time 0 it was built with, and the first
    /// `doStep` at the start time was refused.
    pub fn set_start_time(&mut self, t: f64) {
        self.settings.start_time = t;
        if let Some(model) = self.model.as_mut() {
            model.set_start_time(t);
        }
    }

    /// Sets the stop time (`fmi2SetupExperiment`, `fmi3EnterInitializationMode`, with
    /// `stopTimeDefined`): a step that would end after it is refused, as the standards ask
    /// (FMI 2.0 §4.2.1: "if the environment tries to compute past stopTime the FMU has to
    /// return fmi2Error"; FMI 3 alike). It was ignored. Refused itself when not a number or
    /// before the start time.
    pub fn set_stop_time(&mut self, stop: Option<f64>) -> Result<(), FmuError> {
        if let Some(stop) = stop
            && !(stop >= self.settings.start_time)
        {
            return Err(FmuError::Setting(format!(
                "stopTime = {}: before startTime = {} (or not a number)",
                Num(stop),
                Num(self.settings.start_time)
            )));
        }
        self.stop_time = stop;
        Ok(())
    }

    /// A new instance in state `Instantiated`.
    pub fn new(name: String, resources: Option<PathBuf>, logging_on: bool, log: LogFn) -> Self {
        Self {
            name,
            state: State::Instantiated,
            settings: Settings::default(),
            resources,
            logging_on,
            model: None,
            stale: true,
            stop_time: None,
            log,
        }
    }

    /// Logs an informational message (when logging is on).
    pub fn info(&self, message: &str) {
        if self.logging_on {
            (self.log)(Level::Info, message);
        }
    }

    /// Logs a warning (always).
    pub fn warning(&self, message: &str) {
        (self.log)(Level::Warning, message);
    }

    /// Logs an error (always).
    pub fn error(&self, message: &str) {
        (self.log)(Level::Error, message);
    }

    /// Fails unless the instance is in one of `allowed` states.
    pub fn expect(&self, function: &str, allowed: &'static [State]) -> Result<(), FmuError> {
        if allowed.contains(&self.state) {
            Ok(())
        } else {
            Err(FmuError::State {
                function: function.to_string(),
                state: self.state,
                allowed,
            })
        }
    }

    /// The scene the instance runs, as a user names it.
    pub fn scene_name(&self) -> String {
        if !self.settings.scene.is_empty() {
            return self.settings.scene.clone();
        }
        let file = self
            .resources
            .as_deref()
            .and_then(|dir| crate::model::default_scene(dir).ok())
            .and_then(|p| p.file_name().map(|f| f.to_string_lossy().into_owned()))
            .unwrap_or_else(|| crate::model::DEFAULT_SCENE.to_string());
        format!("resources/{file}")
    }

    /// The model, built from the settings on first use (again after a parameter changed).
    pub fn model(&mut self) -> Result<&mut CrowdModel, FmuError> {
        if self.stale || self.model.is_none() {
            self.model = Some(CrowdModel::new(&self.settings, self.resources.as_deref())?);
            self.stale = false;
            self.info("model built from the scene");
        }
        Ok(self.model.as_mut().expect("just built"))
    }

    /// The variable `vr`: one of the model's, or the position input of a moving body of the
    /// scene (the model is built to know the scene's bodies).
    fn describe(&mut self, vr: u32) -> Result<Described, FmuError> {
        if let Some(v) = variable(vr) {
            return Ok(Described {
                name: v.name.to_string(),
                kind: v.kind,
                causality: v.causality,
                of: None,
            });
        }
        if let Some((k, input)) = exit_input(vr)
            .map(|k| (k, true))
            .or_else(|| exit_output(vr).map(|k| (k, false)))
        {
            let scene = self.scene_name();
            let model = self.model()?;
            let count = model.exits().len();
            let name = model.exits().nth(k).ok_or_else(|| {
                FmuError::Setting(format!(
                    "unknown value reference {vr}: the scene {scene} has {count} exits \
                     (value references {} and up for their inputs, {} and up for their outputs)",
                    vr::EXIT_OPEN,
                    vr::EXIT_PASSED
                ))
            })?;
            return Ok(if input {
                Described {
                    name: format!("exit_open.{name}"),
                    kind: Kind::Boolean,
                    causality: Causality::Input,
                    of: Some(SceneVariable::ExitOpen(k)),
                }
            } else {
                Described {
                    name: format!("passed.{name}"),
                    kind: Kind::Integer,
                    causality: Causality::Output,
                    of: Some(SceneVariable::Passed(k)),
                }
            });
        }
        let b = moving_body(vr).ok_or(FmuError::UnknownReference(vr))?;
        let scene = self.scene_name();
        let model = self.model()?;
        let count = model.moving().len();
        let input = model.moving().get(b).ok_or_else(|| {
            FmuError::Setting(format!(
                "unknown value reference {vr}: the scene {scene} has {count} moving bodies \
                 (value references {} and up, one per body)",
                vr::MOVING
            ))
        })?;
        Ok(Described {
            name: input.name.clone(),
            kind: Kind::Real,
            causality: Causality::Input,
            of: Some(SceneVariable::Body(b)),
        })
    }

    fn settable(&mut self, vr: u32, kind: Kind) -> Result<Described, FmuError> {
        let v = self.describe(vr)?;
        if v.kind != kind {
            return Err(FmuError::WrongType { vr, name: v.name });
        }
        match (v.causality, self.state) {
            (Causality::StructuralParameter, State::Instantiated | State::Configuration) => {}
            (Causality::Parameter, State::Instantiated | State::Initialization) => {}
            (Causality::Input, State::Instantiated | State::Initialization | State::Stepping) => {}
            (Causality::Output, _) => {
                return Err(FmuError::Setting(format!(
                    "{} is an output: it cannot be set",
                    v.name
                )));
            }
            (_, state) => {
                return Err(FmuError::Setting(format!(
                    "{} cannot be set in state {state:?}",
                    v.name
                )));
            }
        }
        Ok(v)
    }

    fn changed(&mut self, causality: Causality) -> Result<(), FmuError> {
        match causality {
            Causality::Parameter | Causality::StructuralParameter => self.stale = true,
            _ => {
                if let Some(m) = self.model.as_mut().filter(|_| !self.stale) {
                    m.apply(&self.settings)?;
                }
            }
        }
        Ok(())
    }

    /// Sets a Real.
    pub fn set_real(&mut self, vr: u32, value: f64) -> Result<(), FmuError> {
        if vr == vr::TIME {
            return Err(FmuError::Setting(
                "time (value reference 0) is the independent variable: DoStep advances it, it \
                 cannot be set"
                    .into(),
            ));
        }
        let v = self.settable(vr, Kind::Real)?;
        if let Some(SceneVariable::Body(b)) = v.of {
            return self.set_moving(b, &v.name, value);
        }
        let (causality, name) = (v.causality, v.name.as_str());
        let old = *self.real_slot(vr).ok_or(FmuError::UnknownReference(vr))?;
        if !value.is_finite() {
            return Err(FmuError::Setting(format!(
                "{name} = {}: not a finite number (it keeps its value {})",
                Num(value),
                Num(old)
            )));
        }
        // Every settable Real is ≥ 0 (a step or ε factor of 0: the scene's own).
        if value < 0.0 {
            return Err(FmuError::Setting(format!(
                "{name} = {}: must be ≥ 0 (it keeps its value {})",
                Num(value),
                Num(old)
            )));
        }
        *self.real_slot(vr).expect("checked above") = value;
        // A value the model refuses is not kept either: the next step runs with the old one.
        if let Err(e) = self.changed(causality) {
            *self.real_slot(vr).expect("checked above") = old;
            let _ = self.changed(causality);
            return Err(e);
        }
        Ok(())
    }

    /// Sets the position input `name` of moving body `b`: a keyframe parameter of the body
    /// (finite, between its first and last keyframe times); a refused value is not kept.
    fn set_moving(&mut self, b: usize, name: &str, value: f64) -> Result<(), FmuError> {
        let old = self.get_moving(b)?;
        let input = self.model()?.moving()[b].clone();
        if let Some(why) = input.refuse(value) {
            return Err(FmuError::Setting(format!(
                "{name} = {}: {why} (it keeps its value {})",
                Num(value),
                Num(old)
            )));
        }
        let before = self.settings.moving.insert(b, value);
        if let Err(e) = self.changed(Causality::Input) {
            match before {
                Some(x) => self.settings.moving.insert(b, x),
                None => self.settings.moving.remove(&b),
            };
            let _ = self.changed(Causality::Input);
            return Err(e);
        }
        Ok(())
    }

    /// The position input of moving body `b`: as set, or its start value.
    fn get_moving(&mut self, b: usize) -> Result<f64, FmuError> {
        let set = self.settings.moving.get(&b).copied();
        let model = self.model()?;
        Ok(set.unwrap_or_else(|| model.moving()[b].start()))
    }

    /// The settable Real `vr`.
    fn real_slot(&mut self, vr: u32) -> Option<&mut f64> {
        Some(match vr {
            vr::STEP => &mut self.settings.step,
            vr::EPS_KAPPA => &mut self.settings.eps_kappa,
            vr::DESIRED_SPEED_FACTOR => &mut self.settings.desired_speed_factor,
            vr::SPEED_FACTOR => &mut self.settings.speed_factor,
            _ => return None,
        })
    }

    /// Sets a Boolean: `door_open`, or `exit_open.<name>` (exit 0's is `door_open`); a value
    /// the model refuses is not kept.
    pub fn set_boolean(&mut self, vr: u32, value: bool) -> Result<(), FmuError> {
        let v = self.settable(vr, Kind::Boolean)?;
        let exit = match (vr, v.of) {
            (vr::DOOR_OPEN, _) | (_, Some(SceneVariable::ExitOpen(0))) => 0,
            (_, Some(SceneVariable::ExitOpen(k))) => k,
            _ => return Err(FmuError::UnknownReference(vr)),
        };
        let before = (self.settings.door_open, self.settings.exits_open.clone());
        if exit == 0 {
            self.settings.door_open = value;
        } else {
            self.settings.exits_open.insert(exit, value);
        }
        if let Err(e) = self.changed(v.causality) {
            (self.settings.door_open, self.settings.exits_open) = before;
            let _ = self.changed(v.causality);
            return Err(e);
        }
        Ok(())
    }

    /// Sets a String.
    pub fn set_string(&mut self, vr: u32, value: &str) -> Result<(), FmuError> {
        let causality = self.settable(vr, Kind::String)?.causality;
        match vr {
            vr::SCENE => self.settings.scene = value.to_string(),
            _ => return Err(FmuError::UnknownReference(vr)),
        }
        self.changed(causality)
    }

    /// Sets an Integer: there is no Integer to set.
    pub fn set_integer(&mut self, vr: u32, _value: i32) -> Result<(), FmuError> {
        self.settable(vr, Kind::Integer).map(|_| ())
    }

    /// Sets a UInt64 (`n_people`: checked against the scene when the model is built).
    pub fn set_uint64(&mut self, vr: u32, value: u64) -> Result<(), FmuError> {
        let causality = self.settable(vr, Kind::UInt64)?.causality;
        match vr {
            vr::N_PEOPLE => self.settings.people = Some(value),
            _ => return Err(FmuError::UnknownReference(vr)),
        }
        self.changed(causality)
    }

    fn readable(&mut self, vr: u32, kind: Kind) -> Result<Described, FmuError> {
        let v = self.describe(vr)?;
        if v.kind != kind {
            return Err(FmuError::WrongType { vr, name: v.name });
        }
        if v.causality == Causality::Output
            && matches!(self.state, State::Instantiated | State::Configuration)
        {
            return Err(FmuError::Setting(format!(
                "{} is not available before initialization",
                v.name
            )));
        }
        Ok(v)
    }

    /// Gets a Real.
    pub fn get_real(&mut self, vr: u32) -> Result<f64, FmuError> {
        if vr == vr::TIME {
            // The communication point reached (the start time before the model is built).
            return Ok(self.time().unwrap_or(self.settings.start_time));
        }
        if let Some(SceneVariable::Body(b)) = self.readable(vr, Kind::Real)?.of {
            return self.get_moving(b);
        }
        Ok(match vr {
            vr::STEP => self.settings.step,
            vr::EPS_KAPPA => self.settings.eps_kappa,
            vr::DESIRED_SPEED_FACTOR => self.settings.desired_speed_factor,
            vr::SPEED_FACTOR => self.settings.speed_factor,
            other => self
                .model()?
                .real(other)
                .ok_or(FmuError::UnknownReference(other))?,
        })
    }

    /// Gets an Integer.
    pub fn get_integer(&mut self, vr: u32) -> Result<i32, FmuError> {
        if let Some(SceneVariable::Passed(k)) = self.readable(vr, Kind::Integer)?.of {
            return Ok(self.model()?.passed(k));
        }
        self.model()?
            .integer(vr)
            .ok_or(FmuError::UnknownReference(vr))
    }

    /// Gets a UInt64 (`n_people`: the scene's count).
    pub fn get_uint64(&mut self, vr: u32) -> Result<u64, FmuError> {
        self.readable(vr, Kind::UInt64)?;
        match vr {
            vr::N_PEOPLE => Ok(self.model()?.people() as u64),
            _ => Err(FmuError::UnknownReference(vr)),
        }
    }

    /// Gets a Boolean.
    pub fn get_boolean(&mut self, vr: u32) -> Result<bool, FmuError> {
        match (vr, self.readable(vr, Kind::Boolean)?.of) {
            (vr::DOOR_OPEN, _) | (_, Some(SceneVariable::ExitOpen(0))) => {
                Ok(self.settings.door_open)
            }
            (_, Some(SceneVariable::ExitOpen(k))) => {
                Ok(self.settings.exits_open.get(&k).copied().unwrap_or(true))
            }
            _ => Err(FmuError::UnknownReference(vr)),
        }
    }

    /// Gets a String.
    pub fn get_string(&mut self, vr: u32) -> Result<String, FmuError> {
        self.readable(vr, Kind::String)?;
        match vr {
            vr::SCENE => Ok(self.settings.scene.clone()),
            _ => Err(FmuError::UnknownReference(vr)),
        }
    }

    /// The length of an array output (people at the start, times 2 for positions).
    pub fn array_len(&mut self, vr: u32) -> Result<usize, FmuError> {
        self.readable(vr, Kind::RealArray)?;
        let people = self.model()?.people();
        Ok(match vr {
            vr::POSITIONS => 2 * people,
            _ => people,
        })
    }

    /// Writes an array output into `out` (of [`array_len`](Self::array_len)).
    pub fn get_array(&mut self, vr: u32, out: &mut [f64]) -> Result<(), FmuError> {
        self.readable(vr, Kind::RealArray)?;
        let model = self.model()?;
        match vr {
            vr::POSITIONS => model.positions(out),
            _ => model.radii(out),
        }
        Ok(())
    }

    /// Instantiated → Configuration (FMI 3).
    pub fn enter_configuration(&mut self) -> Result<(), FmuError> {
        self.expect("EnterConfigurationMode", &[State::Instantiated])?;
        self.state = State::Configuration;
        Ok(())
    }

    /// Configuration → Instantiated (FMI 3).
    pub fn exit_configuration(&mut self) -> Result<(), FmuError> {
        self.expect("ExitConfigurationMode", &[State::Configuration])?;
        self.state = State::Instantiated;
        Ok(())
    }

    /// Instantiated → Initialization.
    pub fn enter_initialization(&mut self) -> Result<(), FmuError> {
        self.expect("EnterInitializationMode", &[State::Instantiated])?;
        self.state = State::Initialization;
        Ok(())
    }

    /// Initialization → Stepping; builds the model if nothing asked for it yet.
    pub fn exit_initialization(&mut self) -> Result<(), FmuError> {
        self.expect("ExitInitializationMode", &[State::Initialization])?;
        self.model()?;
        self.state = State::Stepping;
        Ok(())
    }

    /// One communication step from `t` to `t + h`.
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<(), FmuError> {
        self.expect("DoStep", &[State::Stepping])?;
        if !(h > 0.0 && h.is_finite()) {
            return Err(FmuError::Setting(format!(
                "communicationStepSize = {}: must be finite and > 0",
                Num(h)
            )));
        }
        if !t.is_finite() {
            return Err(FmuError::Setting(format!(
                "currentCommunicationPoint = {}: not a finite number",
                Num(t)
            )));
        }
        // Past it by more than the Reference-FMUs' `isClose`: 10⁻⁵ s, or 10⁻⁵ of the times
        // (a host whose time grid is in single precision reaches the stop time within that;
        // fmpy within 10⁻⁹).
        let end = t + h;
        if let Some(stop) = self.stop_time
            && end > stop
            && end - stop > 1e-5 * end.abs().max(stop.abs()).max(1.0)
        {
            return Err(FmuError::Setting(format!(
                "a step from {} s of {} s ends after stopTime = {} s, which the experiment set \
                 up: refused",
                Num(t),
                Num(h),
                Num(stop)
            )));
        }
        let settings = self.settings.clone();
        let model = self.model()?;
        model.apply(&settings)?;
        model.do_step(t, h)?;
        if let Some(message) = model.take_warning() {
            self.warning(&format!("DoStep: {message}"));
        }
        Ok(())
    }

    /// The model's time (the last communication point reached), if built.
    pub fn time(&self) -> Option<f64> {
        self.model.as_ref().map(|m| m.time())
    }

    /// Stepping → Terminated.
    pub fn terminate(&mut self) -> Result<(), FmuError> {
        self.expect("Terminate", &[State::Stepping])?;
        self.state = State::Terminated;
        Ok(())
    }

    /// The FMU state: the instance's state, start time, inputs and fixed speed factor, and
    /// the model's state (the model is built first if nothing asked for it yet).
    pub fn snapshot(&mut self) -> Result<Snapshot, FmuError> {
        let model = self.model()?.save();
        Ok(Snapshot {
            state: self.state,
            start_time: self.settings.start_time,
            speed_factor: self.settings.speed_factor,
            door_open: self.settings.door_open,
            exits_open: self.settings.exits_open.clone(),
            moving: self.settings.moving.clone(),
            desired_speed_factor: self.settings.desired_speed_factor,
            model,
        })
    }

    /// Goes back to `snapshot`. The instance keeps its parameters: a snapshot of another
    /// scene (or of another `step`, `eps_kappa` or `desired_speed_factor`) is refused, and then
    /// nothing changes.
    pub fn restore(&mut self, snapshot: &Snapshot) -> Result<(), FmuError> {
        if snapshot.state == State::Error {
            return Err(FmuError::Setting(
                "FMUstate: saved in state Error; nothing to go back to".into(),
            ));
        }
        let scene = self.scene_name();
        let hash = self.model()?.scene_hash();
        if snapshot.scene_hash() != hash {
            return Err(FmuError::Setting(format!(
                "FMUstate: saved from another scene (scene hash {:016x}); this instance runs {scene} \
                 (scene hash {hash:016x}, with its step and eps_kappa): refused",
                snapshot.scene_hash()
            )));
        }
        if snapshot.desired_speed_factor != self.settings.desired_speed_factor {
            return Err(FmuError::Setting(format!(
                "FMUstate: saved with desired_speed_factor = {}, this instance has {}: refused",
                Num(snapshot.desired_speed_factor),
                Num(self.settings.desired_speed_factor)
            )));
        }
        let model = self.model()?;
        for (&b, &value) in &snapshot.moving {
            let why = match model.moving().get(b) {
                None => Some(format!(
                    "the scene has {} moving bodies",
                    model.moving().len()
                )),
                Some(input) => input
                    .refuse(value)
                    .map(|why| format!("{}: {why}", input.name)),
            };
            if let Some(why) = why {
                return Err(FmuError::Setting(format!(
                    "FMUstate: moving body {b} at {}: {why}: refused",
                    Num(value)
                )));
            }
        }
        let exits = model.exits().len();
        if let Some(&k) = snapshot.exits_open.keys().find(|&&k| k == 0 || k >= exits) {
            return Err(FmuError::Setting(format!(
                "FMUstate: an input of exit {k}, the scene has {exits} exits (exit 0's is \
                 door_open): refused"
            )));
        }
        model.load(&snapshot.model)?;
        self.settings.start_time = snapshot.start_time;
        self.settings.speed_factor = snapshot.speed_factor;
        self.settings.door_open = snapshot.door_open;
        self.settings.exits_open = snapshot.exits_open.clone();
        self.settings.moving = snapshot.moving.clone();
        self.state = snapshot.state;
        Ok(())
    }

    /// Back to `Instantiated` with default settings.
    pub fn reset(&mut self) {
        self.model = None;
        self.stale = true;
        self.stop_time = None;
        self.settings = Settings::default();
        self.state = State::Instantiated;
    }
}
