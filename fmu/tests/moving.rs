//! Issue 15, item 7: the position of a moving door as a continuous Real input of the FMU
//! (`moving.door`, value reference 1000), through the FMI 2 and FMI 3 C API as a master calls
//! it: the door closes when the master says and nobody passes it after; the run is the native
//! `Simulation` driven with the same values (`drive_moving`), bit for bit (the FMU translates,
//! it does not simulate); FMU states taken while the door moves give the same continuation;
//! bad values are refused with a log line naming the variable and the value.
// The FMI entry points are a C ABI: raw pointers, as a host passes them.
#![allow(unsafe_code)]

use std::cell::RefCell;
use std::ffi::{CString, c_int, c_void};
use std::path::PathBuf;

use moreau_crowd::{Scene, Simulation};
use moreau_fmu::fmi3;
use moreau_fmu::model::vr;
use moreau_fmu::runtime::Instance;

mod support;
use support::{Api, ERROR, OK};

/// The door's input: the scene's first (and only) moving body.
const DOOR: u32 = vr::MOVING;
/// Where the panel closes the corridor (x, m), and the people's radius.
const PANEL_X: f64 = 12.0;
const RADIUS: f64 = 0.2;
/// People past the door at the start (the scene's group "ahead"), and all of them.
const AHEAD: i32 = 8;
const PEOPLE: usize = 28;

fn corridor() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/fmu/corridor-door.toml"
    ))
}

/// One instance driven through the C API of FMI 2 or FMI 3, every call expected to succeed.
struct Fmu {
    api: Api,
    log: Box<RefCell<Vec<String>>>,
}

impl Fmu {
    /// Instantiated on `scene` (state Instantiated).
    fn instantiate(v3: bool, scene: Option<&str>) -> Self {
        let log = Box::new(RefCell::new(Vec::new()));
        let api = support::instantiate(v3, &log, false);
        let fmu = Self { api, log };
        if let Some(scene) = scene {
            let text = CString::new(scene).unwrap();
            // SAFETY: the live instance; one string, alive through the call.
            fmu.ok(unsafe { fmu.api.set_scene(&text) });
        }
        fmu
    }

    /// Instantiated on the corridor and initialized (state Stepping), start time 0.
    fn stepping(v3: bool) -> Self {
        let mut fmu = Self::instantiate(v3, Some(&corridor().display().to_string()));
        fmu.initialize();
        fmu
    }

    fn initialize(&mut self) {
        self.ok(self.api.enter_initialization(None, 0.0, None));
        self.ok(self.api.exit_initialization());
    }

    fn ok(&self, status: c_int) {
        assert_eq!(status, OK, "log: {:?}", self.log.borrow());
    }

    fn set_real(&mut self, r: u32, x: f64) -> c_int {
        // SAFETY: the live instance; one reference, one value.
        unsafe { self.api.set_real(r, &[x]) }
    }

    fn set_ok(&mut self, r: u32, x: f64) {
        let status = self.set_real(r, x);
        self.ok(status);
    }

    fn get_real(&mut self, r: u32) -> f64 {
        let mut x = vec![f64::NAN];
        // SAFETY: the live instance; one reference, room for one value.
        let status = unsafe { self.api.get_real(&[r], &mut x) };
        self.ok(status);
        x[0]
    }

    fn get_integer(&mut self, r: u32) -> i32 {
        let mut x = vec![-1];
        // SAFETY: the live instance; one reference, room for one value.
        let status = unsafe { self.api.get_integer(&[r], &mut x) };
        self.ok(status);
        x[0]
    }

    fn do_step(&mut self, t: f64, h: f64) {
        // SAFETY: the live instance.
        let status = unsafe { self.api.do_step(t, h) };
        self.ok(status);
    }

    /// The FMI 3 positions `[n_people][2]` by person id (NaN once gone).
    fn positions(&mut self) -> Vec<f64> {
        assert!(self.api.v3);
        let mut q = vec![0.0; 2 * PEOPLE];
        // SAFETY: the live instance; one reference, room for its 2 × n_people values.
        let status = unsafe { self.api.get_real(&[vr::POSITIONS], &mut q) };
        self.ok(status);
        q
    }

    /// What a master reads after a step: the evacuated count, the steps taken and the smallest
    /// gap (to the bit), and in FMI 3 the positions.
    fn outputs(&mut self) -> Outputs {
        Outputs {
            evacuated: self.get_integer(vr::PEOPLE_EVACUATED),
            steps: self.get_integer(vr::INTERNAL_STEPS),
            min_gap: self.get_real(vr::MIN_GAP).to_bits(),
            positions: if self.api.v3 {
                bits(&self.positions())
            } else {
                Vec::new()
            },
        }
    }

