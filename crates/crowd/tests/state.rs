//! The state of a run as a value: saved mid-run, serialized, restored into a new simulation
//! of the same scene, the run goes on bit for bit (positions, exits, entries and step
//! reports), with fixed and with adaptive steps, with people leaving and entering; a state of
//! another scene, or damaged bytes, is refused.

use moreau_core::StepReport;
use moreau_crowd::{
    EntryRecord, ExitRecord, Hall, Observer, ObserverError, Scene, SimState, Simulation,
};

fn room(horizon: f64) -> Scene {
    let mut scene = Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/room-150.toml"
    ))
    .unwrap();
    scene.time.horizon = horizon;
    scene
}

/// Everything a step reports but its wall-clock timings.
fn essentials(r: &StepReport) -> String {
    format!(
        "{} {:?} {:?} {:?} {:?} {:?} {} {} {} {} {} {:?} {}",
        r.step,
        r.t,
        r.mu,
        r.eps_target,
        r.eps,
        r.violation,
        r.iterations,
        r.assembled,
        r.active,
        r.redone,
        r.rejected,
        r.status,
        r.solver
    )
}

#[derive(Default)]
struct Log {
    steps: Vec<String>,
    exits: Vec<ExitRecord>,
    entries: Vec<EntryRecord>,
    frames: usize,
}

impl Observer for Log {
    fn step(&mut self, r: &StepReport) -> Result<(), ObserverError> {
        self.steps.push(essentials(r));
        Ok(())
    }
    fn exit(&mut self, record: &ExitRecord) -> Result<(), ObserverError> {
        self.exits.push(*record);
        Ok(())
    }
    fn enter(&mut self, record: &EntryRecord) -> Result<(), ObserverError> {
        self.entries.push(*record);
        Ok(())
    }
    fn frame(&mut self, _f: &moreau_crowd::Frame<'_>) -> Result<(), ObserverError> {
        self.frames += 1;
        Ok(())
    }
}

/// Runs `scene` to `t_end` in one go, and again stopping at `t_save`, saving the state
/// (through its binary form and through JSON), restoring it into a fresh simulation and going
/// on: both must agree bit for bit. Returns the steps and exits of the whole run, and the
/// saved state.
fn round_trip(scene: Scene, t_save: f64, t_end: f64) -> (usize, usize, SimState) {
    let mut whole = Simulation::new(scene.clone()).unwrap();
    let mut all = Log::default();
    whole.advance_to(t_end, &mut all).unwrap();

    let mut first = Simulation::new(scene.clone()).unwrap();
    let mut before = Log::default();
    first.advance_to(t_save, &mut before).unwrap();
    let saved = first.state();
    let bytes = saved.to_bytes();
    let from_bytes = SimState::from_bytes(&bytes).unwrap();
    assert_eq!(from_bytes, saved, "the binary form round-trips");
    let json = serde_json::to_string(&saved).unwrap();
    let from_json: SimState = serde_json::from_str(&json).unwrap();
    assert_eq!(from_json, saved, "JSON round-trips");
    drop(first);

    for state in [from_bytes, from_json] {
        let mut second = Simulation::new(scene.clone()).unwrap();
        second.restore(&state).unwrap();
        let mut after = Log::default();
        second.advance_to(t_end, &mut after).unwrap();
        let steps: Vec<String> = before.steps.iter().chain(&after.steps).cloned().collect();
        assert_eq!(steps, all.steps, "step reports");
        let exits: Vec<ExitRecord> = before.exits.iter().chain(&after.exits).copied().collect();
        assert_eq!(exits, all.exits, "exit records");
        let entries: Vec<EntryRecord> = before
            .entries
            .iter()
            .chain(&after.entries)
            .copied()
            .collect();
        assert_eq!(entries, all.entries, "entry records");
        assert_eq!(before.frames + after.frames, all.frames, "frames");
        assert_eq!(second.frame().ids, whole.frame().ids);
        // Bit for bit: compare the bits, not within a tolerance.
        let bits = |q: &[f64]| q.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(second.frame().positions),
            bits(whole.frame().positions)
        );
        assert_eq!(second.state(), whole.state());
        assert_eq!(second.total_people(), whole.total_people());
    }
    (all.steps.len(), all.exits.len(), saved)
}

