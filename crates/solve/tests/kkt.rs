//! Projection solvers against the KKT conditions and against an exact active-set enumeration.

use moreau_core::{ConstraintRows, Parallelism, SolveStatus};
use moreau_solve::{
    Apgd, ApgdSettings, AutoSettings, AutoSolver, ClarabelReference, ClarabelSettings, GaussSeidel,
    GaussSeidelSettings, InteriorPoint, InteriorPointSettings, MAX_BUDGET, Newton, NewtonSettings,
    ProjectionProblem, ProjectionSolution, ProjectionSolver, Reach, RowOrder, SolveReport, Target,
    certify,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[path = "support/mod.rs"]
mod support;

#[derive(Clone)]
struct Instance {
    w: Vec<f64>,
    rows: ConstraintRows,
    b: Vec<f64>,
}

/// A feasible random problem: `b = s0 − J v0` with `s0 ≥ 0` (some exactly 0).
/// `kind` adds degeneracy: 1 duplicated rows, 2 more rows than unknowns, 3 zero rows,
/// 4 all of them.
fn random_instance(rng: &mut ChaCha8Rng, kind: u32) -> Instance {
    let n = rng.random_range(2..7);
    let mut m = rng.random_range(1..=n);
    if kind == 2 || kind == 4 {
        m = n + rng.random_range(1..5);
    }
    let mut dense: Vec<Vec<f64>> = (0..m)
        .map(|_| {
            (0..n)
                .map(|_| {
                    if rng.random_bool(0.6) {
                        rng.random_range(-2.0..2.0)
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect();
    if kind == 1 || kind == 4 {
        let k = rng.random_range(0..m);
        dense.push(dense[k].clone());
        let scaled: Vec<f64> = dense[k].iter().map(|a| 2.5 * a).collect();
        dense.push(scaled);
    }
    if kind == 3 || kind == 4 {
        dense.push(vec![0.0; n]);
    }
    feasible(rng, n, &dense)
}

/// The problem of the dense rows `dense` over `n` unknowns made feasible at a random `v0`:
/// `b = s0 − J v0` with `s0 ≥ 0` (some exactly 0), and `w` pushed away from `v0` so that
/// constraints bind.
fn feasible(rng: &mut ChaCha8Rng, n: usize, dense: &[Vec<f64>]) -> Instance {
    let v0: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut rows = ConstraintRows::new(n);
    let mut b = Vec::with_capacity(dense.len());
    for (i, r) in dense.iter().enumerate() {
        let s0 = if rng.random_bool(0.3) {
            0.0
        } else {
            rng.random_range(0.0..1.0)
        };
        let jv: f64 = r.iter().zip(&v0).map(|(a, v)| a * v).sum();
        b.push(s0 - jv);
        rows.push(
            i as u64,
            0.0,
            r.iter()
                .enumerate()
                .filter(|(_, a)| **a != 0.0)
                .map(|(c, &a)| (c, a)),
        );
    }
    let w = v0.iter().map(|v| v + rng.random_range(-3.0..3.0)).collect();
    Instance { w, rows, b }
}

fn dense_row(rows: &ConstraintRows, i: usize) -> Vec<f64> {
    let mut r = vec![0.0; rows.dim()];
    let (c, a) = rows.row(i);
    for (&c, &a) in c.iter().zip(a) {
        r[c] = a;
    }
    r
}

/// The exact projection, by the independent enumerator of the workspace's test support.
fn exact_projection(inst: &Instance) -> (Vec<f64>, Vec<f64>) {
    let j: Vec<Vec<f64>> = (0..inst.b.len())
        .map(|i| dense_row(&inst.rows, i))
        .collect();
    support::exact_qp(&inst.w, &j, &inst.b)
}

/// `½|v − w|²`: the projection's objective.
fn objective(w: &[f64], v: &[f64]) -> f64 {
    0.5 * v.iter().zip(w).map(|(a, b)| (a - b) * (a - b)).sum::<f64>()
}

/// Clarabel's certified answer to `p` (an independent interior point: the reference).
fn clarabel_answer(p: &ProjectionProblem<'_>, t: Target) -> (ProjectionSolution, SolveReport) {
    let mut reference = ProjectionSolution::default();
    let rep = ClarabelReference::default()
        .solve(p, t, &mut reference)
        .unwrap();
    assert!(rep.status.is_converged(), "clarabel: {rep:?}");
    (reference, rep)
}

/// `sol` (certified to `gap`) reaches Clarabel's objective within both certificates.
fn assert_clarabel_objective(
    p: &ProjectionProblem<'_>,
    name: &str,
    sol: &ProjectionSolution,
    gap: f64,
    (reference, crep): &(ProjectionSolution, SolveReport),
) {
    let (ours, theirs) = (objective(p.w, &sol.v), objective(p.w, &reference.v));
    assert!(
        (ours - theirs).abs() <= 2.0 * (gap + crep.gap) + 1e-7,
        "{name}: objective {ours} vs clarabel {theirs}"
    );
}

/// Checks `(v, λ)` against the KKT conditions computed here from the data, and against the
/// exact projection: the certificate must bound the true suboptimality.
fn check_kkt(inst: &Instance, name: &str, sol: &ProjectionSolution, gap: f64, violation: f64) {
    let p = ProjectionProblem {
        w: &inst.w,
        jacobian: &inst.rows,
        b: &inst.b,
    };
    let (m, n) = (p.rows(), p.dim());
    let tol = 1e-6;
    // Dual feasibility.
    assert!(
        sol.lambda.iter().all(|&l| l >= 0.0),
        "{name}: negative multiplier {:?}",
        sol.lambda
    );
    // Primal feasibility and complementarity, from s computed here.
    let s: Vec<f64> = (0..m)
        .map(|i| {
            inst.b[i]
                + dense_row(&inst.rows, i)
                    .iter()
                    .zip(&sol.v)
                    .map(|(a, v)| a * v)
                    .sum::<f64>()
        })
        .collect();
    let viol = s.iter().fold(0.0_f64, |a, &s| a.max(-s));
    assert!(viol <= tol, "{name}: violation {viol}");
    assert!(
        (viol - violation).abs() <= 1e-12,
        "{name}: reported violation {violation} but it is {viol}"
    );
    for i in 0..m {
        assert!(
            (sol.lambda[i] * s[i]).abs() <= tol,
            "{name}: complementarity λ{i}·s{i} = {}",
            sol.lambda[i] * s[i]
        );
    }
    // Stationarity v = w + Jᵀλ.
    let mut jtl = vec![0.0; n];
    inst.rows.mul_transpose_add(&sol.lambda, &mut jtl);
    for c in 0..n {
        assert!(
            (sol.v[c] - inst.w[c] - jtl[c]).abs() <= 1e-4,
            "{name}: stationarity at {c}"
        );
    }
    // Honest certificate: P(v) − P(v*) ≤ gap + |λ*|₁ · violation.
    let (vstar, lstar) = exact_projection(inst);
    let excess = objective(&inst.w, &sol.v) - objective(&inst.w, &vstar);
    let l1: f64 = lstar.iter().sum();
    assert!(
        excess <= gap + l1 * violation + 1e-12,
        "{name}: certificate {gap} does not bound the excess {excess}"
    );
    // And strong convexity: ½|v − v*|² ≤ P(v) − P(v*) + |λ*|₁·violation.
    let dist_sq: f64 = sol
        .v
        .iter()
        .zip(&vstar)
        .map(|(a, b)| (a - b) * (a - b))
        .sum();
    assert!(
        0.5 * dist_sq <= gap + l1 * violation + 1e-10,
        "{name}: |v − v*|² = {dist_sq} vs gap {gap}"
    );
}

fn run_all(kind: u32, cases: usize, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let target = Target {
        gap: 1e-10,
        violation: 1e-9,
    };
    let mut apgd = Apgd::new(ApgdSettings::default()).unwrap();
    let mut clarabel = ClarabelReference::new(ClarabelSettings::default());
    // One interior point for all cases: its pattern and symbolic analysis must follow the
    // changing sizes and sparsity.
    let mut interior = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut newton = Newton::new(NewtonSettings::default()).unwrap();
    let mut gauss_seidel = GaussSeidel::default();
    for case in 0..cases {
        let inst = random_instance(&mut rng, kind);
        let p = ProjectionProblem {
            w: &inst.w,
            jacobian: &inst.rows,
            b: &inst.b,
        };
        for solver in [
            &mut apgd as &mut dyn ProjectionSolver,
            &mut clarabel,
            &mut interior,
            &mut newton,
            &mut gauss_seidel,
        ] {
            let mut sol = ProjectionSolution::default();
            let rep = solver
                .solve(
                    &p,
                    Target {
                        gap: 1e-8,
                        ..target
                    },
                    &mut sol,
                )
                .unwrap();
            let name = format!("{} kind {kind} case {case}", solver.name());
            assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
            assert_eq!(rep.solver, solver.name());
            check_kkt(&inst, &name, &sol, rep.gap, rep.violation);
            check_report(
                &p,
                Target {
                    gap: 1e-8,
                    ..target
                },
                &name,
                &sol,
                &rep,
            );
        }
    }
}

/// The report is the certificate of what was returned, and a converged one meets the target.
fn check_report(
    p: &ProjectionProblem<'_>,
    target: Target,
    name: &str,
    sol: &ProjectionSolution,
    rep: &SolveReport,
) {
    if rep.status.is_converged() {
        assert!(
            rep.gap <= target.gap && rep.violation <= target.violation,
            "{name}: converged with {rep:?} for {target:?}"
        );
    }
    let (mut sm, mut sn) = (vec![0.0; p.rows()], vec![0.0; p.dim()]);
    let c = certify(p, &sol.v, &sol.lambda, &mut sm, &mut sn);
    assert!(
        (c.gap - rep.gap).abs() <= 1e-9 + 1e-6 * rep.gap,
        "{name}: certify {} vs report {}",
        c.gap,
        rep.gap
    );
    assert_eq!(c.violation, rep.violation, "{name}");
}

/// Row `i` scaled by `r_i`, log-uniform in [1, 100] (as rows of disks whose radii span
/// 1:100): the same feasible set, multipliers of other scales.
fn scale_rows(rng: &mut ChaCha8Rng, inst: &Instance) -> Instance {
    let mut rows = ConstraintRows::new(inst.rows.dim());
    let mut b = Vec::new();
    for i in 0..inst.b.len() {
        let r = 100f64.powf(rng.random_range(0.0..1.0));
        let (c, a) = inst.rows.row(i);
        rows.push(
            inst.rows.keys()[i],
            0.0,
            c.iter().zip(a).map(|(&c, &a)| (c, r * a)),
        );
        b.push(r * inst.b[i]);
    }
    Instance {
        w: inst.w.clone(),
        rows,
        b,
    }
}

/// The next step's problem: `w` moved by up to `dw` and every `b` raised by up to `db`
/// (so that `v0` stays feasible); with `churn`, a random third of the rows dropped and as
/// many new random rows (new keys) added, all still satisfied by the instance's `v0`.
fn perturb(rng: &mut ChaCha8Rng, inst: &Instance, dw: f64, db: f64, churn: bool) -> Instance {
    let n = inst.rows.dim();
    let w: Vec<f64> = inst
        .w
        .iter()
        .map(|w| w + rng.random_range(-dw..=dw))
        .collect();
    let mut rows = ConstraintRows::new(n);
    let mut b = Vec::new();
    let mut next_key = 1000 + inst.rows.keys().iter().max().copied().unwrap_or(0);
    for i in 0..inst.b.len() {
        if churn && rng.random_bool(0.33) {
            // Replaced by a new row through a point at most 0.5 from the origin's side.
            let mut r: Vec<(usize, f64)> = Vec::new();
            for c in 0..n {
                if rng.random_bool(0.6) {
                    r.push((c, rng.random_range(-2.0..2.0)));
                }
            }
            // b ≥ |r|₁ keeps every instance's v0 (in [−1, 1]ⁿ) feasible.
            let l1: f64 = r.iter().map(|(_, a)| a.abs()).sum();
            rows.push(next_key, 0.0, r);
            next_key += 1;
            b.push(l1 * rng.random_range(1.0..1.5));
            continue;
        }
        let (c, a) = inst.rows.row(i);
        rows.push(
            inst.rows.keys()[i],
            0.0,
            c.iter().copied().zip(a.iter().copied()),
        );
        b.push(inst.b[i] + rng.random_range(0.0..=db));
    }
    Instance { w, rows, b }
}

/// The same rows (keys and columns) with new coefficients, as a crowd's contacts turn from
/// one step to the next, and offsets in `[0, |J_i|₁ / 2]` (feasible: `v = 0` holds them).
fn new_coefficients(rng: &mut ChaCha8Rng, inst: &Instance) -> Instance {
    let mut rows = ConstraintRows::new(inst.rows.dim());
    let mut b = Vec::new();
    for i in 0..inst.b.len() {
        let (c, _) = inst.rows.row(i);
        let a: Vec<f64> = c.iter().map(|_| rng.random_range(-2.0..2.0)).collect();
        let l1: f64 = a.iter().map(|a| a.abs()).sum();
        rows.push(inst.rows.keys()[i], 0.0, c.iter().copied().zip(a));
        b.push(l1 * rng.random_range(0.0..0.5));
    }
    Instance {
        w: inst.w.clone(),
        rows,
        b,
    }
}

/// The multipliers of `old`'s rows matched to `new`'s by key (0 for new rows), as the
/// integrator's warm start does.
fn matched(old: &Instance, lambda: &[f64], new: &Instance) -> Vec<f64> {
    new.rows
        .keys()
        .iter()
        .map(|k| {
            old.rows
                .keys()
                .iter()
                .position(|o| o == k)
                .map_or(0.0, |i| lambda[i])
        })
        .collect()
}

/// `solver`'s answer to `inst`, converged and checked against the KKT conditions, the exact
/// enumerator, its own report and Clarabel's objective.
fn solve_and_check(
    solver: &mut dyn ProjectionSolver,
    inst: &Instance,
    target: Target,
    sol: &mut ProjectionSolution,
    name: &str,
) -> SolveReport {
    let p = ProjectionProblem {
        w: &inst.w,
        jacobian: &inst.rows,
        b: &inst.b,
    };
    let rep = solver.solve(&p, target, sol).unwrap();
    assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
    check_kkt(inst, name, sol, rep.gap, rep.violation);
    check_report(&p, target, name, sol, &rep);
    // Clarabel, an independent interior point, reaches the same objective.
    assert_clarabel_objective(&p, name, sol, rep.gap, &clarabel_answer(&p, target));
    rep
}

/// Newton cold, then warm from its answer on the next (perturbed) problem, both checked
/// against the KKT conditions, the exact enumerator and Clarabel's objective.
fn run_newton(kind: u32, cases: usize, seed: u64, scaled: bool, churn: bool) {
    let mut newton = Newton::new(NewtonSettings::default()).unwrap();
    run_cold_and_warm(&mut newton, kind, cases, seed, scaled, churn);
}

/// `solver` cold, then warm from its answer on the next (perturbed) problem, both checked
/// against the KKT conditions, the exact enumerator and Clarabel's objective.
fn run_cold_and_warm(
    solver: &mut dyn ProjectionSolver,
    kind: u32,
    cases: usize,
    seed: u64,
    scaled: bool,
    churn: bool,
) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let target = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let solver_name = solver.name();
    let mut solve = |inst: &Instance, sol: &mut ProjectionSolution, name: &str| {
        solve_and_check(solver, inst, target, sol, name);
    };
    for case in 0..cases {
        let mut inst = random_instance(&mut rng, kind);
        if scaled {
            inst = scale_rows(&mut rng, &inst);
        }
        let next = perturb(&mut rng, &inst, 0.05, 0.01, churn);
        let name = format!("{solver_name} kind {kind} case {case} scaled {scaled} churn {churn}");
        let mut sol = ProjectionSolution::default();
        solve(&inst, &mut sol, &format!("{name} cold"));
        sol.lambda = matched(&inst, &sol.lambda, &next);
        solve(&next, &mut sol, &format!("{name} warm"));
    }
}

/// A feasible random problem shaped like a crowd's: `people` disks, unknowns `2p, 2p + 1`
/// (x, y), rows for a contact between two disks (`−n` on one, `n` on the other) or with a
/// wall (`n` on one), some of them duplicated or doubled (redundant contacts).
fn disk_instance(rng: &mut ChaCha8Rng) -> Instance {
    let people = rng.random_range(2..=4);
    let n = 2 * people;
    let mut dense: Vec<Vec<f64>> = Vec::new();
    for _ in 0..rng.random_range(1..=people + 3) {
        let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let (nx, ny) = (angle.cos(), angle.sin());
        let a = rng.random_range(0..people);
        let mut row = vec![0.0; n];
        row[2 * a] = nx;
        row[2 * a + 1] = ny;
        if rng.random_bool(0.7) {
            let b = (a + rng.random_range(1..people)) % people;
            row[2 * a] = -nx;
            row[2 * a + 1] = -ny;
            row[2 * b] = nx;
            row[2 * b + 1] = ny;
        }
        dense.push(row);
        if rng.random_bool(0.15) {
            let copy = dense.last().unwrap().clone();
            let factor = if rng.random_bool(0.5) { 1.0 } else { 2.0 };
            dense.push(copy.iter().map(|x| factor * x).collect());
        }
    }
    feasible(rng, n, &dense)
}

/// A crowd's problem (rows scaled 1 to 100 in odd cases), the next step's, the same with
/// everyone pushing 1 % harder (the active set holds), and another crowd of the same size
/// (the pattern changes under the warm start).
fn disk_case(rng: &mut ChaCha8Rng, case: usize) -> [Instance; 4] {
    let mut inst = disk_instance(rng);
    if case % 2 == 1 {
        inst = scale_rows(rng, &inst);
    }
    let next = perturb(rng, &inst, 0.05, 0.01, false);
    let mut other = disk_instance(rng);
    while other.rows.dim() != next.rows.dim() {
        other = disk_instance(rng);
    }
    let harder = Instance {
        w: next.w.iter().map(|w| 1.01 * w).collect(),
        ..next.clone()
    };
    [inst, next, harder, other]
}

/// `solve` on a [`disk_case`]'s four problems in turn, each from the last answer's
/// multipliers matched by key: cold, warm, pushed harder, after a pattern change.
fn run_disk_case(
    [inst, next, harder, other]: &[Instance; 4],
    name: &str,
    mut solve: impl FnMut(&Instance, &mut ProjectionSolution, &str) -> SolveReport,
) -> [SolveReport; 4] {
    let mut sol = ProjectionSolution::default();
    let cold = solve(inst, &mut sol, &format!("{name} cold"));
    sol.lambda = matched(inst, &sol.lambda, next);
    let warm = solve(next, &mut sol, &format!("{name} warm"));
    let held = solve(harder, &mut sol, &format!("{name} pushed harder"));
    sol.lambda = matched(harder, &sol.lambda, other);
    let changed = solve(other, &mut sol, &format!("{name} pattern change"));
    [cold, warm, held, changed]
}

/// The interior point on disks' contacts factorizes in 2×2 blocks: cold, warm on the next
/// step's problem, and after a change of pattern (another crowd of the same size), with
/// rows scaled 1 to 100 in every other case, checked against the KKT conditions, the exact
/// enumerator and Clarabel's objective.
#[test]
fn the_interior_point_in_two_by_two_blocks_meets_kkt_on_disk_contacts() {
    let mut rng = ChaCha8Rng::seed_from_u64(55);
    let target = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    // The default, Gondzio's correctors on every solve (by default they wait for factors
    // denser than these small crowds make), the warm polish tried on every warm solve its
    // back-off allows (by default only after a solve that changed ≤ 0.5 % of its rows'
    // sides), and one step length for the primal and the dual variables.
    let mut interiors = [
        InteriorPointSettings::default(),
        InteriorPointSettings::builder()
            .corrector_threshold(0.0)
            .build()
            .unwrap(),
        InteriorPointSettings::builder()
            .polish_changes(1.0)
            .build()
            .unwrap(),
        InteriorPointSettings::builder()
            .separate_steps(false)
            .build()
            .unwrap(),
    ]
    .map(|s| InteriorPoint::new(s).unwrap());
    let solve = |interior: &mut InteriorPoint,
                 inst: &Instance,
                 sol: &mut ProjectionSolution,
                 name: &str| {
        let p = ProjectionProblem {
            w: &inst.w,
            jacobian: &inst.rows,
            b: &inst.b,
        };
        let before = interior.counts();
        let rep = interior.solve(&p, target, sol).unwrap();
        assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
        let after = interior.counts();
        assert_eq!(
            after.block_factorizations - before.block_factorizations,
            after.factorizations - before.factorizations,
            "{name}: a factorization was not in blocks"
        );
        check_kkt(inst, name, sol, rep.gap, rep.violation);
        check_report(&p, target, name, sol, &rep);
        assert_clarabel_objective(&p, name, sol, rep.gap, &clarabel_answer(&p, target));
        rep
    };
    // Warm solves the polish answered (one factorization and no interior-point iteration
    // after it: its report says 1 factorization and its multiplier updates, 1–4, as
    // iterations), for the last variant.
    let mut polished = 0;
    for case in 0..80 {
        let problems = disk_case(&mut rng, case);
        for (k, interior) in interiors.iter_mut().enumerate() {
            let name = format!("disks case {case}, interior point {k}");
            let [_, warm, held, changed] = run_disk_case(&problems, &name, |inst, sol, name| {
                solve(interior, inst, sol, name)
            });
            if k == 2 {
                polished += [warm, held, changed]
                    .iter()
                    .filter(|r| r.factorizations == 1 && (1..=4).contains(&r.iterations))
                    .count();
            }
        }
    }
    // Most of the 80 solves pushed harder should be polished (89 warm solves in all when
    // written), each of them checked above against the enumerator and Clarabel.
    assert!(polished >= 40, "the polish answered {polished} warm solves");
    for interior in &interiors {
        assert!(
            interior.counts().block_factorizations > 100,
            "{:?}",
            interior.counts()
        );
    }
}

/// Newton on disks' contacts, where its factors are in 2×2 blocks: with a few changed rows
/// updated into the factor in hand (the default) and with every Newton matrix factorized,
/// cold, warm, pushed harder and across a change of pattern, each answer checked against the
/// KKT conditions, the exact enumerator and Clarabel's objective; on the small crush too.
/// The updates must have been taken, and saved factorizations.
#[test]
fn newton_with_factor_updates_meets_kkt_on_disk_contacts() {
    let mut rng = ChaCha8Rng::seed_from_u64(57);
    let target = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let mut newtons = [NewtonSettings::default().max_updates, 0]
        .map(|k| Newton::new(NewtonSettings::builder().max_updates(k).build().unwrap()).unwrap());
    assert!(NewtonSettings::default().max_updates > 0);
    for case in 0..60 {
        let problems = disk_case(&mut rng, case);
        for (k, newton) in newtons.iter_mut().enumerate() {
            let name = format!("disks case {case}, newton {k}");
            run_disk_case(&problems, &name, |inst, sol, name| {
                solve_and_check(newton, inst, target, sol, name)
            });
        }
    }
    // (Too many rows for the enumerator: the report and Clarabel's objective.)
    let (w, rows, b) = small_crush();
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let reference = clarabel_answer(&p, target);
    for (k, newton) in newtons.iter_mut().enumerate() {
        let name = format!("small crush, newton {k}");
        let mut sol = ProjectionSolution::default();
        let rep = newton.solve(&p, target, &mut sol).unwrap();
        assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
        check_report(&p, target, &name, &sol, &rep);
        assert_clarabel_objective(&p, &name, &sol, rep.gap, &reference);
    }
    let (updating, factorizing) = (newtons[0].counts(), newtons[1].counts());
    assert_eq!(factorizing.updates, 0, "{factorizing:?}");
    assert!(updating.updates > 50, "{updating:?}");
    assert!(
        updating.factorizations < factorizing.factorizations,
        "{updating:?} against {factorizing:?}"
    );
}

#[test]
fn random_feasible_problems_meet_kkt() {
    run_all(0, 60, 1);
}

#[test]
fn duplicated_constraints_meet_kkt() {
    run_all(1, 40, 2);
}

#[test]
fn more_constraints_than_unknowns_meet_kkt() {
    run_all(2, 40, 3);
}

#[test]
fn zero_rows_meet_kkt() {
    run_all(3, 40, 4);
}

#[test]
fn all_degeneracies_together_meet_kkt() {
    run_all(4, 40, 5);
}

#[test]
fn newton_cold_and_warm_meet_kkt_on_every_family() {
    for kind in 0..5 {
        run_newton(kind, 40, 100 + kind as u64, false, false);
    }
}

#[test]
fn newton_on_rows_scaled_1_to_100_meets_kkt() {
    for kind in 0..5 {
        run_newton(kind, 40, 200 + kind as u64, true, false);
    }
}

#[test]
fn newton_warm_across_a_pattern_change_meets_kkt() {
    for kind in 0..5 {
        run_newton(kind, 40, 300 + kind as u64, kind % 2 == 1, true);
    }
}

/// Regression for the copy of `Jᵀ`'s coefficients the normal equations keep: their analysis
/// is reused while the rows keep their columns, and the products with `Jᵀ` must then read
/// the new coefficients (without the copy's refresh both solvers converge to wrong answers
/// or not at all here).
#[test]
fn new_coefficients_on_the_same_columns_are_solved_with_the_new_coefficients() {
    let target = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(808);
    let mut solvers: [Box<dyn ProjectionSolver>; 2] = [
        Box::new(InteriorPoint::new(InteriorPointSettings::default()).unwrap()),
        Box::new(Newton::new(NewtonSettings::default()).unwrap()),
    ];
    for case in 0..40 {
        let inst = random_instance(&mut rng, case % 5);
        let next = new_coefficients(&mut rng, &inst);
        for solver in solvers.iter_mut() {
            let mut sol = ProjectionSolution::default();
            for (step, inst) in [&inst, &next].into_iter().enumerate() {
                let name = format!("{} case {case} step {step}", solver.name());
                let p = ProjectionProblem {
                    w: &inst.w,
                    jacobian: &inst.rows,
                    b: &inst.b,
                };
                let rep = solver.solve(&p, target, &mut sol).unwrap();
                assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
                check_kkt(inst, &name, &sol, rep.gap, rep.violation);
                check_report(&p, target, &name, &sol, &rep);
                assert_clarabel_objective(&p, &name, &sol, rep.gap, &clarabel_answer(&p, target));
            }
        }
    }
}

// The same instances as Newton's (Clarabel, the reference, fails on a few other seeds).
#[test]
fn gauss_seidel_cold_and_warm_meet_kkt_on_every_family() {
    let mut solver = GaussSeidel::default();
    for kind in 0..5 {
        run_cold_and_warm(&mut solver, kind, 40, 100 + kind as u64, false, false);
    }
}

#[test]
fn gauss_seidel_on_rows_scaled_1_to_100_meets_kkt() {
    let mut solver = GaussSeidel::default();
    for kind in 0..5 {
        run_cold_and_warm(&mut solver, kind, 40, 200 + kind as u64, true, false);
    }
}

#[test]
fn gauss_seidel_warm_across_a_pattern_change_meets_kkt() {
    let mut solver = GaussSeidel::default();
    for kind in 0..5 {
        run_cold_and_warm(
            &mut solver,
            kind,
            40,
            300 + kind as u64,
            kind % 2 == 1,
            true,
        );
    }
}

// `auto` on the same families: most of these problems are one component or a few; with
// Gauss–Seidel's budget cut to one pass the interior point answers most of them.
#[test]
fn auto_cold_and_warm_meet_kkt_on_every_family() {
    for passes in [200, 1] {
        let mut solver = AutoSolver::new(AutoSettings {
            first_order_passes: passes,
            ..AutoSettings::default()
        })
        .unwrap();
        for kind in 0..5 {
            run_cold_and_warm(&mut solver, kind, 40, 100 + kind as u64, false, false);
            run_cold_and_warm(&mut solver, kind, 20, 200 + kind as u64, true, false);
            run_cold_and_warm(
                &mut solver,
                kind,
                20,
                300 + kind as u64,
                kind % 2 == 1,
                true,
            );
        }
    }
}

/// `auto` setting rows aside by their own reach whenever that keeps fewer rows than the
/// shared floor (`own_reach_ratio = 1`), and its interior point answering (one Gauss–Seidel
/// pass): the same families, cold and warm, meet KKT at the exact projection; the own reach
/// is taken in most solves, and rows it set aside are needed (rounds) in some.
#[test]
fn auto_setting_rows_aside_by_their_own_reach_meets_kkt_on_every_family() {
    let mut auto = AutoSolver::new(AutoSettings {
        first_order_passes: 1,
        own_reach_ratio: 1.0,
        ..AutoSettings::default()
    })
    .unwrap();
    let target = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let (mut solves, mut own, mut rounds) = (0, 0, 0);
    // The instances of `auto_cold_and_warm_meet_kkt_on_every_family`, as `run_cold_and_warm`
    // draws them.
    for (kind, family) in (0..5).flat_map(|k| (0..3).map(move |f| (k, f))) {
        let (seed, cases, scaled, churn) = [
            (100, 40, false, false),
            (200, 20, true, false),
            (300, 20, kind % 2 == 1, true),
        ][family];
        let mut rng = ChaCha8Rng::seed_from_u64(seed + kind as u64);
        for case in 0..cases {
            let mut inst = random_instance(&mut rng, kind);
            if scaled {
                inst = scale_rows(&mut rng, &inst);
            }
            let next = perturb(&mut rng, &inst, 0.05, 0.01, churn);
            let name = format!("own reach kind {kind} family {family} case {case}");
            let mut sol = ProjectionSolution::default();
            for (problem, when) in [(&inst, "cold"), (&next, "warm")] {
                if when == "warm" {
                    sol.lambda = matched(&inst, &sol.lambda, &next);
                }
                let name = format!("{name} {when}");
                solve_and_check(&mut auto, problem, target, &mut sol, &name);
                let screen = auto.screen();
                solves += 1;
                own += usize::from(screen.reach == Reach::Own);
                rounds += usize::from(screen.rounds > 0);
            }
        }
    }
    assert!(
        2 * own > solves && rounds > 0,
        "{own} own, {rounds} with rounds of {solves}"
    );
}

/// `blocks` side by side: one problem whose components are (at least) the blocks.
fn side_by_side(blocks: &[(Vec<f64>, ConstraintRows, Vec<f64>)]) -> Instance {
    let n: usize = blocks.iter().map(|(w, _, _)| w.len()).sum();
    let mut rows = ConstraintRows::new(n);
    let (mut w, mut b) = (Vec::new(), Vec::new());
    let mut key = 0;
    for (bw, brows, bb) in blocks {
        let shift = w.len();
        for i in 0..bb.len() {
            let (c, a) = brows.row(i);
            rows.push(key, 0.0, c.iter().zip(a).map(|(&c, &a)| (c + shift, a)));
            key += 1;
        }
        w.extend_from_slice(bw);
        b.extend_from_slice(bb);
    }
    Instance { w, rows, b }
}

/// A crush beside small random problems: Gauss–Seidel finishes the small ones within a
/// budget of 20 passes and not the crush, which the interior point then answers; the
/// whole answer is Clarabel's, each block is the exact projection of the enumerator, and
/// the crush, recognised by its rows' keys, skips Gauss–Seidel for `retry_after` solves,
/// then is tried again; a solver given the first one's memory does the same.
#[test]
fn auto_answers_each_component_with_the_solver_that_finishes_it() {
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    let mut blocks = vec![small_crush()];
    let mut small = Vec::new();
    for _ in 0..8 {
        let inst = random_instance(&mut rng, 0);
        small.push(inst.clone());
        blocks.push((inst.w, inst.rows, inst.b));
    }
    let whole = side_by_side(&blocks);
    let p = ProjectionProblem {
        w: &whole.w,
        jacobian: &whole.rows,
        b: &whole.b,
    };
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let settings = AutoSettings {
        first_order_passes: 20,
        retry_after: 3,
        ..AutoSettings::default()
    };
    let mut auto = AutoSolver::new(settings).unwrap();
    let cold = |auto: &mut AutoSolver| {
        let mut sol = ProjectionSolution::default();
        let rep = auto.solve(&p, t, &mut sol).unwrap();
        (rep, sol)
    };
    let (first, sol) = cold(&mut auto);
    assert_eq!(first.status, SolveStatus::Converged, "{first:?}");
    assert_eq!(first.solver, "gs+interior", "{first:?}");
    assert!(
        first.factorizations > 0,
        "the interior point's are counted: {first:?}"
    );
    check_report(&p, t, "auto", &sol, &first);
    assert_clarabel_objective(&p, "auto", &sol, first.gap, &clarabel_answer(&p, t));
    // Each small block: the exact projection (its unknowns follow the crush's 450).
    let mut shift = blocks[0].0.len();
    for inst in &small {
        let (v, _) = exact_projection(inst);
        for (k, x) in v.iter().enumerate() {
            assert!(
                (sol.v[shift + k] - x).abs() <= 1e-4,
                "block at {shift}: {:?} vs {v:?}",
                &sol.v[shift..shift + v.len()]
            );
        }
        shift += v.len();
    }
    // The next `retry_after` solves skip Gauss–Seidel on the crush: fewer passes; then it
    // is tried again and spends its budget as the first time. (A report's iterations are
    // Gauss–Seidel's passes plus the interior point's iterations, one factorization each;
    // the interior point's own start from its kept iterate makes those fewer.)
    let passes = |r: &SolveReport| r.iterations - r.factorizations;
    let mut restored = AutoSolver::new(settings).unwrap();
    restored.set_memory(&auto.memory());
    let mut answers = Vec::new();
    for (name, solver) in [("auto", &mut auto), ("restored", &mut restored)] {
        let next: Vec<(SolveReport, ProjectionSolution)> =
            (0..4).map(|_| cold(&mut *solver)).collect();
        let next_passes: Vec<usize> = next.iter().map(|(r, _)| passes(r)).collect();
        assert!(
            next_passes[..3].iter().all(|&it| it < passes(&first)),
            "{name}: {next_passes:?} vs {}",
            passes(&first)
        );
        assert_eq!(next_passes[3], passes(&first), "{name}: {next_passes:?}");
        answers.push(next);
    }
    // The restored solver carries on as the one whose memory it took, bit for bit.
    for (k, ((a, x), (b, y))) in answers[0].iter().zip(&answers[1]).enumerate() {
        let timeless = |r: &SolveReport| SolveReport {
            time_analyse: 0.0,
            time_factorize: 0.0,
            ..*r
        };
        assert_eq!(
            timeless(a),
            timeless(b),
            "solve {k} after the memory was taken"
        );
        assert_eq!(x, y, "solve {k} after the memory was taken");
    }
}

/// Two crushes beside small problems: the interior point answers the larger crush alone
/// and the other with whatever Gauss–Seidel left, on one thread in turn or on two at once:
/// the same bits either way (the split does not depend on the thread count).
#[test]
fn auto_gives_the_same_bits_on_one_and_two_threads() {
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let crush = small_crush();
    // The second crush with its last 40 people's rows left out: smaller.
    let mut smaller = ConstraintRows::new(crush.0.len());
    let mut smaller_b = Vec::new();
    for i in 0..crush.2.len() {
        let (c, a) = crush.1.row(i);
        if c.iter().all(|&c| c < crush.0.len() - 80) {
            smaller.push(i as u64, 0.0, c.iter().copied().zip(a.iter().copied()));
            smaller_b.push(crush.2[i]);
        }
    }
    let mut blocks = vec![crush.clone(), (crush.0.clone(), smaller, smaller_b)];
    for _ in 0..6 {
        let inst = random_instance(&mut rng, 0);
        blocks.push((inst.w, inst.rows, inst.b));
    }
    let whole = side_by_side(&blocks);
    let p = ProjectionProblem {
        w: &whole.w,
        jacobian: &whole.rows,
        b: &whole.b,
    };
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let solve = |threads: usize| {
        let mut auto = AutoSolver::new(AutoSettings {
            first_order_passes: 20,
            parallelism: Parallelism::threads(threads),
            ..AutoSettings::default()
        })
        .unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = auto.solve(&p, t, &mut sol).unwrap();
        assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
        check_report(&p, t, "auto", &sol, &rep);
        (sol, rep)
    };
    let (one, r1) = solve(1);
    let (two, r2) = solve(2);
    assert!(r1.solver.contains("interior"), "{r1:?}");
    let bits = |x: &[f64]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one.v), bits(&two.v));
    assert_eq!(bits(&one.lambda), bits(&two.lambda));
    assert_eq!((r1.iterations, r1.gap), (r2.iterations, r2.gap));
}

/// `auto` on `push`'s rows at rest (`w = 0`, converged: so that the next solve expects small
/// changes), then on `push`: the second solve's report and answer.
fn at_rest_then_pushed(
    auto: &mut AutoSolver,
    push: &Instance,
    t: Target,
) -> (SolveReport, ProjectionSolution) {
    let zero = vec![0.0; push.w.len()];
    let rest = ProjectionProblem {
        w: &zero,
        jacobian: &push.rows,
        b: &push.b,
    };
    let mut sol = ProjectionSolution::default();
    assert!(
        auto.solve(&rest, t, &mut sol)
            .unwrap()
            .status
            .is_converged()
    );
    let p = ProjectionProblem {
        w: &push.w,
        jacobian: &push.rows,
        b: &push.b,
    };
    let rep = auto.solve(&p, t, &mut sol).unwrap();
    (rep, sol)
}

/// `auto` at rest on `rows` (so that the next solve expects small changes), then pushed at
/// `w`: converged, meeting the KKT conditions, at the exact projection; its multipliers.
fn auto_pushed_after_rest(rows: &ConstraintRows, b: &[f64], w: &[f64], name: &str) -> Vec<f64> {
    let t = Target {
        gap: 1e-12,
        violation: 1e-9,
    };
    let mut auto = AutoSolver::new(AutoSettings::default()).unwrap();
    let push = Instance {
        w: w.to_vec(),
        rows: rows.clone(),
        b: b.to_vec(),
    };
    let (rep, sol) = at_rest_then_pushed(&mut auto, &push, t);
    assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
    check_kkt(&push, name, &sol, rep.gap, rep.violation);
    let (v, _) = exact_projection(&push);
    for (a, b) in sol.v.iter().zip(&v) {
        assert!((a - b).abs() <= 1e-5, "{name}: {:?} vs {v:?}", sol.v);
    }
    sol.lambda
}

/// A row far from binding at `w` is set aside, but the correction of another row moves it
/// past zero (a row with a large gradient): `auto` sees the violation in its certificate
/// and solves again with the rows needed (and, if a row set aside is needed still, with
/// every row), reaching the exact projection.
#[test]
fn auto_solves_again_when_a_row_it_set_aside_is_needed() {
    // v1 − v0 ≥ 0 and 100 (v2 − v1) + 40 ≥ 0. Person 0 pushes person 1 at 1 m/s:
    // s(w) = (−1, 40); the second row is set aside (40 is beyond its reach), but v1 = 0.5
    // alone would make it −10.
    let mut rows = ConstraintRows::new(3);
    rows.push(0, 0.0, [(0, -1.0), (1, 1.0)]);
    rows.push(1, 0.0, [(1, -100.0), (2, 100.0)]);
    let lambda = auto_pushed_after_rest(&rows, &[0.0, 40.0], &[1.0, 0.0, 0.0], "a pair");
    assert!(lambda[1] > 0.0, "the second row binds: {lambda:?}");

    // A chain of three rows pushed at 3 m/s: the second row is needed (the first solve
    // violates it), and with it the third (the solve again with the second violates it),
    // so the last solve has every row.
    let mut rows = ConstraintRows::new(4);
    rows.push(0, 0.0, [(0, -1.0), (1, 1.0)]);
    rows.push(1, 0.0, [(1, -100.0), (2, 100.0)]);
    rows.push(2, 0.0, [(2, -100.0), (3, 100.0)]);
    let w = [3.0, 0.0, 0.0, 0.0];
    let lambda = auto_pushed_after_rest(&rows, &[0.0, 40.0, 40.0], &w, "a chain");
    assert!(
        lambda.iter().all(|&l| l > 0.0),
        "every row binds: {lambda:?}"
    );
}

/// A chain of `n` people pushed at its head (rows `v_{k+1} − v_k ≥ 0`, touching), its last
/// person `n − 1` 0.04 m behind person `n` through a stiff row `1000 (v_n − v_{n−1}) + 40 ≥ 0`
/// that is far from binding at rest: `auto`, its Gauss–Seidel given one pass (so the chain
/// goes to a Newton-type solver), at rest and then pushed; the pushed solve's report and
/// answer. The first answer moves the chain at `1/n`, which violates the stiff row: a round
/// takes back that one row.
fn pushed_chain_with_a_round(
    settings: AutoSettings,
    n: usize,
) -> (SolveReport, Instance, Vec<f64>, Vec<f64>) {
    let mut rows = ConstraintRows::new(n + 1);
    for k in 0..n - 1 {
        rows.push(k as u64, 0.0, [(k, -1.0), (k + 1, 1.0)]);
    }
    rows.push(n as u64, 0.0, [(n - 1, -1000.0), (n, 1000.0)]);
    let mut b = vec![0.0; n];
    b[n - 1] = 40.0;
    let mut w = vec![0.0; n + 1];
    w[0] = 1.0;
    let push = Instance { w, rows, b };
    let t = Target {
        gap: 1e-10,
        violation: 1e-9,
    };
    let mut auto = AutoSolver::new(AutoSettings {
        first_order_passes: 1,
        ..settings
    })
    .unwrap();
    let (rep, sol) = at_rest_then_pushed(&mut auto, &push, t);
    assert_eq!(auto.screen().rounds, 1, "{rep:?}");
    (rep, push, sol.v, sol.lambda)
}

/// A round that takes back one row goes to the semismooth Newton method first, warm from
/// the answer it corrects: certified, at the closed-form projection (the chain and its last
/// person move together at `1.04 / (n + 1)`, the last one 0.04 m/s slower), with the same
/// bits on two threads; the interior point gives the same projection when the Newton
/// method is off. (That it takes the round back when the Newton method does not finish, with
/// that work counted, is `auto.rs`' unit test
/// `a_round_the_newton_method_does_not_finish_goes_back_to_the_interior_point`.)
#[test]
fn a_round_that_takes_back_a_row_is_answered_by_newton_from_the_answer_it_corrects() {
    let n = 10;
    let c = 1.04 / (n + 1) as f64;
    let exact: Vec<f64> = (0..=n).map(|k| if k < n { c } else { c - 0.04 }).collect();
    let check =
        |name: &str, (rep, push, v, lambda): &(SolveReport, Instance, Vec<f64>, Vec<f64>)| {
            assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
            let sol = ProjectionSolution {
                v: v.clone(),
                lambda: lambda.clone(),
            };
            check_kkt(push, name, &sol, rep.gap, rep.violation);
            for (k, (a, e)) in v.iter().zip(&exact).enumerate() {
                assert!(
                    (a - e).abs() <= 1e-6,
                    "{name}: v[{k}] = {a}, closed form {e}"
                );
            }
            assert!(
                lambda.iter().all(|&l| l > 0.0),
                "{name}: every row binds: {lambda:?}"
            );
        };

    let newton = pushed_chain_with_a_round(AutoSettings::default(), n);
    check("newton", &newton);
    assert_eq!(newton.0.solver, "newton", "{:?}", newton.0);
    let two = pushed_chain_with_a_round(
        AutoSettings {
            parallelism: Parallelism::threads(2),
            ..AutoSettings::default()
        },
        n,
    );
    assert_eq!(two.0.solver, "newton");
    let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&newton.2), bits(&two.2));
    assert_eq!(bits(&newton.3), bits(&two.3));

    let interior = pushed_chain_with_a_round(
        AutoSettings {
            round_newton_factorizations: 0,
            ..AutoSettings::default()
        },
        n,
    );
    check("interior", &interior);
    assert_eq!(interior.0.solver, "interior", "{:?}", interior.0);
}

/// Every option of the Gauss–Seidel (no momentum, symmetric sweeps, under- and
/// over-relaxation, the rows by unknown, a certificate after every sweep).
fn gauss_seidel_variants() -> Vec<(&'static str, GaussSeidelSettings)> {
    let b = GaussSeidelSettings::builder;
    vec![
        ("plain", b().momentum(false).build().unwrap()),
        ("symmetric", b().symmetric(true).build().unwrap()),
        (
            "symmetric plain",
            b().symmetric(true).momentum(false).build().unwrap(),
        ),
        ("ω 1.7", b().relaxation(1.7).build().unwrap()),
        (
            "ω 0.6",
            b().relaxation(0.6).momentum(false).build().unwrap(),
        ),
        (
            "by unknown",
            b().order(RowOrder::ByUnknown).build().unwrap(),
        ),
        ("certify every sweep", b().certify_every(1).build().unwrap()),
    ]
}

#[test]
fn every_gauss_seidel_variant_meets_kkt_cold_and_warm() {
    for (i, (name, settings)) in gauss_seidel_variants().into_iter().enumerate() {
        let mut solver = GaussSeidel::new(settings).unwrap();
        // The instances of the three families of tests above, in turn (the first 12 of 40).
        let set = i % 3;
        for kind in 0..5 {
            let seed = 100 * (set as u64 + 1) + kind as u64;
            let (scaled, churn) = [(false, false), (true, false), (kind % 2 == 1, true)][set];
            // Any failure names the solver; say which variant too.
            eprintln!("variant {name}, family {kind}");
            run_cold_and_warm(&mut solver, kind, 12, seed, scaled, churn);
        }
    }
}

/// `x ≥ 1` and `x ≤ 0` (with a harmless second unknown), then the same pair hidden among
/// feasible rows: no multiplier can close the gap, and no variant may call it converged.
#[test]
fn an_infeasible_problem_is_never_converged_by_gauss_seidel() {
    let mut small = ConstraintRows::new(2);
    small.push(0, 0.0, [(0, 1.0)]);
    small.push(1, 0.0, [(0, -1.0)]);
    let mut mixed = ConstraintRows::new(3);
    mixed.push(0, 0.0, [(1, 1.0), (2, -1.0)]);
    mixed.push(1, 0.0, [(0, 2.0), (1, 0.5)]);
    mixed.push(2, 0.0, [(0, -1.0), (1, -0.25)]);
    mixed.push(3, 0.0, [(2, 1.0)]);
    let problems = [
        (small, vec![0.3, -0.2], vec![-1.0, 0.0]),
        (mixed, vec![1.0, -1.0, 0.5], vec![0.5, -2.0, 0.0, 1.0]),
    ];
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    for (rows, w, b) in &problems {
        let p = ProjectionProblem {
            w,
            jacobian: rows,
            b,
        };
        let mut variants = gauss_seidel_variants();
        variants.push(("default", GaussSeidelSettings::default()));
        for (name, settings) in variants {
            let settings = GaussSeidelSettings {
                max_passes: 3000,
                ..settings
            };
            let mut sol = ProjectionSolution::default();
            let rep = GaussSeidel::new(settings)
                .unwrap()
                .solve(&p, t, &mut sol)
                .unwrap();
            assert!(
                matches!(
                    rep.status,
                    SolveStatus::MaxIterations | SolveStatus::Infeasible
                ),
                "{name}: {rep:?}"
            );
            assert!(
                rep.violation > t.violation || rep.gap > t.gap,
                "{name}: {rep:?}"
            );
            check_report(&p, t, name, &sol, &rep);
        }
    }
}

/// The small crush solved by every Gauss–Seidel variant to the same objective as Clarabel,
/// cold and warm.
/// A hexagonal packing of 15 × 15 disks 2.4 mm apart, everyone pushing at 1 m/s towards the
/// centre (the bench's crush in miniature: every row a contact of 4 nonzeros): `(w, J, b)`.
fn small_crush() -> (Vec<f64>, ConstraintRows, Vec<f64>) {
    crush(15, 0.995)
}

/// A hexagonal packing of `side × side` disks 0.48 m apart, of radius `fill` × 0.24 m,
/// everyone pushing at 1 m/s towards the centre over a step of 0.05 s: `(w, J, b)`. Two
/// neighbours at a distance `r` from the centre close at about `d/r` m/s, so only the
/// contacts within `0.05 d / gap` of the centre are violated at `w`.
fn crush(side: usize, fill: f64) -> (Vec<f64>, ConstraintRows, Vec<f64>) {
    crush_moved(side, fill, &[])
}

/// [`crush`] with each disk moved by `moves` (none where it is shorter): the rows are still
/// those of the packing's neighbours, their normals and gaps the moved disks'.
fn crush_moved(side: usize, fill: f64, moves: &[[f64; 2]]) -> (Vec<f64>, ConstraintRows, Vec<f64>) {
    let (d, mu) = (0.48, 0.05);
    let radius = fill * d / 2.0;
    let (per_row, rows_of_people) = (side, side);
    let mut q = Vec::new();
    for r in 0..rows_of_people {
        for c in 0..per_row {
            let shift = if r % 2 == 1 { d / 2.0 } else { 0.0 };
            q.push([c as f64 * d + shift, r as f64 * d * 3f64.sqrt() / 2.0]);
        }
    }
    let n = q.len();
    let centre = [
        q.iter().map(|p| p[0]).sum::<f64>() / n as f64,
        q.iter().map(|p| p[1]).sum::<f64>() / n as f64,
    ];
    let mut w = Vec::with_capacity(2 * n);
    for p in &q {
        let (dx, dy) = (centre[0] - p[0], centre[1] - p[1]);
        let len = (dx * dx + dy * dy).sqrt().max(1e-9);
        w.extend([dx / len, dy / len]);
    }
    let mut rows = ConstraintRows::new(2 * n);
    let mut b = Vec::new();
    let moved: Vec<[f64; 2]> = (0..n)
        .map(|i| match moves.get(i) {
            Some(m) => [q[i][0] + m[0], q[i][1] + m[1]],
            None => q[i],
        })
        .collect();
    for i in 0..n {
        for j in i + 1..n {
            let (dx, dy) = (q[i][0] - q[j][0], q[i][1] - q[j][1]);
            if (dx * dx + dy * dy).sqrt() < d + 0.1 {
                let (dx, dy) = (moved[i][0] - moved[j][0], moved[i][1] - moved[j][1]);
                let dist = (dx * dx + dy * dy).sqrt();
                let e = [dx / dist, dy / dist];
                rows.push(
                    (i * n + j) as u64,
                    0.0,
                    [
                        (2 * i, e[0]),
                        (2 * i + 1, e[1]),
                        (2 * j, -e[0]),
                        (2 * j + 1, -e[1]),
                    ],
                );
                b.push((dist - 2.0 * radius) / mu);
            }
        }
    }
    (w, rows, b)
}

#[test]
fn a_small_crush_matches_clarabel() {
    let (w, rows, b) = small_crush();
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let reference = clarabel_answer(&p, t);
    let mut variants = gauss_seidel_variants();
    variants.push(("default", GaussSeidelSettings::default()));
    for (name, settings) in variants {
        let mut solver = GaussSeidel::new(settings).unwrap();
        let mut sol = ProjectionSolution::default();
        let cold = solver.solve(&p, t, &mut sol).unwrap();
        assert_eq!(cold.status, SolveStatus::Converged, "{name}: {cold:?}");
        assert!(
            cold.iterations > 10 && cold.active > rows.len() / 2,
            "{name}: {cold:?}"
        );
        check_report(&p, t, name, &sol, &cold);
        assert_clarabel_objective(&p, name, &sol, cold.gap, &reference);
        // Warm from its own answer: certified before any sweep.
        let warm = solver.solve(&p, t, &mut sol).unwrap();
        assert_eq!(
            (warm.status, warm.iterations),
            (SolveStatus::Converged, 0),
            "{name}: {warm:?}"
        );
    }
    // The interior point on the same crush: a factorization (at least) per iteration, and
    // each counted.
    let mut interior = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    let rep = interior.solve(&p, t, &mut sol).unwrap();
    assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
    assert!(
        rep.factorizations >= rep.iterations && rep.factorizations <= 3 * rep.iterations + 3,
        "{rep:?}"
    );
    check_report(&p, t, "interior", &sol, &rep);
    assert_clarabel_objective(&p, "interior", &sol, rep.gap, &reference);
    // With Gondzio's correctors on every iteration: the same answer, certified.
    let mut corrected = InteriorPoint::new(
        InteriorPointSettings::builder()
            .corrector_threshold(0.0)
            .max_correctors(3)
            .build()
            .unwrap(),
    )
    .unwrap();
    let mut sol = ProjectionSolution::default();
    let rep = corrected.solve(&p, t, &mut sol).unwrap();
    assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
    check_report(&p, t, "interior with correctors", &sol, &rep);
    assert_clarabel_objective(&p, "interior with correctors", &sol, rep.gap, &reference);
    // And they do what they are for: longer steps, fewer factorizations than without.
    let plain = InteriorPoint::new(
        InteriorPointSettings::builder()
            .max_correctors(0)
            .build()
            .unwrap(),
    )
    .unwrap()
    .solve(&p, t, &mut ProjectionSolution::default())
    .unwrap();
    assert!(
        rep.factorizations < plain.factorizations,
        "with correctors {rep:?}, without {plain:?}"
    );
}

/// A crush whose pressure is local: 60 × 60 disks 4.8 mm apart, so that only the contacts
/// within ~5 m of the centre are violated at `w` (453 of 10,561). `auto`'s first, cold, solve sets aside
/// every row beyond its own predicted reach (the shared floor, infinite before a first
/// answer, would keep them all); the centre's pressure pushes its neighbours outward, so
/// rows set aside are needed and join, with the rows around them, in rounds; the answer is
/// Clarabel's, as with every row kept, and the same on two threads.
#[test]
fn a_crush_with_local_pressure_sets_rows_aside_by_their_own_reach() {
    let (w, rows, b) = crush(60, 0.99);
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let t = Target {
        gap: 1e-6,
        violation: 1e-9,
    };
    let violated = (0..rows.len())
        .filter(|&i| {
            let (c, a) = rows.row(i);
            b[i] + c.iter().zip(a).map(|(&c, a)| a * w[c]).sum::<f64>() < 0.0
        })
        .count();
    assert!(
        violated > 0 && violated < rows.len() / 8,
        "{violated} of {} rows violated at w",
        rows.len()
    );
    let reference = clarabel_answer(&p, t);
    let solve = |settings: AutoSettings| {
        let mut auto = AutoSolver::new(settings).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = auto.solve(&p, t, &mut sol).unwrap();
        let name = format!("{:?}", auto.screen());
        assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
        check_report(&p, t, &name, &sol, &rep);
        assert_clarabel_objective(&p, &name, &sol, rep.gap, &reference);
        (auto.screen(), sol, rep)
    };
    let (screen, sol, rep) = solve(AutoSettings::default());
    assert_eq!(screen.reach, Reach::Own, "{screen:?}");
    // More rows are needed than those violated at w (the pressure travels), far fewer than
    // all: one or two rounds (the rows needed joined with the rows around them; without
    // those, 5 rounds, a ring each: checked), not every row.
    assert!(
        rep.active > 2 * violated,
        "{rep:?}, {violated} violated at w"
    );
    assert!(
        (1..=2).contains(&screen.rounds) && screen.rows_kept < rows.len() / 2,
        "{screen:?} of {} rows",
        rows.len()
    );
    let (every, _, _) = solve(AutoSettings {
        own_reach_ratio: f64::INFINITY,
        ..AutoSettings::default()
    });
    assert_eq!(
        (every.reach, every.rows_kept),
        (Reach::None, rows.len()),
        "{every:?}"
    );
    let (on_two, two, _) = solve(AutoSettings {
        parallelism: Parallelism::threads(2),
        ..AutoSettings::default()
    });
    assert_eq!(on_two, screen);
    assert_eq!(
        (&sol.v, &sol.lambda),
        (&two.v, &two.lambda),
        "one thread and two"
    );
}

/// A settled crush: the small crush solved again and again from the previous answer's
/// multipliers (the integrator's warm start), everyone pushing 2 % harder each time, so that
/// the contacts stay and only their multipliers move. Once a solve ends with the active set
/// it started from, the next is answered by the warm polish in one factorization, and the
/// one after by the polish with that factorization again; every answer is Clarabel's, and
/// the same on two threads. Then everyone pulls away: the polish is tried, fails, and the
/// interior point answers.
#[test]
fn a_settled_crush_is_answered_by_the_warm_polish_in_one_factorization() {
    let (w, rows, b) = small_crush();
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let pushes: Vec<Vec<f64>> = (0..4)
        .map(|k| w.iter().map(|x| (1.0 + 0.02 * k as f64) * x).collect())
        .collect();
    let settled = |settings: InteriorPointSettings| {
        let mut interior = InteriorPoint::new(settings).unwrap();
        let mut sol = ProjectionSolution::default();
        let mut reports = Vec::new();
        for (k, push) in pushes.iter().enumerate() {
            let p = ProjectionProblem {
                w: push,
                jacobian: &rows,
                b: &b,
            };
            let rep = interior.solve(&p, t, &mut sol).unwrap();
            let name = format!("push {k}");
            assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
            check_report(&p, t, &name, &sol, &rep);
            assert_clarabel_objective(&p, &name, &sol, rep.gap, &clarabel_answer(&p, t));
            reports.push(rep);
        }
        (interior, sol, reports)
    };
    let (mut interior, mut sol, reports) = settled(InteriorPointSettings::default());
    // The same answers, bit for bit, on two threads (the loops sum in fixed chunks; the 2×2
    // blocks factorize sequentially).
    let (_, two_threads, _) = settled(
        InteriorPointSettings::builder()
            .parallelism(Parallelism::threads(2))
            .build()
            .unwrap(),
    );
    assert_eq!(
        (&sol.v, &sol.lambda),
        (&two_threads.v, &two_threads.lambda),
        "one thread and two"
    );
    // And with the factorizations and solves split over two threads (the elimination tree's
    // two heaviest parts at once): the same bits again.
    let (split, split_answer, split_reports) = settled(
        InteriorPointSettings::builder()
            .split_factorization(true)
            .build()
            .unwrap(),
    );
    assert!(
        split.counts().split_factorizations > 0,
        "{:?}",
        split.counts()
    );
    assert_eq!(
        (&sol.v, &sol.lambda),
        (&split_answer.v, &split_answer.lambda),
        "one thread and the split factorization"
    );
    for (a, b) in reports.iter().zip(&split_reports) {
        assert_eq!((a.iterations, a.gap), (b.iterations, b.gap));
    }
    // Cold, then warm by the interior point (its warm start not yet known to be settled),
    // then polished (two multiplier updates), then polished with the same factorization
    // (the rows and `J` the same) from the extrapolated multipliers (one update).
    assert!(reports[0].factorizations > 5, "{:?}", reports[0]);
    assert!(reports[1].factorizations > 1, "{:?}", reports[1]);
    assert_eq!((reports[2].iterations, reports[2].factorizations), (2, 1));
    assert_eq!((reports[3].iterations, reports[3].factorizations), (1, 0));
    // Without the polish the settled solves take the interior point's iterations.
    let (_, _, plain) = settled(
        InteriorPointSettings::builder()
            .polish_penalty(0.0)
            .build()
            .unwrap(),
    );
    assert!(plain[3].factorizations > 3, "{:?}", plain[3]);

    // Everyone pulls away from the centre: no contact stays active.
    let away: Vec<f64> = w.iter().map(|x| -x).collect();
    let q = ProjectionProblem {
        w: &away,
        jacobian: &rows,
        b: &b,
    };
    let rep = interior.solve(&q, t, &mut sol).unwrap();
    assert_eq!(rep.status, SolveStatus::Converged, "{rep:?}");
    assert!(rep.factorizations > 1, "{rep:?}");
    check_report(&q, t, "pulled away", &sol, &rep);
    assert_clarabel_objective(&q, "pulled away", &sol, rep.gap, &clarabel_answer(&q, t));
}

/// Gauss–Seidel giving up by its progress, on the small crush from cold (it needs `P`
/// passes, slowly at first: the distance to the target falls ninefold in its first 18
/// passes and 3·10⁷-fold in the next 170): with a budget of 3P it still finishes, with the same
/// passes and bits as without the rule; with P/4 it gives up before spending half of it,
/// returning a certified pair, where without the rule it spends all of it.
#[test]
fn gauss_seidel_gives_up_early_only_when_its_budget_will_not_finish() {
    let (w, rows, b) = small_crush();
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let solve = |budget: usize, abandon: bool| {
        let settings = GaussSeidelSettings::builder()
            .max_passes(budget)
            .abandon_when_slow(abandon)
            .build()
            .unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = GaussSeidel::new(settings)
            .unwrap()
            .solve(&p, t, &mut sol)
            .unwrap();
        check_report(&p, t, "gauss-seidel", &sol, &rep);
        (rep, sol)
    };
    let (full, full_sol) = solve(20_000, false);
    assert_eq!(full.status, SolveStatus::Converged, "{full:?}");
    let needed = full.iterations;
    assert!(needed >= 200, "the crush should need many passes: {full:?}");

    let (roomy, roomy_sol) = solve(3 * needed, true);
    assert_eq!(
        (roomy.status, roomy.iterations),
        (SolveStatus::Converged, needed),
        "{roomy:?}"
    );
    let bits = |x: &[f64]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&roomy_sol.lambda), bits(&full_sol.lambda));

    let short = needed / 4;
    let (spent, _) = solve(short, false);
    assert_eq!(
        (spent.status, spent.iterations),
        (SolveStatus::MaxIterations, short),
        "{spent:?}"
    );
    let (given_up, _) = solve(short, true);
    assert_eq!(given_up.status, SolveStatus::MaxIterations, "{given_up:?}");
    assert!(
        (16..short / 2).contains(&given_up.iterations),
        "gave up after {} of {short} passes",
        given_up.iterations
    );
}

