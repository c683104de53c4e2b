//! The last analysis's ordering of the normal equations, kept so that the next analysis
//! orders afresh only the groups of unknowns (people) whose rows changed: the others keep
//! their places, as whole subtrees of the last elimination tree.
//!
//! Why it is exact about fill: a group is *clean* when its rows (by key) are the last
//! analysis's and so are those of every descendant of it in the last elimination tree; the
//! clean groups form whole subtrees, each touching only *dirty* groups outside it (an edge
//! between two subtrees would have made one an ancestor of the other). Eliminated first, in
//! their old order, the clean groups make exactly their old fill, and each subtree leaves
//! one clique on the dirty groups around it. The dirty groups are then ordered by minimum
//! degree on their own rows and those cliques: the graph that is left after the clean ones.
//! Any ordering factorizes correctly (the pattern of `L` is analysed anew), so what this
//! risks is fill, not answers: the fill drifts up from analysis to analysis, so all groups
//! are ordered afresh every [`KeptOrdering::FRESH_EVERY`] analyses, and whenever more than
//! [`KeptOrdering::MAX_DIRTY_SHARE`] of them are dirty (where keeping saves nothing), then
//! for a while without looking.
//!
//! The orderings then depend on the analyses before: all of that is in the memory
//! ([`KeptOrdering::memory`]), with the last analysis's ordering and a hash of its structure,
//! which a restored solver's first analysis takes as it is when `J` has that structure (the
//! original analysed nothing again there). Measured in benches/README.md, session 29.

use moreau_core::{ConstraintKey, ConstraintRows};

use crate::products::Index;

const NONE: Index = Index::MAX;

/// The last analysis's rows and elimination tree, and scratch for the next ordering (see
/// the module's documentation).
#[derive(Debug, Clone, Default)]
pub(crate) struct KeptOrdering {
    // The last analysis, or nothing (`parent` empty): its rows sorted by key, each with the
    // places (in the elimination order) of the groups of its first and second unknowns
    // (`NONE` for a row of one group); per place, the rows of its group and its parent in
    // the elimination tree (`NONE` at a root).
    rows: Vec<(ConstraintKey, [Index; 2])>,
    count: Vec<Index>,
    parent: Vec<Index>,
    // Analyses since every group was last ordered afresh, and analyses left before a kept
    // ordering is tried again (after one with too many groups dirty).
    since_fresh: usize,
    skip: usize,
    // Whether `row_groups` are those of the analysis under way (found by `dirty_graph`).
    grouped: bool,
    // Read from a memory: the last analysis's ordering (the group at each place) and a hash
    // of the structure of `J` it was made for, which the next analysis takes as it is if it
    // is of that structure (where the original solver analysed nothing again).
    restored: Option<(u64, Vec<Index>)>,
    // Scratch: each new row's groups; each new group's old place and row count; each old
    // place's new group (if clean), whether it is dirty and its subtree; each new group's
    // index among the dirty ones; the graph's entries; the dirty groups; the (subtree, dirty
    // group) pairs of the rows between them, then by subtree (a counting sort: each
    // subtree's start, a cursor per subtree, the dirty groups in subtree order); the last
    // subtree each dirty group was found around.
    row_groups: Vec<[Index; 2]>,
    place_of: Vec<Index>,
    rows_of: Vec<Index>,
    owner: Vec<Index>,
    dirty_place: Vec<bool>,
    subtree: Vec<Index>,
    dirty_index: Vec<Index>,
    pairs: Vec<[Index; 2]>,
    dirty: Vec<Index>,
    around: Vec<[Index; 2]>,
    tree_start: Vec<Index>,
    tree_fill: Vec<Index>,
    around_by_tree: Vec<Index>,
    mark: Vec<Index>,
}

/// The groups of each row's unknowns (the first's, then another's, or `NONE`); false when
/// a row touches more than two groups.
fn groups_of_rows(j: &ConstraintRows, group_of: &[usize], out: &mut Vec<[Index; 2]>) -> bool {
    out.clear();
    let (starts, cols) = (j.row_starts(), j.columns());
    for i in 0..j.len() {
        let mut g = [NONE; 2];
        for &c in &cols[starts[i]..starts[i + 1]] {
            let x = group_of[c] as Index;
            if g[0] == NONE || g[0] == x {
                g[0] = x;
            } else if g[1] == NONE || g[1] == x {
                g[1] = x;
            } else {
                return false;
            }
        }
        out.push(g);
    }
    true
}

