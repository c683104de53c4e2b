//! What one projection costs each solver, and what the interior point's factorization will
//! cost before any numeric work (faer's symbolic analysis: nonzeros and multiply–adds of the
//! factor): `cargo run --release -p moreau-crowd --example factor_cost -- hall|crush PEOPLE
//! WARMUP_STEPS`. The scale table's accuracy; cold solves from zero multipliers.

use moreau_crowd::{Crush, Hall, Simulation};
use moreau_solve::{
    Apgd, ApgdSettings, InteriorPoint, InteriorPointSettings, ProjectionSolution, ProjectionSolver,
    Target,
};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let kind = &args[1];
    let n: usize = args[2].parse().unwrap();
    let warm: usize = args[3].parse().unwrap();
    let scene = if kind == "crush" {
        let mut c = Crush::new(n);
        c.horizon = 100.0;
        c.solver.eps_kappa = (1e-3f64 * 0.18).powi(2) / 0.05f64.powi(3);
        c.solver.max_violation = 1e-4 * 0.18;
        c.scene().unwrap()
    } else {
        let mut h = Hall::new(n, 2.6);
        h.horizon = 100.0;
        h.solver.eps_kappa = (1e-3f64 * 0.18).powi(2) / 0.05f64.powi(3);
        h.solver.max_violation = 1e-4 * 0.18;
        h.solver.grid_cell = (h.side() / 400.0).max(0.25);
        h.scene().unwrap()
    };
    let mut sim = Simulation::new(scene).unwrap();
    sim.advance_to(0.05 * warm as f64, &mut ()).unwrap();
    let p = sim.last_projection();
    let eps = sim.scene().solver.eps_kappa * 0.05f64.powi(3);
    let target = Target {
        gap: eps / (2.0 * 0.05 * 0.05),
        violation: sim.scene().solver.max_violation / 0.05,
    };
    let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    let t = std::time::Instant::now();
    let r = ip.solve(&p, target, &mut sol).unwrap();
    let tip = t.elapsed().as_secs_f64();
    let c = ip.counts();
    let mut ap = Apgd::new(
        ApgdSettings::builder()
            .max_iterations(100000)
            .build()
            .unwrap(),
    )
    .unwrap();
    let mut sol2 = ProjectionSolution::default();
    let t = std::time::Instant::now();
    let r2 = ap.solve(&p, target, &mut sol2).unwrap();
    let tap = t.elapsed().as_secs_f64();
    let nnz = p.jacobian.nnz();
    println!(
        "{kind} {n}: unknowns {} rows {} nnzJ {} | L nnz {} flops {:.3e} flops/nnzJ {:.1} | IP {:.3}s {} it {:?} | APGD {:.3}s {} it {:?}",
        p.dim(),
        p.rows(),
        nnz,
        c.factor_nnz,
        c.factor_flops as f64,
        c.factor_flops as f64 / nnz as f64,
        tip,
        r.iterations,
        r.status,
        tap,
        r2.iterations,
        r2.status
    );
}