#[test]
fn a_violated_zero_row_is_reported_infeasible_by_all() {
    let mut rows = ConstraintRows::new(2);
    rows.push(0, 0.0, [(0, 1.0)]);
    rows.push(1, 0.0, []);
    let p = ProjectionProblem {
        w: &[1.0, 1.0],
        jacobian: &rows,
        b: &[0.0, -1.0],
    };
    let t = Target {
        gap: 1e-10,
        violation: 1e-9,
    };
    let mut sol = ProjectionSolution::default();
    assert_eq!(
        Apgd::default().solve(&p, t, &mut sol).unwrap().status,
        SolveStatus::Infeasible
    );
    let mut sol = ProjectionSolution::default();
    assert_eq!(
        ClarabelReference::default()
            .solve(&p, t, &mut sol)
            .unwrap()
            .status,
        SolveStatus::Infeasible
    );
    let mut sol = ProjectionSolution::default();
    let mut interior = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    assert_eq!(
        interior.solve(&p, t, &mut sol).unwrap().status,
        SolveStatus::Infeasible
    );
    let mut sol = ProjectionSolution::default();
    let mut newton = Newton::new(NewtonSettings::default()).unwrap();
    assert_eq!(
        newton.solve(&p, t, &mut sol).unwrap().status,
        SolveStatus::Infeasible
    );
    let mut sol = ProjectionSolution::default();
    assert_eq!(
        GaussSeidel::default()
            .solve(&p, t, &mut sol)
            .unwrap()
            .status,
        SolveStatus::Infeasible
    );
}

