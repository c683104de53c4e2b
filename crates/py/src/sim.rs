//! `moreau.Simulation` (stepping with the GIL released, the people as numpy arrays, the
//! last step's report and contact forces, state and pickling, changes during a run, frames
//! recorded for PedPy) and `run_to_file`, the run file written by `moreau run`'s observer.

use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use moreau_core::{Num, StepReport};
use moreau_crowd::{
    ContactKind, CrowdError, Frame, Observer, ObserverError, SimState, Simulation, ToleranceWarning,
};
use moreau_io::{IoError, Overwrite, RunWriter};
use moreau_record::{Interrupted, Record, Summary};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::{PyFileExistsError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyString, PyTuple};

use crate::scene::{PyScene, geometry};
use crate::value::to_py;

/// How often a long computation without the GIL looks for Ctrl-C (and calls progress).
const POLL: Duration = Duration::from_millis(200);

/// One recorded frame: time, ids, positions `[x0, y0, …]`.
#[derive(Debug, Clone)]
struct RecordedFrame {
    t: f64,
    ids: Vec<u32>,
    positions: Vec<f64>,
}

/// The last step: its report and where its people were before it (for the velocities).
#[derive(Debug, Clone)]
struct LastStep {
    report: StepReport,
    ids: Vec<u32>,
    positions: Vec<f64>,
}

/// Everything behind the lock.
#[derive(Debug)]
struct Inner {
    sim: Simulation,
    last: Option<LastStep>,
    recording: bool,
    frames: Vec<RecordedFrame>,
    /// The one warning a simulation that adaptive steps miss `time.tol`.
    unmet: ToleranceWarning,
    /// That warning, until it is given (stepping runs without the GIL).
    warning: Option<String>,
}

/// The observer of the Python stepping: records frames when asked.
struct Watch<'a> {
    frames: Option<&'a mut Vec<RecordedFrame>>,
}

impl Observer for Watch<'_> {
    fn frame(&mut self, f: &Frame<'_>) -> Result<(), ObserverError> {
        if let Some(frames) = self.frames.as_deref_mut() {
            frames.push(RecordedFrame {
                t: f.t,
                ids: f.ids.to_vec(),
                positions: f.positions.to_vec(),
            });
        }
        Ok(())
    }
}

/// Why stepping stopped early.
enum Stop {
    Crowd(CrowdError),
    Interrupt(PyErr),
}

impl Inner {
    /// One step of `advance_to(t_end)` (see `Simulation::advance_step`), remembering the
    /// positions before it.
    fn one_step(&mut self, t_end: f64) -> Result<Option<StepReport>, CrowdError> {
        let people = self.sim.people();
        let (ids, positions) = (people.ids().to_vec(), people.positions().to_vec());
        let mut watch = Watch {
            frames: self.recording.then_some(&mut self.frames),
        };
        let report = self.sim.advance_step(t_end, &mut watch)?;
        if let Some(message) = report.as_ref().and_then(|r| self.unmet.first(r)) {
            self.warning = Some(message);
        }
        if let Some(r) = &report {
            self.last = Some(LastStep {
                report: r.clone(),
                ids,
                positions,
            });
        }
        Ok(report)
    }

    /// Gives the frames due at the current time, as `advance_to` does where it ends
    /// (`advance_step` to the current time takes no step): after `step()` they came with the
    /// next call, and the horizon's not at all.
    fn frames_due_now(&mut self) -> Result<(), CrowdError> {
        let t = self.sim.time();
        let mut watch = Watch {
            frames: self.recording.then_some(&mut self.frames),
        };
        self.sim.advance_step(t, &mut watch).map(|_| ())
    }

    /// Steps to `t_end`, looking for Ctrl-C every [`POLL`].
    fn advance(&mut self, t_end: f64) -> Result<(), Stop> {
        let mut polled = Instant::now();
        while self.one_step(t_end).map_err(Stop::Crowd)?.is_some() {
            if polled.elapsed() >= POLL {
                polled = Instant::now();
                Python::attach(|py| py.check_signals()).map_err(Stop::Interrupt)?;
            }
        }
        Ok(())
    }