impl KeptOrdering {
    /// Every this many analyses all groups are ordered afresh: the factor's multiply–adds
    /// drift up while subtrees keep their places (cromosim's scene: 1.3 % more than fresh
    /// orderings' every 4 analyses, 4.2 % every 16, 10 % never; benches/README.md, session
    /// 29).
    pub(crate) const FRESH_EVERY: usize = 16;

    /// With more than this share of the groups dirty, all are ordered afresh: the minimum
    /// degree of the dirty ones and the cliques costs about what a fresh one does, and the
    /// factor has more fill (the jammed 2,000 at half its groups dirty: 10 % more
    /// multiply–adds for no time saved; benches/README.md, session 29) …
    pub(crate) const MAX_DIRTY_SHARE: f64 = 0.4;

    /// … and so are they in this many analyses after, without finding the dirty ones (a
    /// scene whose contacts change that much a step goes on doing so).
    const SKIP_AFTER_TOO_DIRTY: usize = 8;

    /// Forgets the last analysis: the next ordering is a fresh one.
    pub(crate) fn forget(&mut self) {
        self.rows.clear();
        self.count.clear();
        self.parent.clear();
    }

    /// Analyses since every group was last ordered afresh (0: the last analysis was).
    #[cfg(test)]
    pub(crate) fn since_fresh(&self) -> usize {
        self.since_fresh
    }

    /// The groups the last ordering that started from a kept analysis found dirty.
    #[cfg(test)]
    pub(crate) fn dirty(&self) -> &[Index] {
        &self.dirty
    }

    /// Whether there is a last analysis.
    #[cfg(test)]
    pub(crate) fn is_kept(&self) -> bool {
        !self.parent.is_empty()
    }

    /// The ordering read from a memory and the hash of the structure it was made for, once
    /// (see [`Self::set_memory`]).
    pub(crate) fn take_restored(&mut self) -> Option<(u64, Vec<Index>)> {
        self.restored.take()
    }