#[test]
fn warm_start_from_the_answer_needs_no_iteration_and_cold_start_does() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let t = Target {
        gap: 1e-9,
        violation: 1e-9,
    };
    let mut solver = Apgd::new(ApgdSettings::default()).unwrap();
    // The first instance whose unconstrained velocity is infeasible.
    let (inst, mut sol, cold) = loop {
        let inst = random_instance(&mut rng, 2);
        let p = ProjectionProblem {
            w: &inst.w,
            jacobian: &inst.rows,
            b: &inst.b,
        };
        let mut sol = ProjectionSolution::default();
        let cold = solver.solve(&p, t, &mut sol).unwrap();
        if cold.active > 0 {
            break (inst, sol, cold);
        }
    };
    let p = ProjectionProblem {
        w: &inst.w,
        jacobian: &inst.rows,
        b: &inst.b,
    };
    let warm = solver.solve(&p, t, &mut sol).unwrap();
    assert!(
        cold.iterations > 0 && warm.iterations == 0,
        "cold {cold:?} warm {warm:?}"
    );
}

#[test]
fn settings_are_validated() {
    assert!(ApgdSettings::builder().max_iterations(0).build().is_err());
    let e = ApgdSettings::builder()
        .power_iterations(0)
        .build()
        .unwrap_err();
    assert!(e.to_string().contains("power_iterations"), "{e}");
    let gs = GaussSeidelSettings::builder;
    for omega in [0.0, 2.0, -1.0, f64::NAN] {
        let e = gs().relaxation(omega).build().unwrap_err();
        assert!(e.to_string().contains("relaxation"), "{e}");
    }
    assert!(gs().relaxation(1.99).build().is_ok());
    for ratio in [0.5, f64::NAN] {
        let e = AutoSolver::new(AutoSettings {
            own_reach_ratio: ratio,
            ..AutoSettings::default()
        })
        .unwrap_err();
        assert!(e.to_string().contains("own_reach_ratio"), "{e}");
    }
    let e = gs().max_passes(0).build().unwrap_err();
    assert!(e.to_string().contains("max_passes"), "{e}");
    // Budgets above 10⁶ are refused by name: `power_iterations = 1e15` was taken and ran
    // inside one solve until killed.
    let e = ApgdSettings::builder()
        .power_iterations(1_000_000_000_000_000)
        .build()
        .unwrap_err();
    assert!(
        e.to_string()
            .contains("power_iterations = 1000000000000000"),
        "{e}"
    );
    assert!(
        ApgdSettings::builder()
            .power_iterations(MAX_BUDGET)
            .build()
            .is_ok()
    );
    let e = gs().max_passes(MAX_BUDGET + 1).build().unwrap_err();
    assert!(e.to_string().contains("max_passes"), "{e}");
    let e = AutoSolver::new(AutoSettings {
        first_order_passes: usize::MAX,
        ..AutoSettings::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("first_order_passes"), "{e}");
    // (Regression: unchecked, and 2³² was cut to 0 retries.)
    let e = AutoSolver::new(AutoSettings {
        retry_after: 1 << 32,
        ..AutoSettings::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("retry_after"), "{e}");
    // (Regression: Clarabel's settings were not checked.)
    let mut rows = ConstraintRows::new(1);
    rows.push(0, 0.0, [(0, 1.0)]);
    let p = ProjectionProblem {
        w: &[0.0],
        jacobian: &rows,
        b: &[0.0],
    };
    let t = Target {
        gap: 1e-9,
        violation: 1e-9,
    };
    for (settings, field) in [
        (
            ClarabelSettings {
                tolerance: f64::NAN,
                ..Default::default()
            },
            "tolerance",
        ),
        (
            ClarabelSettings {
                tolerance: -1.0,
                ..Default::default()
            },
            "tolerance",
        ),
        (
            ClarabelSettings {
                max_iterations: 0,
                ..Default::default()
            },
            "max_iterations",
        ),
    ] {
        let e = ClarabelReference::new(settings)
            .solve(&p, t, &mut ProjectionSolution::default())
            .unwrap_err();
        assert!(e.to_string().contains(field), "{e}");
    }
    let e = gs().certify_every(0).build().unwrap_err();
    assert!(e.to_string().contains("certify_every"), "{e}");
    let bad = GaussSeidelSettings {
        relaxation: 2.5,
        ..GaussSeidelSettings::default()
    };
    assert!(GaussSeidel::new(bad).is_err());
    let mut rows = ConstraintRows::new(1);
    rows.push(0, 0.0, [(0, 1.0)]);
    let p = ProjectionProblem {
        w: &[f64::NAN],
        jacobian: &rows,
        b: &[0.0],
    };
    let e = Apgd::default()
        .solve(
            &p,
            Target {
                gap: 1.0,
                violation: 1.0,
            },
            &mut ProjectionSolution::default(),
        )
        .unwrap_err();
    assert!(e.to_string().contains("non-finite w at index 0"), "{e}");
}

/// A NaN or ∞ in the Jacobian was certified as a perfect answer (gap 0, violation 0) by every
/// kind, and through the integrator a step ended inside its obstacle, "converged"; a NaN
/// velocity too. Now the problem is refused by name, and the certificate of a NaN answer is
/// infinite.
#[test]
fn a_nan_in_the_jacobian_was_certified_as_a_perfect_answer() {
    use moreau_core::Parallelism;
    for bad in [f64::NAN, f64::INFINITY] {
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, bad), (1, 1.0)]);
        let p = ProjectionProblem {
            w: &[-1.0, 0.0],
            jacobian: &rows,
            b: &[0.0],
        };
        let target = Target {
            gap: 1e-9,
            violation: 1e-9,
        };
        for kind in moreau_solve::SolverKind::ALL {
            let mut solver = kind.build(Parallelism::SEQUENTIAL, 2).unwrap();
            let e = solver
                .solve(&p, target, &mut ProjectionSolution::default())
                .unwrap_err();
            assert!(
                e.to_string().contains("jacobian coefficient at index 0"),
                "{kind:?}: {e}"
            );
        }
    }
    let mut rows = ConstraintRows::new(2);
    rows.push(0, 0.0, [(0, 1.0), (1, 1.0)]);
    let p = ProjectionProblem {
        w: &[-1.0, 0.0],
        jacobian: &rows,
        b: &[0.0],
    };
    let (mut sm, mut sn) = (vec![0.0; 1], vec![0.0; 2]);
    let c = certify(&p, &[f64::NAN, 0.0], &[0.5], &mut sm, &mut sn);
    assert!(
        c.violation == f64::INFINITY && c.gap == f64::INFINITY,
        "{c:?}"
    );
    let c = certify(&p, &[-0.5, 0.5], &[0.5], &mut sm, &mut sn);
    assert!(c.violation == 0.0 && c.gap.abs() < 1e-15, "{c:?}");
    // A NaN target ran the whole budget (20,000 APGD iterations) before saying it was not
    // met; now refused by every kind, as a negative one. An infinite gap asks nothing.
    for (gap, violation) in [(f64::NAN, 1e-9), (1e-9, f64::NAN), (-1.0, 1e-9)] {
        for kind in moreau_solve::SolverKind::ALL {
            let mut solver = kind.build(Parallelism::SEQUENTIAL, 2).unwrap();
            let e = solver
                .solve(
                    &p,
                    Target { gap, violation },
                    &mut ProjectionSolution::default(),
                )
                .unwrap_err();
            assert!(
                e.to_string().contains("invalid setting target"),
                "{kind:?}: {e}"
            );
        }
    }
    let mut solver = moreau_solve::SolverKind::Auto
        .build(Parallelism::SEQUENTIAL, 2)
        .unwrap();
    let target = Target {
        gap: f64::INFINITY,
        violation: 1e-9,
    };
    solver
        .solve(&p, target, &mut ProjectionSolution::default())
        .unwrap();
}

