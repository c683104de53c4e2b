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

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::products::Index;
use moreau_core::Helper;

/// Block products (2×2) of a factorization below which it is not split over two threads:
/// a handoff costs about a microsecond, ~5,000 products about eight.
const SPLIT_MIN_PRODUCTS: u64 = 5_000;

/// A split is kept when its two threads' time (the larger part, then the rest) is at most this
/// fraction of one thread's, counted in block products (see `split_columns`).
const SPLIT_MAX_SHARE: f64 = 0.85;

/// The most columns of a supernode whose updates of a row's block the factorization gathers
/// in one pass (see `row_group`).
const MAX_GROUP: usize = 8;

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
    row_col: Vec<Index>,
    // Per entry of the row lists: how many entries from it on (at most `MAX_GROUP`) are
    // columns of one supernode, whose rest from that row on is the same rows (0 inside such
    // a run: read only at its start).
    row_group: Vec<u8>,
    values: Vec<Block>,
    work: Vec<Block>,
    // scratch of the analysis, kept from analysis to analysis
    mark: Vec<Index>,
    scratch: AnalysisScratch,
    // The columns in two parts for two threads, if the analysis was asked for one and found
    // it worth it, with the second thread's workspace.
    split: Option<Split>,
    work2: Vec<Block>,
}

/// The block columns in three parts: two unions of disjoint subtrees of the elimination tree
/// (factorized at once, each on its own thread: a column reads only its descendants) and the
/// rest, their ancestors (factorized after both). Each part lists its columns in increasing
/// order.
#[derive(Debug, Clone, Default)]
struct Split {
    part: Vec<u8>,
    cols: [Vec<Index>; 3],
}

/// The analysis's scratch: the elimination tree's children as linked lists, a column's
/// rows, the row lists' fill pointers, the split's subtree weights and frontier, and the
/// last split's lists when the last analysis made none.
#[derive(Debug, Clone, Default)]
struct AnalysisScratch {
    head: Vec<Index>,
    next: Vec<Index>,
    col: Vec<Index>,
    fill: Vec<Index>,
    entry_col: Vec<Index>,
    joins: Vec<bool>,
    weight: Vec<u64>,
    frontier: Vec<usize>,
    split: Split,
}

/// The rest's part number in [`Split::part`].
const REST: u8 = 2;

