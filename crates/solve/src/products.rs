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
}

impl Transpose {
    /// The whole transpose of `j`: each unknown's rows, where its coefficients are in `j`,
    /// and a copy of them.
    pub(crate) fn build(&mut self, j: &ConstraintRows) {
        self.index(j, true);
        self.refresh(j);
    }

    /// The rows of each unknown alone ([`Self::rows_of`]; no coefficients, nothing for
    /// [`Self::dot`]): a third of the memory, for an index that only walks the rows around
    /// an unknown (`auto`'s joins: on a million people ~80 MB less).
    pub(crate) fn build_rows(&mut self, j: &ConstraintRows) {
        self.index(j, false);
        self.values = Vec::new();
    }

    /// `col_start` and `rows`, and with `entries` where each coefficient is in `j` (else
    /// none): a counting sort of `j`'s entries by column, rows ascending.
    fn index(&mut self, j: &ConstraintRows, entries: bool) {
        let n = j.dim();
        // Counts two ahead, so that filling moves each start one ahead, onto its place.
        self.col_start.clear();
        self.col_start.resize(n + 2, 0);
        for &c in j.columns() {
            self.col_start[c + 2] += 1;
        }
        for c in 0..n {
            self.col_start[c + 2] += self.col_start[c + 1];
        }
        self.rows.clear();
        self.rows.resize(j.nnz(), 0);
        self.entries.clear();
        if entries {
            self.entries.resize(j.nnz(), 0);
        } else {
            self.entries.shrink_to_fit();
        }
        let (starts, columns) = (j.row_starts(), j.columns());
        for i in 0..j.len() {
            for e in starts[i]..starts[i + 1] {
                let k = &mut self.col_start[columns[e] + 1];
                self.rows[*k] = i as Index;
                if entries {
                    self.entries[*k] = e as Index;
                }
                *k += 1;
            }
        }
        self.col_start.truncate(n + 1);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The index of rows alone lists each unknown's rows as the whole transpose does, on rows
    /// with repeated and unused columns, and after a larger build.
    #[test]
    fn the_rows_alone_are_the_rows_of_the_whole_transpose() {
        let mut j = ConstraintRows::new(7);
        for (i, cols) in [
            vec![0, 3],
            vec![3, 3, 5],
            vec![1],
            vec![6, 0, 2],
            vec![],
            vec![5],
        ]
        .into_iter()
        .enumerate()
        {
            j.push(i as u64, 0.0, cols.into_iter().map(|c| (c, 1.0)));
        }
        let mut whole = Transpose::default();
        whole.build(&j);
        let mut rows = Transpose::default();
        let mut larger = ConstraintRows::new(9);
        larger.push(0, 0.0, [(8, 1.0), (7, 2.0)]);
        rows.build(&larger);
        rows.build_rows(&j);
        for c in 0..7 {
            assert_eq!(rows.rows_of(c), whole.rows_of(c), "unknown {c}");
        }
        assert_eq!(rows.rows_of(3), &[0, 1, 1]);
        assert!(rows.rows_of(4).is_empty());
        assert_eq!(rows.col_start.len(), 8);
    }
}
