//! The paper's room end to end: no overlap beyond the certified bound (checked here, O(N²)),
//! and the fast solver's velocities match Clarabel's within the certified tolerance.

mod common;

use common::worst_overlap;
use moreau_core::StepReport;
use moreau_crowd::{Frame, Observer, ObserverError, Scene, Simulation};

fn room() -> Scene {
    Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/room-150.toml"
    ))
    .unwrap()
}

#[test]
fn the_room_runs_to_the_horizon_without_overlap() {
    let scene = room();
    let mut sim = Simulation::new(scene.clone()).unwrap();
    assert_eq!(sim.total_people(), 150);
    let bound = scene.solver.max_violation;
    struct Check<'a> {
        scene: &'a Scene,
        bound: f64,
        frames: usize,
        worst: f64,
        max_reported: f64,
        last_t: f64,
    }
    impl Observer for Check<'_> {
        fn step(&mut self, r: &StepReport) -> Result<(), ObserverError> {
            assert!(r.status.is_converged());
            assert!(
                r.eps <= r.eps_target * (1.0 + 1e-12),
                "step {}: ε {} above {}",
                r.step,
                r.eps,
                r.eps_target
            );
            self.max_reported = self.max_reported.max(r.violation);
            Ok(())
        }
        fn frame(&mut self, f: &Frame<'_>) -> Result<(), ObserverError> {
            assert!(f.positions.iter().all(|x| x.is_finite()));
            let (d, w) = worst_overlap(self.scene, f.positions, f.radii);
            // The linearized constraints are inner approximations: overlap only up to the
            // certified violation of the last step (plus rounding).
            assert!(
                d <= self.bound + 1e-12 && w <= self.bound + 1e-12,
                "t = {}: overlaps {d} (disks), {w} (walls)",
                f.t
            );
            self.worst = self.worst.max(d).max(w);
            self.frames += 1;
            self.last_t = f.t;
            Ok(())
        }
    }
    let mut check = Check {
        scene: &scene,
        bound,
        frames: 0,
        worst: 0.0,
        max_reported: 0.0,
        last_t: 0.0,
    };
    sim.run(&mut check).unwrap();
    let Check {
        frames,
        worst,
        max_reported,
        last_t,
        ..
    } = check;
    assert_eq!(frames, 201);
    assert!((last_t - 20.0).abs() < 1e-9);
    assert!(max_reported <= bound);
    // As many through the door as an independent solver lets through: within the range
    // Clarabel gives over seeds (CLARABEL_PASSED), widened by one seed-to-seed spread.
    let out = sim.exit_records().len();
    let (lo, hi) = (CLARABEL_PASSED[0] - 8, CLARABEL_PASSED[5] + 8);
    assert!(
        (lo..=hi).contains(&out),
        "{out} people passed the door, not in {lo}..={hi}"
    );
    // The state keeps its size (people continue to the target area).
    assert_eq!(sim.frame().ids.len(), 150);
    eprintln!(
        "worst overlap {worst:e}, max reported violation {max_reported:e}, {out} through the door"
    );
}

/// People through the door in 20 s with every projection solved by Clarabel (the reference
/// interior point, not ours), for seeds 1 to 6, sorted: `moreau run` of room-150.toml with
/// `seed = s` and `[solver] kind = "clarabel"`, 2026-11-23. The count is chaotic in the seed
/// and in the solver's rounding (the same seed gives up to 8 more or fewer with another
/// solver); its median over seeds is the stable statistic.
const CLARABEL_PASSED: [usize; 6] = [114, 116, 121, 122, 125, 131];

/// The median over seeds of the people through the door with the scene's own solver lies
/// within two standard errors (±8: a seed-to-seed spread of ~6, a median of six) of
/// Clarabel's median.
#[test]
fn the_rooms_passing_count_matches_clarabels_over_seeds() {
    let mut counts: Vec<usize> = (1..=6)
        .map(|seed| {
            let mut scene = room();
            scene.seed = seed;
            let mut sim = Simulation::new(scene).unwrap();
            sim.run(&mut ()).unwrap();
            sim.exit_records().len()
        })
        .collect();
    counts.sort_unstable();
    let median = |c: &[usize]| (c[2] + c[3]) as f64 / 2.0;
    let (ours, reference) = (median(&counts), median(&CLARABEL_PASSED));
    assert!(
        (ours - reference).abs() <= 8.0,
        "median {ours} through the door over seeds 1–6 ({counts:?}), Clarabel's {reference}"
    );
}

#[test]
fn fast_solver_matches_clarabel_within_the_certified_tolerance_on_the_room() {
    let mut sim = Simulation::new(room()).unwrap();
    let (mut compared, mut worst_ratio) = (0, 0.0f64);
    for k in 0..160 {
        let before = sim.frame().positions.to_vec();
        let report = sim.step(0.05).unwrap();
        if k % 8 != 0 {
            continue;
        }
        worst_ratio = worst_ratio.max(common::assert_matches_clarabel(&sim, &before, &report));
        // The comparison is not vacuous: contacts are active.
        if report.active > 0 {
            compared += 1;
        }
    }
    assert!(compared >= 15, "only {compared} steps with contacts");
    eprintln!("largest |Δv| / certified radius: {worst_ratio:.3}");
}
