//! Stepping one step at a time (`advance_step`, what the Python module's `step` and
//! `advance_to` call) against `advance_to` in one go, and removing people during a run
//! (`remove_people`).

use moreau_core::StepReport;
use moreau_crowd::{Frame, Observer, ObserverError, Scene, Simulation};

fn room(horizon: f64) -> Scene {
    let mut scene = Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/room-60.toml"
    ))
    .unwrap();
    scene.time.horizon = horizon;
    scene
}

/// Every step's time and size, every frame's time and positions, as bits.
#[derive(Default, PartialEq, Debug)]
struct Trace {
    steps: Vec<(u64, u64)>,
    frames: Vec<(u64, Vec<u64>)>,
}

impl Observer for Trace {
    fn step(&mut self, r: &StepReport) -> Result<(), ObserverError> {
        self.steps.push((r.t.to_bits(), r.mu.to_bits()));
        Ok(())
    }
    fn frame(&mut self, f: &Frame<'_>) -> Result<(), ObserverError> {
        let bits = f.positions.iter().map(|x| x.to_bits()).collect();
        self.frames.push((f.t.to_bits(), bits));
        Ok(())
    }
}

#[test]
fn advance_step_until_none_is_advance_to() {
    let scene = room(3.0);
    let mut whole = Simulation::new(scene.clone()).unwrap();
    let mut expected = Trace::default();
    whole.advance_to(1.33, &mut expected).unwrap();
    whole.advance_to(3.0, &mut expected).unwrap();

    let mut stepped = Simulation::new(scene).unwrap();
    let mut got = Trace::default();
    for t_end in [1.33, 3.0] {
        let mut reports = 0;
        while let Some(r) = stepped.advance_step(t_end, &mut got).unwrap() {
            assert!(r.t <= t_end + 1e-9, "a step past t_end: {} > {t_end}", r.t);
            reports += 1;
        }
        assert!(reports > 0);
        // Reached: more calls take no step and report nothing.
        let frames = got.frames.len();
        assert!(stepped.advance_step(t_end, &mut got).unwrap().is_none());
        assert_eq!(got.frames.len(), frames);
    }
    assert_eq!(got, expected);
    assert_eq!(stepped.people().positions(), whole.people().positions());
    assert!(stepped.advance_step(f64::NAN, &mut ()).is_err());
}

#[test]
fn removed_people_leave_and_the_others_go_on() {
    let scene = room(2.0);
    let mut sim = Simulation::new(scene.clone()).unwrap();
    sim.advance_to(1.0, &mut ()).unwrap();
    let before = sim.people().clone();
    // Everyone in the left half of the room.
    let inside = |p: [f64; 2]| p[0] < 5.0;
    let expect: Vec<u32> = (0..before.len())
        .filter(|&i| !inside(before.position(i)))
        .map(|i| before.ids()[i])
        .collect();
    assert!(!expect.is_empty() && expect.len() < before.len());
    let mut seen = Vec::new();
    let removed = sim.remove_people(|id, p| {
        seen.push(id);
        inside(p)
    });
    assert_eq!(seen, before.ids(), "asked once for everyone, in order");
    assert_eq!(removed, before.len() - expect.len());
    assert_eq!(sim.people().ids(), expect.as_slice());
    for (k, &id) in expect.iter().enumerate() {
        let i = before.index_of(id).unwrap();
        assert_eq!(sim.people().position(k), before.position(i));
        assert_eq!(sim.people().radii()[k], before.radii()[i]);
        assert_eq!(sim.people().places()[k], before.places()[i]);
    }
    assert!(sim.exit_records().iter().all(|r| expect.contains(&r.id)));
    sim.advance_to(2.0, &mut ()).unwrap();
    assert!(sim.people().ids().iter().all(|id| expect.contains(id)));
    assert!(sim.min_gap(0.5) >= -1e-6, "no overlap after the removal");

    // Removing nobody changes nothing: the run goes on bit for bit.
    let mut a = Simulation::new(scene.clone()).unwrap();
    let mut b = Simulation::new(scene).unwrap();
    a.advance_to(1.0, &mut ()).unwrap();
    b.advance_to(1.0, &mut ()).unwrap();
    assert_eq!(b.remove_people(|_, _| false), 0);
    a.advance_to(2.0, &mut ()).unwrap();
    b.advance_to(2.0, &mut ()).unwrap();
    assert_eq!(a.people().positions(), b.people().positions());
}
