//! A primal–dual interior point in velocity space: Newton systems `I + Jᵀ D J` factorized by
//! faer's sparse Cholesky, the symbolic analysis reused while the contact pattern holds.
//!
//! The problem `min ½|v − w|² s.t. s = b + J v ≥ 0` has the KKT system
//! `v − w − Jᵀλ = 0`, `s − b − J v = 0`, `s ∘ λ = 0`, `s, λ ≥ 0`. Eliminating `Δs` and `Δλ`
//! from the Newton step leaves the normal equations `(I + Jᵀ D J) Δv = r` with
//! `D = diag(λ / s)`: symmetric positive definite for every `D ≥ 0` (it is at least the
//! identity), so redundant contacts — more active rows than a jammed person has degrees of
//! freedom — cost nothing, where the dual Hessian `J Jᵀ` of an active-set method is singular.
//! Mehrotra's predictor–corrector takes two solves per factorization.
//!
//! What is separated: the *ordering* (AMD on one node per group of unknowns that share their
//! rows, a person's x and y), the permuted *pattern* of `I + Jᵀ D J` with the slot where each
//! row's products land, and faer's *symbolic* Cholesky — all three redone only when the
//! columns of `J`'s rows change — and the *numeric* factorization, every iteration. Scratch
//! memory is sized at each symbolic analysis.

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
use moreau_core::{ConstraintRows, Parallelism, SolveStatus};

use crate::certificate::certify;
use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::products::{Index, Transpose, row_dot};
use crate::workers::Workers;

/// Settings of [`InteriorPoint`]; build them with [`InteriorPointSettings::builder`].
#[derive(Debug, Clone, PartialEq)]
pub struct InteriorPointSettings {
    /// Iteration (factorization) budget per solve.
    pub max_iterations: usize,
    /// Fraction of the step to the boundary of `s, λ ≥ 0` taken each iteration, in (0, 1).
    pub step_fraction: f64,
    /// Threads for the numeric factorization and the triangular solves.
    pub parallelism: Parallelism,
}

impl Default for InteriorPointSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            step_fraction: 0.99,
            parallelism: Parallelism::SEQUENTIAL,
        }
    }
}

