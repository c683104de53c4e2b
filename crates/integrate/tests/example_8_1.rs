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

/// The iterates `(t_k, x_k)` of a fixed-step run, with the certified `√ε_k` of each step.
fn iterates(a: f64, b: f64, x0: f64, h: f64, t_end: f64) -> Vec<(f64, f64, f64)> {
    let field = FnField::new(1, move |_t, x: &[f64], out: &mut [f64]| {
        out[0] = -(a + 1.0) * x[0] + b
    });
    let mut scheme = Scheme::new(linearized(), EpsPolicy::new(1e-2, 3.0).unwrap());
    let mut x = [x0];
    let mut out = vec![(0.0, x0, 0.0)];
    scheme
        .run(
            &field,
            &mut half_line(),
            0.0,
            &mut x,
            &StepSequence::Fixed { h, t_end },
            |r, x| out.push((r.t, x[0], r.eps.sqrt())),
        )
        .unwrap();
    out
}

/// §8.1 (iii): `x(t)² ≤ e^{−(a+1)t} x0² + b²/(a+1)² (1 − e^{−(a+1)t})` (31) and its corollary
/// `x(t)² ≤ max{x0², b²/(a+1)²}` (32). The iterates keep (32) up to the certified projection
/// errors (for `(a+1)h ≤ 1` the prediction is a convex combination of `x_k` and `b/(a+1)`, and
/// projecting onto `C ∋ 0` does not lengthen it), and approach (31) as `h → 0`: its largest
/// excess over the step times falls at least like `h`.
#[test]
fn the_iterates_keep_the_energy_bounds_31_and_32() {
    for (a, b, x0) in CASES {
        let k = a + 1.0;
        let bound_31 = |t: f64| (-k * t).exp() * x0 * x0 + (b / k).powi(2) * (1.0 - (-k * t).exp());
        let bound_32 = x0.abs().max(b.abs() / k);
        let mut excess = Vec::new();
        let hs: Vec<f64> = (0..5).map(|j| 0.1 / 2f64.powi(j)).collect();
        for &h in &hs {
            let run = iterates(a, b, x0, h, 4.0);
            let mut slack = 0.0;
            let mut worst: f64 = 0.0;
            for &(t, x, sqrt_eps) in &run {
                slack += sqrt_eps;
                assert!(
                    x.abs() <= bound_32 + slack + 1e-12,
                    "(32) at t = {t}, h = {h}: |x| = {x} > {bound_32} + {slack}"
                );
                worst = worst.max(x * x - bound_31(t));
            }
            excess.push(worst.max(0.0));
        }
        // (31): the excess vanishes with h (order ≥ 1, or is zero already).
        for w in excess.windows(2) {
            assert!(
                w[1] <= 0.6 * w[0] + 1e-12,
                "(a, b, x0) = ({a}, {b}, {x0}): excess over (31) {excess:?}"
            );
        }
        assert!(
            excess[4] <= 0.05 * x0.max(b.abs() / k).max(1e-3).powi(2),
            "{excess:?}"
        );
    }
}

/// §8.1 (vii): the dynamics contracts, `|x1(t) − x2(t)| ≤ e^{−(a+1)t} |x1(0) − x2(0)|`; the
/// scheme's iterates from two starting points do too (the prediction scales differences by
/// `1 − (a+1)h ≤ e^{−(a+1)h}`, the projection does not lengthen them), up to the certified
/// projection errors of both runs.
#[test]
fn iterates_from_two_starts_contract_like_the_dynamics() {
    for (a, b, x0) in CASES {
        let k = a + 1.0;
        let other = x0 + 1.5;
        for h in [0.1, 0.02] {
            let (r1, r2) = (iterates(a, b, x0, h, 3.0), iterates(a, b, other, h, 3.0));
            let mut slack = 0.0;
            for (&(t, x1, e1), &(_, x2, e2)) in r1.iter().zip(&r2) {
                slack += e1 + e2;
                let bound = (-k * t).exp() * (other - x0) + slack + 1e-12;
                assert!(
                    (x1 - x2).abs() <= bound,
                    "(a, b) = ({a}, {b}), h = {h}, t = {t}: |Δx| = {} > {bound}",
                    (x1 - x2).abs()
                );
            }
        }
    }
}