    /// Gives the pending warning, if any, as a `RuntimeWarning` (as `moreau run` prints it to
    /// stderr and the FMU logs it): an error if the host turned warnings into errors.
    fn warn(&mut self, py: Python<'_>) -> PyResult<()> {
        warn(py, self.warning.take())
    }

    fn velocities(&self) -> Vec<f64> {
        let people = self.sim.people();
        let mut v = vec![f64::NAN; people.positions().len()];
        let Some(last) = &self.last else { return v };
        for (k, &id) in people.ids().iter().enumerate() {
            if let Ok(i) = last.ids.binary_search(&id) {
                for d in 0..2 {
                    v[2 * k + d] = (people.positions()[2 * k + d] - last.positions[2 * i + d])
                        / last.report.mu;
                }
            }
        }
        v
    }
}

/// `message`, if any, as a `RuntimeWarning`: an error if the host turned warnings into errors.
fn warn(py: Python<'_>, message: Option<String>) -> PyResult<()> {
    let Some(message) = message else {
        return Ok(());
    };
    let message = std::ffi::CString::new(message).unwrap_or_default();
    PyErr::warn(
        py,
        &py.get_type::<pyo3::exceptions::PyRuntimeWarning>(),
        &message,
        1,
    )
}

/// A crowd run in this process: built from a `Scene`, stepped by the catching-up scheme,
/// inspected as numpy arrays. Stepping releases the GIL, so several simulations run in
/// parallel from threads (one thread at a time per simulation: a call while another thread
/// steps it raises `RuntimeError`). Pickles as its scene's TOML and `state()`.
#[pyclass(name = "Simulation", module = "moreau")]
#[derive(Debug)]
pub struct PySimulation {
    scene: PyScene,
    inner: Mutex<Inner>,
}

fn crowd_err(e: CrowdError) -> PyErr {
    Python::attach(|py| to_py(py, e))
}

fn stop_err(stop: Stop) -> PyErr {
    match stop {
        Stop::Crowd(e) => crowd_err(e),
        Stop::Interrupt(e) => e,
    }
}

fn f64_array<'py>(py: Python<'py>, v: Vec<f64>, pairs: bool) -> PyResult<Bound<'py, PyAny>> {
    let a = PyArray1::from_vec(py, v);
    Ok(if pairs {
        let n = a.len()? / 2;
        a.reshape([n, 2])?.into_any()
    } else {
        a.into_any()
    })
}

fn report_dict<'py>(py: Python<'py>, r: &StepReport) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("step", r.step)?;
    d.set_item("t", r.t)?;
    d.set_item("mu", r.mu)?;
    d.set_item("eps", r.eps)?;
    d.set_item("eps_target", r.eps_target)?;
    d.set_item("violation", r.violation)?;
    d.set_item("iterations", r.iterations)?;
    d.set_item("assembled", r.assembled)?;
    d.set_item("active", r.active)?;
    d.set_item("redone", r.redone)?;
    d.set_item("rejected", r.rejected)?;
    d.set_item("local_error", r.local_error)?;
    d.set_item("solver", r.solver)?;
    d.set_item("status", r.status.as_str())?;
    let t = PyDict::new(py);
    let s = &r.timings;
    for (name, value) in [
        ("predict", s.predict),
        ("assemble", s.assemble),
        ("solve", s.solve),
        ("solve_analyse", s.solve_analyse),
        ("solve_factorize", s.solve_factorize),
        ("verify", s.verify),
        ("total", s.total),
    ] {
        t.set_item(name, value)?;
    }
    d.set_item("timings", t)?;
    Ok(d)
}

