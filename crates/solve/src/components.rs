//! The connected components of a projection problem, and the sub-problems made of some of
//! them: rows that share no unknown, directly or through other rows, are independent
//! problems whose gaps add up, checked each against its share and answered into the whole
//! solution, by several threads at once if need be.

use moreau_core::ConstraintRows;

use crate::problem::{ProjectionProblem, ProjectionSolution, Target};

/// The components of the last problem given to [`split`](Self::split). Scratch only: sized
/// by the largest problem seen, nothing allocated per row once warm.
#[derive(Debug, Default)]
pub(crate) struct Components {
    // union–find over unknowns (roots are the smallest unknown of their set)
    parent: Vec<u32>,
    // component of each root unknown, u32::MAX before it is numbered
    numbered: Vec<u32>,
    // component of each row (NONE: set aside)
    row_component: Vec<u32>,
    // the rows of component c are rows[start[c]..start[c + 1]], in storage order
    start: Vec<u32>,
    rows: Vec<u32>,
}

/// The scratch of a check of components against their shares of a target: per row of the
/// problem checked its slack, per component its gap and violation. One per thread that
/// checks sub-problems of the same [`Components`] at once.
#[derive(Debug, Default)]
pub(crate) struct CheckScratch {
    slack: Vec<f64>,
    gap: Vec<f64>,
    violation: Vec<f64>,
}

/// The whole problem's solution as several threads write it at once, each the answers of
/// sub-problems of its own components (see [`SubProblem::scatter_into`]): components share no
/// row and no unknown, so no entry is written by two threads.
pub(crate) struct DisjointSolution<'a> {
    v: *mut f64,
    v_len: usize,
    lambda: *mut f64,
    lambda_len: usize,
    _solution: std::marker::PhantomData<&'a mut ProjectionSolution>,
}

// SAFETY: the threads sharing one write disjoint entries (the rows and unknowns of their own
// components) and read none; the entries are plain numbers.
#[allow(unsafe_code)]
unsafe impl Send for DisjointSolution<'_> {}
#[allow(unsafe_code)]
unsafe impl Sync for DisjointSolution<'_> {}

impl<'a> DisjointSolution<'a> {
    /// `sol`, lent for the writes.
    pub fn new(sol: &'a mut ProjectionSolution) -> Self {
        Self {
            v: sol.v.as_mut_ptr(),
            v_len: sol.v.len(),
            lambda: sol.lambda.as_mut_ptr(),
            lambda_len: sol.lambda.len(),
            _solution: std::marker::PhantomData,
        }
    }

    fn set(ptr: *mut f64, len: usize, i: usize, x: f64) {
        assert!(i < len, "entry {i} of {len}");
        // SAFETY: in bounds (checked); the entry belongs to a component of the calling thread
        // (the only writer of its rows and unknowns while the solution is lent), and no
        // reference to it exists meanwhile.
        #[allow(unsafe_code)]
        unsafe {
            ptr.add(i).write(x);
        }
    }

    fn set_v(&self, c: usize, x: f64) {
        Self::set(self.v, self.v_len, c, x);
    }

    fn set_lambda(&self, i: usize, x: f64) {
        Self::set(self.lambda, self.lambda_len, i, x);
    }
}

/// A sub-problem made of some components: their rows, the unknowns those rows touch
/// (renumbered in order of appearance), and its solution buffers. Scratch, reused.
#[derive(Debug, Default)]
pub(crate) struct SubProblem {
    // unknown -> local index (u32::MAX: not in it); all unset between calls
    local: Vec<u32>,
    unknowns: Vec<u32>,
    rows: Vec<u32>,
    jacobian: ConstraintRows,
    w: Vec<f64>,
    b: Vec<f64>,
    solution: ProjectionSolution,
}

/// The component of a row set aside.
const NONE: u32 = u32::MAX;

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let up = parent[parent[i as usize] as usize];
        parent[i as usize] = up;
        i = up;
    }
    i
}