    fn get_state(&mut self) -> *mut c_void {
        let mut state = std::ptr::null_mut();
        // SAFETY: the live instance; a null slot of ours: the FMU puts a new state there.
        let status = unsafe { self.api.get_state(&mut state) };
        self.ok(status);
        state
    }

    fn set_state(&mut self, state: *mut c_void) {
        // SAFETY: a live state of this FMU.
        let status = unsafe { self.api.set_state(state) };
        self.ok(status);
    }

    fn serialize(&mut self, state: *mut c_void) -> Vec<u8> {
        // SAFETY: a live state of this FMU.
        unsafe { self.api.serialize(state) }.unwrap_or_else(|status| {
            self.ok(status);
            unreachable!()
        })
    }

    fn deserialize(&mut self, bytes: &[u8]) -> *mut c_void {
        let mut state = std::ptr::null_mut();
        // SAFETY: the live instance; the bytes; a null slot of ours.
        let status = unsafe { self.api.deserialize(bytes, &mut state) };
        self.ok(status);
        state
    }

    fn free_state(&mut self, mut state: *mut c_void) {
        // SAFETY: a live state of this FMU; freed once.
        let status = unsafe { self.api.free_state(&mut state) };
        self.ok(status);
    }

    fn last_log(&self) -> String {
        self.log.borrow().last().cloned().unwrap_or_default()
    }
}

impl Drop for Fmu {
    fn drop(&mut self) {
        // The instance this value made, freed once.
        self.api.free();
    }
}

#[derive(Debug, Clone, PartialEq)]
struct Outputs {
    evacuated: i32,
    steps: i32,
    min_gap: u64,
    positions: Vec<u64>,
}

fn bits(x: &[f64]) -> Vec<u64> {
    x.iter().map(|v| v.to_bits()).collect()
}

/// The communication steps: 0.25 s to 12 s.
const H: f64 = 0.25;
const STEPS: usize = 48;

/// The door's input over the run: open (0) until the communication point at 2 s, where the
/// master closes it (1) over that one step.
fn door(k: usize) -> f64 {
    if k as f64 * H >= 2.0 { 1.0 } else { 0.0 }
}

/// How a native run drives the door.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Drive {
    /// Not at all: it follows its keyframes in time (and closes during the first second).
    Never,
    /// To the value for each communication step, before every step.
    EveryStep,
    /// Held at the start, then again only when the value changes.
    OnChange,
}

/// The native run of `scene`, its door driven with `door(k)` for the communication step `k`
/// (to that value at the end of the step). The outputs after each step, as [`Fmu::outputs`]
/// reads them.
fn native_of(scene: Scene, door: impl Fn(usize) -> f64, drive: Drive) -> Vec<Outputs> {
    let mut sim = Simulation::new(scene).unwrap();
    let mut out = Vec::new();
    let mut q = vec![0.0; 2 * PEOPLE];
    for k in 0..STEPS {
        let t_end = sim.time() + H;
        let changed = k == 0 || door(k) != door(k - 1);
        if drive == Drive::EveryStep || (drive == Drive::OnChange && changed) {
            sim.drive_moving(0, door(k), t_end).unwrap();
        }
        sim.advance_to(t_end, &mut ()).unwrap();
        sim.frame().positions_by_id(&mut q);
        let gap = sim.min_gap(1.0);
        out.push(Outputs {
            evacuated: sim.exit_records().len() as i32,
            steps: sim.steps() as i32,
            min_gap: if gap.is_finite() { gap } else { 1.0 }.to_bits(),
            positions: bits(&q),
        });
    }
    out
}

/// The native run of the corridor, its door driven before every communication step.
fn native(door: impl Fn(usize) -> f64, drive: bool) -> Vec<Outputs> {
    let drive = if drive {
        Drive::EveryStep
    } else {
        Drive::Never
    };
    native_of(Scene::from_file(corridor()).unwrap(), door, drive)
}

/// The FMU run with the door's input from `door` (set before each step; `None`: never set).
fn fmu_run(v3: bool, door: impl Fn(usize) -> Option<f64>) -> Vec<Outputs> {
    fmu_run_of(v3, &corridor().display().to_string(), door)
}

