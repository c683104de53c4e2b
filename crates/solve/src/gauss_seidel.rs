//! Projected Gauss–Seidel on the dual in velocity form: one row's multiplier at a time, the
//! velocity kept equal to `w + Jᵀλ`, with optional over-relaxation, symmetric sweeps and
//! momentum, certified from scratch after sweeps 1, 2, 4, 8, ….

use moreau_core::{Num, Parallelism, SolveStatus};

use crate::certificate::gap_and_violation;
use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::workers::Workers;

/// Passes before [`GaussSeidelSettings::abandon_when_slow`] may end a solve, whatever the
/// budget.
const ABANDON_AFTER: usize = 16;

/// The order in which a forward pass visits the rows (a backward pass reverses it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RowOrder {
    /// The order the rows are stored in (a crowd's: the broad phase's pairs, then walls).
    Storage,
    /// Rows sorted stably by their smallest unknown (in a crowd: grouped by person, people
    /// in their numbering along a space-filling curve).
    ByUnknown,
}

/// Settings of [`GaussSeidel`]; build them with [`GaussSeidelSettings::builder`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GaussSeidelSettings {
    /// Budget of passes over the rows per solve (a symmetric sweep is two passes).
    pub max_passes: usize,
    /// Over-relaxation `ω` in `(0, 2)`: `λ_k ← max(0, λ_k − ω s_k / |J_k|²)`.
    pub relaxation: f64,
    /// Sweeps of a forward then a backward pass (symmetric Gauss–Seidel) instead of forward
    /// passes only.
    pub symmetric: bool,
    /// The order of the rows in a forward pass.
    pub order: RowOrder,
    /// Nesterov's extrapolation between sweeps, `λ + β(λ − λ_prev)` with `v` following
    /// linearly and FISTA's `β_k`, left out after any sweep that ends with a larger dual
    /// objective than the one before (the next sweep then starts from that sweep's result),
    /// and FISTA's sequence started again when that objective is also above the one of the
    /// last such sweep.
    pub momentum: bool,
    /// The most sweeps between two certificates. Certificates (each about two passes of
    /// work) are taken after sweeps 1, 2, 4, 8, … (as many sweeps again as made so far),
    /// then every `certify_every`; and as soon as the sweep's own running estimate (each
    /// row's multiplier times its slack as the pass found it) meets the target.
    pub certify_every: usize,
    /// Give up before the budget when the certificates show it will not be enough: from a
    /// quarter of the budget (and at least 16 passes) on, at each certificate the distance
    /// to the target (the larger of gap / target gap and violation / target violation, the
    /// least seen so far) is extrapolated at the rate it fell since the certificate at half
    /// the passes made; when that predicts more passes than the budget has left, the solve
    /// ends there (`MaxIterations`). Momentum makes the early passes slower than the later
    /// ones, hence the quarter: before it, no rate measured is a prediction.
    pub abandon_when_slow: bool,
    /// Threads for the certificate's passes and the dual objective's sums (the sweeps
    /// themselves are sequential); the same bits on any count.
    #[serde(skip)]
    pub parallelism: Parallelism,
}

impl Default for GaussSeidelSettings {
    fn default() -> Self {
        Self {
            max_passes: 20_000,
            relaxation: 1.0,
            symmetric: false,
            order: RowOrder::Storage,
            momentum: true,
            certify_every: 64,
            abandon_when_slow: false,
            parallelism: Parallelism::SEQUENTIAL,
        }
    }
}

