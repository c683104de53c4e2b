//! The normal equations `shift·I + Jᵀ diag(d) J` of the Newton solvers, factorized in 2×2
//! blocks ([`crate::blocked`]) when the unknowns pair up and the factor is thin, by faer's
//! sparse Cholesky otherwise (a supernodal one factorized by [`crate::frontal`] and solved
//! by [`crate::supernodal`], both on two threads where the helper is there): ordering,
//! pattern, symbolic analysis (redone only when the columns of `J`'s rows change), numeric
//! factorization, triangular solves, and the time spent in each.
//!
//! What is separated: the *ordering* (AMD on one node per group of unknowns that share their
//! rows, a person's x and y, or, for the interior point, on only the groups whose rows
//! changed since the last analysis, the others keeping their places ([`crate::reorder`]);
//! on large patterns whose minimum-degree factor is dense, a crush's, also nested dissection
//! ([`crate::dissection`]), keeping whichever factor costs fewer multiply–adds), the
//! permuted *pattern* of `I + Jᵀ D J` with the slot where each row's products land (in 2×2
//! blocks: each row's blocks and where its coefficients are, so that the factorization adds
//! `J`'s rows into each column as it reaches it, with no assembled copy of the matrix), and
//! the *symbolic* Cholesky — all three redone only when the columns of `J`'s rows change —
//! and the *numeric* factorization, as often as the caller asks. The matrix is
//! `shift·I + Jᵀ D J` for any `D ≥ 0` and `shift > 0`: symmetric positive definite however
//! redundant the rows are. Scratch memory is sized at each symbolic analysis.

use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use moreau_core::{ConstraintRows, Helper, Parallelism};

use crate::blocked::{Block, BlockCholesky, BlockColumns, BlockPattern};
use crate::dissection::{Dissection, FillCount};
use crate::error::SolveError;
use crate::frontal::Multifrontal;
use crate::problem::SolveReport;
use crate::products::{Index, Transpose};
use crate::reorder::{KeptOrdering, structure_hash};
use crate::supernodal;
use crate::workers::Workers;

/// What the factorization machinery did over the solver's life (for benchmarks).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FactorizationCounts {
    /// Orderings, patterns and symbolic analyses (the columns of the rows changed).
    pub analyses: usize,
    /// Numeric factorizations.
    pub factorizations: usize,
    /// Stored entries of the last factorized triangle of `I + Jᵀ D J`.
    pub matrix_nnz: usize,
    /// Stored entries of its last Cholesky factor (the fill the ordering left).
    pub factor_nnz: usize,
    /// Numeric factorizations done in 2×2 blocks (the rest by faer).
    pub block_factorizations: usize,
    /// Multiply–adds of one numeric factorization of the last analysed pattern,
    /// `Σ_j c_j (c_j + 1) / 2` over the factor's column counts `c_j`: the cost a factorization
    /// will have, known before any numeric work.
    pub factor_flops: u64,
    /// Analyses that ordered by nested dissection (the rest by minimum degree alone).
    pub dissections: usize,
    /// Numeric factorizations in 2×2 blocks split over two threads
    /// ([`InteriorPointSettings::split_factorization`](crate::InteriorPointSettings)).
    pub split_factorizations: usize,
    /// Rank-one updates and downdates of a factorization in 2×2 blocks.
    pub updates: usize,
    /// Numeric factorizations of the Newton system's augmented form, which the interior point
    /// takes once the normal equations broke down (not in `factorizations`; a solve's report
    /// counts both).
    pub augmented_factorizations: usize,
}

/// Seconds spent per stage of the factorization machinery, accumulated.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct StageTimes {
    /// Orderings, patterns and symbolic analyses (and the check whether they are current).
    pub(crate) analyse: f64,
    /// Assembling `I + Jᵀ D J`, numeric factorizations and triangular solves.
    pub(crate) factorize: f64,
    /// Numeric factorizations (a count: [`FactorizationCounts::factorizations`] when read).
    pub(crate) factorizations: usize,
}

impl StageTimes {
    /// The time spent since `earlier` (a reading of the same accumulator).
    pub(crate) fn since(self, earlier: StageTimes) -> StageTimes {
        StageTimes {
            analyse: self.analyse - earlier.analyse,
            factorize: self.factorize - earlier.factorize,
            factorizations: self.factorizations - earlier.factorizations,
        }
    }

    /// Both accumulators added up.
    pub(crate) fn plus(self, other: StageTimes) -> StageTimes {
        StageTimes {
            analyse: self.analyse + other.analyse,
            factorize: self.factorize + other.factorize,
            factorizations: self.factorizations + other.factorizations,
        }
    }

    /// Writes these times into a report's stage fields.
    pub(crate) fn report_into(self, report: &mut SolveReport) {
        report.time_analyse = self.analyse;
        report.time_factorize = self.factorize;
        report.factorizations = self.factorizations;
    }
}

/// Runs `f` and adds its wall-clock time to `acc`.
fn timed<R>(acc: &mut f64, f: impl FnOnce() -> R) -> R {
    let clock = Instant::now();
    let r = f();
    *acc += clock.elapsed().as_secs_f64();
    r
}

/// One triangle of `I + Jᵀ D J` in compressed columns, in a given symmetric ordering, and
/// where each product `D_i a_ia a_ib` of row `i` of `J` lands in it.
#[derive(Debug, Clone, Default)]
struct NormalPattern {
    n: usize,
    col_ptr: Vec<Index>,
    row_idx: Vec<Index>,
    diag: Vec<usize>,
    // For each row of J, each ordered pair (a, b) of its entries with col_a ≥ col_b, in
    // traversal order: where the product lands in `row_idx`.
    slots: Vec<Index>,
    // Where each row's products start in `slots` (one more entry than rows).
    slot_start: Vec<usize>,
    // Length of the values `slots` index (the pattern's entries).
    value_len: usize,
    // In 2×2 blocks (after [`NormalPattern::build_blocks`], instead of `slots`): for each row
    // of J, the blocks it touches, each `[block, position of the row's coefficient at the
    // block's first unknown, at its second]` (positions in `J`'s coefficients), from
    // `row_entry_start[i]`; for each block column, the `[row, entry]` of the rows touching it,
    // from `col_entry_start[k]`, rows increasing.
    row_entry_start: Vec<Index>,
    row_entries: Vec<[Index; 3]>,
    col_entry_start: Vec<Index>,
    col_entries: Vec<[Index; 2]>,
    // scratch for building
    count: Vec<usize>,
    fill: Vec<Index>,
    row_groups: Vec<usize>,
    // The entries of the pattern being built, as `[row, column]` (scratch).
    pairs: Vec<[Index; 2]>,
}

/// Calls `f(col_a, col_b)` for the ordered pairs of entries of every row with `col_a ≥ col_b`,
/// in the order [`NormalPattern::assemble`] visits them.
fn for_each_product(j: &ConstraintRows, mut f: impl FnMut(usize, usize)) {
    for i in 0..j.len() {
        let cols = j.row(i).0;
        for &ca in cols {
            for &cb in cols {
                if ca >= cb {
                    f(ca, cb);
                }
            }
        }
    }
}

/// Calls `f(a, b)` once per row for each pair `a ≠ b` of the distinct values `group(c)`
/// takes on that row's columns (`seen` is scratch): the off-diagonal entries of the pattern of
/// `Jᵀ J` compressed by `group`, a row between two disks one pair where
/// [`for_each_product`] visits its ten products.
fn for_each_pair_of(
    j: &ConstraintRows,
    group: impl Fn(usize) -> usize,
    seen: &mut Vec<usize>,
    mut f: impl FnMut(usize, usize),
) {
    for i in 0..j.len() {
        seen.clear();
        for &c in j.row(i).0 {
            let g = group(c);
            if !seen.contains(&g) {
                seen.push(g);
            }
        }
        for (k, &a) in seen.iter().enumerate() {
            for &b in &seen[k + 1..] {
                f(a, b);
            }
        }
    }
}

