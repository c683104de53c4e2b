//! Nested dissection: a fill-reducing ordering of a symmetric pattern that splits the graph
//! by level-structure separators (George and Liu) and orders the small pieces by approximate
//! minimum degree (faer's AMD). On a fully pressed 2-D contact network minimum degree alone
//! leaves wide fronts; separators ordered last keep the factor's fronts at the separators'
//! size.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMatRef;
use faer::sparse::linalg::amd;

use crate::error::SolveError;
use crate::products::Index;

/// Pieces of at most this many nodes are ordered by minimum degree, not split further.
const LEAF: usize = 64;

/// A level separates only if it leaves at least this fraction of the piece on either side;
/// among those, the smallest level is taken (0.5 would be the middle level: 1.15–1.25×
/// more multiply–adds on crushes of 10⁴–4·10⁴).
const BALANCE: f64 = 0.4;

/// AMD's scratch for the leaves, grown to the largest leaf seen (not allocated per leaf).
#[derive(Default)]
struct LeafScratch {
    sized_for: (usize, usize),
    mem: Option<MemBuffer>,
}

impl std::fmt::Debug for LeafScratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LeafScratch{:?}", self.sized_for)
    }
}

impl LeafScratch {
    fn for_amd(&mut self, n: usize, nnz: usize) -> &mut MemBuffer {
        let (sn, snnz) = self.sized_for;
        if self.mem.is_none() || n > sn || nnz > snnz {
            self.sized_for = (n.max(sn), nnz.max(snnz));
            let (n, nnz) = self.sized_for;
            self.mem = Some(MemBuffer::new(amd::order_maybe_unsorted_scratch::<Index>(
                n, nnz,
            )));
        }
        self.mem.as_mut().expect("sized above")
    }
}

/// Scratch of the ordering, sized by the largest graph seen.
#[derive(Debug, Default)]
pub(crate) struct Dissection {
    // The full adjacency (both triangles, no diagonal) in compressed rows.
    adj_start: Vec<usize>,
    adj: Vec<Index>,
    // The nodes, in the order being built: every piece is a contiguous range of it.
    order: Vec<Index>,
    // The piece a node belongs to now (the stamp of the range it was last placed in).
    piece: Vec<u32>,
    level: Vec<u32>,
    queue: Vec<Index>,
    level_count: Vec<usize>,
    stack: Vec<(usize, usize)>,
    split: Vec<Index>,
    // A leaf's local pattern for AMD.
    local: Vec<Index>,
    leaf_ptr: Vec<Index>,
    leaf_idx: Vec<Index>,
    leaf_perm: Vec<Index>,
    leaf_perm_inv: Vec<Index>,
    leaf_mem: LeafScratch,
}

impl Dissection {
    /// Writes into `perm` (new position → node) and `perm_inv` (node → new position) a
    /// nested-dissection ordering of the `n` nodes of the symmetric pattern `lower` (one
    /// triangle, the diagonal optional).
    pub(crate) fn order(
        &mut self,
        lower: SymbolicSparseColMatRef<'_, Index>,
        perm: &mut [Index],
        perm_inv: &mut [Index],
    ) -> Result<(), SolveError> {
        let n = lower.ncols();
        self.adjacency(lower);
        self.order.clear();
        self.order.extend((0..n).map(|v| v as Index));
        self.piece.clear();
        self.piece.resize(n, 0);
        self.level.clear();
        self.level.resize(n, u32::MAX);
        self.local.clear();
        self.local.resize(n, 0);
        let mut stamp = 0u32;
        self.stack.clear();
        self.stack.push((0, n));
        while let Some((s, e)) = self.stack.pop() {
            stamp += 1;
            for &v in &self.order[s..e] {
                self.piece[v as usize] = stamp;
            }
            if e - s <= LEAF {
                self.leaf(s, e, stamp)?;
                continue;
            }
            match self.separate(s, e, stamp) {
                Some((a, b)) => {
                    // [s, a) and [a, b) are the two sides, [b, e) the separator (last).
                    self.stack.push((s, a));
                    if b > a {
                        self.stack.push((a, b));
                    }
                }
                None => self.leaf(s, e, stamp)?,
            }
        }
        for (k, &v) in self.order.iter().enumerate() {
            perm[k] = v;
            perm_inv[v as usize] = k as Index;
        }
        Ok(())
    }

