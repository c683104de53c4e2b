//! The interior point's Newton system in its augmented form, `[I, Jᵀ; J, −D⁻¹] [Δv; y] =
//! [r; 0]`, for the iterations where the normal equations `(I + Jᵀ D J) Δv = r` can no longer
//! be factorized: pattern, symbolic analysis, regularized LDLᵀ (faer's) and iterative
//! refinement against the unregularized matrix.
//!
//! Why: `D = λ / s` grows like the inverse of the target gap on the active rows. On a long
//! chain pushed together, or a queue pressed against a wall, every row is active and the
//! pressure adds up along it, so `D` reaches 10¹⁷–10²¹ while the motions the contacts allow
//! keep their unit weight: `I + Jᵀ D J` then has a condition number beyond 1/ε of double
//! precision, and its Cholesky factorization breaks down (a pivot that is not positive)
//! before the target gap is reached. The augmented matrix holds `D⁻¹` instead of `D` and
//! nothing is multiplied by it: quasi-definite, factorized stably with a small static
//! regularization of its second block (faer's LDLᵀ with the expected signs, any ordering),
//! and refined against the true matrix so that the direction is the normal equations' own.
//! Redundant contacts (a self-stress `y` with `Jᵀ y = 0`) leave `Δv` unchanged whatever the
//! regularization does to `y`. It costs an `n + m` factorization, so the interior point takes
//! it only once the normal equations broke down (benches/README.md, session 22).

use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LdltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use moreau_core::ConstraintRows;

use crate::error::SolveError;
use crate::normal::StageTimes;
use crate::products::Index;

/// The static regularization of the second block, relative to each row's `|J_i|²`: the
/// factorized matrix has `−D_i⁻¹ − δ|J_i|²` there, refinement restores `−D_i⁻¹`.
const STATIC_REGULARIZATION: f64 = 1e-10;
/// Pivots of the wrong sign or smaller than this are replaced (faer's dynamic regularization,
/// relative to the largest `|J_i|²`, as Clarabel does).
const DYNAMIC_EPSILON: f64 = 1e-14;
/// ... by this (with the expected sign).
const DYNAMIC_DELTA: f64 = 1e-8;
/// Iterative refinement: at most this many corrections ...
const REFINE_MAX: usize = 20;
/// ... stopped once the residual is below this share of the right-hand side (both in the
/// largest entry), or when a correction does not shrink it by [`REFINE_STALL`].
const REFINE_TOLERANCE: f64 = 1e-15;
/// See [`REFINE_TOLERANCE`].
const REFINE_STALL: f64 = 0.5;

/// The augmented Newton matrix of one [`ConstraintRows`]: its upper triangle in compressed
/// columns (unknowns first, then one column per row with `J_i` above its diagonal), its
/// symbolic LDLᵀ and the last numeric factor. Scratch is sized at each analysis.
#[derive(Default)]
pub(crate) struct AugmentedSystem {
    n: usize,
    m: usize,
    col_ptr: Vec<Index>,
    row_idx: Vec<Index>,
    /// The true values (the second block's diagonal `−D⁻¹` as last factorized).
    values: Vec<f64>,
    /// The values factorized: `values` with the static regularization.
    regularized: Vec<f64>,
    /// Where row `i`'s diagonal is in `values`.
    diag: Vec<usize>,
    /// `δ |J_i|²` of each row.
    shift: Vec<f64>,
    signs: Vec<i8>,
    largest_row: f64,
    symbolic: Option<SymbolicCholesky<Index>>,
    /// The pattern (`col_ptr`, `row_idx`) `symbolic` analysed, and its unknowns (the
    /// pattern alone does not tell an unknown from an empty row).
    analysed: (Vec<Index>, Vec<Index>),
    analysed_n: usize,
    /// Whether the matrix holds the rows of this solve.
    current: bool,
    analyses: usize,
    l: Vec<f64>,
    mem: Option<MemBuffer>,
    /// A row's entries while the pattern is built.
    entries: Vec<(usize, f64)>,
    x: Vec<f64>,
    rhs: Vec<f64>,
    residual: Vec<f64>,
    correction: Vec<f64>,
    times: StageTimes,
}

impl std::fmt::Debug for AugmentedSystem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AugmentedSystem")
            .field("n", &self.n)
            .field("m", &self.m)
            .field("analysed", &self.symbolic.is_some())
            .finish()
    }
}

