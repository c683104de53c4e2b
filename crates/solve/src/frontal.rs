//! The multifrontal numeric Cholesky factorization over faer's supernodal symbolic factor,
//! on two threads along the elimination tree: the two halves of the tree below its first
//! fork at once, then the rest. It writes the factor in faer's supernodal layout, so the
//! supernodal solves ([`crate::supernodal`]) read it unchanged.
//!
//! Each supernode's columns are factorized as a dense front (faer's dense Cholesky and
//! triangular solve) and its whole update to the rest formed once, a symmetric product of
//! its block below the diagonal with itself; the parent adds it into its own front at
//! positions computed at the analysis (the *extend-add*). On one thread it takes about the
//! time of faer's left-looking factorization of the same symbolic factor (a few per cent
//! less on the pressed crush of 10⁵; benches/README.md, session 24); what it adds is that the
//! supernodes of two disjoint subtrees touch disjoint memory, so a crush's nested
//! dissection, whose two halves hold most of the work, factorizes on two threads (the
//! shared helper thread takes the second half): the pressed crush of 10⁵ 7.8 → 5.8 s a step
//! on two threads.

use std::ops::Range;
use std::sync::Mutex;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::matmul::triangular::{BlockStructure, matmul as triangular_matmul};
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::SparseColMatRef;
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{Accum, MatMut, MatRef, Par};

use moreau_core::Helper;

use crate::normal::Scratch;
use crate::products::Index;
use crate::supernodal::Supernode;

const NONE: Index = Index::MAX;

/// What one thread's factorization of a range of supernodes writes besides the factor.
#[derive(Debug, Default)]
struct ThreadScratch {
    // A row's position in the front being assembled (faer's `global_to_local`).
    local: Vec<Index>,
    mem: Option<Scratch>,
}

/// The supernodes' tree and where each update lands in its parent's front.
#[derive(Debug, Default)]
struct Tree {
    // The children of `s`: `children[child_start[s]..child_start[s + 1]]`.
    child_start: Vec<usize>,
    children: Vec<Index>,
    // For each supernode with a parent, the position in the parent's front of each row of its
    // pattern, from `rel_start[s]`: below the parent's width one of its columns, from it on a
    // row of the parent's own update.
    rel_start: Vec<usize>,
    rel: Vec<Index>,
}

/// The analysis of one supernodal pattern and the scratch of its factorizations.
#[derive(Debug, Default)]
pub(crate) struct Multifrontal {
    tree: Tree,
    // Supernodes `[0, at)` and `[at, fork)` are two disjoint unions of subtrees, `[fork, ns)`
    // what is above them (the fork and its ancestors): the two threads' parts and the rest.
    // None when the tree has no fork that pays.
    split: Option<(usize, usize)>,
    // Each supernode's update (its pattern's rows and columns, column-major, the lower
    // triangle), kept from its factorization until its parent's.
    updates: Vec<Vec<f64>>,
    // Storage of large updates already added into their parents', for reuse by either
    // thread (one pool: what one thread's updates leave, the other's may take).
    pool: Mutex<Vec<Vec<f64>>>,
    threads: [ThreadScratch; 2],
}

/// The smaller part's share of the two parts' multiply–adds below which the factorization
/// stays on one thread.
const MIN_SHARE: f64 = 0.2;

