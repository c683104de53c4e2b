//! The state of a run as a value: saved mid-run, serialized, restored into a new simulation
//! of the same scene, the run goes on bit for bit (positions, exits and step reports), with
//! fixed and with adaptive steps; a state of another scene, or damaged bytes, is refused.

use moreau_core::StepReport;
use moreau_crowd::{ExitRecord, Hall, Observer, ObserverError, Scene, SimState, Simulation};

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
    fn frame(&mut self, _f: &moreau_crowd::Frame<'_>) -> Result<(), ObserverError> {
        self.frames += 1;
        Ok(())
    }
}

/// Runs `scene` to `t_end` in one go, and again stopping at `t_save`, saving the state
/// (through its binary form and through JSON), restoring it into a fresh simulation and going
/// on: both must agree bit for bit.
fn round_trip(scene: Scene, t_save: f64, t_end: f64) -> (usize, usize) {
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
        assert_eq!(before.frames + after.frames, all.frames, "frames");
        assert_eq!(second.frame().ids, whole.frame().ids);
        // Bit for bit: compare the bits, not within a tolerance.
        let bits = |q: &[f64]| q.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(second.frame().positions),
            bits(whole.frame().positions)
        );
        assert_eq!(second.state(), whole.state());
    }
    (all.steps.len(), all.exits.len())
}

#[test]
fn a_restored_state_continues_bit_for_bit_with_fixed_steps() {
    // 200 steps of 0.05 s, saved after 100: the queue at the door has formed by then.
    let (steps, exits) = round_trip(room(10.0), 5.0, 10.0);
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
    let (steps, exits) = round_trip(scene, 3.0, 6.0);
    assert!(steps > 60, "{steps} adaptive steps");
    assert!(exits > 0);
}

#[test]
fn a_restored_state_continues_bit_for_bit_when_people_leave() {
    // People who pass the hall's door are removed: the state shrinks before the save.
    let mut hall = Hall::new(400, 2.6);
    hall.horizon = 4.0;
    let (_, exits) = round_trip(hall.scene().unwrap(), 2.0, 4.0);
    assert!(exits > 5, "{exits} left");
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
    let mut newer = state.clone();
    newer.format += 1;
    let err = sim.restore(&newer).unwrap_err().to_string();
    assert!(err.contains("state.format"), "{err}");
}
