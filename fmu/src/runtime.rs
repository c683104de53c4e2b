//! The small generic runtime under both FMI layers: an instance, its state machine, its
//! settings, logging, and stepping the model to the communication point.

use std::path::PathBuf;

use crate::FmuError;
use crate::model::{Causality, CrowdModel, Kind, Settings, variable, vr};

/// The states of a co-simulation instance (FMI 2 names in brackets).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// After instantiation: parameters may be set.
    Instantiated,
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
            log,
        }
    }

    /// Logs an informational message (when logging is on).
    pub fn info(&self, message: &str) {
        if self.logging_on {
            (self.log)(Level::Info, message);
        }
    }

    /// Logs an error (always).
    pub fn error(&self, message: &str) {
        (self.log)(Level::Error, message);
    }

    /// Fails unless the instance is in one of `allowed` states.
    pub fn expect(&self, function: &str, allowed: &[State]) -> Result<(), FmuError> {
        if allowed.contains(&self.state) {
            Ok(())
        } else {
            Err(FmuError::State {
                function: function.to_string(),
                state: self.state,
            })
        }
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

    fn settable(&self, vr: u32, kind: Kind) -> Result<Causality, FmuError> {
        let v = variable(vr).ok_or(FmuError::UnknownReference(vr))?;
        if v.kind != kind {
            return Err(FmuError::WrongType { vr, name: v.name });
        }
        match (v.causality, self.state) {
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
        Ok(v.causality)
    }

    fn changed(&mut self, causality: Causality) -> Result<(), FmuError> {
        match causality {
            Causality::Parameter => self.stale = true,
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
        let causality = self.settable(vr, Kind::Real)?;
        if !value.is_finite() {
            let name = variable(vr).map_or("?", |v| v.name);
            return Err(FmuError::Setting(format!(
                "{name} = {value}: not a finite number"
            )));
        }
        match vr {
            vr::STEP => self.settings.step = value,
            vr::EPS_KAPPA => self.settings.eps_kappa = value,
            vr::DESIRED_SPEED_FACTOR => self.settings.desired_speed_factor = value,
            vr::SPEED_FACTOR => self.settings.speed_factor = value,
            _ => return Err(FmuError::UnknownReference(vr)),
        }
        self.changed(causality)
    }

    /// Sets a Boolean.
    pub fn set_boolean(&mut self, vr: u32, value: bool) -> Result<(), FmuError> {
        let causality = self.settable(vr, Kind::Boolean)?;
        match vr {
            vr::DOOR_OPEN => self.settings.door_open = value,
            _ => return Err(FmuError::UnknownReference(vr)),
        }
        self.changed(causality)
    }

    /// Sets a String.
    pub fn set_string(&mut self, vr: u32, value: &str) -> Result<(), FmuError> {
        let causality = self.settable(vr, Kind::String)?;
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

    fn readable(&self, vr: u32, kind: Kind) -> Result<(), FmuError> {
        let v = variable(vr).ok_or(FmuError::UnknownReference(vr))?;
        if v.kind != kind {
            return Err(FmuError::WrongType { vr, name: v.name });
        }
        if v.causality == Causality::Output && self.state == State::Instantiated {
            return Err(FmuError::Setting(format!(
                "{} is not available before initialization",
                v.name
            )));
        }
        Ok(())
    }

    /// Gets a Real.
    pub fn get_real(&mut self, vr: u32) -> Result<f64, FmuError> {
        self.readable(vr, Kind::Real)?;
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
        self.readable(vr, Kind::Integer)?;
        self.model()?
            .integer(vr)
            .ok_or(FmuError::UnknownReference(vr))
    }

    /// Gets a Boolean.
    pub fn get_boolean(&mut self, vr: u32) -> Result<bool, FmuError> {
        self.readable(vr, Kind::Boolean)?;
        match vr {
            vr::DOOR_OPEN => Ok(self.settings.door_open),
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
                "communicationStepSize = {h}: must be finite and > 0"
            )));
        }
        if !t.is_finite() {
            return Err(FmuError::Setting(format!(
                "currentCommunicationPoint = {t}: not a finite number"
            )));
        }
        let settings = self.settings.clone();
        let model = self.model()?;
        model.apply(&settings)?;
        model.do_step(t, h)
    }

    /// The model's time (the last communication point reached), if built.
    pub fn time(&self) -> Option<f64> {
        self.model.as_ref().map(|m| m.time())
    }

    /// Stepping/Initialization → Terminated.
    pub fn terminate(&mut self) -> Result<(), FmuError> {
        self.expect("Terminate", &[State::Stepping, State::Initialization])?;
        self.state = State::Terminated;
        Ok(())
    }

    /// Back to `Instantiated` with default settings.
    pub fn reset(&mut self) {
        self.model = None;
        self.stale = true;
        self.settings = Settings::default();
        self.state = State::Instantiated;
    }
}