impl InteriorPointSettings {
    /// A builder starting from the defaults.
    pub fn builder() -> InteriorPointSettingsBuilder {
        InteriorPointSettingsBuilder(Self::default())
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SolveError> {
        if self.max_iterations == 0 {
            return Err(SolveError::InvalidSetting {
                field: "max_iterations",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        if !(self.step_fraction > 0.0 && self.step_fraction < 1.0) {
            return Err(SolveError::InvalidSetting {
                field: "step_fraction",
                value: self.step_fraction.to_string(),
                reason: "must be in (0, 1)",
            });
        }
        Ok(())
    }
}

/// Builder of [`InteriorPointSettings`].
#[derive(Debug, Clone)]
pub struct InteriorPointSettingsBuilder(InteriorPointSettings);

impl InteriorPointSettingsBuilder {
    /// Iteration budget per solve.
    pub fn max_iterations(mut self, n: usize) -> Self {
        self.0.max_iterations = n;
        self
    }
    /// Fraction to the boundary.
    pub fn step_fraction(mut self, f: f64) -> Self {
        self.0.step_fraction = f;
        self
    }
    /// Threads for the factorization.
    pub fn parallelism(mut self, p: Parallelism) -> Self {
        self.0.parallelism = p;
        self
    }
    /// Validates and returns the settings.
    pub fn build(self) -> Result<InteriorPointSettings, SolveError> {
        self.0.validate()?;
        Ok(self.0)
    }
}

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
    // scratch for building
    count: Vec<usize>,
    fill: Vec<Index>,
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
        // Bucket the entries by column, then sort and deduplicate each column.
        self.count.clear();
        self.count.resize(n, 1); // the diagonal
        for_each_product(j, |ca, cb| self.count[place(ca, cb).1] += 1);
        let mut total = 0;
        for c in self.count.iter_mut() {
            let k = *c;
            *c = total;
            total += k;
        }
        self.fill.clear();
        self.fill.resize(total, 0);
        {
            let (count, fill) = (&mut self.count, &mut self.fill);
            for c in 0..n {
                fill[count[c]] = c as Index;
                count[c] += 1;
            }
            for_each_product(j, |ca, cb| {
                let (r, c) = place(ca, cb);
                fill[count[c]] = r as Index;
                count[c] += 1;
            });
        }
        // count[c] is now the end of column c's bucket and the start of column c + 1's.
        self.col_ptr.clear();
        self.row_idx.clear();
        let mut start = 0;
        for c in 0..n {
            let end = self.count[c];
            let bucket = &mut self.fill[start..end];
            bucket.sort_unstable();
            self.col_ptr.push(self.row_idx.len() as Index);
            let mut last = Index::MAX;
            for &r in bucket.iter() {
                if r != last {
                    self.row_idx.push(r);
                    last = r;
                }
            }
            start = end;
        }
        self.col_ptr.push(self.row_idx.len() as Index);
        self.diag.clear();
        self.slots.clear();
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
        for_each_product(j, |ca, cb| {
            let (r, c) = place(ca, cb);
            out.push(find(col_ptr, row_idx, r, c) as Index);
        });
    }

    fn symbolic(&self) -> SymbolicSparseColMatRef<'_, Index> {
        SymbolicSparseColMatRef::new_checked(self.n, self.n, &self.col_ptr, None, &self.row_idx)
    }

    /// `values = triangle(I + Jᵀ diag(d) J)`.
    fn assemble(&self, j: &ConstraintRows, d: &[f64], values: &mut Vec<f64>) {
        values.clear();
        values.resize(self.row_idx.len(), 0.0);
        for &p in &self.diag {
            values[p] = 1.0;
        }
        let mut k = 0;
        for (i, &di) in d.iter().enumerate() {
            let (cols, coefs) = j.row(i);
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

/// faer's workspace, sized at each symbolic analysis.
struct Scratch(MemBuffer);

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
}

/// Mehrotra's predictor–corrector interior point on the velocity-form projection, with
/// sparse Cholesky normal equations. Its answers are certified by [`certify`].
#[derive(Debug)]
pub struct InteriorPoint {
    settings: InteriorPointSettings,
    // The structure of J the analysis below was made for.
    j_row_start: Vec<usize>,
    j_cols: Vec<usize>,
    // The unpermuted lower triangle (input of the ordering), the fill-reducing ordering,
    // and the permuted triangle that is factorized (no permutation per factorization).
    natural: NormalPattern,
    perm: Vec<usize>,
    perm_inv: Vec<usize>,
    group_of: Vec<usize>,
    group_start: Vec<usize>,
    group_perm: Vec<Index>,
    group_perm_inv: Vec<Index>,
    jt: Transpose,
    workers: Workers,
    pattern: NormalPattern,
    symbolic: Option<SymbolicCholesky<Index>>,
    side: Side,
    counts: FactorizationCounts,
    time_factorize: f64,
    h: Vec<f64>,
    l: Vec<f64>,
    mem: Scratch,
    // per-row
    s: Vec<f64>,
    d: Vec<f64>,
    rp: Vec<f64>,
    rc: Vec<f64>,
    ds: Vec<f64>,
    dl: Vec<f64>,
    ds_aff: Vec<f64>,
    dl_aff: Vec<f64>,
    scratch_m: Vec<f64>,
    // per-unknown
    rd: Vec<f64>,
    dv: Vec<f64>,
    scratch_n: Vec<f64>,
}

impl InteriorPoint {
    /// A solver with validated settings.
    pub fn new(settings: InteriorPointSettings) -> Result<Self, SolveError> {
        settings.validate()?;
        Ok(Self {
            settings: settings.clone(),
            j_row_start: Vec::new(),
            j_cols: Vec::new(),
            natural: NormalPattern::default(),
            perm: Vec::new(),
            perm_inv: Vec::new(),
            group_of: Vec::new(),
            group_start: Vec::new(),
            group_perm: Vec::new(),
            group_perm_inv: Vec::new(),
            jt: Transpose::default(),
            workers: Workers::new(settings.parallelism)?,
            pattern: NormalPattern::default(),
            symbolic: None,
            side: Side::Upper,
            counts: FactorizationCounts::default(),
            time_factorize: 0.0,
            h: Vec::new(),
            l: Vec::new(),
            mem: Scratch(MemBuffer::new(StackReq::EMPTY)),
            s: Vec::new(),
            d: Vec::new(),
            rp: Vec::new(),
            rc: Vec::new(),
            ds: Vec::new(),
            dl: Vec::new(),
            ds_aff: Vec::new(),
            dl_aff: Vec::new(),
            scratch_m: Vec::new(),
            rd: Vec::new(),
            dv: Vec::new(),
            scratch_n: Vec::new(),
        })
    }

    /// Patterns, analyses and factorizations done so far.
    pub fn counts(&self) -> FactorizationCounts {
        self.counts
    }

    fn par(&self) -> Par {
        if self.settings.parallelism.is_sequential() {
            Par::Seq
        } else {
            Par::rayon(self.settings.parallelism.get())
        }
    }

    fn size(&mut self, m: usize, n: usize) {
        for v in [
            &mut self.s,
            &mut self.d,
            &mut self.rp,
            &mut self.rc,
            &mut self.ds,
            &mut self.dl,
            &mut self.ds_aff,
            &mut self.dl_aff,
            &mut self.scratch_m,
        ] {
            v.clear();
            v.resize(m, 0.0);
        }
        for v in [&mut self.rd, &mut self.dv, &mut self.scratch_n] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// Makes the ordering, the pattern and the symbolic analysis fit `j`; nothing is redone
    /// while the columns of `j`'s rows stay the same.
    fn analyse(&mut self, j: &ConstraintRows) -> Result<(), SolveError> {
        if self.symbolic.is_some()
            && self.pattern.n == j.dim()
            && self.j_row_start == j.row_starts()
            && self.j_cols == j.columns()
        {
            return Ok(());
        }
        self.j_row_start.clear();
        self.j_row_start.extend_from_slice(j.row_starts());
        self.j_cols.clear();
        self.j_cols.extend_from_slice(j.columns());
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

        // Fill-reducing ordering (AMD) of the pattern compressed to groups of adjacent
        // unknowns that appear in the same rows (a disk's x and y): a quarter of the entries.
        self.jt.build(j);
        let groups = column_groups(&self.jt, &mut self.group_of);
        self.natural
            .build(j, Some((&self.group_of, groups)), false, false);
        let nnz = self.natural.row_idx.len();
        self.group_perm.clear();
        self.group_perm.resize(groups, 0);
        self.group_perm_inv.clear();
        self.group_perm_inv.resize(groups, 0);
        let mut mem = MemBuffer::new(amd::order_maybe_unsorted_scratch::<Index>(groups, nnz));
        amd::order_maybe_unsorted(
            &mut self.group_perm,
            &mut self.group_perm_inv,
            self.natural.symbolic(),
            amd::Control::default(),
            MemStack::new(&mut mem),
        )
        .map_err(|e| SolveError::Factorization(format!("{e:?}")))?;
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
        let par = self.par();
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, par),
        ]);
        self.mem = Scratch(MemBuffer::new(req));
        self.l.clear();
        self.l.resize(symbolic.len_val(), 0.0);
        self.counts.factor_nnz = symbolic.len_val();
        self.counts.matrix_nnz = self.pattern.row_idx.len();
        self.symbolic = Some(symbolic);
        self.counts.analyses += 1;
        Ok(())
    }

    /// Factorizes `I + Jᵀ D J`; false when it is not numerically positive definite.
    fn factorize(&mut self, j: &ConstraintRows) -> bool {
        self.pattern.assemble(j, &self.d, &mut self.h);
        let clock = Instant::now();
        let par = self.par();
        let symbolic = self.symbolic.as_ref().expect("analysed");
        let a = SparseColMatRef::new(self.pattern.symbolic(), &self.h);
        self.counts.factorizations += 1;
        let (l, side, mem) = (&mut self.l, self.side, &mut self.mem.0);
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
        self.time_factorize += clock.elapsed().as_secs_f64();
        ok
    }

    /// One Newton direction for the complementarity right-hand side in `self.rc`:
    /// `(I + JᵀDJ) Δv = −r_d + Jᵀ(r_c/s + D r_p)`, `Δs = JΔv − r_p`, `Δλ = (r_c − λΔs)/s`.
    fn direction(&mut self, j: &ConstraintRows, lam: &[f64]) {
        let w = &self.workers;
        let (s, d, rp, rc) = (&self.s, &self.d, &self.rp, &self.rc);
        w.map(&mut self.scratch_m, |i, _| rc[i] / s[i] + d[i] * rp[i]);
        // Δv's right-hand side −r_d + Jᵀ(r_c/s + D r_p) in natural order (memory in
        // order), then permuted into the factor's order.
        let (y, rd, jt, coefs) = (&self.scratch_m, &self.rd, &self.jt, j.coefficients());
        w.map(&mut self.dv, |c, _| jt.dot(coefs, y, c) - rd[c]);
        let (dv, perm) = (&self.dv, &self.perm);
        w.map(&mut self.scratch_n, |k, _| dv[perm[k]]);
        let clock = Instant::now();
        let par = self.par();
        let symbolic = self.symbolic.as_ref().expect("analysed");
        let n = self.dv.len();
        let (l, x, mem) = (&self.l, &mut self.scratch_n, &mut self.mem.0);
        w.install(|| {
            LltRef::new(symbolic, l).solve_in_place_with_conj(
                Conj::No,
                MatMut::from_column_major_slice_mut(x, n, 1),
                par,
                MemStack::new(mem),
            )
        });
        self.time_factorize += clock.elapsed().as_secs_f64();
        let (x, perm_inv) = (&self.scratch_n, &self.perm_inv);
        w.map(&mut self.dv, |c, _| x[perm_inv[c]]);
        let dv = &self.dv;
        w.map(&mut self.ds, |i, _| row_dot(j, dv, i) - rp[i]);
        let ds = &self.ds;
        w.map(&mut self.dl, |i, _| (rc[i] - lam[i] * ds[i]) / s[i]);
    }

    /// The largest `α ≤ 1` keeping `s + αΔs ≥ 0` and `λ + αΔλ ≥ 0`.
    fn max_step(w: &Workers, s: &[f64], ds: &[f64], lam: &[f64], dl: &[f64]) -> f64 {
        let ratio = |x: f64, dx: f64| if dx < 0.0 { -x / dx } else { f64::INFINITY };
        w.min(s.len(), |i| ratio(s[i], ds[i]).min(ratio(lam[i], dl[i])))
            .min(1.0)
    }
}

impl ProjectionSolver for InteriorPoint {
    fn name(&self) -> &'static str {
        "interior"
    }