impl BlockCholesky {
    /// Analyses the pattern of `A` (block columns of its lower triangle, each with its
    /// diagonal block first and its rows increasing): the pattern of `L` by merging each
    /// column's children in the elimination tree, and the row lists the numeric
    /// factorization walks.
    ///
    /// With `split`, the columns are also divided for two threads where that pays
    /// ([`Self::is_split`]).
    pub(crate) fn analyse(&mut self, a: BlockPattern, split: bool) {
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
        let AnalysisScratch {
            head, next, col, ..
        } = &mut self.scratch;
        head.clear();
        head.resize(n, none);
        next.clear();
        next.resize(n, none);
        self.row_ptr.clear();
        self.row_ptr.resize(n + 1, 0);
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
            for &r in col.iter() {
                self.row_ptr[r as usize + 1] += 1;
            }
            l.row.push(k as Index);
            l.row.extend_from_slice(col);
            l.ptr.push(l.row.len() as Index);
            if let Some(&parent) = col.first() {
                let p = parent as usize;
                next[k] = head[p];
                head[p] = k as Index;
            }
        }
        // Row lists: for each row k, the positions of its off-diagonal blocks in increasing
        // column order (a counting sort of L's entries by row, counted as the columns were
        // made), and the runs of supernode columns in them (`row_group`).
        for k in 0..n {
            self.row_ptr[k + 1] += self.row_ptr[k];
        }
        let entries = self.row_ptr[n] as usize;
        self.row_pos.clear();
        self.row_pos.resize(entries, 0);
        self.row_end.clear();
        self.row_end.resize(entries, 0);
        self.row_group.clear();
        self.row_group.resize(entries, 0);
        // (The columns of the row lists' blocks only for a split's forward solve.)
        self.row_col.clear();
        let AnalysisScratch {
            fill,
            entry_col,
            joins,
            ..
        } = &mut self.scratch;
        // Column j and j + 1 are one supernode's when L(:, j) is j, then L(:, j + 1)'s rows:
        // in a row list they are neighbours, and their rest from that row on is the same rows.
        joins.clear();
        joins.extend((0..n).map(|j| {
            let c = l.col(j);
            j + 1 < n && c.len() == l.col(j + 1).len() + 1 && l.row[c.start + 1] as usize == j + 1
        }));
        fill.clear();
        fill.extend_from_slice(&self.row_ptr[..n]);
        entry_col.clear();
        entry_col.resize(entries, 0);
        // The entry where each row's current run starts.
        let run = &mut self.mark;
        for k in 0..n {
            let end = l.ptr[k + 1];
            for p in l.ptr[k] as usize + 1..end as usize {
                let r = l.row[p] as usize;
                let e = fill[r] as usize;
                fill[r] += 1;
                self.row_pos[e] = p as Index;
                self.row_end[e] = end;
                entry_col[e] = k as Index;
                let start = run[r] as usize;
                if e > self.row_ptr[r] as usize
                    && entry_col[e - 1] + 1 == k as Index
                    && joins[k - 1]
                    && (self.row_group[start] as usize) < MAX_GROUP
                {
                    self.row_group[start] += 1;
                } else {
                    run[r] = e as Index;
                    self.row_group[e] = 1;
                }
            }
        }
        if split {
            self.row_col.extend_from_slice(entry_col);
        }
        // (Every successful factorization writes every block of the factor, and nothing
        // reads one before: the storage is sized, not cleared.)
        self.values.resize(self.l.row.len(), [0.0; 4]);
        self.work.clear();
        self.work.resize(n, [0.0; 4]);
        if let Some(last) = self.split.take() {
            self.scratch.split = last;
        }
        self.split = if split { self.split_columns() } else { None };
        if self.split.is_some() {
            self.work2.clear();
            self.work2.resize(n, [0.0; 4]);
        } else {
            self.work2 = Vec::new();
        }
    }

    /// The analysed pattern of `A`, whose storage a new pattern may take (the analysis is
    /// then gone: analyse again before factorizing).
    pub(crate) fn take_pattern(&mut self) -> BlockPattern {
        std::mem::take(&mut self.a)
    }

    /// The parent of block column `k` in the last analysis's elimination tree (`None` at a
    /// root).
    pub(crate) fn parent(&self, k: usize) -> Option<usize> {
        let c = self.l.col(k);
        (c.len() > 1).then(|| self.l.row[c.start + 1] as usize)
    }

    /// The block rows of column `k` of `L` (its diagonal first).
    #[cfg(test)]
    pub(crate) fn column(&self, k: usize) -> &[Index] {
        &self.l.row[self.l.col(k)]
    }

    /// Whether the last analysis divided the columns for two threads.
    pub(crate) fn is_split(&self) -> bool {
        self.split.is_some()
    }

    /// The parts of [`Split`]: starting from the elimination tree's roots, the heaviest
    /// subtree is replaced by its children (its root joining the rest) while that helps, each
    /// time the subtrees dealt to two threads heaviest first, each to the lighter one; the
    /// best of at most 64 such steps, if worth it ([`SPLIT_MIN_PRODUCTS`],
    /// [`SPLIT_MAX_SHARE`]). A column weighs the block products it gathers in the left-looking
    /// factorization (the updates from its descendants) and its own blocks: counted so, the
    /// best split of cromosim's scene takes 0.69 of one thread's time and measured 0.74–0.76
    /// (counted as the products each column sends, 0.60: the updates a part's columns send
    /// to the rest are gathered by the rest).
    fn split_columns(&mut self) -> Option<Split> {
        const NONE: usize = usize::MAX;
        let l = &self.l;
        let n = l.columns();
        let parent = |k: usize| {
            let c = l.col(k);
            if c.len() > 1 {
                l.row[c.start + 1] as usize
            } else {
                NONE
            }
        };
        // A column's work in the left-looking factorization: the updates it gathers (each the
        // rest of a descendant's column from its row on) and its own blocks.
        let (row_ptr, row_pos, row_end) = (&self.row_ptr, &self.row_pos, &self.row_end);
        let cost = |k: usize| {
            let row = row_ptr[k] as usize..row_ptr[k + 1] as usize;
            let gathered: u64 = (row_pos[row.clone()].iter().zip(&row_end[row]))
                .map(|(&p, &end)| u64::from(end - p))
                .sum();
            gathered + l.col(k).len() as u64
        };
        // (The analysis is done with the children's lists: here they list the same children.)
        let AnalysisScratch {
            head,
            next,
            weight,
            frontier,
            split,
            ..
        } = &mut self.scratch;
        weight.clear();
        weight.extend((0..n).map(cost));
        let total: u64 = weight.iter().sum();
        if total < SPLIT_MIN_PRODUCTS {
            return None;
        }
        let child = |x: Index| if x == Index::MAX { NONE } else { x as usize };
        frontier.clear();
        for k in 0..n {
            match parent(k) {
                NONE => frontier.push(k),
                p => weight[p] += weight[k],
            }
        }
        let weight = &*weight;
        // The two threads' loads, the heaviest subtrees first, each to the lighter thread.
        let deal = |frontier: &mut Vec<usize>, bins: Option<&mut Vec<u8>>| {
            frontier.sort_unstable_by_key(|&k| (std::cmp::Reverse(weight[k]), k));
            let mut load = [0u64; 2];
            let mut bins = bins;
            for &k in frontier.iter() {
                let b = usize::from(load[1] < load[0]);
                load[b] += weight[k];
                if let Some(bins) = bins.as_deref_mut() {
                    bins[k] = b as u8;
                }
            }
            load[0].max(load[1])
        };
        let (mut rest, mut best, mut best_steps) = (0u64, total, None);
        for steps in 0..=64 {
            let time = deal(frontier, None) + rest;
            if time < best {
                (best, best_steps) = (time, Some(steps));
            }
            // The heaviest subtree (first after the deal) gives way to its children.
            let k = frontier[0];
            if child(head[k]) == NONE {
                break;
            }
            frontier.swap_remove(0);
            rest += cost(k);
            let mut c = child(head[k]);
            while c != NONE {
                frontier.push(c);
                c = child(next[c]);
            }
        }
        let steps = best_steps?;
        if (best as f64) > SPLIT_MAX_SHARE * total as f64 {
            return None;
        }
        // Again up to the best step, then the subtrees dealt for good.
        frontier.clear();
        frontier.extend((0..n).filter(|&k| parent(k) == NONE));
        for _ in 0..steps {
            deal(frontier, None);
            let k = frontier.swap_remove(0);
            let mut c = child(head[k]);
            while c != NONE {
                frontier.push(c);
                c = child(next[c]);
            }
        }
        let Split { mut part, mut cols } = std::mem::take(split);
        part.clear();
        part.resize(n, REST);
        deal(frontier, Some(&mut part));
        // Descendants follow their subtree's root (parents come after children).
        for k in (0..n).rev() {
            let p = parent(k);
            if p != NONE && part[p] != REST {
                part[k] = part[p];
            }
        }
        for c in &mut cols {
            c.clear();
        }
        for (k, &b) in part.iter().enumerate() {
            cols[b as usize].push(k as Index);
        }
        Some(Split { part, cols })
    }

    /// The factor of `A + σ w wᵀ` from that of `A` (`σ` = 1: an update, −1: a downdate), in
    /// place: Gill, Golub, Murray and Saunders' rotations column by column along the
    /// elimination tree's path from `first` (Davis and Hager's sparse form), which `w`'s
    /// nonzeros must lie on (a row of `J` whose blocks the analysis saw does: its first
    /// block column's path passes through the others). `w` is in the factor's order, two
    /// entries a block column, and is left zero. False when a downdate leaves a pivot that
    /// is not positive (the factor is then damaged: factorize again).
    pub(crate) fn update(&mut self, w: &mut [f64], first: usize, sigma: f64) -> bool {
        let (l, values) = (&self.l, &mut self.values);
        debug_assert_eq!(w.len(), 2 * l.columns());
        // The rotation of a scalar column with diagonal `d` and `w`'s entry `wj`: its new
        // diagonal, `c` and `s` (`None` when the new pivot is not positive).
        let rotation = |d: f64, wj: f64| {
            let r2 = d * d + sigma * wj * wj;
            (r2 > 0.0).then(|| {
                let r = r2.sqrt();
                (r, r / d, wj / d)
            })
        };
        let mut k = first;
        loop {
            let lk = l.col(k);
            let rows = &l.row[lk.start + 1..lk.end];
            let column = &mut values[lk];
            let (diag, below) = column.split_first_mut().expect("a diagonal block");
            // Column 2k: l₁₀ in the diagonal block, then lanes 0 and 1 of the blocks below.
            let Some((l00, c, s)) = rotation(1.0 / diag[0], w[2 * k]) else {
                return false;
            };
            let (ss, ic) = (sigma * s, 1.0 / c);
            let mut w1 = w[2 * k + 1];
            diag[1] = (diag[1] + ss * w1) * ic;
            w1 = c * w1 - s * diag[1];
            diag[0] = 1.0 / l00;
            // Column 2k + 1: its rotation is known once column 2k's has reached w₁; then
            // each block below takes both rotations in one pass (lanes 0 and 1, then 2 and 3,
            // the second on the `w` the first left).
            let Some((l11, c1, s1)) = rotation(1.0 / diag[3], w1) else {
                return false;
            };
            diag[3] = 1.0 / l11;
            let (ss1, ic1) = (sigma * s1, 1.0 / c1);
            for (&r, b) in rows.iter().zip(below.iter_mut()) {
                let r = 2 * r as usize;
                let (x0, x1) = (w[r], w[r + 1]);
                let (e0, e1) = ((b[0] + ss * x0) * ic, (b[1] + ss * x1) * ic);
                let (x0, x1) = (c * x0 - s * e0, c * x1 - s * e1);
                let (e2, e3) = ((b[2] + ss1 * x0) * ic1, (b[3] + ss1 * x1) * ic1);
                *b = [e0, e1, e2, e3];
                w[r] = c1 * x0 - s1 * e2;
                w[r + 1] = c1 * x1 - s1 * e3;
            }
            w[2 * k] = 0.0;
            w[2 * k + 1] = 0.0;
            match rows.first() {
                Some(&parent) => k = parent as usize,
                None => return true,
            }
        }
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
    /// positive definite. Compiled for AVX where the processor has it
    /// ([`factor_columns_dispatch`]).
    #[inline]
    pub(crate) fn factorize_columns(&mut self, columns: &impl BlockColumns) -> bool {
        self.factorize_with(columns, false)
    }

    /// All columns on this thread; `portable`: without AVX whatever the processor (the tests
    /// compare both).
    fn factorize_with(&mut self, columns: &impl BlockColumns, portable: bool) -> bool {
        let n = self.l.columns();
        let rows = RowLists {
            l: &self.l,
            row_ptr: &self.row_ptr,
            row_pos: &self.row_pos,
            row_end: &self.row_end,
            row_group: &self.row_group,
        };
        let values = SharedValues::new(&mut self.values);
        let work = &mut self.work[..];
        let ok = if portable {
            factor_shared_columns(&rows, 0..n, columns, work, values)
        } else {
            factor_columns_dispatch(&rows, 0..n, columns, work, values)
        };
        if !ok {
            self.work.fill([0.0; 4]);
        }
        ok
    }

    /// [`factorize_columns`](Self::factorize_columns) on two threads where the analysis split
    /// the columns (the two parts at once, the second on `helper`, then the rest): the same
    /// operations on every column, so the same bits as on one thread.
    pub(crate) fn factorize_columns_split(
        &mut self,
        columns: &(impl BlockColumns + Sync),
        helper: &Helper,
    ) -> bool {
        let Some(split) = self.split.take() else {
            return self.factorize_columns(columns);
        };
        let ok = self.factorize_split(&split, columns, helper);
        self.split = Some(split);
        ok
    }

    fn factorize_split(
        &mut self,
        split: &Split,
        columns: &(impl BlockColumns + Sync),
        helper: &Helper,
    ) -> bool {
        let rows = RowLists {
            l: &self.l,
            row_ptr: &self.row_ptr,
            row_pos: &self.row_pos,
            row_end: &self.row_end,
            row_group: &self.row_group,
        };
        let (work, work2) = (&mut self.work, Mutex::new(&mut self.work2));
        let values = SharedValues::new(&mut self.values);
        let second_ok = AtomicBool::new(true);
        let second = || {
            let mut work2 = work2.lock().unwrap_or_else(|e| e.into_inner());
            let cols = split.cols[1].iter().map(|&k| k as usize);
            let ok = factor_columns_dispatch(&rows, cols, columns, &mut work2[..], values);
            second_ok.store(ok, Ordering::Relaxed);
        };
        let first_ok = helper.join(
            || {
                let cols = split.cols[0].iter().map(|&k| k as usize);
                factor_columns_dispatch(&rows, cols, columns, &mut work[..], values)
            },
            &second,
        );
        let work2 = work2.into_inner().unwrap_or_else(|e| e.into_inner());
        let mut ok = first_ok && second_ok.load(Ordering::Relaxed);
        if ok {
            let cols = split.cols[2].iter().map(|&k| k as usize);
            ok = factor_columns_dispatch(&rows, cols, columns, &mut work[..], values);
        }
        if !ok {
            work.fill([0.0; 4]);
            work2.fill([0.0; 4]);
        }
        ok
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
        // Lᵀ x = y, column by column backwards.
        backward_columns(l, values, (0..n).rev(), SharedX::new(x));
    }
}

