//! The certificate of a primal–dual pair: duality gap and violation, computed from the data.

use crate::problem::ProjectionProblem;
use crate::workers::Workers;

/// What a pair `(v, λ)` proves about the projection problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Certificate {
    /// `P(v) − D(λ)` for the problem whose offsets are relaxed by the violation, so that `v`
    /// is feasible for it: an upper bound on `½|v − w|² − ½|v* − w|²` there.
    pub gap: f64,
    /// What the slacks' rounding alone can hide of the gap, `u Σ λ_i (|b_i| + |J_i| |v|)`
    /// (`u` the unit roundoff; each slack `b_i + J_i v` is rounded to about `u` of its
    /// terms): no pair certifies much below it, and a target under it is a
    /// [`SolveStatus::RoundingFloor`](moreau_core::SolveStatus::RoundingFloor).
    pub floor: f64,
    /// `max_i (−s_i)⁺` with `s = b + J v`.
    pub violation: f64,
    /// Rows with `λ_i > 0`.
    pub active: usize,
}

/// Certifies `(v, λ)`: `λ` is clamped to `λ ≥ 0` first (a dual point must be dual feasible).
///
/// With `b' = b + (−s)⁺` the pair is primal and dual feasible for offsets `b'`, and
/// `P(v) − D(λ) = ½|v − w|² + ½|Jᵀλ|² + λᵀ(b' + J w)`, computed as the equal
/// `Σ λ_i s_i⁺ + ½|v − w − Jᵀλ|²` (complementarity and the dual residual, each term ≥ 0).
/// The first form's four sums are each about `|w|²` and cancel: at `|w|` ~ 10⁴ its rounding
/// hid gaps thousands of times the target, computed as 0 (regression test
/// `a_gap_lost_to_cancellation_was_certified_as_zero`). `scratch` must have one entry per
/// row (it holds `J v` at the end) and `scratch_n` one per unknown.
pub fn certify(
    problem: &ProjectionProblem<'_>,
    v: &[f64],
    lambda: &[f64],
    scratch: &mut [f64],
    scratch_n: &mut [f64],
) -> Certificate {
    let j = problem.jacobian;
    // s = b + J v
    j.mul(v, scratch);
    let mut violation: f64 = 0.0;
    let mut complementarity = 0.0;
    let mut active = 0;
    for i in 0..problem.rows() {
        let s = problem.b[i] + scratch[i];
        // A NaN slack (a NaN or ∞ in `J` or `v`) is no satisfied row: `f64::max` dropped
        // it, and an answer of NaN was certified perfect (gap 0, violation 0).
        let relax = if s.is_nan() {
            f64::INFINITY
        } else {
            (-s).max(0.0)
        };
        violation = violation.max(relax);
        let l = lambda[i].max(0.0);
        if l > 0.0 {
            active += 1;
            complementarity += l * s.max(0.0);
        }
    }
    // Jᵀλ, and the slacks' rounding Σ λ_i (|b_i| + |J_i| |v|).
    scratch_n.iter_mut().for_each(|x| *x = 0.0);
    let mut reach = 0.0;
    let clamped = lambda.iter().map(|l| l.max(0.0));
    for (i, l) in clamped.enumerate() {
        if l > 0.0 {
            let (c, a) = j.row(i);
            let mut terms = problem.b[i].abs();
            for (&c, &a) in c.iter().zip(a) {
                scratch_n[c] += a * l;
                terms += (a * v[c]).abs();
            }
            reach += l * terms;
        }
    }
    let residual_sq: f64 = (0..v.len())
        .map(|c| {
            let r = v[c] - problem.w[c] - scratch_n[c];
            r * r
        })
        .sum();
    let gap = complementarity + 0.5 * residual_sq;
    Certificate {
        gap: if gap.is_nan() { f64::INFINITY } else { gap },
        floor: f64::EPSILON * reach,
        violation,
        active,
    }
}

/// The certificate of a pair with `v = w + Jᵀλ` (as the first-order solvers keep it), from
/// the slacks `s = b + Jv`: the gap `Σ λ_i s_i⁺` and the violation `max (−s_i)⁺`, summed on
/// `w`'s threads in fixed chunks.
pub(crate) fn gap_and_violation(w: &Workers, lam: &[f64], s: &[f64]) -> (f64, f64) {
    let gap = w.sum(s.len(), |i| lam[i] * s[i].max(0.0));
    // A NaN slack is an infinite violation (`f64::min` and `max` drop NaN: a NaN answer was
    // certified perfect).
    let lowest = w.min(s.len(), |i| {
        if s[i].is_nan() {
            f64::NEG_INFINITY
        } else {
            s[i]
        }
    });
    let viol = (-lowest).max(0.0);
    (if gap.is_nan() { f64::INFINITY } else { gap }, viol)
}