    /// Finds the dirty groups of `j` (groups `group_of`, `groups` of them) against the last
    /// analysis, and the graph the minimum-degree ordering of them reads ([`Self::pairs`]:
    /// entries of its upper triangle, `[row, column]`, repeats allowed, no diagonal) on the
    /// dirty groups numbered `0..d`: their rows, and the clique each clean subtree leaves on
    /// the dirty groups around it. `None`, for a fresh ordering, when there is no last
    /// analysis, when it is time for a fresh one ([`Self::FRESH_EVERY`], and
    /// [`Self::SKIP_AFTER_TOO_DIRTY`] analyses after one with more than `max_dirty` groups
    /// dirty) or the rows cannot be matched (a row of more than two groups); else `d`.
    pub(crate) fn dirty_graph(
        &mut self,
        j: &ConstraintRows,
        group_of: &[usize],
        groups: usize,
        max_dirty: usize,
    ) -> Option<usize> {
        self.grouped = false;
        if self.skip > 0 {
            self.skip -= 1;
            return None;
        }
        if self.parent.is_empty() || self.since_fresh + 1 >= Self::FRESH_EVERY {
            return None;
        }
        if !groups_of_rows(j, group_of, &mut self.row_groups) {
            return None;
        }
        self.grouped = true;
        let places = self.parent.len();
        // Each new group's old place, by its rows found among the last analysis's, slot by
        // slot; a group whose rows disagree, or that has a row not found, is dirty (`NONE`).
        const UNSET: Index = NONE - 1;
        self.place_of.clear();
        self.place_of.resize(groups, UNSET);
        self.rows_of.clear();
        self.rows_of.resize(groups, 0);
        let keys = j.keys();
        let mut from = 0;
        for (i, g) in self.row_groups.iter().enumerate() {
            let old = find_from(&self.rows, keys[i], &mut from, |r| r.0).map(|o| self.rows[o].1);
            // A row that lost or gained a group leaves both dirty.
            let same_shape = old.is_some_and(|o| (o[1] == NONE) == (g[1] == NONE));
            for slot in 0..2 {
                let x = g[slot];
                if x == NONE {
                    continue;
                }
                let x = x as usize;
                self.rows_of[x] += 1;
                let at = &mut self.place_of[x];
                match old.map(|o| o[slot]) {
                    Some(p) if same_shape && (*at == UNSET || *at == p) => *at = p,
                    _ => *at = NONE,
                }
            }
        }
        // Clean so far: every row found at the same place, and as many rows as that place's
        // group had. Each old place owned by at most one new group.
        self.owner.clear();
        self.owner.resize(places, NONE);
        self.dirty_place.clear();
        self.dirty_place.resize(places, false);
        for g in 0..groups {
            let p = self.place_of[g];
            if p >= places as Index || self.count[p as usize] != self.rows_of[g] {
                self.place_of[g] = NONE;
                continue;
            }
            let p = p as usize;
            if self.owner[p] == NONE {
                self.owner[p] = g as Index;
            } else {
                self.dirty_place[p] = true;
            }
        }
        // Every place without an owner is dirty, and every ancestor of a dirty place (parents
        // come after their children).
        for p in 0..places {
            if self.owner[p] == NONE {
                self.dirty_place[p] = true;
            }
            let q = self.parent[p];
            if self.dirty_place[p] && q != NONE {
                self.dirty_place[q as usize] = true;
            }
        }
        // Each clean place's subtree, numbered from its root down (a parent comes after its
        // children).
        self.subtree.clear();
        self.subtree.resize(places, NONE);
        let mut trees = 0;
        for p in (0..places).rev() {
            if self.dirty_place[p] {
                continue;
            }
            let q = self.parent[p];
            self.subtree[p] = if q != NONE && !self.dirty_place[q as usize] {
                self.subtree[q as usize]
            } else {
                trees += 1;
                trees - 1
            };
        }
        // The dirty groups, numbered in their own order.
        self.dirty_index.clear();
        self.dirty_index.resize(groups, NONE);
        self.dirty.clear();
        for g in 0..groups {
            let p = self.place_of[g];
            if p == NONE || self.dirty_place[p as usize] {
                self.dirty_index[g] = self.dirty.len() as Index;
                self.dirty.push(g as Index);
            }
        }
        if self.dirty.len() > max_dirty {
            self.skip = Self::SKIP_AFTER_TOO_DIRTY;
            return None;
        }
        let d = self.dirty.len() as Index;
        // The graph: rows between dirty groups, and a clique on the dirty groups around each
        // subtree (collected by subtree, a counting sort, each group once: `mark`).
        self.pairs.clear();
        self.around.clear();
        let trees = trees as usize;
        self.tree_start.clear();
        self.tree_start.resize(trees + 1, 0);
        let node = |x: Index| match self.dirty_index[x as usize] {
            NONE => d + self.subtree[self.place_of[x as usize] as usize],
            i => i,
        };
        for g in &self.row_groups {
            if g[1] == NONE {
                continue;
            }
            let (a, b) = (node(g[0]), node(g[1]));
            match (a < d, b < d) {
                (true, true) => self.pairs.push([a.min(b), a.max(b)]),
                (true, false) => self.around.push([b - d, a]),
                (false, true) => self.around.push([a - d, b]),
                // Two clean groups: of one subtree (see the module's documentation).
                (false, false) if a != b => return None,
                (false, false) => continue,
            }
        }
        for &[t, _] in &self.around {
            self.tree_start[t as usize + 1] += 1;
        }
        for t in 0..trees {
            self.tree_start[t + 1] += self.tree_start[t];
        }
        self.tree_fill.clear();
        self.tree_fill.extend_from_slice(&self.tree_start[..trees]);
        self.around_by_tree.clear();
        self.around_by_tree.resize(self.around.len(), 0);
        for &[t, a] in &self.around {
            let at = &mut self.tree_fill[t as usize];
            self.around_by_tree[*at as usize] = a;
            *at += 1;
        }
        self.mark.clear();
        self.mark.resize(d as usize, NONE);
        for t in 0..trees {
            let start = self.tree_start[t] as usize;
            let mut end = start;
            for k in start..self.tree_start[t + 1] as usize {
                let a = self.around_by_tree[k];
                if self.mark[a as usize] != t as Index {
                    self.mark[a as usize] = t as Index;
                    self.around_by_tree[end] = a;
                    end += 1;
                }
            }
            let clique = &self.around_by_tree[start..end];
            for (k, &a) in clique.iter().enumerate() {
                for &b in &clique[k + 1..] {
                    self.pairs.push([a.min(b), a.max(b)]);
                }
            }
        }
        Some(d as usize)
    }