impl Multifrontal {
    /// Analyses the supernodal pattern: the tree, the extend-add positions and the split.
    /// False when a supernode's pattern does not fit in its parent's front (a symbolic factor
    /// that is not faer's: never on faer's own).
    pub(crate) fn analyse(&mut self, symbolic: &SymbolicSupernodalCholesky<Index>) -> bool {
        let ns = symbolic.n_supernodes();
        let n = symbolic.nrows();
        let rows = symbolic.row_idx();
        let widest = (0..ns)
            .map(|s| Supernode::of(symbolic, s).width)
            .max()
            .unwrap_or(0);
        for t in &mut self.threads {
            t.local.clear();
            t.local.resize(n, NONE);
            t.mem = Some(Scratch(MemBuffer::new(cholesky_in_place_scratch::<f64>(
                widest,
                Par::Seq,
                Default::default(),
            ))));
        }
        let tree = &mut self.tree;
        let [
            ThreadScratch { local, .. },
            ThreadScratch { local: owner, .. },
        ] = &mut self.threads;
        // The parent of a supernode: the one holding the first row of its pattern.
        for s in 0..ns {
            let sn = Supernode::of(symbolic, s);
            owner[sn.begin..sn.begin + sn.width].fill(s as Index);
        }
        let parent = |s: usize| -> Option<usize> {
            let sn = Supernode::of(symbolic, s);
            (sn.below > 0).then(|| owner[rows[sn.rows_at] as usize] as usize)
        };
        tree.child_start.clear();
        tree.child_start.resize(ns + 1, 0);
        for s in 0..ns {
            if let Some(p) = parent(s) {
                if p <= s {
                    return false;
                }
                tree.child_start[p + 1] += 1;
            }
        }
        for s in 0..ns {
            tree.child_start[s + 1] += tree.child_start[s];
        }
        tree.children.clear();
        tree.children.resize(tree.child_start[ns], 0);
        let mut next = tree.child_start.clone();
        for s in 0..ns {
            if let Some(p) = parent(s) {
                tree.children[next[p]] = s as Index;
                next[p] += 1;
            }
        }
        // Extend-add positions, from each parent's map of its front.
        tree.rel_start.clear();
        tree.rel_start.resize(ns + 1, 0);
        for s in 0..ns {
            tree.rel_start[s + 1] = tree.rel_start[s] + Supernode::of(symbolic, s).below;
        }
        tree.rel.clear();
        tree.rel.resize(tree.rel_start[ns], NONE);
        for p in 0..ns {
            let sp = Supernode::of(symbolic, p);
            let pattern = sp.pattern(symbolic);
            for k in 0..sp.width {
                local[sp.begin + k] = k as Index;
            }
            for (i, &r) in pattern.iter().enumerate() {
                local[r as usize] = (sp.width + i) as Index;
            }
            for &c in &tree.children[tree.child_start[p]..tree.child_start[p + 1]] {
                let c = c as usize;
                let sc = Supernode::of(symbolic, c);
                let mut last = None;
                for (i, &r) in sc.pattern(symbolic).iter().enumerate() {
                    let l = local[r as usize];
                    // Every row in the parent's front, in increasing positions.
                    if l == NONE || last.is_some_and(|m| l <= m) {
                        return false;
                    }
                    last = Some(l);
                    tree.rel[tree.rel_start[c] + i] = l;
                }
            }
            local[sp.begin..sp.begin + sp.width].fill(NONE);
            for &r in pattern {
                local[r as usize] = NONE;
            }
        }
        owner.fill(NONE);
        self.split = split(symbolic, tree);
        self.updates.resize_with(ns, Vec::new);
        self.updates.truncate(ns);
        true
    }

    /// The split (supernodes `[0, at)` and `[at, fork)`, two disjoint unions of subtrees),
    /// if the tree has one that pays.
    pub(crate) fn split(&self) -> Option<(usize, usize)> {
        self.split
    }

    /// Factorizes `a_lower` (the lower triangle, in the symbolic factor's order) into `l`, in
    /// faer's supernodal layout; false when a pivot is not positive. With a `helper`, the
    /// second part of the split on it while this thread does the first, then the rest here.
    /// Each supernode's operations are the same either way: the same bits.
    pub(crate) fn factorize(
        &mut self,
        symbolic: &SymbolicSupernodalCholesky<Index>,
        a_lower: SparseColMatRef<'_, Index, f64>,
        l: &mut [f64],
        helper: Option<&Helper>,
    ) -> bool {
        let ns = symbolic.n_supernodes();
        let (tree, pool) = (&self.tree, &self.pool);
        let [t0, t1] = &mut self.threads;
        let ok = match (self.split, helper) {
            (Some((at, fork)), Some(helper)) => {
                let values_at = |s: usize| Supernode::of(symbolic, s).values_at;
                let (l0, rest) = l.split_at_mut(values_at(at));
                let (l1, l_top) = rest.split_at_mut(values_at(fork) - values_at(at));
                let (u0, rest) = self.updates.split_at_mut(at);
                let (u1, _) = rest.split_at_mut(fork - at);
                let (ok0, ok1) = helper.join_once(
                    || factor_range(symbolic, tree, a_lower, (l0, 0), (u0, 0), 0..at, t0, pool),
                    || {
                        let l = (l1, values_at(at));
                        factor_range(symbolic, tree, a_lower, l, (u1, at), at..fork, t1, pool)
                    },
                );
                let (l, u) = ((l_top, values_at(fork)), (&mut self.updates[..], 0));
                ok0 && ok1 && factor_range(symbolic, tree, a_lower, l, u, fork..ns, t0, pool)
            }
            _ => factor_range(
                symbolic,
                tree,
                a_lower,
                (l, 0),
                (&mut self.updates, 0),
                0..ns,
                t0,
                pool,
            ),
        };
        // Updates not yet added (a root's is empty; a failed run's) go back.
        for u in &mut self.updates {
            let u = std::mem::take(u);
            give_back(pool, u);
        }
        ok
    }
}