/// Numbers the runs of adjacent unknowns that appear in exactly the same rows
/// (`group_of[c]`, increasing in `c`) and returns how many runs there are.
fn column_groups(jt: &Transpose, group_of: &mut Vec<usize>) -> usize {
    let n = jt.col_start.len() - 1;
    group_of.clear();
    let mut groups = 0;
    for c in 0..n {
        if c == 0 || jt.rows_of(c - 1) != jt.rows_of(c) {
            groups += 1;
        }
        group_of.push(groups - 1);
    }
    groups
}

/// Columns `0..n`, each with its diagonal and the entries `pairs` (as `[row, column]`),
/// rows sorted and without repeats, into `ptr` (one more entry than columns) and `rows`.
/// `count` and `fill` are scratch.
fn sorted_columns(
    n: usize,
    pairs: &[[Index; 2]],
    (count, fill): (&mut Vec<usize>, &mut Vec<Index>),
    ptr: &mut Vec<Index>,
    rows: &mut Vec<Index>,
) {
    count.clear();
    count.resize(n, 1); // the diagonal
    for &[_, c] in pairs {
        count[c as usize] += 1;
    }
    let mut total = 0;
    for c in count.iter_mut() {
        let k = *c;
        *c = total;
        total += k;
    }
    fill.clear();
    fill.resize(total, 0);
    for c in 0..n {
        fill[count[c]] = c as Index;
        count[c] += 1;
    }
    for &[r, c] in pairs {
        let k = &mut count[c as usize];
        fill[*k] = r;
        *k += 1;
    }
    // count[c] is now the end of column c's bucket and the start of column c + 1's.
    ptr.clear();
    rows.clear();
    ptr.push(0);
    let mut start = 0;
    for &end in count.iter() {
        let bucket = &mut fill[start..end];
        bucket.sort_unstable();
        let mut last = Index::MAX;
        for &r in bucket.iter() {
            if r != last {
                rows.push(r);
                last = r;
            }
        }
        ptr.push(rows.len() as Index);
        start = end;
    }
}

impl NormalPattern {
    /// Builds the pattern of `j` with unknown `c` at position `at[c]` (identity without
    /// `at`), storing the upper triangle (row ≤ column) when `upper`, else the lower one;
    /// with `slots`, also where each product lands.
    fn build(
        &mut self,
        j: &ConstraintRows,
        at: Option<(&[usize], usize)>,
        upper: bool,
        slots: bool,
    ) {
        let n = at.map_or(j.dim(), |a| a.1);
        self.n = n;
        let at = at.map(|a| a.0);
        let place = |ca: usize, cb: usize| -> (usize, usize) {
            let (pa, pb) = match at {
                Some(at) => (at[ca], at[cb]),
                None => (ca, cb),
            };
            let (lo, hi) = if pa <= pb { (pa, pb) } else { (pb, pa) };
            if upper { (lo, hi) } else { (hi, lo) } // (row, column)
        };
        // Without slots only the pattern is wanted: each row's distinct pairs of positions
        // (the diagonal is always in it), not every product.
        let mut pairs = std::mem::take(&mut self.pairs);
        pairs.clear();
        let mut push = |r: usize, c: usize| pairs.push([r as Index, c as Index]);
        if slots {
            for_each_product(j, |ca, cb| {
                let (r, c) = place(ca, cb);
                push(r, c)
            })
        } else {
            let group = |c: usize| at.map_or(c, |at| at[c]);
            let mut seen = std::mem::take(&mut self.row_groups);
            for_each_pair_of(j, group, &mut seen, |a, b| {
                let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
                if upper { push(lo, hi) } else { push(hi, lo) }
            });
            self.row_groups = seen;
        }
        sorted_columns(
            n,
            &pairs,
            (&mut self.count, &mut self.fill),
            &mut self.col_ptr,
            &mut self.row_idx,
        );
        self.pairs = pairs;
        self.value_len = self.row_idx.len();
        self.diag.clear();
        self.slots.clear();
        self.slot_start.clear();
        if !slots {
            return;
        }
        let find = |col_ptr: &[Index], row_idx: &[Index], r: usize, c: usize| {
            let (a, b) = (col_ptr[c] as usize, col_ptr[c + 1] as usize);
            a + row_idx[a..b]
                .binary_search(&(r as Index))
                .expect("every product has a slot in the pattern")
        };
        for c in 0..n {
            self.diag.push(find(&self.col_ptr, &self.row_idx, c, c));
        }
        let (col_ptr, row_idx, out) = (&self.col_ptr, &self.row_idx, &mut self.slots);
        for i in 0..j.len() {
            self.slot_start.push(out.len());
            let cols = j.row(i).0;
            for &ca in cols {
                for &cb in cols {
                    if ca >= cb {
                        let (r, c) = place(ca, cb);
                        out.push(find(col_ptr, row_idx, r, c) as Index);
                    }
                }
            }
        }
        self.slot_start.push(out.len());
    }

    /// The lower triangle of `j`'s normal matrix in 2×2 blocks, with unknown `c` at position
    /// `at[c]` of `n` (even) and positions `2k, 2k + 1` paired into block `k`: the blocks'
    /// pattern, and each row's blocks with where its coefficients are (`row_entries`,
    /// `col_entries`). `None` when a row does not have exactly one coefficient at each
    /// unknown of the blocks it touches (a column repeated in a row).
    fn build_blocks(
        &mut self,
        j: &ConstraintRows,
        at: &[usize],
        n: usize,
        mut blocks: BlockPattern,
    ) -> Option<BlockPattern> {
        debug_assert!(n.is_multiple_of(2));
        let nb = n / 2;
        self.n = n;
        self.col_ptr.clear();
        self.row_idx.clear();
        self.diag.clear();
        self.slots.clear();
        self.slot_start.clear();
        self.value_len = 0;
        // Each row's blocks, with the positions of its two coefficients there.
        const NONE: Index = Index::MAX;
        self.row_entry_start.clear();
        self.row_entries.clear();
        let (starts, cols) = (j.row_starts(), j.columns());
        for i in 0..j.len() {
            let first = self.row_entries.len();
            self.row_entry_start.push(first as Index);
            for t in starts[i]..starts[i + 1] {
                let pos = at[cols[t]];
                let (q, lane) = ((pos / 2) as Index, 1 + pos % 2);
                let e = match self.row_entries[first..].iter().position(|e| e[0] == q) {
                    Some(e) => first + e,
                    None => {
                        self.row_entries.push([q, NONE, NONE]);
                        self.row_entries.len() - 1
                    }
                };
                if self.row_entries[e][lane] != NONE {
                    return None;
                }
                self.row_entries[e][lane] = t as Index;
            }
            if self.row_entries[first..]
                .iter()
                .any(|e| e[1] == NONE || e[2] == NONE)
            {
                return None;
            }
        }
        self.row_entry_start.push(self.row_entries.len() as Index);
        // By block column: a counting sort of the entries by block, rows increasing.
        self.col_entry_start.clear();
        self.col_entry_start.resize(nb + 1, 0);
        for e in &self.row_entries {
            self.col_entry_start[e[0] as usize + 1] += 1;
        }
        for k in 0..nb {
            self.col_entry_start[k + 1] += self.col_entry_start[k];
        }
        self.col_entries.clear();
        self.col_entries.resize(self.row_entries.len(), [0, 0]);
        self.count.clear();
        self.count
            .extend(self.col_entry_start[..nb].iter().map(|&c| c as usize));
        for i in 0..j.len() {
            let range = self.row_entry_start[i] as usize..self.row_entry_start[i + 1] as usize;
            for e in range {
                let k = self.row_entries[e][0] as usize;
                self.col_entries[self.count[k]] = [i as Index, e as Index];
                self.count[k] += 1;
            }
        }
        // The off-diagonal blocks by column, behind each column's diagonal block.
        // (Each row's blocks are distinct in `row_entries`: its pairs of them.)
        self.pairs.clear();
        for w in self.row_entry_start.windows(2) {
            let row = &self.row_entries[w[0] as usize..w[1] as usize];
            for (k, a) in row.iter().enumerate() {
                for b in &row[k + 1..] {
                    self.pairs.push([a[0].max(b[0]), a[0].min(b[0])]);
                }
            }
        }
        sorted_columns(
            nb,
            &self.pairs,
            (&mut self.count, &mut self.fill),
            &mut blocks.ptr,
            &mut blocks.row,
        );
        Some(blocks)
    }

