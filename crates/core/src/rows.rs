//! Sparse constraint rows: the values `g_i` and gradients `∇g_i` of the assembled constraints.

/// A stable identity of one constraint across steps (a pair of bodies, a body and a wall, a
/// bound index), used to warm-start multipliers from the previous step.
pub type ConstraintKey = u64;

/// The constraints assembled near a state, stored row by row (compressed sparse rows).
///
/// Row `i` holds `g_i` and the nonzeros of `∇g_i`; the feasible side is `g_i ≥ 0`. The buffers
/// are reused from step to step: [`ConstraintRows::clear`] keeps their capacity.
#[derive(Debug, Clone, Default)]
pub struct ConstraintRows {
    dim: usize,
    keys: Vec<ConstraintKey>,
    values: Vec<f64>,
    row_start: Vec<usize>,
    cols: Vec<usize>,
    coefs: Vec<f64>,
}

impl ConstraintRows {
    /// Empty rows for unknowns of dimension `dim`.
    pub fn new(dim: usize) -> Self {
        Self {
            dim,
            row_start: vec![0],
            ..Self::default()
        }
    }

    /// Forgets all rows, keeps the memory, and sets the dimension of the unknowns.
    pub fn clear(&mut self, dim: usize) {
        self.dim = dim;
        self.keys.clear();
        self.values.clear();
        self.row_start.clear();
        self.row_start.push(0);
        self.cols.clear();
        self.coefs.clear();
    }

    /// Appends one constraint `g ≥ 0` with gradient entries `(column, coefficient)`.
    ///
    /// # Panics
    /// If a column is out of range (a bug in the caller, not bad input).
    pub fn push(
        &mut self,
        key: ConstraintKey,
        g: f64,
        gradient: impl IntoIterator<Item = (usize, f64)>,
    ) {
        for (c, a) in gradient {
            assert!(
                c < self.dim,
                "constraint column {c} out of range for dimension {}",
                self.dim
            );
            self.cols.push(c);
            self.coefs.push(a);
        }
        self.keys.push(key);
        self.values.push(g);
        self.row_start.push(self.cols.len());
    }

    /// Appends `other`'s rows after these, in their order (the same rows as pushing them
    /// here one by one).
    ///
    /// # Panics
    /// If `other` has columns beyond this dimension (a bug in the caller).
    pub fn append(&mut self, other: &ConstraintRows) {
        assert!(
            other.cols.iter().all(|&c| c < self.dim),
            "appended rows of dimension {} to rows of dimension {}",
            other.dim,
            self.dim
        );
        let shift = self.cols.len();
        self.cols.extend_from_slice(&other.cols);
        self.coefs.extend_from_slice(&other.coefs);
        self.keys.extend_from_slice(&other.keys);
        self.values.extend_from_slice(&other.values);
        self.row_start
            .extend(other.row_start[1..].iter().map(|&s| s + shift));
    }

    /// Number of rows (assembled constraints).
    #[inline]
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// True when no constraint is assembled.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Dimension of the unknowns (number of columns).
    #[inline]
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The constraint values `g_i`.
    #[inline]
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The constraint identities.
    #[inline]
    pub fn keys(&self) -> &[ConstraintKey] {
        &self.keys
    }

    /// Row `i` of the Jacobian: its columns and coefficients.
    #[inline]
    pub fn row(&self, i: usize) -> (&[usize], &[f64]) {
        let (a, b) = (self.row_start[i], self.row_start[i + 1]);
        (&self.cols[a..b], &self.coefs[a..b])
    }

    /// Where each row starts in [`ConstraintRows::columns`] (one more entry than rows).
    #[inline]
    pub fn row_starts(&self) -> &[usize] {
        &self.row_start
    }

    /// The columns of all gradient entries, row after row.
    #[inline]
    pub fn columns(&self) -> &[usize] {
        &self.cols
    }

    /// The coefficients of all gradient entries, row after row.
    #[inline]
    pub fn coefficients(&self) -> &[f64] {
        &self.coefs
    }