impl BlockCholesky {
    /// [`solve_in_place`](Self::solve_in_place) on two threads where the analysis split the
    /// columns: forward, the two parts at once (each column's updates to rows of its own part),
    /// then the rows of the rest, each gathering its updates from its row of `L` in increasing
    /// column order (the order the column sweep applies them: the same bits); backward, the
    /// rest, then the two parts at once.
    pub(crate) fn solve_in_place_split(&self, x: &mut [f64], helper: &Helper) {
        let Some(split) = &self.split else {
            return self.solve_in_place(x);
        };
        let (l, values) = (&self.l, &self.values);
        debug_assert_eq!(x.len(), 2 * l.columns());
        let forward = |shared: SharedX<'_>, part: usize| {
            for &k in &split.cols[part] {
                let k = k as usize;
                let lk = l.col(k);
                let [i00, l10, _, i11] = values[lk.start];
                let y0 = shared.get(2 * k) * i00;
                let y1 = (shared.get(2 * k + 1) - l10 * y0) * i11;
                shared.set(2 * k, y0);
                shared.set(2 * k + 1, y1);
                let below = lk.start + 1..lk.end;
                for (&i, b) in l.row[below.clone()].iter().zip(&values[below]) {
                    let i = i as usize;
                    if split.part[i] == REST {
                        continue;
                    }
                    let t = [b[0] * y0 + b[2] * y1, b[1] * y0 + b[3] * y1];
                    shared.set(2 * i, shared.get(2 * i) - t[0]);
                    shared.set(2 * i + 1, shared.get(2 * i + 1) - t[1]);
                }
            }
        };
        {
            let shared = SharedX::new(x);
            helper.join(|| forward(shared, 0), &|| forward(shared, 1));
        }
        for &k in &split.cols[2] {
            let k = k as usize;
            let (mut x0, mut x1) = (x[2 * k], x[2 * k + 1]);
            let row = self.row_ptr[k] as usize..self.row_ptr[k + 1] as usize;
            for (&p, &j) in self.row_pos[row.clone()].iter().zip(&self.row_col[row]) {
                let (b, j) = (values[p as usize], j as usize);
                let (y0, y1) = (x[2 * j], x[2 * j + 1]);
                let t = [b[0] * y0 + b[2] * y1, b[1] * y0 + b[3] * y1];
                x0 -= t[0];
                x1 -= t[1];
            }
            let [i00, l10, _, i11] = values[l.col(k).start];
            let y0 = x0 * i00;
            x[2 * k] = y0;
            x[2 * k + 1] = (x1 - l10 * y0) * i11;
        }
        let backward = |shared: SharedX<'_>, part: usize| {
            let cols = split.cols[part].iter().rev().map(|&k| k as usize);
            backward_columns(l, values, cols, shared);
        };
        let shared = SharedX::new(x);
        backward(shared, REST as usize);
        helper.join(|| backward(shared, 0), &|| backward(shared, 1));
    }
}

