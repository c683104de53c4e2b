//! `seeds/003` Theorem 2: for monotone `f` and polyhedral `C`, catching-up, the projected
//! system (PDS) and the complementarity system (CDS) have the same solution and multipliers.
//!
//! Catching-up runs through the library (APGD on the projection in velocity form); the CDS is
//! solved as what it is, a linear complementarity problem in the multipliers, by Lemke's
//! complementary pivoting written here (no projection and no library solver on that path);
//! PDS steps are built from the independent exact enumerator of `support`.

#[path = "../../solve/tests/support/mod.rs"]
mod support;

use moreau_core::{FnField, HalfSpace, HalfSpaces};
use moreau_integrate::{EpsPolicy, LinearizedProjection, LinearizedSettings, Scheme, fixed_step};
use moreau_solve::{Apgd, ApgdSettings};

/// `f(x) = M x + c`, monotone: the symmetric part of `M` is diag(1, 0.5).
const M: [[f64; 2]; 2] = [[1.0, 2.0], [-2.0, 0.5]];
const C: [f64; 2] = [-3.1, 2.6];
/// `C = {x : H x ≤ d}`.
const H: [[f64; 2]; 3] = [[1.0, 0.0], [1.0, 1.0], [0.0, -1.0]];
const D: [f64; 3] = [1.0, 1.5, 0.5];
const X0: [f64; 2] = [-1.0, 0.0];
const T_END: f64 = 4.0;

fn f(x: &[f64]) -> [f64; 2] {
    [
        M[0][0] * x[0] + M[0][1] * x[1] + C[0],
        M[1][0] * x[0] + M[1][1] * x[1] + C[1],
    ]
}

struct Trajectory {
    x: Vec<[f64; 2]>,
    lambda: Vec<[f64; 3]>,
}

fn catching_up(h: f64) -> Trajectory {
    let field = FnField::new(2, |_t, x: &[f64], out: &mut [f64]| {
        let fx = f(x);
        out[0] = -fx[0];
        out[1] = -fx[1];
    });
    let faces = H
        .iter()
        .zip(D)
        .map(|(a, d)| HalfSpace::new(a.to_vec(), d).unwrap())
        .collect();
    let mut set = HalfSpaces::new(faces).unwrap();
    let correction = LinearizedProjection::new(
        Apgd::new(ApgdSettings::default()).unwrap(),
        LinearizedSettings {
            max_violation: 1e-12,
            max_redo: 0,
        },
    )
    .unwrap();
    let mut scheme = Scheme::new(correction, EpsPolicy::new(1e-6, 3.0).unwrap());
    let mut x = X0;
    let mut traj = Trajectory {
        x: vec![X0],
        lambda: Vec::new(),
    };
    let (mut k, mut t) = (0, 0.0);
    while let Some(mu) = fixed_step(h, T_END - t) {
        scheme.step(&field, &mut set, k, t, &mut x, mu).unwrap();
        (k, t) = (k + 1, t + mu);
        // The rows are all three faces (margin ∞), keyed by face index, in order.
        let corr = scheme.correction();
        assert_eq!(corr.rows().keys(), &[0, 1, 2]);
        let l = corr.multipliers();
        traj.x.push(x);
        traj.lambda.push([l[0], l[1], l[2]]);
    }
    traj
}

/// Rows of `J` for `g = d − H x ≥ 0` are `−H`.
fn minus_h() -> Vec<Vec<f64>> {
    H.iter().map(|r| r.iter().map(|a| -a).collect()).collect()
}

