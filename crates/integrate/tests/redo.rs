//! The redo path of the linearized projection: a set whose margin misses a constraint the
//! step crosses is caught by the check after the step, and the step is redone with doubled
//! margins until the constraint is assembled (or fails, naming what was crossed, when the
//! redo budget runs out).

use moreau_core::{BoxSet, ConstraintRows, ConstraintSet, FnField};
use moreau_integrate::{
    EpsPolicy, IntegrateError, LinearizedProjection, LinearizedSettings, Scheme,
};
use moreau_solve::InteriorPoint;

/// The box `q ≥ 0` (and `q ≤ 10`) with a margin that underestimates what a step can close.
struct Shortsighted {
    set: BoxSet,
    margin: f64,
}

impl ConstraintSet for Shortsighted {
    fn dim(&self) -> usize {
        self.set.dim()
    }
    fn assemble(&mut self, t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows) {
        self.set.assemble(t, q, margin, rows);
    }
    fn margin(&self, _q: &[f64], _w: &[f64], _mu: f64) -> f64 {
        self.margin
    }
}

/// One step of `q' = −1` from `q = 0.1` of size 0.5 (the prediction crosses `q ≥ 0` by 0.4).
fn step(max_redo: usize) -> (Result<moreau_core::StepReport, IntegrateError>, f64) {
    let field = FnField::new(1, |_t, _q: &[f64], out: &mut [f64]| out[0] = -1.0);
    let mut set = Shortsighted {
        set: BoxSet::new(vec![0.0], vec![10.0]).unwrap(),
        margin: 1e-3,
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

#[test]
fn a_constraint_the_margin_missed_is_caught_and_the_step_redone() {
    let (report, q) = step(8);
    let report = report.unwrap();
    // Margins 0.001, 0.002, …: the face at distance 0.1 is assembled at 0.128, the 8th try.
    assert_eq!(report.redone, 7);
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
    let (report, _) = step(3);
    match report {
        Err(IntegrateError::CrossedOutside {
            crossed, redone, ..
        }) => assert_eq!((crossed, redone), (1, 3)),
        other => panic!("expected CrossedOutside, got {other:?}"),
    }
}
