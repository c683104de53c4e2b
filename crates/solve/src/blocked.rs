//! A sparse Cholesky factorization in 2×2 blocks, for normal equations whose unknowns come in
//! pairs that share every row (a disk's x and y): symbolic analysis once per pattern, then
//! left-looking numeric factorizations and triangular solves that read one index per block.
//! The matrix's columns are added by the caller as the factorization reaches them
//! ([`BlockColumns`]): the normal equations add `J`'s rows there, with no assembled copy.
//!
//! Why not faer's simplicial factorization, which it replaces on such matrices: that one is
//! scalar and up-looking, reads an index per multiply–add and recomputes each row's pattern
//! (its `ereach`) at every numeric factorization. Here the row patterns and the position of
//! every update are found once by the analysis, and each index read serves a 2×2 block
//! product (8 multiply–adds). Measured on jammed halls in benches/README.md.
//!
//! Storage: block columns of the lower triangle, the diagonal block first, blocks in column
//! order `[a₀₀, a₁₀, a₀₁, a₁₁]`. Of a diagonal block of `A` only `a₀₀, a₁₀, a₁₁` are read;
//! the factor keeps its diagonal blocks as `[1/l₀₀, l₁₀, 0, 1/l₁₁]`, so that no division is
//! left in the numeric factorization's columns or in the triangular solves.

use crate::products::Index;

/// A 2×2 block in column order `[a₀₀, a₁₀, a₀₁, a₁₁]`.
pub(crate) type Block = [f64; 4];

/// `w −= l bᵀ` for 2×2 blocks, with `b` spread as `bx = [b₀₀, b₀₀, b₁₀, b₁₀]` and
/// `by = [b₀₁, b₀₁, b₁₁, b₁₁]`: `w −= [l(:, 0), l(:, 0)] ∘ bx + [l(:, 1), l(:, 1)] ∘ by`, lane
/// by lane the same operations in the same order as entry by entry, and compiled to packed
/// arithmetic (two pairs of lanes, or four lanes at once with AVX).
#[inline(always)]
fn sub_mul_transpose(w: &mut Block, l: &Block, bx: &Block, by: &Block) {
    let la = [l[0], l[1], l[0], l[1]];
    let lb = [l[2], l[3], l[2], l[3]];
    for q in 0..4 {
        w[q] -= la[q] * bx[q] + lb[q] * by[q];
    }
}

/// The block columns of the matrix a factorization reads (see
/// [`BlockCholesky::factorize_columns`]).
pub(crate) trait BlockColumns {
    /// Adds block column `k` (its blocks in rows `≥ k`; of the diagonal block `a₀₀, a₁₀,
    /// a₁₁`) into `work`, indexed by block row; only blocks of the analysed pattern.
    fn add_column(&self, k: usize, work: &mut [Block]);
}

/// The block columns of `A` from its blocks `values`, laid out as `pattern`.
#[cfg(test)]
struct StoredColumns<'a> {
    pattern: &'a BlockPattern,
    values: &'a [f64],
}

#[cfg(test)]
impl BlockColumns for StoredColumns<'_> {
    #[inline(always)]
    fn add_column(&self, k: usize, work: &mut [Block]) {
        let a = self.pattern;
        for p in a.col(k) {
            let w = &mut work[a.row[p] as usize];
            for (q, x) in w.iter_mut().enumerate() {
                *x += self.values[4 * p + q];
            }
        }
    }
}

/// The block structure of a lower triangle (`ptr`, `row`: block columns, diagonal first).
#[derive(Debug, Clone, Default)]
pub(crate) struct BlockPattern {
    pub(crate) ptr: Vec<Index>,
    pub(crate) row: Vec<Index>,
}

impl BlockPattern {
    fn columns(&self) -> usize {
        self.ptr.len().saturating_sub(1)
    }
    fn col(&self, k: usize) -> std::ops::Range<usize> {
        self.ptr[k] as usize..self.ptr[k + 1] as usize
    }
}

/// The symbolic and numeric factorization `A = L Lᵀ` of a block-sparse symmetric positive
/// definite matrix (see the module's documentation).
#[derive(Debug, Clone, Default)]
pub(crate) struct BlockCholesky {
    // A's pattern and, per block column of L, the pattern of L.
    a: BlockPattern,
    l: BlockPattern,
    // Row k of L below the diagonal: the positions in L's storage of its blocks, by column,
    // and where each of those columns ends.
    row_ptr: Vec<Index>,
    row_pos: Vec<Index>,
    row_end: Vec<Index>,
    values: Vec<Block>,
    work: Vec<Block>,
    // scratch of the analysis
    mark: Vec<Index>,
}