#[test]
fn a_restored_state_continues_bit_for_bit_with_fixed_steps() {
    // 200 steps of 0.05 s, saved after 100: the queue at the door has formed by then.
    let (steps, exits, _) = round_trip(room(10.0), 5.0, 10.0);
    assert_eq!(steps, 200);
    assert!(
        exits > 10,
        "only {exits} through the door: the test would not see exits"
    );
}

#[test]
fn a_restored_state_continues_bit_for_bit_with_adaptive_steps() {
    let mut scene = room(6.0);
    scene.time.tol = Some(0.01);
    let (steps, exits, _) = round_trip(scene, 3.0, 6.0);
    assert!(steps > 60, "{steps} adaptive steps");
    assert!(exits > 0);
}

#[test]
fn a_restored_state_continues_bit_for_bit_when_people_leave() {
    // People who pass the hall's door are removed: the state shrinks before the save.
    let mut hall = Hall::new(400, 2.6);
    hall.horizon = 4.0;
    let (_, exits, _) = round_trip(hall.scene().unwrap(), 2.0, 4.0);
    assert!(exits > 5, "{exits} left");
}

/// A corridor with a group released at 1.5 s in front of a gate whose inflow (6 a second,
/// radii drawn) outruns what its 0.3 m square takes (one person at a time): a queue waits.
fn gate_with_a_queue(horizon: f64) -> Scene {
    let text = format!(
        r#"
name = "queue"
seed = 5
[area]
outer = [[0.0, 0.0], [12.0, 0.0], [12.0, 3.0], [0.0, 3.0]]
[[exits]]
name = "end"
area = [[11.5, 0.0], [12.0, 0.0], [12.0, 3.0], [11.5, 3.0]]
action = "remove"
[[groups]]
name = "waiting"
count = 8
spawn = [[2.0, 0.0], [4.0, 0.0], [4.0, 3.0], [2.0, 3.0]]
radius = 0.2
speed = 1.0
destination = "end"
release = 1.5
[[sources]]
name = "turnstile"
area = [[0.5, 1.35], [0.8, 1.35], [0.8, 1.65], [0.5, 1.65]]
rate = 6.0
stop = 3.0
radius = {{ min = 0.2, max = 0.25 }}
speed = {{ min = 1.1, max = 1.4 }}
destination = "end"
[time]
horizon = {horizon}
step = 0.05
output_interval = 0.25
[solver]
eps_kappa = 1e-3
max_violation = 1e-6
"#
    );
    Scene::from_toml(&text, "queue").unwrap()
}

#[test]
fn a_restored_state_continues_bit_for_bit_mid_inflow_with_a_queue() {
    // Saved at 1.2 s: the group still stands, the source owes 7 and has placed fewer, the
    // first waiting has a radius drawn.
    let (_, exits, saved) = round_trip(gate_with_a_queue(10.0), 1.2, 10.0);
    let inflow = saved.inflow[0];
    assert!(
        inflow.emitted >= 1 && inflow.emitted < 7,
        "{} placed by 1.2 s: no queue to save",
        inflow.emitted
    );
    assert!(inflow.waiting_radius.is_some(), "{inflow:?}");
    assert!(exits > 5, "{exits} left");
}

#[test]
fn a_restored_state_continues_bit_for_bit_mid_inflow_with_adaptive_steps() {
    let mut scene = gate_with_a_queue(6.0);
    scene.time.tol = Some(0.01);
    let (steps, _, saved) = round_trip(scene, 2.0, 6.0);
    assert!(steps > 20, "{steps} adaptive steps");
    assert!(saved.inflow[0].emitted >= 1);
}

#[test]
fn the_gate_inflow_scene_restores_bit_for_bit_before_its_release() {
    let mut scene = Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/gate-inflow.toml"
    ))
    .unwrap();
    scene.time.horizon = 8.0;
    let (_, _, saved) = round_trip(scene, 4.0, 8.0);
    assert_eq!(saved.inflow[0].emitted, 12);
}