    /// The entries of the graph [`Self::dirty_graph`] made.
    pub(crate) fn pairs(&self) -> &[[Index; 2]] {
        &self.pairs
    }

    /// The ordering of every group: the clean ones in their old order, then the dirty ones
    /// in `dirty_order` (the dirty groups `0..d` of [`Self::dirty_graph`] in the order
    /// minimum degree gave them).
    pub(crate) fn ordering(
        &mut self,
        dirty_order: &[Index],
        perm: &mut [Index],
        perm_inv: &mut [Index],
    ) {
        let mut k = 0;
        for p in 0..self.dirty_place.len() {
            if !self.dirty_place[p] {
                perm[k] = self.owner[p];
                k += 1;
            }
        }
        for &x in dirty_order {
            perm[k] = self.dirty[x as usize];
            k += 1;
        }
        debug_assert_eq!(k, perm.len());
        for (k, &g) in perm.iter().enumerate() {
            perm_inv[g as usize] = k as Index;
        }
        self.since_fresh += 1;
    }

    /// Keeps the analysis just made of `j` (groups `group_of`, at places `place`), whose
    /// elimination tree's parent of place `k` is `parent(k)`; `fresh` when every group was
    /// ordered afresh. Forgets it when a row touches more than two groups, and when the next
    /// analysis will not look at it ([`Self::SKIP_AFTER_TOO_DIRTY`]). Call after
    /// [`Self::dirty_graph`] of the same analysis (whose rows' groups it takes).
    pub(crate) fn keep(
        &mut self,
        j: &ConstraintRows,
        group_of: &[usize],
        place: &[Index],
        parent: impl Fn(usize) -> Option<usize>,
        fresh: bool,
    ) {
        if fresh {
            self.since_fresh = 0;
        }
        let grouped = std::mem::take(&mut self.grouped);
        if self.skip > 0 || !(grouped || groups_of_rows(j, group_of, &mut self.row_groups)) {
            self.forget();
            return;
        }
        let places = place.len();
        let at = |g: Index| if g == NONE { NONE } else { place[g as usize] };
        self.rows.clear();
        self.rows.extend(
            j.keys()
                .iter()
                .zip(&self.row_groups)
                .map(|(&key, g)| (key, [at(g[0]), at(g[1])])),
        );
        self.rows.sort_unstable_by_key(|r| r.0);
        self.count.clear();
        self.count.resize(places, 0);
        for g in &self.row_groups {
            for &x in g.iter().filter(|&&x| x != NONE) {
                self.count[place[x as usize] as usize] += 1;
            }
        }
        self.parent.clear();
        self.parent
            .extend((0..places).map(|k| parent(k).map_or(NONE, |q| q as Index)));
    }
}

impl KeptOrdering {
    /// `[since_fresh, skip, G, (structure_high, structure_low, the group at each of the G
    /// places)?, P, (rows, parent) of each of the P places, R, (key_high, key_low, place₀,
    /// place₁) of each of the R rows]` appended to `out` (−1 for `NONE`; keys and the hash in
    /// two 32-bit halves, exact in an f64): `last`, the last analysis's structure's hash and
    /// ordering (`G` = 0 without one), then the analysis kept for the next ordering (`P` =
    /// `R` = 0 without one). An ordering read from a memory and not yet taken stands for the
    /// last analysis's.
    pub(crate) fn memory(&self, last: Option<(u64, &[Index])>, out: &mut Vec<f64>) {
        let number = |x: Index| if x == NONE { -1.0 } else { f64::from(x) };
        // (No groups, no ordering: the same whatever came before.)
        let last = (self.restored.as_ref().map(|(h, o)| (*h, &o[..])))
            .or(last)
            .filter(|l| !l.1.is_empty());
        let groups = last.map_or(0, |l| l.1.len());
        out.reserve(8 + groups + 2 * self.parent.len() + 4 * self.rows.len());
        out.extend([self.since_fresh as f64, self.skip as f64, groups as f64]);
        if let Some((hash, order)) = last {
            out.extend([(hash >> 32) as f64, (hash as u32) as f64]);
            out.extend(order.iter().map(|&g| f64::from(g)));
        }
        out.push(self.parent.len() as f64);
        for (&c, &q) in self.count.iter().zip(&self.parent) {
            out.extend([f64::from(c), number(q)]);
        }
        out.push(self.rows.len() as f64);
        for &(key, [a, b]) in &self.rows {
            out.extend([
                (key >> 32) as f64,
                (key as u32) as f64,
                number(a),
                number(b),
            ]);
        }
    }

