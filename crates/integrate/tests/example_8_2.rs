//! `seeds/002` Example 8.2: `x' ∈ τ − K x − ∂ψ(x) − N_C(x)`, dry friction in a box.

use moreau_core::{BoxSet, FnField, SeparableAbs};
use moreau_integrate::{
    EpsPolicy, LinearizedProjection, LinearizedSettings, Scheme, Selection, StepSequence,
};
use moreau_solve::{Apgd, ApgdSettings};

const K: [[f64; 3]; 3] = [[2.0, 0.3, 0.0], [0.3, 1.0, 0.2], [0.0, 0.2, 1.5]];
const TAU: [f64; 3] = [5.0, 0.3, -1.2];
const MU: [f64; 3] = [0.5, 0.6, 0.4];
const LO: f64 = -1.0;
const HI: f64 = 1.0;
const X0: [f64; 3] = [0.0, 0.8, 0.5];

fn f(x: &[f64]) -> [f64; 3] {
    let mut r = TAU;
    for i in 0..3 {
        for j in 0..3 {
            r[i] -= K[i][j] * x[j];
        }
    }
    r
}

/// Runs to `t_end` with step `h`; returns the states at the step times.
fn run(selection: Selection, h: f64, t_end: f64) -> Vec<[f64; 3]> {
    let field = FnField::new(3, |_t, x: &[f64], out: &mut [f64]| {
        out.copy_from_slice(&f(x))
    });
    let mut boxset = BoxSet::new(vec![LO; 3], vec![HI; 3]).unwrap();
    let correction = LinearizedProjection::new(
        Apgd::new(ApgdSettings::default()).unwrap(),
        LinearizedSettings {
            max_violation: 1e-10,
            max_redo: 0,
        },
    )
    .unwrap();
    let mut scheme = Scheme::new(correction, EpsPolicy::new(1.0, 3.0).unwrap())
        .with_convex_part(Box::new(SeparableAbs::new(MU.to_vec()).unwrap()), selection);
    let mut x = X0;
    let mut out = vec![X0];
    scheme
        .run(
            &field,
            &mut boxset,
            0.0,
            &mut x,
            &StepSequence::Fixed { h, t_end },
            |r, x| {
                // Iterates stay in the box up to the certified violation.
                for &xi in x {
                    assert!(
                        xi >= LO - r.violation - 1e-15 && xi <= HI + r.violation + 1e-15,
                        "left the box: {x:?} (violation {})",
                        r.violation
                    );
                }
                assert!(r.eps <= r.eps_target);
                out.push([x[0], x[1], x[2]]);
            },
        )
        .unwrap();
    out
}

/// `dist(f(x), ∂_δψ(x) + N_C(x))` componentwise, where `|x_i| ≤ δ` counts as 0 and
/// `x_i` within `δ` of a bound counts as on it: the equilibrium residual of `0 ∈ F(x) − N_C(x)`.
fn equilibrium_residual(x: &[f64; 3], delta: f64) -> f64 {
    let r = f(x);
    let mut worst: f64 = 0.0;
    for i in 0..3 {
        // ∂ψ_i: an interval.
        let (mut lo, mut hi) = if x[i].abs() <= delta {
            (-MU[i], MU[i])
        } else {
            (MU[i] * x[i].signum(), MU[i] * x[i].signum())
        };
        // N_C: (−∞, 0] at the lower bound, [0, ∞) at the upper.
        if x[i] <= LO + delta {
            lo = f64::NEG_INFINITY;
        }
        if x[i] >= HI - delta {
            hi = f64::INFINITY;
        }
        worst = worst.max((lo - r[i]).max(r[i] - hi).max(0.0));
    }
    worst
}

#[test]
fn semi_implicit_reaches_the_equilibrium_exactly() {
    let traj = run(Selection::SemiImplicit, 0.01, 20.0);
    let x = traj.last().unwrap();
    // The equilibrium has one component on a bound, one stuck at 0, one interior and moving:
    // x1 = 1, x2 = 0, x3 = (τ3 + μ3)/K33 = −0.8/1.5.
    assert!(
        (x[0] - HI).abs() < 1e-9 && x[1].abs() < 1e-12 && (x[2] + 0.8 / 1.5).abs() < 1e-6,
        "{x:?}"
    );
    let res = equilibrium_residual(x, 1e-9);
    assert!(res < 1e-6, "residual {res}");
}

#[test]
fn explicit_selection_reaches_the_equilibrium_up_to_chattering_of_order_h() {
    for h in [0.01, 0.001] {
        let traj = run(Selection::Explicit, h, 20.0);
        let x = traj.last().unwrap();
        // The explicit selection chatters around x2 = 0 with amplitude ≤ h·(|f2| + μ2).
        let delta = h * 2.0;
        assert!(x[1].abs() <= delta, "h = {h}: x2 = {}", x[1]);
        let res = equilibrium_residual(x, delta);
        assert!(res < 10.0 * h, "h = {h}: residual {res}");
        // Without the δ-enlargement the residual is not small: the test can tell.
        if x[1] != 0.0 {
            assert!(equilibrium_residual(x, 0.0) > 0.1);
        }
    }
}

#[test]
fn explicit_and_semi_implicit_converge_to_the_same_trajectory() {
    let hs = [0.04, 0.02, 0.01, 0.005, 0.0025];
    let diffs: Vec<f64> = hs
        .iter()
        .map(|&h| {
            let a = run(Selection::Explicit, h, 5.0);
            let b = run(Selection::SemiImplicit, h, 5.0);
            a.iter()
                .zip(&b)
                .map(|(x, y)| (0..3).map(|i| (x[i] - y[i]).abs()).fold(0.0, f64::max))
                .fold(0.0, f64::max)
        })
        .collect();
    for w in diffs.windows(2) {
        assert!(
            w[1] < 0.75 * w[0],
            "distance does not shrink with h: {diffs:?}"
        );
    }
    assert!(diffs[4] < 0.02, "{diffs:?}");
}