impl GaussSeidelSettings {
    /// A builder starting from the defaults.
    pub fn builder() -> GaussSeidelSettingsBuilder {
        GaussSeidelSettingsBuilder(Self::default())
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SolveError> {
        crate::error::check_budgets(&[
            ("max_passes", self.max_passes),
            ("certify_every", self.certify_every),
        ])?;
        if self.max_passes == 0 {
            return Err(SolveError::InvalidSetting {
                field: "max_passes",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        if !(self.relaxation > 0.0 && self.relaxation < 2.0) {
            return Err(SolveError::InvalidSetting {
                field: "relaxation",
                value: Num(self.relaxation).to_string(),
                reason: "must be in (0, 2)",
            });
        }
        if self.certify_every == 0 {
            return Err(SolveError::InvalidSetting {
                field: "certify_every",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        Ok(())
    }
}

/// Builder of [`GaussSeidelSettings`].
#[derive(Debug, Clone)]
pub struct GaussSeidelSettingsBuilder(GaussSeidelSettings);

impl GaussSeidelSettingsBuilder {
    /// Budget of passes over the rows per solve.
    pub fn max_passes(mut self, n: usize) -> Self {
        self.0.max_passes = n;
        self
    }
    /// Over-relaxation `ω` in `(0, 2)`.
    pub fn relaxation(mut self, omega: f64) -> Self {
        self.0.relaxation = omega;
        self
    }
    /// Symmetric (forward then backward) sweeps on or off.
    pub fn symmetric(mut self, on: bool) -> Self {
        self.0.symmetric = on;
        self
    }
    /// The order of the rows.
    pub fn order(mut self, order: RowOrder) -> Self {
        self.0.order = order;
        self
    }
    /// Momentum between sweeps on or off.
    pub fn momentum(mut self, on: bool) -> Self {
        self.0.momentum = on;
        self
    }
    /// The most sweeps between two certificates.
    pub fn certify_every(mut self, n: usize) -> Self {
        self.0.certify_every = n;
        self
    }
    /// Giving up when the certificates predict the budget will not be enough, on or off.
    pub fn abandon_when_slow(mut self, on: bool) -> Self {
        self.0.abandon_when_slow = on;
        self
    }
    /// Threads for the certificate's passes and the dual objective's sums.
    pub fn parallelism(mut self, p: Parallelism) -> Self {
        self.0.parallelism = p;
        self
    }
    /// Validates and returns the settings.
    pub fn build(self) -> Result<GaussSeidelSettings, SolveError> {
        self.0.validate()?;
        Ok(self.0)
    }
}

/// The rows in sweep order, packed for streaming: 32-bit columns, each row's step
/// `ω / |J_k|²` (0 for a row without gradient) and offset `b_k`, where it came from, and
/// the columns' entries in sweep order for the gather of `Jᵀλ`.
#[derive(Debug, Default)]
struct SweepRows {
    start: Vec<u32>,
    cols: Vec<u32>,
    coefs: Vec<f64>,
    b: Vec<f64>,
    step: Vec<f64>,
    original: Vec<u32>,
    col_start: Vec<u32>,
    col_entries: Vec<u32>,
    entry_row: Vec<u32>,
    col_next: Vec<u32>,
}

/// What a pass saw: the sum of each row's multiplier times its slack, and the largest
/// violation, both as the pass found them (before the row's update).
#[derive(Debug, Clone, Copy, Default)]
struct PassEstimate {
    gap: f64,
    violation: f64,
}

impl SweepRows {
    fn build(
        &mut self,
        p: &ProjectionProblem<'_>,
        order: RowOrder,
        omega: f64,
    ) -> Result<(), SolveError> {
        let j = p.jacobian;
        let (m, n) = (p.rows(), p.dim());
        if j.nnz() >= u32::MAX as usize || m >= u32::MAX as usize || n >= u32::MAX as usize {
            return Err(SolveError::InvalidSetting {
                field: "problem size",
                value: format!("{m} rows, {n} unknowns, {} nonzeros", j.nnz()),
                reason: "Gauss–Seidel indexes rows, unknowns and nonzeros with 32 bits",
            });
        }
        self.original.clear();
        self.original.extend(0..m as u32);
        if order == RowOrder::ByUnknown {
            let first = |i: u32| j.row(i as usize).0.iter().copied().min().unwrap_or(n);
            self.original.sort_by_key(|&i| first(i));
        }
        for v in [&mut self.start, &mut self.cols, &mut self.entry_row] {
            v.clear();
        }
        for v in [&mut self.coefs, &mut self.b, &mut self.step] {
            v.clear();
        }
        self.start.push(0);
        for (k, &i) in self.original.iter().enumerate() {
            let (c, a) = j.row(i as usize);
            self.cols.extend(c.iter().map(|&c| c as u32));
            self.coefs.extend_from_slice(a);
            self.entry_row
                .extend(std::iter::repeat_n(k as u32, c.len()));
            self.start.push(self.cols.len() as u32);
            self.b.push(p.b[i as usize]);
            let norm_sq = j.row_norm_sq(i as usize);
            self.step
                .push(if norm_sq > 0.0 { omega / norm_sq } else { 0.0 });
        }
        // Each unknown's entries in ascending sweep position.
        self.col_start.clear();
        self.col_start.resize(n + 1, 0);
        for &c in &self.cols {
            self.col_start[c as usize + 1] += 1;
        }
        for c in 0..n {
            self.col_start[c + 1] += self.col_start[c];
        }
        self.col_entries.clear();
        self.col_entries.resize(self.cols.len(), 0);
        self.col_next.clear();
        self.col_next.extend_from_slice(&self.col_start);
        for (e, &c) in self.cols.iter().enumerate() {
            let slot = &mut self.col_next[c as usize];
            self.col_entries[*slot as usize] = e as u32;
            *slot += 1;
        }
        Ok(())
    }

    fn len(&self) -> usize {
        self.b.len()
    }

    fn row(&self, k: usize) -> (&[u32], &[f64]) {
        let (a, b) = (self.start[k] as usize, self.start[k + 1] as usize);
        (&self.cols[a..b], &self.coefs[a..b])
    }

    /// `J_k x`.
    fn dot(&self, k: usize, x: &[f64]) -> f64 {
        let (c, a) = self.row(k);
        c.iter().zip(a).map(|(&c, &a)| a * x[c as usize]).sum()
    }

    /// `(Jᵀλ)_c`, summed in ascending sweep position.
    fn transpose_dot(&self, lam: &[f64], c: usize) -> f64 {
        let (a, b) = (self.col_start[c] as usize, self.col_start[c + 1] as usize);
        self.col_entries[a..b]
            .iter()
            .map(|&e| self.coefs[e as usize] * lam[self.entry_row[e as usize] as usize])
            .sum()
    }

    /// One row's update `λ_k ← max(0, λ_k − step_k s_k)`, `v += J_kᵀ Δλ_k`, with the slack
    /// `s_k = b_k + J_k v` it found added to the pass's estimate.
    #[inline(always)]
    fn relax(&self, k: usize, lam: &mut [f64], v: &mut [f64], seen: &mut PassEstimate) {
        let (c, a) = self.row(k);
        let s = self.b[k]
            + c.iter()
                .zip(a)
                .map(|(&c, &a)| a * v[c as usize])
                .sum::<f64>();
        let old = lam[k];
        seen.gap += old.max(0.0) * s.max(0.0);
        seen.violation = seen.violation.max(-s);
        let next = (old - self.step[k] * s).max(0.0);
        let delta = next - old;
        if delta != 0.0 {
            lam[k] = next;
            for (&c, &a) in c.iter().zip(a) {
                v[c as usize] += a * delta;
            }
        }
    }
}

/// Projected Gauss–Seidel (successive over-relaxation) on the dual
/// `min_{λ≥0} φ(λ) = ½|Jᵀλ|² + λᵀ(b + Jw)`, in velocity form.
///
/// The velocity `v = w + Jᵀλ` is kept alongside `λ`, so that one row's exact minimization
/// costs its nonzeros twice: its slack `s_k = b_k + J_k v`, then `v += J_kᵀ Δλ_k`; a pass
/// allocates nothing. With momentum, the multipliers and the velocity are extrapolated
/// between sweeps (both linearly, so `v = w + Jᵀλ` still holds; an extrapolated multiplier
/// may be negative until the next sweep projects it), except after a sweep that ends with a
/// larger `φ` than the previous one; FISTA's sequence starts again only when that `φ` is
/// also above the one of the previous such sweep. (Starting it again at every rise, as
/// O'Donoghue–Candès' restart does, fired every two or three sweeps on a crush and kept the
/// momentum near zero; never starting it again let over-relaxed sweeps diverge.)
///
/// After sweeps 1, 2, 4, 8, … the multipliers are certified from scratch: `v = w + Jᵀλ`
/// gathered anew (which also removes the rounding the incremental updates accumulate),
/// `s = b + Jv`, the gap `Σ λ_k s_k⁺` and the violation `max (−s_k)⁺` — what
/// [`certify`](crate::certify) computes for that pair. The returned pair is always a
/// certified one.
///
/// Single-threaded where it matters: the sweeps are sequential (a colouring of the rows
/// would let the rows of one colour go in parallel; not done). The certificate's passes and
/// the dual objective's sums split over threads in fixed chunks, so results do not depend
/// on the thread count.
#[derive(Debug)]
pub struct GaussSeidel {
    settings: GaussSeidelSettings,
    workers: Workers,
    rows: SweepRows,
    // per-row scratch, in sweep order: λ, the slack of the certificate, λ before the last
    // sweep, b + Jw
    lam: Vec<f64>,
    slack: Vec<f64>,
    lam_prev: Vec<f64>,
    offset_at_w: Vec<f64>,
    // per-unknown scratch: v, v before the last sweep
    v: Vec<f64>,
    v_prev: Vec<f64>,
    // (passes, least distance to the target so far) at each certificate of a solve
    history: Vec<(usize, f64)>,
}

impl GaussSeidel {
    /// A solver with validated settings.
    pub fn new(settings: GaussSeidelSettings) -> Result<Self, SolveError> {
        settings.validate()?;
        Ok(Self {
            workers: Workers::new(settings.parallelism)?,
            settings,
            rows: SweepRows::default(),
            lam: Vec::new(),
            slack: Vec::new(),
            lam_prev: Vec::new(),
            offset_at_w: Vec::new(),
            v: Vec::new(),
            v_prev: Vec::new(),
            history: Vec::new(),
        })
    }

    /// The settings.
    pub fn settings(&self) -> &GaussSeidelSettings {
        &self.settings
    }

    /// `v = w + Jᵀλ` from scratch, `s = b + Jv`, and the certificate `(Σ λ_k s_k⁺, max (−s_k)⁺)`.
    fn certificate(&mut self, w: &[f64]) -> (f64, f64) {
        let (rows, lam, wk) = (&self.rows, &self.lam, &self.workers);
        wk.map(&mut self.v, |c, _| w[c] + rows.transpose_dot(lam, c));
        let v: &[f64] = &self.v;
        wk.map(&mut self.slack, |k, _| rows.b[k] + rows.dot(k, v));
        gap_and_violation(wk, lam, &self.slack)
    }

    /// The dual objective `φ(λ) = ½|v − w|² + λᵀ(b + Jw)` for `v = w + Jᵀλ`.
    fn dual_objective(&self, w: &[f64]) -> f64 {
        let (v, lam, c, wk) = (&self.v, &self.lam, &self.offset_at_w, &self.workers);
        0.5 * wk.sum(v.len(), |i| (v[i] - w[i]) * (v[i] - w[i]))
            + wk.sum(lam.len(), |k| lam[k] * c[k])
    }

    /// One sweep: a forward pass, and a backward one when symmetric; returns the passes made
    /// and what the last pass saw.
    fn sweep(&mut self, passes_left: usize) -> (usize, PassEstimate) {
        let (rows, lam, v) = (&self.rows, &mut self.lam, &mut self.v);
        let m = rows.len();
        let mut seen = PassEstimate::default();
        for k in 0..m {
            rows.relax(k, lam, v, &mut seen);
        }
        if !self.settings.symmetric || passes_left < 2 {
            return (1, seen);
        }
        seen = PassEstimate::default();
        for k in (0..m).rev() {
            rows.relax(k, lam, v, &mut seen);
        }
        (2, seen)
    }
}

impl Default for GaussSeidel {
    /// Default settings, one thread.
    fn default() -> Self {
        Self::new(GaussSeidelSettings::default()).expect("the default settings are valid")
    }
}

impl ProjectionSolver for GaussSeidel {
    fn name(&self) -> &'static str {
        "gauss-seidel"
    }

    fn solve(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        p.validate()?;
        target.validate()?;
        let (m, n) = (p.rows(), p.dim());
        sol.resize_for(p);
        let settings = self.settings;
        self.rows.build(p, settings.order, settings.relaxation)?;
        // The warm start in sweep order, clamped to λ ≥ 0; a row without gradient gets 0
        // (its slack is the constant b_k: a multiplier there would only add to the gap).
        self.lam.clear();
        self.lam
            .extend(self.rows.original.iter().enumerate().map(|(k, &i)| {
                let l = sol.lambda[i as usize];
                if self.rows.step[k] > 0.0 && l.is_finite() {
                    l.max(0.0)
                } else {
                    0.0
                }
            }));
        self.slack.clear();
        self.slack.resize(m, 0.0);
        self.v.clear();
        self.v.resize(n, 0.0);

        // A row without gradient is a fixed number: b_k < 0 there cannot be repaired.
        let infeasible =
            (0..m).any(|k| self.rows.step[k] == 0.0 && self.rows.b[k] < -target.violation);
        let (mut gap, mut violation) = self.certificate(p.w);
        let meets = |gap: f64, violation: f64| gap <= target.gap && violation <= target.violation;
        let mut passes = 0;
        let mut status = SolveStatus::MaxIterations;
        if infeasible {
            status = SolveStatus::Infeasible;
        } else if meets(gap, violation) {
            status = SolveStatus::Converged;
        } else {
            if settings.momentum {
                let rows = &self.rows;
                self.offset_at_w.clear();
                self.offset_at_w
                    .extend((0..m).map(|k| rows.b[k] + rows.dot(k, p.w)));
                self.lam_prev.clear();
                self.lam_prev.extend_from_slice(&self.lam);
                self.v_prev.clear();
                self.v_prev.extend_from_slice(&self.v);
            }
            let mut objective = f64::INFINITY;
            let mut t = 1.0_f64;
            let mut last_rise = f64::INFINITY;
            let mut sweeps = 0;
            let mut next_certificate = 1;
            // The estimate must reach target × trust to trigger a certificate; halved each
            // time an estimate-triggered certificate misses.
            let mut trust = 1.0;
            // For abandon_when_slow: each certificate's passes and the least distance to
            // the target so far.
            let distance =
                |gap: f64, violation: f64| (gap / target.gap).max(violation / target.violation);
            let abandon_from = ABANDON_AFTER.max(settings.max_passes / 4);
            self.history.clear();
            self.history.push((0, distance(gap, violation)));
            while passes < settings.max_passes {
                let (made, seen) = self.sweep(settings.max_passes - passes);
                passes += made;
                sweeps += 1;
                let estimated = meets(seen.gap / trust, seen.violation / trust);
                if estimated || sweeps >= next_certificate || passes >= settings.max_passes {
                    (gap, violation) = self.certificate(p.w);
                    if meets(gap, violation) {
                        status = SolveStatus::Converged;
                        break;
                    }
                    if estimated {
                        trust *= 0.5;
                    }
                    // Doubling: a certificate costs about two passes, and most warm solves
                    // end on the sweep's own estimate (a quarter as many sweeps again
                    // instead: `auto` 1.1× slower on jammed halls of 40,000 and 100,000
                    // people, benches/README.md).
                    next_certificate = sweeps + sweeps.clamp(1, settings.certify_every);
                    let least = self.history.last().map_or(f64::INFINITY, |h| h.1);
                    self.history
                        .push((passes, least.min(distance(gap, violation))));
                    if settings.abandon_when_slow
                        && passes >= abandon_from
                        && too_slow(&self.history, settings.max_passes)
                    {
                        break;
                    }
                }
                if passes >= settings.max_passes {
                    break;
                }
                if settings.momentum {
                    let now = self.dual_objective(p.w);
                    // A sweep that ended higher than the one before is not extrapolated
                    // (the next sweep starts from its own result) and the sequence `t` goes
                    // on, unless it also ended higher than the last sweep that did: then
                    // `t` starts again (without that, over-relaxed sweeps diverged).
                    let beta = if now > objective {
                        if now > last_rise {
                            t = 1.0;
                        }
                        last_rise = now;
                        0.0
                    } else {
                        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
                        let beta = (t - 1.0) / t_next;
                        t = t_next;
                        beta
                    };
                    objective = now;
                    extrapolate(&mut self.lam, &mut self.lam_prev, beta);
                    extrapolate(&mut self.v, &mut self.v_prev, beta);
                }
            }
        }
        for (k, &i) in self.rows.original.iter().enumerate() {
            sol.lambda[i as usize] = self.lam[k];
        }
        sol.v.copy_from_slice(&self.v);
        let active = self.lam.iter().filter(|&&l| l > 0.0).count();
        Ok(SolveReport {
            solver: self.name(),
            status,
            gap,
            violation,
            iterations: passes,
            active,
            ..SolveReport::default()
        })
    }
}

/// Whether the distance to the target, at the rate it fell from the certificate at half
/// the passes made to the last one, would still be above 1 after `budget` passes in all.
/// `history`: (passes, least distance so far) of each certificate, the warm start's first.
fn too_slow(history: &[(usize, f64)], budget: usize) -> bool {
    let Some(&(p1, d1)) = history.last() else {
        return false;
    };
    let at_half = history.partition_point(|&(p, _)| 2 * p <= p1);
    let (p0, d0) = history[at_half.saturating_sub(1)];
    if !(d1 > 1.0 && d1.is_finite() && d0.is_finite()) || p1 <= p0 {
        return false;
    }
    if d1 >= d0 {
        return true;
    }
    let passes_needed = (p1 - p0) as f64 * d1.ln() / (d0 / d1).ln();
    p1 as f64 + passes_needed > budget as f64
}

/// `x ← x + β(x − prev)` and `prev ← x` (its value before), in one sequential pass.
fn extrapolate(x: &mut [f64], prev: &mut [f64], beta: f64) {
    for (x, prev) in x.iter_mut().zip(prev.iter_mut()) {
        let now = *x;
        *x = now + beta * (now - *prev);
        *prev = now;
    }
}
