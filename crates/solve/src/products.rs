//! Products with `J` (per row) and `Jᵀ` (gathered per unknown) that split over threads
//! without changing the order of any sum.

use moreau_core::ConstraintRows;

/// The index type of the sparse structures: half the memory of `usize`, enough for
/// 4·10⁹ entries (the interior point checks its patterns against it).
pub(crate) type Index = u32;

/// The structure of `Jᵀ`: for each unknown, the rows it appears in (ascending) and where
/// its coefficient is stored in `J`. Products `Jᵀy` gather per unknown, so they split over
/// threads without changing the order of any sum.
#[derive(Debug, Clone, Default)]
pub(crate) struct Transpose {
    pub(crate) col_start: Vec<usize>,
    rows: Vec<Index>,
    entries: Vec<Index>,
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
    }

    /// `(Jᵀ y)_c`.
    pub(crate) fn dot(&self, coefs: &[f64], y: &[f64], c: usize) -> f64 {
        (self.col_start[c]..self.col_start[c + 1])
            .map(|k| coefs[self.entries[k] as usize] * y[self.rows[k] as usize])
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
