//! Projected Gauss–Seidel on the dual in velocity form: one row's multiplier at a time, the
//! velocity kept equal to `w + Jᵀλ`, certified every few sweeps.

use moreau_core::{Parallelism, SolveStatus};

use crate::error::SolveError;
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::workers::Workers;

/// The order in which a sweep visits the rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowOrder {
    /// The order the rows are stored in (a crowd's: the broad phase's pairs, then walls).
    Storage,
    /// Rows sorted by their smallest unknown, stably (in a crowd: grouped by person, people
    /// in their numbering along a space-filling curve).
    ByUnknown,
}

/// Settings of [`GaussSeidel`]; build them with [`GaussSeidelSettings::builder`].
#[derive(Debug, Clone, PartialEq)]
pub struct GaussSeidelSettings {
    /// Budget of passes over the rows per solve (a symmetric sweep is two passes).
    pub max_passes: usize,
    /// Over-relaxation `ω` in `(0, 2)`: `λ_k ← max(0, λ_k − ω s_k / |J_k|²)`.
    pub relaxation: f64,
    /// Forward then backward passes (symmetric Gauss–Seidel) instead of forward only.
    pub symmetric: bool,
    /// The order of the rows in a forward pass.
    pub order: RowOrder,
    /// The longest run of passes between two certificates (each costs about one pass): the
    /// interval grows from 1 to this as the solve goes on.
    pub certify_every: usize,
    /// Threads for the certificate's passes (the sweeps are sequential); the same bits on
    /// any count.
    pub parallelism: Parallelism,
}