/// [`fmu_run`] on the scene file `scene`.
fn fmu_run_of(v3: bool, scene: &str, door: impl Fn(usize) -> Option<f64>) -> Vec<Outputs> {
    let mut fmu = Fmu::instantiate(v3, Some(scene));
    fmu.initialize();
    (0..STEPS)
        .map(|k| {
            if let Some(x) = door(k) {
                fmu.set_ok(DOOR, x);
                assert_eq!(fmu.get_real(DOOR), x);
            }
            fmu.do_step(k as f64 * H, H);
            fmu.outputs()
        })
        .collect()
}

#[test]
fn the_door_closes_at_the_masters_word_and_the_fmu_is_the_native_run_driven_alike() {
    let native_run = native(door, true);
    for v3 in [false, true] {
        let which = if v3 { "FMI 3" } else { "FMI 2" };
        let run = fmu_run(v3, |k| Some(door(k)));
        for (k, (f, n)) in run.iter().zip(&native_run).enumerate() {
            let t = (k + 1) as f64 * H;
            assert_eq!(f.evacuated, n.evacuated, "{which}, t = {t}");
            assert_eq!(f.steps, n.steps, "{which}, t = {t}: internal steps");
            assert_eq!(f.min_gap, n.min_gap, "{which}, t = {t}: min_gap to the bit");
            if v3 {
                assert_eq!(f.positions, n.positions, "{which}, t = {t}: positions");
            }
        }
        // Everyone ahead of the door leaves, nobody behind it.
        assert_eq!(run.last().unwrap().evacuated, AHEAD, "{which}");
    }
    // Nobody passes the panel once it closed (at 2.25 s): whoever was behind it at 2 s stays
    // behind it, and the front of the crowd stands against it.
    let x = |o: &Outputs, id: usize| f64::from_bits(o.positions[2 * id]);
    let at_2s = &native_run[7];
    let behind: Vec<usize> = (0..PEOPLE).filter(|&id| x(at_2s, id) < PANEL_X).collect();
    assert_eq!(behind.len(), PEOPLE - AHEAD as usize);
    let mut front: f64 = 0.0;
    for o in &native_run[8..] {
        for &id in &behind {
            assert!(
                x(o, id) <= PANEL_X - RADIUS + 1e-6,
                "person {id} at x = {}",
                x(o, id)
            );
            front = front.max(x(o, id));
        }
    }
    assert!(
        front > PANEL_X - RADIUS - 0.01,
        "the front stops at {front}"
    );
}

#[test]
fn without_its_input_the_door_stays_open_and_without_the_drive_the_runs_differ() {
    // Never set: the door is held open (it does not follow the scene's keyframes, which close
    // it within the first second), and people behind it walk through and leave.
    let open = fmu_run(true, |_| None);
    let held = native(|_| 0.0, true);
    assert_eq!(open, held);
    assert!(open.last().unwrap().evacuated > AHEAD + 3);
    // The same FMU run against a native run that is not driven (its door follows the clock):
    // the comparison sees it.
    let clock = native(|_| 0.0, false);
    assert_ne!(open, clock);
    assert_eq!(clock.last().unwrap().evacuated, AHEAD);
    // And the door closed at 2 s is another run than the open one.
    assert_ne!(open, native(door, true));
}

