//! A primal–dual interior point in velocity space: Newton systems `I + Jᵀ D J` factorized by
//! [`NormalEquations`] (in 2×2 blocks, or by faer's supernodal Cholesky where the factor is
//! dense), the symbolic analysis reused while the contact pattern holds.
//!
//! The problem `min ½|v − w|² s.t. s = b + J v ≥ 0` has the KKT system
//! `v − w − Jᵀλ = 0`, `s − b − J v = 0`, `s ∘ λ = 0`, `s, λ ≥ 0`. Eliminating `Δs` and `Δλ`
//! from the Newton step leaves the normal equations `(I + Jᵀ D J) Δv = r` with
//! `D = diag(λ / s)`: symmetric positive definite for every `D ≥ 0` (it is at least the
//! identity), so redundant contacts — more active rows than a jammed person has degrees of
//! freedom — cost nothing, where the dual Hessian `J Jᵀ` of an active-set method is singular.
//! Mehrotra's predictor–corrector takes two solves per factorization, and where the factor
//! is dense (a crush's) Gondzio's centrality correctors up to two more.
//!
//! The normal equations (ordering, pattern, symbolic analysis reused while the columns of
//! `J`'s rows hold, a numeric factorization every iteration) are [`NormalEquations`]'s; where
//! their factorization breaks down (`D` past ~10¹⁷: a long chain pushed together, a crush at a
//! tight gap) the rest of the solve takes the augmented form of [`AugmentedSystem`]. This
//! module is the interior-point loop, which also stops at the certificate's rounding floor
//! ([`SolveStatus::RoundingFloor`]).

use moreau_core::{ConstraintKey, ConstraintRows, Num, Parallelism, SolveStatus};

use crate::augmented::AugmentedSystem;
use crate::certificate::{Certificate, certify};
use crate::error::SolveError;
use crate::normal::{FactorizationCounts, NormalEquations, StageTimes};
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::products::row_dot;
use crate::reorder::{find_from, fnv};
use crate::workers::Workers;

/// Settings of [`InteriorPoint`]; build them with [`InteriorPointSettings::builder`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InteriorPointSettings {
    /// Iteration (factorization) budget per solve.
    pub max_iterations: usize,
    /// Fraction of the step to the boundary of `s, λ ≥ 0` taken each iteration, in (0, 1).
    pub step_fraction: f64,
    /// The starting multipliers are at least this multiple of the mean of the caller's
    /// (the previous step's) multipliers; 0: Mehrotra's start alone. The previous step's
    /// multipliers are no starting point (too close to the boundary), but their scale is
    /// what the pressure of a packed crowd needs, three orders of magnitude above the
    /// slacks Mehrotra's start goes by: measured on crushes, 1.1–2.3× fewer iterations from
    /// the second step on, halls unchanged to within 5 % (benches/README.md, session 11).
    pub warm_scale: f64,
    /// Gondzio's centrality correctors tried per iteration (each a pair of triangular solves
    /// with the factorization in hand, kept when it lengthens the step).
    pub max_correctors: usize,
    /// The correctors are tried only when a factorization costs more than this many
    /// multiply–adds per entry of its factor, so that a pair of triangular solves is cheap
    /// beside it (crushes; 0: always). Measured: 6–10 % a step on crushes of 40,000 and
    /// 100,000; halls stay below it, where they save factorizations but cost as much in
    /// solves (benches/README.md, sessions 8 and 11).
    pub corrector_threshold: f64,
    /// Penalty `ρ` of the warm polish (0: never tried): when the previous solve ended with
    /// at most `polish_changes` of its rows changing sides from its warm start, the caller's
    /// active set is tried first, as equalities: one factorization of `I + J_Aᵀ D J_A` with
    /// `D_i = ρ / |J_i|²` on the rows whose multiplier is positive, then the method of
    /// multipliers with it, and the interior point only if that does not certify. A settled
    /// crush then costs one factorization a step instead of nine (benches/README.md,
    /// session 12).
    pub polish_penalty: f64,
    /// Fraction of rows whose activity changed in the last solve up to which the polish is
    /// tried (jams: 3–4 %, where it would rarely certify; a settled crush: 0). After `k`
    /// failures in a row, the next `2ᵏ − 1` such solves skip it (`k ≤ 6`).
    pub polish_changes: f64,
    /// Multiplier updates of the polish (each a pair of triangular solves).
    pub polish_updates: usize,
    /// The start from a kept iterate (0: never; Mehrotra's start every time): each solve
    /// keeps its first iterate whose `sᵀλ` is at most this multiple of the target gap — on
    /// the central path, well before the end — with its rows' keys, and the next solve starts
    /// from it (rows matched by key; a new row at its slack at `w`), with `v = w + Jᵀλ` and
    /// each slack raised to the row's slack at that `v`. Gondzio and Grothey's re-optimization
    /// start: the iterations that take `sᵀλ` from the cold start's down to that level are
    /// skipped while the problem moves little (cromosim's scene: 11.8 iterations a solve →
    /// 9.1; 10⁷ and 10¹⁰ did as well there, but 10⁷ lost on the crush of 40,000 and gained
    /// nothing in jams, benches/README.md, session 13). Where the problem moves more than that
    /// iterate's centrality allows it costs iterations instead: a start from it that takes at
    /// least as many iterations as the last cold start makes the next `2ᵏ − 1` solves start
    /// cold after `k` such losses in a row (`k ≤ 6`), and one that has not converged within
    /// twice those iterations is redone cold.
    pub warm_iterate: f64,
    /// Separate step lengths: the primal variables `(v, s)` go the fraction
    /// `step_fraction` of the way to the boundary of `s ≥ 0`, the multipliers that of the way
    /// to `λ ≥ 0`, instead of both the shorter of the two (as in LP interior points; the dual
    /// residual `v − w − Jᵀλ` then shrinks unevenly, and the certificate still decides). Measured
    /// on one build, alternated (benches/README.md, session 14): factorizations a step 7.41 →
    /// 6.92 on cromosim's scene, 14.1 → 13.1 on the jammed 2,000, 11.7 → 10.9 and 14.5 → 13.6
    /// over whole evacuations of 2,000 and 10,000.
    pub separate_steps: bool,
    /// Factorizations and triangular solves in 2×2 blocks on two threads where the
    /// elimination tree splits into two parts that pay (the loops over rows and unknowns stay
    /// on `parallelism`): a helper thread, spinning between jobs, takes one part, whenever the
    /// run's own probes measure the split faster than one thread (what it gains depends on
    /// where the machine puts the two threads: benches/README.md, session 16). The same bits
    /// as on one thread.
    pub split_factorization: bool,
    /// Threads for the loops over rows and unknowns and for faer's factorizations and
    /// triangular solves (the 2×2-block factorization of crowds is sequential unless
    /// `split_factorization`).
    #[serde(skip)]
    pub parallelism: Parallelism,
}