/// APGD's backtracking on a one-row problem with coefficients of 1e80 and more doubled its
/// Lipschitz estimate forever (its test never held once the products overflowed): the solve
/// never returned. Now it ends, with an honest status, and the chain's fallback answers.
#[test]
fn apgd_never_returned_on_a_row_with_huge_coefficients() {
    use std::sync::mpsc;
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for c in [1e80, 1e100, 1e155, 1e160] {
            let mut rows = ConstraintRows::new(2);
            rows.push(0, 0.0, [(0, c), (1, 0.0)]);
            let p = ProjectionProblem {
                w: &[-1.0, 0.0],
                jacobian: &rows,
                b: &[0.0],
            };
            let target = Target {
                gap: 1e-9,
                violation: 1e-9,
            };
            let r = Apgd::default().solve(&p, target, &mut ProjectionSolution::default());
            tx.send((c, r.map(|r| r.status))).unwrap();
        }
    });
    for _ in 0..4 {
        let (c, status) = rx
            .recv_timeout(std::time::Duration::from_secs(120))
            .expect("APGD did not return within 2 minutes");
        // Converged only with its certificate, which the solve computes; whatever the status.
        assert!(status.is_ok(), "c = {c}: {status:?}");
    }
}

/// On 1 and 2 threads: APGD and Gauss–Seidel give the same bits (their parallel loops sum in
/// fixed chunks);
/// the interior point's, Newton's and `auto`'s answers agree within their certified radii (faer's parallel
/// supernodal factorization, which it picks on this random problem, sums in another order).
/// Problems larger than one chunk (4,096 rows) so that the loops do split.
#[test]
fn one_and_two_threads_give_the_same_answer() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let n = 6000;
    // Feasible by construction: b = s0 − J v0 with s0 ≥ 0 (a third exactly 0).
    let v0: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut rows = ConstraintRows::new(n);
    let mut b = Vec::new();
    for i in 0..9000 {
        let (c1, c2) = (rng.random_range(0..n), rng.random_range(0..n));
        if c1 == c2 {
            continue;
        }
        let a2 = -rng.random_range(0.5..1.5);
        rows.push(i, 0.0, [(c1, 1.0), (c2, a2)]);
        let s0 = if rng.random_bool(0.3) {
            0.0
        } else {
            rng.random_range(0.0..0.5)
        };
        b.push(s0 - v0[c1] - a2 * v0[c2]);
    }
    let w: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let solve = |threads: usize, which: &str| {
        let par = Parallelism::threads(threads);
        let mut solver: Box<dyn ProjectionSolver> = match which {
            "interior" => Box::new(
                InteriorPoint::new(
                    InteriorPointSettings::builder()
                        .parallelism(par)
                        .build()
                        .unwrap(),
                )
                .unwrap(),
            ),
            "newton" => Box::new(
                Newton::new(NewtonSettings::builder().parallelism(par).build().unwrap()).unwrap(),
            ),
            "auto" => Box::new(
                AutoSolver::new(AutoSettings {
                    parallelism: par,
                    ..AutoSettings::default()
                })
                .unwrap(),
            ),
            "gauss-seidel" => Box::new(
                GaussSeidel::new(
                    GaussSeidelSettings::builder()
                        .parallelism(par)
                        .build()
                        .unwrap(),
                )
                .unwrap(),
            ),
            _ => Box::new(
                Apgd::new(ApgdSettings::builder().parallelism(par).build().unwrap()).unwrap(),
            ),
        };
        let mut sol = ProjectionSolution::default();
        let rep = solver.solve(&p, t, &mut sol).unwrap();
        assert!(rep.status.is_converged(), "{rep:?}");
        assert!(rep.iterations > 0);
        (sol, rep)
    };
    let ((one, _), (two, _)) = (solve(1, "apgd"), solve(2, "apgd"));
    assert_eq!(one.v, two.v, "APGD");
    assert_eq!(one.lambda, two.lambda, "APGD");
    // Gauss–Seidel: sequential sweeps, certificates and objectives summed in fixed chunks.
    let ((one, r1), (two, r2)) = (solve(1, "gauss-seidel"), solve(2, "gauss-seidel"));
    assert_eq!(one.v, two.v, "Gauss–Seidel");
    assert_eq!(one.lambda, two.lambda, "Gauss–Seidel");
    assert_eq!(r1, r2, "Gauss–Seidel");
    // ½|v − v*|² ≤ gap + |λ*|₁·violation for each answer (λ* approximated by the answer's λ).
    for which in ["interior", "newton", "auto"] {
        let ((one, r1), (two, r2)) = (solve(1, which), solve(2, which));
        let l1: f64 = one.lambda.iter().sum();
        let radius = |r: &SolveReport| (2.0 * (r.gap + l1 * r.violation)).sqrt();
        let dist = one
            .v
            .iter()
            .zip(&two.v)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        assert!(
            dist <= radius(&r1) + radius(&r2),
            "{which}: |v₁ − v₂| = {dist} > {} + {}",
            radius(&r1),
            radius(&r2)
        );
    }
}