/// `Lᵀ x = y` on the columns `cols` (each after the columns below it: decreasing, or the rest
/// before the parts), each `x_k` from its own column: `[r₀, r₁] −= Σ bᵀ x_i`.
///
/// Each column's blocks are read from its last to its first, so that the columns taken in
/// decreasing order read the factor as one decreasing stream, which the processor
/// prefetches (a crush's factor is far larger than the caches: read from each column's front,
/// every column started a stream of its own, and the pressed crush of 40,000 took 1.2× longer
/// a step).
#[inline(always)]
fn backward_columns(
    l: &BlockPattern,
    values: &[Block],
    cols: impl Iterator<Item = usize>,
    x: SharedX<'_>,
) {
    for k in cols {
        let lk = l.col(k);
        let below = lk.start + 1..lk.end;
        let mut r = [x.get(2 * k), x.get(2 * k + 1)];
        for (&i, b) in l.row[below.clone()].iter().zip(&values[below]).rev() {
            let i = 2 * i as usize;
            let (x0, x1) = (x.get(i), x.get(i + 1));
            r = [
                r[0] - (b[0] * x0 + b[1] * x1),
                r[1] - (b[2] * x0 + b[3] * x1),
            ];
        }
        let [i00, l10, _, i11] = values[lk.start];
        let x1 = r[1] * i11;
        let x0 = (r[0] - l10 * x1) * i00;
        x.set(2 * k, x0);
        x.set(2 * k + 1, x1);
    }
}