impl Default for GaussSeidelSettings {
    fn default() -> Self {
        Self {
            max_passes: 20_000,
            relaxation: 1.0,
            symmetric: false,
            order: RowOrder::Storage,
            certify_every: 16,
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
                value: self.relaxation.to_string(),
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
    /// The longest run of passes between two certificates.
    pub fn certify_every(mut self, n: usize) -> Self {
        self.0.certify_every = n;
        self
    }
    /// Threads for the certificate's passes.
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

/// The rows in sweep order, packed for streaming: 32-bit columns, each row's offset and its
/// step `ω / |J_k|²` (0 for a row without gradient), and where it came from.
#[derive(Debug, Default)]
struct SweepRows {
    start: Vec<u32>,
    cols: Vec<u32>,
    coefs: Vec<f64>,
    b: Vec<f64>,
    step: Vec<f64>,
    original: Vec<u32>,
    /// For each unknown, the entries of its column in ascending sweep position (the gather
    /// of `Jᵀλ` in a fixed order).
    col_start: Vec<u32>,
    col_entries: Vec<u32>,
    entry_row: Vec<u32>,
    col_next: Vec<u32>, // scratch for building
}

impl SweepRows {
    fn build(&mut self, p: &ProjectionProblem<'_>, order: RowOrder, omega: f64) {
        let j = p.jacobian;
        let (m, n) = (p.rows(), p.dim());
        self.original.clear();
        self.original.extend(0..m as u32);
        if order == RowOrder::ByUnknown {
            let first = |i: u32| j.row(i as usize).0.iter().copied().min().unwrap_or(n);
            self.original.sort_by_key(|&i| first(i));
        }
        self.start.clear();
        self.cols.clear();
        self.coefs.clear();
        self.b.clear();
        self.step.clear();
        self.entry_row.clear();
        self.start.push(0);
        for (k, &i) in self.original.iter().enumerate() {
            let (c, a) = j.row(i as usize);
            self.cols.extend(c.iter().map(|&c| c as u32));
            self.coefs.extend_from_slice(a);
            self.entry_row.extend(std::iter::repeat_n(k as u32, c.len()));
            self.start.push(self.cols.len() as u32);
            self.b.push(p.b[i as usize]);
            let norm_sq = j.row_norm_sq(i as usize);
            self.step
                .push(if norm_sq > 0.0 { omega / norm_sq } else { 0.0 });
        }
        // The columns: counts, offsets, then entries in ascending sweep position.
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
    }

    fn row(&self, k: usize) -> (&[u32], &[f64]) {
        let (a, b) = (self.start[k] as usize, self.start[k + 1] as usize);
        (&self.cols[a..b], &self.coefs[a..b])
    }

    /// `(Jᵀλ)_c`, summed in ascending sweep position.
    fn transpose_dot(&self, lam: &[f64], c: usize) -> f64 {
        let (a, b) = (self.col_start[c] as usize, self.col_start[c + 1] as usize);
        self.col_entries[a..b]
            .iter()
            .map(|&e| self.coefs[e as usize] * lam[self.entry_row[e as usize] as usize])
            .sum()
    }

    /// One row's update: `λ_k ← max(0, λ_k − step_k s_k)`, `v += J_kᵀ Δλ_k`.
    #[inline(always)]
    fn relax(&self, k: usize, lam: &mut [f64], v: &mut [f64]) {
        let (c, a) = self.row(k);
        let s = self.b[k]
            + c.iter()
                .zip(a)
                .map(|(&c, &a)| a * v[c as usize])
                .sum::<f64>();
        let next = (lam[k] - self.step[k] * s).max(0.0);
        let delta = next - lam[k];
        if delta != 0.0 {
            lam[k] = next;
            for (&c, &a) in c.iter().zip(a) {
                v[c as usize] += a * delta;
            }
        }
    }
}

/// Projected Gauss–Seidel (with over-relaxation) on the dual `min_{λ≥0} ½λᵀJJᵀλ + λᵀ(b + Jw)`.
///
/// The velocity `v = w + Jᵀλ` is kept alongside `λ`, so that one row's exact minimization
/// costs its nonzeros twice: its slack `s_k = b_k + J_k v`, then `v += J_kᵀ Δλ_k`. Every few
/// passes the pair is certified from scratch: `v = w + Jᵀλ` gathered anew (which also removes
/// the rounding the incremental updates accumulate), `s = b + Jv`, the gap `Σ λ_k s_k⁺` and the
/// violation `max (−s_k)⁺` — the same numbers [`certify`](crate::certify) computes for that
/// pair. The sweeps are sequential (Gauss–Seidel is), the certificate's passes split over
/// threads in fixed chunks, so results do not depend on the thread count. Scratch memory is
/// sized once and reused.
#[derive(Debug)]
pub struct GaussSeidel {
    settings: GaussSeidelSettings,
    workers: Workers,
    rows: SweepRows,
    // per-row scratch, in sweep order
    lam: Vec<f64>,
    slack: Vec<f64>,
    // per-unknown scratch
    v: Vec<f64>,
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
            v: Vec::new(),
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
        wk.map(&mut self.slack, |k, _| {
            let (c, a) = rows.row(k);
            rows.b[k]
                + c.iter()
                    .zip(a)
                    .map(|(&c, &a)| a * v[c as usize])
                    .sum::<f64>()
        });
        let s: &[f64] = &self.slack;
        let gap = wk.sum(s.len(), |k| lam[k] * s[k].max(0.0));
        let violation = (-wk.min(s.len(), |k| s[k])).max(0.0);
        (gap, violation)
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
        let (m, n) = (p.rows(), p.dim());
        sol.resize_for(p);
        let settings = &self.settings;
        self.rows.build(p, settings.order, settings.relaxation);
        // The warm start in sweep order, clamped to λ ≥ 0; a row without gradient gets 0
        // (its slack is the constant b_k: λ_k > 0 would only add to the gap).
        self.lam.clear();
        self.lam.extend(self.rows.original.iter().enumerate().map(|(k, &i)| {
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
        let infeasible = (0..m).any(|k| self.rows.step[k] == 0.0 && self.rows.b[k] < -target.violation);
        let (mut gap, mut violation) = self.certificate(p.w);
        let meets = |gap: f64, violation: f64| gap <= target.gap && violation <= target.violation;
        let mut passes = 0;
        let mut status = SolveStatus::MaxIterations;
        if infeasible {
            status = SolveStatus::Infeasible;
        } else if meets(gap, violation) {
            status = SolveStatus::Converged;
        } else {
            let (max_passes, symmetric, every) = (
                self.settings.max_passes,
                self.settings.symmetric,
                self.settings.certify_every,
            );
            let mut next_certificate = 1;
            while passes < max_passes {
                let backward = symmetric && passes % 2 == 1;
                let (rows, lam, v) = (&self.rows, &mut self.lam, &mut self.v);
                if backward {
                    for k in (0..m).rev() {
                        rows.relax(k, lam, v);
                    }
                } else {
                    for k in 0..m {
                        rows.relax(k, lam, v);
                    }
                }
                passes += 1;
                if passes >= next_certificate || passes == max_passes {
                    (gap, violation) = self.certificate(p.w);
                    if meets(gap, violation) {
                        status = SolveStatus::Converged;
                        break;
                    }
                    next_certificate = passes + (passes / 4).clamp(1, every);
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