/// The interior point's start from its kept iterate (`warm_iterate`) on a crush pushed a
/// little harder, and in new directions, at every solve: fewer iterations than Mehrotra's
/// start on the same problems, the same answers to the target (Clarabel's objective), and a
/// solver restored from another's memory goes on bit for bit.
#[test]
fn the_kept_iterate_starts_the_next_solve_closer_and_survives_a_restore() {
    let (w, rows, b) = small_crush();
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let pushes: Vec<Vec<f64>> = (0..8)
        .map(|k| {
            w.iter()
                .map(|x| (1.0 + 0.01 * k as f64) * x + rng.random_range(-0.01..0.01))
                .collect()
        })
        .collect();
    // The polish off: each solve is the interior point's.
    let settings = |kept: f64| {
        InteriorPointSettings::builder()
            .polish_penalty(0.0)
            .warm_iterate(kept)
            .build()
            .unwrap()
    };
    let run = |interior: &mut InteriorPoint, sol: &mut ProjectionSolution, k: usize| {
        let p = ProjectionProblem {
            w: &pushes[k],
            jacobian: &rows,
            b: &b,
        };
        let rep = interior.solve(&p, t, sol).unwrap();
        let name = format!("push {k}");
        assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
        check_report(&p, t, &name, sol, &rep);
        assert_clarabel_objective(&p, &name, sol, rep.gap, &clarabel_answer(&p, t));
        rep.iterations
    };
    let (mut kept, mut cold) = (
        InteriorPoint::new(settings(1e9)).unwrap(),
        InteriorPoint::new(settings(0.0)).unwrap(),
    );
    let (mut kept_sol, mut cold_sol) =
        (ProjectionSolution::default(), ProjectionSolution::default());
    let (mut kept_its, mut cold_its) = (Vec::new(), Vec::new());
    for k in 0..4 {
        kept_its.push(run(&mut kept, &mut kept_sol, k));
        cold_its.push(run(&mut cold, &mut cold_sol, k));
    }
    // The first solve is cold for both; the next ones start from the kept iterate.
    assert_eq!(kept_its[0], cold_its[0]);
    let (a, c): (usize, usize) = (kept_its[1..].iter().sum(), cold_its[1..].iter().sum());
    assert!(
        4 * a <= 3 * c,
        "kept {kept_its:?} against Mehrotra's start {cold_its:?}"
    );
    // Restored from the memory, a new solver answers the next pushes as the first does.
    let mut restored = InteriorPoint::new(settings(1e9)).unwrap();
    restored.set_memory(&kept.memory());
    let mut restored_sol = kept_sol.clone();
    for k in 4..8 {
        let a = run(&mut kept, &mut kept_sol, k);
        let b = run(&mut restored, &mut restored_sol, k);
        assert_eq!(a, b, "push {k}");
        assert_eq!(kept_sol, restored_sol, "push {k}");
    }
    // A damaged row of the kept iterate (its multiplier not a number) starts as a new row:
    // the start from the rest still pays, from zero multipliers as from the previous ones.
    let mut memory = kept.memory();
    let ordering = after_kept_analysis(&memory);
    memory[ordering + 6 + 3] = f64::NAN;
    let mut damaged = InteriorPoint::new(settings(1e9)).unwrap();
    damaged.set_memory(&memory);
    let its = run(&mut damaged, &mut ProjectionSolution::default(), 7);
    assert!(
        its < cold_its[0],
        "{its} iterations from a damaged kept iterate, {} from Mehrotra's start",
        cold_its[0]
    );
    // A memory that is not one leaves the solver as new (its first solve is cold).
    let mut fresh = InteriorPoint::new(settings(1e9)).unwrap();
    fresh.set_memory(&[1.0, 2.0, f64::NAN]);
    assert!(fresh.memory().len() == 6, "{:?}", fresh.memory());
    let mut fresh_sol = ProjectionSolution::default();
    assert_eq!(run(&mut fresh, &mut fresh_sol, 0), cold_its[0]);
}