    fn adjacency(&mut self, lower: SymbolicSparseColMatRef<'_, Index>) {
        let n = lower.ncols();
        self.adj_start.clear();
        self.adj_start.resize(n + 1, 0);
        for c in 0..n {
            for &r in lower.row_idx_of_col_raw(c) {
                let r = r as usize;
                if r != c {
                    self.adj_start[r + 1] += 1;
                    self.adj_start[c + 1] += 1;
                }
            }
        }
        for v in 0..n {
            self.adj_start[v + 1] += self.adj_start[v];
        }
        self.adj.clear();
        self.adj.resize(self.adj_start[n], 0);
        let mut next = self.adj_start[..n].to_vec();
        for c in 0..n {
            for &r in lower.row_idx_of_col_raw(c) {
                let r = r as usize;
                if r != c {
                    self.adj[next[r]] = c as Index;
                    next[r] += 1;
                    self.adj[next[c]] = r as Index;
                    next[c] += 1;
                }
            }
        }
    }

    fn neighbours(&self, v: usize) -> &[Index] {
        &self.adj[self.adj_start[v]..self.adj_start[v + 1]]
    }

    /// Breadth-first levels from `root` within the piece `stamp`; returns the nodes reached
    /// (in `queue`, by level) and the last level.
    fn levels(&mut self, root: Index, stamp: u32) -> u32 {
        self.queue.clear();
        self.queue.push(root);
        self.level[root as usize] = 0;
        let mut head = 0;
        let mut last = 0;
        while head < self.queue.len() {
            let v = self.queue[head] as usize;
            head += 1;
            let l = self.level[v];
            last = l;
            for k in self.adj_start[v]..self.adj_start[v + 1] {
                let w = self.adj[k] as usize;
                if self.piece[w] == stamp && self.level[w] == u32::MAX {
                    self.level[w] = l + 1;
                    self.queue.push(w as Index);
                }
            }
        }
        last
    }

    fn clear_levels(&mut self) {
        for &v in &self.queue {
            self.level[v as usize] = u32::MAX;
        }
    }

    /// Splits the piece `order[s..e]` into two sides and a separator, reordered in place as
    /// `[s, a) | [a, b) | [b, e)`; `None` when the piece is too compact to split.
    fn separate(&mut self, s: usize, e: usize, stamp: u32) -> Option<(usize, usize)> {
        // A pseudo-peripheral root (George and Liu): from the minimum-degree node of the last
        // level, again, while the depth grows (at most four times). The levels kept are those
        // of the last search.
        let mut depth = self.levels(self.order[s], stamp);
        if self.queue.len() < e - s {
            // Disconnected: the component reached, then the rest (no separator).
            let reached = self.queue.len();
            self.partition(s, e, |d, v| d.level[v] != u32::MAX, 0);
            self.clear_levels();
            return Some((s + reached, e));
        }
        for _ in 0..4 {
            let last_level = self
                .queue
                .iter()
                .rev()
                .take_while(|&&v| self.level[v as usize] == depth);
            let root = last_level
                .min_by_key(|&&v| self.neighbours(v as usize).len())
                .copied()
                .expect("the last level has a node");
            self.clear_levels();
            let d = self.levels(root, stamp);
            let deeper = d > depth;
            depth = d;
            if !deeper {
                break;
            }
        }
        if depth < 2 {
            self.clear_levels();
            return None;
        }
        // The middle level: the first whose cumulative count reaches half the piece.
        self.level_count.clear();
        self.level_count.resize(depth as usize + 1, 0);
        for &v in &self.queue {
            self.level_count[self.level[v as usize] as usize] += 1;
        }
        // The separating level: the smallest among those that leave at least `BALANCE` of
        // the piece on either side.
        let size = (e - s) as f64;
        let mut cumulative = 0;
        let mut middle = 0;
        let mut best = usize::MAX;
        for l in 1..depth as usize {
            cumulative += self.level_count[l - 1];
            let near = cumulative as f64 / size;
            let far = 1.0 - (cumulative + self.level_count[l]) as f64 / size;
            let c = self.level_count[l];
            if near.min(far) >= BALANCE && c < best {
                best = c;
                middle = l as u32;
            }
        }
        if middle == 0 {
            let half = (e - s) / 2;
            let mut cumulative = 0;
            for (l, &c) in self.level_count.iter().enumerate() {
                cumulative += c;
                if cumulative >= half {
                    middle = l as u32;
                    break;
                }
            }
        }
        let middle = middle.clamp(1, depth - 1);
        // Separator: the middle level's nodes with a neighbour beyond it; the others join the
        // near side.
        let is_separator = |d: &Self, v: usize| {
            d.level[v] == middle
                && d.neighbours(v)
                    .iter()
                    .any(|&w| d.piece[w as usize] == stamp && d.level[w as usize] == middle + 1)
        };
        // Order: near side (levels < middle and the middle's non-separators), far side, then
        // the separator.
        let sep = self.partition(s, e, is_separator, 2);
        let near = self.partition(s, sep, |d, v| d.level[v] <= middle, 0);
        self.clear_levels();
        Some((near, sep))
    }