    /// Number of stored gradient entries.
    #[inline]
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }

    /// `out = J x`.
    pub fn mul(&self, x: &[f64], out: &mut [f64]) {
        debug_assert_eq!(x.len(), self.dim);
        for (i, o) in out.iter_mut().enumerate().take(self.len()) {
            let (c, a) = self.row(i);
            *o = c.iter().zip(a).map(|(&c, &a)| a * x[c]).sum();
        }
    }

    /// `out += Jᵀ y`.
    pub fn mul_transpose_add(&self, y: &[f64], out: &mut [f64]) {
        debug_assert_eq!(out.len(), self.dim);
        for (i, &yi) in y.iter().enumerate().take(self.len()) {
            if yi == 0.0 {
                continue;
            }
            let (c, a) = self.row(i);
            for (&c, &a) in c.iter().zip(a) {
                out[c] += a * yi;
            }
        }
    }

    /// `|∇g_i|²` for row `i`. A column repeated within the row is one coefficient, the sum of
    /// its entries (as the products read it): the sum of the entries' squares made
    /// Gauss–Seidel's step twice too long on `2x ≥ 2` written as `x + x`, and it never
    /// converged.
    #[inline]
    pub fn row_norm_sq(&self, i: usize) -> f64 {
        let (c, a) = self.row(i);
        if c.windows(2).all(|w| w[0] < w[1]) {
            return a.iter().map(|a| a * a).sum();
        }
        (0..c.len())
            .filter(|&k| !c[..k].contains(&c[k]))
            .map(|k| {
                let sum: f64 = (k..c.len()).filter(|&l| c[l] == c[k]).map(|l| a[l]).sum();
                sum * sum
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_match_dense() {
        let mut r = ConstraintRows::new(3);
        r.push(7, 1.0, [(0, 1.0), (2, -2.0)]);
        r.push(8, -0.5, []);
        r.push(9, 0.0, [(1, 3.0)]);
        let x = [1.0, 2.0, 3.0];
        let mut jx = [0.0; 3];
        r.mul(&x, &mut jx);
        assert_eq!(jx, [1.0 - 6.0, 0.0, 6.0]);
        let mut jty = [0.0; 3];
        r.mul_transpose_add(&[1.0, 5.0, 2.0], &mut jty);
        assert_eq!(jty, [1.0, 6.0, -2.0]);
        assert_eq!(r.keys(), &[7, 8, 9]);
        assert_eq!(r.row_norm_sq(0), 5.0);
        // Regression: a repeated column is one coefficient (x + x is 2x: norm² 4, not 2),
        // whatever its place in the row.
        r.push(8, 0.0, [(1, 1.0), (0, 3.0), (1, 1.0)]);
        assert_eq!(r.row_norm_sq(3), 13.0);
        r.clear(3);
        assert!(r.is_empty());
    }

    #[test]
    fn appended_rows_are_the_rows_pushed_one_by_one() {
        type Row<'a> = (u64, f64, &'a [(usize, f64)]);
        let rows: [Row; 4] = [
            (7, 1.0, &[(0, 1.0), (2, -2.0)]),
            (8, -0.5, &[]),
            (9, 0.0, &[(1, 3.0)]),
            (10, 2.0, &[(2, 1.0), (0, 4.0), (1, 5.0)]),
        ];
        let mut pushed = ConstraintRows::new(3);
        for &(k, g, a) in &rows {
            pushed.push(k, g, a.iter().copied());
        }
        let mut first = ConstraintRows::new(3);
        let mut second = ConstraintRows::new(3);
        for (n, &(k, g, a)) in rows.iter().enumerate() {
            let into = if n < 2 { &mut first } else { &mut second };
            into.push(k, g, a.iter().copied());
        }
        first.append(&second);
        first.append(&ConstraintRows::new(3));
        assert_eq!(first.keys(), pushed.keys());
        assert_eq!(first.values(), pushed.values());
        assert_eq!(first.row_starts(), pushed.row_starts());
        assert_eq!(first.columns(), pushed.columns());
        assert_eq!(first.coefficients(), pushed.coefficients());
    }
}
