//! The interior point on crowds: its answers against Clarabel's on small scenes, the same
//! answers for 1 and 2 threads, and the jammed step that Clarabel and APGD could not certify.

mod common;

use common::{assert_feasible, assert_matches_clarabel, listed, room, spawn, start_index};
use moreau_crowd::{Hall, Scene, Simulation, SolverKind, SolverSettings};
use moreau_solve::{
    Apgd, ApgdSettings, InteriorPoint, InteriorPointSettings, ProjectionSolution, ProjectionSolver,
    Target, certify,
};

fn interior(mut scene: Scene) -> Scene {
    scene.solver.kind = SolverKind::Interior;
    scene
}

/// Every step checked for overlaps independently and compared with Clarabel (when nobody
/// left during it).
fn run_against_clarabel(scene: Scene) -> usize {
    let mut sim = Simulation::new(scene.clone()).unwrap();
    let mut compared = 0;
    for mu in common::steps(sim.scene()) {
        let before = sim.frame().positions.to_vec();
        let people = sim.frame().ids.len();
        let report = sim.step(mu).unwrap();
        assert_eq!(
            report.solver, "interior",
            "the fallback answered: {report:?}"
        );
        assert_feasible(&scene, &sim, &report);
        if sim.frame().ids.len() == people {
            assert_matches_clarabel(&sim, &before, &report);
            compared += 1;
        }
    }
    compared
}

#[test]
fn interior_point_matches_clarabel_on_a_queue_at_a_door() {
    let compared = run_against_clarabel(interior(room(1.2, 0.05, 4.0, &spawn(120, "0.2", "1.0"))));
    assert!(compared > 40, "{compared}");
}

#[test]
fn interior_point_matches_clarabel_in_a_jam_at_a_door_too_narrow() {
    let compared = run_against_clarabel(interior(room(0.3, 0.05, 3.0, &spawn(75, "0.25", "1.0"))));
    assert!(compared > 40, "{compared}");
}

#[test]
fn interior_point_matches_clarabel_on_degenerate_contacts() {
    // As in extremes.rs: a chain exactly touching end to end (r = 0.25, spacing 0.5, exact
    // in binary) whose head touches the wall by the 0.3 m door, disks touching both walls at
    // the room's corners, a touching pair and a disk pushed into it.
    let chain: Vec<[f64; 2]> = (0..10).map(|k| [5.75 - 0.5 * k as f64, 3.0]).collect();
    let groups = format!(
        "{}{}{}{}",
        listed("chain", &chain, 0.25, 1.0),
        listed("corners", &[[0.25, 0.25], [0.25, 5.75]], 0.25, 1.0),
        listed("pair", &[[3.0, 0.75], [3.0, 1.25]], 0.25, 0.0),
        listed("wedge", &[[2.0, 1.0]], 0.25, 1.0),
    );
    let mut sim = Simulation::new(interior(room(0.3, 0.05, 4.0, &groups))).unwrap();
    let head_index = start_index(sim.scene(), [5.75, 3.0]);
    let scene = sim.scene().clone();
    for mu in common::steps(sim.scene()) {
        let before = sim.frame().positions.to_vec();
        let report = sim.step(mu).unwrap();
        assert_eq!(report.solver, "interior");
        assert_feasible(&scene, &sim, &report);
        assert_matches_clarabel(&sim, &before, &report);
    }
    // The chain's head (it started at (5.75, 3)) sits in the door's corners:
    // (x − 6)² + 0.15² = 0.25².
    let k = head_index;
    let head = &sim.frame().positions[2 * k..2 * k + 2];
    assert!((head[0] - (6.0 - 0.2)).abs() < 1e-3, "head at {head:?}");
}

#[test]
fn interior_point_matches_clarabel_with_radii_one_to_a_hundred() {
    let groups = format!(
        "{}{}",
        spawn(4, "1.0", "0.8"),
        spawn(250, "0.01", "1.2").replace("\"crowd\"", "\"small\"")
    );
    let compared = run_against_clarabel(interior(room(2.4, 0.05, 3.0, &groups)));
    assert!(compared > 20, "{compared}");
}