#[test]
fn with_field_update_the_fields_see_the_door_the_fmu_closed() {
    // The corridor with its distance fields solved again every 0.5 s around the bodies that
    // moved: once the door is closed, the people behind it have no way to the exit and stand
    // where they are instead of pressing against the door.
    let mut scene = Scene::from_file(corridor()).unwrap();
    scene.model.field_update = Some(0.5);
    let dir = std::env::temp_dir().join(format!("moreau-fmu-moving-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("corridor-door-fields.toml");
    std::fs::write(&path, scene.to_toml()).unwrap();

    let run = fmu_run_of(true, &path.display().to_string(), |k| Some(door(k)));
    // The simulation, driven as a user of the crate drives it (once at the start to hold the
    // door, once to close it), is the FMU's run, field updates included.
    assert_eq!(run, native_of(scene.clone(), door, Drive::OnChange));
    let x = |o: &Outputs, id: usize| f64::from_bits(o.positions[2 * id]);
    let behind: Vec<usize> = (0..PEOPLE).filter(|&id| x(&run[7], id) < PANEL_X).collect();
    let front = behind
        .iter()
        .map(|&id| x(run.last().unwrap(), id))
        .fold(0.0, f64::max);
    assert!(
        front < PANEL_X - 1.0,
        "the front stands at {front}, not at the door"
    );
    assert_eq!(run.last().unwrap().evacuated, AHEAD);
    // A drive before every step holds the door just the same and gives the same run: the
    // simulation solves the fields again when a body is elsewhere than at the last solve,
    // whatever drive put it there. (Before, it judged by the current drive's speed, and a
    // drive per step hid the door that the previous drive had closed.)
    assert_eq!(run, native_of(scene, door, Drive::EveryStep));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_state_taken_while_the_door_closes_gives_the_same_continuation() {
    // The door closes over four communication steps (0.25, 0.5, 0.75, 1 from 2 s on); the
    // state is taken at 2.5 s with 0.75 set for the step that follows: the body half-way, its
    // next target pending.
    let ramp = |k: usize| (0.25 * (k as f64 - 7.0)).clamp(0.0, 1.0);
    for v3 in [false, true] {
        let which = if v3 { "FMI 3" } else { "FMI 2" };
        let mut fmu = Fmu::stepping(v3);
        for k in 0..10 {
            fmu.set_ok(DOOR, ramp(k));
            fmu.do_step(k as f64 * H, H);
        }
        fmu.set_ok(DOOR, ramp(10));
        assert_eq!(ramp(10), 0.75);
        let state = fmu.get_state();
        let bytes = fmu.serialize(state);
        let go_on = |fmu: &mut Fmu, set_first: bool| -> Vec<Outputs> {
            (10..24)
                .map(|k| {
                    if k > 10 || set_first {
                        fmu.set_ok(DOOR, ramp(k));
                    }
                    fmu.do_step(k as f64 * H, H);
                    fmu.outputs()
                })
                .collect()
        };
        let straight = go_on(&mut fmu, false);

        // Back to 2.5 s: the pending 0.75 is restored with the state, not set again.
        fmu.set_state(state);
        assert_eq!(fmu.get_real(DOOR), 0.75, "{which}");
        assert_eq!(go_on(&mut fmu, false), straight, "{which}: set back");
        fmu.free_state(state);

        // Serialized, into a new instance never initialized.
        let mut again = Fmu::instantiate(v3, Some(&corridor().display().to_string()));
        let state = again.deserialize(&bytes);
        again.set_state(state);
        again.free_state(state);
        assert_eq!(again.get_real(DOOR), 0.75, "{which}");
        assert_eq!(go_on(&mut again, false), straight, "{which}: deserialized");

        // The native run driven with the same values from the start.
        let native_run = native(ramp, true);
        assert_eq!(
            straight.iter().map(|o| o.steps).collect::<Vec<_>>(),
            native_run[10..24]
                .iter()
                .map(|o| o.steps)
                .collect::<Vec<_>>()
        );
        if v3 {
            assert_eq!(straight, native_run[10..24].to_vec());
        }
    }
}

#[test]
fn bad_values_are_refused_with_a_log_line_naming_the_input_and_the_value() {
    let mut fmu = Fmu::stepping(true);
    fmu.do_step(0.0, H);
    assert_eq!(fmu.set_real(DOOR, 1.5), ERROR);
    assert_eq!(
        fmu.last_log(),
        "fmi3SetFloat64: moving.door = 1.5: outside the body's keyframe times [0, 1] \
         (it keeps its value 0)"
    );
    assert_eq!(fmu.set_real(DOOR, f64::NAN), ERROR);
    assert_eq!(
        fmu.last_log(),
        "fmi3SetFloat64: moving.door = NaN: not a finite number (it keeps its value 0)"
    );
    assert_eq!(fmu.set_real(DOOR, -0.5), ERROR);
    assert!(
        fmu.last_log().contains("moving.door = -0.5"),
        "{}",
        fmu.last_log()
    );
    assert_eq!(fmu.get_real(DOOR), 0.0, "refused values are not kept");
    // A body the scene does not have.
    assert_eq!(fmu.set_real(DOOR + 1, 0.5), ERROR);
    let line = fmu.last_log();
    assert!(
        line.contains("unknown value reference 1001")
            && line.contains("corridor-door.toml has 1 moving bodies"),
        "{line}"
    );
    // The input is a Float64.
    let mut i = 0;
    // SAFETY: one reference, room for one value.
    assert_eq!(
        unsafe { fmi3::fmi3GetInt32(fmu.api.c, &DOOR, 1, &mut i, 1) },
        ERROR
    );
    assert!(
        fmu.last_log()
            .contains("value reference 1000 (moving.door) is of another type"),
        "{}",
        fmu.last_log()
    );
    // Steps go on with the old value; a fine one is taken.
    fmu.do_step(H, H);
    fmu.set_ok(DOOR, 0.5);
    fmu.do_step(2.0 * H, H);
    assert_eq!(fmu.get_real(DOOR), 0.5);
    // After terminate, inputs are no longer settable (FMI 2 §4.2.4, FMI 3 §4.2).
    fmu.ok(fmi3::fmi3Terminate(fmu.api.c));
    assert_eq!(fmu.set_real(DOOR, 1.0), ERROR);
    assert!(
        fmu.last_log()
            .contains("fmi3SetFloat64 is not allowed in state Terminated"),
        "{}",
        fmu.last_log()
    );
    assert_eq!(fmu.get_real(DOOR), 0.5, "readable after terminate");

    // In configuration mode only structural parameters are settable; in Instantiated and
    // initialization mode inputs are.
    let mut fmu = Fmu::instantiate(true, Some(&corridor().display().to_string()));
    fmu.ok(fmi3::fmi3EnterConfigurationMode(fmu.api.c));
    assert_eq!(fmu.set_real(DOOR, 1.0), ERROR);
    assert!(
        fmu.last_log()
            .contains("moving.door cannot be set in state Configuration"),
        "{}",
        fmu.last_log()
    );
    fmu.ok(fmi3::fmi3ExitConfigurationMode(fmu.api.c));
    fmu.set_ok(DOOR, 0.25);

    // The room has no moving body.
    let mut room = Fmu::instantiate(
        false,
        Some(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../data/scenes/room-60.toml"
        )),
    );
    room.initialize();
    assert_eq!(room.set_real(DOOR, 0.0), ERROR);
}

#[test]
fn a_value_set_before_the_first_step_is_reached_at_its_end() {
    // The input is where the body is at the end of the step that follows its setting: set
    // in initialization mode, the door is still open at the start and closed at the first
    // communication point.
    let mut inst = Instance::new("ramp".into(), None, false, Box::new(|_, _| {}));
    inst.settings.scene = corridor().display().to_string();
    inst.enter_initialization().unwrap();
    inst.set_real(DOOR, 1.0).unwrap();
    inst.exit_initialization().unwrap();
    assert_eq!(inst.model().unwrap().moving_position(0), 0.0);
    inst.do_step(0.0, 0.5).unwrap();
    assert_eq!(inst.model().unwrap().moving_position(0), 1.0);
    // Half-way through the step the door was half-way: the motion is linear in between.
    let sim = inst.model().unwrap().simulation();
    assert_eq!(sim.moving().param(0, 0.25), 0.5);
    assert_eq!(sim.moving().param(0, 0.0), 0.0);
}

/// The fields are solved at about 2.01 s during the drive 0 → 0.25 over [2, 2.25], and the
/// state is taken at 2.5 s under the drive 0.25 → 0.5 over [2.25, 2.5]: the restored fields
/// must be solved with the door where it was at 2.01 s (`SimState::fields_built` keeps the
/// bodies' parameters of the last solve; it kept only its time, and the door was put where the
/// current drive says it was, 0.25 instead of about 0.01).
#[test]
fn with_field_update_a_state_taken_during_a_ramp_gives_the_same_continuation() {
    let mut scene = Scene::from_file(corridor()).unwrap();
    scene.model.field_update = Some(0.5);
    let dir = std::env::temp_dir().join(format!("moreau-fmu-ramp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("corridor-door-fields.toml");
    std::fs::write(&path, scene.to_toml()).unwrap();
    let ramp = |k: usize| (0.25 * (k as f64 - 7.0)).clamp(0.0, 1.0);
    let mut fmu = Fmu::instantiate(true, Some(&path.display().to_string()));
    fmu.initialize();
    for k in 0..10 {
        fmu.set_ok(DOOR, ramp(k));
        fmu.do_step(k as f64 * H, H);
    }
    let state = fmu.get_state();
    let go_on = |fmu: &mut Fmu| -> Vec<Outputs> {
        (10..30)
            .map(|k| {
                fmu.set_ok(DOOR, ramp(k));
                fmu.do_step(k as f64 * H, H);
                fmu.outputs()
            })
            .collect()
    };
    let straight = go_on(&mut fmu);
    fmu.set_state(state);
    let again = go_on(&mut fmu);
    fmu.free_state(state);
    std::fs::remove_dir_all(&dir).unwrap();
    let first = straight.iter().zip(&again).position(|(a, b)| a != b);
    assert_eq!(
        first, None,
        "the continuations differ from step {first:?} on"
    );
}