    fn symbolic(&self) -> SymbolicSparseColMatRef<'_, Index> {
        SymbolicSparseColMatRef::new_checked(self.n, self.n, &self.col_ptr, None, &self.row_idx)
    }

    /// `values = triangle(shift·I + Jᵀ diag(d) J)`; rows with `d_i = 0` are skipped.
    fn assemble(&self, j: &ConstraintRows, shift: f64, d: &[f64], values: &mut Vec<f64>) {
        values.clear();
        values.resize(self.value_len, 0.0);
        for &p in &self.diag {
            values[p] = shift;
        }
        for (i, &di) in d.iter().enumerate() {
            if di == 0.0 {
                continue;
            }
            let (cols, coefs) = j.row(i);
            let mut k = self.slot_start[i];
            for (&ca, &aa) in cols.iter().zip(coefs) {
                for (&cb, &ab) in cols.iter().zip(coefs) {
                    if ca >= cb {
                        values[self.slots[k] as usize] += di * aa * ab;
                        k += 1;
                    }
                }
            }
        }
    }
}

/// The block columns of `shift·I + Jᵀ diag(d) J` from `J`'s rows, by the entries of
/// [`NormalPattern::build_blocks`]; rows with `d_i = 0` are skipped.
struct NormalColumns<'a> {
    pattern: &'a NormalPattern,
    coefs: &'a [f64],
    shift: f64,
    d: &'a [f64],
}

impl BlockColumns for NormalColumns<'_> {
    #[inline(always)]
    fn add_column(&self, k: usize, work: &mut [Block]) {
        let (shift, d, coefs) = (self.shift, self.d, self.coefs);
        let pattern = self.pattern;
        let diag = &mut work[k];
        diag[0] += shift;
        diag[3] += shift;
        let (rows, entries) = (&pattern.row_entry_start, &pattern.row_entries);
        let range = pattern.col_entry_start[k] as usize..pattern.col_entry_start[k + 1] as usize;
        for &[i, e] in &pattern.col_entries[range] {
            let di = d[i as usize];
            if di == 0.0 {
                continue;
            }
            let [_, o0, o1] = entries[e as usize];
            let (u0, u1) = (di * coefs[o0 as usize], di * coefs[o1 as usize]);
            let row = rows[i as usize] as usize..rows[i as usize + 1] as usize;
            for &[q, p0, p1] in &entries[row] {
                if (q as usize) < k {
                    continue;
                }
                let (v0, v1) = (coefs[p0 as usize], coefs[p1 as usize]);
                let w = &mut work[q as usize];
                w[0] += v0 * u0;
                w[1] += v1 * u0;
                w[2] += v0 * u1;
                w[3] += v1 * u1;
            }
        }
    }
}

/// faer's workspace, sized at each symbolic analysis.
pub(crate) struct Scratch(pub(crate) MemBuffer);

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
}

/// AMD's workspace and its size in bytes, grown as needed and kept from ordering to
/// ordering.
#[derive(Default)]
struct AmdScratch(Option<(MemBuffer, usize)>);

impl std::fmt::Debug for AmdScratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("AmdScratch")
    }
}

impl AmdScratch {
    /// The minimum-degree ordering of `graph` (its upper triangle, rows sorted, no repeats).
    fn order(
        &mut self,
        perm: &mut [Index],
        perm_inv: &mut [Index],
        graph: &NormalPattern,
    ) -> Result<(), SolveError> {
        // (Bytes enough at any alignment.)
        let bytes =
            amd::order_scratch::<Index>(graph.n, graph.row_idx.len()).unaligned_bytes_required();
        if self.0.as_ref().is_none_or(|m| m.1 < bytes) {
            self.0 = Some((MemBuffer::new(StackReq::new::<u8>(bytes)), bytes));
        }
        let mem = &mut self.0.as_mut().expect("sized above").0;
        amd::order(
            perm,
            perm_inv,
            graph.symbolic(),
            amd::Control::default(),
            MemStack::new(mem),
        )
        .map_err(|e| SolveError::Factorization(format!("{e:?}")))?;
        Ok(())
    }
}

/// Multiply–adds per factor entry above which faer's supernodal factorization is used
/// instead of the 2×2-block one: where they cross on crushes since the blocks gather a
/// supernode's updates (benches/README.md, session 23: the blocks 1.35× faster at 63
/// multiply–adds an entry, 1.18× at 107, even at 153; before, the supernodes were 1.3×
/// faster at 63 and this was 40).
const SUPERNODAL_FLOPS_PER_ENTRY: u64 = 150;

/// Nested dissection is tried on patterns of at least this many groups of unknowns …
const DISSECTION_MIN_GROUPS: usize = 2048;

/// … whose minimum-degree factor has at least this many multiply–adds per entry (counted on
/// the groups): a crush's factor has ~50 at 10⁴ people, a jammed hall's ~4
/// (benches/README.md, session 12).
const DISSECTION_MIN_PRODUCTS_PER_ENTRY: u64 = 16;

/// The normal equations `shift·I + Jᵀ diag(d) J` of one structure of `J`: analysed once per
/// structure, factorized for any values, solved in the unknowns' natural order.
///
/// Owns the workers (thread pool) its factorizations run on; the solvers use the same ones
/// for their own loops ([`NormalEquations::workers`]).
#[derive(Debug)]
pub(crate) struct NormalEquations {
    parallelism: Parallelism,
    workers: Workers,
    // The structure of J the analysis below was made for.
    j_row_start: Vec<Index>,
    j_cols: Vec<Index>,
    // The unpermuted lower triangle (input of the ordering), the fill-reducing ordering,
    // and the permuted triangle that is factorized (no permutation per factorization).
    natural: NormalPattern,
    perm: Vec<usize>,
    perm_inv: Vec<usize>,
    group_of: Vec<usize>,
    group_start: Vec<usize>,
    group_perm: Vec<Index>,
    group_perm_inv: Vec<Index>,
    dissection: Dissection,
    fill: FillCount,
    nd_perm: Vec<Index>,
    nd_perm_inv: Vec<Index>,
    jt: Transpose,
    pattern: NormalPattern,
    symbolic: Option<SymbolicCholesky<Index>>,
    // The multifrontal factorization of a supernodal `symbolic` (crate::frontal).
    frontal: Multifrontal,
    // Whether `frontal` holds the analysis of `symbolic` (else faer's own factorization).
    frontal_ready: bool,
    // The factorization in 2×2 blocks, used instead of faer's when the unknowns pair up and
    // the factor is thin (`blocked`).
    block: BlockCholesky,
    blocked: bool,
    // Multiply–adds per factor entry above which faer's supernodal factorization takes over
    // (`SUPERNODAL_FLOPS_PER_ENTRY`; a test lowers it to reach faer's on a small crush).
    supernodal_flops_per_entry: u64,
    side: Side,
    counts: FactorizationCounts,
    times: StageTimes,
    h: Vec<f64>,
    l: Vec<f64>,
    mem: Scratch,
    // AMD's workspace
    amd_mem: AmdScratch,
    // Whether the ordering starts from the last analysis's (crate::reorder), that analysis,
    // and the ordering of the groups it found dirty.
    keep_orderings: bool,
    kept: KeptOrdering,
    dirty_perm: Vec<Index>,
    dirty_perm_inv: Vec<Index>,
    // The right-hand side in the factor's order.
    x: Vec<f64>,
    // The supernodal solve's buffer (a supernode's rows), and its two threads' scratch for
    // a factor the multifrontal factorization split.
    solve_scratch: Vec<f64>,
    split_solve_scratch: supernodal::SplitScratch,
    // The row of an update, in the factor's order (left zero by each update).
    update_w: Vec<f64>,
    // The second thread of factorizations and solves in 2×2 blocks split in two, whether
    // the split pays here, and whether the last factorization was split.
    helper: Option<std::sync::Arc<Helper>>,
    split_choice: SplitChoice,
    last_split: bool,
}