#[test]
fn a_step_of_1e300_over_a_span_of_1_took_no_step() {
    // `fixed_step` takes what is left below a billionth of the step for rounding: with
    // h = 1e300 that was the whole span, and the run ended at t0 with x unchanged.
    let (a, b, x0) = (1.0, 2.0, 3.0);
    let field = FnField::new(1, move |_t, x: &[f64], out: &mut [f64]| {
        out[0] = -(a + 1.0) * x[0] + b
    });
    let mut scheme = Scheme::new(ExactProjection::new(), EpsPolicy::new(1e-2, 3.0).unwrap());
    let mut set = BoxSet::new(vec![0.0], vec![f64::INFINITY]).unwrap();
    let mut x = [x0];
    let mut steps = Vec::new();
    let t = scheme
        .run(
            &field,
            &mut set,
            0.5,
            &mut x,
            &StepSequence::Fixed {
                h: 1e300,
                t_end: 1.5,
            },
            |r, _| steps.push(r.mu),
        )
        .unwrap();
    assert_eq!((t, steps), (1.5, vec![1.0]));
    // One explicit step of the span: x0 + 1.0 · (−(a + 1) x0 + b) = 3 − 4 = −1, projected on C.
    assert_eq!(x, [0.0]);
}

#[test]
fn a_box_with_an_infinite_bound_could_not_be_linearized() {
    // `BoxSet`'s upper bound ∞, under the default infinite margin, pushed a row of value ∞,
    // which every solver refuses: a box on the half-line ran only with the exact projection.
    // It is the half-space x ≥ 0, and runs as it does.
    for (a, b, x0) in CASES {
        let steps = StepSequence::Fixed {
            h: 0.01,
            t_end: 3.0,
        };
        let boxed = max_error(
            a,
            b,
            x0,
            &steps,
            linearized(),
            &mut BoxSet::new(vec![0.0], vec![f64::INFINITY]).unwrap(),
        );
        let half = max_error(a, b, x0, &steps, linearized(), &mut half_line());
        assert_eq!(boxed, half, "(a, b, x0) = ({a}, {b}, {x0})");
        assert!(boxed < 0.05, "{boxed}");
    }
}

#[test]
fn steps_below_the_times_resolution_never_advanced_it() {
    // From t0 = 1.7e9 (a Unix time) with h = 1e-7, t + h rounded back to t: the run stepped
    // forever at the same time. Now refused by name; steps the time resolves still run.
    let field = FnField::new(1, |_t, x: &[f64], out: &mut [f64]| out[0] = -x[0]);
    let mut scheme = Scheme::new(ExactProjection::new(), EpsPolicy::new(1e-2, 3.0).unwrap());
    let mut set = BoxSet::new(vec![0.0], vec![f64::INFINITY]).unwrap();
    let t0 = 1.7e9;
    let mut x = [1.0];
    let e = scheme
        .run(
            &field,
            &mut set,
            t0,
            &mut x,
            &StepSequence::Fixed {
                h: 1e-7,
                t_end: t0 + 1e-5,
            },
            |_, _| {},
        )
        .unwrap_err();
    assert!(e.to_string().contains("invalid setting h = 1e-7"), "{e}");
    // A NaN start was blamed on t_end ("t_end = 1: must be finite and ≥ t0").
    let e = scheme
        .run(
            &field,
            &mut set,
            f64::NAN,
            &mut x,
            &StepSequence::Fixed { h: 0.1, t_end: 1.0 },
            |_, _| {},
        )
        .unwrap_err();
    assert!(e.to_string().contains("invalid setting t0 = NaN"), "{e}");
    let mut steps = 0;
    scheme
        .run(
            &field,
            &mut set,
            t0,
            &mut x,
            &StepSequence::Fixed {
                h: 1e-3,
                t_end: t0 + 0.01,
            },
            |_, _| steps += 1,
        )
        .unwrap();
    assert!((10..=11).contains(&steps), "{steps}");
}
