use moreau_crowd::{Hall, Simulation};
use moreau_solve::{
    InteriorPoint, InteriorPointSettings, ProjectionSolution, ProjectionSolver, Target,
};

fn find(p: &mut [usize], mut x: usize) -> usize {
    while p[x] != x {
        p[x] = p[p[x]];
        x = p[x];
    }
    x
}

fn sizes(p: &moreau_solve::ProjectionProblem, keep: &dyn Fn(usize) -> bool) -> Vec<usize> {
    let n = p.dim();
    let mut par: Vec<usize> = (0..n).collect();
    for i in 0..p.rows() {
        if !keep(i) {
            continue;
        }
        let cols = p.jacobian.row(i).0;
        let a = find(&mut par, cols[0]);
        for &c in &cols[1..] {
            let b = find(&mut par, c);
            par[b] = a;
        }
    }
    let mut cnt = vec![0usize; n];
    for i in 0..p.rows() {
        if !keep(i) {
            continue;
        }
        let r = find(&mut par, p.jacobian.row(i).0[0]);
        cnt[r] += 1;
    }
    let mut v: Vec<usize> = cnt.into_iter().filter(|&c| c > 0).collect();
    v.sort_unstable_by(|a, b| b.cmp(a));
    v
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[1].parse().unwrap();
    let warm: usize = args[2].parse().unwrap();
    let mut h = Hall::new(n, 2.6);
    h.horizon = 100.0;
    h.solver.eps_kappa = (1e-3f64 * 0.18).powi(2) / 0.05f64.powi(3);
    h.solver.max_violation = 1e-4 * 0.18;
    h.solver.grid_cell = (h.side() / 400.0).max(0.25);
    let mut sim = Simulation::new(h.scene().unwrap()).unwrap();
    sim.advance_to(0.05 * warm as f64, &mut ()).unwrap();
    let p = sim.last_projection();
    let eps = sim.scene().solver.eps_kappa * 0.05f64.powi(3);
    let target = Target {
        gap: eps / (2.0 * 0.05 * 0.05),
        violation: sim.scene().solver.max_violation / 0.05,
    };
    let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    ip.solve(&p, target, &mut sol).unwrap();
    // slack at w
    let sw: Vec<f64> = (0..p.rows())
        .map(|i| {
            let (c, a) = p.jacobian.row(i);
            p.b[i] + c.iter().zip(a).map(|(&c, &a)| a * p.w[c]).sum::<f64>()
        })
        .collect();
    let all = sizes(&p, &|_| true);
    let act = sizes(&p, &|i| sol.lambda[i] > 1e-12);
    let viol = sizes(&p, &|i| sw[i] < 0.0);
    let show = |name: &str, v: &Vec<usize>| {
        println!(
            "{name}: rows {} comps {} largest {:?} singletons {}",
            v.iter().sum::<usize>(),
            v.len(),
            &v[..v.len().min(8)],
            v.iter().filter(|&&c| c == 1).count()
        )
    };
    show("candidate", &all);
    show("active", &act);
    show("violated at w", &viol);
}
