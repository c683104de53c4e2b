//! The adaptive step controller on Example 8.1 of `seeds/002` (closed form, a contact event at
//! `t*` where the velocity jumps): errors follow the tolerance, steps shrink at the event and
//! grow after it, the `ε_k` policy follows the step, and it costs fewer steps than fixed steps
//! at the same error; and on a sweeping process driven by its moving set alone.

use moreau_core::{FnField, HalfSpace, SolveStatus, StepReport};
use moreau_integrate::{
    AdaptiveSettings, Correction, EpsPolicy, ErrorEstimate, ExactProjection, IntegrateError,
    Scheme, StepController, StepSequence, Stepping, Unconstrained,
};

const A: f64 = 1.0;
const B: f64 = -1.0;
const X0: f64 = 1.0;
const T: f64 = 3.0;

fn exact(t: f64) -> f64 {
    let k = A + 1.0;
    let xs = B / k;
    let t_hit = ((X0 - xs) / -xs).ln() / k;
    if t >= t_hit {
        0.0
    } else {
        xs + (X0 - xs) * (-k * t).exp()
    }
}

fn t_hit() -> f64 {
    let k = A + 1.0;
    ((X0 + 1.0 / k) / (1.0 / k)).ln() / k
}

type Example = Scheme<ExactProjection<HalfSpace>>;
type ExampleField = FnField<fn(f64, &[f64], &mut [f64])>;

fn f(_t: f64, x: &[f64], out: &mut [f64]) {
    out[0] = -(A + 1.0) * x[0] + B;
}

/// The field, the set and the scheme.
fn scheme() -> (ExampleField, HalfSpace, Example) {
    let half_line = HalfSpace::new(vec![-1.0], 0.0).unwrap();
    (
        FnField::new(1, f as fn(f64, &[f64], &mut [f64])),
        half_line,
        Scheme::new(ExactProjection::new(), Default::default()),
    )
}

/// Runs adaptively to T: (max error at the step times, accepted steps, rejected, steps (t, μ)).
fn adaptive(settings: AdaptiveSettings) -> (f64, usize, usize, Vec<(f64, f64)>) {
    let (field, mut set, mut s) = scheme();
    let mut c = StepController::new(settings).unwrap();
    let (mut t, mut x, mut err, mut steps) = (0.0, [X0], 0.0f64, Vec::new());
    let mut k = 0;
    while t < T {
        let step = c.step(&mut s, &field, &mut set, k, t, &mut x, T).unwrap();
        let r = &step.report;
        assert!(
            (r.eps_target
                - settings.eps_policy().eps(
                    r.mu / if settings.estimate == ErrorEstimate::StepDoubling {
                        2.0
                    } else {
                        1.0
                    }
                ))
            .abs()
                <= 1e-15 * r.eps_target.max(1e-300)
        );
        t = r.t;
        k += 1;
        assert!(x[0] >= 0.0, "left C at t = {t}");
        err = err.max((x[0] - exact(t)).abs());
        steps.push((t, r.mu));
    }
    assert_eq!(t, T, "the run lands on T exactly");
    (err, c.accepted, c.rejected, steps)
}

fn fixed(h: f64) -> (f64, usize) {
    let (field, mut set, mut s) = scheme();
    let mut x = [X0];
    let (mut err, mut n) = (0.0f64, 0);
    s.run(
        &field,
        &mut set,
        0.0,
        &mut x,
        &StepSequence::Fixed { h, t_end: T },
        |r, x| {
            err = err.max((x[0] - exact(r.t)).abs());
            n += 1;
        },
    )
    .unwrap();
    (err, n)
}

/// With the error bounded per step, smooth stretches take steps `μ ~ √(tol/C)` and the global
/// error of a first-order scheme is `~ (T/μ) C μ² ~ √tol`: the observed slope of log error
/// against log tol is 1/2, and errors shrink with every tolerance.
#[test]
fn errors_follow_the_tolerance() {
    for estimate in [ErrorEstimate::StepDoubling, ErrorEstimate::VelocityChange] {
        let mut points = Vec::new();
        for tol in [1e-3, 1e-4, 1e-5, 1e-6, 1e-7] {
            let mut settings = AdaptiveSettings::new(tol);
            settings.estimate = estimate;
            let (err, accepted, rejected, _) = adaptive(settings);
            eprintln!(
                "{estimate:?} tol {tol:e}: error {err:.3e}, {accepted} steps, {rejected} rejected"
            );
            if let Some(&(_, last)) = points.last() {
                assert!(
                    err < last,
                    "{estimate:?}: error did not shrink at tol {tol}"
                );
            }
            points.push((tol, err));
        }
        let n = points.len() as f64;
        let (lx, ly): (Vec<f64>, Vec<f64>) = points.iter().map(|(t, e)| (t.ln(), e.ln())).unzip();
        let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
        let slope = lx
            .iter()
            .zip(&ly)
            .map(|(x, y)| (x - mx) * (y - my))
            .sum::<f64>()
            / lx.iter().map(|x| (x - mx).powi(2)).sum::<f64>();
        assert!(
            (slope - 0.5).abs() <= 0.1,
            "{estimate:?}: error ~ tol^{slope}"
        );
    }
}