/// The split of the tree for two threads: from the root down its chain of single children to
/// the first supernode with several (the fork), whose children's subtrees are cut in two
/// groups of about equal multiply–adds, each group a consecutive range of supernodes (a
/// nested dissection's two sides are: their columns are). None for a forest, subtrees that
/// interleave, or a fork too lopsided to pay.
fn split(symbolic: &SymbolicSupernodalCholesky<Index>, tree: &Tree) -> Option<(usize, usize)> {
    let ns = symbolic.n_supernodes();
    if ns < 3 || Supernode::of(symbolic, ns - 1).below != 0 {
        return None;
    }
    let kids = |s: usize| &tree.children[tree.child_start[s]..tree.child_start[s + 1]];
    let (mut fork, mut chain) = (ns - 1, 0);
    while let [only] = kids(fork) {
        fork = *only as usize;
        chain += 1;
    }
    // Every supernode above the fork on its chain (no other subtree up there).
    if kids(fork).len() < 2 || chain != ns - 1 - fork {
        return None;
    }
    // Below the fork: which of its children each supernode descends from (parents come
    // after their children), and each child's range of supernodes and multiply–adds.
    let mut parent = vec![NONE; fork];
    for p in 0..=fork {
        for &c in kids(p) {
            parent[c as usize] = p as Index;
        }
    }
    let mut from = vec![NONE; fork];
    let mut span = vec![(usize::MAX, 0usize, 0.0f64); fork];
    for s in (0..fork).rev() {
        // (A root below the fork: a forest, not split.)
        let p = parent[s];
        if p == NONE {
            return None;
        }
        let p = p as usize;
        let c = if p == fork { s } else { from[p] as usize };
        from[s] = c as Index;
        let sn = Supernode::of(symbolic, s);
        let (w, f) = (sn.width as f64, (sn.width + sn.below) as f64);
        let (lo, hi, work) = &mut span[c];
        (*lo, *hi, *work) = ((*lo).min(s), (*hi).max(s), *work + w * f * f);
    }
    let mut groups: Vec<(usize, usize, f64)> =
        kids(fork).iter().map(|&c| span[c as usize]).collect();
    groups.sort_by_key(|g| g.0);
    // The children's ranges must tile [0, fork) without interleaving.
    let mut next = 0;
    for &(lo, hi, _) in &groups {
        if lo != next {
            return None;
        }
        next = hi + 1;
    }
    let total: f64 = groups.iter().map(|g| g.2).sum();
    let (mut acc, mut best) = (0.0, (0.0, 0));
    for g in &groups[..groups.len() - 1] {
        acc += g.2;
        let share = acc.min(total - acc) / total;
        if share > best.0 {
            best = (share, g.1 + 1);
        }
    }
    (best.0 >= MIN_SHARE).then_some((best.1, fork))
}

/// Updates of at most this many entries are allocated and freed by the allocator (its
/// small-size caches are fast); larger ones are kept for reuse.
const KEEP_FROM: usize = 1 << 14;

/// Empty storage for an update of `len` entries: the smallest kept one that holds it (so
/// that what is kept stays near what is live at once), or a new one.
fn take_storage(pool: &Mutex<Vec<Vec<f64>>>, len: usize) -> Vec<f64> {
    if len > KEEP_FROM {
        let mut free = pool.lock().unwrap_or_else(|e| e.into_inner());
        let best = free
            .iter()
            .enumerate()
            .filter(|(_, v)| v.capacity() >= len)
            .min_by_key(|(_, v)| v.capacity())
            .map(|(k, _)| k);
        if let Some(k) = best {
            let mut v = free.swap_remove(k);
            v.clear();
            return v;
        }
    }
    Vec::with_capacity(len)
}

/// Storage of an update that has been added into its parent's: kept if large.
fn give_back(pool: &Mutex<Vec<Vec<f64>>>, v: Vec<f64>) {
    if v.capacity() > KEEP_FROM {
        pool.lock().unwrap_or_else(|e| e.into_inner()).push(v);
    }
}

