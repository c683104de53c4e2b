//! The paper's room end to end: no overlap beyond the certified bound (checked here, O(N²)),
//! and the fast solver's velocities match Clarabel's within the certified tolerance.

use moreau_crowd::{Scene, Simulation};
use moreau_solve::{
    ClarabelReference, ClarabelSettings, ProjectionProblem, ProjectionSolution, ProjectionSolver,
    Target,
};

fn room() -> Scene {
    Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/room-150.toml"
    ))
    .unwrap()
}

/// The largest overlap between two disks, and of a disk with a wall, computed directly.
fn worst_overlap(scene: &Scene, pos: &[f64], radii: &[f64]) -> (f64, f64) {
    let n = radii.len();
    let mut disks: f64 = 0.0;
    for i in 0..n {
        for j in i + 1..n {
            let d = ((pos[2 * i] - pos[2 * j]).powi(2) + (pos[2 * i + 1] - pos[2 * j + 1]).powi(2))
                .sqrt();
            disks = disks.max(radii[i] + radii[j] - d);
        }
    }
    let walls = scene.walls();
    let mut wall: f64 = 0.0;
    for i in 0..n {
        let p = [pos[2 * i], pos[2 * i + 1]];
        assert!(
            scene.walkable(p),
            "person {i} left the walkable area: {p:?}"
        );
        for w in &walls {
            wall = wall.max(radii[i] - w.distance(p));
        }
    }
    (disks, wall)
}

#[test]
fn the_room_runs_to_the_horizon_without_overlap() {
    let scene = room();
    let mut sim = Simulation::new(scene.clone()).unwrap();
    assert_eq!(sim.total_people(), 150);
    let bound = scene.solver.max_violation;
    let (mut frames, mut worst, mut max_reported) = (0, 0.0f64, 0.0f64);
    let mut last_t = 0.0;
    sim.run::<moreau_crowd::CrowdError>(
        |_, r| {
            assert!(r.status.is_converged());
            assert!(
                r.eps <= r.eps_target * (1.0 + 1e-12),
                "step {}: ε {} above {}",
                r.step,
                r.eps,
                r.eps_target
            );
            max_reported = max_reported.max(r.violation);
            Ok(())
        },
        |f| {
            assert!(f.positions.iter().all(|x| x.is_finite()));
            let (d, w) = worst_overlap(&scene, f.positions, f.radii);
            // The linearized constraints are inner approximations: overlap only up to the
            // certified violation of the last step (plus rounding).
            assert!(
                d <= bound + 1e-12 && w <= bound + 1e-12,
                "t = {}: overlaps {d} (disks), {w} (walls)",
                f.t
            );
            worst = worst.max(d).max(w);
            frames += 1;
            last_t = f.t;
            Ok(())
        },
    )
    .unwrap();
    assert_eq!(frames, 201);
    assert!((last_t - 20.0).abs() < 1e-9);
    assert!(max_reported <= bound);
    // People moved: a good part of the room passed the door (the paper's room empties in ~30 s).
    let out = sim.exit_times().len();
    assert!((50..150).contains(&out), "{out} people passed the door");
    // The state keeps its size (people continue to the target area).
    assert_eq!(sim.frame().ids.len(), 150);
    eprintln!(
        "worst overlap {worst:e}, max reported violation {max_reported:e}, {out} through the door"
    );
}

#[test]
fn fast_solver_matches_clarabel_within_the_certified_tolerance_on_the_room() {
    let scene = room();
    let mut sim = Simulation::new(scene).unwrap();
    let mut reference = ClarabelReference::new(ClarabelSettings {
        tolerance: 1e-11,
        max_iterations: 200,
    });
    let mut compared = 0;
    let mut worst_ratio: f64 = 0.0;
    for k in 0..160 {
        let mu = 0.05;
        let before = sim.frame().positions.to_vec();
        let report = sim.step(mu).unwrap();
        if k % 8 != 0 {
            continue;
        }
        let after = sim.frame().positions;
        let v_fast: Vec<f64> = before
            .iter()
            .zip(after)
            .map(|(a, b)| (b - a) / mu)
            .collect();
        let corr = sim.scheme().correction();
        let rows = corr.rows();
        let b: Vec<f64> = rows.values().iter().map(|g| g / mu).collect();
        let problem = ProjectionProblem {
            w: sim.scheme().prediction(),
            jacobian: rows,
            b: &b,
        };
        let mut sol = ProjectionSolution::default();
        // The fast solver certifies gap ≤ ε/(2μ²) = 2.5e-5 here; the reference is far tighter.
        let rc = reference
            .solve(
                &problem,
                Target {
                    gap: 1e-8,
                    violation: 1e-9,
                },
                &mut sol,
            )
            .unwrap();
        assert!(rc.status.is_converged(), "{rc:?}");
        // ½|v − v*|² ≤ gap + |λ*|₁·violation for each answer, so their distance is bounded by
        // the sum of the two certified radii.
        let l1: f64 = sol.lambda.iter().sum();
        let gap_fast = report.eps / (2.0 * mu * mu);
        let viol_fast = report.violation / mu;
        let radius_fast = (2.0 * (gap_fast + l1 * viol_fast)).sqrt();
        let radius_ref = (2.0 * (rc.gap + l1 * rc.violation)).sqrt();
        let dist = v_fast
            .iter()
            .zip(&sol.v)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            dist <= radius_fast + radius_ref + 1e-9,
            "step {k}: |v_fast − v_clarabel| = {dist} > {radius_fast} + {radius_ref}"
        );
        // And the comparison is not vacuous: contacts are active and the bound is tight-ish.
        worst_ratio = worst_ratio.max(dist / (radius_fast + radius_ref));
        if report.active > 0 {
            compared += 1;
        }
    }
    assert!(compared >= 15, "only {compared} steps with contacts");
    eprintln!("largest |Δv| / certified radius: {worst_ratio:.3}");
}