/// A jammed hall run with 1 and with 2 threads: the positions agree bit for bit, as the
/// README says (the solver's loops sum in fixed chunks, faer picks its sequential simplicial
/// factorization on crowds, and `auto` on two threads splits its largest component's 2×2-block
/// factorizations between two threads, in the same operations), and in any case within the
/// certified tolerance (what `solver.threads` promises where faer's parallel supernodal
/// factorization would run). Both the interior point alone and `auto`: over these 4 s the
/// door's component grows to ~1,900 people, whose analyses split (33 of 55), and `auto`'s
/// probes run split factorizations whichever way the timings then go (10 in a run measured).
#[test]
fn thread_count_does_not_change_the_answer() {
    let mut hall = Hall::new(3000, 2.6);
    hall.door = 2.0;
    hall.seed = 5;
    hall.horizon = 4.0;
    for kind in [SolverKind::Interior, SolverKind::Auto] {
        hall.solver = SolverSettings {
            kind,
            eps_kappa: 1e-3,
            max_violation: 1e-6,
            ..SolverSettings::default()
        };
        let scene = hall.scene().unwrap();
        let run = |threads: usize| {
            let mut s = scene.clone();
            s.solver.threads = threads;
            let mut sim = Simulation::new(s).unwrap();
            let mut eps_sum = 0.0f64;
            let mut active = 0;
            for mu in common::steps(sim.scene()) {
                let r = sim.step(mu).unwrap();
                if kind == SolverKind::Interior {
                    assert_eq!(r.solver, "interior");
                }
                eps_sum += r.eps.sqrt();
                active = active.max(r.active);
            }
            (
                sim.frame().ids.to_vec(),
                sim.frame().positions.to_vec(),
                eps_sum,
                active,
            )
        };
        let (ids1, q1, eps1, active) = run(1);
        let (ids2, q2, eps2, _) = run(2);
        assert!(
            active > 1000,
            "{kind:?}: the hall must be jammed: {active} active contacts"
        );
        assert_eq!(ids1, ids2);
        // Two ε-projections per step of the same point differ by at most √ε₁ + √ε₂; over the
        // run the differences add up at most (the projection is non-expansive).
        let dist = q1
            .iter()
            .zip(&q2)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        assert!(
            dist <= eps1 + eps2,
            "{kind:?}: |q₁ − q₂| = {dist} > {}",
            eps1 + eps2
        );
        let bits = |q: &[f64]| q.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(
            bits(&q1) == bits(&q2) && eps1.to_bits() == eps2.to_bits(),
            "{kind:?}: 1 and 2 threads differ: |q₁ − q₂| = {dist:e}"
        );
    }
}

/// Regression: the evacuation study's jammed step (door 0.8 m, seed 20130707, step 123 at
/// t = 6.2 s) that Clarabel (NumericalError/MaxIterations short of the target) and APGD
/// (20,000 iterations) could not certify; the interior point certifies that very problem.
#[test]
fn the_jam_step_that_clarabel_and_apgd_could_not_certify_is_certified_by_the_interior_point() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/room-door-0.8-jam.toml"
    );
    let scene = Scene::from_toml(&std::fs::read_to_string(path).unwrap(), path).unwrap();
    let mut sim = Simulation::new(scene.clone()).unwrap();
    let mut failed = None;
    for mu in common::steps(sim.scene()) {
        if let Err(e) = sim.step(mu) {
            failed = Some((mu, e.to_string()));
            break;
        }
    }
    let (mu, error) = failed.expect("Clarabel alone fails on this jam");
    assert!(
        error.contains("step 123") && error.contains("not certified"),
        "{error}"
    );

    let problem = sim.last_projection();
    let eps_target = scene.solver.eps_kappa * mu.powi(3);
    let target = Target {
        gap: eps_target / (2.0 * mu * mu),
        violation: scene.solver.max_violation / mu,
    };
    let mut apgd = Apgd::new(ApgdSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    let rep = apgd.solve(&problem, target, &mut sol).unwrap();
    assert!(!rep.status.is_converged(), "APGD now certifies it: {rep:?}");

    let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    let rep = ip.solve(&problem, target, &mut sol).unwrap();
    assert!(rep.status.is_converged(), "{rep:?}");
    // The certificate, recomputed here from the returned pair.
    let (mut sm, mut sn) = (vec![0.0; problem.rows()], vec![0.0; problem.dim()]);
    let c = certify(&problem, &sol.v, &sol.lambda, &mut sm, &mut sn);
    assert!(
        c.gap <= target.gap && c.violation <= target.violation,
        "{c:?} vs {target:?}"
    );
    assert!(sol.lambda.iter().all(|&l| l >= 0.0));
}

/// A crowd large enough that, with threads, its desired velocities are computed in bands,
/// its broad phase sweeps its grid in bands, its contact rows are assembled in bands and
/// Gauss–Seidel sweeps its groups on all of them: the same rows and positions, bit for bit,
/// on one and three threads (`auto`, whose every other part gives the same bits on any thread
/// count too).
#[test]
fn a_large_crowd_steps_the_same_on_one_and_three_threads() {
    steps_the_same_on(32_000, 3, 0.3, 3, 30_000..usize::MAX);
}