/// What a column of the numeric factorization reads of the analysis.
struct RowLists<'a> {
    l: &'a BlockPattern,
    row_ptr: &'a [Index],
    row_pos: &'a [Index],
    row_end: &'a [Index],
    row_group: &'a [u8],
}

/// An array shared by the threads of a split factorization or solve (the factor's values, the
/// right-hand side): each thread writes only the entries of its own part's columns and reads
/// only those and the rest's, which no thread writes while the parts run (on one thread: all
/// of them, one after the other).
struct Shared<'a, T> {
    ptr: *mut T,
    len: usize,
    _array: std::marker::PhantomData<&'a mut [T]>,
}

impl<T> Clone for Shared<'_, T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Shared<'_, T> {}

// SAFETY: the threads sharing one reach disjoint entries, or read entries no one writes
// meanwhile (see `Shared::read`); `T` is plain data (blocks, numbers).
#[allow(unsafe_code)]
unsafe impl<T: Send> Send for Shared<'_, T> {}
#[allow(unsafe_code)]
unsafe impl<T: Send> Sync for Shared<'_, T> {}

/// The factor's values as a factorization's columns reach them.
type SharedValues<'a> = Shared<'a, Block>;

/// The right-hand side of a split solve.
type SharedX<'a> = Shared<'a, f64>;

impl<'a, T: Copy> Shared<'a, T> {
    fn new(array: &'a mut [T]) -> Self {
        Self {
            ptr: array.as_mut_ptr(),
            len: array.len(),
            _array: std::marker::PhantomData,
        }
    }

    /// Entries no thread writes while the slice lives: a column of the calling thread's own
    /// part, or of the rest once both parts are done.
    #[inline(always)]
    fn read(&self, range: std::ops::Range<usize>) -> &[T] {
        assert!(range.start <= range.end && range.end <= self.len);
        // SAFETY: in bounds (checked); a column is written only by the thread that
        // factorizes it, once, before any column that reads it (its ancestors: the same part,
        // or the rest) is started; the rest is written only while the parts do not run.
        #[allow(unsafe_code)]
        unsafe {
            std::slice::from_raw_parts(self.ptr.add(range.start), range.len())
        }
    }

    /// Entries only the calling thread reaches while the slice lives: the column it is
    /// factorizing (or an entry of its own part).
    #[inline(always)]
    #[allow(clippy::mut_from_ref)]
    fn write(&self, range: std::ops::Range<usize>) -> &mut [T] {
        assert!(range.start <= range.end && range.end <= self.len);
        // SAFETY: in bounds (checked); the entries belong to the calling thread's part (or to
        // the rest, while the parts do not run), so no other thread reaches them, and the
        // slice is dropped before another column starts.
        #[allow(unsafe_code)]
        unsafe {
            std::slice::from_raw_parts_mut(self.ptr.add(range.start), range.len())
        }
    }

    #[inline(always)]
    fn get(&self, i: usize) -> T {
        self.read(i..i + 1)[0]
    }