#[test]
fn a_state_of_another_scene_or_damaged_bytes_is_refused_and_changes_nothing() {
    let mut sim = Simulation::new(room(2.0)).unwrap();
    sim.advance_to(1.0, &mut ()).unwrap();
    let state = sim.state();
    let mut other_scene = room(2.0);
    other_scene.seed += 1;
    let mut other = Simulation::new(other_scene).unwrap();
    let before = other.state();
    let err = other.restore(&state).unwrap_err().to_string();
    assert!(err.contains("state.scene_hash"), "{err}");
    assert_eq!(other.state(), before, "a refused restore changes nothing");

    let bytes = state.to_bytes();
    let err = SimState::from_bytes(&bytes[..bytes.len() / 2])
        .unwrap_err()
        .to_string();
    assert!(err.contains("state"), "{err}");
    // A place naming an exit the scene does not have (a damaged or forged state).
    let mut forged: serde_json::Value = serde_json::to_value(&state).unwrap();
    forged["people"]["place"][0] = serde_json::json!({"ToExit": 7});
    let forged: SimState = serde_json::from_value(forged).unwrap();
    let err = sim.restore(&forged).unwrap_err().to_string();
    assert!(
        err.contains("state.people") && err.contains("ToExit(7)"),
        "{err}"
    );
    // Inflow state for a source the scene does not have.
    let mut forged = state.clone();
    forged.inflow.push(moreau_crowd::InflowState {
        emitted: 3,
        waiting_radius: None,
        rng_word: 0,
    });
    let err = sim.restore(&forged).unwrap_err().to_string();
    assert!(
        err.contains("state.inflow") && err.contains("1 sources"),
        "{err}"
    );
    // Regression: a speed factor that is not a number was refused as `state.time` (with the
    // time's value), and a negative one, or a time before the run's start, was taken (from
    // t = −65,536 s the run stepped for minutes to reach the next frame).
    for (field, forge) in [
        (
            "state.speed_factor = NaN",
            (|s: &mut SimState| s.speed_factor = f64::NAN) as fn(&mut SimState),
        ),
        ("state.speed_factor = -0.5", |s| s.speed_factor = -0.5),
        ("state.time = -65536", |s| s.time = -65536.0),
        ("state.time = inf", |s| s.time = f64::INFINITY),
    ] {
        let mut forged = state.clone();
        forge(&mut forged);
        let err = sim.restore(&forged).unwrap_err().to_string();
        assert!(err.contains(field), "{field}: {err}");
    }
    // Regression: a person's radius or desired speed not a number, zero or negative, was
    // taken (the steps then failed, or went on with a person of no size).
    let people = |radius: f64, speed: f64| {
        let mut forged: serde_json::Value = serde_json::to_value(&state).unwrap();
        forged["people"]["radius"][3] = serde_json::json!(radius);
        forged["people"]["speed"][5] = serde_json::json!(speed);
        serde_json::from_value::<SimState>(forged).unwrap()
    };
    for (forged, what) in [
        (people(0.0, 1.0), "radius 0 of person index 3"),
        (people(-0.2, 1.0), "radius -0.2 of person index 3"),
        (people(0.25, -1.0), "desired speed -1 of person index 5"),
    ] {
        let err = sim.restore(&forged).unwrap_err().to_string();
        assert!(
            err.contains("state.people") && err.contains(what),
            "{what}: {err}"
        );
    }
    assert!(sim.restore(&people(0.25, 1.0)).is_ok());
    // Regression: a person 10³⁰⁰ m away was taken, and the next step failed on a
    // non-finite right-hand side instead of the restore naming the person.
    let mut forged: serde_json::Value = serde_json::to_value(&state).unwrap();
    forged["people"]["position"][9] = serde_json::json!(-1e300);
    let forged: SimState = serde_json::from_value(forged).unwrap();
    let err = sim.restore(&forged).unwrap_err().to_string();
    assert!(
        err.contains("state.people") && err.contains("-1e300 of person index 4"),
        "{err}"
    );
    let mut newer = state.clone();
    newer.format += 1;
    let err = sim.restore(&newer).unwrap_err().to_string();
    assert!(err.contains("state.format"), "{err}");
}

/// The factor on the desired speeds is part of the state: a fresh simulation (factor 1)
/// restored from a slowed run reads the slowed run's factor and goes on as it did.
#[test]
fn a_restored_state_keeps_the_speed_factor() {
    let scene = room(2.0);
    let slowed = |t: f64| {
        let mut sim = Simulation::new(scene.clone()).unwrap();
        sim.set_speed_factor(0.5);
        sim.advance_to(t, &mut Log::default()).unwrap();
        sim
    };
    let whole = slowed(2.0);
    let saved = slowed(1.0).state();
    let mut restored = Simulation::new(scene.clone()).unwrap();
    assert_eq!(restored.speed_factor(), 1.0);
    restored.restore(&saved).unwrap();
    assert_eq!(restored.speed_factor(), 0.5);
    restored.advance_to(2.0, &mut Log::default()).unwrap();
    let bits = |q: &[f64]| q.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(restored.frame().positions),
        bits(whole.frame().positions)
    );
    // At full speed the same scene ends elsewhere: the factor was not lost on the way.
    let mut full = Simulation::new(scene).unwrap();
    full.advance_to(2.0, &mut Log::default()).unwrap();
    assert_ne!(bits(full.frame().positions), bits(whole.frame().positions));
}