/// A `Scene` from a `Scene` or a path to a scene file.
pub fn scene_of(obj: &Bound<'_, PyAny>) -> PyResult<PyScene> {
    if let Ok(s) = obj.cast::<PyScene>() {
        return Ok(s.get().clone());
    }
    let path: PathBuf = obj.extract().map_err(|_| {
        pyo3::exceptions::PyTypeError::new_err(format!(
            "expected a moreau.Scene or a path to a scene file, got {}",
            obj.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    })?;
    moreau_crowd::Scene::from_file(&path)
        .map(|scene| PyScene { scene })
        .map_err(|e| to_py(obj.py(), e))
}

impl PySimulation {
    fn lock(&self) -> PyResult<MutexGuard<'_, Inner>> {
        match self.inner.try_lock() {
            Ok(g) => Ok(g),
            Err(std::sync::TryLockError::WouldBlock) => Err(PyRuntimeError::new_err(
                "this Simulation is being stepped by another thread",
            )),
            Err(std::sync::TryLockError::Poisoned(p)) => Ok(p.into_inner()),
        }
    }
}

#[pymethods]
impl PySimulation {
    /// Builds the run from `scene` (a `Scene` or a path to a scene file): distance fields,
    /// initial positions, solver. With `record=True` every output frame (each
    /// `time.output_interval`, as in the run file) is kept in memory for `to_pedpy`.
    #[new]
    #[pyo3(signature = (scene, record = false))]
    fn new(py: Python<'_>, scene: &Bound<'_, PyAny>, record: bool) -> PyResult<Self> {
        Self::built(py, scene_of(scene)?, record)
    }

    /// What unpickling calls: the simulation of `scene` with its thread count lowered to what
    /// this machine runs (a pickle made where more cores were, sent to a smaller worker, was
    /// refused: `solver.threads = 4: more than this machine runs usefully`; results do not
    /// depend on it).
    #[staticmethod]
    fn _unpickle(py: Python<'_>, scene: &Bound<'_, PyAny>, record: bool) -> PyResult<Self> {
        let mut scene = scene_of(scene)?;
        let threads = &mut scene.scene.solver.threads;
        *threads = moreau_crowd::limits::threads_here(*threads);
        Self::built(py, scene, record)
    }

    /// One step of the scene's stepping (its step `time.step`, shortened to land on the next
    /// output time; or adaptive when `time.tol` is set), exactly as `advance_to` and
    /// `moreau run` take them; returns the step's report (see `last_report`).
    fn step<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut guard = self.lock()?;
        let inner: &mut Inner = &mut guard;
        let report = py
            .detach(|| -> Result<_, CrowdError> {
                let report = inner.one_step(f64::MAX)?;
                inner.frames_due_now()?;
                Ok(report)
            })
            .map_err(crowd_err)?
            .expect("a step towards the next output time");
        inner.warn(py)?;
        report_dict(py, &report)
    }

    /// Steps to time `t` (s), the last step shortened to land on it, with the GIL released.
    /// Ctrl-C stops it between two steps (the simulation stays at its last step). Adaptive
    /// steps that miss `time.tol` give one `RuntimeWarning` a simulation (here or in `step`).
    fn advance_to(&self, py: Python<'_>, t: f64) -> PyResult<()> {
        let mut guard = self.lock()?;
        let inner: &mut Inner = &mut guard;
        inner.sim.check_t_end(t).map_err(|e| to_py(py, e))?;
        let advanced = py.detach(|| inner.advance(t)).map_err(stop_err);
        inner.warn(py)?;
        advanced
    }

    /// Runs to the scene's horizon (`advance_to(scene.horizon)`).
    fn run(&self, py: Python<'_>) -> PyResult<()> {
        self.advance_to(py, self.scene.scene.time.horizon)
    }

    /// The scene.
    #[getter]
    fn scene(&self) -> PyScene {
        self.scene.clone()
    }

    /// Current time (s).
    #[getter]
    fn time(&self) -> PyResult<f64> {
        Ok(self.lock()?.sim.time())
    }

    /// Steps taken.
    #[getter]
    fn steps(&self) -> PyResult<usize> {
        Ok(self.lock()?.sim.steps())
    }

    /// Positions of the people present, float64 `(n, 2)` (m), in the order of `ids`.
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = self.lock()?.sim.people().positions().to_vec();
        f64_array(py, v, true)
    }

    /// Velocities of the people present over the last step, float64 `(n, 2)` (m/s):
    /// `(q_after − q_before) / μ` of that step (the projected velocity, not the desired one).
    /// NaN before the first step and after `restore`.
    #[getter]
    fn velocities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = self.lock()?.velocities();
        f64_array(py, v, true)
    }

    /// Radii of the people present, float64 `(n,)` (m).
    #[getter]
    fn radii<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = self.lock()?.sim.people().radii().to_vec();
        f64_array(py, v, false)
    }

    /// Ids of the people present, uint32 `(n,)`, increasing (rows of `positions`).
    #[getter]
    fn ids<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let v = self.lock()?.sim.people().ids().to_vec();
        Ok(PyArray1::from_vec(py, v))
    }

    /// Everyone so far: the people at the start and those who entered from sources.
    #[getter]
    fn total_people(&self) -> PyResult<usize> {
        Ok(self.lock()?.sim.total_people())
    }

    /// Everyone who passed an exit so far: a list of `(id, exit index, t)`.
    fn exit_records(&self) -> PyResult<Vec<(u32, u32, f64)>> {
        Ok(self
            .lock()?
            .sim
            .exit_records()
            .iter()
            .map(|r| (r.id, r.exit, r.t))
            .collect())
    }

    /// Each inflow source's `(name, due, entered)`: the people due by now and those who
    /// entered (in the scene's order; empty without sources). Where they differ, people wait
    /// for room in the source's area.
    fn source_tallies(&self) -> PyResult<Vec<(String, u64, u64)>> {
        Ok(self
            .lock()?
            .sim
            .source_tallies()
            .into_iter()
            .map(|s| (s.name, s.due, s.entered))
            .collect())
    }

    /// The last step's report: a dict with `step`, `t`, `mu` (s), certified `eps` and its
    /// target `eps_target` (m²), `violation` (m), `iterations`, `assembled`, `active`,
    /// `redone`, `rejected`, `solver` (which answered), `status`, `timings` (s per stage);
    /// None before the first step and after `restore`.
    #[getter]
    fn last_report<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let inner = self.lock()?;
        inner
            .last
            .as_ref()
            .map(|l| report_dict(py, &l.report))
            .transpose()
    }

    /// The contact forces of the last step (multipliers `λ > 10⁻⁶` m/s, the run file's
    /// `/contacts`): a dict of numpy arrays `kind` (uint8: 0 person–person, 1 person–wall,
    /// 2 person–moving wall), `a` (uint32, a person id), `b` (uint32, the other person's id,
    /// the wall's row in the run file's `/walls`, or the moving segment's column in its
    /// `/frames/moving_walls`), `lambda` (float64, m/s).
    fn contacts<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let inner = self.lock()?;
        let frame = inner.sim.frame();
        let (mut kind, mut a, mut b, mut lambda) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for c in frame.contact_forces() {
            kind.push(match c.kind {
                ContactKind::PersonPerson => 0u8,
                ContactKind::PersonWall => 1u8,
                ContactKind::MovingWall => 2u8,
            });
            a.push(c.a);
            b.push(c.b);
            lambda.push(c.lambda);
        }
        let d = PyDict::new(py);
        d.set_item("kind", PyArray1::from_vec(py, kind))?;
        d.set_item("a", PyArray1::from_vec(py, a))?;
        d.set_item("b", PyArray1::from_vec(py, b))?;
        d.set_item("lambda", PyArray1::from_vec(py, lambda))?;
        Ok(d)
    }

    /// The desired velocities at the current configuration, float64 `(n, 2)` (m/s).
    fn desired_velocities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let mut inner = self.lock()?;
        let mut out = vec![0.0; inner.sim.people().positions().len()];
        inner.sim.desired_velocities(&mut out);
        f64_array(py, out, true)
    }

    /// Everything the next step depends on, as bytes (`SimState`'s compact binary form).
    fn state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let bytes = self.lock()?.sim.state().to_bytes();
        Ok(PyBytes::new(py, &bytes))
    }

    /// Continues from `state()` bytes of a simulation of the same scene: what follows is
    /// what followed the save, bit for bit. Bytes of another scene or damaged bytes raise
    /// `SceneError` and change nothing.
    fn restore(&self, py: Python<'_>, state: &[u8]) -> PyResult<()> {
        let mut inner = self.lock()?;
        let state = SimState::from_bytes(state).map_err(|e| to_py(py, e))?;
        inner.sim.restore(&state).map_err(|e| to_py(py, e))?;
        inner.last = None;
        // The frames recorded after the saved one belong to a branch given up: kept, a
        // roll-back gave `to_pedpy` two rows for each person at each of their frames.
        let frames = inner.sim.frames();
        inner.frames.truncate(frames);
        Ok(())
    }

    /// The factor on every desired speed, from the next step on (1 at the start).
    #[getter]
    fn speed_factor(&self) -> PyResult<f64> {
        Ok(self.lock()?.sim.speed_factor())
    }

    /// Sets the factor on every desired speed, from the next step on. NaN, infinite and
    /// negative factors raise `ValueError` and change nothing.
    fn set_speed_factor(&self, factor: f64) -> PyResult<()> {
        if !(factor.is_finite() && factor >= 0.0) {
            return Err(PyValueError::new_err(format!(
                "speed_factor = {}: must be finite and ≥ 0",
                Num(factor)
            )));
        }
        self.lock()?.sim.set_speed_factor(factor);
        Ok(())
    }

    /// Opens or closes an exit (by name or index), from the next step on. A closed exit is a
    /// wall across it: nobody passes, and people standing in it are pushed out.
    fn set_exit_open(&self, py: Python<'_>, exit: &Bound<'_, PyAny>, open: bool) -> PyResult<()> {
        let exits = &self.scene.scene.exits;
        let index = if let Ok(name) = exit.cast::<PyString>() {
            let name = name.to_str()?;
            exits.iter().position(|e| e.name == name).ok_or_else(|| {
                let names: Vec<&str> = exits.iter().map(|e| e.name.as_str()).collect();
                PyValueError::new_err(format!("exit = {name:?}: the scene's exits are {names:?}"))
            })?
        } else {
            let i: i64 = exit.extract()?;
            usize::try_from(i).map_err(|_| {
                PyValueError::new_err(format!("exit = {i}: the scene has {} exits", exits.len()))
            })?
        };
        self.lock()?
            .sim
            .set_exit_open(index, open)
            .map_err(|e| to_py(py, e))
    }

    /// Whether each exit is open, in the scene's order, as `set_exit_open` left it (an exit
    /// with a panel, `closes` or `opens` in the scene, is also shut by the panel on its own
    /// schedule, whatever this says).
    fn exits_open(&self) -> PyResult<Vec<bool>> {
        let inner = self.lock()?;
        Ok((0..self.scene.scene.exits.len())
            .map(|e| inner.sim.exit_open(e).unwrap_or(false))
            .collect())
    }

    /// Removes the people whose centre lies inside `polygon` (a shapely geometry or WKT;
    /// `shapely.contains_xy`, so the boundary is outside), from the next step on; they get no
    /// exit record. Returns how many were removed.
    fn remove_people_in(&self, polygon: &Bound<'_, PyAny>) -> PyResult<usize> {
        let py = polygon.py();
        // Named `polygon`, not the scene's `area`; and anything but a geometry refused (a list
        // of points met a numpy broadcast error, None removed nobody).
        let geom = geometry(polygon, "polygon", "a shapely geometry", |e| {
            PyValueError::new_err(format!("polygon = {polygon:?}: {e}"))
        })?;
        let mut inner = self.lock()?;
        let q = inner.sim.people().positions();
        let xs: Vec<f64> = q.iter().step_by(2).copied().collect();
        let ys: Vec<f64> = q.iter().skip(1).step_by(2).copied().collect();
        let inside: Vec<bool> = py
            .import("shapely")?
            .call_method1(
                "contains_xy",
                (geom, PyArray1::from_vec(py, xs), PyArray1::from_vec(py, ys)),
            )?
            .call_method0("tolist")?
            .extract()?;
        let mut k = 0;
        Ok(inner.sim.remove_people(|_, _| {
            k += 1;
            inside[k - 1]
        }))
    }

    /// The frames recorded so far (`record=True`): `(frame, t, id, x, y)` arrays, one row per
    /// person and frame, frames numbered from 0 in the order they were recorded.
    fn recorded_frames<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let inner = self.lock()?;
        if !inner.recording {
            return Err(PyValueError::new_err(
                "record = False: build the Simulation with record=True to keep its frames",
            ));
        }
        let (mut frame, mut t, mut id, mut x, mut y) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (k, f) in inner.frames.iter().enumerate() {
            for (j, &i) in f.ids.iter().enumerate() {
                frame.push(k as i64);
                t.push(f.t);
                id.push(i as i64);
                x.push(f.positions[2 * j]);
                y.push(f.positions[2 * j + 1]);
            }
        }
        (
            PyArray1::from_vec(py, frame),
            PyArray1::from_vec(py, t),
            PyArray1::from_vec(py, id),
            PyArray1::from_vec(py, x),
            PyArray1::from_vec(py, y),
        )
            .into_pyobject(py)
    }

    fn __repr__(&self) -> String {
        match self.inner.try_lock() {
            Ok(inner) => format!(
                "Simulation(scene={:?}, t={}, people={})",
                self.scene.scene.name,
                Num(inner.sim.time()),
                inner.sim.people().len()
            ),
            Err(_) => format!("Simulation(scene={:?}, <stepping>)", self.scene.scene.name),
        }
    }

    /// Pickled as `(Simulation._unpickle(scene, record), state())`: unpickled, it goes on bit
    /// for bit, on at most the threads the unpickling machine runs (recorded frames,
    /// `last_report` and `velocities` are not carried).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        let py = slf.py();
        let this = slf.borrow();
        let recording = this.lock()?.recording;
        let state = this.state(py)?;
        let scene = Bound::new(py, this.scene.clone())?;
        let unpickle = slf.get_type().getattr("_unpickle")?;
        (unpickle, (scene, recording), state).into_pyobject(py)
    }

    /// What `__reduce__` hands to `pickle`: the `state()` bytes, restored here.
    fn __setstate__(&self, py: Python<'_>, state: &[u8]) -> PyResult<()> {
        self.restore(py, state)
    }
}