impl BlockCholesky {
    /// Analyses the pattern of `A` (block columns of its lower triangle, each with its
    /// diagonal block first and its rows increasing): the pattern of `L` by merging each
    /// column's children in the elimination tree, and the row lists the numeric
    /// factorization walks.
    pub(crate) fn analyse(&mut self, a: BlockPattern) {
        let n = a.columns();
        self.a = a;
        let l = &mut self.l;
        l.ptr.clear();
        l.row.clear();
        l.ptr.push(0);
        self.mark.clear();
        self.mark.resize(n, Index::MAX);
        // children[k]: the columns whose elimination-tree parent is k, as linked lists.
        let none = Index::MAX;
        let mut head = vec![none; n];
        let mut next = vec![none; n];
        let mut col: Vec<Index> = Vec::new();
        for k in 0..n {
            col.clear();
            self.mark[k] = k as Index;
            for &r in &self.a.row[self.a.col(k)] {
                if self.mark[r as usize] != k as Index {
                    self.mark[r as usize] = k as Index;
                    col.push(r);
                }
            }
            let mut child = head[k];
            while child != none {
                let c = child as usize;
                let range = l.ptr[c] as usize + 1..l.ptr[c + 1] as usize;
                for p in range {
                    let r = l.row[p];
                    if r as usize > k && self.mark[r as usize] != k as Index {
                        self.mark[r as usize] = k as Index;
                        col.push(r);
                    }
                }
                child = next[c];
            }
            col.sort_unstable();
            l.row.push(k as Index);
            l.row.extend_from_slice(&col);
            l.ptr.push(l.row.len() as Index);
            if let Some(&parent) = col.first() {
                let p = parent as usize;
                next[k] = head[p];
                head[p] = k as Index;
            }
        }
        // Row lists: for each row k, the positions of its off-diagonal blocks in increasing
        // column order (a counting sort of L's entries by row).
        self.row_ptr.clear();
        self.row_ptr.resize(n + 1, 0);
        for k in 0..n {
            for p in l.ptr[k] as usize + 1..l.ptr[k + 1] as usize {
                self.row_ptr[l.row[p] as usize + 1] += 1;
            }
        }
        for k in 0..n {
            self.row_ptr[k + 1] += self.row_ptr[k];
        }
        self.row_pos.clear();
        self.row_pos.resize(self.row_ptr[n] as usize, 0);
        self.row_end.clear();
        self.row_end.resize(self.row_ptr[n] as usize, 0);
        let mut fill: Vec<Index> = self.row_ptr[..n].to_vec();
        for k in 0..n {
            for p in l.ptr[k] as usize + 1..l.ptr[k + 1] as usize {
                let r = l.row[p] as usize;
                self.row_pos[fill[r] as usize] = p as Index;
                self.row_end[fill[r] as usize] = l.ptr[k + 1];
                fill[r] += 1;
            }
        }
        self.values.clear();
        self.values.resize(l.row.len(), [0.0; 4]);
        self.work.clear();
        self.work.resize(n, [0.0; 4]);
    }

    /// Blocks of `L` (the fill the ordering left), for the reports.
    pub(crate) fn factor_blocks(&self) -> usize {
        self.l.row.len()
    }

    /// Block multiply–adds of one numeric factorization, `Σ_k c_k (c_k + 1) / 2` over the
    /// block column counts `c_k`, each a 2×2 product (8 scalar multiply–adds).
    pub(crate) fn factor_block_products(&self) -> u64 {
        (0..self.l.columns())
            .map(|k| {
                let c = self.l.col(k).len() as u64;
                c * (c + 1) / 2
            })
            .sum()
    }

    /// Factorizes the matrix whose blocks `a_values` are laid out as the analysed pattern of
    /// `A`; false when it is not numerically positive definite.
    #[cfg(test)]
    pub(crate) fn factorize(&mut self, a_values: &[f64]) -> bool {
        debug_assert_eq!(a_values.len(), 4 * self.a.row.len());
        let a = std::mem::take(&mut self.a);
        let ok = self.factorize_columns(&StoredColumns {
            pattern: &a,
            values: a_values,
        });
        self.a = a;
        ok
    }