/// Factorizes the supernodes `range` in order: each child's update already in `updates` (its
/// own factorization before, in this range or an earlier one). `l` and `updates` are the
/// parts of the factor's values and of the updates from the offsets given with them.
#[allow(clippy::too_many_arguments)]
fn factor_range(
    symbolic: &SymbolicSupernodalCholesky<Index>,
    tree: &Tree,
    a_lower: SparseColMatRef<'_, Index, f64>,
    (l, l_at): (&mut [f64], usize),
    (updates, u_at): (&mut [Vec<f64>], usize),
    range: Range<usize>,
    scratch: &mut ThreadScratch,
    pool: &Mutex<Vec<Vec<f64>>>,
) -> bool {
    let par = Par::Seq;
    let ThreadScratch { local, mem } = scratch;
    let mem = &mut mem.as_mut().expect("analysed").0;
    for s in range {
        let sn = Supernode::of(symbolic, s);
        let (w, r) = (sn.width, sn.below);
        let f = w + r;
        let pattern = sn.pattern(symbolic);
        for (i, &row) in pattern.iter().enumerate() {
            local[row as usize] = (w + i) as Index;
        }
        // The front: the supernode's columns (`l`'s, f × w) and its update (r × r).
        let ls = &mut l[sn.values_at - l_at..sn.values_at - l_at + f * w];
        ls.fill(0.0);
        let mut u = take_storage(pool, r * r);
        u.resize(r * r, 0.0);
        for j in 0..w {
            let col = sn.begin + j;
            let (idx, val) = (a_lower.row_idx_of_col_raw(col), a_lower.val_of_col(col));
            for (&i, &v) in idx.iter().zip(val) {
                let i = i as usize;
                if i < col {
                    continue;
                }
                let li = if i < sn.begin + w {
                    i - sn.begin
                } else {
                    local[i] as usize
                };
                ls[li + j * f] += v;
            }
        }
        // Each child's update, added where its rows are in this front.
        for &c in &tree.children[tree.child_start[s]..tree.child_start[s + 1]] {
            let c = c as usize;
            let uc = std::mem::take(&mut updates[c - u_at]);
            let rel = &tree.rel[tree.rel_start[c]..tree.rel_start[c + 1]];
            let rc = rel.len();
            for (jj, &lj) in rel.iter().enumerate() {
                let lj = lj as usize;
                let column = &uc[jj * rc + jj..(jj + 1) * rc];
                let targets = &rel[jj..];
                if lj < w {
                    let dst = &mut ls[lj * f..(lj + 1) * f];
                    for (&li, &v) in targets.iter().zip(column) {
                        dst[li as usize] += v;
                    }
                } else {
                    let dst = &mut u[(lj - w) * r..(lj - w + 1) * r];
                    for (&li, &v) in targets.iter().zip(column) {
                        dst[li as usize - w] += v;
                    }
                }
            }
            give_back(pool, uc);
        }
        for &row in pattern {
            local[row as usize] = NONE;
        }
        let front = MatMut::from_column_major_slice_mut(ls, f, w);
        let (mut top, mut bottom) = front.split_at_row_mut(w);
        if cholesky_in_place(
            top.rb_mut(),
            LltRegularization::default(),
            par,
            MemStack::new(mem),
            Default::default(),
        )
        .is_err()
        {
            // (The updates not yet added go back in `Multifrontal::factorize`.)
            return false;
        }
        solve_lower_triangular_in_place(top.rb().conjugate(), bottom.rb_mut().transpose_mut(), par);
        if r > 0 {
            let bottom: MatRef<'_, f64> = bottom.rb();
            triangular_matmul(
                MatMut::from_column_major_slice_mut(&mut u, r, r),
                BlockStructure::TriangularLower,
                Accum::Add,
                bottom,
                BlockStructure::Rectangular,
                bottom.transpose(),
                BlockStructure::Rectangular,
                -1.0,
                par,
            );
        }
        updates[s - u_at] = u;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::supernodal::tests::{compressed, faer_supernodal, symmetric_times};
    use crate::supernodal::{SplitScratch, solve_in_place, solve_in_place_split};
    use faer::Side;
    use faer::sparse::SymbolicSparseColMatRef;
    use faer::sparse::linalg::cholesky::{SymbolicCholeskyRaw, SymmetricOrdering};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The lower triangle of `I + Σ w_e (e_a − e_b)(e_a − e_b)ᵀ` over two `k × k` grids with
    /// their diagonals, numbered one after the other, and a line of `k` nodes after them
    /// joined to the first grid's last column and the second's first (a nested dissection's
    /// shape: two sides, then their separator); unless `joined`, the line is left out (a
    /// forest of two trees). `negative` makes that node's diagonal negative (not positive
    /// definite).
    fn two_grids(
        k: usize,
        negative: Option<usize>,
        joined: bool,
    ) -> (Vec<u32>, Vec<u32>, Vec<f64>) {
        let n = 2 * k * k + if joined { k } else { 0 };
        let mut seed = 3u64;
        let mut weight = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            0.01 + 100.0 * ((seed >> 11) as f64 / (1u64 << 53) as f64)
        };
        let mut edges = Vec::new();
        for g in 0..2 {
            let at = |i: usize, j: usize| g * k * k + i * k + j;
            for i in 0..k {
                for j in 0..k {
                    for (di, dj) in [(0, 1), (1, 0), (1, 1)] {
                        if i + di < k && j + dj < k {
                            edges.push((at(i, j), at(i + di, j + dj)));
                        }
                    }
                }
            }
        }
        for i in (0..k).filter(|_| joined) {
            let sep = 2 * k * k + i;
            edges.push((i * k + k - 1, sep));
            edges.push((k * k + i * k, sep));
            if i + 1 < k {
                edges.push((sep, sep + 1));
            }
        }
        let mut cols: Vec<Vec<(u32, f64)>> = (0..n).map(|c| vec![(c as u32, 1.0)]).collect();
        for (a, b) in edges {
            let w = weight();
            cols[a][0].1 += w;
            cols[b][0].1 += w;
            cols[a.min(b)].push((a.max(b) as u32, -w));
        }
        if let Some(v) = negative {
            cols[v][0].1 = -1.0;
        }
        compressed(cols)
    }

    /// The upper triangle's pattern of the lower triangle `ptr`, `idx` (the symbolic
    /// analysis reads the upper triangle, as `normal.rs` gives it).
    fn upper_triangle(ptr: &[u32], idx: &[u32]) -> (Vec<u32>, Vec<u32>) {
        let n = ptr.len() - 1;
        let mut upper: Vec<Vec<u32>> = vec![Vec::new(); n];
        for c in 0..n {
            for &r in &idx[ptr[c] as usize..ptr[c + 1] as usize] {
                upper[r as usize].push(c as u32);
            }
        }
        let (mut uptr, mut uidx) = (vec![0u32], Vec::new());
        for mut c in upper {
            c.sort();
            uidx.extend(c);
            uptr.push(uidx.len() as u32);
        }
        (uptr, uidx)
    }

    /// A factor's values, or none when refused.
    type Values = Option<Vec<f64>>;

    /// For each of `negatives` in turn (see [`two_grids`], one pattern), faer's factor
    /// values and ours on one thread and split over two, one [`Multifrontal`] analysed once
    /// for all of them; and whether it split.
    fn factors(
        k: usize,
        negatives: &[Option<usize>],
        joined: bool,
    ) -> (Vec<(Values, [Values; 2])>, bool) {
        let (ptr, idx, _) = two_grids(k, None, joined);
        let n = ptr.len() - 1;
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &ptr, None, &idx);
        let (uptr, uidx) = upper_triangle(&ptr, &idx);
        let upper = SymbolicSparseColMatRef::new_checked(n, n, &uptr, None, &uidx);
        let mut mf = Multifrontal::default();
        let helper = Helper::start().expect("a thread");
        let results = negatives
            .iter()
            .map(|&negative| {
                let (_, _, val) = two_grids(k, negative, joined);
                let a = SparseColMatRef::new(pattern, &val);
                let (symbolic, faer) =
                    faer_supernodal(upper, Side::Upper, SymmetricOrdering::Identity, a);
                let SymbolicCholeskyRaw::Supernodal(s) = symbolic.raw() else {
                    panic!("supernodal forced");
                };
                if mf.tree.child_start.is_empty() {
                    assert!(mf.analyse(s));
                }
                let ours = [None, Some(&helper)].map(|h| {
                    let mut l = vec![0.0; symbolic.len_val()];
                    // Twice: the second factorization reuses the first's storage.
                    for _ in 0..2 {
                        if !mf.factorize(s, a, &mut l, h) {
                            return None;
                        }
                    }
                    Some(l)
                });
                (faer, ours)
            })
            .collect();
        (results, mf.split().is_some())
    }

    /// Ours on one thread and two against faer's factor (to 10⁻¹² of its largest entry) and
    /// against each other (bit for bit).
    fn assert_faers(k: usize, (faer, [one, two]): &(Values, [Values; 2])) {
        let (faer, one, two) = (
            faer.as_ref().unwrap(),
            one.as_ref().unwrap(),
            two.as_ref().unwrap(),
        );
        let scale = faer.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (e, (a, b)) in faer.iter().zip(one.iter().zip(two)) {
            assert!(
                (a - e).abs() <= 1e-12 * scale,
                "k = {k}: {a} against faer's {e}"
            );
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "k = {k}: one thread and two differ"
            );
        }
    }

    #[test]
    fn the_multifrontal_factor_is_faers_on_one_thread_and_on_two() {
        for (k, joined) in [(8, true), (16, true), (8, false)] {
            let (results, split) = factors(k, &[None], joined);
            // Two trees (no separator): no fork, one thread.
            assert_eq!(split, joined, "k = {k}: the two grids are the two parts");
            assert_faers(k, &results[0]);
        }
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_is_refused_on_one_thread_and_on_two() {
        let k = 12;
        // A node of the first grid, of the second, of the separator, each followed by a good
        // matrix of the same pattern, which the same analysis factorizes as faer does.
        let bad = [5, k * k + 7, 2 * k * k + 3];
        let negatives: Vec<Option<usize>> = bad.iter().flat_map(|&v| [Some(v), None]).collect();
        let (results, split) = factors(k, &negatives, true);
        assert!(split);
        for (negative, result) in negatives.iter().zip(&results) {
            match negative {
                Some(v) => {
                    let (faer, [one, two]) = result;
                    assert!(faer.is_none(), "node {v}: faer refuses it");
                    assert!(one.is_none() && two.is_none(), "node {v}");
                }
                None => assert_faers(k, result),
            }
        }
    }

    #[test]
    fn the_split_solve_gives_the_one_thread_solves_bits() {
        // The two grids and their separator: the solve's two parts at once, the second's
        // updates of the separator's rows added after the first's, as one thread adds them.
        // Grids of 6 × 6 to 24 × 24 nodes (at 3 × 3 the tree does not split).
        let helper = Helper::start().expect("a thread");
        let mut scratch = SplitScratch::default();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for k in [6, 16, 24] {
            let (ptr, idx, val) = two_grids(k, None, true);
            let n = ptr.len() - 1;
            let pattern = SymbolicSparseColMatRef::new_checked(n, n, &ptr, None, &idx);
            let (uptr, uidx) = upper_triangle(&ptr, &idx);
            let upper = SymbolicSparseColMatRef::new_checked(n, n, &uptr, None, &uidx);
            let a = SparseColMatRef::new(pattern, &val);
            let (symbolic, l) = faer_supernodal(upper, Side::Upper, SymmetricOrdering::Identity, a);
            let l = l.expect("positive definite");
            let SymbolicCholeskyRaw::Supernodal(s) = symbolic.raw() else {
                panic!("supernodal forced");
            };
            let mut mf = Multifrontal::default();
            assert!(mf.analyse(s));
            let split = mf.split().expect("the two grids are the two parts");
            let b: Vec<f64> = (0..n).map(|_| rng.random_range(-0.5..0.5)).collect();
            let mut one = b.clone();
            solve_in_place(s, &l, &mut one, &mut Vec::new());
            // Twice: the second solve reuses the first's scratch (and every size reuses the
            // larger ones').
            for _ in 0..2 {
                let mut two = b.clone();
                solve_in_place_split(s, &l, &mut two, split, &mut scratch, &helper);
                for (r, (x1, x2)) in one.iter().zip(&two).enumerate() {
                    assert_eq!(
                        x1.to_bits(),
                        x2.to_bits(),
                        "k = {k}, row {r}: one thread and two differ"
                    );
                }
            }
            // And it solves the system (the identity ordering: the factor's order is the
            // matrix's).
            let ax = symmetric_times(&ptr, &idx, &val, &one);
            for (r, (ax, b)) in ax.iter().zip(&b).enumerate() {
                assert!((ax - b).abs() <= 1e-9, "k = {k}, row {r}: {ax} ≠ {b}");
            }
        }
    }
}