/// Runs `scene` (a `Scene` or a path) to its horizon into the HDF5 run file `output`,
/// with `moreau run`'s observer: the same datasets and attributes (`command` says
/// `command`). `progress(t, steps, people_left)` is called about every 0.2 s; Ctrl-C stops
/// the run (the file keeps what was written, `status` says why). Returns the summary JSON.
#[pyfunction]
#[pyo3(signature = (scene, output, force = false, command = None, progress = None))]
pub fn run_to_file(
    py: Python<'_>,
    scene: &Bound<'_, PyAny>,
    output: PathBuf,
    force: bool,
    command: Option<String>,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    // A run never writes over its input (`moreau run` refuses it too): `moreau.run("s.toml",
    // "s.toml", force=True)` replaced the scene file by the run file.
    if scene.cast::<PyScene>().is_err()
        && let Ok(path) = scene.extract::<PathBuf>()
        && moreau_io::same_file(&output, &path)
    {
        return Err(PyValueError::new_err(format!(
            "output '{}' is the scene file: a run never writes over its input",
            output.display()
        )));
    }
    let scene = scene_of(scene)?;
    let origin = match scene.scene.name.as_str() {
        "" => "<python>".to_string(),
        name => format!("{name} (python)"),
    };
    let overwrite = if force {
        Overwrite::Allowed
    } else {
        Overwrite::Never
    };
    // The writer's messages name the CLI's `--force`; here it is the keyword.
    let io_err = |e: IoError| {
        let message = e.to_string().replace("pass --force", "pass force=True");
        match e {
            IoError::Exists { .. } => PyFileExistsError::new_err(message),
            _ => PyOSError::new_err(message),
        }
    };
    moreau_io::check_output(&output, overwrite).map_err(io_err)?;
    let s = scene.scene.clone();
    let mut sim = py
        .detach(move || Simulation::new(s))
        .map_err(|e| to_py(py, e))?;
    let command = command.unwrap_or_else(|| format!("moreau.run({:?})", output.display()));
    let header = moreau_record::header(&sim, command);
    let mut writer = RunWriter::create(&output, &header, overwrite).map_err(io_err)?;
    let people = sim.total_people();
    let mut interrupted: Option<PyErr> = None;
    // Adaptive steps that miss `time.tol`: said once, as `Simulation` and `moreau run` say it.
    let mut once = ToleranceWarning::new(&sim.scene().time);
    let mut unmet: Option<String> = None;
    // Sources that left people waiting at the end: said as `moreau run` says it.
    let mut waiting: Option<String> = None;
    let (outcome, json, finished) = py.detach(|| {
        let start = Instant::now();
        let mut polled = Instant::now();
        let mut tell = |r: &StepReport, stats: &moreau_core::RunStats, left: usize| {
            if let Some(message) = once.first(r) {
                unmet = Some(message);
            }
            if polled.elapsed() < POLL {
                return Ok(());
            }
            polled = Instant::now();
            Python::attach(|py| -> PyResult<()> {
                py.check_signals()?;
                if let Some(p) = &progress {
                    p.call1(py, (r.t, stats.steps, left))?;
                }
                Ok(())
            })
            .map_err(|e| -> ObserverError {
                let message = e.to_string();
                let ctrl_c = Python::attach(|py| {
                    e.is_instance_of::<pyo3::exceptions::PyKeyboardInterrupt>(py)
                });
                interrupted = Some(e);
                match ctrl_c {
                    true => Box::new(Interrupted("Ctrl-C (KeyboardInterrupt)")),
                    false => format!("stopped from Python: {message}").into(),
                }
            })
        };
        let mut record = Record::new(Some(&mut writer as &mut dyn moreau_io::RunSink), people)
            .with_progress(&mut tell);
        let outcome = moreau_record::run_to_horizon(&mut sim, &mut record);
        // Ctrl-C is `interrupted`, as `moreau run` writes it (it was "failed: stopped from
        // Python: KeyboardInterrupt").
        let status = match &outcome {
            Ok(()) => "complete".to_string(),
            Err(CrowdError::Observer(e)) if e.is::<Interrupted>() => "interrupted".to_string(),
            Err(e) => format!("failed: {e:#}"),
        };
        let wall = start.elapsed().as_secs_f64();
        let summary = Summary::new(
            &sim,
            &record,
            origin,
            Some(output.display().to_string()),
            status.clone(),
            wall,
        );
        let json = summary.to_json();
        waiting = summary.waiting_warning();
        drop(record);
        let finished = writer.finish(&status, &json);
        (outcome, json, finished)
    });
    if let Some(e) = interrupted {
        return Err(e);
    }
    warn(py, unmet)?;
    warn(py, waiting)?;
    if let Some(p) = &progress {
        p.call1(
            py,
            // Everyone so far (those who entered too) less those out, as the steps' calls
            // count them: the people at the start less those out wrapped around once people
            // from sources had left.
            (
                sim.time(),
                sim.steps(),
                sim.total_people().saturating_sub(sim.exit_records().len()),
            ),
        )?;
    }
    outcome.map_err(|e| to_py(py, e))?;
    finished.map_err(|e| PyOSError::new_err(e.to_string()))?;
    Ok(json)
}

impl PySimulation {
    /// The simulation of `scene`, recording its frames with `record`.
    fn built(py: Python<'_>, scene: PyScene, record: bool) -> PyResult<Self> {
        let s = scene.scene.clone();
        let sim = py
            .detach(move || Simulation::new(s))
            .map_err(|e| to_py(py, e))?;
        let unmet = ToleranceWarning::new(&sim.scene().time);
        Ok(PySimulation {
            scene,
            inner: Mutex::new(Inner {
                sim,
                last: None,
                recording: record,
                frames: Vec::new(),
                unmet,
                warning: None,
            }),
        })
    }
}