impl Components {
    /// Finds the components of `p`'s rows, leaving out the rows `i` with `set_aside[i]`
    /// (they belong to none), numbered in the order of their first row (a row without
    /// gradient is a component of its own), and returns how many there are.
    pub fn split(&mut self, p: &ProjectionProblem<'_>, set_aside: &[bool]) -> usize {
        let (m, n) = (p.rows(), p.dim());
        let j = p.jacobian;
        self.parent.clear();
        self.parent.extend(0..n as u32);
        let aside = |i: usize| set_aside.get(i).copied().unwrap_or(false);
        for i in 0..m {
            if aside(i) {
                continue;
            }
            let cols = j.row(i).0;
            if let Some((&first, rest)) = cols.split_first() {
                let mut a = find(&mut self.parent, first as u32);
                for &c in rest {
                    let b = find(&mut self.parent, c as u32);
                    if a != b {
                        let (lo, hi) = (a.min(b), a.max(b));
                        self.parent[hi as usize] = lo;
                        a = lo;
                    }
                }
            }
        }
        self.numbered.clear();
        self.numbered.resize(n, u32::MAX);
        self.row_component.clear();
        let mut count = 0u32;
        for i in 0..m {
            if aside(i) {
                self.row_component.push(NONE);
                continue;
            }
            let c = match j.row(i).0.first() {
                Some(&first) => {
                    let root = find(&mut self.parent, first as u32) as usize;
                    if self.numbered[root] == u32::MAX {
                        self.numbered[root] = count;
                        count += 1;
                    }
                    self.numbered[root]
                }
                None => {
                    count += 1;
                    count - 1
                }
            };
            self.row_component.push(c);
        }
        // Rows grouped by component (a counting sort keeps storage order within each).
        let k = count as usize;
        self.start.clear();
        self.start.resize(k + 1, 0);
        for &c in &self.row_component {
            if c != NONE {
                self.start[c as usize + 1] += 1;
            }
        }
        for c in 0..k {
            self.start[c + 1] += self.start[c];
        }
        self.rows.clear();
        self.rows.resize(self.start[k] as usize, 0);
        // `numbered` is free again: reuse it as the next slot of each component.
        self.numbered.clear();
        self.numbered.extend_from_slice(&self.start[..k]);
        for (i, &c) in self.row_component.iter().enumerate() {
            if c == NONE {
                continue;
            }
            let slot = &mut self.numbered[c as usize];
            self.rows[*slot as usize] = i as u32;
            *slot += 1;
        }
        k
    }

    /// The rows of component `c` (after [`split`](Self::split)).
    pub fn rows_of(&self, c: usize) -> &[u32] {
        &self.rows[self.start[c] as usize..self.start[c + 1] as usize]
    }

    /// Whether each component meets its share of `target` (its rows / all rows of the gap,
    /// all of the violation) with the answer `sol` to the whole problem `p`, which must have
    /// `v = w + Jᵀλ` (as every solver returns it): the gap is then `Σ λ_k s_k⁺`. Sets
    /// `met[c]` for every component.
    #[cfg(test)]
    pub fn check_whole(
        &self,
        p: &ProjectionProblem<'_>,
        sol: &ProjectionSolution,
        target: Target,
        met: &mut [bool],
    ) {
        let mut scratch = CheckScratch::default();
        self.check(p.jacobian, p.b, sol, None, target, &mut scratch, met);
    }

    /// Whether each component meets its share of `target`, as `check_whole` (in the tests)
    /// for the whole problem, for a sub-problem of these components and its solution: sets
    /// `met[c]` for the components of the sub-problem only.
    pub fn check_sub(
        &self,
        sub: &SubProblem,
        target: Target,
        scratch: &mut CheckScratch,
        met: &mut [bool],
    ) {
        self.check(
            &sub.jacobian,
            &sub.b,
            &sub.solution,
            Some(&sub.rows),
            target,
            scratch,
            met,
        );
    }

