//! The certificate of a primal–dual pair: duality gap and violation, computed from the data.

use crate::problem::ProjectionProblem;
use crate::workers::Workers;

/// What a pair `(v, λ)` proves about the projection problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Certificate {
    /// `P(v) − D(λ)` for the problem whose offsets are relaxed by the violation, so that `v`
    /// is feasible for it, plus [`floor`](Self::floor): an upper bound on
    /// `½|v − w|² − ½|v* − w|²` there, with its computation's rounding as estimated.
    pub gap: f64,
    /// How far the computed `P(v) − D(λ)` can be from its exact value by rounding alone (the
    /// unit roundoff times the magnitudes its sums add up, see [`certify`]): no pair
    /// certifies a gap below it, a target under it is a
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
/// `gap = ½|v − w|² + ½|Jᵀλ|² + λᵀ(b' + J w)`. For `v = w + Jᵀλ` this is `Σ λ_i max(s_i, 0)`.
/// Its rounding floor, added to it, is `u (½|v − w|² + ½|Jᵀλ|² + Σ λ_i |b'_i| +
/// Σ λ_i |(J w)_i|)` with `u` the unit roundoff: the rounding of the four sums, which cancel
/// to the gap (an estimate, not a bound: the products inside them round too, but a
/// difference of neighbouring multipliers is mostly exact, and the rounding of many terms
/// is random and mostly cancels; bounds term by term were 10–50× above the gaps the
/// interior point reaches on pushed chains, checked against their closed form).
/// `scratch` must have one entry per row and `scratch_n` one per unknown.
pub fn certify(
    problem: &ProjectionProblem<'_>,
    v: &[f64],
    lambda: &[f64],
    scratch: &mut [f64],
    scratch_n: &mut [f64],
) -> Certificate {
    certify_given(problem, v, lambda, None, scratch, scratch_n)
}

/// [`certify`], with `J w` when the caller has it (the same numbers, a pass fewer; `scratch`
/// then holds `J v` at the end).
pub(crate) fn certify_given(
    problem: &ProjectionProblem<'_>,
    v: &[f64],
    lambda: &[f64],
    jw: Option<&[f64]>,
    scratch: &mut [f64],
    scratch_n: &mut [f64],
) -> Certificate {
    let j = problem.jacobian;
    // s = b + J v
    j.mul(v, scratch);
    let mut violation: f64 = 0.0;
    let mut lam_bprime = 0.0;
    // Σ λ_i |b'_i|, for the floor.
    let mut lam_bprime_abs = 0.0;
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
        }
        lam_bprime += l * (problem.b[i] + relax);
        lam_bprime_abs += l * (problem.b[i] + relax).abs();
    }
    // J w
    let jw = match jw {
        Some(jw) => jw,
        None => {
            j.mul(problem.w, scratch);
            scratch
        }
    };
    let (lam_jw, lam_jw_abs) = (0..problem.rows())
        .map(|i| lambda[i].max(0.0) * jw[i])
        .fold((0.0, 0.0), |(s, a), x| (s + x, a + x.abs()));
    // Jᵀλ
    scratch_n.iter_mut().for_each(|x| *x = 0.0);
    let clamped = lambda.iter().map(|l| l.max(0.0));
    for (i, l) in clamped.enumerate() {
        if l > 0.0 {
            let (c, a) = j.row(i);
            for (&c, &a) in c.iter().zip(a) {
                scratch_n[c] += a * l;
            }
        }
    }
    let jtl_sq: f64 = scratch_n.iter().map(|x| x * x).sum();
    let dv_sq: f64 = v
        .iter()
        .zip(problem.w)
        .map(|(v, w)| (v - w) * (v - w))
        .sum();
    let gap = 0.5 * dv_sq + 0.5 * jtl_sq + lam_bprime + lam_jw;
    let floor = f64::EPSILON * (0.5 * dv_sq + 0.5 * jtl_sq + lam_bprime_abs + lam_jw_abs);
    Certificate {
        gap: if gap.is_nan() || floor.is_nan() {
            f64::INFINITY
        } else {
            gap.max(0.0) + floor
        },
        floor,
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