    /// Factorizes the matrix of the analysed pattern whose block columns `columns` adds as the
    /// factorization reaches them (no assembled copy); false when it is not numerically
    /// positive definite.
    #[inline]
    pub(crate) fn factorize_columns(&mut self, columns: &impl BlockColumns) -> bool {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor has AVX (just checked), all `factorize_avx` asks for.
            #[allow(unsafe_code)]
            return unsafe { self.factorize_avx(columns) };
        }
        self.factorize_with(columns)
    }

    /// [`factorize_columns`](Self::factorize_columns) compiled for AVX: each block update in
    /// one 4-lane operation instead of two pairs of lanes. The same operations in the same
    /// order (no fused multiply–add), so the same bits on any x86-64.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn factorize_avx(&mut self, columns: &impl BlockColumns) -> bool {
        self.factorize_with(columns)
    }

    #[inline(always)]
    fn factorize_with(&mut self, columns: &impl BlockColumns) -> bool {
        let n = self.l.columns();
        let (l, work, values) = (&self.l, &mut self.work, &mut self.values);
        // `work` is zero between columns: each block is reset where column k's factor reads
        // it (no pass that clears the column first), and all of it after a failure.
        for k in 0..n {
            let lk = l.col(k);
            columns.add_column(k, work);
            // A(:, k) − Σ_j L(:, j) L(k, j)ᵀ over the columns j < k with a block in row k.
            let row = self.row_ptr[k] as usize..self.row_ptr[k + 1] as usize;
            for (&p, &end) in self.row_pos[row.clone()].iter().zip(&self.row_end[row]) {
                let (p, end) = (p as usize, end as usize);
                let b = values[p];
                let (bx, by) = ([b[0], b[0], b[1], b[1]], [b[2], b[2], b[3], b[3]]);
                // The rest of column j from row k on (its rows increase).
                for (&r, v) in l.row[p..end].iter().zip(&values[p..end]) {
                    sub_mul_transpose(&mut work[r as usize], v, &bx, &by);
                }
            }
            // L(k, k) by the 2×2 Cholesky of the diagonal block, kept as
            // `[1/l₀₀, l₁₀, 0, 1/l₁₁]`: the divisions of the column below and of every
            // triangular solve become multiplications.
            let d = std::mem::replace(&mut work[k], [0.0; 4]);
            let l00 = d[0].sqrt();
            let l10 = d[1] / l00;
            let schur = d[3] - l10 * l10;
            if !(d[0] > 0.0 && schur > 0.0) {
                work.fill([0.0; 4]);
                return false;
            }
            let (i00, i11) = (1.0 / l00, 1.0 / schur.sqrt());
            values[lk.start] = [i00, l10, 0.0, i11];
            // L(i, k) = W(i) L(k, k)⁻ᵀ: each row of the block solved against L(k, k)ᵀ.
            for (&r, out) in l.row[lk.start + 1..lk.end]
                .iter()
                .zip(&mut values[lk.start + 1..lk.end])
            {
                let w = std::mem::replace(&mut work[r as usize], [0.0; 4]);
                let (x0, x1) = (w[0] * i00, w[1] * i00); // rows 0 and 1
                *out = [x0, x1, (w[2] - x0 * l10) * i11, (w[3] - x1 * l10) * i11];
            }
        }
        true
    }

    /// Overwrites `x` (two entries per block column, in the factor's order) by `A⁻¹ x`.
    pub(crate) fn solve_in_place(&self, x: &mut [f64]) {
        let (l, values) = (&self.l, &self.values);
        let n = l.columns();
        debug_assert_eq!(x.len(), 2 * n);
        // L y = b, column by column; each update is one pair of lanes.
        for k in 0..n {
            let lk = l.col(k);
            let [i00, l10, _, i11] = values[lk.start];
            let y0 = x[2 * k] * i00;
            let y1 = (x[2 * k + 1] - l10 * y0) * i11;
            x[2 * k] = y0;
            x[2 * k + 1] = y1;
            let below = lk.start + 1..lk.end;
            for (&i, b) in l.row[below.clone()].iter().zip(&values[below]) {
                let i = 2 * i as usize;
                let t = [b[0] * y0 + b[2] * y1, b[1] * y0 + b[3] * y1];
                let xi = &mut x[i..i + 2];
                xi[0] -= t[0];
                xi[1] -= t[1];
            }
        }
        // Lᵀ x = y, column by column backwards: [r₀, r₁] −= bᵀ x_i as one pair of lanes.
        for k in (0..n).rev() {
            let lk = l.col(k);
            let mut r = [x[2 * k], x[2 * k + 1]];
            let below = lk.start + 1..lk.end;
            for (&i, b) in l.row[below.clone()].iter().zip(&values[below]) {
                let i = 2 * i as usize;
                let (x0, x1) = (x[i], x[i + 1]);
                r = [
                    r[0] - (b[0] * x0 + b[1] * x1),
                    r[1] - (b[2] * x0 + b[3] * x1),
                ];
            }
            let [i00, l10, _, i11] = values[lk.start];
            let x1 = r[1] * i11;
            let x0 = (r[0] - l10 * x1) * i00;
            x[2 * k] = x0;
            x[2 * k + 1] = x1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense symmetric matrix from blocks of `pattern` filled by `value(block, sub)`.
    fn dense(pattern: &BlockPattern, values: &[f64]) -> Vec<Vec<f64>> {
        let n = 2 * pattern.columns();
        let mut m = vec![vec![0.0; n]; n];
        for k in 0..pattern.columns() {
            for p in pattern.col(k) {
                let i = pattern.row[p] as usize;
                for (sub, &(r, c)) in [(0, 0), (1, 0), (0, 1), (1, 1)].iter().enumerate() {
                    if i == k && sub == 2 {
                        continue;
                    }
                    let v = values[4 * p + sub];
                    m[2 * i + r][2 * k + c] = v;
                    m[2 * k + c][2 * i + r] = v;
                }
            }
        }
        m
    }

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64) / ((1u64 << 53) as f64)
    }

    #[test]
    fn solves_a_random_block_sparse_system_as_a_dense_elimination_does() {
        let mut seed = 7u64;
        for &(n, density) in &[(1usize, 0.0), (5, 0.4), (40, 0.08), (120, 0.03)] {
            // Random lower block pattern, diagonal first, rows increasing.
            let mut pattern = BlockPattern::default();
            pattern.ptr.push(0);
            for k in 0..n {
                pattern.row.push(k as Index);
                for i in k + 1..n {
                    if lcg(&mut seed) < density {
                        pattern.row.push(i as Index);
                    }
                }
                pattern.ptr.push(pattern.row.len() as Index);
            }
            // Values: random off-diagonal blocks, diagonally dominant diagonal blocks.
            let mut values = vec![0.0; 4 * pattern.row.len()];
            let mut row_sum = vec![0.0; 2 * n];
            for k in 0..n {
                for p in pattern.col(k).skip(1) {
                    let i = pattern.row[p] as usize;
                    for sub in 0..4 {
                        let v = lcg(&mut seed) - 0.5;
                        values[4 * p + sub] = v;
                        row_sum[2 * i + sub % 2] += v.abs();
                        row_sum[2 * k + sub / 2] += v.abs();
                    }
                }
            }
            for k in 0..n {
                let p = pattern.ptr[k] as usize;
                let off = 0.3 * (lcg(&mut seed) - 0.5);
                values[4 * p] = 1.0 + row_sum[2 * k] + off.abs();
                values[4 * p + 1] = off;
                values[4 * p + 3] = 1.0 + row_sum[2 * k + 1] + off.abs();
            }
            let a = dense(&pattern, &values);
            let b: Vec<f64> = (0..2 * n).map(|_| lcg(&mut seed) - 0.5).collect();

            let mut chol = BlockCholesky::default();
            chol.analyse(pattern.clone());
            assert!(chol.factorize(&values));
            // The factor is the same, bit for bit, whichever instructions computed it.
            let mut portable = chol.clone();
            assert!(portable.factorize_with(&StoredColumns {
                pattern: &pattern,
                values: &values,
            }));
            assert_eq!(portable.values, chol.values, "n {n}");
            let mut x = b.clone();
            chol.solve_in_place(&mut x);
            // Residual of the dense system.
            let scale: f64 = b.iter().map(|v| v.abs()).sum::<f64>() + 1.0;
            for r in 0..2 * n {
                let ax: f64 = (0..2 * n).map(|c| a[r][c] * x[c]).sum();
                assert!(
                    (ax - b[r]).abs() <= 1e-12 * scale,
                    "n {n} row {r}: {ax} vs {}",
                    b[r]
                );
            }
        }
    }

    #[test]
    fn an_indefinite_matrix_is_refused_and_the_next_factorization_starts_clean() {
        // Blocks (0, 0), (1, 0), (1, 1), (2, 1), (2, 2): the first three are I, 2I, I
        // (eigenvalues −1 and 3: column 1 fails), after block (2, 1) was added into the
        // workspace.
        let pattern = BlockPattern {
            ptr: vec![0, 2, 4, 5],
            row: vec![0, 1, 1, 2, 2],
        };
        let eye = [1.0, 0.0, 0.0, 1.0];
        let values: Vec<f64> = [eye, [2.0, 0.0, 0.0, 2.0], eye, eye, eye].concat();
        let mut chol = BlockCholesky::default();
        chol.analyse(pattern.clone());
        assert!(!chol.factorize(&values));
        // The next factorization starts clean (the workspace a failed one left is cleared):
        // the same factor, bit for bit, as a new factorization's.
        let definite: Vec<f64> = [
            [4.0, 1.0, 0.0, 3.0],
            [0.5, 0.2, -0.3, 0.1],
            [5.0, -1.0, 0.0, 2.0],
            [0.7, -0.4, 0.2, 0.3],
            [6.0, 0.5, 0.0, 4.0],
        ]
        .concat();
        assert!(chol.factorize(&definite));
        let mut fresh = BlockCholesky::default();
        fresh.analyse(pattern);
        assert!(fresh.factorize(&definite));
        assert_eq!(chol.values, fresh.values);
    }
}
