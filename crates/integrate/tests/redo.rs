//! The redo path of the linearized projection: a set whose margin misses a constraint the
//! step crosses is caught by the check after the step, and the step is redone with wider
//! margins (doubled, and at least twice as far as the step moved) until the constraint is
//! assembled (or fails, naming what was crossed, when the redo budget runs out).

use moreau_core::{BoxSet, ConstraintRows, ConstraintSet, FnField};
use moreau_integrate::{
    EpsPolicy, IntegrateError, LinearizedProjection, LinearizedSettings, Scheme,
};
use moreau_solve::InteriorPoint;

/// The box `q ≥ 0` (and `q ≤ 10`) with a margin that underestimates what a step can close,
/// and that assembles nothing below a margin of `blind` (a set whose rows the redos cannot
/// reach).
struct Shortsighted {
    set: BoxSet,
    margin: f64,
    blind: f64,
}

impl ConstraintSet for Shortsighted {
    fn dim(&self) -> usize {
        self.set.dim()
    }
    fn assemble(&mut self, t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows) {
        // The check after a step (a negative margin: rows violated) always sees them.
        if margin < 0.0 || margin >= self.blind {
            self.set.assemble(t, q, margin, rows);
        }
    }
    fn margin(&self, _q: &[f64], _w: &[f64], _mu: f64) -> f64 {
        self.margin
    }
}

/// One step of `q' = −1` from `q = 0.1` of size 0.5 (the prediction crosses `q ≥ 0` by 0.4)
/// with the set's `margin`.
fn step_with(
    max_redo: usize,
    margin: f64,
) -> (Result<moreau_core::StepReport, IntegrateError>, f64) {
    step_blind(max_redo, margin, 0.0)
}

/// [`step_with`] for a set that assembles nothing below a margin of `blind`.
fn step_blind(
    max_redo: usize,
    margin: f64,
    blind: f64,
) -> (Result<moreau_core::StepReport, IntegrateError>, f64) {
    let field = FnField::new(1, |_t, _q: &[f64], out: &mut [f64]| out[0] = -1.0);
    let mut set = Shortsighted {
        set: BoxSet::new(vec![0.0], vec![10.0]).unwrap(),
        margin,
        blind,
    };
    let correction = LinearizedProjection::new(
        InteriorPoint::new(Default::default()).unwrap(),
        LinearizedSettings {
            max_violation: 1e-9,
            max_redo,
        },
    )
    .unwrap();
    let mut scheme = Scheme::new(correction, EpsPolicy::new(1e-3, 3.0).unwrap());
    let mut q = [0.1];
    let r = scheme.step(&field, &mut set, 0, 0.0, &mut q, 0.5);
    (r, q[0])
}

fn step(max_redo: usize) -> (Result<moreau_core::StepReport, IntegrateError>, f64) {
    step_with(max_redo, 1e-3)
}

#[test]
fn a_constraint_the_margin_missed_is_caught_and_the_step_redone() {
    let (report, q) = step(8);
    let report = report.unwrap();
    // Margins 0.001, then 1 (twice the 0.5 the step moved; doubling alone reached the face
    // at distance 0.1 at 0.128, the 8th try): assembled at the 2nd.
    assert_eq!(report.redone, 1);
    assert_eq!(report.assembled, 1);
    // On the face, to the certified accuracy: |q − 0|² ≤ ε (and never beyond it).
    assert!(
        q >= -1e-9 && q <= report.eps.sqrt(),
        "the step stops on the face: q = {q}, √ε = {}",
        report.eps.sqrt()
    );
}

#[test]
fn a_step_that_runs_out_of_redos_fails_naming_what_was_crossed() {
    // Margins 0.001, 1, 2, 4: below the 10 the set needs to assemble its row, so the step is
    // redone three times and still crosses.
    let (report, _) = step_blind(3, 1e-3, 10.0);
    match report {
        Err(IntegrateError::CrossedOutside {
            crossed, redone, ..
        }) => assert_eq!((crossed, redone), (1, 3)),
        other => panic!("expected CrossedOutside, got {other:?}"),
    }
}

#[test]
fn a_margin_of_zero_stayed_zero_through_every_redo() {
    // A set whose margin is the speed times the step is 0 at rest, and doubling 0 left it 0:
    // eight identical redos, then CrossedOutside. The margin now grows to twice the distance
    // the step moved, and the face is found at the first redo.
    let (report, q) = step_with(8, 0.0);
    let report = report.unwrap();
    assert_eq!((report.redone, report.assembled), (1, 1));
    assert!(q >= -1e-9 && q <= report.eps.sqrt(), "q = {q}");
}

#[test]
fn a_nan_or_negative_margin_switched_the_constraints_off() {
    // NaN (or −∞) assembled no row and skipped the check after the step: q' = −1 crossed the
    // half-line to −0.4 as a certified step. Refused, naming the margin.
    for margin in [f64::NAN, f64::NEG_INFINITY, -0.5] {
        let (report, _) = step_with(8, margin);
        match report {
            Err(IntegrateError::InvalidSetting { field, .. }) => assert_eq!(field, "margin"),
            other => panic!("margin {margin}: expected InvalidSetting, got {other:?}"),
        }
    }
    // +∞ assembles everything, as the default margin does.
    let (report, q) = step_with(8, f64::INFINITY);
    assert_eq!(report.unwrap().redone, 0);
    assert!(q >= -1e-9, "q = {q}");
}