    #[allow(clippy::too_many_arguments)]
    fn check(
        &self,
        j: &ConstraintRows,
        b: &[f64],
        sol: &ProjectionSolution,
        sub_rows: Option<&[u32]>,
        target: Target,
        scratch: &mut CheckScratch,
        met: &mut [bool],
    ) {
        let total_rows = self.row_component.len();
        let CheckScratch {
            slack,
            gap,
            violation,
        } = scratch;
        slack.clear();
        slack.resize(b.len(), 0.0);
        j.mul(&sol.v, slack);
        let k = self.start.len() - 1;
        gap.resize(k, 0.0);
        violation.resize(k, 0.0);
        let component = |r: usize| {
            let i = sub_rows.map_or(r, |rows| rows[r] as usize);
            self.row_component[i]
        };
        // Only the components of these rows are reset: a sub-problem costs its own size.
        for r in 0..b.len() {
            let c = component(r);
            if c != NONE {
                gap[c as usize] = 0.0;
                violation[c as usize] = 0.0;
            }
        }
        for (r, (&jv, &b)) in slack.iter().zip(b).enumerate() {
            let c = component(r);
            if c == NONE {
                continue;
            }
            let c = c as usize;
            let s = jv + b;
            gap[c] += sol.lambda[r].max(0.0) * s.max(0.0);
            violation[c] = violation[c].max(-s);
        }
        for r in 0..b.len() {
            let c = component(r);
            if c == NONE {
                continue;
            }
            let c = c as usize;
            let share =
                target.gap * (self.start[c + 1] - self.start[c]) as f64 / total_rows.max(1) as f64;
            met[c] = gap[c] <= share && violation[c] <= target.violation;
        }
    }
}

impl SubProblem {
    /// Makes the sub-problem of the components `c` with `take[c]`: their rows (in storage
    /// order), the unknowns those rows touch, the warm start `lambda` of those rows. Returns
    /// its number of rows.
    pub fn gather(
        &mut self,
        parts: &Components,
        p: &ProjectionProblem<'_>,
        lambda: &[f64],
        take: &[bool],
    ) -> usize {
        self.rows.clear();
        for (i, &c) in parts.row_component.iter().enumerate() {
            if c != NONE && take[c as usize] {
                self.rows.push(i as u32);
            }
        }
        self.gather_rows(p, lambda)
    }

    /// [`gather`](Self::gather) for the components `comps`, their rows one component after
    /// the other, in time proportional to their size.
    pub fn gather_components(
        &mut self,
        parts: &Components,
        p: &ProjectionProblem<'_>,
        lambda: &[f64],
        comps: &[u32],
    ) -> usize {
        self.rows.clear();
        for &c in comps {
            self.rows.extend_from_slice(parts.rows_of(c as usize));
        }
        self.gather_rows(p, lambda)
    }

    /// [`gather`](Self::gather) for component `c` alone, in time proportional to its size.
    pub fn gather_one(
        &mut self,
        parts: &Components,
        p: &ProjectionProblem<'_>,
        lambda: &[f64],
        c: usize,
    ) -> usize {
        self.rows.clear();
        self.rows.extend_from_slice(parts.rows_of(c));
        self.gather_rows(p, lambda)
    }

    fn gather_rows(&mut self, p: &ProjectionProblem<'_>, lambda: &[f64]) -> usize {
        let j = p.jacobian;
        // `local` is all unset between calls; only the entries set here are reset below.
        if self.local.len() != p.dim() {
            self.local.clear();
            self.local.resize(p.dim(), u32::MAX);
        }
        self.unknowns.clear();
        for &i in &self.rows {
            for &c in j.row(i as usize).0 {
                if self.local[c] == u32::MAX {
                    self.local[c] = self.unknowns.len() as u32;
                    self.unknowns.push(c as u32);
                }
            }
        }
        self.jacobian.clear(self.unknowns.len());
        self.b.clear();
        self.solution.lambda.clear();
        let keys = j.keys();
        for &i in &self.rows {
            let i = i as usize;
            let (cols, coefs) = j.row(i);
            let local = &self.local;
            self.jacobian.push(
                keys[i],
                j.values()[i],
                cols.iter()
                    .zip(coefs)
                    .map(|(&c, &a)| (local[c] as usize, a)),
            );
            self.b.push(p.b[i]);
            self.solution
                .lambda
                .push(lambda.get(i).copied().unwrap_or(0.0));
        }
        self.w.clear();
        self.w
            .extend(self.unknowns.iter().map(|&c| p.w[c as usize]));
        for &c in &self.unknowns {
            self.local[c as usize] = u32::MAX;
        }
        self.rows.len()
    }