#[test]
fn steps_shrink_at_the_contact_and_grow_after_it() {
    let (_, _, _, steps) = adaptive(AdaptiveSettings::new(1e-5));
    let th = t_hit();
    let near = steps
        .iter()
        .filter(|(t, _)| (t - th).abs() < 0.05)
        .map(|s| s.1)
        .fold(f64::INFINITY, f64::min);
    let after = steps
        .iter()
        .filter(|(t, _)| *t > th + 0.5)
        .map(|s| s.1)
        .fold(0.0, f64::max);
    assert!(
        after >= 0.5 * AdaptiveSettings::new(1e-5).mu_max,
        "largest step after the contact {after}"
    );
    assert!(
        near * 20.0 < after,
        "step at the contact {near} vs after {after}"
    );
}

#[test]
fn adaptive_steps_cost_less_than_fixed_steps_at_the_same_error() {
    let (err, accepted, rejected, _) = adaptive(AdaptiveSettings::new(1e-5));
    // The largest fixed step whose error is no larger: halve until it is.
    let mut h = 0.1;
    let (mut e, mut n) = fixed(h);
    while e > err {
        h /= 2.0;
        (e, n) = fixed(h);
    }
    // Step doubling: three projections per trial.
    let adaptive_cost = 3 * (accepted + rejected);
    eprintln!(
        "adaptive: error {err:.3e} for {adaptive_cost} projections; fixed h = {h}: error {e:.3e} for {n}"
    );
    assert!(
        2 * adaptive_cost <= n,
        "adaptive {adaptive_cost} vs fixed {n}"
    );
}

#[test]
fn bad_settings_name_the_field() {
    let mut s = AdaptiveSettings::new(f64::NAN);
    assert!(matches!(
        StepController::new(s),
        Err(IntegrateError::InvalidSetting { field: "tol", .. })
    ));
    s.tol = 1e-3;
    s.mu_first = 10.0;
    assert!(matches!(
        StepController::new(s),
        Err(IntegrateError::InvalidSetting {
            field: "mu_first",
            ..
        })
    ));
    s.mu_first = 0.01;
    s.shrink = 1.5;
    assert!(matches!(
        StepController::new(s),
        Err(IntegrateError::InvalidSetting {
            field: "shrink",
            ..
        })
    ));
    s.shrink = 0.2;
    for floor in [0.0, -1e-7, f64::NAN, f64::INFINITY] {
        s.eps_floor = floor;
        assert!(matches!(
            StepController::new(s),
            Err(IntegrateError::InvalidSetting {
                field: "eps_floor",
                ..
            })
        ));
    }
}

/// The floor of `ε/μ²` is the settings' own (a solver that certifies less far down gets a
/// higher one): where the tolerance's term falls below it, `ε = floor μ²`.
#[test]
fn the_eps_floor_is_the_settings_own() {
    let mut settings = AdaptiveSettings::new(0.01);
    assert_eq!(settings.eps_floor, EpsPolicy::ADAPTIVE_FLOOR);
    settings.eps_floor = 2e-6;
    let policy = settings.eps_policy();
    let budget = settings.theta * settings.tol;
    for mu in [0.5, 0.1, 1e-2, 1e-3, 1e-6] {
        let tolerance = budget * budget * (mu / settings.mu_max).powi(3);
        let expected = tolerance.max(2e-6 * mu * mu);
        assert!(
            (policy.eps(mu) / expected - 1.0).abs() < 1e-12,
            "μ = {mu}: {} against {expected}",
            policy.eps(mu)
        );
    }
    // At μ = 10⁻³ the tolerance asks 8·10⁻¹⁵, the default floor 2·10⁻¹³, this one 2·10⁻¹².
    assert!(policy.eps(1e-3) > 5.0 * AdaptiveSettings::new(0.01).eps_policy().eps(1e-3));
}