/// Whether a factorization whose analysis found a split runs it, by measurement: what two
/// threads gain depends on how far apart the machine puts their cores (the factor's columns
/// cross between them): on this 2-core VM the split factorization and solves of the jammed
/// 2,000 took 0.72× one thread's time in one hour and 1.2× in another (benches/README.md,
/// session 16). Every [`Self::PROBE_EVERY`]-th analysis with a split is probed: its
/// factorizations go one thread, one thread, split, split; the first of each pair is not timed
/// (after an analysis, or after the other way, each thread finds the columns it writes in the
/// other's cache), the second ones are, and the ratio of their times (the same pattern, so the
/// same work), averaged over the probes, decides every other factorization (the split until
/// a probe has finished). A probe a new analysis interrupts is dropped. The answers are the
/// same bits either way.
#[derive(Debug, Default)]
struct SplitChoice {
    // Split over one thread, averaged over the probes (0: none yet).
    ratio: f64,
    analyses: u64,
    probe: Probe,
}

/// Where a probe of [`SplitChoice`] stands: which factorization comes next.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
enum Probe {
    #[default]
    Off,
    // One thread, not timed.
    Start,
    // One thread, timed.
    One,
    // Split, not timed (after one thread's seconds).
    ToSplit(f64),
    // Split, timed.
    Split(f64),
}

impl SplitChoice {
    const PROBE_EVERY: u64 = 8;

    /// A new analysis with a split.
    fn analysed(&mut self) {
        self.probe = if self.analyses.is_multiple_of(Self::PROBE_EVERY) {
            Probe::Start
        } else {
            Probe::Off
        };
        self.analyses += 1;
    }

    fn split_now(&self) -> bool {
        match self.probe {
            Probe::Start | Probe::One => false,
            Probe::ToSplit(_) | Probe::Split(_) => true,
            Probe::Off => self.ratio < 1.0,
        }
    }

    fn record(&mut self, seconds: f64) {
        self.probe = match self.probe {
            Probe::Off => Probe::Off,
            Probe::Start => Probe::One,
            Probe::One => Probe::ToSplit(seconds),
            Probe::ToSplit(one) => Probe::Split(one),
            Probe::Split(one) => {
                let r = seconds / one;
                self.ratio = if self.ratio == 0.0 {
                    r
                } else {
                    0.75 * self.ratio + 0.25 * r
                };
                Probe::Off
            }
        };
    }
}

impl NormalEquations {
    /// Nothing analysed yet; factorizations and loops on `parallelism` threads.
    pub(crate) fn new(parallelism: Parallelism) -> Result<Self, SolveError> {
        Ok(Self {
            parallelism,
            workers: Workers::new(parallelism)?,
            j_row_start: Vec::new(),
            j_cols: Vec::new(),
            natural: NormalPattern::default(),
            perm: Vec::new(),
            perm_inv: Vec::new(),
            group_of: Vec::new(),
            group_start: Vec::new(),
            group_perm: Vec::new(),
            group_perm_inv: Vec::new(),
            dissection: Dissection::default(),
            fill: FillCount::default(),
            nd_perm: Vec::new(),
            nd_perm_inv: Vec::new(),
            jt: Transpose::default(),
            pattern: NormalPattern::default(),
            symbolic: None,
            frontal: Multifrontal::default(),
            frontal_ready: false,
            block: BlockCholesky::default(),
            blocked: false,
            supernodal_flops_per_entry: SUPERNODAL_FLOPS_PER_ENTRY,
            side: Side::Upper,
            counts: FactorizationCounts::default(),
            times: StageTimes::default(),
            h: Vec::new(),
            l: Vec::new(),
            mem: Scratch(MemBuffer::new(StackReq::EMPTY)),
            amd_mem: AmdScratch::default(),
            keep_orderings: false,
            kept: KeptOrdering::default(),
            dirty_perm: Vec::new(),
            dirty_perm_inv: Vec::new(),
            x: Vec::new(),
            solve_scratch: Vec::new(),
            split_solve_scratch: supernodal::SplitScratch::default(),
            update_w: Vec::new(),
            helper: None,
            split_choice: SplitChoice::default(),
            last_split: false,
        })
    }

    /// From the next analysis on, factorizations and triangular solves in 2×2 blocks, and
    /// multifrontal factorizations of faer's supernodal factors and their solves, run on two
    /// threads where the
    /// elimination tree splits in two parts that pay (the shared helper thread,
    /// [`Helper::shared`], for the second part, when no other job holds it; the same bits as
    /// on one thread). Without a thread to be had, nothing changes.
    pub(crate) fn split_over_two_threads(&mut self) {
        if self.helper.is_none() {
            self.helper = Helper::shared();
        }
    }

    /// From the next analysis on, each ordering starts from the last analysis's where the
    /// unknowns pair up (crate::reorder): the groups whose rows are the last analysis's keep
    /// their places. The orderings then depend on the analyses before, which the caller must
    /// keep with its state ([`Self::kept_memory`], [`Self::set_kept_memory`]).
    pub(crate) fn keep_orderings(&mut self) {
        self.keep_orderings = true;
    }

    /// What the next ordering depends on besides `J` ([`Self::keep_orderings`]): the last
    /// analysis's ordering, with a hash of its structure, and the analysis kept for the next
    /// ordering, as numbers appended to `out` (`KeptOrdering::memory`).
    pub(crate) fn kept_memory(&self, out: &mut Vec<f64>) {
        let analysed = self.symbolic.is_some() || self.blocked;
        let last = analysed.then(|| {
            let hash = structure_hash(&self.j_row_start, &self.j_cols);
            (hash, &self.group_perm[..])
        });
        self.kept.memory(last, out);
    }

    /// Whether the orderings depend on the analyses before ([`Self::keep_orderings`]).
    pub(crate) fn keeps_orderings(&self) -> bool {
        self.keep_orderings
    }