    /// The sub-problem made by [`gather`](Self::gather) and its solution buffers.
    pub fn problem(&mut self) -> (ProjectionProblem<'_>, &mut ProjectionSolution) {
        (
            ProjectionProblem {
                w: &self.w,
                jacobian: &self.jacobian,
                b: &self.b,
            },
            &mut self.solution,
        )
    }

    /// Writes the whole sub-problem's solution into `sol`.
    pub fn scatter_all(&self, sol: &mut ProjectionSolution) {
        let local_sol = &self.solution;
        for (k, &i) in self.rows.iter().enumerate() {
            sol.lambda[i as usize] = local_sol.lambda[k];
        }
        for (k, &c) in self.unknowns.iter().enumerate() {
            sol.v[c as usize] = local_sol.v[k];
        }
    }

    /// Writes the sub-problem's solution into `sol` (its rows' multipliers, its unknowns'
    /// velocities) for the components `c` with `keep[c]`.
    #[cfg(test)]
    pub fn scatter(&self, parts: &Components, sol: &mut ProjectionSolution, keep: &[bool]) {
        self.scatter_into(parts, &DisjointSolution::new(sol), keep);
    }

    /// Writes the sub-problem's solution, as `scatter` (in the tests), into a solution other
    /// threads write at the same time (the answers of other components).
    pub fn scatter_into(&self, parts: &Components, sol: &DisjointSolution<'_>, keep: &[bool]) {
        let local_sol = &self.solution;
        for (k, &i) in self.rows.iter().enumerate() {
            let i = i as usize;
            if keep[parts.row_component[i] as usize] {
                sol.set_lambda(i, local_sol.lambda[k]);
                for &c in self.jacobian.row(k).0 {
                    sol.set_v(self.unknowns[c] as usize, local_sol.v[c]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows over unknowns 0–5: (0, 1), (2), (1, 3), a row without gradient, (4, 5), (3):
    /// components {rows 0, 2, 5}, {1}, {3}, {4}, numbered by their first row.
    fn problem() -> (ConstraintRows, Vec<f64>, Vec<f64>) {
        let mut rows = ConstraintRows::new(7);
        rows.push(10, 0.1, [(0, 1.0), (1, -1.0)]);
        rows.push(11, 0.2, [(2, 1.0)]);
        rows.push(12, 0.3, [(1, 1.0), (3, -1.0)]);
        rows.push(13, 0.4, []);
        rows.push(14, 0.5, [(4, 1.0), (5, -1.0)]);
        rows.push(15, 0.6, [(3, 2.0)]);
        let w = (0..7).map(|c| c as f64).collect();
        let b = (0..6).map(|i| -(i as f64)).collect();
        (rows, w, b)
    }

    #[test]
    fn rows_sharing_unknowns_through_other_rows_are_one_component() {
        let (rows, w, b) = problem();
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let mut parts = Components::default();
        assert_eq!(parts.split(&p, &[]), 4);
        assert_eq!(parts.rows_of(0), &[0, 2, 5]);
        assert_eq!(parts.rows_of(1), &[1]);
        assert_eq!(parts.rows_of(2), &[3]);
        assert_eq!(parts.rows_of(3), &[4]);
        // Row 2 set aside: rows 0 and 5 no longer meet.
        assert_eq!(
            parts.split(&p, &[false, false, true, false, false, false]),
            5
        );
        assert_eq!(parts.rows_of(0), &[0]);
        assert_eq!(parts.rows_of(4), &[5]);
        // A second, different problem in the same scratch.
        let mut one = ConstraintRows::new(2);
        one.push(0, 0.0, [(1, 1.0)]);
        let p = ProjectionProblem {
            w: &w[..2],
            jacobian: &one,
            b: &b[..1],
        };
        assert_eq!(parts.split(&p, &[]), 1);
        assert_eq!(parts.rows_of(0), &[0]);
    }

    #[test]
    fn a_sub_problem_keeps_its_rows_in_storage_order_and_writes_back_only_what_is_kept() {
        let (rows, w, b) = problem();
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let mut parts = Components::default();
        parts.split(&p, &[]);
        let warm = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let mut part = SubProblem::default();
        assert_eq!(
            part.gather(&parts, &p, &warm, &[true, false, false, true]),
            4
        );
        {
            let (sub, sol) = part.problem();
            // rows 0, 2, 4, 5; unknowns in order of appearance 0, 1, 3, 4, 5
            assert_eq!(sub.jacobian.keys(), &[10, 12, 14, 15]);
            assert_eq!(sub.b, &[0.0, -2.0, -4.0, -5.0]);
            assert_eq!(sub.w, &[0.0, 1.0, 3.0, 4.0, 5.0]);
            assert_eq!(sub.jacobian.row(1).0, &[1, 2]);
            assert_eq!(sub.jacobian.row(3), (&[2usize][..], &[2.0][..]));
            assert_eq!(sol.lambda, vec![1.0, 3.0, 5.0, 6.0]);
            sol.v = vec![10.0, 11.0, 13.0, 14.0, 15.0];
            sol.lambda = vec![-1.0, -3.0, -5.0, -6.0];
        }
        let mut out = ProjectionSolution {
            v: vec![0.0; 7],
            lambda: vec![0.0; 6],
        };
        part.scatter(&parts, &mut out, &[false, false, false, true]);
        assert_eq!(out.lambda, vec![0.0, 0.0, 0.0, 0.0, -5.0, 0.0]);
        assert_eq!(out.v, vec![0.0, 0.0, 0.0, 0.0, 14.0, 15.0, 0.0]);
        part.scatter(&parts, &mut out, &[true, true, true, true]);
        assert_eq!(out.lambda, vec![-1.0, 0.0, -3.0, 0.0, -5.0, -6.0]);
        assert_eq!(out.v, vec![10.0, 11.0, 0.0, 13.0, 14.0, 15.0, 0.0]);
        let mut all = ProjectionSolution {
            v: vec![0.0; 7],
            lambda: vec![0.0; 6],
        };
        part.scatter_all(&mut all);
        assert_eq!(all, out);
        // Component 1 alone (row 1, unknown 2).
        assert_eq!(part.gather_one(&parts, &p, &warm, 1), 1);
        {
            let (sub, sol) = part.problem();
            assert_eq!((sub.w, sub.b), (&[2.0][..], &[-1.0][..]));
            assert_eq!(sol.lambda, vec![2.0]);
            sol.v = vec![12.0];
        }
        part.scatter_all(&mut all);
        assert_eq!(all.v[2], 12.0);
    }

    #[test]
    fn each_component_is_checked_against_its_share_of_the_target() {
        // Two components of one row each, x0 ≥ 1 and x1 ≥ 1, from w = 0.
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, 1.0)]);
        rows.push(1, 0.0, [(1, 1.0)]);
        let (w, b) = ([0.0, 0.0], [-1.0, -1.0]);
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let mut parts = Components::default();
        parts.split(&p, &[]);
        let mut scratch = CheckScratch::default();
        // The first solved exactly (λ = 1, s = 0); the second with λ = 0.5 (v = 0.5:
        // s = −0.5, violated).
        let mut sol = ProjectionSolution {
            v: vec![1.0, 0.5],
            lambda: vec![1.0, 0.5],
        };
        let t = Target {
            gap: 1e-9,
            violation: 1e-3,
        };
        let mut met = [false, true];
        parts.check_whole(&p, &sol, t, &mut met);
        assert_eq!(met, [true, false]);
        // The second feasible with a gap λ s = 0.5 · 0.25 (the arithmetic only: this v is
        // not w + Jᵀλ): met only with a share (half the target) ≥ it.
        sol.v[1] = 1.25;
        parts.check_whole(&p, &sol, Target { gap: 0.25, ..t }, &mut met);
        assert_eq!(met, [true, true]);
        parts.check_whole(&p, &sol, Target { gap: 0.24, ..t }, &mut met);
        assert_eq!(met, [true, false]);
        // The second alone as a sub-problem: the first's verdict is left as it was.
        let mut part = SubProblem::default();
        part.gather(&parts, &p, &[0.0, 0.0], &[false, true]);
        {
            let (_, sub_sol) = part.problem();
            sub_sol.v = vec![1.0];
            sub_sol.lambda = vec![1.0];
        }
        let mut met = [false, false];
        parts.check_sub(&part, t, &mut scratch, &mut met);
        assert_eq!(met, [false, true]);
    }
}