    #[inline(always)]
    fn set(&self, i: usize, v: T) {
        self.write(i..i + 1)[0] = v;
    }
}

/// The columns `cols` (each after its descendants) of the factorization, in `work` (zero
/// before, zero after unless a column fails: then false at once), the values shared with
/// another thread's part when the factorization is split (one thread: all of them).
#[inline(always)]
fn factor_shared_columns(
    rows: &RowLists<'_>,
    cols: impl Iterator<Item = usize>,
    columns: &impl BlockColumns,
    work: &mut [Block],
    values: SharedValues<'_>,
) -> bool {
    let l = rows.l;
    for k in cols {
        let lk = l.col(k);
        columns.add_column(k, work);
        // A(:, k) − Σ_j L(:, j) L(k, j)ᵀ over the columns j < k with a block in row k.
        let (mut e, last) = (rows.row_ptr[k] as usize, rows.row_ptr[k + 1] as usize);
        while e < last {
            let w = rows.row_group[e] as usize;
            let (p, end) = (rows.row_pos[e] as usize, rows.row_end[e] as usize);
            if w == 1 {
                // The rest of column j from row k on (its rows increase).
                let column = values.read(p..end);
                let b = column[0];
                let (bx, by) = ([b[0], b[0], b[1], b[1]], [b[2], b[2], b[3], b[3]]);
                for (&r, v) in l.row[p..end].iter().zip(column) {
                    sub_mul_transpose(&mut work[r as usize], v, &bx, &by);
                }
            } else {
                // Columns j, j + 1, …, j + w − 1 of one supernode: the same rows from row k
                // on, so each row's block gathers their updates in turn (in the same order as
                // one column after the other: the same bits) and is read and written once.
                let len = end - p;
                let mut columns: [&[Block]; MAX_GROUP] = [&[]; MAX_GROUP];
                let mut spread = [([0.0; 4], [0.0; 4]); MAX_GROUP];
                for i in 0..w {
                    let q = rows.row_pos[e + i] as usize;
                    columns[i] = values.read(q..q + len);
                    let b = columns[i][0];
                    spread[i] = ([b[0], b[0], b[1], b[1]], [b[2], b[2], b[3], b[3]]);
                }
                for (t, &r) in l.row[p..end].iter().enumerate() {
                    let mut acc = work[r as usize];
                    for i in 0..w {
                        sub_mul_transpose(&mut acc, &columns[i][t], &spread[i].0, &spread[i].1);
                    }
                    work[r as usize] = acc;
                }
            }
            e += w;
        }
        if !finish_column(l, k, work, values.write(lk)) {
            return false;
        }
    }
    true
}

/// [`factor_shared_columns`] compiled for AVX where the processor has it: each block update
/// in one 4-lane operation instead of two pairs of lanes. The same operations in the same
/// order (no fused multiply–add), so the same bits on any x86-64.
fn factor_columns_dispatch(
    rows: &RowLists<'_>,
    cols: impl Iterator<Item = usize>,
    columns: &impl BlockColumns,
    work: &mut [Block],
    values: SharedValues<'_>,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[target_feature(enable = "avx")]
        fn avx(
            rows: &RowLists<'_>,
            cols: impl Iterator<Item = usize>,
            columns: &impl BlockColumns,
            work: &mut [Block],
            values: SharedValues<'_>,
        ) -> bool {
            factor_shared_columns(rows, cols, columns, work, values)
        }
        // SAFETY: the processor has AVX (just checked), all `avx` asks for.
        #[allow(unsafe_code)]
        return unsafe { avx(rows, cols, columns, work, values) };
    }
    factor_shared_columns(rows, cols, columns, work, values)
}