    /// Reorders `order[s..e]` so that the nodes with `pred` come first (`at == 0`) or last
    /// (otherwise), stably; returns the boundary.
    fn partition(
        &mut self,
        s: usize,
        e: usize,
        pred: impl Fn(&Self, usize) -> bool,
        at: u8,
    ) -> usize {
        self.split.clear();
        let mut first = s;
        for k in s..e {
            let v = self.order[k];
            let yes = pred(self, v as usize);
            if yes == (at == 0) {
                self.order[first] = v;
                first += 1;
            } else {
                self.split.push(v);
            }
        }
        self.order[first..e].copy_from_slice(&self.split);
        first
    }

    /// Orders the piece `order[s..e]` by AMD on its own pattern.
    fn leaf(&mut self, s: usize, e: usize, stamp: u32) -> Result<(), SolveError> {
        let m = e - s;
        if m <= 2 {
            return Ok(());
        }
        for (k, &v) in self.order[s..e].iter().enumerate() {
            self.local[v as usize] = k as Index;
        }
        self.leaf_ptr.clear();
        self.leaf_idx.clear();
        self.leaf_ptr.push(0);
        for k in s..e {
            let v = self.order[k] as usize;
            let me = self.local[v];
            self.leaf_idx.push(me);
            for a in self.adj_start[v]..self.adj_start[v + 1] {
                let w = self.adj[a] as usize;
                if self.piece[w] == stamp {
                    self.leaf_idx.push(self.local[w]);
                }
            }
            self.leaf_ptr.push(self.leaf_idx.len() as Index);
        }
        let pattern = SymbolicSparseColMatRef::new_unsorted_checked(
            m,
            m,
            &self.leaf_ptr,
            None,
            &self.leaf_idx,
        );
        self.leaf_perm.clear();
        self.leaf_perm.resize(m, 0);
        self.leaf_perm_inv.clear();
        self.leaf_perm_inv.resize(m, 0);
        let mem = self.leaf_mem.for_amd(m, self.leaf_idx.len());
        amd::order_maybe_unsorted(
            &mut self.leaf_perm,
            &mut self.leaf_perm_inv,
            pattern,
            amd::Control::default(),
            MemStack::new(mem),
        )
        .map_err(|e| SolveError::Factorization(format!("{e:?}")))?;
        self.split.clear();
        self.split.extend(self.order[s..e].iter().copied());
        for k in 0..m {
            self.order[s + k] = self.split[self.leaf_perm[k] as usize];
        }
        Ok(())
    }
}

/// Scratch of [`FillCount`].
#[derive(Debug, Clone, Default)]
pub(crate) struct FillCount {
    ptr: Vec<Index>,
    idx: Vec<Index>,
    next: Vec<usize>,
    etree: Vec<i32>,
    counts: Vec<Index>,
}