/// Where the interior point's memory goes on after what its orderings depend on (`[−4,
/// since, skip, G, (hash halves, G groups)?, P, P pairs, R, R quadruples]`, crate::reorder),
/// 0 without it.
fn after_kept_analysis(memory: &[f64]) -> usize {
    if memory.first() != Some(&-4.0) {
        return 0;
    }
    let groups = memory[3] as usize;
    let at = 4 + if groups > 0 { 2 + groups } else { 0 };
    let places = memory[at] as usize;
    let rows = memory[at + 1 + 2 * places] as usize;
    at + 2 + 2 * places + 4 * rows
}

/// Regression: the polish's history (whether the last solve settled, its back-off) was not in
/// the interior point's memory, so a run resumed from a saved state could start a solve
/// differently from the run that went on. Restored from the memory, a solver polishes the
/// settled crush exactly as the original does.
#[test]
fn a_restored_interior_point_polishes_as_the_original() {
    let (w, rows, b) = small_crush();
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let pushes: Vec<Vec<f64>> = (0..4)
        .map(|k| w.iter().map(|x| (1.0 + 0.02 * k as f64) * x).collect())
        .collect();
    let solve = |interior: &mut InteriorPoint, sol: &mut ProjectionSolution, k: usize| {
        let p = ProjectionProblem {
            w: &pushes[k],
            jacobian: &rows,
            b: &b,
        };
        let rep = interior.solve(&p, t, sol).unwrap();
        assert_eq!(rep.status, SolveStatus::Converged, "push {k}: {rep:?}");
        check_report(&p, t, &format!("push {k}"), sol, &rep);
        (rep.iterations, rep.factorizations)
    };
    let mut original = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    solve(&mut original, &mut sol, 0);
    solve(&mut original, &mut sol, 1);
    let mut restored = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    restored.set_memory(&original.memory());
    let mut restored_sol = sol.clone();
    for k in 2..4 {
        let a = solve(&mut original, &mut sol, k);
        let b = solve(&mut restored, &mut restored_sol, k);
        // The first polish factorizes and takes two multiplier updates; the second takes its
        // factorization (the rows the same) and, from the extrapolated multipliers, one.
        assert_eq!(
            a,
            if k == 2 { (2, 1) } else { (1, 0) },
            "push {k}: the original polished"
        );
        assert_eq!(a, b, "push {k}");
        assert_eq!(sol, restored_sol, "push {k}");
    }
}