/// Below ten thousand people the loops run in two bands on two threads, the second on the
/// helper thread (which the interior point's split factorization shares).
#[test]
fn a_crowd_of_thousands_steps_the_same_with_its_second_band_on_the_helper() {
    steps_the_same_on(3_000, 5, 0.5, 2, 2_000..10_000);
}

/// A hall of `people` (seed, horizon) steps the same on one and on `threads` threads: the
/// rows assembled a step (the most of them in `rows`) and the positions, bit for bit.
fn steps_the_same_on(
    people: usize,
    seed: u64,
    horizon: f64,
    threads: usize,
    rows: std::ops::Range<usize>,
) {
    let mut hall = Hall::new(people, 2.5);
    hall.seed = seed;
    hall.horizon = horizon;
    let scene = hall.scene().unwrap();
    let (ids1, q1, rows1) = steps_on(&scene, 1);
    let most = rows1.iter().copied().max().unwrap_or(0);
    assert!(rows.contains(&most), "contacts for the bands: {most} rows");
    let (ids, q, rows) = steps_on(&scene, threads);
    assert_eq!(rows1, rows, "rows assembled a step");
    assert_eq!(ids1, ids);
    assert!(q1 == q, "other positions on {threads} threads");
}

/// The run of `scene` on `threads` threads: ids and position bits at the end, rows a step.
fn steps_on(scene: &Scene, threads: usize) -> (Vec<u32>, Vec<u64>, Vec<usize>) {
    let mut s = scene.clone();
    s.solver.threads = threads;
    let mut sim = Simulation::new(s).unwrap();
    let mut rows = Vec::new();
    for mu in common::steps(sim.scene()) {
        rows.push(sim.step(mu).unwrap().assembled);
    }
    let bits = sim
        .frame()
        .positions
        .iter()
        .map(|x| x.to_bits())
        .collect::<Vec<_>>();
    (sim.frame().ids.to_vec(), bits, rows)
}

/// A scene's `[solver.interior]` reaches the interior point, alone and inside `auto`, and
/// round-trips through the scene's TOML (a scene without it writes no such table): with one
/// iteration allowed, the jam's projections that need the interior point go to the fallback
/// (Clarabel), which the step reports name; with the defaults none does.
#[test]
fn the_scenes_interior_point_settings_reach_the_solver() {
    let jam = room(0.3, 0.05, 3.0, &spawn(75, "0.25", "1.0"));
    assert!(!jam.to_toml().contains("[solver.interior]"));
    for kind in [SolverKind::Interior, SolverKind::Auto] {
        let answered_by_the_fallback = |max_iterations: Option<usize>| {
            let mut scene = jam.clone();
            scene.solver.kind = kind;
            if let Some(n) = max_iterations {
                scene.solver.interior.max_iterations = n;
                let text = scene.to_toml();
                assert!(text.contains("[solver.interior]"), "{text}");
                assert!(!text.contains("[solver.newton]"), "{text}");
                let again = Scene::from_toml(&text, "<round trip>").unwrap();
                assert_eq!(again, scene);
            }
            let mut sim = Simulation::new(scene.clone()).unwrap();
            let mut fallback = 0;
            for mu in common::steps(sim.scene()) {
                let report = sim.step(mu).unwrap();
                assert_feasible(&scene, &sim, &report);
                fallback += usize::from(report.solver == "clarabel");
            }
            fallback
        };
        assert_eq!(answered_by_the_fallback(None), 0, "{kind:?}");
        let one = answered_by_the_fallback(Some(1));
        assert!(one >= 3, "{kind:?}: the fallback answered {one} steps");
    }
}

/// The bench's hall and crush wrote their solver's tables at the top level of the scene
/// (`[auto]` after `[solver]`'s keys, read back as an unknown top-level table), so a hall or
/// crush with any solver setting of its own failed to build.
#[test]
fn a_hall_or_crush_with_solver_tables_wrote_them_at_the_top_level() {
    let mut solver = SolverSettings {
        kind: SolverKind::Auto,
        ..SolverSettings::default()
    };
    solver.auto.own_reach_ratio = 2.0;
    solver.interior.max_iterations = 7;
    let mut hall = Hall::new(200, 2.6);
    hall.solver = solver;
    let mut crush = moreau_crowd::Crush::new(200);
    crush.solver = solver;
    for scene in [hall.scene().unwrap(), crush.scene().unwrap()] {
        assert_eq!(scene.solver, solver, "{}", scene.name);
    }
}