impl FillCount {
    /// The Cholesky factor of the symmetric pattern `lower` (one triangle) with node `v` at
    /// position `perm_inv[v]`, counted on the pattern's own nodes: its multiply–adds
    /// `Σ c(c + 1)/2` and its entries `Σ c` over the column counts `c`.
    pub(crate) fn count(
        &mut self,
        lower: SymbolicSparseColMatRef<'_, Index>,
        perm_inv: &[Index],
    ) -> (u64, u64) {
        let n = lower.ncols();
        // The permuted upper triangle, rows unsorted.
        self.next.clear();
        self.next.resize(n + 1, 0);
        for c in 0..n {
            for &r in lower.row_idx_of_col_raw(c) {
                let (a, b) = (perm_inv[r as usize], perm_inv[c]);
                self.next[a.max(b) as usize + 1] += 1;
            }
        }
        for v in 0..n {
            self.next[v + 1] += self.next[v];
        }
        self.ptr.clear();
        self.ptr.extend(self.next.iter().map(|&p| p as Index));
        self.idx.clear();
        self.idx.resize(self.next[n], 0);
        for c in 0..n {
            for &r in lower.row_idx_of_col_raw(c) {
                let (a, b) = (perm_inv[r as usize], perm_inv[c]);
                let col = a.max(b) as usize;
                self.idx[self.next[col]] = a.min(b);
                self.next[col] += 1;
            }
        }
        let upper = SymbolicSparseColMatRef::new_unsorted_checked(n, n, &self.ptr, None, &self.idx);
        self.etree.clear();
        self.etree.resize(n, 0);
        self.counts.clear();
        self.counts.resize(n, 0);
        let mut mem = MemBuffer::new(
            faer::sparse::linalg::cholesky::simplicial::prefactorize_symbolic_cholesky_scratch::<
                Index,
            >(n, self.idx.len()),
        );
        faer::sparse::linalg::cholesky::simplicial::prefactorize_symbolic_cholesky(
            &mut self.etree,
            &mut self.counts,
            upper,
            MemStack::new(&mut mem),
        );
        self.counts.iter().fold((0, 0), |(products, entries), &c| {
            let c = c as u64;
            (products + c * (c + 1) / 2, entries + c)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lower triangle (with diagonal) of a graph given by its edges.
    fn lower(n: usize, edges: &[(usize, usize)]) -> (Vec<Index>, Vec<Index>) {
        let mut cols = vec![Vec::new(); n];
        for (c, col) in cols.iter_mut().enumerate() {
            col.push(c as Index);
        }
        for &(a, b) in edges {
            cols[a.min(b)].push(a.max(b) as Index);
        }
        let mut ptr = vec![0];
        let mut idx = Vec::new();
        for mut col in cols {
            col.sort_unstable();
            col.dedup();
            idx.extend(col);
            ptr.push(idx.len() as Index);
        }
        (ptr, idx)
    }

    /// A hexagonal packing of `side × side` nodes, each touching its six neighbours.
    fn hexagonal(side: usize) -> Vec<(usize, usize)> {
        let at = |r: usize, c: usize| r * side + c;
        let mut edges = Vec::new();
        for r in 0..side {
            for c in 0..side {
                if c + 1 < side {
                    edges.push((at(r, c), at(r, c + 1)));
                }
                if r + 1 < side {
                    edges.push((at(r, c), at(r + 1, c)));
                    // odd rows shifted right: the diagonal neighbour below
                    let d = if r % 2 == 1 { c + 1 } else { c.wrapping_sub(1) };
                    if d < side {
                        edges.push((at(r, c), at(r + 1, d)));
                    }
                }
            }
        }
        edges
    }

    fn order(n: usize, edges: &[(usize, usize)]) -> (Vec<Index>, Vec<Index>, (u64, u64)) {
        let (ptr, idx) = lower(n, edges);
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &ptr, None, &idx);
        let (mut perm, mut perm_inv) = (vec![0; n], vec![0; n]);
        Dissection::default()
            .order(pattern, &mut perm, &mut perm_inv)
            .unwrap();
        let count = FillCount::default().count(pattern, &perm_inv);
        (perm, perm_inv, count)
    }

    fn minimum_degree(n: usize, edges: &[(usize, usize)]) -> (u64, u64) {
        let (ptr, idx) = lower(n, edges);
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &ptr, None, &idx);
        let (mut perm, mut perm_inv) = (vec![0; n], vec![0; n]);
        let mut mem = MemBuffer::new(amd::order_maybe_unsorted_scratch::<Index>(n, idx.len()));
        amd::order_maybe_unsorted(
            &mut perm,
            &mut perm_inv,
            pattern,
            amd::Control::default(),
            MemStack::new(&mut mem),
        )
        .unwrap();
        FillCount::default().count(pattern, &perm_inv)
    }

    /// Multiply–adds of a dense elimination in the given order, column counts by brute force
    /// (the reference for [`FillCount`]).
    fn eliminated(n: usize, edges: &[(usize, usize)], perm_inv: &[Index]) -> (u64, u64) {
        let mut adj = vec![vec![false; n]; n];
        for &(a, b) in edges {
            let (a, b) = (perm_inv[a] as usize, perm_inv[b] as usize);
            adj[a][b] = true;
            adj[b][a] = true;
        }
        let (mut products, mut entries) = (0, 0);
        for k in 0..n {
            let below: Vec<usize> = (k + 1..n).filter(|&r| adj[k][r]).collect();
            for &a in &below {
                for &b in &below {
                    if a != b {
                        adj[a][b] = true;
                    }
                }
            }
            let c = 1 + below.len() as u64;
            products += c * (c + 1) / 2;
            entries += c;
        }
        (products, entries)
    }

    fn is_permutation(perm: &[Index], perm_inv: &[Index]) -> bool {
        let mut seen = vec![false; perm.len()];
        perm.iter().enumerate().all(|(k, &v)| {
            let fresh = !std::mem::replace(&mut seen[v as usize], true);
            fresh && perm_inv[v as usize] as usize == k
        })
    }

    #[test]
    fn every_node_is_ordered_once_whatever_the_graph() {
        // A path, a star, a clique, disconnected pieces and isolated nodes, a hexagonal
        // packing.
        let path: Vec<_> = (0..999).map(|v| (v, v + 1)).collect();
        let star: Vec<_> = (1..700).map(|v| (0, v)).collect();
        let clique: Vec<_> = (0..300)
            .flat_map(|a| (a + 1..300).map(move |b| (a, b)))
            .collect();
        let mut pieces = hexagonal(20);
        pieces.extend((0..300).map(|v| (400 + v, 400 + (v + 1) % 300)));
        for (n, edges) in [
            (1000, path),
            (700, star),
            (300, clique),
            (1000, pieces),
            (2500, hexagonal(50)),
        ] {
            let (perm, perm_inv, _) = order(n, &edges);
            assert!(is_permutation(&perm, &perm_inv), "{n} nodes");
        }
    }

    #[test]
    fn the_fill_count_is_the_dense_elimination_s() {
        let edges = hexagonal(14);
        let n = 14 * 14;
        let (_, perm_inv, count) = order(n, &edges);
        assert_eq!(count, eliminated(n, &edges, &perm_inv));
        let natural: Vec<Index> = (0..n as Index).collect();
        let (ptr, idx) = lower(n, &edges);
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &ptr, None, &idx);
        assert_eq!(
            FillCount::default().count(pattern, &natural),
            eliminated(n, &edges, &natural)
        );
    }

    #[test]
    fn a_pressed_hexagonal_network_costs_less_than_by_minimum_degree() {
        // 10,000 people pressed together: minimum degree leaves fronts as wide as the
        // crowd; the separators keep them at a separator's size. Measured 0.66 on the bench's
        // crush of 10,000 (benches/README.md, session 12).
        let side = 100;
        let edges = hexagonal(side);
        let (_, _, (dissected, _)) = order(side * side, &edges);
        let (minimum, _) = minimum_degree(side * side, &edges);
        assert!(
            (dissected as f64) < 0.8 * minimum as f64,
            "nested dissection {dissected} against minimum degree {minimum} multiply–adds"
        );
    }
}