/// seeds/002 (Definition 4.3) asks `ε_k/μ_k² → 0` of the steps a run takes: with adaptive steps the tolerance
/// fixes the budget, and `ε/μ²` must still fall as `μ` falls (the power-1 policy used before
/// made it grow: 10 at `μ = 10⁻⁶`, tol = 0.01), down to the floor double precision certifies.
#[test]
fn adaptive_eps_over_mu_squared_vanishes_as_the_steps_shrink() {
    let settings = AdaptiveSettings::new(0.01);
    let policy = settings.eps_policy();
    assert!(
        EpsPolicy::new(policy.kappa, policy.power).is_ok(),
        "the adaptive policy passes the fixed-step check (p > 2): {policy:?}"
    );
    let budget = settings.theta * settings.tol;
    let mut mu = settings.mu_max;
    let mut last = f64::INFINITY;
    while mu >= settings.mu_min {
        let eps = policy.eps(mu);
        assert!(
            eps.sqrt() <= budget * (1.0 + 1e-12),
            "√ε within the budget at μ = {mu}"
        );
        let ratio = eps / (mu * mu);
        assert!(
            ratio < last || ratio <= EpsPolicy::ADAPTIVE_FLOOR * (1.0 + 1e-12),
            "ε/μ² = {ratio:e} at μ = {mu:e} did not fall"
        );
        last = ratio;
        mu /= 10.0;
    }
    // Five decades below μ_max it is at the floor, 2·10⁻⁷: a duality gap of 10⁻⁷ (m/s)².
    assert!(
        (last / EpsPolicy::ADAPTIVE_FLOOR - 1.0).abs() < 1e-12,
        "{last:e}"
    );
    assert!(policy.eps(settings.mu_max) / settings.mu_max.powi(2) > 10.0 * last);
}

/// A projection whose certificates stop at `reach · μ²` (a solver that stalls above the
/// floor) at steps larger than `easy`, and certify anything at smaller ones; it counts its
/// calls. Nothing to project onto: `q + μ w`.
struct Stalling {
    reach: f64,
    easy: f64,
    calls: usize,
}

impl Correction for Stalling {
    type Set<'a> = ();

    fn correct(
        &mut self,
        _set: &mut (),
        q: &[f64],
        w: &[f64],
        eps_target: f64,
        q_next: &mut [f64],
        report: &mut StepReport,
    ) -> Result<(), IntegrateError> {
        self.calls += 1;
        Unconstrained.correct(&mut (), q, w, eps_target, q_next, report)?;
        let mu = report.mu;
        let eps = self.reach * mu * mu;
        if mu > self.easy && eps > eps_target {
            return Err(IntegrateError::NotCertified {
                step: report.step,
                t: report.t,
                status: SolveStatus::MaxIterations,
                eps,
                eps_target,
                violation: 0.0,
                max_violation: 0.0,
            });
        }
        report.eps = eps.min(eps_target);
        report.eps_target = eps_target;
        report.solver = "stalling";
        Ok(())
    }
}

/// One adaptive step from x = 1 with a first trial of `mu_first`, on a projection that
/// stalls at `reach μ²` above `easy`: the step, and how many trials the projection saw.
fn stalling_step(mu_first: f64, reach: f64, easy: f64) -> (Result<f64, IntegrateError>, usize) {
    let mut settings = AdaptiveSettings::new(0.01);
    settings.estimate = ErrorEstimate::VelocityChange;
    settings.mu_first = mu_first;
    let field: ExampleField = FnField::new(1, f as fn(f64, &[f64], &mut [f64]));
    let mut scheme = Scheme::new(
        Stalling {
            reach,
            easy,
            calls: 0,
        },
        Default::default(),
    );
    let mut c = StepController::new(settings).unwrap();
    let mut x = [X0];
    let step = c.step(&mut scheme, &field, &mut (), 0, 0.0, &mut x, T);
    let calls = scheme.correction().calls;
    (step.map(|s| s.report.mu), calls)
}