/// The small crush settled, pushed a little harder at each solve, its people moving a little
/// between solves (by up to 10⁻⁷ m each way): `J` changes in its last digits, its rows not.
/// Each solve after the first polish takes that polish's factorization again (its solves
/// refined against the new `J`) and starts from the extrapolation of the caller's
/// multipliers (the push grows linearly, and so do they): one multiplier update where the
/// first polish took two. Each answer, judged by the certificate as any other, is Clarabel's.
/// A solve whose people have moved farther (10⁻⁴ m), where that factorization no longer
/// does, is answered too, with factorizations of its own.
#[test]
fn a_settled_crush_that_moves_a_little_is_polished_with_the_factorization_in_hand() {
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let mut interior = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    let mut factorizations = Vec::new();
    for k in 0..7 {
        let (w, rows, b) = moved(k, if k == 6 { 1e-4 } else { 1e-7 });
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let rep = interior.solve(&p, t, &mut sol).unwrap();
        let name = format!("step {k}");
        assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
        check_report(&p, t, &name, &sol, &rep);
        assert_clarabel_objective(&p, &name, &sol, rep.gap, &clarabel_answer(&p, t));
        factorizations.push((rep.iterations, rep.factorizations));
    }
    // Cold, the interior point again, then polished: with a factorization (two updates),
    // then with it again and again (one update each); moved far, polished or solved with
    // factorizations of its own.
    assert!(
        factorizations[0].1 > 5 && factorizations[1].1 > 1,
        "{factorizations:?}"
    );
    assert_eq!(factorizations[2], (2, 1), "{factorizations:?}");
    assert_eq!(&factorizations[3..6], &[(1, 0); 3], "{factorizations:?}");
    assert!(factorizations[6].1 >= 1, "{factorizations:?}");
}

/// Regression for the factorization the polish keeps: a solver restored from the memory
/// taken after a polish makes that factorization again, from the coefficients it was made
/// of (not the new `J`'s), starts from the same extrapolated multipliers, and goes on with
/// the original's bits; the memory round-trips, one cut short leaves a solver as new, and
/// session 26's layout (no start) still restores.
#[test]
fn a_restored_interior_point_polishes_with_the_original_factorization() {
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let steps: Vec<(Vec<f64>, ConstraintRows, Vec<f64>)> = (0..6).map(|k| moved(k, 1e-7)).collect();
    let solve = |interior: &mut InteriorPoint, sol: &mut ProjectionSolution, k: usize| {
        let p = ProjectionProblem {
            w: &steps[k].0,
            jacobian: &steps[k].1,
            b: &steps[k].2,
        };
        let rep = interior.solve(&p, t, sol).unwrap();
        assert_eq!(rep.status, SolveStatus::Converged, "step {k}: {rep:?}");
        check_report(&p, t, &format!("step {k}"), sol, &rep);
        rep
    };
    let mut original = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    for k in 0..3 {
        solve(&mut original, &mut sol, k);
    }
    let memory = original.memory();
    let mut restored = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    restored.set_memory(&memory);
    assert_eq!(restored.memory(), memory, "the memory round-trips");
    // Cut short, it is no memory: the solver stays as new.
    let new = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut damaged = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    damaged.set_memory(&memory[..memory.len() - 1]);
    assert_eq!(damaged.memory(), new.memory(), "a memory cut short");
    // Session 26's layout (marked −2: no polish start after the back-off) is read too: the
    // factorization made again, the first polish from the caller's multipliers, two updates.
    let rows = steps[3].1.len();
    assert_eq!(
        memory[memory.len() - rows - 1],
        rows as f64,
        "the start's count"
    );
    let mut unstarted = memory[..memory.len() - rows - 3].to_vec();
    let ordering = after_kept_analysis(&unstarted);
    assert_eq!(unstarted[ordering], -3.0);
    unstarted[ordering] = -2.0;
    let mut older = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    older.set_memory(&unstarted);
    let older_report = solve(&mut older, &mut sol.clone(), 3);
    assert_eq!(
        (older_report.iterations, older_report.factorizations),
        (2, 1)
    );
    let mut restored_sol = sol.clone();
    for k in 3..6 {
        let a = solve(&mut original, &mut sol, k);
        let b = solve(&mut restored, &mut restored_sol, k);
        assert_eq!(
            a.factorizations, 0,
            "step {k}: the original reused its factorization"
        );
        // The restored solver makes it again once, then reuses it as the original does; both
        // start from the extrapolated multipliers (one update).
        assert_eq!(b.factorizations, usize::from(k == 3), "step {k}");
        assert_eq!(a.iterations, 1, "step {k}");
        assert_eq!((a.iterations, a.gap), (b.iterations, b.gap), "step {k}");
        assert_eq!(sol, restored_sol, "step {k}");
    }
    // Made from the new `J` instead, the factorization gives other bits: the comparison
    // above can tell.
    let mut fresh = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut fresh_sol = ProjectionSolution::default();
    for k in 0..3 {
        solve(&mut fresh, &mut fresh_sol, k);
    }
    let mut other = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut head = fresh.memory();
    // The same memory without its factorization (the older layout): the next polish
    // factorizes the new `J`.
    let ordering = after_kept_analysis(&head);
    let kept = head[ordering + 7] as usize;
    let older: Vec<f64> = head[..ordering]
        .iter()
        .chain(&head[ordering + 1..ordering + 7])
        .chain(&head[ordering + 8..ordering + 8 + 4 * kept])
        .copied()
        .collect();
    head = older;
    other.set_memory(&head);
    let mut other_sol = fresh_sol.clone();
    let a = solve(&mut fresh, &mut fresh_sol, 3);
    let b = solve(&mut other, &mut other_sol, 3);
    assert_eq!((a.factorizations, b.factorizations), (0, 1));
    assert_ne!(fresh_sol, other_sol, "another factorization, other bits");
}

/// The small crush with its people moved a little by step `k`: each disk by up to `size`
/// metres in each direction (drawn per step and disk; none at step 0), everyone pushing
/// `1 + 0.02 k` times as hard: `(w, J, b)`, the same rows at every step.
fn moved(k: usize, size: f64) -> (Vec<f64>, ConstraintRows, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(1_000 + k as u64);
    let moves: Vec<[f64; 2]> = (0..15 * 15)
        .map(|_| {
            let mut draw = || {
                if k == 0 {
                    0.0
                } else {
                    size * rng.random_range(-1.0..=1.0)
                }
            };
            [draw(), draw()]
        })
        .collect();
    let (w, rows, b) = crush_moved(15, 0.995, &moves);
    let w = w.iter().map(|x| (1.0 + 0.02 * k as f64) * x).collect();
    (w, rows, b)
}

/// Regression: a crush of 900 disks asked a gap of 10⁻¹² drives `D = λ/s` past what the
/// Cholesky factorization of `I + JᵀDJ` holds, and the interior point ended with
/// `NumericalError`. It finishes with the Newton system's augmented form, certified, within
/// the certified distance of its own answer at 10⁻¹⁰ (or at 10⁻¹², since the certificate is
/// computed without cancellation, stops at its rounding floor, within 100 times it).
#[test]
fn a_crush_asked_a_tight_gap_is_certified_after_the_normal_equations_break_down() {
    let (w, rows, b) = crush(30, 0.999);
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let mut answers = Vec::new();
    for gap in [1e-10, 1e-12] {
        let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let target = Target {
            gap,
            violation: 1e-10,
        };
        let rep = ip.solve(&p, target, &mut sol).unwrap();
        let (mut sm, mut sn) = (vec![0.0; b.len()], vec![0.0; w.len()]);
        let floor = certify(&p, &sol.v, &sol.lambda, &mut sm, &mut sn).floor;
        assert!(
            (rep.status.is_converged() && rep.gap <= gap
                || rep.status == SolveStatus::RoundingFloor && rep.gap <= 1e2 * floor)
                && rep.violation <= 1e-10,
            "{rep:?}, floor {floor:e}"
        );
        let augmented = ip.counts().augmented_factorizations;
        assert_eq!(
            augmented > 0,
            gap < 1e-11,
            "{augmented} augmented at {gap:e}"
        );
        answers.push((sol.v, rep.gap));
    }
    let dist = (0..w.len())
        .map(|c| (answers[0].0[c] - answers[1].0[c]).powi(2))
        .sum::<f64>()
        .sqrt();
    let bound = (2.0 * answers[0].1).sqrt() + (2.0 * answers[1].1).sqrt();
    assert!(dist <= bound, "{dist:e} > {bound:e}");
}

