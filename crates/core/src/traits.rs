//! The traits a problem implements: field, constraint set, convex part, convex set.

use crate::rows::ConstraintRows;

/// The single-valued part of the right-hand side, `F(t, q)` (desired velocities for a crowd).
pub trait Field {
    /// Dimension of the state.
    fn dim(&self) -> usize;
    /// Writes `F(t, q)` into `out`.
    fn eval(&self, t: f64, q: &[f64], out: &mut [f64]);
}

/// A [`Field`] from a closure, for small problems and tests.
pub struct FnField<F> {
    dim: usize,
    f: F,
}

impl<F: Fn(f64, &[f64], &mut [f64])> FnField<F> {
    /// Wraps `f(t, q, out)` acting on states of dimension `dim`.
    pub fn new(dim: usize, f: F) -> Self {
        Self { dim, f }
    }
}

impl<F> std::fmt::Debug for FnField<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FnField")
            .field("dim", &self.dim)
            .finish_non_exhaustive()
    }
}

impl<F: Fn(f64, &[f64], &mut [f64])> Field for FnField<F> {
    fn dim(&self) -> usize {
        self.dim
    }
    fn eval(&self, t: f64, q: &[f64], out: &mut [f64]) {
        (self.f)(t, q, out)
    }
}

/// A feasible set `Q(t) = ∩_i {q : g_i(t, q) ≥ 0}` with each `g_i` smooth and convex in `q`,
/// reported near a state as sparse rows.
pub trait ConstraintSet {
    /// Dimension of the state.
    fn dim(&self) -> usize;

    /// Appends to `rows` (cleared by the caller) every constraint with `g_i(t, q) ≤ margin`,
    /// with its gradient `∇_q g_i(t, q)` and a key that names it across steps.
    fn assemble(&mut self, t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows);

    /// The margin `ρ` for a step of size `mu` from `q` with predicted velocity `w`: every
    /// constraint that can become active within the step must have `g_i ≤ ρ`. The default
    /// assembles everything; a set with many far-away constraints (a crowd) derives `ρ` from
    /// the speeds, and the check after the step ([`ConstraintSet::crossed_outside`]) catches
    /// what the estimate missed.
    fn margin(&self, _q: &[f64], _w: &[f64], _mu: f64) -> f64 {
        f64::INFINITY
    }

    /// Whether every constraint left out of `assemble(t, q, margin, …)` is certainly violated
    /// by no more than `tol` at `(t, q_next)`, from how far the state moved: a proof that
    /// lets the step skip [`ConstraintSet::crossed_outside`]. The default cannot tell.
    fn left_out_stay_feasible(
        &self,
        _t: f64,
        _q: &[f64],
        _q_next: &[f64],
        _margin: f64,
        _tol: f64,
    ) -> bool {
        false
    }

    /// After a step that moved the state farther than the margin: how many constraints that
    /// were *not* assembled the step passed through on its way from `q` to `q_next`,
    /// satisfied at both ends (a disk pushed through a thin wall it never saw lands on the
    /// free side, and no check at `q_next` sees it). A nonzero answer means the step must be
    /// redone with a wider margin, as for [`ConstraintSet::crossed_outside`]. The default
    /// finds none: for a convex set no step passes through a constraint it satisfies at both
    /// ends.
    fn passed_through(
        &mut self,
        _t: f64,
        _q: &[f64],
        _q_next: &[f64],
        _assembled: &ConstraintRows,
    ) -> usize {
        0
    }

    /// After a step: how many constraints that were *not* assembled are violated at `(t, q)`
    /// by more than `tol`. A nonzero answer means the step must be redone with a wider margin.
    ///
    /// The default assembles everything below `-tol` and compares keys; a set that can do it
    /// faster (a crowd with a broad phase) overrides it.
    fn crossed_outside(
        &mut self,
        t: f64,
        q: &[f64],
        assembled: &ConstraintRows,
        tol: f64,
    ) -> usize {
        let mut violated = ConstraintRows::new(self.dim());
        self.assemble(t, q, -tol, &mut violated);
        count_outside(&violated, assembled, tol, &mut Vec::new())
    }
}

/// How many rows of `candidates` have `g < −tol` and a key that `assembled` lacks: the count
/// [`ConstraintSet::crossed_outside`] returns. The violated keys (usually none) are collected
/// in `scratch` and sorted, and `assembled`'s keys searched among them.
pub fn count_outside(
    candidates: &ConstraintRows,
    assembled: &ConstraintRows,
    tol: f64,
    scratch: &mut Vec<crate::rows::ConstraintKey>,
) -> usize {
    scratch.clear();
    scratch.extend(
        candidates
            .keys()
            .iter()
            .zip(candidates.values())
            .filter(|&(_, &g)| g < -tol)
            .map(|(&k, _)| k),
    );
    if scratch.is_empty() {
        return 0;
    }
    scratch.sort_unstable();
    let known = assembled
        .keys()
        .iter()
        .filter(|k| scratch.binary_search(k).is_ok())
        .count();
    scratch.len() - known
}

/// A convex, lower semicontinuous `ψ` whose subdifferential `G = ∂ψ` is the set-valued
/// regular part of the right-hand side (dry friction, for example). `Send`, so that a scheme
/// (and a crowd `Simulation`) can move to another thread.
pub trait ConvexPart: Send {
    /// Writes the element of minimal norm of `f − ∂ψ(x)` into `out` (the explicit selection
    /// of the catching-up scheme, `seeds/002` Definition 4.3).
    fn min_norm_selection(&self, x: &[f64], f: &[f64], out: &mut [f64]);
    /// Writes `prox_{τψ}(x) = argmin_z τψ(z) + ½|z − x|²` into `out`.
    fn prox(&self, tau: f64, x: &[f64], out: &mut [f64]);
}

/// A closed convex set with an exact Euclidean projection.
pub trait ConvexSet {
    /// Dimension of the ambient space.
    fn dim(&self) -> usize;
    /// Writes the projection of `y` onto the set into `out`.
    fn project(&self, y: &[f64], out: &mut [f64]);
    /// Euclidean distance from `y` to the set.
    fn distance(&self, y: &[f64]) -> f64 {
        let mut p = vec![0.0; y.len()];
        self.project(y, &mut p);
        y.iter()
            .zip(&p)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt()
    }
}
