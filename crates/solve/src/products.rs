//! Products with `J` (per row) and `Jᵀ` (gathered per unknown) that split over threads
//! without changing the order of any sum.

use moreau_core::ConstraintRows;

/// The index type of the sparse structures: half the memory of `usize`, enough for
/// 4·10⁹ entries (the interior point checks its patterns against it).
pub(crate) type Index = u32;

/// `Jᵀ`: for each unknown, the rows it appears in (ascending), where its coefficient is
/// stored in `J`, and a copy of that coefficient (so that a product reads it in order).
/// Products `Jᵀy` gather per unknown, so they split over threads without changing the order
/// of any sum.
#[derive(Debug, Clone, Default)]
pub(crate) struct Transpose {
    pub(crate) col_start: Vec<usize>,
    rows: Vec<Index>,
    entries: Vec<Index>,
    values: Vec<f64>,
    next: Vec<usize>, // scratch for building
}

impl Transpose {
    pub(crate) fn build(&mut self, j: &ConstraintRows) {
        let n = j.dim();
        self.col_start.clear();
        self.col_start.resize(n + 1, 0);
        for &c in j.columns() {
            self.col_start[c + 1] += 1;
        }
        for c in 0..n {
            self.col_start[c + 1] += self.col_start[c];
        }
        self.rows.clear();
        self.rows.resize(j.nnz(), 0);
        self.entries.clear();
        self.entries.resize(j.nnz(), 0);
        let starts = j.row_starts();
        self.next.clear();
        self.next.extend_from_slice(&self.col_start);
        for i in 0..j.len() {
            for e in starts[i]..starts[i + 1] {
                let c = j.columns()[e];
                let k = self.next[c];
                self.rows[k] = i as Index;
                self.entries[k] = e as Index;
                self.next[c] += 1;
            }
        }
        self.refresh(j);
    }

    /// Copies the coefficients of `j`, whose rows have the columns [`Self::build`] saw.
    pub(crate) fn refresh(&mut self, j: &ConstraintRows) {
        let coefs = j.coefficients();
        self.values.clear();
        self.values
            .extend(self.entries.iter().map(|&e| coefs[e as usize]));
    }

    /// `(Jᵀ y)_c`, with the coefficients of the last [`Self::build`] or [`Self::refresh`].
    pub(crate) fn dot(&self, y: &[f64], c: usize) -> f64 {
        let (a, b) = (self.col_start[c], self.col_start[c + 1]);
        self.values[a..b]
            .iter()
            .zip(&self.rows[a..b])
            .map(|(&v, &r)| v * y[r as usize])
            .sum()
    }

    /// The rows of unknown `c`.
    pub(crate) fn rows_of(&self, c: usize) -> &[Index] {
        &self.rows[self.col_start[c]..self.col_start[c + 1]]
    }
}

/// `(J x)_i`.
pub(crate) fn row_dot(j: &ConstraintRows, x: &[f64], i: usize) -> f64 {
    let (c, a) = j.row(i);
    c.iter().zip(a).map(|(&c, &a)| a * x[c]).sum()
}

/// `(J (x + y))_i`.
pub(crate) fn row_dot_sum(j: &ConstraintRows, x: &[f64], y: &[f64], i: usize) -> f64 {
    let (c, a) = j.row(i);
    c.iter().zip(a).map(|(&c, &a)| a * (x[c] + y[c])).sum()
}