    fn solve(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        p.validate()?;
        let (m, n) = (p.rows(), p.dim());
        let j = p.jacobian;
        sol.resize_for(p);
        self.size(m, n);
        let (v, lam) = (&mut sol.v, &mut sol.lambda);
        v.copy_from_slice(p.w);

        let infeasible = (0..m).any(|i| j.row_norm_sq(i) == 0.0 && p.b[i] < -target.violation);
        if m == 0 || infeasible {
            lam.iter_mut().for_each(|l| *l = 0.0);
            let cert = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
            let status = if infeasible {
                SolveStatus::Infeasible
            } else {
                SolveStatus::Converged
            };
            return Ok(SolveReport {
                solver: self.name(),
                status,
                gap: cert.gap,
                violation: cert.violation,
                iterations: 0,
                active: 0,
                ..SolveReport::default()
            });
        }
        // The caller's multipliers (the previous step's, or zeros) may already answer: a
        // free-flowing crowd, or nobody moving, costs no factorization at all.
        lam.iter_mut()
            .for_each(|l| *l = if l.is_finite() { l.max(0.0) } else { 0.0 });
        j.mul_transpose_add(lam, v);
        let c = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
        if c.gap <= target.gap && c.violation <= target.violation {
            return Ok(SolveReport {
                solver: self.name(),
                status: SolveStatus::Converged,
                gap: c.gap,
                violation: c.violation,
                iterations: 0,
                active: c.active,
                ..SolveReport::default()
            });
        }
        v.copy_from_slice(p.w);

        let clock = Instant::now();
        self.analyse(j)?;
        let time_analyse = clock.elapsed().as_secs_f64();
        self.time_factorize = 0.0;

        // Starting point (Mehrotra's heuristic on v = w): shift the slacks of the
        // unconstrained velocity into the interior, then balance s and λ. The caller's
        // multipliers are not used: interior points gain little from a warm start, and
        // measured on jammed crowds it cost 2–4× more iterations (benches/README.md).
        j.mul(p.w, &mut self.s);
        let mut min_s = f64::INFINITY;
        let mut mean_abs = 0.0;
        for (s, b) in self.s.iter_mut().zip(p.b) {
            *s += b;
            min_s = min_s.min(*s);
            mean_abs += s.abs();
        }
        mean_abs /= m as f64;
        let scale = if mean_abs > 0.0 { mean_abs } else { 1.0 };
        let shift = (-1.5 * min_s).max(0.0);
        self.s.iter_mut().for_each(|s| *s += shift);
        lam.iter_mut().for_each(|l| *l = scale);
        let sl: f64 = self.s.iter().zip(lam.iter()).map(|(s, l)| s * l).sum();
        let (sum_s, sum_l): (f64, f64) = (self.s.iter().sum(), lam.iter().sum());
        let (bump_s, bump_l) = (0.5 * sl / sum_l, 0.5 * sl / sum_s.max(f64::MIN_POSITIVE));
        for (s, l) in self.s.iter_mut().zip(lam.iter_mut()) {
            *s = (*s + bump_s).max(1e-8 * scale);
            *l += bump_l;
        }

        let tau = self.settings.step_fraction;
        let mut iterations = 0;
        let status = loop {
            // Residuals r_d = v − w − Jᵀλ, r_p = s − b − J v.
            let (wk, jt, coefs) = (&self.workers, &self.jt, j.coefficients());
            {
                let (v, lam): (&[f64], &[f64]) = (v, lam);
                wk.map(&mut self.rd, |c, _| v[c] - p.w[c] - jt.dot(coefs, lam, c));
                let s = &self.s;
                wk.map(&mut self.rp, |i, _| s[i] - p.b[i] - row_dot(j, v, i));
            }
            // Once the residuals vanish the certificate is sᵀλ: below the target gap is
            // when it is worth computing.
            let sl = {
                let (s, lam): (&[f64], &[f64]) = (&self.s, lam);
                wk.sum(m, |i| s[i] * lam[i])
            };
            let last = iterations == self.settings.max_iterations;
            if sl <= target.gap || last {
                let c = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
                if c.gap <= target.gap && c.violation <= target.violation {
                    break SolveStatus::Converged;
                }
                if last {
                    break SolveStatus::MaxIterations;
                }
            }
            iterations += 1;
            let mu = sl / m as f64;
            {
                let (s, lam): (&[f64], &[f64]) = (&self.s, lam);
                self.workers.map(&mut self.d, |i, _| lam[i] / s[i]);
                // Predictor (affine scaling).
                self.workers.map(&mut self.rc, |i, _| -s[i] * lam[i]);
            }
            if !self.factorize(j) {
                break SolveStatus::NumericalError;
            }
            self.direction(j, lam);
            let wk = &self.workers;
            let (s, ds, dl) = (&self.s, &self.ds, &self.dl);
            let alpha_aff = Self::max_step(wk, s, ds, lam, dl);
            let lam_ref: &[f64] = lam;
            let mu_aff = wk.sum(m, |i| {
                (s[i] + alpha_aff * ds[i]) * (lam_ref[i] + alpha_aff * dl[i])
            }) / m as f64;
            // (μ = 0 only when sᵀλ underflowed: no centring then, not a NaN.)
            let sigma = if mu > 0.0 {
                (mu_aff / mu).clamp(0.0, 1.0).powi(3)
            } else {
                0.0
            };
            std::mem::swap(&mut self.ds, &mut self.ds_aff);
            std::mem::swap(&mut self.dl, &mut self.dl_aff);
            // Corrector (centring and second order).
            {
                let (s, dsa, dla) = (&self.s, &self.ds_aff, &self.dl_aff);
                let lam: &[f64] = lam;
                self.workers.map(&mut self.rc, |i, _| {
                    -s[i] * lam[i] - dsa[i] * dla[i] + sigma * mu
                });
            }
            self.direction(j, lam);
            let wk = &self.workers;
            let alpha = tau * Self::max_step(wk, &self.s, &self.ds, lam, &self.dl);
            if !(alpha > 0.0) || self.dv.iter().any(|x| !x.is_finite()) {
                break SolveStatus::NumericalError;
            }
            let (dv, ds, dl) = (&self.dv, &self.ds, &self.dl);
            wk.map(v, |k, x| x + alpha * dv[k]);
            wk.map(&mut self.s, |i, x| x + alpha * ds[i]);
            wk.map(lam, |i, x| x + alpha * dl[i]);
        };
        let cert = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
        // Active: rows whose multiplier dominates their slack (complementarity decides).
        let active = (0..m).filter(|&i| lam[i] > self.s[i]).count();
        Ok(SolveReport {
            solver: self.name(),
            status,
            gap: cert.gap,
            violation: cert.violation,
            iterations,
            active,
            time_analyse,
            time_factorize: self.time_factorize,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solve(rows: &ConstraintRows, w: &[f64], b: &[f64]) -> (SolveReport, ProjectionSolution) {
        let p = ProjectionProblem {
            w,
            jacobian: rows,
            b,
        };
        let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let rep = ip
            .solve(
                &p,
                Target {
                    gap: 1e-14,
                    violation: 1e-12,
                },
                &mut sol,
            )
            .unwrap();
        (rep, sol)
    }

    #[test]
    fn projects_onto_a_half_plane_in_closed_form() {
        // v ≥ (1, ·) from w = (−1, 2): the projection is (1, 2) with λ = 2.
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, 1.0)]);
        let (rep, sol) = solve(&rows, &[-1.0, 2.0], &[-1.0]);
        assert!(rep.status.is_converged(), "{rep:?}");
        assert!((sol.v[0] - 1.0).abs() < 1e-6 && (sol.v[1] - 2.0).abs() < 1e-9);
        assert!((sol.lambda[0] - 2.0).abs() < 1e-5);
        assert_eq!(rep.active, 1);
    }

