//! The certificate of a primal–dual pair: duality gap and violation, computed from the data.

use crate::problem::ProjectionProblem;
use crate::workers::Workers;

/// What a pair `(v, λ)` proves about the projection problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Certificate {
    /// `P(v) − D(λ)` for the problem whose offsets are relaxed by the violation, so that `v`
    /// is feasible for it: an upper bound on `½|v − w|² − ½|v* − w|²` there.
    pub gap: f64,
    /// `max_i (−s_i)⁺` with `s = b + J v`.
    pub violation: f64,
    /// Rows with `λ_i > 0`.
    pub active: usize,
}

/// Certifies `(v, λ)`: `λ` is clamped to `λ ≥ 0` first (a dual point must be dual feasible).
///
/// With `b' = b + (−s)⁺` the pair is primal and dual feasible for offsets `b'`, and
/// `gap = ½|v − w|² + ½|Jᵀλ|² + λᵀ(b' + J w)`. For `v = w + Jᵀλ` this is `Σ λ_i max(s_i, 0)`.
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
    }
    // J w
    let jw = match jw {
        Some(jw) => jw,
        None => {
            j.mul(problem.w, scratch);
            scratch
        }
    };
    let lam_jw: f64 = (0..problem.rows())
        .map(|i| lambda[i].max(0.0) * jw[i])
        .sum();
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
    Certificate {
        gap: if gap.is_nan() {
            f64::INFINITY
        } else {
            gap.max(0.0)
        },
        violation,
        active,
    }
}

/// How far [`certify`]'s gap for `(v, λ)` can be from its exact value by rounding alone: the
/// unit roundoff times the magnitudes its sums add up (`½|v − w|²`, `Σ_c ((|J|ᵀλ)_c)²` for
/// `½|Jᵀλ|²`, and `Σ_i λ_i (|b'_i| + (|J| (|v| + |w|))_i)` for `λᵀ(b' + J w)`, where `|J| |v|`
/// also bounds the slacks' own rounding). No pair certifies much below it: a target under it
/// is a [`SolveStatus::RoundingFloor`](moreau_core::SolveStatus::RoundingFloor), a stall far
/// above it is not. Two passes over `J`: for a solver's rare stop, not for each iteration.
/// `scratch_n` must have one entry per unknown.
pub fn rounding_floor(
    problem: &ProjectionProblem<'_>,
    v: &[f64],
    lambda: &[f64],
    scratch_n: &mut [f64],
) -> f64 {
    let j = problem.jacobian;
    scratch_n.iter_mut().for_each(|x| *x = 0.0);
    let mut rows = 0.0;
    for (i, &l) in lambda.iter().enumerate() {
        let l = l.max(0.0);
        if l == 0.0 {
            continue;
        }
        let (c, a) = j.row(i);
        let mut jv = 0.0;
        let mut reach = 0.0;
        for (&c, &a) in c.iter().zip(a) {
            scratch_n[c] += a.abs() * l;
            jv += a * v[c];
            reach += a.abs() * (v[c].abs() + problem.w[c].abs());
        }
        let relax = (-(problem.b[i] + jv)).max(0.0);
        rows += l * ((problem.b[i] + relax).abs() + reach);
    }
    let jtl: f64 = scratch_n.iter().map(|x| x * x).sum();
    let dv: f64 = v
        .iter()
        .zip(problem.w)
        .map(|(v, w)| (v - w) * (v - w))
        .sum();
    f64::EPSILON * (0.5 * dv + jtl + rows)
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