/// Regression: `gauss-seidel` (or `apgd`, `newton`) that ran out of passes on a crush handed
/// the projection to Clarabel, which stops above the target there, and the run failed
/// (`NumericalError` on the crush of 40,000, benches/README.md, session 22). Our interior
/// point now comes first among the fallbacks and certifies.
#[test]
fn a_solver_that_misses_on_a_crush_hands_it_to_our_interior_point() {
    let (w, rows, b) = crush(30, 0.999);
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let target = Target {
        gap: 1e-9,
        violation: 1e-10,
    };
    let mut tuning = moreau_solve::SolverTuning::default();
    tuning.gauss_seidel.max_passes = 3;
    tuning.apgd.max_iterations = 3;
    tuning.newton.max_iterations = 1;
    for kind in [
        moreau_solve::SolverKind::GaussSeidel,
        moreau_solve::SolverKind::Apgd,
        moreau_solve::SolverKind::Newton,
    ] {
        let mut solver = kind
            .build_with(Parallelism::SEQUENTIAL, w.len(), &tuning)
            .unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = solver.solve(&p, target, &mut sol).unwrap();
        assert!(
            rep.status.is_converged() && rep.gap <= target.gap && rep.solver == "interior",
            "{kind:?}: {rep:?}"
        );
        // The answer is certified from the data, whoever gave it.
        let (mut sm, mut sn) = (vec![0.0; b.len()], vec![0.0; w.len()]);
        let c = certify(&p, &sol.v, &sol.lambda, &mut sm, &mut sn);
        assert!(
            c.gap <= target.gap && c.violation <= target.violation,
            "{c:?}"
        );
    }
}

/// Regression: a crush of 3,600 (multipliers summing to 59,000) asked a gap of 10⁻¹² is
/// below what double precision certifies (`sᵀλ` stops at 2·10⁻¹¹, its slacks at their
/// rounding), and the interior point spent its whole budget of 100 iterations there (1.9 s).
/// It stops after ten iterations without progress, with the answer it reached, and says why.
#[test]
fn a_crush_asked_below_its_rounding_floor_stops_there() {
    let (w, rows, b) = crush(60, 0.999);
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
    let mut sol = ProjectionSolution::default();
    let target = Target {
        gap: 1e-12,
        violation: 1e-10,
    };
    let rep = ip.solve(&p, target, &mut sol).unwrap();
    assert_eq!(rep.status, SolveStatus::RoundingFloor, "{rep:?}");
    assert!(rep.iterations < 40, "{rep:?}");
    assert!(rep.gap < 1e-10 && rep.violation <= 1e-10, "{rep:?}");
}

/// A solver's memory comes back from a saved run's file, i.e. from the user: damaged at any
/// place in any way (not a number, infinite, negative, fractional, huge, a count one off) or
/// cut short anywhere, the interior point and `auto` take what they can read and forget the
/// rest: never a panic, and every answer after it converged and certified to the target,
/// on the structure the memory was made on (where a kept ordering and factorization are
/// taken) and on the next one.
#[test]
fn a_solvers_memory_damaged_anywhere_is_forgotten_or_used_never_a_panic() {
    let (w, rows, b) = crush(10, 0.995);
    let moves: Vec<[f64; 2]> = (0..100)
        .map(|i| {
            [
                1e-3 * ((i * 7 % 11) as f64 - 5.0),
                1e-3 * ((i * 5 % 13) as f64 - 6.0),
            ]
        })
        .collect();
    let (_, moved_rows, moved_b) = crush_moved(10, 0.995, &moves);
    let t = Target {
        gap: 1e-8,
        violation: 1e-9,
    };
    let push = |k: usize| -> Vec<f64> { w.iter().map(|x| (1.0 + 0.02 * k as f64) * x).collect() };
    type Make = fn() -> Box<dyn ProjectionSolver>;
    let kinds: [(&str, Make); 2] = [
        ("interior", || {
            Box::new(InteriorPoint::new(InteriorPointSettings::default()).unwrap())
        }),
        ("auto", || {
            Box::new(AutoSolver::new(AutoSettings::default()).unwrap())
        }),
    ];
    for (name, make) in kinds {
        // A memory with everything in it: a kept iterate, a kept analysis and ordering, a
        // settled crush's polish with its factorization and start.
        let mut solver = make();
        let mut sol = ProjectionSolution::default();
        let mut last = SolveReport::default();
        for k in 0..4 {
            let w = push(k);
            let p = ProjectionProblem {
                w: &w,
                jacobian: &rows,
                b: &b,
            };
            let rep = solver.solve(&p, t, &mut sol).unwrap();
            assert_eq!(
                rep.status,
                SolveStatus::Converged,
                "{name} push {k}: {rep:?}"
            );
            last = rep;
        }
        // (The last push was polished with the factorization kept from the one before.)
        assert_eq!(
            (last.iterations, last.factorizations),
            (1, 0),
            "{name}: {last:?}"
        );
        let memory = solver.memory();
        assert!(memory.len() > 1000, "{name}: {} numbers", memory.len());
        let (w4, w5) = (push(4), push(5));
        let next = [
            ProjectionProblem {
                w: &w4,
                jacobian: &rows,
                b: &b,
            },
            ProjectionProblem {
                w: &w5,
                jacobian: &moved_rows,
                b: &moved_b,
            },
        ];
        let restored_runs = |memory: &[f64], what: &str| {
            let mut restored = make();
            restored.set_memory(memory);
            let mut s = sol.clone();
            for (k, p) in next.iter().enumerate() {
                let rep = restored.solve(p, t, &mut s).unwrap();
                let case = format!("{name}, {what}, solve {k}");
                assert_eq!(rep.status, SolveStatus::Converged, "{case}: {rep:?}");
                check_report(p, t, &case, &s, &rep);
            }
        };
        restored_runs(&memory, "as saved");
        let mut rng = ChaCha8Rng::seed_from_u64(30);
        let len = memory.len();
        // The head (layouts, counts) everywhere, the body at places drawn at random.
        let mut places: Vec<usize> = (0..len.min(48)).collect();
        places.extend((0..600).map(|_| rng.random_range(0..len)));
        for &at in &places {
            let was = memory[at];
            for bad in [
                f64::NAN,
                f64::INFINITY,
                -1.0,
                -7.0,
                0.5,
                1e300,
                4_294_967_296.0,
                was + 1.0,
                was - 1.0,
            ] {
                let mut damaged = memory.clone();
                damaged[at] = bad;
                restored_runs(&damaged, &format!("number {at} ({was}) set to {bad}"));
            }
        }
        for cut in (0..len).step_by(len / 40 + 1) {
            restored_runs(&memory[..cut], &format!("cut to {cut} numbers"));
        }
    }
}

/// Regression: the interior point's stall rule called every stall near the end
/// `RoundingFloor` ("the target is below what double precision certifies: ask a larger ε"),
/// and `WithFallback` then asks no fallback. On redundant, badly scaled rows with `|w|` ~ 10⁴
/// it stalled with a certified gap of up to 2.6·10⁹ (the dual residual lost to a Newton
/// matrix whose `D` spans 10³⁰), where the floor is ~10⁻⁸. A stall is the floor only within
/// a factor 100 of the certificate's `floor`; above, it is a numerical error and the fallback
/// answers.
#[test]
fn a_stall_far_above_the_rounding_floor_was_reported_as_the_floor() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let target = Target {
        gap: 5e-12,
        violation: 1e-10,
    };
    let (mut floors, mut far) = (0, 0);
    for case in 0..400 {
        let inst = random_instance(&mut rng, case % 5);
        let inst = scale_rows(&mut rng, &inst);
        let scale = 10f64.powf(rng.random_range(3.0..4.0));
        let w: Vec<f64> = inst.w.iter().map(|x| x * scale).collect();
        let p = ProjectionProblem {
            w: &w,
            jacobian: &inst.rows,
            b: &inst.b,
        };
        let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = ip.solve(&p, target, &mut sol).unwrap();
        let (mut sm, mut sn) = (vec![0.0; inst.b.len()], vec![0.0; w.len()]);
        let c = certify(&p, &sol.v, &sol.lambda, &mut sm, &mut sn);
        let floor = c.floor;
        if rep.status == SolveStatus::RoundingFloor {
            floors += 1;
            assert!(
                c.gap <= 1e2 * floor,
                "case {case}: {rep:?}, floor {floor:e}"
            );
        }
        if c.gap > 1e3 * floor {
            far += 1;
            // Not the floor: the chain asks its fallback (Clarabel at this size).
            let mut chain = moreau_solve::SolverKind::Interior
                .build(Parallelism::SEQUENTIAL, w.len())
                .unwrap();
            let rep = chain
                .solve(&p, target, &mut ProjectionSolution::default())
                .unwrap();
            assert_eq!(rep.solver, "clarabel", "case {case}: {rep:?}");
        }
    }
    // Both kinds of stop occur in this family (else the test proves nothing).
    assert!(floors > 0 && far > 0, "{floors} {far}");
}

/// Regression: the certificate summed `½|v − w|² + ½|Jᵀλ|² + λᵀ(b' + J w)`, four terms of
/// about `|w|²` that cancel, and clamped the rounding at 0: a push of 10⁸ stopped by a wall
/// was certified with gap 0 while the pair's exact gap was 1.66 (`λ_1 s_1 = 5·10⁷ ×
/// 1.5·10⁻⁸`). The projection of `w = (−10⁸, −5·10⁷)` on `v_0 ≥ 0, v_0 + v_1 ≥ 0` is
/// `v* = 0`: every kind's answer, through its fallbacks, is certified, and its distance to
/// `v*` within what the certificate claims (`|v − v*| ≤ √(2 gap)`, plus the violation's
/// share).
#[test]
fn a_gap_lost_to_cancellation_was_certified_as_zero() {
    let mut rows = ConstraintRows::new(2);
    rows.push(0, 0.0, [(0, 1.0)]);
    rows.push(1, 0.0, [(0, 1.0), (1, 1.0)]);
    let (w, b) = ([-1e8, -5e7], [0.0, 0.0]);
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let target = Target {
        gap: 1e-10,
        violation: 1e-9,
    };
    for kind in moreau_solve::SolverKind::ALL {
        let mut solver = kind.build(Parallelism::SEQUENTIAL, 2).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = solver.solve(&p, target, &mut sol).unwrap();
        // (The gap is that of the offsets relaxed by the violation, whose projection is
        // within 2 × the violation of `v*` here.)
        let distance = sol.v[0].hypot(sol.v[1]);
        let bound = (2.0 * rep.gap).sqrt() + 2.0 * rep.violation;
        assert!(
            rep.status.is_converged() && rep.gap <= target.gap && distance <= bound,
            "{kind:?}: {rep:?}, v = {:?}, |v − v*| = {distance:e} > {bound:e}",
            sol.v
        );
    }
}

/// Regression: a column repeated within a row (`2x ≥ 2` written as `x + x`, which the products
/// read as `2x`) made Gauss–Seidel's step twice too long (the row's norm was the sum of the
/// entries' squares): it oscillated for all its passes; Clarabel took the entries apart and
/// ended with NumericalError. Every kind alone answers `x = 1, λ = 0.5` (from `w = 0`), as
/// with the row written `2x`.
#[test]
fn a_column_repeated_in_a_row_broke_gauss_seidel_and_clarabel() {
    let mut rows = ConstraintRows::new(1);
    rows.push(0, 0.0, [(0, 1.0), (0, 1.0)]);
    let (w, b) = ([0.0], [-2.0]);
    let p = ProjectionProblem {
        w: &w,
        jacobian: &rows,
        b: &b,
    };
    let target = Target {
        gap: 1e-9, // (Clarabel stops near 10⁻¹⁰)
        violation: 1e-10,
    };
    for kind in moreau_solve::SolverKind::ALL {
        let mut solver = kind.build_alone(Parallelism::SEQUENTIAL).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = solver.solve(&p, target, &mut sol).unwrap();
        assert!(
            rep.status.is_converged()
                && (sol.v[0] - 1.0).abs() < 1e-6
                && (sol.lambda[0] - 0.5).abs() < 1e-6,
            "{kind:?}: {rep:?}, v = {:?}, λ = {:?}",
            sol.v,
            sol.lambda
        );
    }
}