    #[test]
    fn redundant_rows_keep_the_normal_matrix_definite() {
        // The same constraint three times plus a parallel weaker one: J Jᵀ is singular.
        let mut rows = ConstraintRows::new(2);
        for k in 0..3 {
            rows.push(k, 0.0, [(0, 1.0), (1, 1.0)]);
        }
        rows.push(3, 0.0, [(0, 2.0), (1, 2.0)]);
        let b = [-2.0, -2.0, -2.0, -1.0];
        let (rep, sol) = solve(&rows, &[0.0, 0.0], &b);
        assert!(rep.status.is_converged(), "{rep:?}");
        // projection of 0 onto x + y ≥ 2 is (1, 1)
        assert!((sol.v[0] - 1.0).abs() < 1e-6 && (sol.v[1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_feasible_prediction_is_returned_unchanged_without_factorizing() {
        let mut rows = ConstraintRows::new(2);
        rows.push(0, 0.0, [(0, 1.0)]);
        let w = [0.3, -0.7];
        let (rep, sol) = solve(&rows, &w, &[0.0]);
        assert_eq!((rep.iterations, rep.active), (0, 0));
        assert_eq!(sol.v, w);
    }

    #[test]
    fn the_analysis_is_reused_while_the_rows_keep_their_columns() {
        let target = Target {
            gap: 1e-12,
            violation: 1e-12,
        };
        let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
        let mut rows = ConstraintRows::new(3);
        rows.push(0, 0.0, [(0, 1.0), (1, -1.0)]);
        rows.push(1, 0.0, [(1, 1.0), (2, -1.0)]);
        let w = [-1.0, 0.0, 1.0];
        let mut solve = |rows: &ConstraintRows, b: &[f64]| {
            let p = ProjectionProblem {
                w: &w,
                jacobian: rows,
                b,
            };
            let mut sol = ProjectionSolution::default();
            let rep = ip.solve(&p, target, &mut sol).unwrap();
            assert!(rep.status.is_converged() && rep.iterations > 0, "{rep:?}");
            ip.counts()
        };
        let first = solve(&rows, &[0.0, 0.0]);
        assert_eq!(first.analyses, 1);
        // Other values (offsets), same columns: numeric factorizations only.
        let second = solve(&rows, &[-0.5, 0.1]);
        assert_eq!(second.analyses, 1);
        assert!(second.factorizations > first.factorizations);
        // A row with other columns: analysed again.
        let mut other = ConstraintRows::new(3);
        other.push(0, 0.0, [(0, 1.0), (2, -1.0)]);
        other.push(1, 0.0, [(1, 1.0), (2, -1.0)]);
        assert_eq!(solve(&other, &[0.0, 0.0]).analyses, 2);
    }

    #[test]
    fn a_zero_row_that_cannot_hold_is_infeasible() {
        let mut rows = ConstraintRows::new(1);
        rows.push(0, 0.0, []);
        let (rep, _) = solve(&rows, &[0.0], &[-1.0]);
        assert_eq!(rep.status, SolveStatus::Infeasible);
    }

    #[test]
    fn bad_settings_name_the_field() {
        let e = InteriorPointSettings::builder()
            .step_fraction(1.0)
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("step_fraction"), "{e}");
    }
}