impl AugmentedSystem {
    /// Time spent so far (analyses in `analyse`, factorizations and refined solves in
    /// `factorize`).
    pub(crate) fn times(&self) -> StageTimes {
        self.times
    }

    /// Marks the rows as new (another solve): the next [`Self::factorize`] reads them again,
    /// and analyses them again only if their pattern changed.
    pub(crate) fn forget(&mut self) {
        self.current = false;
    }

    /// Symbolic analyses done so far.
    #[cfg(test)]
    pub(crate) fn analyses(&self) -> usize {
        self.analyses
    }

    /// The matrix of `j` (pattern and values) and, when its pattern differs from the last
    /// one analysed, its symbolic analysis (AMD on the whole augmented matrix).
    fn analyse(&mut self, j: &ConstraintRows) -> Result<(), SolveError> {
        let clock = Instant::now();
        let (n, m) = (j.dim(), j.len());
        (self.n, self.m) = (n, m);
        self.col_ptr.clear();
        self.row_idx.clear();
        self.values.clear();
        self.diag.clear();
        self.shift.clear();
        self.col_ptr.push(0);
        for c in 0..n {
            self.row_idx.push(c as Index);
            self.values.push(1.0);
            self.col_ptr.push(self.row_idx.len() as Index);
        }
        self.largest_row = 0.0;
        for i in 0..m {
            let (cols, coefs) = j.row(i);
            let start = self.row_idx.len();
            // The row's columns sorted, a repeated column's coefficients added up.
            self.entries.clear();
            self.entries
                .extend(cols.iter().copied().zip(coefs.iter().copied()));
            self.entries.sort_unstable_by_key(|e| e.0);
            for &(c, a) in &self.entries {
                if self.row_idx.len() > start && *self.row_idx.last().unwrap() == c as Index {
                    *self.values.last_mut().unwrap() += a;
                } else {
                    self.row_idx.push(c as Index);
                    self.values.push(a);
                }
            }
            let norm = j.row_norm_sq(i);
            self.largest_row = self.largest_row.max(norm);
            self.shift.push(STATIC_REGULARIZATION * norm);
            self.diag.push(self.row_idx.len());
            self.row_idx.push((n + i) as Index);
            self.values.push(-1.0);
            self.col_ptr.push(self.row_idx.len() as Index);
        }
        let size = n + m;
        let same = self.symbolic.is_some()
            && self.analysed_n == n
            && self.col_ptr == self.analysed.0
            && self.row_idx == self.analysed.1;
        if same {
            self.current = true;
            self.times.analyse += clock.elapsed().as_secs_f64();
            return Ok(());
        }
        self.symbolic = None;
        self.analysed.0.clone_from(&self.col_ptr);
        self.analysed.1.clone_from(&self.row_idx);
        self.analysed_n = n;
        self.analyses += 1;
        let pattern =
            SymbolicSparseColMatRef::new_checked(size, size, &self.col_ptr, None, &self.row_idx);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Upper,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| SolveError::Factorization(format!("{e:?}")))?;
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_ldlt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ]);
        self.mem = Some(MemBuffer::new(req));
        self.l.clear();
        self.l.resize(symbolic.len_val(), 0.0);
        self.symbolic = Some(symbolic);
        self.signs.clear();
        self.signs
            .extend((0..size).map(|k| if k < n { 1 } else { -1 }));
        for v in [
            &mut self.x,
            &mut self.rhs,
            &mut self.residual,
            &mut self.correction,
        ] {
            v.clear();
            v.resize(size, 0.0);
        }
        // (Only now: an analysis that failed is tried again, not taken for done.)
        self.current = true;
        self.times.analyse += clock.elapsed().as_secs_f64();
        Ok(())
    }

    /// Factorizes `[I, Jᵀ; J, −D⁻¹]` (rows with `d_i = 0` count as very far from binding), the
    /// rows read again when [`Self::forget`] was called since the last factorization; false
    /// when the factorization fails.
    pub(crate) fn factorize(&mut self, j: &ConstraintRows, d: &[f64]) -> Result<bool, SolveError> {
        if !self.current {
            self.analyse(j)?;
        }
        let clock = Instant::now();
        for (i, &di) in d.iter().enumerate() {
            // (D⁻¹ of an inactive row is large and harmless; of a zero weight, as large as
            // a finite number may safely be.)
            let inv = if di > 0.0 {
                (1.0 / di).min(1e150)
            } else {
                1e150
            };
            self.values[self.diag[i]] = -inv;
        }
        self.regularized.clear();
        self.regularized.extend_from_slice(&self.values);
        for i in 0..self.m {
            self.regularized[self.diag[i]] -= self.shift[i];
        }
        let symbolic = self.symbolic.as_ref().expect("analysed");
        let size = self.n + self.m;
        let a = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(size, size, &self.col_ptr, None, &self.row_idx),
            &self.regularized,
        );
        let scale = self.largest_row.max(1.0);
        let ok = symbolic
            .factorize_numeric_ldlt(
                &mut self.l,
                a,
                Side::Upper,
                LdltRegularization {
                    dynamic_regularization_signs: Some(&self.signs),
                    dynamic_regularization_delta: DYNAMIC_DELTA * scale,
                    dynamic_regularization_epsilon: DYNAMIC_EPSILON * scale,
                },
                Par::Seq,
                MemStack::new(self.mem.as_mut().expect("analysed")),
                Default::default(),
            )
            .is_ok()
            && self.l.iter().all(|x| x.is_finite());
        self.times.factorizations += 1;
        self.times.factorize += clock.elapsed().as_secs_f64();
        Ok(ok)
    }

    /// `out = K x` for the true (unregularized) matrix, from its upper triangle.
    fn apply(&self, x: &[f64], out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        for col in 0..self.n + self.m {
            let range = self.col_ptr[col] as usize..self.col_ptr[col + 1] as usize;
            for k in range {
                let (row, a) = (self.row_idx[k] as usize, self.values[k]);
                out[row] += a * x[col];
                if row != col {
                    out[col] += a * x[row];
                }
            }
        }
    }

    /// The regularized factor's solution of `K z = b`, in place.
    fn solve_factor(&mut self, b: &mut [f64]) {
        let symbolic = self.symbolic.as_ref().expect("analysed");
        let size = self.n + self.m;
        LdltRef::new(symbolic, &self.l).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(b, size, 1),
            Par::Seq,
            MemStack::new(self.mem.as_mut().expect("analysed")),
        );
    }

    /// Overwrites `(top, bottom)` (lengths `n` and `m`) by the solution `(Δv, y)` of
    /// `[I, Jᵀ; J, −D⁻¹] [Δv; y] = [top; bottom]`, refined against the true matrix.
    pub(crate) fn solve_in_place(&mut self, top: &mut [f64], bottom: &mut [f64]) {
        let clock = Instant::now();
        let (n, size) = (self.n, self.n + self.m);
        let mut b = std::mem::take(&mut self.rhs);
        let mut x = std::mem::take(&mut self.x);
        let mut r = std::mem::take(&mut self.residual);
        let mut z = std::mem::take(&mut self.correction);
        b[..n].copy_from_slice(top);
        b[n..size].copy_from_slice(bottom);
        x.copy_from_slice(&b);
        self.solve_factor(&mut x);
        let scale = b.iter().fold(0.0f64, |a, e| a.max(e.abs()));
        let mut last = f64::INFINITY;
        for _ in 0..REFINE_MAX {
            self.apply(&x, &mut r);
            r.iter_mut().zip(&b).for_each(|(r, b)| *r = b - *r);
            let norm = r.iter().fold(0.0f64, |a, e| a.max(e.abs()));
            if norm > last {
                // The last correction made it worse: undone.
                x.iter_mut().zip(&z).for_each(|(x, z)| *x -= z);
                break;
            }
            if !(norm > REFINE_TOLERANCE * scale) || !(norm < REFINE_STALL * last) {
                break;
            }
            last = norm;
            z.copy_from_slice(&r);
            self.solve_factor(&mut z);
            x.iter_mut().zip(&z).for_each(|(x, z)| *x += z);
        }
        top.copy_from_slice(&x[..n]);
        bottom.copy_from_slice(&x[n..size]);
        (self.rhs, self.x, self.residual, self.correction) = (b, x, r, z);
        self.times.factorize += clock.elapsed().as_secs_f64();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `(x, y)` back from the right-hand side `[x + Jᵀy; J x − D⁻¹ y]` they make (computed
    /// without multiplying by `D`), on a chain of 1,000 with `D` from 1 to 10²⁰ (the normal
    /// equations' factorization breaks down from ~10¹⁷ on), with a row repeated: the pair's
    /// split of its total is as ill-conditioned as `D` is large (a self-stress, which moves
    /// neither `x` nor `Jᵀy`), every other entry exact to ten digits. The rows' values change
    /// from solve to solve (doubled every other one), their pattern does not: one analysis.
    #[test]
    fn the_augmented_solve_is_accurate_whatever_the_weights() {
        let n = 1000;
        let m = n; // n − 1 links and the first one again
        let mut rows = ConstraintRows::new(n);
        for k in 0..n - 1 {
            rows.push(k as u64, 0.0, [(k + 1, 1.0), (k, -1.0)]);
        }
        rows.push(n as u64, 0.0, [(1, 1.0), (0, -1.0)]);
        let x_true: Vec<f64> = (0..n).map(|k| ((k * 31 % 17) as f64) - 8.0).collect();
        let mut y_true: Vec<f64> = (0..m).map(|k| ((k * 37 % 23) as f64) * 100.0).collect();
        let mut aug = AugmentedSystem::default();
        let mut rows_scaled = ConstraintRows::new(n);
        for i in 0..m {
            let (c, a) = rows.row(i);
            rows_scaled.push(i as u64, 0.0, c.iter().zip(a).map(|(&c, &a)| (c, 2.0 * a)));
        }
        for (k, decades) in [0, 4, 8, 12, 16, 20].into_iter().enumerate() {
            // Every other solve with the rows doubled: the same pattern, other values.
            let rows = if k % 2 == 1 { &rows_scaled } else { &rows };
            let d: Vec<f64> = (0..m)
                .map(|k| 10f64.powi(decades) * (1.0 + (k % 7) as f64))
                .collect();
            // The repeated pair carries `y_0 + y_{m−1}` in total whatever its split: the
            // split with `y_0/d_0 = y_{m−1}/d_{m−1}` is the one the matrix asks.
            let pair = y_true[0] + y_true[m - 1];
            y_true[0] = pair * d[0] / (d[0] + d[m - 1]);
            y_true[m - 1] = pair * d[m - 1] / (d[0] + d[m - 1]);
            aug.forget();
            assert!(aug.factorize(rows, &d).unwrap());
            assert_eq!(aug.analyses(), 1, "the pattern held: analysed once");
            let mut top = x_true.clone();
            rows.mul_transpose_add(&y_true, &mut top);
            let mut bottom = vec![0.0; m];
            rows.mul(&x_true, &mut bottom);
            for i in 0..m {
                bottom[i] -= y_true[i] / d[i];
            }
            aug.solve_in_place(&mut top, &mut bottom);
            let err_x = (0..n).fold(0.0f64, |e, k| e.max((top[k] - x_true[k]).abs()));
            let err_y = (1..m - 1).fold(0.0f64, |e, i| e.max((bottom[i] - y_true[i]).abs()));
            let err_pair = (bottom[0] + bottom[m - 1] - pair).abs();
            // |x| ≤ 8, |y| ≤ 2,200: ten digits of each.
            assert!(err_x < 1e-10 * 8.0, "D ~ 1e{decades}: x off by {err_x:e}");
            assert!(
                err_y < 1e-10 * 2200.0,
                "D ~ 1e{decades}: y off by {err_y:e}"
            );
            assert!(
                err_pair < 1e-10 * 4400.0,
                "D ~ 1e{decades}: pair off by {err_pair:e}"
            );
        }
        // Without the repeated row: another pattern, analysed again.
        let mut chain = ConstraintRows::new(n);
        for i in 0..n - 1 {
            let (c, a) = rows.row(i);
            chain.push(i as u64, 0.0, c.iter().copied().zip(a.iter().copied()));
        }
        aug.forget();
        assert!(aug.factorize(&chain, &vec![1e12; n - 1]).unwrap());
        assert_eq!(aug.analyses(), 2);
        // y = 0: the right-hand side is [x; J x].
        let mut top = x_true.clone();
        let mut bottom = vec![0.0; n - 1];
        chain.mul(&x_true, &mut bottom);
        aug.solve_in_place(&mut top, &mut bottom);
        let err_x = (0..n).fold(0.0f64, |e, k| e.max((top[k] - x_true[k]).abs()));
        assert!(err_x < 1e-10 * 8.0, "x off by {err_x:e}");
        let err_y = bottom.iter().fold(0.0f64, |e, y| e.max(y.abs()));
        assert!(err_y < 1e-10 * 8.0 * 1e12, "y off by {err_y:e} (D = 10¹²)");
    }
}