/// Lemke's complementary pivoting for `LCP(q, M)`: `w = q + M z ≥ 0`, `z ≥ 0`, `wᵀz = 0`,
/// covering vector `e`, ties broken towards the artificial variable, then by row. `None` on
/// ray termination. (It terminates for the positive semidefinite `M` here.)
fn lemke(m: &[Vec<f64>], q: &[f64]) -> Option<Vec<f64>> {
    let n = q.len();
    if q.iter().all(|&v| v >= 0.0) {
        return Some(vec![0.0; n]);
    }
    // Columns: w_0..w_{n−1}, z_0..z_{n−1}, z0 (artificial); then the right-hand side.
    let (z0, rhs) = (2 * n, 2 * n + 1);
    let mut t: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let mut row = vec![0.0; 2 * n + 2];
            row[i] = 1.0;
            for j in 0..n {
                row[n + j] = -m[i][j];
            }
            row[z0] = -1.0;
            row[rhs] = q[i];
            row
        })
        .collect();
    let mut basis: Vec<usize> = (0..n).collect();
    let pivot = |t: &mut Vec<Vec<f64>>, r: usize, c: usize| {
        let p = t[r][c];
        t[r].iter_mut().for_each(|x| *x /= p);
        let pr = t[r].clone();
        for (i, row) in t.iter_mut().enumerate() {
            if i != r && row[c] != 0.0 {
                let f = row[c];
                row.iter_mut().zip(&pr).for_each(|(x, y)| *x -= f * y);
            }
        }
    };
    let r0 = (0..n).min_by(|&a, &b| q[a].total_cmp(&q[b])).unwrap();
    pivot(&mut t, r0, z0);
    let mut leaving = basis[r0];
    basis[r0] = z0;
    for _ in 0..100 {
        let entering = if leaving < n {
            leaving + n
        } else {
            leaving - n
        };
        let mut best: Option<(usize, f64)> = None;
        for i in 0..n {
            if t[i][entering] > 1e-12 {
                let ratio = t[i][rhs] / t[i][entering];
                let better = match best {
                    None => true,
                    Some((b, r)) => {
                        ratio < r - 1e-12
                            || (ratio <= r + 1e-12 && basis[i] == z0 && basis[b] != z0)
                    }
                };
                if better {
                    best = Some((i, ratio));
                }
            }
        }
        let (r, _) = best?;
        pivot(&mut t, r, entering);
        leaving = basis[r];
        basis[r] = entering;
        if leaving == z0 {
            let mut z = vec![0.0; n];
            for (i, &b) in basis.iter().enumerate() {
                if (n..2 * n).contains(&b) {
                    z[b - n] = t[i][rhs];
                }
            }
            return Some(z);
        }
    }
    None
}

/// CDS, time-discretized: `x_{k+1} = x_k − h(f(x_k) + Hᵀλ)` with the LCP
/// `0 ≤ λ ⟂ d − H x_{k+1} = q + M λ ≥ 0`, `M = h H Hᵀ`, `q = d − H(x_k − h f(x_k))`, solved by
/// Lemke's method.
fn cds(h: f64) -> Trajectory {
    let mut x = X0;
    let mut traj = Trajectory {
        x: vec![X0],
        lambda: Vec::new(),
    };
    let m: Vec<Vec<f64>> = (0..3)
        .map(|i| {
            (0..3)
                .map(|j| h * (H[i][0] * H[j][0] + H[i][1] * H[j][1]))
                .collect()
        })
        .collect();
    let n = (T_END / h).round() as usize;
    for _ in 0..n {
        let fx = f(&x);
        let free = [x[0] - h * fx[0], x[1] - h * fx[1]];
        let q: Vec<f64> = (0..3)
            .map(|i| D[i] - H[i][0] * free[0] - H[i][1] * free[1])
            .collect();
        let l = lemke(&m, &q).expect("the CDS step's LCP has a solution");
        let xn = [
            free[0] - h * (H[0][0] * l[0] + H[1][0] * l[1] + H[2][0] * l[2]),
            free[1] - h * (H[0][1] * l[0] + H[1][1] * l[1] + H[2][1] * l[2]),
        ];
        // The LCP's conditions, checked on the new state.
        for i in 0..3 {
            let slack = D[i] - H[i][0] * xn[0] - H[i][1] * xn[1];
            assert!(l[i] >= -1e-12 && slack >= -1e-9 && (l[i] * slack).abs() < 1e-9);
        }
        x = xn;
        traj.x.push(x);
        traj.lambda.push([l[0], l[1], l[2]]);
    }
    traj
}