impl Default for InteriorPointSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            step_fraction: 0.99,
            warm_scale: 3.0,
            max_correctors: 2,
            corrector_threshold: 32.0,
            polish_penalty: 1e6,
            polish_changes: 0.005,
            polish_updates: 4,
            warm_iterate: 1e9,
            separate_steps: true,
            split_factorization: false,
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
        crate::error::check_budgets(&[
            ("max_iterations", self.max_iterations),
            ("max_correctors", self.max_correctors),
            ("polish_updates", self.polish_updates),
        ])?;
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
                value: Num(self.step_fraction).to_string(),
                reason: "must be in (0, 1)",
            });
        }
        if !(self.warm_scale >= 0.0 && self.warm_scale.is_finite()) {
            return Err(SolveError::InvalidSetting {
                field: "warm_scale",
                value: Num(self.warm_scale).to_string(),
                reason: "must be finite and ≥ 0",
            });
        }
        if !(self.corrector_threshold >= 0.0) {
            return Err(SolveError::InvalidSetting {
                field: "corrector_threshold",
                value: Num(self.corrector_threshold).to_string(),
                reason: "must be ≥ 0",
            });
        }
        if !(self.polish_penalty >= 0.0 && self.polish_penalty.is_finite()) {
            return Err(SolveError::InvalidSetting {
                field: "polish_penalty",
                value: Num(self.polish_penalty).to_string(),
                reason: "must be finite and ≥ 0",
            });
        }
        if self.polish_penalty > 0.0 && self.polish_updates == 0 {
            return Err(SolveError::InvalidSetting {
                field: "polish_updates",
                value: "0".into(),
                reason: "must be ≥ 1 while polish_penalty > 0 (else each polish is a wasted factorization)",
            });
        }
        if !(self.warm_iterate >= 0.0 && self.warm_iterate.is_finite()) {
            return Err(SolveError::InvalidSetting {
                field: "warm_iterate",
                value: Num(self.warm_iterate).to_string(),
                reason: "must be finite and ≥ 0",
            });
        }
        if !(0.0..=1.0).contains(&self.polish_changes) {
            return Err(SolveError::InvalidSetting {
                field: "polish_changes",
                value: Num(self.polish_changes).to_string(),
                reason: "must be in [0, 1]",
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
    /// Multiple of the caller's mean multiplier below which the start does not go.
    pub fn warm_scale(mut self, k: f64) -> Self {
        self.0.warm_scale = k;
        self
    }
    /// Centrality correctors tried per iteration.
    pub fn max_correctors(mut self, n: usize) -> Self {
        self.0.max_correctors = n;
        self
    }
    /// Multiply–adds per factor entry above which the correctors are tried.
    pub fn corrector_threshold(mut self, t: f64) -> Self {
        self.0.corrector_threshold = t;
        self
    }
    /// Penalty of the warm polish (0: never tried).
    pub fn polish_penalty(mut self, rho: f64) -> Self {
        self.0.polish_penalty = rho;
        self
    }
    /// Fraction of rows changing sides in the last solve up to which the polish is tried.
    pub fn polish_changes(mut self, f: f64) -> Self {
        self.0.polish_changes = f;
        self
    }
    /// Multiplier updates of the polish.
    pub fn polish_updates(mut self, n: usize) -> Self {
        self.0.polish_updates = n;
        self
    }
    /// Multiple of the target gap at which the iterate the next solve starts from is kept
    /// (0: never).
    pub fn warm_iterate(mut self, k: f64) -> Self {
        self.0.warm_iterate = k;
        self
    }
    /// Separate primal and dual step lengths.
    pub fn separate_steps(mut self, on: bool) -> Self {
        self.0.separate_steps = on;
        self
    }
    /// Factorizations in 2×2 blocks split over two threads.
    pub fn split_factorization(mut self, on: bool) -> Self {
        self.0.split_factorization = on;
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

/// The interior point stops after this many iterations in a row near the end (`sᵀλ` within
/// [`STALL_ZONE`] times the target gap) that did not bring the measure of progress 10 % below
/// its best: `sᵀλ` while it is above the target, then the certified gap. The target is then
/// mostly below what double precision can certify of this problem: each slack is rounded to ~10⁻¹⁶ of the velocities, so neither `sᵀλ` (the steps
/// then blocked by slacks at their rounding) nor the certified gap (which holds `Σ λ_i s_i`)
/// go below about `10⁻¹⁶ Σ λ_i` (benches/README.md, sessions 20 and 22). On a chain of 3,000
/// pushed together (multipliers up to 56,000) the certified gap stays at 8.8·10⁻⁸ while
/// `sᵀλ` falls; on a crush of 3,600 `sᵀλ` stays at 2.0·10⁻¹¹ (`Σ λ` = 59,000); the solves
/// used to spend their whole budget of 100 iterations there. The stop is a
/// [`SolveStatus::RoundingFloor`] when the certified gap is within [`FLOOR_MARGIN`] of
/// its rounding floor ([`Certificate::floor`]) and the violation meets its target, and a
/// [`SolveStatus::NumericalError`] otherwise (a violation the stall rule, which measures the
/// gap, cannot see improve is no floor of the gap's).
const STALLED_ITERATIONS: usize = 10;
/// See [`STALLED_ITERATIONS`].
const STALL_ZONE: f64 = 1e3;
/// A stall is at the rounding floor when the certified gap is within this factor of
/// [`Certificate::floor`]; further above, the iterate lost its dual residual to the
/// Newton matrices' rounding and the stop is a [`SolveStatus::NumericalError`].
const FLOOR_MARGIN: f64 = 1e2;

/// Mehrotra's predictor–corrector interior point on the velocity-form projection, with
/// sparse Cholesky normal equations. Its answers are certified by [`certify`].
#[derive(Debug)]
pub struct InteriorPoint {
    settings: InteriorPointSettings,
    normal: NormalEquations,
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
    // the direction before a centrality corrector, kept in case it is not taken
    kept_m: [Vec<f64>; 3],
    kept_n: Vec<f64>,
    // the caller's multipliers, and the fraction of rows whose activity the last solve changed
    warm: Vec<f64>,
    warm_floor: f64,
    last_changes: Option<f64>,
    // when the polish is tried
    polish_backoff: BackOff,
    // The polish's last factorization, while nothing has been analysed or factorized since
    // (see [`PolishFactor`]); and one read from a memory, made again by the next solve.
    polish_factor: Option<PolishFactor>,
    restored_polish_factor: Option<PolishFactor>,
    // the right-hand side of a polish solve with that factorization, and its residual
    polish_rhs: Vec<f64>,
    polish_residual: Vec<f64>,
    // The iterate kept for the next start (row key, s, λ; sorted by key), the iterations of
    // the last cold start, and when a start from the kept iterate is tried.
    kept_iterate: Vec<(ConstraintKey, f64, f64)>,
    cold_iterations: Option<usize>,
    kept_backoff: BackOff,
    // The Newton system's augmented form, and whether this solve has taken it (the normal
    // equations broke down).
    augmented: AugmentedSystem,
    augmented_on: bool,
    // Every solve by the augmented form (tests).
    augmented_only: bool,
}

/// The warm polish's factorization of `I + J_Aᵀ D J_A`, reused by the next settled solves.
///
/// In a settled crush the people barely move between steps: `J` changes in its last digits,
/// its rows and the active set not at all. The next polish then solves with the factor in
/// hand instead of factorizing again (measured: the pressed crush of 10⁵ once settled, 320–330
/// → 106–108 ms a step on one thread, benches/README.md, session 26); the certificate judges
/// its answer as any
/// other, and a polish that does not certify with it is tried again with a factorization of
/// its own before the interior point takes over (and after `k` such failures in a row the
/// next `2ᵏ − 1` polishes factorize at once). The factor is used only while nothing has
/// been analysed or factorized since it was made (`analyses`, `factorizations`), and with the
/// same rows active (`d`'s positive entries).
///
/// Its last polish's start is kept with it too: a settled crush's multipliers change almost
/// linearly from step to step, so the next polish on the same rows starts from their
/// extrapolation, `2λ − λ_start`, and one multiplier update certifies where the caller's
/// multipliers took two (the settled crush of 10⁵: first gap ~5·10⁻⁹ against 7.2·10⁻⁶ for a
/// target of 6.5·10⁻⁶; benches/README.md, session 27).
///
/// What made it (`J`'s coefficients, `d`, and a hash of `J`'s structure) and that start are
/// part of the solver's memory, so that a restored solver makes the same factor again and
/// goes on with the same bits as the original.
#[derive(Debug, Clone, PartialEq)]
struct PolishFactor {
    analyses: usize,
    factorizations: usize,
    d: Vec<f64>,
    coefficients: Vec<f64>,
    structure: u64,
    // When it is tried again: where the people move more between steps than it allows (the
    // crush of 10,000 once settled: its first solve's residual 13–20 times the right-hand
    // side), after `k` failures in a row the next `2ᵏ − 1` polishes factorize at once.
    reuse: BackOff,
    // The caller's multipliers (above the floor) the last polish started from, and a hash of
    // their rows' keys: the next polish on the same rows extrapolates from them.
    start: Vec<f64>,
    start_keys: u64,
}

/// A hash of `j`'s rows' keys, in order: whether two problems' rows are the same contacts.
fn keys_hash(j: &ConstraintRows) -> u64 {
    fnv(j.keys().iter().copied())
}

/// A hash of `j`'s structure (its dimension, row starts and columns): what decides whether
/// the normal equations' analysis is redone.
fn structure_hash(j: &ConstraintRows) -> u64 {
    let size = [j.dim() as u64, j.len() as u64];
    let starts = j.row_starts().iter().map(|&s| s as u64);
    fnv(size
        .into_iter()
        .chain(starts)
        .chain(j.columns().iter().map(|&c| c as u64)))
}

/// An attempt that may lose (the polish, the kept iterate's start): after `k` losses in a
/// row, the next `2ᵏ − 1` chances to try it are skipped (`k ≤ 6`): where it keeps losing it
/// costs an attempt every ~2ᵏ solves, not every solve.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct BackOff {
    losses: u32,
    skips: usize,
}

impl BackOff {
    /// Whether to try now; a chance not taken counts down the skips.
    fn allows(&mut self) -> bool {
        if self.skips > 0 {
            self.skips -= 1;
            return false;
        }
        true
    }

    /// The outcome of an attempt.
    fn record(&mut self, won: bool) {
        self.losses = if won { 0 } else { (self.losses + 1).min(6) };
        self.skips = (1 << self.losses) - 1;
    }
}

impl InteriorPoint {
    /// A solver with validated settings.
    pub fn new(settings: InteriorPointSettings) -> Result<Self, SolveError> {
        settings.validate()?;
        let mut normal = NormalEquations::new(settings.parallelism)?;
        normal.keep_orderings();
        if settings.split_factorization {
            normal.split_over_two_threads();
        }
        Ok(Self {
            settings,
            normal,
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
            kept_m: [Vec::new(), Vec::new(), Vec::new()],
            kept_n: Vec::new(),
            warm: Vec::new(),
            warm_floor: 0.0,
            last_changes: None,
            polish_backoff: BackOff::default(),
            kept_iterate: Vec::new(),
            polish_factor: None,
            restored_polish_factor: None,
            polish_rhs: Vec::new(),
            polish_residual: Vec::new(),
            cold_iterations: None,
            kept_backoff: BackOff::default(),
            augmented: AugmentedSystem::default(),
            augmented_on: false,
            augmented_only: false,
        })
    }

    /// Every Newton system by the augmented form, as if the normal equations always broke
    /// down (to test that form on every kind of problem).
    #[cfg(test)]
    fn augmented_only(mut self) -> Self {
        self.augmented_only = true;
        self
    }

    /// Patterns, analyses and factorizations done so far.
    pub fn counts(&self) -> FactorizationCounts {
        FactorizationCounts {
            augmented_factorizations: self.augmented.times().factorizations,
            ..self.normal.counts()
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
            &mut self.warm,
        ] {
            v.clear();
            v.resize(m, 0.0);
        }
        for v in &mut self.kept_m {
            v.clear();
            v.resize(m, 0.0);
        }
        for v in [
            &mut self.rd,
            &mut self.dv,
            &mut self.scratch_n,
            &mut self.kept_n,
        ] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// Factorizes the Newton matrix for the weights `self.d`: the normal equations, or, once
    /// they broke down in this solve, the augmented form ([`AugmentedSystem`]) for the rest of
    /// it. False when that fails too.
    fn factorize_newton(&mut self, j: &ConstraintRows) -> bool {
        if !self.augmented_on {
            if self.normal.factorize(j, 1.0, &self.d) {
                return true;
            }
            // `D` spans more decades than the normal equations hold (a long chain pushed
            // together at a tight target): not a failure of the method.
            self.augmented_on = true;
        }
        matches!(self.augmented.factorize(j, &self.d), Ok(true))
    }

    /// Both factorizations' times.
    fn times(&self) -> StageTimes {
        self.normal.times().plus(self.augmented.times())
    }

    /// One Newton direction for the complementarity right-hand side in `self.rc`:
    /// `(I + JᵀDJ) Δv = −r_d + Jᵀ(r_c/s + D r_p)`, `Δs = JΔv − r_p`, `Δλ = (r_c − λΔs)/s`; once
    /// the normal equations broke down, from the augmented form (nothing multiplied by `D`):
    /// `[I, Jᵀ; J, −D⁻¹] [Δv; −Δλ] = [−r_d; r_c/λ + r_p]`.
    fn direction(&mut self, j: &ConstraintRows, lam: &[f64]) {
        let w = self.normal.workers();
        let (s, d, rp, rc) = (&self.s, &self.d, &self.rp, &self.rc);
        if self.augmented_on {
            w.map(&mut self.scratch_m, |i, _| rc[i] / lam[i] + rp[i]);
            let rd = &self.rd;
            w.map(&mut self.dv, |c, _| -rd[c]);
            self.augmented
                .solve_in_place(&mut self.dv, &mut self.scratch_m);
            let (w, dv, y) = (self.normal.workers(), &self.dv, &self.scratch_m);
            w.map(&mut self.ds, |i, _| row_dot(j, dv, i) - rp[i]);
            w.map(&mut self.dl, |i, _| -y[i]);
            return;
        }
        w.map(&mut self.scratch_m, |i, _| rc[i] / s[i] + d[i] * rp[i]);
        // Δv's right-hand side −r_d + Jᵀ(r_c/s + D r_p) in natural order.
        let (y, rd, jt) = (&self.scratch_m, &self.rd, self.normal.transpose());
        w.map(&mut self.dv, |c, _| jt.dot(y, c) - rd[c]);
        self.normal.solve_in_place(&mut self.dv);
        let w = self.normal.workers();
        let dv = &self.dv;
        w.map(&mut self.ds, |i, _| row_dot(j, dv, i) - rp[i]);
        let ds = &self.ds;
        w.map(&mut self.dl, |i, _| (rc[i] - lam[i] * ds[i]) / s[i]);
    }

    /// The warm polish (see [`InteriorPointSettings::polish_penalty`]) from the caller's
    /// multipliers in `lam`: `(I + J_Aᵀ D J_A) v = w + J_Aᵀ(λ − D b)`, `λ ← λ − D (b + J v)`
    /// on the rows `A` with `λ > 0`, whose fixed point has those rows tight and
    /// `v = w + J_Aᵀλ`. Multipliers at most `warm_floor` count as zero. The certificate when
    /// the solve's `v` and `λ⁺` meet `target` after an update (then in `v`, `lam`); `None` as soon
    /// as an update does not halve the largest residual of those rows, or after
    /// `polish_updates`.
    ///
    /// With `reuse`, the factorization of the last polish is taken instead of a new one where
    /// it still fits ([`PolishFactor`]); the second value says whether it was. A certified
    /// polish comes with the multiplier updates it took.
    fn polish(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        v: &mut [f64],
        lam: &mut [f64],
        reuse: bool,
    ) -> (Option<(Certificate, usize)>, bool) {
        let j = p.jacobian;
        let penalty = self.settings.polish_penalty;
        let floor = self.warm_floor;
        self.normal
            .workers()
            .map(lam, |_, l| if l > floor { l } else { 0.0 });
        {
            let lam: &[f64] = lam;
            self.normal.workers().map(&mut self.d, |i, _| {
                if lam[i] > 0.0 {
                    penalty / j.row_norm_sq(i)
                } else {
                    0.0
                }
            });
        }
        let fits = reuse && self.polish_factor_fits();
        let reused = fits
            && self
                .polish_factor
                .as_mut()
                .is_some_and(|f| f.reuse.allows());
        if !reused {
            // The last one's storage is written over; a factorization that fits but is
            // skipped hands its back-off to the new one.
            let last = self.polish_factor.take();
            let backoff = match &last {
                Some(f) if fits => f.reuse,
                _ => BackOff::default(),
            };
            if !self.normal.factorize(j, 1.0, &self.d) {
                return (None, false);
            }
            let c = self.normal.counts();
            let mut f = last.unwrap_or_else(|| PolishFactor {
                analyses: 0,
                factorizations: 0,
                d: Vec::new(),
                coefficients: Vec::new(),
                structure: 0,
                reuse: BackOff::default(),
                start: Vec::new(),
                start_keys: 0,
            });
            f.d.clone_from(&self.d);
            f.coefficients.clear();
            f.coefficients.extend_from_slice(j.coefficients());
            (f.analyses, f.factorizations) = (c.analyses, c.factorizations);
            (f.structure, f.reuse) = (structure_hash(j), backoff);
            self.polish_factor = Some(f);
        }
        // Where the last polish's factorization fits (the last solve was that polish, on the
        // same active rows), the first attempt on the rows it started on starts from the
        // extrapolation of the caller's multipliers (see `PolishFactor`).
        let keys = keys_hash(j);
        if let Some(f) = self.polish_factor.as_mut() {
            if fits && f.start_keys == keys && f.start.len() == lam.len() {
                for (l, start) in lam.iter_mut().zip(&mut f.start) {
                    let caller = *l;
                    if caller > 0.0 {
                        *l = (2.0 * caller - *start).max(0.0);
                    }
                    *start = caller;
                }
            } else {
                f.start.clear();
                f.start.extend_from_slice(lam);
            }
            f.start_keys = keys;
        }
        let polished = self.polish_updates(p, target, v, lam, reused);
        if reused && let Some(f) = self.polish_factor.as_mut() {
            f.reuse.record(polished.is_some());
        }
        (polished, reused)
    }

    /// Whether the last polish's factorization is the one in hand and fits this polish's
    /// `d`: nothing analysed or factorized since, the same rows active.
    fn polish_factor_fits(&self) -> bool {
        let c = self.normal.counts();
        self.polish_factor.as_ref().is_some_and(|f| {
            (f.analyses, f.factorizations) == (c.analyses, c.factorizations)
                && f.d.len() == self.d.len()
                && f.d
                    .iter()
                    .zip(&self.d)
                    .all(|(a, b)| (*a > 0.0) == (*b > 0.0))
        })
    }

    /// The polish's multiplier updates with the factorization in hand (see [`Self::polish`]):
    /// the certificate and the updates taken.
    fn polish_updates(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        v: &mut [f64],
        lam: &mut [f64],
        reused: bool,
    ) -> Option<(Certificate, usize)> {
        let j = p.jacobian;
        let m = p.rows();
        let mut last = f64::INFINITY;
        for update in 1..=self.settings.polish_updates {
            let wk = self.normal.workers();
            let d = &self.d;
            {
                let lam: &[f64] = lam;
                wk.map(&mut self.scratch_m, |i, _| lam[i] - d[i] * p.b[i]);
            }
            let (y, jt) = (&self.scratch_m, self.normal.transpose());
            wk.map(&mut self.dv, |c, _| p.w[c] + jt.dot(y, c));
            if reused {
                self.polish_rhs.clone_from(&self.dv);
            }
            self.normal.solve_in_place(&mut self.dv);
            if reused && !self.refine_polish_solve(j) {
                return None;
            }
            let (wk, d, dv) = (self.normal.workers(), &self.d, &self.dv);
            wk.map(&mut self.rp, |i, _| {
                if d[i] > 0.0 {
                    p.b[i] + row_dot(j, dv, i)
                } else {
                    0.0
                }
            });
            let rp = &self.rp;
            let residual = -wk.min(m, |i| -rp[i].abs());
            wk.map(lam, |i, l| (l - d[i] * rp[i]).max(0.0));
            // The solve's velocity is `w + J_Aᵀλ` for the updated multipliers (to rounding:
            // recomputing it from them would add the rounding of `D r`, up to 10⁻¹⁰ a row,
            // to the slacks), and its slacks are the residuals just computed.
            v.copy_from_slice(dv);
            let c = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
            if c.gap <= target.gap && c.violation <= target.violation {
                return Some((c, update));
            }
            if !(residual <= 0.5 * last) {
                return None;
            }
            last = residual;
        }
        None
    }

    /// Makes `dv`, solved with a polish factorization made for an earlier `J`, solve
    /// `(I + Jᵀ D J) dv = polish_rhs` for this one: iterative refinement against the true
    /// matrix, each round a pair of triangular solves. True when the residual is below
    /// [`STALE_SOLVE_TOLERANCE`] of the right-hand side (at once in a settled crush, whose `J`
    /// moved in its last digits); false when a round does not halve it or
    /// [`STALE_SOLVE_ROUNDS`] are spent (the polish then factorizes).
    fn refine_polish_solve(&mut self, j: &ConstraintRows) -> bool {
        let norm = |x: &[f64]| x.iter().map(|x| x * x).sum::<f64>().sqrt();
        let scale = norm(&self.polish_rhs);
        let mut last = f64::INFINITY;
        for round in 0..=STALE_SOLVE_ROUNDS {
            // r = rhs − dv − Jᵀ(D (J dv))
            j.mul(&self.dv, &mut self.scratch_m);
            for (t, d) in self.scratch_m.iter_mut().zip(&self.d) {
                *t *= -d;
            }
            self.polish_residual.clear();
            self.polish_residual
                .extend(self.polish_rhs.iter().zip(&self.dv).map(|(r, x)| r - x));
            j.mul_transpose_add(&self.scratch_m, &mut self.polish_residual);
            let r = norm(&self.polish_residual);
            if r <= STALE_SOLVE_TOLERANCE * scale {
                return true;
            }
            if round == STALE_SOLVE_ROUNDS || !(r <= 0.5 * last) {
                return false;
            }
            last = r;
            self.normal.solve_in_place(&mut self.polish_residual);
            for (x, dx) in self.dv.iter_mut().zip(&self.polish_residual) {
                *x += dx;
            }
        }
        false
    }

    /// Makes again, for `j`, the polish factorization a restored memory describes, if `j`
    /// has the structure it was made for (else the original would have analysed again and
    /// dropped it too).
    fn make_polish_factor_again(&mut self, j: &ConstraintRows, mut f: PolishFactor) {
        if f.structure != structure_hash(j)
            || f.d.len() != j.len()
            || f.coefficients.len() != j.nnz()
        {
            return;
        }
        let mut made = ConstraintRows::new(j.dim());
        let (keys, values, starts, columns) = (j.keys(), j.values(), j.row_starts(), j.columns());
        for i in 0..j.len() {
            let (a, b) = (starts[i], starts[i + 1]);
            made.push(
                keys[i],
                values[i],
                columns[a..b]
                    .iter()
                    .copied()
                    .zip(f.coefficients[a..b].iter().copied()),
            );
        }
        if self.normal.factorize(&made, 1.0, &f.d) {
            let c = self.normal.counts();
            (f.analyses, f.factorizations) = (c.analyses, c.factorizations);
            self.polish_factor = Some(f);
        }
    }

    /// The fraction of rows whose activity differs between the caller's multipliers (in
    /// `self.warm`) and the answer's.
    fn changes(&self, lam: &[f64], active: impl Fn(usize) -> bool) -> f64 {
        let m = lam.len();
        let changed = (0..m)
            .filter(|&i| (self.warm[i] > self.warm_floor) != active(i))
            .count();
        changed as f64 / m.max(1) as f64
    }

    /// Exchanges the direction and its complementarity right-hand side with the kept ones.
    fn swap_kept(&mut self) {
        let [ds, dl, rc] = &mut self.kept_m;
        std::mem::swap(&mut self.ds, ds);
        std::mem::swap(&mut self.dl, dl);
        std::mem::swap(&mut self.rc, rc);
        std::mem::swap(&mut self.dv, &mut self.kept_n);
    }

    /// Mehrotra's starting point on `v = w`: the slacks of the unconstrained velocity shifted
    /// into the interior, then `s` and `λ` balanced. The caller's multipliers are not the
    /// start (measured on jammed crowds, starting from them cost 2–4× more iterations,
    /// benches/README.md); only their scale is, through `warm_scale` (`warm_mean`: their
    /// mean).
    fn cold_start(
        &mut self,
        p: &ProjectionProblem<'_>,
        v: &mut [f64],
        lam: &mut [f64],
        warm_mean: f64,
    ) {
        let (m, j) = (p.rows(), p.jacobian);
        v.copy_from_slice(p.w);
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
        // The previous multipliers' scale, but no more than a rough bound of what a
        // multiplier needs here (a heuristic: a wedge can need more): the pushes of `w` all
        // passed on to one contact, plus each row's own violation stopped by it alone. Where the answer's multipliers are not unique (a pair of
        // opposite rows, an equality written as two inequalities: `J_Aᵀ` has a null space)
        // the answer keeps its start along that null space, and starting at 3 × the last
        // answer's mean multiplied it step after step (×3 a step on a bead held to a line,
        // until the 22nd step ended in NumericalError at λ ~ 10²⁹⁸).
        let warm = if warm_mean > 0.0 {
            let pushes: f64 = p.w.iter().map(|x| x.abs()).sum();
            let stops: f64 = (0..m)
                .map(|i| {
                    let n2 = j.row_norm_sq(i);
                    if n2 > 0.0 { self.s[i].abs() / n2 } else { 0.0 }
                })
                .sum();
            warm_mean.min(pushes + stops)
        } else {
            warm_mean
        };
        let shift = (-1.5 * min_s).max(0.0);
        self.s.iter_mut().for_each(|s| *s += shift);
        let lam0 = scale.max(self.settings.warm_scale * warm);
        lam.iter_mut().for_each(|l| *l = lam0);
        let sl: f64 = self.s.iter().zip(lam.iter()).map(|(s, l)| s * l).sum();
        let (sum_s, sum_l): (f64, f64) = (self.s.iter().sum(), lam.iter().sum());
        let (bump_s, bump_l) = (0.5 * sl / sum_l, 0.5 * sl / sum_s.max(f64::MIN_POSITIVE));
        for (s, l) in self.s.iter_mut().zip(lam.iter_mut()) {
            *s = (*s + bump_s).max(1e-8 * scale);
            *l += bump_l;
        }
    }

    /// The predictor–corrector iterations from the start in `v`, `self.s`, `lam` until the
    /// certificate meets `target` or `budget` iterations are spent; the status and the
    /// iterations.
    fn iterate(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        (v, lam): (&mut [f64], &mut [f64]),
        correctors: usize,
        budget: usize,
    ) -> (SolveStatus, usize) {
        let (m, j) = (p.rows(), p.jacobian);
        let tau = self.settings.step_fraction;
        let level = self.settings.warm_iterate * target.gap;
        let mut kept = false;
        let mut iterations = 0;
        // The best `sᵀλ` above the target and certified gap below it, and the iterations since
        // either last improved (see [`STALLED_ITERATIONS`]).
        let (mut best_sl, mut best_gap, mut stalled) = (f64::INFINITY, f64::INFINITY, 0);
        let status = loop {
            let wk = self.normal.workers();
            // Once the residuals vanish the certificate is sᵀλ: below the target gap is
            // when it is worth computing.
            let sl = {
                let (s, lam): (&[f64], &[f64]) = (&self.s, lam);
                wk.sum(m, |i| s[i] * lam[i])
            };
            let last = iterations == budget;
            let check = sl <= target.gap || last;
            // The residuals r_d = v − w − Jᵀλ, r_p = s − b − J v from the iterate at the start
            // and where the certificate is consulted; in between they follow from the Newton
            // system (after the step, below): two passes over J fewer an iteration.
            if iterations == 0 || check {
                let jt = self.normal.transpose();
                let (v, lam): (&[f64], &[f64]) = (v, lam);
                wk.map(&mut self.rd, |c, _| v[c] - p.w[c] - jt.dot(lam, c));
                let s = &self.s;
                wk.map(&mut self.rp, |i, _| s[i] - p.b[i] - row_dot(j, v, i));
            }
            let mut cert_gap = f64::INFINITY;
            if check {
                let c = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
                cert_gap = c.gap;
                if c.gap <= target.gap && c.violation <= target.violation {
                    break SolveStatus::Converged;
                }
                if last {
                    break SolveStatus::MaxIterations;
                }
            }
            if sl <= STALL_ZONE * target.gap {
                let (measure, best) = if check {
                    (cert_gap, &mut best_gap)
                } else {
                    (sl, &mut best_sl)
                };
                if measure < 0.9 * *best {
                    (*best, stalled) = (measure, 0);
                } else {
                    stalled += 1;
                    if stalled == STALLED_ITERATIONS {
                        // Met already (`sᵀλ` can stall above the target while the
                        // certificate, consulted only below it, meets it), a stall at the
                        // certificate's rounding floor, or one far above it (the dual
                        // residual lost to the rounding of a Newton matrix whose `D` spans
                        // 10³⁰: the fallback's question, not a larger target's).
                        let c = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
                        break if c.gap <= target.gap && c.violation <= target.violation {
                            SolveStatus::Converged
                        } else if c.gap <= FLOOR_MARGIN * c.floor && c.violation <= target.violation
                        {
                            SolveStatus::RoundingFloor
                        } else {
                            SolveStatus::NumericalError
                        };
                    }
                }
            }
            if !kept && iterations > 0 && sl <= level {
                kept = true;
                self.keep_iterate(j, lam);
            }
            iterations += 1;
            let mu = sl / m as f64;
            {
                let (s, lam): (&[f64], &[f64]) = (&self.s, lam);
                self.normal.workers().map(&mut self.d, |i, _| lam[i] / s[i]);
                // Predictor (affine scaling).
                self.normal
                    .workers()
                    .map(&mut self.rc, |i, _| -s[i] * lam[i]);
            }
            if !self.factorize_newton(j) {
                break SolveStatus::NumericalError;
            }
            self.direction(j, lam);
            let wk = self.normal.workers();
            let (s, ds, dl) = (&self.s, &self.ds, &self.dl);
            let alpha_aff = Self::max_step(Self::max_steps(wk, s, ds, lam, dl));
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
                self.normal.workers().map(&mut self.rc, |i, _| {
                    -s[i] * lam[i] - dsa[i] * dla[i] + sigma * mu
                });
            }
            self.direction(j, lam);
            let wk = self.normal.workers();
            let mut steps = Self::max_steps(wk, &self.s, &self.ds, lam, &self.dl);
            let mut alpha_max = Self::max_step(steps);
            for _ in 0..correctors {
                if alpha_max >= 1.0 {
                    break;
                }
                // Gondzio's centrality corrector: the products s∘λ at a longer trial step,
                // pushed back into [0.1 σμ, 10 σμ] (the large ones by at most 10 σμ).
                let trial = (1.5 * alpha_max).min(1.0);
                let (lo, hi) = (0.1 * sigma * mu, 10.0 * sigma * mu);
                {
                    // The corrected right-hand side into the kept buffers, then the current
                    // direction and right-hand side swapped there, in case the new one is
                    // not taken.
                    let (s, ds, dl, rc) = (&self.s, &self.ds, &self.dl, &self.rc);
                    let lam: &[f64] = lam;
                    self.normal.workers().map(&mut self.kept_m[2], |i, _| {
                        let v = (s[i] + trial * ds[i]) * (lam[i] + trial * dl[i]);
                        rc[i] + (v.clamp(lo, hi) - v).max(-hi)
                    });
                }
                self.swap_kept();
                self.direction(j, lam);
                let wk = self.normal.workers();
                let next_steps = Self::max_steps(wk, &self.s, &self.ds, lam, &self.dl);
                let next = Self::max_step(next_steps);
                if next >= 1.01 * alpha_max && self.dv.iter().all(|x| x.is_finite()) {
                    (steps, alpha_max) = (next_steps, next);
                } else {
                    self.swap_kept();
                    break;
                }
            }
            let wk = self.normal.workers();
            let alpha = tau * alpha_max;
            if !(alpha > 0.0) || self.dv.iter().any(|x| !x.is_finite()) {
                break SolveStatus::NumericalError;
            }
            let (dv, ds, dl) = (&self.dv, &self.ds, &self.dl);
            let (alpha_primal, alpha_dual) = if self.settings.separate_steps {
                (tau * steps.0, tau * steps.1)
            } else {
                (alpha, alpha)
            };
            wk.map(v, |k, x| x + alpha_primal * dv[k]);
            wk.map(&mut self.s, |i, x| x + alpha_primal * ds[i]);
            wk.map(lam, |i, x| x + alpha_dual * dl[i]);
            // The residuals after the step, from `JᵀΔλ = Δv + r_d` and `Δs = JΔv − r_p`:
            // `r_d ← (1 − α_d) r_d + (α_p − α_d) Δv`, `r_p ← (1 − α_p) r_p` (to the rounding
            // of the triangular solves, which the exact residuals at a check bring back).
            wk.map(&mut self.rd, |c, r| {
                (1.0 - alpha_dual) * r + (alpha_primal - alpha_dual) * dv[c]
            });
            wk.map(&mut self.rp, |_, r| (1.0 - alpha_primal) * r);
        };
        (status, iterations)
    }

    /// Keeps the iterate `(s, λ)` with its rows' keys for the next solve's start.
    fn keep_iterate(&mut self, j: &ConstraintRows, lam: &[f64]) {
        let keys = j.keys();
        self.kept_iterate.clear();
        self.kept_iterate
            .extend((0..lam.len()).map(|i| (keys[i], self.s[i], lam[i])));
        self.kept_iterate.sort_unstable_by_key(|e| e.0);
    }

    /// The start from the kept iterate (see [`InteriorPointSettings::warm_iterate`]): each row
    /// found by its key takes its kept `s` and `λ`; a new row its slack at `w`, at least
    /// `√μ` of the kept iterate, and `λ = μ / s`. Then `v = w + Jᵀλ` (no dual residual) and
    /// each slack is raised to its row's slack at that `v` where that is larger (a contact
    /// opening since). False, with nothing changed that the cold start does not overwrite,
    /// when fewer than half of the rows are found.
    fn kept_start(&mut self, p: &ProjectionProblem<'_>, v: &mut [f64], lam: &mut [f64]) -> bool {
        let (m, j) = (p.rows(), p.jacobian);
        let kept = &self.kept_iterate;
        // (A kept pair is strictly positive unless a memory was damaged: then as new.)
        let inside = |x: f64| x > 0.0 && x.is_finite();
        let (sum, count) = kept
            .iter()
            .filter(|e| inside(e.1) && inside(e.2))
            .fold((0.0, 0usize), |(sum, n), e| (sum + e.1 * e.2, n + 1));
        let mu = sum / count as f64;
        if !inside(mu) {
            return false;
        }
        let keys = j.keys();
        let mut found = 0;
        // Rows mostly come in increasing keys (a crowd's pairs by person): each search starts
        // where the last one ended, galloping.
        let mut from = 0;
        for i in 0..m {
            let at = find_from(kept, keys[i], &mut from, |e| e.0);
            if let Some(&(_, s, l)) = at.map(|k| &kept[k]).filter(|e| inside(e.1) && inside(e.2)) {
                (self.s[i], lam[i]) = (s, l);
                found += 1;
            } else {
                self.s[i] = (p.b[i] + row_dot(j, p.w, i)).max(mu.sqrt());
                lam[i] = mu / self.s[i];
            }
        }
        if 2 * found < m {
            return false;
        }
        v.copy_from_slice(p.w);
        j.mul_transpose_add(lam, v);
        for i in 0..m {
            self.s[i] = self.s[i].max(p.b[i] + row_dot(j, v, i));
        }
        true
    }

    /// The largest `α ≤ 1` keeping `s + αΔs ≥ 0`, and that keeping `λ + αΔλ ≥ 0`, in one
    /// pass.
    fn max_steps(w: &Workers, s: &[f64], ds: &[f64], lam: &[f64], dl: &[f64]) -> (f64, f64) {
        let (p, d) = w.min_pair(s.len(), |i| {
            (step_ratio(s[i], ds[i]), step_ratio(lam[i], dl[i]))
        });
        (p.min(1.0), d.min(1.0))
    }

    /// The largest `α ≤ 1` keeping both (of [`Self::max_steps`]).
    fn max_step((primal, dual): (f64, f64)) -> f64 {
        primal.min(dual)
    }
}

/// How far along `dx` the positive `x` may go, where that is less than all the way (`dx` and
/// beyond: `∞`, as every use takes at most 1): `x / −dx` where `x < −dx` (then `dx < 0`; a
/// quotient that rounds up to 1 is 1 either way), else `∞`. Most rows do not block a step:
/// their division is skipped.
fn step_ratio(x: f64, dx: f64) -> f64 {
    if x < -dx { x / -dx } else { f64::INFINITY }
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
        target.validate()?;
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
            self.last_changes = Some(0.0);
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
        let warm_mean = lam.iter().sum::<f64>() / m as f64;
        self.warm.copy_from_slice(lam);
        // An interior point leaves every multiplier positive, those of the inactive rows
        // ~μ/s: the caller's active rows are those above a millionth of the mean.
        self.warm_floor = 1e-6 * warm_mean;

        let times = self.times();
        self.normal.analyse(j)?;
        if let Some(restored) = self.restored_polish_factor.take() {
            self.make_polish_factor_again(j, restored);
        }
        self.augmented_on = self.augmented_only;
        self.augmented.forget();
        let settled = self
            .last_changes
            .is_some_and(|c| c <= self.settings.polish_changes);
        let tried = self.settings.polish_penalty > 0.0 && warm_mean > 0.0 && settled;
        if tried && self.polish_backoff.allows() {
            // Backed off where it keeps failing (a crush of 40,000 whose contacts still open
            // and close by the handful).
            let polished = match self.polish(p, target, v, lam, true) {
                // The factorization kept from an earlier step did not do: again with one of
                // its own, from the caller's multipliers.
                (None, true) => {
                    let reuse = self.polish_factor.as_ref().map(|f| f.reuse);
                    lam.copy_from_slice(&self.warm);
                    let polished = self.polish(p, target, v, lam, false).0;
                    if let (Some(f), Some(reuse)) = (self.polish_factor.as_mut(), reuse) {
                        f.reuse = reuse;
                    }
                    polished
                }
                (polished, _) => polished,
            };
            self.polish_backoff.record(polished.is_some());
            if let Some((cert, updates)) = polished {
                self.last_changes = Some(self.changes(lam, |i| lam[i] > 0.0));
                // Its iterations: the multiplier updates (each a pair of triangular solves).
                let mut report = SolveReport {
                    solver: self.name(),
                    status: SolveStatus::Converged,
                    gap: cert.gap,
                    violation: cert.violation,
                    iterations: updates,
                    active: cert.active,
                    ..SolveReport::default()
                };
                self.times().since(times).report_into(&mut report);
                return Ok(report);
            }
        }
        // The interior point's factorizations replace the polish's.
        self.polish_factor = None;
        let correctors = {
            let c = self.normal.counts();
            let dense =
                c.factor_flops as f64 > self.settings.corrector_threshold * c.factor_nnz as f64;
            if dense {
                self.settings.max_correctors
            } else {
                0
            }
        };
        // The kept iterate's start, unless the last ones lost (see `warm_iterate`); redone
        // cold when it does not converge.
        let kept = self.settings.warm_iterate > 0.0 && !self.kept_iterate.is_empty();
        let from_kept = kept && self.kept_backoff.allows() && self.kept_start(p, v, lam);
        // A start from the kept iterate that takes twice the last cold start's iterations
        // has lost already: it is stopped there and redone cold.
        let max = self.settings.max_iterations;
        let (mut status, mut iterations) = if from_kept {
            let budget = self.cold_iterations.map_or(max, |c| (2 * c).clamp(1, max));
            self.iterate(p, target, (v, lam), correctors, budget)
        } else {
            (SolveStatus::MaxIterations, 0)
        };
        if from_kept {
            let lost = !status.is_converged()
                || self.cold_iterations.is_some_and(|cold| iterations >= cold);
            self.kept_backoff.record(!lost);
        }
        if !from_kept || !status.is_converged() {
            self.cold_start(p, v, lam, warm_mean);
            let (cold_status, cold_iterations) = self.iterate(p, target, (v, lam), correctors, max);
            status = cold_status;
            iterations += cold_iterations;
            self.cold_iterations = Some(cold_iterations);
        }
        let cert = certify(p, v, lam, &mut self.scratch_m, &mut self.scratch_n);
        // Active: rows whose multiplier dominates their slack (complementarity decides).
        let active = (0..m).filter(|&i| lam[i] > self.s[i]).count();
        self.last_changes = Some(self.changes(lam, |i| lam[i] > self.s[i]));
        let mut report = SolveReport {
            solver: self.name(),
            status,
            gap: cert.gap,
            violation: cert.violation,
            iterations,
            active,
            ..SolveReport::default()
        };
        self.times().since(times).report_into(&mut report);
        Ok(report)
    }

    /// `[last_changes, the polish's losses and skips, cold_iterations, the kept start's losses
    /// and skips, (key_high, key_low, s, λ) of each row of the kept iterate…]`: what decides
    /// the next solve's polish and start (`-1` for none yet; each key in two 32-bit halves,
    /// exact in an f64). With the warm polish's factorization kept for the next settled
    /// solves, what made it follows: `[−3, the six numbers above, K, the kept iterate's 4K
    /// numbers, M, d (M numbers), C, J's coefficients (C numbers), the structure's hash in
    /// two 32-bit halves, its reuse's losses and skips, the hash of the rows' keys in two
    /// halves, S, the polish's start (S numbers)]` (session 26's layout, marked −2, ends
    /// before the keys' hash; it is still read). Once something is analysed, what the next
    /// ordering depends on (crate::reorder: the last analysis's ordering and the analysis
    /// kept for the next one) comes first, `[−4, its numbers]`.
    fn memory(&self) -> Vec<f64> {
        let mut memory = Vec::new();
        if self.normal.keeps_orderings() {
            memory.push(ORDERING_LAYOUT);
            self.normal.kept_memory(&mut memory);
            // (Nothing analysed or kept: the older layouts alone.)
            if memory[1..].iter().all(|&x| x == 0.0) {
                memory.clear();
            }
        }
        self.append_memory(&mut memory);
        memory
    }

    /// Takes what [`memory`](Self::memory) gave; anything else leaves the solver as new.
    fn set_memory(&mut self, memory: &[f64]) {
        let rest = if memory.first() == Some(&ORDERING_LAYOUT) {
            self.normal.set_kept_memory(&memory[1..])
        } else {
            self.normal.set_kept_memory(&[]).map(|_| memory)
        };
        // (A memory that is not one leaves the solver as new, its kept analysis too.)
        if !rest.is_some_and(|rest| self.set_rest_of_memory(rest)) {
            self.set_rest_of_memory(&[]);
            self.normal.set_kept_memory(&[]);
        }
    }
}

impl InteriorPoint {
    /// [`ProjectionSolver::memory`] after the kept analysis, appended to `out`.
    fn append_memory(&self, out: &mut Vec<f64>) {
        let counts = self.normal.counts();
        let factor = self
            .restored_polish_factor
            .as_ref()
            .or(self.polish_factor.as_ref().filter(|f| {
                (f.analyses, f.factorizations) == (counts.analyses, counts.factorizations)
            }));
        let memory = out;
        memory.reserve(
            MEMORY_HEAD
                + 4 * self.kept_iterate.len()
                + factor.map_or(0, |f| 10 + f.d.len() + f.coefficients.len() + f.start.len()),
        );
        if factor.is_some() {
            memory.push(POLISH_FACTOR_LAYOUT);
        }
        memory.extend([
            self.last_changes.unwrap_or(-1.0),
            self.polish_backoff.losses as f64,
            self.polish_backoff.skips as f64,
            self.cold_iterations.map_or(-1.0, |c| c as f64),
            self.kept_backoff.losses as f64,
            self.kept_backoff.skips as f64,
        ]);
        if factor.is_some() {
            memory.push(self.kept_iterate.len() as f64);
        }
        for &(key, s, l) in &self.kept_iterate {
            memory.extend([(key >> 32) as f64, (key as u32) as f64, s, l]);
        }
        if let Some(f) = factor {
            memory.push(f.d.len() as f64);
            memory.extend_from_slice(&f.d);
            memory.push(f.coefficients.len() as f64);
            memory.extend_from_slice(&f.coefficients);
            memory.extend([
                (f.structure >> 32) as f64,
                (f.structure as u32) as f64,
                f.reuse.losses as f64,
                f.reuse.skips as f64,
                (f.start_keys >> 32) as f64,
                (f.start_keys as u32) as f64,
                f.start.len() as f64,
            ]);
            memory.extend_from_slice(&f.start);
        }
    }

    /// [`ProjectionSolver::set_memory`] after the kept analysis; false, with the solver's
    /// history as new, when `memory` is not one.
    fn set_rest_of_memory(&mut self, memory: &[f64]) -> bool {
        let count = |x: f64| (x >= 0.0 && x.fract() == 0.0).then_some(x as usize);
        self.last_changes = None;
        self.polish_backoff = BackOff::default();
        (self.cold_iterations, self.kept_backoff) = (None, BackOff::default());
        self.kept_iterate.clear();
        (self.polish_factor, self.restored_polish_factor) = (None, None);
        // With a polish factorization: its layout mark, the head, the kept rows' count and
        // numbers, then the factorization's; without: the head and the kept rows' numbers.
        let layout = memory.first().copied();
        let (head, rows, factor) = if layout == Some(POLISH_FACTOR_LAYOUT)
            || layout == Some(POLISH_FACTOR_LAYOUT_UNSTARTED)
        {
            let with_start = layout == Some(POLISH_FACTOR_LAYOUT);
            let Some(parts) = split_polish_memory(&memory[1..], with_start) else {
                return false;
            };
            parts
        } else {
            match (memory.get(..MEMORY_HEAD), memory.get(MEMORY_HEAD..)) {
                (Some(head), Some(rows)) if rows.len() % 4 == 0 => (head, rows, None),
                _ => return false,
            }
        };
        let (Some(pf), Some(ps), Some(wf), Some(ws)) = (
            count(head[1]),
            count(head[2]),
            count(head[4]),
            count(head[5]),
        ) else {
            return false;
        };
        self.last_changes = (head[0] >= 0.0).then_some(head[0]);
        self.polish_backoff = BackOff {
            losses: (pf as u32).min(6),
            skips: ps,
        };
        self.cold_iterations = count(head[3]);
        self.kept_backoff = BackOff {
            losses: (wf as u32).min(6),
            skips: ws,
        };
        self.kept_iterate.extend(
            rows.chunks_exact(4)
                .map(|r| (((r[0] as u64) << 32) | r[1] as u64, r[2], r[3])),
        );
        self.kept_iterate.sort_unstable_by_key(|e| e.0);
        self.restored_polish_factor = factor;
        true
    }
}

/// A count, then as many times `per` numbers: those numbers and the rest; `None` if `memory`
/// does not begin so.
fn counted(memory: &[f64], per: usize) -> Option<(&[f64], &[f64])> {
    let n = *memory.first()?;
    let n = (n >= 0.0 && n.fract() == 0.0).then_some(n as usize)?;
    let end = n.checked_mul(per)?.checked_add(1)?;
    Some((memory.get(1..end)?, memory.get(end..)?))
}

/// The parts of a memory in the layout with a polish factorization (after its mark): the
/// head, the kept iterate's numbers and the factorization; `None` if it is not one.
fn split_polish_memory(
    memory: &[f64],
    with_start: bool,
) -> Option<(&[f64], &[f64], Option<PolishFactor>)> {
    let count = |x: &f64| (*x >= 0.0 && x.fract() == 0.0).then_some(*x as usize);
    let head = memory.get(..MEMORY_HEAD)?;
    let rest = &memory[MEMORY_HEAD..];
    let (rows, rest) = counted(rest, 4)?;
    let (d, rest) = counted(rest, 1)?;
    let (coefficients, rest) = counted(rest, 1)?;
    let half = |x: &f64| count(x).filter(|&x| x <= u32::MAX as usize);
    let word = |high: &f64, low: &f64| Some(((half(high)? as u64) << 32) | half(low)? as u64);
    let ([high, low, losses, skips], start, start_keys) = match rest {
        [high, low, losses, skips] if !with_start => ([high, low, losses, skips], &[][..], 0),
        [high, low, losses, skips, keys_high, keys_low, start @ ..] if with_start => {
            let (start, rest) = counted(start, 1)?;
            if !rest.is_empty() {
                return None;
            }
            let keys = word(keys_high, keys_low)?;
            ([high, low, losses, skips], start, keys)
        }
        _ => return None,
    };
    let structure = word(high, low)?;
    let reuse = BackOff {
        losses: (count(losses)? as u32).min(6),
        skips: count(skips)?,
    };
    Some((
        head,
        rows,
        Some(PolishFactor {
            analyses: 0,
            factorizations: 0,
            d: d.to_vec(),
            coefficients: coefficients.to_vec(),
            structure,
            reuse,
            start: start.to_vec(),
            start_keys,
        }),
    ))
}

/// A polish solve with a factorization made for an earlier `J` is taken when its residual
/// against this `J` is at most this fraction of the right-hand side (the pressed crush of
/// 10⁵ once settled: ~3·10⁻¹⁰ at once, which is also about the rounding of the residual
/// itself with the polish's penalty of 10⁶).
const STALE_SOLVE_TOLERANCE: f64 = 1e-8;

/// Rounds of iterative refinement a polish solve with such a factorization may take.
const STALE_SOLVE_ROUNDS: usize = 4;

/// The first number of [`InteriorPoint`]'s memory when it holds a polish factorization (the
/// other layout begins with `last_changes`, at least −1).
const POLISH_FACTOR_LAYOUT: f64 = -3.0;

/// The same, from before the polish's start was kept with its factorization (read with no
/// start: the next polish starts from the caller's multipliers).
const POLISH_FACTOR_LAYOUT_UNSTARTED: f64 = -2.0;

/// The first number of [`InteriorPoint`]'s memory when it holds what the next ordering
/// depends on (followed by it, then by one of the other layouts).
const ORDERING_LAYOUT: f64 = -4.0;

/// Numbers before the kept iterate's rows in [`InteriorPoint`]'s memory.
const MEMORY_HEAD: usize = 6;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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

    /// The orderings kept from analysis to analysis (crate::reorder) depend on the analyses
    /// before, so what they depend on is part of the memory. Restored from it mid-run, a
    /// solver answers a wandering crowd's projections bit for bit as the original does, with
    /// the crowd calm (most people keep their places; some steps have the last step's rows,
    /// where the original analyses nothing) and restless (too many people dirty: fresh
    /// orderings for a while); restored without it (its own orderings afresh), it does not.
    #[test]
    fn a_restored_interior_point_orders_and_answers_as_the_original() {
        for (jitter, seed) in [(0.01, 5), (0.06, 6)] {
            let crowd = crate::reorder::wandering_crowd(150, 24, jitter, seed);
            let target = Target {
                gap: 1e-8,
                violation: 1e-9,
            };
            let solve = |ip: &mut InteriorPoint, sol: &mut ProjectionSolution, k: usize| {
                let (j, b, w) = &crowd[k];
                let p = ProjectionProblem { w, jacobian: j, b };
                let rep = ip.solve(&p, target, sol).unwrap();
                assert!(rep.status.is_converged(), "step {k}: {rep:?}");
            };
            let new = || InteriorPoint::new(InteriorPointSettings::default()).unwrap();
            let mut original = new();
            let mut sol = ProjectionSolution::default();
            for k in 0..6 {
                solve(&mut original, &mut sol, k);
            }
            let memory = original.memory();
            assert_eq!(memory[0], ORDERING_LAYOUT);
            let mut restored = new();
            restored.set_memory(&memory);
            assert_eq!(restored.memory(), memory);
            // The same memory without what the orderings depend on (the layout after it).
            let mut rest = new();
            rest.set_memory(&memory);
            rest.normal.set_kept_memory(&[]);
            let (mut restored_sol, mut rest_sol) = (sol.clone(), sol.clone());
            let mut differed = false;
            for k in 6..crowd.len() {
                solve(&mut original, &mut sol, k);
                solve(&mut restored, &mut restored_sol, k);
                solve(&mut rest, &mut rest_sol, k);
                assert_eq!(sol, restored_sol, "jitter {jitter}, step {k}");
                assert_eq!(
                    original.memory(),
                    restored.memory(),
                    "jitter {jitter}, step {k}"
                );
                differed |= sol != rest_sol;
            }
            assert!(
                differed,
                "jitter {jitter}: the orderings' memory changed no answer"
            );
        }
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

    /// A chain of `n` unknowns on a line pushed together: rows `v_{k+1} − v_k ≥ 0.05`, the
    /// unconstrained velocities `w_k = −k/n` with a ±0.01 wobble, so that every row is active
    /// and the pressure adds up along the chain (multipliers up to ~n²/160).
    fn pushed_chain(n: usize) -> (ConstraintRows, Vec<f64>, Vec<f64>) {
        let mut rows = ConstraintRows::new(n);
        for k in 0..n - 1 {
            rows.push(k as u64, 0.0, [(k + 1, 1.0), (k, -1.0)]);
        }
        let wobble = |k: usize| 0.01 * ((k * 7919 % 13) as f64 / 6.0 - 1.0);
        let w = (0..n).map(|k| -(k as f64) / n as f64 + wobble(k)).collect();
        (rows, w, vec![-0.05; n - 1])
    }

    /// Regression: on a chain of 1,000 pushed together `D = λ/s` reaches 10¹⁷ and more below
    /// a gap of ~10⁻⁷, the Cholesky factorization of `I + JᵀDJ` broke down and the solve
    /// ended with `NumericalError`. The augmented form takes over and the answer is the
    /// closed form: every gap exactly 0.05 (`v_k = c + 0.05 k`, `c` the mean of `w_k − 0.05
    /// k`) and `λ_k = Σ_{i ≤ k} (w_i − v_i)`; the same bits on two threads.
    #[test]
    fn a_long_chain_pushed_together_is_certified_after_the_normal_equations_break_down() {
        let n = 1000;
        let (rows, w, b) = pushed_chain(n);
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let c = (0..n).map(|k| w[k] - 0.05 * k as f64).sum::<f64>() / n as f64;
        let exact: Vec<f64> = (0..n).map(|k| c + 0.05 * k as f64).collect();
        let exact_lambda: Vec<f64> = (0..n - 1)
            .scan(0.0, |sum, k| {
                *sum += w[k] - exact[k];
                Some(*sum)
            })
            .collect();
        // (Not 10⁻⁹: the certificate computed from the slacks has a rounding floor of
        // `u Σ λ_i |J_i| |v|` ~ 10⁻⁸ here; the cancelling form it replaced reached 10⁻⁹ by
        // rounding luck.)
        for gap in [1e-7, 3e-8] {
            let target = Target {
                gap,
                violation: 1e-9,
            };
            let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
            let mut sol = ProjectionSolution::default();
            let rep = ip.solve(&p, target, &mut sol).unwrap();
            assert!(
                rep.status.is_converged() && rep.gap <= gap && rep.violation <= 1e-9,
                "{rep:?}"
            );
            let counts = ip.counts();
            assert!(counts.augmented_factorizations > 0, "{counts:?}");
            assert_eq!(
                rep.factorizations,
                counts.factorizations + counts.augmented_factorizations
            );
            // A certified gap bounds the distance to the projection: ½|v − v*|² ≤ gap.
            let err = (0..n).map(|k| (sol.v[k] - exact[k]).powi(2)).sum::<f64>();
            assert!(0.5 * err <= rep.gap, "velocity off by {err:e}");
            let err = (0..n - 1).fold(0.0f64, |e, k| {
                e.max((sol.lambda[k] - exact_lambda[k]).abs() / exact_lambda[k])
            });
            assert!(err < 1e-6, "multipliers off by {err:e} (relative)");
            // The same bits on two threads.
            let mut two = InteriorPoint::new(InteriorPointSettings {
                parallelism: Parallelism::threads(2),
                ..InteriorPointSettings::default()
            })
            .unwrap();
            let mut other = ProjectionSolution::default();
            let rep2 = two.solve(&p, target, &mut other).unwrap();
            assert_eq!(rep2.iterations, rep.iterations);
            let bits = |x: &[f64]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert!(bits(&other.v) == bits(&sol.v) && bits(&other.lambda) == bits(&sol.lambda));
        }
    }

    /// Regression: on a chain of 3,000 pushed together (multipliers up to 56,000) a gap of
    /// 10⁻⁸ is below what double precision certifies (the slacks' rounding times `Σ λ`:
    /// ~9·10⁻⁸), and the solve spent its whole budget of 100 iterations at that floor. It
    /// stops after [`STALLED_ITERATIONS`] iterations that do not improve the gap, the answer
    /// the certified one at the floor.
    #[test]
    fn a_target_below_what_double_precision_certifies_stops_at_the_floor() {
        let n = 3000;
        let (rows, w, b) = pushed_chain(n);
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let mut ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
        let mut sol = ProjectionSolution::default();
        let target = Target {
            gap: 1e-8,
            violation: 1e-9,
        };
        let rep = ip.solve(&p, target, &mut sol).unwrap();
        assert_eq!(rep.status, SolveStatus::RoundingFloor, "{rep:?}");
        assert!(rep.iterations <= 30, "{rep:?}");
        assert!(rep.gap < 1e-6 && rep.violation <= 1e-9, "{rep:?}");
        let c = (0..n).map(|k| w[k] - 0.05 * k as f64).sum::<f64>() / n as f64;
        let err = (0..n)
            .map(|k| (sol.v[k] - c - 0.05 * k as f64).powi(2))
            .sum::<f64>();
        assert!(0.5 * err <= rep.gap, "velocity off by {err:e}");
    }

    /// The augmented form alone (as if the normal equations always broke down) answers what
    /// they answer: the chain of four in closed form, and random problems with repeated rows
    /// (`J Jᵀ` singular: a self-stress the regularization decides), each certified, within the
    /// two certified gaps of each other.
    #[test]
    fn the_augmented_form_answers_every_problem_the_normal_equations_answer() {
        let target = Target {
            gap: 1e-10,
            violation: 1e-10,
        };
        let exercised = std::cell::Cell::new(0);
        let solve_both = |rows: &ConstraintRows, w: &[f64], b: &[f64]| {
            let p = ProjectionProblem {
                w,
                jacobian: rows,
                b,
            };
            let mut out = Vec::new();
            for augmented in [false, true] {
                let ip = InteriorPoint::new(InteriorPointSettings::default()).unwrap();
                let mut ip = if augmented { ip.augmented_only() } else { ip };
                let mut sol = ProjectionSolution::default();
                let rep = ip.solve(&p, target, &mut sol).unwrap();
                assert!(rep.status.is_converged(), "augmented {augmented}: {rep:?}");
                let counts = ip.counts();
                let by_normal = counts.factorizations;
                assert!(!augmented || by_normal == 0, "{counts:?}");
                assert!(
                    augmented || counts.augmented_factorizations == 0,
                    "{counts:?}"
                );
                exercised.set(exercised.get() + counts.augmented_factorizations.min(1));
                out.push((sol, rep.gap));
            }
            let ((normal, gap_n), (aug, gap_a)) = (out.remove(0), out.remove(0));
            // ½|v − v*|² ≤ gap for each.
            let dist = (0..w.len())
                .map(|c| (aug.v[c] - normal.v[c]).powi(2))
                .sum::<f64>();
            assert!(
                dist.sqrt() <= (2.0 * gap_n).sqrt() + (2.0 * gap_a).sqrt(),
                "{:?} {:?}",
                aug.v,
                normal.v
            );
            aug
        };
        // The chain of four against a wall: v = 0, λ = (4, 3, 2, 1).
        let (rows, w, b) = chain();
        let aug = solve_both(&rows, &w, &b);
        for (k, want) in [4.0, 3.0, 2.0, 1.0].into_iter().enumerate() {
            assert!((aug.lambda[k] - want).abs() < 1e-8, "{:?}", aug.lambda);
            assert!(aug.v[k].abs() < 1e-9, "{:?}", aug.v);
        }
        // Random feasible problems (each row holds at a random `v₀`, a third of them tight
        // there), a third of their rows repeated (J Jᵀ singular).
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        for _ in 0..20 {
            let (n, m) = (rng.random_range(2..12), rng.random_range(1..16));
            let v0: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut rows = ConstraintRows::new(n);
            let mut b = Vec::new();
            for i in 0..m {
                if i > 0 && rng.random_bool(0.3) {
                    let (c, a) = rows.row(i - 1);
                    let entries: Vec<(usize, f64)> =
                        c.iter().copied().zip(a.iter().copied()).collect();
                    rows.push(i as u64, 0.0, entries);
                    b.push(b[i - 1]);
                    continue;
                }
                let k = rng.random_range(1..=n.min(4));
                let entries: Vec<(usize, f64)> = (0..k)
                    .map(|_| (rng.random_range(0..n), rng.random_range(-1.0..1.0)))
                    .collect();
                rows.push(i as u64, 0.0, entries);
                let slack = if rng.random_bool(0.3) {
                    0.0
                } else {
                    rng.random_range(0.0..0.3)
                };
                b.push(slack - row_dot(&rows, &v0, i));
            }
            let w: Vec<f64> = (0..n).map(|_| rng.random_range(-2.0..2.0)).collect();
            solve_both(&rows, &w, &b);
        }
        assert!(
            exercised.get() >= 15,
            "{} of 21 solved by the augmented form",
            exercised.get()
        );
    }

    #[test]
    fn a_zero_row_that_cannot_hold_is_infeasible() {
        let mut rows = ConstraintRows::new(1);
        rows.push(0, 0.0, []);
        let (rep, _) = solve(&rows, &[0.0], &[-1.0]);
        assert_eq!(rep.status, SolveStatus::Infeasible);
    }

    /// A chain of four disks on a line, each pushed into the next, against a wall: every row
    /// active, multipliers 1, 2, 3, 4 (the pressure adds up along the chain).
    fn chain() -> (ConstraintRows, Vec<f64>, Vec<f64>) {
        let mut rows = ConstraintRows::new(4);
        rows.push(0, 0.0, [(0, 1.0)]);
        for k in 1..4 {
            rows.push(k as u64, 0.0, [(k, 1.0), (k - 1, -1.0)]);
        }
        (rows, vec![-1.0; 4], vec![0.0; 4])
    }

    fn solve_from(
        settings: InteriorPointSettings,
        warm: &[f64],
    ) -> (SolveReport, ProjectionSolution) {
        let (rows, w, b) = chain();
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let mut ip = InteriorPoint::new(settings).unwrap();
        let mut sol = ProjectionSolution {
            v: Vec::new(),
            lambda: warm.to_vec(),
        };
        let target = Target {
            gap: 1e-14,
            violation: 1e-12,
        };
        (ip.solve(&p, target, &mut sol).unwrap(), sol)
    }

    #[test]
    fn the_start_takes_its_scale_from_the_callers_multipliers_whatever_they_are() {
        // The closed form: v = 0, λ = (4, 3, 2, 1) from the wall outwards.
        for warm in [
            [0.0; 4],
            [1.0, 1.0, 1.0, 1.0],
            [1e6, 0.0, 1e6, 0.0],
            [1e-9; 4],
        ] {
            for scale in [0.0, 1.0, 10.0] {
                let settings = InteriorPointSettings::builder()
                    .warm_scale(scale)
                    .build()
                    .unwrap();
                let (rep, sol) = solve_from(settings, &warm);
                assert!(rep.status.is_converged(), "{warm:?} {scale}: {rep:?}");
                for (k, l) in sol.lambda.iter().enumerate() {
                    assert!(
                        (l - (4 - k) as f64).abs() < 1e-6,
                        "{warm:?} {scale}: {sol:?}"
                    );
                }
                assert!(sol.v.iter().all(|v| v.abs() < 1e-6), "{sol:?}");
            }
        }
    }

    #[test]
    fn without_warm_multipliers_the_start_is_mehrotras() {
        let with = |scale| {
            let settings = InteriorPointSettings::builder()
                .warm_scale(scale)
                .build()
                .unwrap();
            solve_from(settings, &[0.0; 4])
        };
        let ((a, sa), (b, sb)) = (with(0.0), with(10.0));
        assert_eq!((a.iterations, sa), (b.iterations, sb));
    }

    #[test]
    fn centrality_correctors_change_the_path_not_the_answer() {
        // Always tried (threshold 0), up to 3 an iteration, against none: both reach the
        // closed form, from cold and from warm multipliers; the correctors take fewer
        // factorizations on this chain, which is what they are for.
        for warm in [[0.0; 4], [1.0, 0.0, 2.0, 0.0]] {
            let with = |n| {
                let settings = InteriorPointSettings::builder()
                    .max_correctors(n)
                    .corrector_threshold(0.0)
                    .build()
                    .unwrap();
                solve_from(settings, &warm)
            };
            let ((plain, _), (corrected, sol)) = (with(0), with(3));
            assert!(corrected.status.is_converged(), "{corrected:?}");
            for (k, l) in sol.lambda.iter().enumerate() {
                assert!((l - (4 - k) as f64).abs() < 1e-6, "{sol:?}");
            }
            assert!(
                corrected.factorizations <= plain.factorizations,
                "{plain:?} {corrected:?}"
            );
        }
    }

    #[test]
    fn bad_settings_name_the_field() {
        let e = InteriorPointSettings::builder()
            .step_fraction(1.0)
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("step_fraction"), "{e}");
        for bad in [-1.0, f64::NAN, f64::INFINITY] {
            let e = InteriorPointSettings::builder()
                .warm_scale(bad)
                .build()
                .unwrap_err();
            assert!(e.to_string().contains("warm_scale"), "{e}");
        }
        let e = InteriorPointSettings::builder()
            .corrector_threshold(f64::NAN)
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("corrector_threshold"), "{e}");
        let e = InteriorPointSettings::builder()
            .polish_updates(0)
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("polish_updates"), "{e}");
        assert!(
            InteriorPointSettings::builder()
                .polish_penalty(0.0)
                .polish_updates(0)
                .build()
                .is_ok()
        );
        for (field, e) in [
            (
                "polish_penalty",
                InteriorPointSettings::builder()
                    .polish_penalty(-1.0)
                    .build(),
            ),
            (
                "polish_changes",
                InteriorPointSettings::builder().polish_changes(1.5).build(),
            ),
        ] {
            let e = e.unwrap_err();
            assert!(e.to_string().contains(field), "{e}");
        }
    }
}