    /// Takes what [`Self::memory`] gave at the start of `memory`, and returns the rest;
    /// `None`, with everything forgotten, when it is not one (an ordering that is not a
    /// permutation, a parent not after its child, a place out of range, a damaged count).
    pub(crate) fn set_memory<'a>(&mut self, memory: &'a [f64]) -> Option<&'a [f64]> {
        self.forget();
        let rest = self.read_memory(memory);
        if rest.is_none() {
            self.forget();
            (self.since_fresh, self.skip, self.restored) = (0, 0, None);
        }
        rest
    }

    fn read_memory<'a>(&mut self, memory: &'a [f64]) -> Option<&'a [f64]> {
        let whole =
            |x: f64| (x >= 0.0 && x.fract() == 0.0 && x <= f64::from(u32::MAX)).then_some(x);
        let index = |x: f64, below: usize| {
            if x == -1.0 {
                Some(NONE)
            } else {
                whole(x)
                    .filter(|&x| (x as usize) < below)
                    .map(|x| x as Index)
            }
        };
        let half = |x: f64| whole(x).map(|x| x as u64);
        let (head, memory) = memory.split_at_checked(3)?;
        let (since, skip, groups) = (whole(head[0])?, whole(head[1])?, whole(head[2])? as usize);
        let memory = if groups > 0 {
            let (numbers, memory) = memory.split_at_checked(groups.checked_add(2)?)?;
            let hash = (half(numbers[0])? << 32) | half(numbers[1])?;
            let mut seen = vec![false; groups];
            let mut order = Vec::with_capacity(groups);
            for &g in &numbers[2..] {
                let g = index(g, groups).filter(|&g| g != NONE)?;
                if std::mem::replace(&mut seen[g as usize], true) {
                    return None;
                }
                order.push(g);
            }
            self.restored = Some((hash, order));
            memory
        } else {
            self.restored = None;
            memory
        };
        let (&places, memory) = memory.split_first()?;
        let places = whole(places)? as usize;
        let (numbers, memory) = memory.split_at_checked(places.checked_mul(2)?)?;
        for (p, pair) in numbers.chunks_exact(2).enumerate() {
            let parent = index(pair[1], places)?;
            if parent != NONE && parent as usize <= p {
                return None;
            }
            self.count.push(whole(pair[0])? as Index);
            self.parent.push(parent);
        }
        let (&rows, memory) = memory.split_first()?;
        let rows = whole(rows)? as usize;
        let (numbers, memory) = memory.split_at_checked(rows.checked_mul(4)?)?;
        for r in numbers.chunks_exact(4) {
            let key = (half(r[0])? << 32) | half(r[1])?;
            self.rows
                .push((key, [index(r[2], places)?, index(r[3], places)?]));
        }
        self.rows.sort_unstable_by_key(|r| r.0);
        (self.since_fresh, self.skip) = (since as usize, skip as usize);
        Some(memory)
    }
}

/// A hash of a structure of `J` (its rows' starts and columns, as the last analysis keeps
/// them): whether a restored solver's first analysis is of the structure the original
/// analysed last.
pub(crate) fn structure_hash(row_starts: &[Index], columns: &[Index]) -> u64 {
    let words = row_starts.iter().chain(columns).map(|&x| u64::from(x));
    fnv(std::iter::once(row_starts.len() as u64).chain(words))
}