/// A saved state is a file the user hands back: with any byte of it damaged (flipped,
/// zeroed, set to the largest exponents), it is refused with a reason (when read or
/// restored: the field and value named; when stepped: the step's error), or it runs; never a
/// panic. The paper's room mid-run, and a
/// gate mid-inflow with its queue held (inflow and release state). At least some damaged
/// states must be refused, and some must run, or the test proves nothing. (Every byte of
/// both, `MOREAU_STATE_FUZZ_ALL=1`: no panic in session 30.)
#[test]
fn a_state_damaged_at_any_byte_is_refused_or_runs_never_a_panic() {
    use rand::{Rng, SeedableRng};
    let all = std::env::var_os("MOREAU_STATE_FUZZ_ALL").is_some();
    for (scene, (t_save, t_end)) in [
        (room(1.2), (1.0, 1.2)),
        (gate_with_a_queue(2.0), (1.0, 1.3)),
    ] {
        let mut sim = Simulation::new(scene.clone()).unwrap();
        sim.advance_to(t_save, &mut ()).unwrap();
        let bytes = sim.state().to_bytes();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(30);
        let mut places: Vec<usize> = (0..bytes.len().min(64)).collect();
        if all {
            places.extend(64..bytes.len());
        } else {
            places.extend((0..300).map(|_| rng.random_range(0..bytes.len())));
        }
        let (mut refused, mut ran) = (0, 0);
        for &at in &places {
            for bad in [bytes[at] ^ 0xff, 0x00, 0x7f, 0xff, bytes[at] ^ 0x01] {
                let mut damaged = bytes.clone();
                damaged[at] = bad;
                let outcome = std::panic::catch_unwind(|| {
                    let state = SimState::from_bytes(&damaged).map_err(|e| e.to_string())?;
                    let mut again = Simulation::new(scene.clone()).unwrap();
                    again.restore(&state).map_err(|e| e.to_string())?;
                    again.advance_to(t_end, &mut ()).map_err(|e| e.to_string())
                });
                let name = &scene.name;
                match outcome {
                    Ok(Ok(())) => ran += 1,
                    Ok(Err(why)) => {
                        assert!(!why.is_empty(), "{name}: byte {at} set to {bad}: no reason");
                        refused += 1;
                    }
                    Err(_) => panic!(
                        "{name}: byte {at} of {} set to {bad:#04x}: a panic",
                        bytes.len()
                    ),
                }
            }
        }
        assert!(
            refused > 0 && ran > 0,
            "{}: {refused} refused, {ran} ran",
            scene.name
        );
    }
}

/// Regression: the thread count was part of the scene's hash, so a state saved on one thread
/// count was refused on another ("saved from another scene"), and a run killed on a larger
/// machine could not go on on a smaller one, though results do not depend on it. A state
/// saved at one thread goes on at two bit for bit; a state saved before (its hash the whole
/// TOML's, threads included: FNV-1a written out here) still restores at its own count.
#[test]
fn a_state_saved_at_one_thread_count_was_refused_at_another() {
    let one = room(4.0);
    let mut two = one.clone();
    two.solver.threads = 2;
    let mut whole = Simulation::new(one.clone()).unwrap();
    whole.advance_to(4.0, &mut Log::default()).unwrap();
    let mut first = Simulation::new(one).unwrap();
    first.advance_to(2.0, &mut Log::default()).unwrap();
    let mut second = Simulation::new(two.clone()).unwrap();
    second.restore(&first.state()).unwrap();
    second.advance_to(4.0, &mut Log::default()).unwrap();
    let bits = |q: &[f64]| q.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(second.frame().positions),
        bits(whole.frame().positions)
    );
    // A state of the older builds: the hash of the whole TOML.
    let fnv = |text: String| {
        text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
        })
    };
    let mut older = Simulation::new(two.clone()).unwrap();
    let mut state = older.state();
    assert_ne!(
        state.scene_hash,
        fnv(two.to_toml()),
        "the hash leaves threads out"
    );
    state.scene_hash = fnv(two.to_toml());
    older.restore(&state).unwrap();
}