/// Column `k` of `L` from its updated column in `work` (read and reset there) into `out`: its
/// diagonal block by the 2×2 Cholesky, kept as `[1/l₀₀, l₁₀, 0, 1/l₁₁]` (the divisions of the
/// column below and of every triangular solve become multiplications), and the blocks below
/// solved against it. False, with `work` left as it is, when the pivot is not positive.
#[inline(always)]
fn finish_column(l: &BlockPattern, k: usize, work: &mut [Block], out: &mut [Block]) -> bool {
    let lk = l.col(k);
    let d = std::mem::replace(&mut work[k], [0.0; 4]);
    let l00 = d[0].sqrt();
    let l10 = d[1] / l00;
    let schur = d[3] - l10 * l10;
    if !(d[0] > 0.0 && schur > 0.0) {
        return false;
    }
    let (i00, i11) = (1.0 / l00, 1.0 / schur.sqrt());
    out[0] = [i00, l10, 0.0, i11];
    // L(i, k) = W(i) L(k, k)⁻ᵀ: each row of the block solved against L(k, k)ᵀ.
    for (&r, out) in l.row[lk.start + 1..lk.end].iter().zip(&mut out[1..]) {
        let w = std::mem::replace(&mut work[r as usize], [0.0; 4]);
        let (x0, x1) = (w[0] * i00, w[1] * i00); // rows 0 and 1
        *out = [x0, x1, (w[2] - x0 * l10) * i11, (w[3] - x1 * l10) * i11];
    }
    true
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
            chol.analyse(pattern.clone(), false);
            assert!(chol.factorize(&values));
            // The factor is the same, bit for bit, whichever instructions computed it.
            let mut portable = chol.clone();
            assert!(portable.factorize_with(
                &StoredColumns {
                    pattern: &pattern,
                    values: &values,
                },
                true
            ));
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
        chol.analyse(pattern.clone(), false);
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
        fresh.analyse(pattern, false);
        assert!(fresh.factorize(&definite));
        assert_eq!(chol.values, fresh.values);
    }

    /// The updates of a supernode's columns gathered row by row (`row_group`) give the
    /// factor one column after the other gives, bit for bit, on a pattern with supernodes
    /// of every width up to `MAX_GROUP` and more (the grids' separator and their last rows).
    #[test]
    fn a_supernodes_columns_gathered_at_once_give_the_same_bits() {
        let (pattern, values) = two_grids_and_a_separator();
        let mut grouped = BlockCholesky::default();
        grouped.analyse(pattern.clone(), false);
        let widths: Vec<u8> = grouped
            .row_group
            .iter()
            .copied()
            .filter(|&w| w > 1)
            .collect();
        assert!(
            widths.contains(&2) && widths.contains(&(MAX_GROUP as u8)),
            "{widths:?}"
        );
        let mut one_by_one = grouped.clone();
        for w in one_by_one.row_group.iter_mut() {
            *w = 1;
        }
        assert!(grouped.factorize(&values) && one_by_one.factorize(&values));
        assert_eq!(grouped.values, one_by_one.values);
        assert!(grouped.factorize_with(
            &StoredColumns {
                pattern: &pattern,
                values: &values
            },
            true
        ));
        assert_eq!(grouped.values, one_by_one.values);
    }

    /// Two 12×12 grids of blocks (each block coupled to its right and upper neighbours) and
    /// a separator of 12 blocks coupled to both: the elimination tree has two heavy subtrees.
    fn two_grids_and_a_separator() -> (BlockPattern, Vec<f64>) {
        let side = 12;
        let g = side * side;
        let n = 2 * g + side;
        let mut lower: Vec<Vec<usize>> = vec![Vec::new(); n];
        for half in 0..2 {
            for y in 0..side {
                for x in 0..side {
                    let k = half * g + y * side + x;
                    if x + 1 < side {
                        lower[k].push(k + 1);
                    }
                    if y + 1 < side {
                        lower[k].push(k + side);
                    }
                    if y + 1 == side {
                        lower[k].push(2 * g + x);
                    }
                }
            }
        }
        for x in 0..side - 1 {
            lower[2 * g + x].push(2 * g + x + 1);
        }
        let mut pattern = BlockPattern::default();
        pattern.ptr.push(0);
        for (k, rows) in lower.iter_mut().enumerate() {
            rows.sort_unstable();
            pattern.row.push(k as Index);
            pattern.row.extend(rows.iter().map(|&r| r as Index));
            pattern.ptr.push(pattern.row.len() as Index);
        }
        let mut seed = 11u64;
        let mut values = vec![0.0; 4 * pattern.row.len()];
        for k in 0..n {
            let p = pattern.ptr[k] as usize;
            let off = 0.2 * (lcg(&mut seed) - 0.5);
            values[4 * p] = 6.0 + lcg(&mut seed);
            values[4 * p + 1] = off;
            values[4 * p + 3] = 6.0 + lcg(&mut seed);
            for q in p + 1..pattern.ptr[k + 1] as usize {
                for sub in 0..4 {
                    values[4 * q + sub] = lcg(&mut seed) - 0.5;
                }
            }
        }
        (pattern, values)
    }

    /// The analysis keeps its scratch and the last split's lists: after a larger and a smaller
    /// pattern, an analysis gives what a fresh one gives (the pattern of `L`, its row lists,
    /// the split).
    #[test]
    fn an_analysis_after_others_gives_what_a_fresh_one_gives() {
        let (grids, _) = two_grids_and_a_separator();
        let small = BlockPattern {
            ptr: vec![0, 2, 4, 5],
            row: vec![0, 1, 1, 2, 2],
        };
        let mut reused = BlockCholesky::default();
        for pattern in [&grids, &grids, &small, &grids] {
            reused.analyse(pattern.clone(), true);
            let mut fresh = BlockCholesky::default();
            fresh.analyse(pattern.clone(), true);
            assert_eq!(reused.l.ptr, fresh.l.ptr);
            assert_eq!(reused.l.row, fresh.l.row);
            assert_eq!(
                (
                    &reused.row_ptr,
                    &reused.row_pos,
                    &reused.row_end,
                    &reused.row_col
                ),
                (
                    &fresh.row_ptr,
                    &fresh.row_pos,
                    &fresh.row_end,
                    &fresh.row_col
                )
            );
            let parts =
                |c: &BlockCholesky| c.split.as_ref().map(|s| (s.part.clone(), s.cols.clone()));
            assert_eq!(parts(&reused), parts(&fresh));
            assert_eq!(reused.is_split(), pattern.columns() > 100);
        }
    }

    /// A rank-one update of the factor with a row of two block columns, one below the
    /// other in the pattern (a contact), gives the factor of `A + w wᵀ` (to rounding), and
    /// the downdate with the same row gives back that of `A`; on the two grids' pattern,
    /// rows starting in either grid or in the separator.
    #[test]
    fn a_rank_one_update_and_downdate_give_the_factors_of_the_changed_matrices() {
        let (pattern, values) = two_grids_and_a_separator();
        let n = pattern.columns();
        let mut chol = BlockCholesky::default();
        chol.analyse(pattern.clone(), false);
        assert!(chol.factorize(&values));
        let mut seed = 11u64;
        for a in [0, 5, 143, 150, 290, n - 2] {
            let col = pattern.ptr[a] as usize..pattern.ptr[a + 1] as usize;
            // The last block below the diagonal of column a: a contact between a and b.
            let p = col.end - 1;
            let b = pattern.row[p] as usize;
            assert!(b > a);
            let wa = [lcg(&mut seed) * 3.0, lcg(&mut seed) - 0.5];
            let wb = [lcg(&mut seed) - 0.5, lcg(&mut seed) * 2.0];
            let mut changed = values.clone();
            let diag = |k: usize| 4 * pattern.ptr[k] as usize;
            for (k, wk) in [(a, wa), (b, wb)] {
                let d = diag(k);
                changed[d] += wk[0] * wk[0];
                changed[d + 1] += wk[1] * wk[0];
                changed[d + 3] += wk[1] * wk[1];
            }
            changed[4 * p] += wb[0] * wa[0];
            changed[4 * p + 1] += wb[1] * wa[0];
            changed[4 * p + 2] += wb[0] * wa[1];
            changed[4 * p + 3] += wb[1] * wa[1];
            let mut fresh = BlockCholesky::default();
            fresh.analyse(pattern.clone(), false);
            assert!(fresh.factorize(&changed));
            let row = |w: &mut Vec<f64>| {
                w.iter_mut().for_each(|x| *x = 0.0);
                w[2 * a..2 * a + 2].copy_from_slice(&wa);
                w[2 * b..2 * b + 2].copy_from_slice(&wb);
            };
            let mut w = vec![0.0; 2 * n];
            let before = chol.values.clone();
            row(&mut w);
            assert!(chol.update(&mut w, a, 1.0));
            assert!(w.iter().all(|&x| x == 0.0), "w left zero");
            let close = |x: &[Block], y: &[Block]| {
                x.iter()
                    .flatten()
                    .zip(y.iter().flatten())
                    .map(|(p, q)| (p - q).abs() / (1.0 + q.abs()))
                    .fold(0.0, f64::max)
            };
            let err = close(&chol.values, &fresh.values);
            assert!(err < 1e-12, "update from column {a}: {err:e}");
            row(&mut w);
            assert!(chol.update(&mut w, a, -1.0));
            let err = close(&chol.values, &before);
            assert!(err < 1e-12, "downdate from column {a}: {err:e}");
        }
        // A downdate that would leave the matrix indefinite is refused.
        let mut w = vec![0.0; 2 * n];
        w[0] = 100.0;
        assert!(!chol.update(&mut w, 0, -1.0));
    }

    #[test]
    fn a_factorization_split_over_two_threads_gives_the_same_bits() {
        let (pattern, values) = two_grids_and_a_separator();
        let mut one = BlockCholesky::default();
        one.analyse(pattern.clone(), false);
        assert!(!one.is_split());
        let mut two = BlockCholesky::default();
        two.analyse(pattern.clone(), true);
        let split = two.split.as_ref().expect("split");
        // The two grids' columns go to the two threads (each with at least a quarter of them).
        let side = 12 * 12;
        assert!(split.cols[0].len() >= side / 4 && split.cols[1].len() >= side / 4);
        let helper = Helper::start().expect("a thread");
        let columns = StoredColumns {
            pattern: &pattern,
            values: &values,
        };
        let mut seed = 5u64;
        for round in 0..3 {
            assert!(one.factorize(&values));
            assert!(two.factorize_columns_split(&columns, &helper));
            assert_eq!(one.values, two.values, "round {round}");
            let b: Vec<f64> = (0..2 * pattern.columns())
                .map(|_| lcg(&mut seed) - 0.5)
                .collect();
            let (mut x1, mut x2) = (b.clone(), b);
            one.solve_in_place(&mut x1);
            two.solve_in_place_split(&mut x2, &helper);
            assert!(
                x1.iter().zip(&x2).all(|(a, b)| a.to_bits() == b.to_bits()),
                "round {round}"
            );
        }
        // A matrix that is not positive definite is refused, and the next one starts clean.
        let mut bad = values.clone();
        let last = pattern.ptr[pattern.columns() - 1] as usize;
        bad[4 * last] = -1.0;
        assert!(!two.factorize_columns_split(
            &StoredColumns {
                pattern: &pattern,
                values: &bad,
            },
            &helper
        ));
        assert!(two.factorize_columns_split(&columns, &helper));
        assert_eq!(one.values, two.values);
    }
}