/// At the floor of `ε/μ²` a smaller step asks the same relative accuracy: a projection that
/// stalls above the floor ends the step after three trials (μ, μ/2, μ/4) with its error,
/// instead of halving on to `mu_min` (fifteen trials from here) first.
#[test]
fn a_solver_that_stalls_above_the_floor_ends_the_step_at_once() {
    let policy = AdaptiveSettings::new(0.01).eps_policy();
    // The largest step at the floor: floor μ² = κ μ³.
    let floor_mu = policy.floor / policy.kappa;
    let mu = floor_mu / 2.0;
    assert!(policy.at_floor(mu) && !policy.at_floor(2.0 * floor_mu));
    let (step, calls) = stalling_step(mu, 10.0 * policy.floor, 0.0);
    assert!(
        matches!(step, Err(IntegrateError::NotCertified { .. })),
        "{step:?}"
    );
    assert_eq!(calls, StepController::UNCERTIFIED_AT_FLOOR);
    // A step that a smaller one does let the solver certify is still halved until it can.
    let (step, calls) = stalling_step(mu, 10.0 * policy.floor, mu / 3.0);
    assert_eq!(step.unwrap(), mu / 4.0);
    assert_eq!(calls, 3);
    // Above the floor (ε/μ² still falls as μ does) the trials go on past three.
    let mu = 16.0 * floor_mu;
    assert!(mu <= AdaptiveSettings::new(0.01).mu_max && !policy.at_floor(mu / 8.0));
    let (step, calls) = stalling_step(mu, 1e9, mu / 10.0);
    assert_eq!(step.unwrap(), mu / 16.0);
    assert_eq!(calls, 5);
}

/// Evaluations of `counted_f` (a step that never ended showed as a count without end).
static EVALUATIONS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

fn counted_f(t: f64, x: &[f64], out: &mut [f64]) {
    let n = EVALUATIONS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    assert!(
        n < 10_000,
        "the field was evaluated {n} times for a few steps"
    );
    f(t, x, out);
}

#[test]
fn a_step_at_the_floor_lengthened_to_land_was_tried_again_forever() {
    // With a tolerance no step meets, steps fall to `mu_min`; a floor step that landing
    // lengthened to what was left (1.3 mu_min, instead of leaving a sliver of 0.3) was neither
    // the floor nor below it, so it was rejected and the same trial came back: `moreau run
    // --tol 1e-300` hung at the first frame, deaf to SIGTERM (checked between steps).
    let mut settings = AdaptiveSettings::new(1e-300);
    settings.estimate = ErrorEstimate::VelocityChange;
    settings.mu_first = settings.mu_min;
    let t_end = 2.3 * settings.mu_min;
    let field: ExampleField = FnField::new(1, counted_f as fn(f64, &[f64], &mut [f64]));
    let (_, mut set, mut scheme) = scheme();
    let mut c = StepController::new(settings).unwrap();
    let (mut t, mut x, mut mus) = (0.0, [X0], Vec::new());
    while t < t_end {
        let step = c
            .step(&mut scheme, &field, &mut set, mus.len(), t, &mut x, t_end)
            .unwrap();
        // (The first step has no earlier velocity to compare with: no error.)
        assert!(
            mus.is_empty() || step.error > settings.tol,
            "{}",
            step.error
        );
        t = step.report.t;
        mus.push(step.report.mu);
    }
    assert_eq!(t, t_end);
    assert_eq!(mus.len(), 2, "{mus:?}");
    assert_eq!(mus[0], settings.mu_min);
    assert!((mus[1] - 1.3 * settings.mu_min).abs() < 1e-18, "{mus:?}");
}

/// The settings' errors printed a value of 1e-300 as "0.000…0001" (three hundred digits),
/// through `f64`'s `Display`: every such value goes through `Num` now.
#[test]
fn a_setting_of_1e_minus_300_was_printed_with_three_hundred_digits() {
    let mut s = AdaptiveSettings::new(1e-3);
    s.mu_first = 1e-300;
    let msg = StepController::new(s).unwrap_err().to_string();
    assert!(msg.contains("1e-300") && msg.len() < 200, "{msg}");
    let msg = moreau_integrate::Stepping::fixed(-1e-300)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("-1e-300") && msg.len() < 200, "{msg}");
}

/// `x ≥ sin t`: a set that moves the state with no field.
struct AboveSine;

impl moreau_core::ConstraintSet for AboveSine {
    fn dim(&self) -> usize {
        1
    }
    fn assemble(
        &mut self,
        t: f64,
        q: &[f64],
        _margin: f64,
        rows: &mut moreau_core::ConstraintRows,
    ) {
        rows.push(0, q[0] - t.sin(), [(0, 1.0)]);
    }
}

