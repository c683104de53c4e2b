//! Rows whose multipliers are not unique: a bead held on the line `y = 0` by two opposite
//! rows `y ≥ 0` and `−y ≥ 0` (an equality written as two inequalities), and `x ∈ [−1, 1]`,
//! under a field of amplitude 100. Only `λ₀ − λ₁` is fixed by the problem.

use moreau_core::{ConstraintRows, ConstraintSet, FnField};
use moreau_integrate::{EpsPolicy, LinearizedProjection, LinearizedSettings, Scheme};
use moreau_solve::{ClarabelReference, ClarabelSettings, InteriorPoint};

struct Line;

impl ConstraintSet for Line {
    fn dim(&self) -> usize {
        2
    }
    fn assemble(&mut self, _t: f64, q: &[f64], _margin: f64, rows: &mut ConstraintRows) {
        rows.push(0, q[1], [(1, 1.0)]);
        rows.push(1, -q[1], [(1, -1.0)]);
        rows.push(2, q[0] + 1.0, [(0, 1.0)]);
        rows.push(3, 1.0 - q[0], [(0, -1.0)]);
    }
}

#[test]
fn opposite_rows_had_the_interior_points_multipliers_tripled_step_after_step() {
    // The interior point started each solve at 3 × the last answer's mean multiplier, and
    // the answer keeps its start along `λ₀ = λ₁`: 89, 240, 740, … 7·10⁶ by step 21, and step 22
    // ended in NumericalError (no fallback here: the run stopped, NotCertified). Now the start
    // is capped by what a multiplier can need.
    let amp = 100.0;
    let field = FnField::new(2, move |t, _q: &[f64], o: &mut [f64]| {
        o[0] = amp * (7.0 * t).cos();
        o[1] = amp * (5.0 * t).sin() + 0.3 * amp;
    });
    let settings = LinearizedSettings {
        max_violation: 1e-9 * amp,
        max_redo: 8,
    };
    let interior = InteriorPoint::new(Default::default()).unwrap();
    let mut scheme = Scheme::new(
        LinearizedProjection::new(interior, settings).unwrap(),
        EpsPolicy::new(1e-3, 3.0).unwrap(),
    );
    // Clarabel alone, on the same steps: the net force to compare with.
    let clarabel = ClarabelReference::new(ClarabelSettings::default());
    let mut reference = Scheme::new(
        LinearizedProjection::new(clarabel, settings).unwrap(),
        EpsPolicy::new(1e-3, 3.0).unwrap(),
    );
    let (mut q, mut q_ref, mut t) = ([0.0, 0.0], [0.0, 0.0], 0.0);
    let mut largest = Vec::new();
    for k in 0..60 {
        let r = scheme
            .step(
                &field,
                &mut Line as &mut dyn ConstraintSet,
                k,
                t,
                &mut q,
                0.1,
            )
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        reference
            .step(
                &field,
                &mut Line as &mut dyn ConstraintSet,
                k,
                t,
                &mut q_ref,
                0.1,
            )
            .unwrap();
        t = r.t;
        let (l, m) = (
            scheme.correction().multipliers(),
            reference.correction().multipliers(),
        );
        largest.push(l[0].max(l[1]));
        // The net force is the problem's: the same as Clarabel's to the certified accuracy.
        assert!(
            ((l[0] - l[1]) - (m[0] - m[1])).abs() <= 1e-3 * amp,
            "step {k}: net {} against Clarabel's {}",
            l[0] - l[1],
            m[0] - m[1]
        );
    }
    // No growth from step to step: the median step's multipliers are those of a cold solve
    // (10²–10⁴; a solve can still end with a larger common part, which the next start drops).
    largest.sort_by(f64::total_cmp);
    let median = largest[largest.len() / 2];
    assert!(median <= 1e4, "the multipliers grew: median {median:e}");
}