    /// Takes what [`Self::kept_memory`] gave at the start of `memory` and returns the rest;
    /// `None`, with nothing kept, when it is not one. With `memory` empty, nothing is kept.
    pub(crate) fn set_kept_memory<'a>(&mut self, memory: &'a [f64]) -> Option<&'a [f64]> {
        if memory.is_empty() {
            self.kept = KeptOrdering::default();
            return Some(memory);
        }
        self.kept.set_memory(memory)
    }

    /// The workers the factorizations run on.
    pub(crate) fn workers(&self) -> &Workers {
        &self.workers
    }

    /// The structure of `Jᵀ` of the last analysis (valid after [`Self::analyse`]).
    pub(crate) fn transpose(&self) -> &Transpose {
        &self.jt
    }

    /// Patterns, analyses and factorizations done so far.
    pub(crate) fn counts(&self) -> FactorizationCounts {
        self.counts
    }

    /// Seconds spent so far, per stage.
    pub(crate) fn times(&self) -> StageTimes {
        // The count is the factorization counts' own (one counter, read here).
        StageTimes {
            factorizations: self.counts.factorizations,
            ..self.times
        }
    }

    fn par(&self) -> Par {
        if self.workers.is_sequential() {
            Par::Seq
        } else {
            Par::rayon(self.parallelism.get())
        }
    }

    /// Makes the ordering, the pattern and the symbolic analysis fit `j`; nothing is redone
    /// while the columns of `j`'s rows stay the same. True when they were redone.
    pub(crate) fn analyse(&mut self, j: &ConstraintRows) -> Result<bool, SolveError> {
        let mut acc = self.times.analyse;
        let r = timed(&mut acc, || self.analyse_untimed(j));
        self.times.analyse = acc;
        r
    }

    fn analyse_untimed(&mut self, j: &ConstraintRows) -> Result<bool, SolveError> {
        let same = |kept: &[Index], now: &[usize]| {
            kept.len() == now.len() && kept.iter().zip(now).all(|(&a, &b)| a as usize == b)
        };
        if (self.symbolic.is_some() || self.blocked)
            && self.pattern.n == j.dim()
            && same(&self.j_row_start, j.row_starts())
            && same(&self.j_cols, j.columns())
        {
            self.jt.refresh(j);
            return Ok(false);
        }
        let n = j.dim();
        let starts = j.row_starts();
        let products: usize = n
            + (0..j.len())
                .map(|i| {
                    let k = starts[i + 1] - starts[i];
                    k * (k + 1) / 2
                })
                .sum::<usize>();
        if products.max(j.nnz()) > Index::MAX as usize {
            return Err(SolveError::Factorization(format!(
                "{products} products in I + JᵀDJ: more than 32-bit indices hold"
            )));
        }
        // The structure analysed, in 32-bit indices (every product, so every column and row
        // start, fits: checked above). Until the analysis below succeeds there is none: a
        // failed one must not leave the previous one standing for this structure.
        self.symbolic = None;
        self.frontal_ready = false;
        self.blocked = false;
        self.j_row_start.clear();
        self.j_row_start.extend(starts.iter().map(|&s| s as Index));
        self.j_cols.clear();
        self.j_cols.extend(j.columns().iter().map(|&c| c as Index));

        // Fill-reducing ordering (AMD) of the pattern compressed to groups of adjacent
        // unknowns that appear in the same rows (a disk's x and y): a quarter of the entries.
        self.jt.build(j);
        let groups = column_groups(&self.jt, &mut self.group_of);
        self.group_perm.clear();
        self.group_perm.resize(groups, 0);
        self.group_perm_inv.clear();
        self.group_perm_inv.resize(groups, 0);
        // A solver restored from a memory orders the structure the original analysed last as
        // the original did (which analysed nothing again); otherwise the groups whose rows are
        // the last analysis's keep their places (crate::reorder) and the rest are ordered on
        // the graph they leave, or all are ordered afresh.
        let restored = self.kept.take_restored().filter(|(hash, order)| {
            order.len() == groups && *hash == structure_hash(&self.j_row_start, &self.j_cols)
        });
        let reused = restored.is_some();
        let dirty = if self.keep_orderings && !reused {
            let most = (KeptOrdering::MAX_DIRTY_SHARE * groups as f64) as usize;
            self.kept.dirty_graph(j, &self.group_of, groups, most)
        } else {
            None
        };
        let fresh = dirty.is_none();
        if let Some((_, order)) = restored {
            for (k, &g) in order.iter().enumerate() {
                self.group_perm[k] = g;
                self.group_perm_inv[g as usize] = k as Index;
            }
        } else if let Some(d) = dirty {
            self.dirty_perm.clear();
            self.dirty_perm.resize(d, 0);
            self.dirty_perm_inv.clear();
            self.dirty_perm_inv.resize(d, 0);
            if d > 0 {
                let graph = &mut self.natural;
                sorted_columns(
                    d,
                    self.kept.pairs(),
                    (&mut graph.count, &mut graph.fill),
                    &mut graph.col_ptr,
                    &mut graph.row_idx,
                );
                graph.n = d;
                self.amd_mem
                    .order(&mut self.dirty_perm, &mut self.dirty_perm_inv, graph)?;
            }
            self.kept.ordering(
                &self.dirty_perm,
                &mut self.group_perm,
                &mut self.group_perm_inv,
            );
        } else {
            // The upper triangle, its rows sorted and without repeats: what faer's AMD makes
            // of any input first (`order_maybe_unsorted`), so `order` takes it as it is.
            self.natural
                .build(j, Some((&self.group_of, groups)), true, false);
            self.amd_mem.order(
                &mut self.group_perm,
                &mut self.group_perm_inv,
                &self.natural,
            )?;
        }
        // (Kept again below where the analysis is one in 2×2 blocks; a restored ordering
        // leaves the restored analysis as the original's.)
        if !reused {
            self.kept.forget();
        }
        // A large pattern whose minimum-degree factor is dense (a crush: wide fronts) is also
        // ordered by nested dissection, and the ordering whose factor costs fewer multiply–adds
        // is kept. Its count is exact for the 2×2 blocks when every group is a pair.
        let mut fill = None;
        if groups >= DISSECTION_MIN_GROUPS {
            self.natural
                .build(j, Some((&self.group_of, groups)), false, false);
            let natural = self.natural.symbolic();
            let (mut products, mut entries) = self.fill.count(natural, &self.group_perm_inv);
            // (A restored ordering is the one the original chose.)
            if !reused && products >= DISSECTION_MIN_PRODUCTS_PER_ENTRY * entries {
                self.nd_perm.clear();
                self.nd_perm.resize(groups, 0);
                self.nd_perm_inv.clear();
                self.nd_perm_inv.resize(groups, 0);
                self.dissection
                    .order(natural, &mut self.nd_perm, &mut self.nd_perm_inv)?;
                let (p, e) = self.fill.count(natural, &self.nd_perm_inv);
                if p < products {
                    std::mem::swap(&mut self.nd_perm, &mut self.group_perm);
                    std::mem::swap(&mut self.nd_perm_inv, &mut self.group_perm_inv);
                    (products, entries) = (p, e);
                    self.counts.dissections += 1;
                }
            }
            fill = Some((products, entries));
        }
        // Expand: the groups in their order, each group's unknowns in theirs.
        self.group_start.clear();
        self.group_start.resize(groups + 1, 0);
        for &g in &self.group_of {
            self.group_start[g + 1] += 1;
        }
        for g in 0..groups {
            self.group_start[g + 1] += self.group_start[g];
        }
        self.perm.clear();
        for &g in &self.group_perm {
            let g = g as usize;
            self.perm
                .extend(self.group_start[g]..self.group_start[g + 1]);
        }
        self.perm_inv.clear();
        self.perm_inv.resize(n, 0);
        for (k, &c) in self.perm.iter().enumerate() {
            self.perm_inv[c] = k;
        }

        // Unknowns in pairs (a disk's x and y: groups of even size, so every pair 2k, 2k + 1
        // shares its rows): the factorization in 2×2 blocks, unless the factor is so dense
        // that faer's supernodal one wins.
        // The blocks' own analysis is skipped when the count above already says their factor
        // is too dense (groups all pairs: group columns are block columns).
        let pairs = self.group_start.windows(2).all(|w| w[1] - w[0] == 2);
        let threshold = self.supernodal_flops_per_entry;
        let dense = |(products, entries): (u64, u64)| 8 * products > threshold * 4 * entries;
        let known_dense = pairs && fill.is_some_and(dense);
        if known_dense {
            self.block = BlockCholesky::default();
        }
        let even = self.group_start.windows(2).all(|w| (w[1] - w[0]) % 2 == 0);
        let blocks = if !known_dense && even {
            self.pattern
                .build_blocks(j, &self.perm_inv, n, self.block.take_pattern())
        } else {
            None
        };
        if let Some(blocks) = blocks {
            let a_blocks = blocks.row.len();
            self.block.analyse(blocks, self.helper.is_some());
            if self.keep_orderings && pairs && !reused {
                let block = &self.block;
                self.kept.keep(
                    j,
                    &self.group_of,
                    &self.group_perm_inv,
                    |k| block.parent(k),
                    fresh,
                );
            }
            if self.block.is_split() {
                self.split_choice.analysed();
            }
            let products = self.block.factor_block_products();
            let blocks = self.block.factor_blocks() as u64;
            // faer's measure, multiply–adds per factor entry, in scalar equivalents.
            if !dense((products, blocks)) {
                self.blocked = true;
                self.mem = Scratch(MemBuffer::new(StackReq::EMPTY));
                self.l = Vec::new();
                self.h = Vec::new();
                // Scalar equivalents: a block column of c blocks is two columns of 2c
                // and 2c − 1 entries, 4c² multiply–adds.
                self.counts.factor_nnz = (4 * blocks - (n / 2) as u64) as usize;
                self.counts.factor_flops = 8 * products - 4 * blocks;
                self.counts.matrix_nnz = 4 * a_blocks - n / 2;
                self.counts.analyses += 1;
                return Ok(true);
            }
            self.block = BlockCholesky::default();
        }

        // The permuted upper triangle: faer's simplicial factorization reads it without a
        // copy (and its symbolic analysis without an ordering reads the upper triangle).
        // The supernodal variant measured slower on crowds (benches/README.md): their
        // factors are thin, 2×2-blocked and have few wide supernodes.
        self.pattern.build(j, Some((&self.perm_inv, n)), true, true);
        let symbolic = factorize_symbolic_cholesky(
            self.pattern.symbolic(),
            Side::Upper,
            SymmetricOrdering::Identity,
            CholeskySymbolicParams {
                // faer's rule (supernodal when flops per factor entry are many): it picks
                // simplicial on these crowds, 1.6× faster than supernodal at 40,000 people,
                // 1.5× slower on a fully jammed 1,000 (benches/README.md).
                supernodal_flop_ratio_threshold: SupernodalThreshold::AUTO,
                ..Default::default()
            },
        )
        .map_err(|e| SolveError::Factorization(format!("{e:?}")))?;
        self.side = match symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(_) => Side::Upper,
            SymbolicCholeskyRaw::Supernodal(_) => {
                self.pattern
                    .build(j, Some((&self.perm_inv, n)), false, true);
                Side::Lower
            }
        };
        // A supernodal factor is factorized and solved by our own (crate::frontal, with its own
        // scratch, and crate::supernodal); faer's scratch only for faer's.
        self.frontal_ready = match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(s) => self.frontal.analyse(s),
            SymbolicCholeskyRaw::Simplicial(_) => false,
        };
        let req = if self.frontal_ready {
            StackReq::EMPTY
        } else {
            let par = self.par();
            StackReq::any_of(&[
                symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
                symbolic.solve_in_place_scratch::<f64>(1, par),
            ])
        };
        self.mem = Scratch(MemBuffer::new(req));
        self.l.clear();
        self.l.resize(symbolic.len_val(), 0.0);
        self.counts.factor_nnz = symbolic.len_val();
        self.counts.factor_flops = match symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => s
                .col_ptr()
                .windows(2)
                .map(|w| {
                    let c = (w[1] - w[0]) as u64;
                    c * (c + 1) / 2
                })
                .sum(),
            // Supernode by supernode: columns × rows of each, a dense trapezoid.
            SymbolicCholeskyRaw::Supernodal(s) => {
                let (begin, end) = (s.supernode_begin(), s.supernode_end());
                let rows = s.col_ptr_for_row_idx();
                (0..s.n_supernodes())
                    .map(|k| {
                        let width = (end[k] - begin[k]) as u64;
                        let below = (rows[k + 1] - rows[k]) as u64;
                        (0..width)
                            .map(|c| {
                                let h = width - c + below;
                                h * (h + 1) / 2
                            })
                            .sum::<u64>()
                    })
                    .sum()
            }
        };
        self.counts.matrix_nnz = self.pattern.row_idx.len();
        self.symbolic = Some(symbolic);
        self.counts.analyses += 1;
        Ok(true)
    }

    /// Factorizes `shift·I + Jᵀ diag(d) J` (after [`Self::analyse`] of the same `j`); false
    /// when it is not numerically positive definite.
    pub(crate) fn factorize(&mut self, j: &ConstraintRows, shift: f64, d: &[f64]) -> bool {
        if self.blocked {
            // The blocks of `A` are added column by column as the factorization reaches them:
            // no assembled copy of `A`.
            let clock = Instant::now();
            self.counts.factorizations += 1;
            self.counts.block_factorizations += 1;
            let columns = NormalColumns {
                pattern: &self.pattern,
                coefs: j.coefficients(),
                shift,
                d,
            };
            // (While another job holds the helper, one thread, and no probe recorded.)
            let held = self.helper.as_ref().is_some_and(|h| h.is_held());
            let split = self.helper.is_some()
                && self.block.is_split()
                && self.split_choice.split_now()
                && !held;
            let ok = match &self.helper {
                Some(helper) if split => {
                    self.counts.split_factorizations += 1;
                    self.block.factorize_columns_split(&columns, helper)
                }
                Some(_) | None => self.block.factorize_columns(&columns),
            };
            let seconds = clock.elapsed().as_secs_f64();
            self.times.factorize += seconds;
            if self.helper.is_some() && self.block.is_split() && ok && !held {
                self.split_choice.record(seconds);
            }
            self.last_split = split;
            return ok;
        }
        let clock = Instant::now();
        self.pattern.assemble(j, shift, d, &mut self.h);
        let par = self.par();
        let symbolic = self.symbolic.as_ref().expect("analysed");
        let a = SparseColMatRef::new(self.pattern.symbolic(), &self.h);
        self.counts.factorizations += 1;
        let (l, side, mem) = (&mut self.l, self.side, &mut self.mem.0);
        if let (true, SymbolicCholeskyRaw::Supernodal(s)) = (self.frontal_ready, symbolic.raw()) {
            // A crush's factor: multifrontal, its two halves at once where the helper thread
            // is there and free.
            let helper = self.helper.as_deref().filter(|h| !h.is_held());
            let ok = self.frontal.factorize(s, a, l, helper);
            self.times.factorize += clock.elapsed().as_secs_f64();
            return ok;
        }
        let ok = self.workers.install(|| {
            symbolic
                .factorize_numeric_llt(
                    l,
                    a,
                    side,
                    LltRegularization::default(),
                    par,
                    MemStack::new(mem),
                    Default::default(),
                )
                .is_ok()
        });
        self.times.factorize += clock.elapsed().as_secs_f64();
        ok
    }

    /// The last factorization changed to that of the same matrix with row `i`'s weight
    /// `d_i` moved by `delta` (a rank-one update, or a downdate when `delta < 0`), in 2×2
    /// blocks only. False when the factor is not in blocks or a downdate left a pivot that
    /// is not positive (factorize again then).
    pub(crate) fn update_row(&mut self, j: &ConstraintRows, i: usize, delta: f64) -> bool {
        if !self.blocked || delta == 0.0 {
            return self.blocked;
        }
        let clock = Instant::now();
        let n = self.pattern.n;
        self.update_w.resize(n, 0.0);
        let scale = delta.abs().sqrt();
        let coefs = j.coefficients();
        let p = &self.pattern;
        let range = p.row_entry_start[i] as usize..p.row_entry_start[i + 1] as usize;
        let mut first = usize::MAX;
        for &[q, p0, p1] in &p.row_entries[range] {
            let q = q as usize;
            self.update_w[2 * q] = scale * coefs[p0 as usize];
            self.update_w[2 * q + 1] = scale * coefs[p1 as usize];
            first = first.min(q);
        }
        self.counts.updates += 1;
        let ok =
            first == usize::MAX || self.block.update(&mut self.update_w, first, delta.signum());
        if !ok {
            self.update_w.iter_mut().for_each(|x| *x = 0.0);
        }
        self.times.factorize += clock.elapsed().as_secs_f64();
        ok
    }

    /// Overwrites `rhs` (in the unknowns' natural order) by the solution of the last
    /// factorized system: permuted into the factor's order, two triangular solves, permuted
    /// back.
    pub(crate) fn solve_in_place(&mut self, rhs: &mut [f64]) {
        let n = rhs.len();
        self.x.resize(n, 0.0);
        let w = &self.workers;
        {
            let (r, perm): (&[f64], _) = (rhs, &self.perm);
            w.map(&mut self.x, |k, _| r[perm[k]]);
        }
        let clock = Instant::now();
        if self.blocked {
            // (The solves go the way the factorization went: each thread then reads the
            // columns it wrote.)
            match &self.helper {
                Some(helper) if self.last_split => {
                    self.block.solve_in_place_split(&mut self.x, helper)
                }
                Some(_) | None => self.block.solve_in_place(&mut self.x),
            }
        } else {
            let par = self.par();
            let symbolic = self.symbolic.as_ref().expect("analysed");
            let (l, x, mem) = (&self.l, &mut self.x, &mut self.mem.0);
            match symbolic.raw() {
                // A supernodal factor is a crush's, far larger than the caches: our solve reads
                // it at the memory's rate (crate::supernodal).
                SymbolicCholeskyRaw::Supernodal(s) => match (&self.helper, self.frontal.split()) {
                    (Some(helper), Some(split)) if self.frontal_ready && !helper.is_held() => {
                        let scratch = &mut self.split_solve_scratch;
                        supernodal::solve_in_place_split(s, l, x, split, scratch, helper)
                    }
                    _ => supernodal::solve_in_place(s, l, x, &mut self.solve_scratch),
                },
                SymbolicCholeskyRaw::Simplicial(_) => w.install(|| {
                    LltRef::new(symbolic, l).solve_in_place_with_conj(
                        Conj::No,
                        MatMut::from_column_major_slice_mut(x, n, 1),
                        par,
                        MemStack::new(mem),
                    )
                }),
            }
        }
        self.times.factorize += clock.elapsed().as_secs_f64();
        let (x, perm_inv) = (&self.x, &self.perm_inv);
        w.map(rhs, |c, _| x[perm_inv[c]]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The split runs where its probes measured it faster, one thread where they measured it
    /// slower; a probe is four factorizations of one analysis (one thread twice, split twice,
    /// the second of each timed), dropped when a new analysis interrupts it.
    #[test]
    fn the_split_goes_the_way_its_probes_measured_faster() {
        // `seconds(split)` for every factorization over `analyses` analyses of `per` each;
        // the ways taken.
        let run = |choice: &mut SplitChoice,
                   analyses: usize,
                   per: usize,
                   seconds: &dyn Fn(bool) -> f64| {
            let mut ways = Vec::new();
            for _ in 0..analyses {
                choice.analysed();
                for _ in 0..per {
                    let split = choice.split_now();
                    choice.record(seconds(split));
                    ways.push(split);
                }
            }
            ways
        };
        let mut fast = SplitChoice::default();
        let ways = run(&mut fast, 8, 6, &|split| if split { 0.6 } else { 1.0 });
        assert_eq!(&ways[..6], &[false, false, true, true, true, true]);
        assert!((fast.ratio - 0.6).abs() < 1e-12, "{fast:?}");
        assert!(ways[6..].iter().all(|&s| s));
        // The next probe (the ninth analysis) measures one thread again.
        let ways = run(&mut fast, 1, 4, &|split| if split { 0.6 } else { 1.0 });
        assert_eq!(ways, [false, false, true, true]);

        let mut slow = SplitChoice::default();
        let ways = run(&mut slow, 8, 6, &|split| if split { 1.3 } else { 1.0 });
        assert_eq!(&ways[..6], &[false, false, true, true, false, false]);
        assert!(ways[6..].iter().all(|&s| !s));
        // A machine that changes: the probes' average follows it.
        let ways = run(&mut slow, 64, 6, &|split| if split { 0.5 } else { 1.0 });
        assert!(slow.ratio < 1.0 && ways.last() == Some(&true), "{slow:?}");

        // Analyses of three factorizations: every eighth starts a probe, which the next one
        // drops; meanwhile (no ratio measured) the split is taken.
        let mut short = SplitChoice::default();
        let ways = run(&mut short, 16, 3, &|_| 1.0);
        assert_eq!(short.ratio, 0.0);
        for (a, c) in ways.chunks(3).enumerate() {
            let expected = if a % 8 == 0 {
                [false, false, true]
            } else {
                [true; 3]
            };
            assert_eq!(c, expected, "analysis {a}");
        }
    }

    /// `shift·I + Jᵀ diag(d) J` dense.
    fn dense(j: &ConstraintRows, shift: f64, d: &[f64]) -> Vec<Vec<f64>> {
        let n = j.dim();
        let mut a = vec![vec![0.0; n]; n];
        for (c, row) in a.iter_mut().enumerate() {
            row[c] = shift;
        }
        for (i, &di) in d.iter().enumerate() {
            let (cols, coefs) = j.row(i);
            for (&ca, &xa) in cols.iter().zip(coefs) {
                for (&cb, &xb) in cols.iter().zip(coefs) {
                    a[ca][cb] += di * xa * xb;
                }
            }
        }
        a
    }

    /// Contacts between `people` disks (unknowns `2p, 2p + 1`) and, when `lone`, one more
    /// unknown that only one row touches (so the unknowns do not pair up).
    fn contacts(rng: &mut ChaCha8Rng, people: usize, rows: usize, lone: bool) -> ConstraintRows {
        let n = 2 * people + usize::from(lone);
        let mut j = ConstraintRows::new(n);
        for i in 0..rows {
            let a = rng.random_range(0..people);
            let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let (nx, ny) = (angle.cos(), angle.sin());
            if rng.random_bool(0.2) {
                // a wall
                j.push(i as u64, 0.0, [(2 * a, nx), (2 * a + 1, ny)]);
            } else {
                let b = (a + rng.random_range(1..people.max(2))) % people;
                let (lo, hi) = (a.min(b), a.max(b));
                if lo == hi {
                    continue;
                }
                j.push(
                    i as u64,
                    0.0,
                    [
                        (2 * lo, -nx),
                        (2 * lo + 1, -ny),
                        (2 * hi, nx),
                        (2 * hi + 1, ny),
                    ],
                );
            }
        }
        if lone {
            j.push(rows as u64, 0.0, [(0, 1.0), (n - 1, -2.0)]);
        }
        j
    }

    #[test]
    fn the_blocked_and_the_scalar_factorizations_solve_the_normal_equations() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for case in 0..30 {
            let people = rng.random_range(1..40);
            let rows = rng.random_range(0..4 * people);
            let lone = case % 3 == 2;
            let j = contacts(&mut rng, people, rows, lone);
            let d: Vec<f64> = (0..j.len())
                .map(|_| {
                    if rng.random_bool(0.2) {
                        0.0
                    } else {
                        rng.random_range(0.0..1e3)
                    }
                })
                .collect();
            let shift = rng.random_range(0.5..2.0);
            let b: Vec<f64> = (0..j.dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut ne = NormalEquations::new(Parallelism::SEQUENTIAL).unwrap();
            ne.analyse(&j).unwrap();
            assert!(ne.factorize(&j, shift, &d));
            let mut x = b.clone();
            ne.solve_in_place(&mut x);
            // The pairs go to the 2×2 blocks, the lone unknown to faer.
            assert_eq!(
                ne.counts().block_factorizations,
                usize::from(!lone),
                "case {case}"
            );
            let a = dense(&j, shift, &d);
            let scale = 1.0 + d.iter().fold(0.0f64, |m, &v| m.max(v)) * 4.0;
            for (r, row) in a.iter().enumerate() {
                let ax: f64 = row.iter().zip(&x).map(|(a, x)| a * x).sum();
                assert!(
                    (ax - b[r]).abs() <= 1e-11 * scale,
                    "case {case} row {r}: {ax} against {}",
                    b[r]
                );
            }
        }
    }

    /// The orderings kept from analysis to analysis (crate::reorder) on a wandering crowd: the
    /// groups found clean keep their places relative to each other and their old column of
    /// `L` exactly (the same people in it), the dirty ones are ordered afresh, every ordering
    /// is a permutation and solves the normal equations; every so often the ordering is a
    /// fresh one.
    #[test]
    fn kept_orderings_give_the_clean_groups_their_old_fill_and_solve() {
        let crowd = crate::reorder::wandering_crowd(150, 40, 0.01, 7);
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut ne = NormalEquations::new(Parallelism::SEQUENTIAL).unwrap();
        ne.keep_orderings();
        // Each person's place and column of L (as people), from the last analysis.
        let mut last: Option<(Vec<Index>, Vec<Vec<Index>>)> = None;
        let (mut kept, mut fresh, mut clean) = (0, 0, 0);
        for (step, (j, _, _)) in crowd.iter().enumerate() {
            // (Steps whose rows are the last step's are not analysed again.)
            let analysed = ne.analyse(j).unwrap();
            assert!(ne.blocked, "step {step}");
            let people = j.dim() / 2;
            let mut sorted = ne.group_perm.clone();
            sorted.sort_unstable();
            assert!(sorted.iter().enumerate().all(|(k, &g)| g as usize == k));
            let place = ne.group_perm_inv.clone();
            let columns: Vec<Vec<Index>> = (0..people)
                .map(|p| {
                    let column = ne.block.column(place[p] as usize);
                    let mut who: Vec<Index> =
                        column.iter().map(|&r| ne.group_perm[r as usize]).collect();
                    who.sort_unstable();
                    who
                })
                .collect();
            if !analysed {
                assert_eq!(Some(&place), last.as_ref().map(|l| &l.0), "step {step}");
            } else if ne.kept.since_fresh() == 0 {
                fresh += 1;
            } else {
                kept += 1;
                let (old_place, old_columns) =
                    last.as_ref().expect("a kept ordering has a last one");
                let dirty: std::collections::HashSet<Index> =
                    ne.kept.dirty().iter().copied().collect();
                let clean_people: Vec<usize> = (0..people)
                    .filter(|&p| !dirty.contains(&(p as Index)))
                    .collect();
                clean += clean_people.len();
                for &p in &clean_people {
                    assert_eq!(
                        columns[p], old_columns[p],
                        "step {step}: person {p}'s column of L"
                    );
                    for &q in &clean_people {
                        assert_eq!(
                            place[p] < place[q],
                            old_place[p] < old_place[q],
                            "step {step}: people {p} and {q}"
                        );
                    }
                }
                // Clean first, in their old order; then the dirty ones.
                assert!(
                    clean_people
                        .iter()
                        .all(|&p| (place[p] as usize) < clean_people.len())
                );
            }
            let d: Vec<f64> = (0..j.len()).map(|_| rng.random_range(0.0..1e3)).collect();
            let b: Vec<f64> = (0..j.dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
            assert!(ne.factorize(j, 1.0, &d), "step {step}");
            let mut x = b.clone();
            ne.solve_in_place(&mut x);
            for (r, row) in dense(j, 1.0, &d).iter().enumerate() {
                let ax: f64 = row.iter().zip(&x).map(|(a, x)| a * x).sum();
                assert!(
                    (ax - b[r]).abs() <= 1e-8,
                    "step {step} row {r}: {ax} against {}",
                    b[r]
                );
            }
            last = Some((place, columns));
        }
        // Most analyses start from the last one, a fresh one every `FRESH_EVERY`, and most
        // people keep their places.
        assert!(fresh >= 3 && kept >= 30, "{fresh} fresh, {kept} kept");
        assert!(
            clean >= kept * 150 / 2,
            "{clean} clean over {kept} kept orderings"
        );
    }

    #[test]
    fn rows_with_their_columns_in_any_order_or_repeated_are_solved() {
        // The 2×2 blocks find each coefficient by its unknown, whatever the order of a row's
        // columns; a column repeated in a row (its coefficients add up) goes to faer.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for repeated in [false, true] {
            let people = 12;
            let mut j = ConstraintRows::new(2 * people);
            for i in 0..30u64 {
                let a = rng.random_range(0..people - 1);
                let b = rng.random_range(a + 1..people);
                let mut row = vec![
                    (2 * a, rng.random_range(-1.0..1.0)),
                    (2 * a + 1, rng.random_range(-1.0..1.0)),
                    (2 * b, rng.random_range(-1.0..1.0)),
                    (2 * b + 1, rng.random_range(-1.0..1.0)),
                ];
                row.swap(rng.random_range(0..4), rng.random_range(0..4));
                row.swap(0, 3);
                if repeated && i == 7 {
                    row.push((2 * a, 0.5));
                }
                j.push(i, 0.0, row);
            }
            let d: Vec<f64> = (0..j.len()).map(|_| rng.random_range(0.0..10.0)).collect();
            let b: Vec<f64> = (0..j.dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut ne = NormalEquations::new(Parallelism::SEQUENTIAL).unwrap();
            ne.analyse(&j).unwrap();
            assert!(ne.factorize(&j, 1.0, &d));
            assert_eq!(ne.counts().block_factorizations, usize::from(!repeated));
            let mut x = b.clone();
            ne.solve_in_place(&mut x);
            for (r, row) in dense(&j, 1.0, &d).iter().enumerate() {
                let ax: f64 = row.iter().zip(&x).map(|(a, x)| a * x).sum();
                assert!((ax - b[r]).abs() <= 1e-10, "row {r}: {ax} against {}", b[r]);
            }
        }
    }

    #[test]
    fn a_crush_is_ordered_by_nested_dissection_and_solved() {
        // 10,000 disks in a hexagonal packing, each row a contact between neighbours: the
        // minimum-degree factor is dense, nested dissection's has fewer multiply–adds
        // (dissection.rs); the 2×2 blocks solve the system (63 multiply–adds an entry), and
        // so does the supernodal path (faer's symbolic factor, the multifrontal factorization
        // and our supernodal solve) where its threshold is lower.
        let side = 100;
        let at = |r: usize, c: usize| r * side + c;
        let mut j = ConstraintRows::new(2 * side * side);
        let mut contact = |a: usize, b: usize, (nx, ny): (f64, f64)| {
            let key = j.len() as u64;
            j.push(
                key,
                0.0,
                [(2 * a, -nx), (2 * a + 1, -ny), (2 * b, nx), (2 * b + 1, ny)],
            );
        };
        let h = 3f64.sqrt() / 2.0;
        for r in 0..side {
            for c in 0..side {
                if c + 1 < side {
                    contact(at(r, c), at(r, c + 1), (1.0, 0.0));
                }
                if r + 1 < side {
                    let (right, left) = if r % 2 == 1 {
                        (c + 1, c)
                    } else {
                        (c, c.wrapping_sub(1))
                    };
                    if right < side {
                        contact(at(r, c), at(r + 1, right), (0.5, h));
                    }
                    if left < side {
                        contact(at(r, c), at(r + 1, left), (-0.5, h));
                    }
                }
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let d: Vec<f64> = (0..j.len()).map(|_| rng.random_range(0.0..1e4)).collect();
        let b: Vec<f64> = (0..j.dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let shift = 1.0;
        for (threshold, blocks) in [(SUPERNODAL_FLOPS_PER_ENTRY, 1), (40, 0)] {
            let mut ne = NormalEquations::new(Parallelism::SEQUENTIAL).unwrap();
            ne.supernodal_flops_per_entry = threshold;
            ne.analyse(&j).unwrap();
            assert!(ne.factorize(&j, shift, &d));
            let mut x = b.clone();
            ne.solve_in_place(&mut x);
            let counts = ne.counts();
            assert_eq!(
                (counts.dissections, counts.block_factorizations),
                (1, blocks),
                "threshold {threshold}"
            );
            // shift·x + Jᵀ D J x = b, row by row of J.
            let mut ax: Vec<f64> = x.iter().map(|v| shift * v).collect();
            for i in 0..j.len() {
                let (cols, coefs) = j.row(i);
                let jx: f64 = cols.iter().zip(coefs).map(|(&c, a)| a * x[c]).sum();
                for (&c, a) in cols.iter().zip(coefs) {
                    ax[c] += d[i] * a * jx;
                }
            }
            let worst = ax
                .iter()
                .zip(&b)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(worst <= 1e-8, "threshold {threshold}: residual {worst}");
        }
    }
}