/// `x′ ∈ −N_{[sin t, ∞)}(x)`, `x(0) = 0`, `F = 0`: the set carries the state up to
/// `x = sin t` until `t = π/2`, where it stays, `x(t) = sin(min(t, π/2))`. The velocity-change
/// estimate follows the tolerance; step doubling cannot see this motion (one step and two
/// half steps both land on the set at the grid times, so its estimate stays at the
/// projections' accuracy and the steps grow to their largest whatever the tolerance; the
/// README says so). Found by a bug
/// hunt of the library API: nothing tested adaptive steps on a set-driven process.
#[test]
fn adaptive_steps_on_a_set_that_moves_the_state() {
    use moreau_integrate::{LinearizedProjection, LinearizedSettings};
    use moreau_solve::{InteriorPoint, InteriorPointSettings};
    let run = |tol: f64, estimate: ErrorEstimate| -> (f64, f64) {
        let field = FnField::new(1, |_t, _x: &[f64], out: &mut [f64]| out[0] = 0.0);
        let correction = LinearizedProjection::new(
            InteriorPoint::new(InteriorPointSettings::default()).unwrap(),
            LinearizedSettings::default(),
        )
        .unwrap();
        let mut s = Scheme::new(correction, EpsPolicy::new(1e-3, 3.0).unwrap());
        let mut settings = AdaptiveSettings::new(tol);
        settings.estimate = estimate;
        let mut c = StepController::new(settings).unwrap();
        let mut set = AboveSine;
        let (mut t, mut x, mut err, mut largest_estimate) = (0.0, [0.0], 0.0f64, 0.0f64);
        let mut k = 0;
        while t < T {
            let step = c.step(&mut s, &field, &mut set, k, t, &mut x, T).unwrap();
            t = step.report.t;
            k += 1;
            err = err.max((x[0] - t.min(std::f64::consts::FRAC_PI_2).sin()).abs());
            largest_estimate = largest_estimate.max(step.report.local_error.unwrap_or(0.0));
        }
        (err, largest_estimate)
    };
    for tol in [1e-2, 1e-3, 1e-4] {
        let (err, _) = run(tol, ErrorEstimate::VelocityChange);
        assert!(err <= tol, "velocity change, tol {tol:e}: error {err:.3e}");
    }
    // Step doubling's estimate stays at the projections' accuracy (~1e-7), far below a
    // tolerance its error exceeds tenfold.
    let tol = 1e-4;
    let (err, estimate) = run(tol, ErrorEstimate::StepDoubling);
    assert!(
        estimate < tol && err > 10.0 * tol,
        "step doubling saw the set's motion (error {err:.3e}, largest estimate \
         {estimate:.3e}): update the README"
    );
}

#[test]
fn a_step_the_time_cannot_resolve_stepped_forever_at_the_same_time() {
    // From t0 = 1.7e9 (a Unix time) steps of 1e-7 round back to t: `Scheme::run` refused
    // them, `Stepping` took them, and the state moved while the time stood still (30 million
    // steps, t − t0 = 0). The adaptive controller's floor alike, from t0 = 10¹².
    let field = FnField::new(1, |_t, _q: &[f64], out: &mut [f64]| out[0] = 1.0);
    let mut scheme = Scheme::new(Unconstrained, EpsPolicy::default());
    let mut q = [0.0];
    let mut fixed = Stepping::fixed(1e-7).unwrap();
    let t0 = 1.7e9;
    match fixed.step(&mut scheme, &field, &mut (), 0, t0, &mut q, t0 + 1e-3) {
        Err(IntegrateError::InvalidSetting { field, value, .. }) => {
            assert_eq!(field, "step");
            assert!(value.contains("1e-7 at times near 1700000000"), "{value}");
        }
        other => panic!("expected InvalidSetting, got {other:?}"),
    }
    assert_eq!(q, [0.0], "no step taken");
    let mut controller = StepController::new(AdaptiveSettings::new(1e-6)).unwrap();
    let t0 = 1e12;
    match controller.step(&mut scheme, &field, &mut (), 0, t0, &mut q, t0 + 1.0) {
        Err(IntegrateError::InvalidSetting { field, .. }) => assert_eq!(field, "mu_min"),
        other => panic!("expected InvalidSetting, got {:?}", other.map(|s| s.report)),
    }
    // Steps the time resolves are taken there: 1e-3 s from 1.7e9 lands on t0 + 1 s.
    let mut fine = Stepping::fixed(1e-3).unwrap();
    let (mut t, mut k) = (1.7e9, 0);
    while let Some(r) = fine
        .step(&mut scheme, &field, &mut (), k, t, &mut q, 1.7e9 + 1.0)
        .unwrap()
    {
        t = r.t;
        k += 1;
    }
    assert_eq!(t, 1.7e9 + 1.0);
    // Times there are rounded to 2.4e-7 s, a quarter of a thousandth of each step: the state
    // follows the time to that (it moved by 1 + 7e-5).
    assert!((q[0] - 1.0).abs() < 1e-3, "q = {}", q[0]);
}
