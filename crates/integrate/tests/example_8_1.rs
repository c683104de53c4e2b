//! `seeds/002` Example 8.1: `x' ∈ −a x + b − A(x)`, `C = [0, ∞)`, against its closed form.

#[path = "../../solve/tests/support/mod.rs"]
mod support;

use moreau_core::{BoxSet, FnField, HalfSpace, HalfSpaces};
use moreau_integrate::{
    Correction, EpsPolicy, ExactProjection, LinearizedProjection, LinearizedSettings, Scheme,
    StepSequence,
};
use moreau_solve::{Apgd, ApgdSettings};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The exact solution of §8.1 (iii)–(iv): the ODE `x' = −(a+1)x + b` in the interior; for
/// `b < 0` the trajectory reaches 0 at `t*` and stays there (the boundary is invariant).
fn exact(a: f64, b: f64, x0: f64, t: f64) -> f64 {
    let k = a + 1.0;
    let xs = b / k;
    if b < 0.0 {
        if x0 <= 0.0 {
            return 0.0;
        }
        let t_hit = ((x0 - xs) / -xs).ln() / k;
        if t >= t_hit {
            return 0.0;
        }
    }
    xs + (x0 - xs) * (-k * t).exp()
}

/// The largest error against the exact solution at the step times.
fn max_error<C: Correction>(
    a: f64,
    b: f64,
    x0: f64,
    steps: &StepSequence,
    correction: C,
    set: &mut C::Set<'_>,
) -> f64 {
    let field = FnField::new(1, move |_t, x: &[f64], out: &mut [f64]| {
        out[0] = -(a + 1.0) * x[0] + b
    });
    let mut scheme = Scheme::new(correction, EpsPolicy::new(1e-2, 3.0).unwrap());
    let mut x = [x0];
    let mut err: f64 = 0.0;
    scheme
        .run(&field, set, 0.0, &mut x, steps, |r, x| {
            assert!(
                x[0] >= -r.violation - 1e-15,
                "left C: x = {} at t = {}",
                x[0],
                r.t
            );
            assert!(
                r.eps <= r.eps_target,
                "certificate {} above target {}",
                r.eps,
                r.eps_target
            );
            err = err.max((x[0] - exact(a, b, x0, r.t)).abs());
        })
        .unwrap();
    err
}

fn half_line() -> HalfSpaces {
    HalfSpaces::new(vec![HalfSpace::new(vec![-1.0], 0.0).unwrap()]).unwrap()
}

fn linearized() -> LinearizedProjection<Apgd> {
    LinearizedProjection::new(
        Apgd::new(ApgdSettings::default()).unwrap(),
        LinearizedSettings::default(),
    )
    .unwrap()
}

const CASES: [(f64, f64, f64); 5] = [
    (1.0, -1.0, 1.0), // b < 0: reaches the boundary at t* ≈ 0.55 and stays
    (2.0, -3.0, 2.5), // b < 0, later impact
    (1.0, 2.0, 0.0),  // b > 0 from the boundary: leaves it at once
    (0.5, 1.0, 3.0),  // b > 0 from inside, decays to x* = b/(a+1)
    (3.0, 0.0, 1.0),  // b = 0: tends to the boundary without reaching it
];

#[test]
fn fixed_steps_converge_with_order_one_for_exact_and_solved_projections() {
    let hs: Vec<f64> = (0..6).map(|j| 0.1 / 2f64.powi(j)).collect();
    for (a, b, x0) in CASES {
        for solved in [false, true] {
            let errs: Vec<f64> = hs
                .iter()
                .map(|&h| {
                    let steps = StepSequence::Fixed { h, t_end: 3.0 };
                    if solved {
                        max_error(a, b, x0, &steps, linearized(), &mut half_line())
                    } else {
                        max_error(
                            a,
                            b,
                            x0,
                            &steps,
                            ExactProjection::new(),
                            &mut BoxSet::new(vec![0.0], vec![f64::INFINITY]).unwrap(),
                        )
                    }
                })
                .collect();
            let (order, r2) = support::fit_order(&hs, &errs);
            assert!(
                (0.9..=1.1).contains(&order),
                "(a, b, x0) = ({a}, {b}, {x0}), solved = {solved}: order {order}, errors {errs:?}"
            );
            assert!(r2 > 0.99, "order fit quality R² = {r2}");
        }
    }
}

#[test]
fn variable_steps_converge_with_order_one() {
    // Steps drawn in [h/4, h] (a fixed seed); the order is fitted against the largest step.
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for (a, b, x0) in CASES {
        let mut hmax = Vec::new();
        let mut errs = Vec::new();
        for j in 0..6 {
            let h = 0.1 / 2f64.powi(j);
            let mut steps = Vec::new();
            let mut t = 0.0;
            while t < 3.0 {
                let mu = rng.random_range(0.25 * h..=h).min(3.0 - t);
                steps.push(mu);
                t += mu;
            }
            let largest = steps.iter().cloned().fold(0.0, f64::max);
            hmax.push(largest);
            errs.push(max_error(
                a,
                b,
                x0,
                &StepSequence::Given(steps),
                linearized(),
                &mut half_line(),
            ));
        }
        let (order, _) = support::fit_order(&hmax, &errs);
        assert!(
            (0.9..=1.1).contains(&order),
            "(a, b, x0) = ({a}, {b}, {x0}): variable-step order {order}, errors {errs:?}"
        );
    }
}

#[test]
fn b_negative_makes_the_boundary_invariant() {
    // Once the scheme reaches 0 with b < 0, it stays exactly there.
    let field = FnField::new(1, |_t, x: &[f64], out: &mut [f64]| {
        out[0] = -2.0 * x[0] - 1.0
    });
    let mut scheme = Scheme::new(linearized(), EpsPolicy::default());
    let mut x = [1.0];
    let mut reached = None;
    scheme
        .run(
            &field,
            &mut half_line(),
            0.0,
            &mut x,
            &StepSequence::Fixed {
                h: 0.01,
                t_end: 3.0,
            },
            |r, x| {
                if reached.is_some() {
                    assert!(
                        x[0].abs() <= r.violation + 1e-12,
                        "left the boundary at t = {}: {}",
                        r.t,
                        x[0]
                    );
                } else if x[0].abs() <= 1e-12 {
                    reached = Some(r.t);
                }
            },
        )
        .unwrap();
    let t_hit = reached.expect("the boundary is reached");
    // t* = ln((x0 − x*)/(−x*))/(a + 1) with x* = b/(a + 1) = −1/2: ln 3 / 2.
    assert!((t_hit - 3f64.ln() / 2.0).abs() < 0.02, "reached at {t_hit}");
}