/// PDS: `x_{k+1} = proj_C(x_k + h proj_{T_C(x_k)}(−f(x_k)))`, with `T_C(x) = {d : H_A d ≤ 0}`
/// over the faces active at `x_k`; its multiplier is that of the tangent-cone projection.
fn pds(h: f64) -> Trajectory {
    let mut x = X0;
    let mut traj = Trajectory {
        x: vec![X0],
        lambda: Vec::new(),
    };
    let n = (T_END / h).round() as usize;
    for _ in 0..n {
        let fx = f(&x);
        let active: Vec<usize> = (0..3)
            .filter(|&i| D[i] - H[i][0] * x[0] - H[i][1] * x[1] <= 1e-9)
            .collect();
        let jt: Vec<Vec<f64>> = active.iter().map(|&i| vec![-H[i][0], -H[i][1]]).collect();
        let (d, la) = support::exact_qp(&[-fx[0], -fx[1]], &jt, &vec![0.0; active.len()]);
        let mut lambda = [0.0; 3];
        for (k, &i) in active.iter().enumerate() {
            lambda[i] = la[k];
        }
        let y = [x[0] + h * d[0], x[1] + h * d[1]];
        // proj_C(y): the QP with w = y in position form (b = d − 0, J = −H).
        let (p, _) = support::exact_qp(&y, &minus_h(), &D);
        x = [p[0], p[1]];
        traj.x.push(x);
        traj.lambda.push(lambda);
    }
    traj
}

fn max_distance(a: &Trajectory, b: &Trajectory) -> f64 {
    a.x.iter()
        .zip(&b.x)
        .map(|(p, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt())
        .fold(0.0, f64::max)
}

/// `∫ |λ_a − λ_b| dt` over the run.
fn multiplier_distance(a: &Trajectory, b: &Trajectory, h: f64) -> f64 {
    a.lambda
        .iter()
        .zip(&b.lambda)
        .map(|(p, q)| h * (0..3).map(|i| (p[i] - q[i]).abs()).sum::<f64>())
        .sum()
}

#[test]
fn the_trajectory_reaches_and_slides_on_faces() {
    // The test is only meaningful if constraints are active: check the reference does.
    let t = cds(0.01);
    let active_steps = t
        .lambda
        .iter()
        .filter(|l| l.iter().any(|&v| v > 1e-6))
        .count();
    assert!(active_steps > 50, "only {active_steps} steps with contact");
    let faces: Vec<usize> = (0..3)
        .filter(|&i| t.lambda.iter().any(|l| l[i] > 1e-6))
        .collect();
    assert!(faces.len() >= 2, "only faces {faces:?} are ever active");
}

#[test]
fn catching_up_and_cds_agree_in_states_and_multipliers() {
    // For a polyhedron the linearized set is the set itself, so a catching-up step (a
    // projection in velocity, by APGD) and a CDS step (an LCP in the multipliers, by Lemke's
    // pivoting) are the same step stated twice: two formulations, two algorithms, and they
    // must agree to solver accuracy at every h.
    for h in [0.05, 0.01] {
        let (a, b) = (catching_up(h), cds(h));
        assert!(
            max_distance(&a, &b) < 1e-6,
            "h = {h}: {}",
            max_distance(&a, &b)
        );
        let worst = a
            .lambda
            .iter()
            .zip(&b.lambda)
            .map(|(p, q)| (0..3).map(|i| (p[i] - q[i]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
        assert!(worst < 1e-4, "h = {h}: multipliers differ by {worst}");
    }
}

#[test]
fn pds_and_catching_up_converge_to_each_other_as_h_shrinks() {
    let hs = [0.04, 0.02, 0.01, 0.005, 0.0025];
    let mut dx = Vec::new();
    let mut dl = Vec::new();
    for &h in &hs {
        let (a, p) = (catching_up(h), pds(h));
        dx.push(max_distance(&a, &p));
        dl.push(multiplier_distance(&a, &p, h));
    }
    let (ox, _) = support::fit_order(&hs, &dx);
    let (ol, _) = support::fit_order(&hs, &dl);
    assert!(
        ox > 0.8,
        "state distance does not shrink like h: order {ox}, {dx:?}"
    );
    assert!(
        ol > 0.8,
        "multiplier distance does not shrink like h: order {ol}, {dl:?}"
    );
    assert!(dx[4] < 0.01 && dl[4] < 0.05, "{dx:?} {dl:?}");
}
