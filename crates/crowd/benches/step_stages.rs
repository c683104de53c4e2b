//! Every stage of a crowd step, timed alone on jammed halls (2.6 people/m², one door, after
//! 3 s of evacuation) of 2,000 and 40,000 people: the desired velocities (predict), the broad
//! phase and the constraint rows (assemble), the projection by each solver on the same
//! problem (solve), and the check that nothing outside the assembled rows was crossed
//! (verify). Accuracy as in the scale table: √ε ≤ 1e-3 r_min, violation ≤ 1e-4 r_min.
//!
//! `cargo bench -p moreau-crowd --bench step_stages`

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use moreau_core::ConstraintRows;
use moreau_crowd::{Hall, Scene, Simulation, SolverKind, SolverSettings};
use moreau_solve::{
    Apgd, ApgdSettings, ClarabelReference, ClarabelSettings, InteriorPoint, InteriorPointSettings,
    ProjectionSolution, ProjectionSolver, Target,
};

const MU: f64 = 0.05;

/// The scale table's hall (crates/cli/src/bench.rs) with `n` people.
fn hall(n: usize) -> Scene {
    let r_min: f64 = 0.18;
    let mut hall = Hall::new(n, 2.6);
    hall.horizon = 100.0;
    hall.output_interval = 1.0;
    hall.solver = SolverSettings {
        kind: SolverKind::Interior,
        eps_kappa: (1e-3 * r_min).powi(2) / MU.powi(3),
        max_violation: 1e-4 * r_min,
        grid_cell: (hall.side() / 400.0).max(0.25),
        ..SolverSettings::default()
    };
    hall.scene().expect("a valid hall")
}

fn stages(c: &mut Criterion) {
    let mut group = c.benchmark_group("step_stages");
    group.sample_size(10);
    for n in [2_000usize, 40_000] {
        let mut sim = Simulation::new(hall(n)).expect("hall builds");
        sim.advance_to(60.0 * MU, &mut ())
            .expect("the warm-up steps");
        sim.advance_to(61.0 * MU, &mut ())
            .expect("the measured step");
        let eps_target = sim.scene().solver.eps_kappa * MU.powi(3);
        let q = sim.frame().positions.to_vec();
        let scene = sim.scene().clone();
        let target = Target {
            gap: eps_target / (2.0 * MU * MU),
            violation: scene.solver.max_violation / MU,
        };
        let label = n.to_string();

        // predict: F(t, q)
        let mut w = vec![0.0; q.len()];
        group.bench_with_input(BenchmarkId::new("predict", &label), &n, |b, _| {
            b.iter(|| sim.desired_velocities(&mut w))
        });

        // solve: the last step's projection, by each solver
        let (problem_w, rows, b_off) = {
            let p = sim.last_projection();
            (p.w.to_vec(), p.jacobian.clone(), p.b.to_vec())
        };
        let problem = moreau_solve::ProjectionProblem {
            w: &problem_w,
            jacobian: &rows,
            b: &b_off,
        };
        let mut sol = ProjectionSolution::default();
        group.bench_with_input(
            BenchmarkId::new("solve-interior-cold", &label),
            &n,
            |b, _| {
                b.iter(|| {
                    // A new solver: ordering and symbolic analysis included.
                    let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
                    // From zero multipliers: a remembered answer would be accepted at once.
                    sol.lambda.iter_mut().for_each(|l| *l = 0.0);
                    let r = ip.solve(&problem, target, &mut sol).unwrap();
                    assert!(r.status.is_converged() && r.iterations > 0);
                })
            },
        );
        let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
        ip.solve(&problem, target, &mut sol).unwrap();
        group.bench_with_input(
            BenchmarkId::new("solve-interior-same-pattern", &label),
            &n,
            |b, _| {
                b.iter(|| {
                    // The rows' pattern is unchanged: numeric factorizations only.
                    // From zero multipliers: a remembered answer would be accepted at once.
                    sol.lambda.iter_mut().for_each(|l| *l = 0.0);
                    let r = ip.solve(&problem, target, &mut sol).unwrap();
                    assert!(r.status.is_converged() && r.iterations > 0);
                })
            },
        );
        let mut apgd = Apgd::new(ApgdSettings::default()).unwrap();
        group.bench_with_input(BenchmarkId::new("solve-apgd-cold", &label), &n, |b, _| {
            b.iter(|| {
                sol.lambda.iter_mut().for_each(|l| *l = 0.0);
                let r = apgd.solve(&problem, target, &mut sol).unwrap();
                assert!(r.status.is_converged());
            })
        });
        let mut clarabel = ClarabelReference::new(ClarabelSettings::default());
        group.bench_with_input(BenchmarkId::new("solve-clarabel", &label), &n, |b, _| {
            b.iter(|| clarabel.solve(&problem, target, &mut sol).unwrap())
        });

        // assemble and verify, on the simulation's own contact sources
        let mut out = ConstraintRows::new(q.len());
        let margin = sim.contact_margin(&problem_w, MU);
        group.bench_with_input(BenchmarkId::new("assemble", &label), &n, |b, _| {
            b.iter(|| sim.contacts(margin, &mut out))
        });
        group.bench_with_input(BenchmarkId::new("verify", &label), &n, |b, _| {
            b.iter(|| sim.crossed_outside(&out, scene.solver.max_violation))
        });
    }
    group.finish();
}

criterion_group!(benches, stages);
criterion_main!(benches);
