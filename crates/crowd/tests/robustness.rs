//! Issue 20, item by item: every input that exhausted the machine (memory, time) or panicked
//! is refused before anything is allocated, with an error that names the field, the value and
//! the limit; misleading messages say what is wrong. Each test is named after what broke.

use moreau_crowd::{DistanceField, FieldError, Scene, Simulation, limits};

/// The small room (`data/scenes/room-60.toml`: 6 m × 6 m, 60 people, a door to a target area),
/// with each `(from, to)` replaced in its text.
fn room(edits: &[(&str, &str)]) -> String {
    let path = format!(
        "{}/../../data/scenes/room-60.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let mut text = std::fs::read_to_string(path).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "room-60.toml has no {from:?}");
        text = text.replace(from, to);
    }
    text
}

/// The error of reading, validating and building `text`, which must fail.
fn refused(text: &str) -> String {
    match Scene::from_toml(text, "<test>").and_then(Simulation::new) {
        Ok(_) => panic!("the scene was accepted"),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(msg: &str, needles: &[&str]) {
    for n in needles {
        assert!(msg.contains(n), "the error does not mention {n:?}: {msg}");
    }
}

#[test]
fn a_micrometre_grid_cell_aborted_on_a_200_terabyte_allocation() {
    let msg = refused(&room(&[("grid_cell = 0.1", "grid_cell = 1e-6")]));
    assert_mentions(&msg, &["solver.grid_cell", "1e-6", "cells", "limit", "4e6"]);
}

#[test]
fn a_100_km_room_aborted_on_its_distance_grid() {
    let msg = refused(&room(&[(
        "[12.0, 6.0], [6.2, 6.0]",
        "[1e5, 1e5], [6.2, 6.0]",
    )]));
    assert_mentions(&msg, &["solver.grid_cell", "cells", "limit"]);
}

#[test]
fn distance_field_build_allocated_whatever_grid_it_was_asked_for() {
    // The library call itself (the FMU and `run --from` build through it too).
    let huge = DistanceField::build([0.0, 0.0], [1e5, 1e5], 1e-3, |_| true, |_| true);
    assert!(
        matches!(huge, Err(FieldError::TooManyCells { .. })),
        "{huge:?}"
    );
    let text = huge.unwrap_err().to_string();
    assert_mentions(&text, &["1.000e16 cells", "limit"]);
    let nan = DistanceField::build([0.0, 0.0], [f64::INFINITY, 1.0], 0.1, |_| true, |_| true);
    assert!(matches!(nan, Err(FieldError::Invalid { .. })), "{nan:?}");
    // Within the limit it builds.
    assert!(DistanceField::build([0.0, 0.0], [10.0, 10.0], 0.1, |_| true, |p| p[0] > 9.9).is_ok());
}

#[test]
fn coordinates_of_1e300_panicked_inside_ndarray() {
    let msg = refused(&room(&[(
        "[12.0, 6.0], [6.2, 6.0]",
        "[1e300, 6.0], [6.2, 6.0]",
    )]));
    assert_mentions(&msg, &["area.outer[", "1e300", "within ±1e15"]);
}

#[test]
fn a_spawn_polygon_at_1e308_panicked_on_an_unwrap() {
    let msg = refused(&room(&[(
        "spawn = [[0.0, 0.0], [6.0, 0.0], [6.0, 6.0], [0.0, 6.0]]",
        "spawn = [[-1e308, -1e308], [1e308, -1e308], [1e308, 1e308], [-1e308, 1e308]]",
    )]));
    assert_mentions(&msg, &["groups[0].spawn[0]", "1e308", "within ±1e15"]);
    let msg = refused(&room(&[(
        "count = 60\nspawn = [[0.0, 0.0], [6.0, 0.0], [6.0, 6.0], [0.0, 6.0]]",
        "positions = [[1e16, 1.0]]",
    )]));
    assert_mentions(&msg, &["groups[0].positions[0]", "1e16"]);
}

#[test]
fn a_step_of_1e_300_overflowed_the_step_schedule() {
    let msg = refused(&room(&[("step = 0.05", "step = 1e-300")]));
    assert_mentions(&msg, &["time.step", "1e-300", "steps", "limit of 1e9"]);
}

#[test]
fn a_horizon_of_1e308_overflowed_the_step_schedule() {
    let msg = refused(&room(&[("horizon = 15.0", "horizon = 1e308")]));
    assert_mentions(&msg, &["time.", "1e308", "limit"]);
}

#[test]
fn a_horizon_of_1e7_with_millisecond_steps_allocated_160_gb() {
    let msg = refused(&room(&[
        ("horizon = 15.0", "horizon = 1e7"),
        ("step = 0.05", "step = 1e-3"),
        ("output_interval = 0.1", "output_interval = 10.0"),
    ]));
    assert_mentions(&msg, &["time.step", "1.000e10 steps", "limit of 1e9"]);
    // With adaptive steps, the bound is on their largest step.
    let msg = refused(&room(&[
        ("horizon = 15.0", "horizon = 1e12"),
        ("output_interval = 0.1", "output_interval = 1e5\ntol = 0.01"),
    ]));
    assert_mentions(&msg, &["time.horizon", "1000000000000", "limit of 1e9"]);
}

#[test]
fn an_output_interval_of_5e_324_was_blamed_on_fps() {
    let msg = refused(&room(&[(
        "output_interval = 0.1",
        "output_interval = 5e-324",
    )]));
    assert_mentions(&msg, &["time.output_interval", "5e-324", "frames", "limit"]);
    assert!(!msg.contains("fps"), "{msg}");
}

#[test]
fn ten_million_people_in_36_m2_took_hours_of_random_placement() {
    let msg = refused(&room(&[("count = 60", "count = 10000000")]));
    assert_mentions(
        &msg,
        &[
            "groups[0].count",
            "10000000",
            "densest packing",
            "people fit in the spawn region",
        ],
    );
}

#[test]
fn a_radius_of_1e300_was_printed_with_its_three_hundred_digits() {
    let msg = refused(&room(&[("radius = 0.2", "radius = 1e300")]));
    assert_mentions(&msg, &["groups[0].count", "disks of radius ≥ 1e300 m"]);
    assert!(msg.len() < 300, "{msg}");
}

#[test]
fn a_step_of_1e300_ended_the_run_at_t_0_as_complete() {
    // The stepping took what was left below a billionth of the step as reached: every frame
    // "reached" at t = 0, no step taken, and the run said it was complete.
    let text = room(&[("step = 0.05", "step = 1e300")]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let (horizon, interval) = (sim.scene().time.horizon, sim.scene().time.output_interval);
    let mut stats = moreau_core::RunStats::default();
    let mut mus = Vec::new();
    while let Some(report) = sim.advance_step(horizon, &mut stats).unwrap() {
        mus.push(report.mu);
    }
    assert_eq!(sim.time(), horizon);
    // Steps end at frames: one step of the output interval each.
    assert_eq!(mus.len(), (horizon / interval).round() as usize, "{mus:?}");
    assert!(mus.iter().all(|mu| (mu - interval).abs() < 1e-9), "{mus:?}");
    assert!(
        !sim.exit_records().is_empty(),
        "nobody passed the door in {horizon} s"
    );
}

#[test]
fn a_horizon_of_1e_minus_300_failed_its_first_step_as_not_certified() {
    // Its one step was certified to ε = κ μ³ = 0: "projection not certified (NumericalError):
    // ε = 0e0 for target 0e0". Now refused by name, with the shortest step the scene's ε allows
    // ((2.2·10⁻³⁰⁸ / 10⁻³)^⅓ = 2.813·10⁻¹⁰² s for room-60's eps_kappa = 10⁻³).
    let msg = refused(&room(&[("horizon = 15.0", "horizon = 1e-300")]));
    assert_mentions(
        &msg,
        &[
            "time.horizon",
            "1e-300",
            "2.813e-102 s",
            "solver.eps_kappa = 0.001",
        ],
    );
    assert!(msg.len() < 400, "{msg}");
    let msg = refused(&room(&[
        ("horizon = 15.0", "horizon = 1e-195"),
        ("step = 0.05", "step = 1e-200"),
    ]));
    assert_mentions(&msg, &["time.step", "1e-200", "2.813e-102 s"]);
    // Adaptive steps: their ε has a floor (2·10⁻⁷ μ²), so they go lower, but not to 10⁻¹⁶⁰.
    let msg = refused(&room(&[
        ("horizon = 15.0", "horizon = 1e-160"),
        ("output_interval = 0.1", "output_interval = 0.1\ntol = 0.01"),
    ]));
    assert_mentions(&msg, &["time.horizon", "1e-160", "3.335e-151 s"]);
    // Short steps above the bound run (the people are not in contact within them).
    for horizon in ["1e-12", "1e-90"] {
        let text = room(&[("horizon = 15.0", &format!("horizon = {horizon}"))]);
        let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
        let end = sim.scene().time.horizon;
        sim.advance_to(end, &mut ()).unwrap();
        assert_eq!((sim.time(), sim.steps()), (end, 1));
    }
}

#[test]
fn a_max_violation_of_1e300_let_people_overlap_by_0_4_m_as_certified() {
    // Every step was "within the bound": the bound is a tolerance on overlaps, and one as large
    // as a radius is none. Refused now, naming the radius it must stay below.
    for bound in ["1e300", "0.2"] {
        let msg = refused(&room(&[(
            "max_violation = 1e-6",
            &format!("max_violation = {bound}"),
        )]));
        assert_mentions(
            &msg,
            &["solver.max_violation", bound, "0.2 m (groups[0].radius)"],
        );
        assert!(msg.len() < 300, "{msg}");
    }
    // Below the smallest radius, however loose, is the scene's call.
    let text = room(&[("max_violation = 1e-6", "max_violation = 0.1")]);
    Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
}

/// The times of the frames a run writes.
#[derive(Default)]
struct FrameTimes(Vec<f64>);

impl moreau_crowd::Observer for FrameTimes {
    fn frame(&mut self, f: &moreau_crowd::Frame<'_>) -> Result<(), moreau_crowd::ObserverError> {
        self.0.push(f.t);
        Ok(())
    }
}

#[test]
fn a_horizon_of_0_3_s_with_frames_every_0_1_s_lost_its_last_frame() {
    // The horizon's frame was due only until the horizon was reached, so it was never
    // written: 0.25 s (a last frame cut short) and 0.3 s (3 × 0.1 = 0.30000000000000004 lies
    // past it) both ended at the frame of 0.2 s, the steps after it in the file with no frame
    // (and the Python module's `run` failed on "a state saved between frames").
    for (horizon, interval, step, want) in [
        (0.3, 0.1, 0.05, vec![0.0, 0.1, 0.2, 0.3]),
        (0.25, 0.1, 0.05, vec![0.0, 0.1, 0.2, 0.25]),
        (0.052, 0.1, 0.05, vec![0.0, 0.052]),
        (0.7, 0.1, 0.03, vec![0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]),
        (0.55, 0.5, 0.05, vec![0.0, 0.5, 0.55]),
        (1.0, 0.5, 0.05, vec![0.0, 0.5, 1.0]),
    ] {
        let text = room(&[
            ("horizon = 15.0", &format!("horizon = {horizon}")),
            ("step = 0.05", &format!("step = {step}")),
            (
                "output_interval = 0.1",
                &format!("output_interval = {interval}"),
            ),
        ]);
        let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
        let mut frames = FrameTimes::default();
        sim.run(&mut frames).unwrap();
        assert_eq!(
            frames.0.len(),
            want.len(),
            "{horizon} / {interval}: {:?}",
            frames.0
        );
        for (t, w) in frames.0.iter().zip(&want) {
            assert!(
                (t - w).abs() < 1e-12,
                "{horizon} / {interval}: {:?}",
                frames.0
            );
        }
        assert_eq!(sim.frames(), want.len());
    }
    // Past the horizon the output times go on (co-simulation hosts step past it).
    let text = room(&[("horizon = 15.0", "horizon = 0.25")]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let mut frames = FrameTimes::default();
    sim.advance_to(0.5, &mut frames).unwrap();
    let want = [0.0, 0.1, 0.2, 0.25, 0.3, 0.4, 0.5];
    assert_eq!(frames.0.len(), want.len(), "{:?}", frames.0);
    for (t, w) in frames.0.iter().zip(&want) {
        assert!((t - w).abs() < 1e-12, "{:?}", frames.0);
    }
}

#[test]
fn advance_to_0_6_gave_the_frame_of_0_6_s_one_call_late() {
    // Frame 6 is due at 6 × 0.1 = 0.6000000000000001 s: `advance_to(0.6)` ended its last
    // step at 0.6 s, within rounding of that frame, yet gave it only on the next call (so a
    // host that reads the frames after each call missed it, as at 0.3 and 0.7 s).
    let text = room(&[("horizon = 15.0", "horizon = 1.0")]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let mut frames = FrameTimes::default();
    for k in 1..=10 {
        let t = k as f64 / 10.0;
        sim.advance_to(t, &mut frames).unwrap();
        assert_eq!(
            frames.0.len(),
            k + 1,
            "after advance_to({t}): {:?}",
            frames.0
        );
        let last = *frames.0.last().unwrap();
        assert!((last - t).abs() < 1e-12, "after advance_to({t}): {last}");
        assert_eq!(sim.frames(), k + 1);
    }
    // The frames and the steps are those of one call to the horizon.
    let mut once = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let mut all = FrameTimes::default();
    once.run(&mut all).unwrap();
    assert_eq!(all.0.len(), frames.0.len());
    for (a, b) in all.0.iter().zip(&frames.0) {
        assert!((a - b).abs() < 1e-12, "{:?} against {:?}", all.0, frames.0);
    }
    assert_eq!(once.steps(), sim.steps());
}

/// Regression: `advance_to(2.4)` with the frame at 24 × 0.1 = 2.4000000000000004 ended its
/// step at 2.4, one ulp before the frame a run to the horizon steps to, and with adaptive
/// steps every step after it differed from that run's (positions by up to 2·10⁻⁹ m). Asked at
/// the output times written in decimal, the run is the run to the horizon, bit for bit; and
/// asked the same time twice, the second call does nothing.
#[test]
fn advance_to_2_4_stopped_one_ulp_before_the_frame_and_the_steps_after_it_differed() {
    let text = room(&[("horizon = 15.0", "horizon = 4.0\ntol = 0.01")]);
    let scene = || Scene::from_toml(&text, "<test>").unwrap();
    let mut once = Simulation::new(scene()).unwrap();
    once.run(&mut FrameTimes::default()).unwrap();
    let mut decimal = Simulation::new(scene()).unwrap();
    let mut frames = FrameTimes::default();
    for k in 1..=40 {
        let t: f64 = format!("{}.{}", k / 10, k % 10).parse().unwrap();
        decimal.advance_to(t, &mut frames).unwrap();
        decimal.advance_to(t, &mut frames).unwrap();
        assert_eq!(frames.0.len(), k + 1, "after advance_to({t})");
    }
    assert_eq!(decimal.steps(), once.steps());
    let bits = |q: &[f64]| q.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(decimal.frame().positions),
        bits(once.frame().positions)
    );
    assert_eq!(decimal.exit_records(), once.exit_records());
}

#[test]
fn a_horizon_of_0_700000001_s_failed_its_last_step_of_1e_minus_9_s() {
    // A stop just past a multiple of the step left a last step of 10⁻⁹ s, whose ε = κ μ³
    // (~10⁻³⁰) no projection certifies in doubles: `moreau run` failed at the horizon, and a
    // host whose communication step is 0.05 s in single precision failed at t = 1.65 s.
    let text = room(&[("horizon = 15.0", "horizon = 0.700000001")]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let mut frames = FrameTimes::default();
    sim.run(&mut frames).unwrap();
    assert_eq!(sim.steps(), 14);
    assert!((sim.time() - 0.700000001).abs() < 1e-15);
    // The output time 0.7 s is the horizon's frame.
    assert_eq!(frames.0.len(), 8, "{:?}", frames.0);
    assert_eq!(*frames.0.last().unwrap(), 0.700000001);
    // A horizon shorter than the shortest span keeps its frame (the first frame, at the
    // start, is not the horizon's).
    let text = room(&[("horizon = 15.0", "horizon = 0.0001")]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let mut frames = FrameTimes::default();
    sim.run(&mut frames).unwrap();
    assert_eq!(frames.0, [0.0, 0.0001]);
    // Frames every 0.1 ms, ten in the last 1 % of a 0.05 s step: each its own, none doubled
    // at the horizon.
    let text = room(&[
        ("horizon = 15.0", "horizon = 0.002"),
        ("output_interval = 0.1", "output_interval = 0.0001"),
    ]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let mut frames = FrameTimes::default();
    sim.run(&mut frames).unwrap();
    assert_eq!(frames.0.len(), 21, "{:?}", frames.0);
    assert!(frames.0.windows(2).all(|w| w[1] > w[0]), "{:?}", frames.0);
    let text = room(&[]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let h = 0.05_f32 as f64;
    for k in 1..=40 {
        sim.advance_to(k as f64 * h, &mut ())
            .unwrap_or_else(|e| panic!("advance_to({}): {e}", k as f64 * h));
    }
    assert_eq!(sim.steps(), 40, "one step a communication step");
}

#[test]
fn advance_to_1e300_asked_for_10_to_the_301_steps_and_ran_until_killed() {
    let text = room(&[]);
    let mut sim = Simulation::new(Scene::from_toml(&text, "<test>").unwrap()).unwrap();
    let msg = sim.advance_to(1e300, &mut ()).unwrap_err().to_string();
    assert_mentions(
        &msg,
        &["t_end", "1e300", "2.000e301 steps of at most 0.05 s", "1e9"],
    );
    assert!(msg.len() < 300, "{msg}");
    assert_eq!((sim.time(), sim.steps()), (0.0, 0), "nothing was stepped");
    // Up to the limit is fine: past the horizon too (co-simulation hosts go on).
    sim.check_t_end(1e9 * 0.05).unwrap();
    sim.advance_to(20.0, &mut ()).unwrap();
    assert_eq!(sim.time(), 20.0);
}

#[test]
fn a_thousand_threads_were_accepted_and_never_finished() {
    let msg = refused(&room(&[(
        "grid_cell = 0.1",
        "grid_cell = 0.1\nthreads = 1024",
    )]));
    let most = limits::max_threads();
    assert_mentions(
        &msg,
        &["solver.threads", "1024", &format!("at most {most}")],
    );
    // Every core (0) and up to the limit are fine.
    for threads in [0, most] {
        let ok = room(&[(
            "grid_cell = 0.1",
            &format!("grid_cell = 0.1\nthreads = {threads}"),
        )]);
        Simulation::new(Scene::from_toml(&ok, "<test>").unwrap()).unwrap();
    }
}

#[test]
fn a_self_intersecting_area_was_reported_as_an_unreachable_destination() {
    // A bow tie: the last two vertices swapped.
    let text = room(&[(
        "[12.0, 6.0], [6.2, 6.0], [6.2, 3.5], [6.0, 3.5], [6.0, 6.0], [0.0, 6.0],",
        "[12.0, 6.0], [6.2, 6.0], [6.2, 3.5], [6.0, 3.5], [0.0, 6.0], [6.0, 6.0],",
    )]);
    let msg = refused(&text);
    assert_mentions(&msg, &["area.outer", "crosses itself"]);
    assert!(!msg.contains("unreachable"), "{msg}");
}

#[test]
fn an_exit_covering_the_whole_room_evacuated_everyone_at_the_first_step() {
    let text = room(&[(
        "area = [[6.0, 2.5], [6.2, 2.5], [6.2, 3.5], [6.0, 3.5]]",
        "area = [[-1.0, -1.0], [13.0, -1.0], [13.0, 7.0], [-1.0, 7.0]]",
    )]);
    let msg = refused(&text);
    assert_mentions(&msg, &["exits[0].area", "door", "starts at", "first step"]);
}