/// FNV-1a over 64-bit words.
pub(crate) fn fnv(words: impl IntoIterator<Item = u64>) -> u64 {
    words.into_iter().fold(0xcbf2_9ce4_8422_2325, |h, x| {
        (h ^ x).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The position of `key` among `kept`'s (sorted by `key_of`), searched from `from` on by
/// galloping when the key before `from` is below `key` (else from the start), `from` then set
/// past where the search ended: what a binary search over the whole finds (of a key kept
/// twice, either, as there), in a few comparisons for keys that mostly increase.
pub(crate) fn find_from<T>(
    kept: &[T],
    key: ConstraintKey,
    from: &mut usize,
    key_of: impl Fn(&T) -> ConstraintKey,
) -> Option<usize> {
    // Every key before `from` is below `key` when the one just before it is.
    let start = if *from > 0 && *from <= kept.len() && key_of(&kept[*from - 1]) < key {
        *from
    } else {
        0
    };
    // Gallop: the first `start + 2^k − 1` whose key is at least `key` bounds the search.
    let (mut lo, mut step) = (start, 1);
    while lo + step <= kept.len() && key_of(&kept[lo + step - 1]) < key {
        lo += step;
        step *= 2;
    }
    let hi = (lo + step).min(kept.len());
    let at = kept[lo..hi].binary_search_by_key(&key, &key_of);
    let (found, end) = match at {
        Ok(p) => (Some(lo + p), lo + p + 1),
        Err(p) => (None, lo + p),
    };
    *from = end;
    found
}

/// A crowd of `people` disks of radius 0.5 wandering in a box toward its centre, each moving
/// up to `jitter` either way a step, `steps` steps of it: at each, the rows of the pairs
/// closer than 1.2 (by key, lower person first) and one floor row per disk, the gaps `b`
/// over a step of 0.1 s, and each disk's push `w`.
#[cfg(test)]
pub(crate) fn wandering_crowd(
    people: usize,
    steps: usize,
    jitter: f64,
    seed: u64,
) -> Vec<(ConstraintRows, Vec<f64>, Vec<f64>)> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let side = (people as f64).sqrt() * 1.1;
    let mut at: Vec<[f64; 2]> = (0..people)
        .map(|_| [rng.random_range(0.0..side), rng.random_range(0.0..side)])
        .collect();
    (0..steps)
        .map(|_| {
            let mut j = ConstraintRows::new(2 * people);
            let mut b = Vec::new();
            for lo in 0..people {
                for hi in lo + 1..people {
                    let (dx, dy) = (at[hi][0] - at[lo][0], at[hi][1] - at[lo][1]);
                    let d = dx.hypot(dy);
                    if d < 1.2 {
                        let (nx, ny) = (dx / d, dy / d);
                        let key = (lo * people + hi) as ConstraintKey;
                        let row = [
                            (2 * lo, -nx),
                            (2 * lo + 1, -ny),
                            (2 * hi, nx),
                            (2 * hi + 1, ny),
                        ];
                        j.push(key, 0.0, row);
                        b.push((d - 1.0) / 0.1);
                    }
                }
            }
            for (p, x) in at.iter().enumerate() {
                let key = (people * people + p) as ConstraintKey;
                j.push(key, 0.0, [(2 * p, 0.0), (2 * p + 1, 1.0)]);
                b.push((x[1] + 1.0) / 0.1);
            }
            let w: Vec<f64> = at
                .iter()
                .flat_map(|x| {
                    let (dx, dy) = (0.5 * side - x[0], 0.5 * side - x[1]);
                    let d = dx.hypot(dy).max(1e-9);
                    [dx / d, dy / d]
                })
                .collect();
            for x in &mut at {
                let pull = [0.5 * side - x[0], 0.5 * side - x[1]];
                for c in 0..2 {
                    x[c] += 0.002 * pull[c] + rng.random_range(-jitter..jitter);
                }
            }
            (j, b, w)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The galloping search finds what a binary search over the whole finds, for queries
    /// that increase, repeat, go back, miss, and run past either end.
    #[test]
    fn a_search_from_the_last_position_finds_what_a_binary_search_finds() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for len in [0, 1, 2, 5, 64, 1000] {
            let mut keys: Vec<u64> = (0..len)
                .map(|_| rng.random_range(0..4 * len as u64 + 4))
                .collect();
            keys.sort_unstable();
            keys.dedup();
            let kept: Vec<(u64, f64, f64)> = keys.iter().map(|&k| (k, 1.0, 1.0)).collect();
            let top = 4 * len as u64 + 8;
            let mut from = 0;
            for q in 0..3000 {
                let key = match q % 4 {
                    0 | 1 => (q as u64 / 2) % top,
                    2 => rng.random_range(0..top),
                    _ => top + q as u64,
                };
                let expected = kept.binary_search_by_key(&key, |e| e.0).ok();
                assert_eq!(
                    find_from(&kept, key, &mut from, |e| e.0),
                    expected,
                    "len {len} key {key}"
                );
            }
        }
    }

    /// The kept analysis of a small pattern: rows `[key, group, group]` over `places` groups
    /// in their own order, a chain as the elimination tree.
    fn kept(rows: &[(ConstraintKey, usize, Option<usize>)], places: usize) -> KeptOrdering {
        let mut j = ConstraintRows::new(2 * places);
        for &(key, a, b) in rows {
            let mut cols = vec![(2 * a, 1.0), (2 * a + 1, 1.0)];
            if let Some(b) = b {
                cols.extend([(2 * b, -1.0), (2 * b + 1, -1.0)]);
            }
            j.push(key, 0.0, cols);
        }
        let group_of: Vec<usize> = (0..2 * places).map(|c| c / 2).collect();
        let place: Vec<Index> = (0..places as Index).collect();
        let mut k = KeptOrdering::default();
        k.keep(
            &j,
            &group_of,
            &place,
            |p| (p + 1 < places).then_some(p + 1),
            true,
        );
        k
    }

    #[test]
    fn a_kept_analysis_survives_its_memory_and_a_damaged_one_is_forgotten() {
        let k = kept(&[(9, 0, Some(1)), (3, 1, Some(2)), (1 << 40, 2, None)], 3);
        let mut memory = vec![];
        k.memory(Some((0xABCD_0000_1234, &[2, 0, 1])), &mut memory);
        // since, skip, G, hash halves, 3 groups, P, 3 × (rows, parent), R, 3 × (key
        // halves, places)
        assert_eq!(memory.len(), 3 + 2 + 3 + 1 + 6 + 1 + 12);
        assert_eq!(
            &memory[3..8],
            &[0xABCD as f64, 0x1234 as f64, 2.0, 0.0, 1.0]
        );
        assert_eq!(&memory[9..15], &[1.0, 1.0, 2.0, 2.0, 2.0, -1.0]);
        let mut tail = memory.clone();
        tail.extend([7.0, 8.0]);
        let mut restored = KeptOrdering::default();
        assert_eq!(restored.set_memory(&tail), Some(&[7.0, 8.0][..]));
        assert_eq!(
            (
                &restored.rows,
                &restored.count,
                &restored.parent,
                restored.since_fresh
            ),
            (&k.rows, &k.count, &k.parent, k.since_fresh)
        );
        // Until taken, the ordering read stands for the last analysis's.
        let mut again = vec![];
        restored.memory(None, &mut again);
        assert_eq!(again, memory);
        assert_eq!(
            restored.take_restored(),
            Some((0xABCD_0000_1234, vec![2, 0, 1]))
        );
        assert_eq!(restored.take_restored(), None);
        // An ordering that is not a permutation, a parent not after its child, a place
        // beyond the places, a count cut short, a key not a whole number: forgotten, no
        // panic.
        for (at, value) in [
            (6, 2.0),
            (7, 3.0),
            (12, 0.0),
            (16 + 3, 3.0),
            (15, 9.0),
            (16 + 1, 0.5),
        ] {
            let mut damaged = memory.clone();
            damaged[at] = value;
            let mut r = kept(&[(1, 0, None)], 1);
            assert_eq!(r.set_memory(&damaged), None, "memory[{at}] = {value}");
            assert!(
                !r.is_kept() && r.take_restored().is_none(),
                "memory[{at}] = {value}"
            );
        }
        let mut r = KeptOrdering::default();
        assert_eq!(r.set_memory(&memory[..memory.len() - 1]), None);
        assert!(!r.is_kept());
    }
}
