//! The automatic choice of solver: each connected component of a projection (rows far from
//! binding set aside, and taken back in rounds where the answer needs them) goes to
//! Gauss–Seidel, which gives it up when its own progress shows the budget will not finish
//! it, and then to the interior point; a round that takes back only a few rows goes first to
//! the semismooth Newton method, warm from the answer it corrects.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use moreau_core::{ConstraintKey, Helper, Num, Parallelism, SolveStatus};

use crate::certificate::certify;
use crate::components::{CheckScratch, Components, DisjointSolution, SubProblem};
use crate::error::SolveError;
use crate::gauss_seidel::{GaussSeidel, GaussSeidelSettings};
use crate::interior::{InteriorPoint, InteriorPointSettings};
use crate::newton::{Newton, NewtonSettings};
use crate::problem::{
    ProjectionProblem, ProjectionSolution, ProjectionSolver, SolveReport, Target,
};
use crate::products::Transpose;

/// Gauss–Seidel takes components of this many rows or more one at a time, and the smaller
/// ones in groups of about this many rows.
const GROUP_ROWS: usize = 256;

/// With threads, Gauss–Seidel's groups are swept on all of them at once when they hold this
/// many rows or more together; fewer stay on the caller, where starting the threads (tens of
/// µs) would cost about what they save (a sweep costs ~50 ns a row, passes and certificates
/// together). Measured on two threads (benches/README.md, session 17): whole evacuations of
/// 10,000 1.15–1.27× faster (median) at 4,096, 1.05–1.10× at 8,192, the same at 16,384.
const PARALLEL_GROUP_ROWS: usize = 4_096;

/// A row's reach for setting it aside (see [`AutoSettings::set_aside_factor`]): this many
/// times the change of its slack the caller's multipliers predict...
const PREDICTED_MARGIN: f64 = 1.0;
/// ... and at least this share of the previous answer's largest change of any slack.
const LARGEST_CHANGE_SHARE: f64 = 0.25;

/// The wait before Gauss–Seidel tries a component it gave up again doubles each time in a row
/// that it gives it up, at most this many times (see [`AutoSettings::retry_after`]).
const MAX_RETRY_DOUBLINGS: u32 = 4;

/// The solves a component Gauss–Seidel gave up `streak` times in a row before (0: the first
/// time) waits before it is tried again.
fn retry_wait(retry_after: u32, streak: u32) -> u32 {
    retry_after.saturating_mul(1 << streak.min(MAX_RETRY_DOUBLINGS))
}

/// A row of a large component Gauss–Seidel gave up (or skipped since), remembered by its key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct GivenUp {
    key: ConstraintKey,
    /// The solves left before Gauss–Seidel tries its component again.
    left: u32,
    /// How many times in a row Gauss–Seidel gave its component up.
    streak: u32,
}

/// With each row set aside by its own reach ([`Reach::Own`]), the rows needed join the
/// others with every row this many hops around them (rows sharing an unknown), twice as
/// many each round, for at most [`OWN_REACH_ROUNDS`] rounds; then every row. A crush's
/// pressure travels outward from person to person, a ring a round without the hops
/// (benches/README.md, session 21: the crush of 10⁵'s third step needed 4 rounds and 129
/// factorizations with 2 hops, 2 rounds and 78 with 8).
const OWN_REACH_HOPS: usize = 8;
/// See [`OWN_REACH_HOPS`].
const OWN_REACH_ROUNDS: usize = 6;

/// A round that takes back at most this many rows set aside (by the shared reach: no rows
/// around them) gives the largest component to the semismooth Newton method first
/// ([`AutoSettings::round_newton_factorizations`]). Whole evacuations' rounds take back one
/// to a few rows (benches/README.md, session 32); a crush's take back rings of hundreds.
const ROUND_NEWTON_MAX_ROWS: usize = 16;

/// The Newton method's penalty in such a round, relative to each row's squared norm
/// ([`NewtonSettings::rho`]): from an answer this close to the round's, a penalty this high
/// finishes most rounds in one or two factorizations. Measured on the 27 rounds of the whole
/// evacuation of 10,000 (benches/README.md, session 32): 10³ (the method's default) took
/// 110 factorizations and 327 ms, 10⁵ 48 and 165 ms, 10⁶ 39 and 136 ms, 10⁷ 47 and 139 ms,
/// 10⁸ 59 and 149 ms; the interior point 314–326 ms on the same rounds.
const ROUND_NEWTON_RHO: f64 = 1e6;

/// How [`AutoSolver`] set rows aside in its last solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Reach {
    /// No row was set aside (the first solve, where the shared floor keeps every row; or
    /// screening off).
    #[default]
    None,
    /// Rows beyond the shared floor (the worst violation at `w`, a quarter of the previous
    /// answer's largest change) and their own predicted change were set aside; rows needed
    /// after all joined once, then every row.
    Shared,
    /// Rows beyond their own predicted change alone were set aside, because the shared
    /// floor kept [`AutoSettings::own_reach_ratio`] times as many; rows needed after all
    /// joined with the rows around them, in rounds.
    Own,
}

/// What [`AutoSolver`]'s last solve kept and set aside.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ScreenReport {
    /// How rows were set aside.
    pub reach: Reach,
    /// The solves again after the first, with rows that had been set aside (0: the first
    /// answer certified).
    pub rounds: usize,
    /// The rows the last solve kept (every row when none was set aside).
    pub rows_kept: usize,
}

/// Settings of [`AutoSolver`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AutoSettings {
    /// Gauss–Seidel's budget of passes over a component (or a group of small ones) before
    /// the interior point takes it. Gauss–Seidel gives a component up before that when its
    /// certificates predict the budget will not be enough
    /// ([`GaussSeidelSettings::abandon_when_slow`]): a jam's component after 25–40 passes.
    /// An interior-point iteration costs 15–20 passes over the same rows on jammed halls
    /// and a solve 9–22 iterations (benches/README.md), so 100 passes stay near half an
    /// interior-point solve.
    pub first_order_passes: usize,
    /// A component of 256 rows or more (`GROUP_ROWS`) that Gauss–Seidel gave up goes straight to
    /// the interior point for this many solves after (recognised by its rows' keys: most of
    /// a sample of its rows were in it); then Gauss–Seidel tries it again (a jam may have
    /// cleared). Each time in a row that it gives the same component up again, the wait
    /// doubles, up to 16 times this (`MAX_RETRY_DOUBLINGS`): a crush that stays pressed is
    /// not swept in vain every 16 solves (measured: benches/README.md, session 27). 0:
    /// Gauss–Seidel tries every component every time.
    pub retry_after: usize,
    /// Rows whose slack at `w` (before any correction) exceeds this factor times their
    /// reach are set aside: they split no component and are only checked, by the
    /// certificate of the whole answer. When some of them turn out to be needed, they join
    /// the others and the projection is solved again from that answer; if a row set aside is
    /// needed still, with every row. `f64::INFINITY`: never. A row's reach is the largest of
    /// the worst violation at `w`, the change of its slack that the caller's multipliers
    /// predict (`Σ_c |J_ic| |(Jᵀλ)_c|`, the correction they make at its unknowns) and a
    /// quarter of the previous answer's largest change of any slack. Measured
    /// (benches/README.md, session 14): with one reach for every row (the largest change) at
    /// 1.5 × the jammed 10,000 took 23.7 ms a step, at 1 × 18.1 (0.7 × solved again too
    /// often, 1.2 × lay between); each row's own reach (1.5 × the prediction) then took the
    /// jammed 2,000 from 8.75 to 7.45 ms, the jammed 10,000 from 18.3 to 16.5, whole
    /// evacuations of 2,000 and 10,000 from 7.7 and 22.0 ms a step (mean) to 7.0 and 18.6;
    /// solving again with only the rows needed (instead of every row) made 1 × the
    /// prediction pay: cromosim's scene 2.37 → 2.24 ms, the jammed 2,000 7.5 → 6.6, whole
    /// evacuations (mean) 6.9 → 6.4 and 18.3 → 16.9.
    pub set_aside_factor: f64,
    /// Rows are set aside by their own predicted change alone ([`Reach::Own`]) when the
    /// shared floor (the worst violation at `w`, a quarter of the previous answer's largest
    /// change) would keep more than this many times as many rows: in a crush the floor,
    /// set by its centre, keeps every row of a crowd whose pressure is local. The rows
    /// needed after all then join in rounds with the rows around them. `f64::INFINITY`:
    /// never. Measured (benches/README.md, session 21): the crush of 10⁵'s first three
    /// steps 6.27, 9.14 and 9.37 s → 0.14, 1.39 and 3.78 s; in halls the floor keeps
    /// 1.0–1.8 times as many rows (cromosim's scene, median 1.06), so they keep the shared
    /// floor after their first, cold, solve.
    pub own_reach_ratio: f64,
    /// When a round takes back only a few rows set aside (at most 16, by the shared reach),
    /// the largest component is given first to the semismooth Newton method ([`Newton`],
    /// with its factor updates), warm from the answer the round corrects, with this many
    /// factorizations; when it does not meet the component's share of the target with them,
    /// the interior point solves the component as before. 0: the interior point always.
    /// From the corrected answer the active set is nearly known and a few Newton matrices
    /// finish it, where the interior point starts again from its kept iterate (9–10
    /// iterations for one row more). Measured (benches/README.md, session 32): the whole
    /// evacuation of 10,000's 27 rounds took 39 factorizations and 136 ms instead of the
    /// interior point's 320 and 320 ms, and whole evacuations of six sizes 6–8 % less time
    /// a step on average. Its penalty is fixed (10⁶ times each row's inverse squared norm,
    /// the value those rounds were measured at) and its other settings are
    /// [`NewtonSettings`]' defaults: a scene's `[solver.newton]` table configures the solver
    /// of `kind = "newton"`, not these rounds.
    pub round_newton_factorizations: usize,
    /// Threads: Gauss–Seidel's groups of components are swept on all of them at once (each
    /// group by one thread, whichever takes it; from 4,096 rows in groups), and the interior
    /// point's part runs as two solves at once (the largest component here, the others on the
    /// shared helper thread), the largest one's factorizations split with the helper when it
    /// is free; a large component Gauss–Seidel skips is solved while it sweeps the others.
    #[serde(skip)]
    pub parallelism: Parallelism,
}

impl AutoSettings {
    /// Checks every field; the error names the first one out of its domain.
    pub fn validate(&self) -> Result<(), SolveError> {
        // (`retry_after` was not checked and was cut to 32 bits: 2³² became 0, Gauss–Seidel
        // tried again at every solve.)
        crate::error::check_budgets(&[
            ("first_order_passes", self.first_order_passes),
            (
                "round_newton_factorizations",
                self.round_newton_factorizations,
            ),
            ("retry_after", self.retry_after),
        ])?;
        if !(self.set_aside_factor >= 1.0) {
            return Err(SolveError::InvalidSetting {
                field: "set_aside_factor",
                value: Num(self.set_aside_factor).to_string(),
                reason: "must be at least 1 (or infinite: never)",
            });
        }
        if !(self.own_reach_ratio >= 1.0) {
            return Err(SolveError::InvalidSetting {
                field: "own_reach_ratio",
                value: Num(self.own_reach_ratio).to_string(),
                reason: "must be at least 1 (or infinite: never)",
            });
        }
        if self.first_order_passes == 0 {
            return Err(SolveError::InvalidSetting {
                field: "first_order_passes",
                value: "0".into(),
                reason: "must be at least 1",
            });
        }
        Ok(())
    }
}

impl Default for AutoSettings {
    fn default() -> Self {
        Self {
            first_order_passes: 100,
            retry_after: 16,
            set_aside_factor: 1.0,
            own_reach_ratio: 4.0,
            round_newton_factorizations: 8,
            parallelism: Parallelism::SEQUENTIAL,
        }
    }
}

/// Splits each projection into its connected components (groups of people in contact, with
/// their walls: independent problems whose gaps add up), and gives each to Gauss–Seidel
/// first, warm-started: a component on its own (the small ones in groups), so that it is
/// swept only until it is finished, and given up as soon as its certificates show that the
/// budget will not finish it ([`AutoSettings::first_order_passes`]). The interior point
/// takes the components Gauss–Seidel left. A large component given up is remembered by
/// its rows' keys and goes straight to the interior point for the next
/// [`AutoSettings::retry_after`] solves (a jam's component is given up after 25–40 passes,
/// which is 10 % of its interior-point solve, step after step). The choice depends only on
/// the work counted (passes and certificates), never on timings, so answers do not depend
/// on the machine or the thread count.
///
/// Before splitting, rows whose slack at `w` is beyond what the correction is expected to
/// move it ([`AutoSettings::set_aside_factor`]: predicted from the caller's multipliers, row
/// by row) are set aside: in a jam they are a quarter of the rows or more, and with them set
/// aside one jam of 14,000 rows falls apart into hundreds of components. They are checked by
/// the certificate of the whole answer (with zero multipliers they add nothing to its gap);
/// those the answer violates join the others and the projection is solved again from that
/// answer, with every row if one set aside is needed still.
///
/// With threads ([`AutoSettings::parallelism`] above one), Gauss–Seidel's groups are solved
/// on all of them at once (each group by one thread, with its own solver and sub-problem,
/// writing its components' answers: components share no row and no unknown), the largest
/// component and the others are solved at once, each by its own interior point (the others on
/// the helper thread, [`moreau_core::Helper`]), and the largest component's factorizations and
/// triangular solves in 2×2 blocks are split with the helper where its elimination tree has
/// two parts that pay and the helper is free ([`InteriorPointSettings::split_factorization`]).
/// When Gauss–Seidel sweeps fewer than 4,096 rows and skips a large component (given up
/// lately), that component goes to the interior point whatever Gauss–Seidel makes of the
/// others: it is solved while they are swept (on the helper), then the others Gauss–Seidel
/// leaves. Which component goes where does not depend on the threads, and the answers are
/// the same on any thread count, bit for bit.
///
/// Each component must meet its share of the target gap (its rows over all rows) and the
/// whole violation target; the answer is then certified as a whole by
/// [`certify`]. The report names the solver that answered:
/// `gauss-seidel`, `interior`, or `gs+interior` when both answered components, with
/// `newton` added where the Newton method answered a round's largest component
/// (`newton`, `gs+newton`, `interior+newton`, `gs+ip+newton`); its
/// iterations are Gauss–Seidel's work in passes over all the rows plus the interior
/// point's iterations.
#[derive(Debug)]
pub struct AutoSolver {
    settings: AutoSettings,
    // Gauss–Seidel on one thread each (the first one also solves a whole problem of one
    // component)
    gauss_seidel: GaussSeidelGroups,
    // the interior point of the largest component (and of the whole problem), and of the
    // other components together: two, so that they can run at once
    interiors: [InteriorPoint; 2],
    // the largest component's solver first in a round that took back a few rows (none when
    // `round_newton_factorizations` is 0)
    newton: Option<Newton>,
    // with threads, the helper thread the largest component's interior point shares
    helper: Option<Arc<Helper>>,
    components: Components,
    parts: [SubProblem; 2],
    // per component: not tried by Gauss–Seidel; finished (by it); left to the interior point
    skip_gs: Vec<bool>,
    finished: Vec<bool>,
    to_interior: Vec<bool>,
    // the rows (by key, sorted) of the large components Gauss–Seidel gave up or skipped,
    // with the solves left before it tries them again; and the next solve's
    given_up: Vec<GivenUp>,
    next_given_up: Vec<GivenUp>,
    // per component: how many times in a row Gauss–Seidel gave it up before, when it tries
    // it again (0: never, or not lately)
    streak: Vec<u32>,
    warm: Vec<f64>,
    // per row: J w (the slack at w is b + J w); set aside
    jw: Vec<f64>,
    set_aside: Vec<bool>,
    // the previous answer's largest |J_i (v − w)| (infinite before the first)
    last_change: f64,
    // the rows of each unknown, built in a solve the first time rows join with the rows
    // around them; the unknowns reached and the rows joined in the last hop and the next,
    // while they join
    jt: Transpose,
    indexed: bool,
    reached: Vec<bool>,
    front: Vec<u32>,
    next_front: Vec<u32>,
    screen: ScreenReport,
    scratch_m: Vec<f64>,
    scratch_n: Vec<f64>,
}

/// Gauss–Seidel on the components not skipped, by groups (a large component alone, small ones
/// together), on one sweeper a thread.
#[derive(Debug)]
struct GaussSeidelGroups {
    // Gauss–Seidel on one thread each (the first one also solves a whole problem of one
    // component)
    sweepers: Vec<GroupSweeper>,
    // group g is group[group_start[g]..group_start[g + 1]]
    group: Vec<u32>,
    group_start: Vec<usize>,
    // the groups of one large component each that Gauss–Seidel gave up in the last sweep
    given_up_groups: Vec<usize>,
    retry_after: u32,
}

/// What a sweep of [`GaussSeidelGroups`] solves: the components of `problem` not skipped,
/// from the caller's multipliers `warm`.
#[derive(Clone, Copy)]
struct Sweep<'a> {
    problem: &'a ProjectionProblem<'a>,
    target: Target,
    components: &'a Components,
    warm: &'a [f64],
    skip: &'a [bool],
    streak: &'a [u32],
}

/// The groups of components of one sweep, shared by the threads that solve them: each takes
/// the next group not yet taken.
struct Groups<'a> {
    on: Sweep<'a>,
    // group g is group[group_start[g]..group_start[g + 1]]
    group: &'a [u32],
    group_start: &'a [usize],
    next: &'a AtomicUsize,
    solution: DisjointSolution<'a>,
}

/// One thread's Gauss–Seidel over groups of components: its own solver, sub-problem and
/// checks' scratch, and what its last sweep found.
#[derive(Debug)]
struct GroupSweeper {
    gauss_seidel: GaussSeidel,
    part: SubProblem,
    check: CheckScratch,
    // per component: met its share (set for the components of this thread's groups)
    met: Vec<bool>,
    // the components it finished, the groups of one large component it gave up, the work in
    // row passes, and the error of its first group that failed (with the group)
    finished: Vec<u32>,
    given_up: Vec<usize>,
    row_passes: usize,
    error: Option<(usize, SolveError)>,
}

impl GroupSweeper {
    fn new(settings: GaussSeidelSettings) -> Result<Self, SolveError> {
        Ok(Self {
            gauss_seidel: GaussSeidel::new(settings)?,
            part: SubProblem::default(),
            check: CheckScratch::default(),
            met: Vec::new(),
            finished: Vec::new(),
            given_up: Vec::new(),
            row_passes: 0,
            error: None,
        })
    }

    /// Solves groups of `work` until none is left; each finished component's answer is
    /// written into the shared solution.
    fn sweep(&mut self, work: &Groups<'_>, components: usize) {
        self.met.clear();
        self.met.resize(components, false);
        self.finished.clear();
        self.given_up.clear();
        self.row_passes = 0;
        self.error = None;
        let groups = work.group_start.len() - 1;
        let total_rows = work.on.problem.rows();
        loop {
            let g = work.next.fetch_add(1, Ordering::Relaxed);
            if g >= groups {
                break;
            }
            let group = &work.group[work.group_start[g]..work.group_start[g + 1]];
            let part = &mut self.part;
            let rows =
                part.gather_components(work.on.components, work.on.problem, work.on.warm, group);
            let rep = match AutoSolver::solve_gathered(
                part,
                &mut self.gauss_seidel,
                total_rows,
                rows,
                work.on.target,
            ) {
                Ok(rep) => rep,
                Err(e) => {
                    if self.error.is_none() {
                        self.error = Some((g, e));
                    }
                    continue;
                }
            };
            self.row_passes += rep.iterations * rows;
            if rep.status.is_converged() {
                for &c in group {
                    self.met[c as usize] = true;
                }
            } else {
                work.on
                    .components
                    .check_sub(part, work.on.target, &mut self.check, &mut self.met);
                if let [c] = *group
                    && !self.met[c as usize]
                    && rows >= GROUP_ROWS
                {
                    self.given_up.push(g);
                }
            }
            self.finished
                .extend(group.iter().filter(|&&c| self.met[c as usize]));
            part.scatter_into(work.on.components, &work.solution, &self.met);
        }
    }
}

impl AutoSolver {
    /// Both solvers, with validated settings (and the default settings of each).
    pub fn new(settings: AutoSettings) -> Result<Self, SolveError> {
        Self::with_solvers(
            settings,
            InteriorPointSettings::default(),
            GaussSeidelSettings::default(),
        )
    }

    /// Both solvers, with validated settings: the interior point's from `interior` but for
    /// its threads and its split factorization (chosen here, below), Gauss–Seidel's from
    /// `gauss_seidel` but for its threads, its budget (`first_order_passes`) and giving
    /// up when slow (always, here).
    pub fn with_solvers(
        settings: AutoSettings,
        interior: InteriorPointSettings,
        gauss_seidel: GaussSeidelSettings,
    ) -> Result<Self, SolveError> {
        settings.validate()?;
        // Gauss–Seidel's certificate loops on a thread pool lost on cromosim's scene (9.2
        // against 11.7 ms a step on two threads): its parts are small; it runs on one thread.
        let gauss_seidel = GaussSeidelSettings {
            max_passes: settings.first_order_passes,
            abandon_when_slow: true,
            parallelism: Parallelism::SEQUENTIAL,
            ..gauss_seidel
        };
        gauss_seidel.validate()?;
        let sweepers = (0..settings.parallelism.get())
            .map(|_| GroupSweeper::new(gauss_seidel))
            .collect::<Result<_, _>>()?;
        let gauss_seidel = GaussSeidelGroups {
            sweepers,
            group: Vec::new(),
            group_start: Vec::new(),
            given_up_groups: Vec::new(),
            retry_after: settings.retry_after as u32,
        };
        // Each interior point's loops run on one thread: with threads, the largest component
        // and the others run at once (two interior points each spreading its loops over the
        // same cores would only contend), and the largest one's factorizations split in two
        // (measured: benches/README.md, session 16).
        let interior = |split: bool| {
            InteriorPoint::new(InteriorPointSettings {
                parallelism: Parallelism::SEQUENTIAL,
                split_factorization: split,
                ..interior
            })
        };
        let threads = !settings.parallelism.is_sequential();
        // One thread, as the interior points': it runs where the largest component's would.
        // Stateless from solve to solve (its penalties and factor are its solve's), so a
        // restored solver needs nothing of it.
        let newton = (settings.round_newton_factorizations > 0)
            .then(|| {
                Newton::new(NewtonSettings {
                    max_iterations: settings.round_newton_factorizations,
                    rho: ROUND_NEWTON_RHO,
                    ..NewtonSettings::default()
                })
            })
            .transpose()?;
        Ok(Self {
            settings,
            gauss_seidel,
            interiors: [interior(threads)?, interior(false)?],
            newton,
            helper: threads.then(Helper::shared).flatten(),
            components: Components::default(),
            parts: [SubProblem::default(), SubProblem::default()],
            finished: Vec::new(),
            to_interior: Vec::new(),
            skip_gs: Vec::new(),
            given_up: Vec::new(),
            next_given_up: Vec::new(),
            streak: Vec::new(),
            warm: Vec::new(),
            jw: Vec::new(),
            set_aside: Vec::new(),
            last_change: f64::INFINITY,
            jt: Transpose::default(),
            indexed: false,
            reached: Vec::new(),
            front: Vec::new(),
            next_front: Vec::new(),
            screen: ScreenReport::default(),
            scratch_m: Vec::new(),
            scratch_n: Vec::new(),
        })
    }

    /// What the last solve kept and set aside.
    pub fn screen(&self) -> ScreenReport {
        self.screen
    }

    /// Solves the sub-problem gathered in `part` (`rows` of the whole problem's
    /// `total_rows`) with `solver` to its share of `target`.
    fn solve_gathered(
        part: &mut SubProblem,
        solver: &mut dyn ProjectionSolver,
        total_rows: usize,
        rows: usize,
        target: Target,
    ) -> Result<SolveReport, SolveError> {
        let share = Target {
            gap: target.gap * rows as f64 / total_rows.max(1) as f64,
            violation: target.violation,
        };
        let (sub, sol) = part.problem();
        solver.solve(&sub, share, sol)
    }
}

impl ProjectionSolver for AutoSolver {
    fn name(&self) -> &'static str {
        "auto"
    }

    fn solve(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
    ) -> Result<SolveReport, SolveError> {
        p.validate()?;
        target.validate()?;
        let m = p.rows();
        let nnz = p.jacobian.nnz();
        if m >= u32::MAX as usize || p.dim() >= u32::MAX as usize || nnz >= u32::MAX as usize {
            return Err(SolveError::InvalidSetting {
                field: "problem size",
                value: format!("{m} rows, {} unknowns, {nnz} nonzeros", p.dim()),
                reason: "auto numbers rows, unknowns, nonzeros and components with 32 bits",
            });
        }
        sol.resize_for(p);
        self.warm.clear();
        self.warm.extend_from_slice(&sol.lambda);
        // s(w) = b + Jw; rows far from binding are set aside (below).
        self.jw.resize(m, 0.0);
        p.jacobian.mul(p.w, &mut self.jw);
        let worst_at_w = (self.jw.iter().zip(p.b)).fold(0.0f64, |a, (jw, b)| a.max(-(jw + b)));
        let reach = if self.settings.set_aside_factor.is_finite() {
            self.set_aside_rows(p, worst_at_w)
        } else {
            Reach::None
        };
        let screened = reach != Reach::None;
        self.indexed = false;
        let mut report = self.solve_split(p, target, sol, screened, false)?;
        // Rows set aside were needed after all: those the answer violates join the others
        // (by their own reach, with the rows around them), and the projection is solved again
        // from that answer (the components they do not touch certify at once); when rows set
        // aside are needed still after the last round, with every row.
        let joins = if reach == Reach::Own {
            OWN_REACH_ROUNDS
        } else {
            1
        };
        let mut rounds = 0;
        while screened && !report.status.is_converged() && self.needed_a_row_set_aside(p, target) {
            let earlier = report;
            rounds += 1;
            let last = rounds > joins;
            let mut newton_round = false;
            if !last {
                let hops = if reach == Reach::Own {
                    OWN_REACH_HOPS << (rounds - 1)
                } else {
                    0
                };
                let joined = self.join_needed(p, target, hops);
                newton_round = hops == 0 && joined <= ROUND_NEWTON_MAX_ROWS;
                self.warm.clear();
                self.warm.extend_from_slice(&sol.lambda);
            }
            report = self.solve_split(p, target, sol, !last, newton_round)?;
            report.add_work(&earlier);
            if last {
                break;
            }
        }
        self.screen = ScreenReport {
            reach,
            rounds,
            rows_kept: self.set_aside.iter().filter(|&&a| !a).count(),
        };
        self.next_given_up.sort_unstable_by_key(|g| g.key);
        std::mem::swap(&mut self.given_up, &mut self.next_given_up);
        // How far the correction moved any row's slack, s(v) − s(w) (`scratch_m` holds J v):
        // the next solve's reach.
        self.last_change = (0..m).fold(0.0f64, |a, i| {
            a.max((p.b[i] + self.scratch_m[i] - (self.jw[i] + p.b[i])).abs())
        });
        Ok(report)
    }

    /// `[−3, last_change, P, P groups of rows given up, L₀, the first interior point's memory
    /// (L₀ numbers), L₁, the second's]`, finite numbers (JSON has no infinity): −3 marks this
    /// layout, `last_change` is −1 before the first solve; a group is `[solves_left, streak,
    /// n, (key_high, key_low) of each of its n rows]`, the rows given up grouped by their wait
    /// (one group a component, mostly: a settled crush's 3·10⁵ rows in two numbers each),
    /// each key in two 32-bit halves (exact in an f64), the groups by wait and the keys in
    /// order.
    fn memory(&self) -> Vec<f64> {
        let interiors = self.interiors.each_ref().map(|i| i.memory());
        let mut by_wait = self.given_up.clone();
        by_wait.sort_unstable_by_key(|g| (g.left, g.streak, g.key));
        let groups = by_wait.chunk_by(|a, b| (a.left, a.streak) == (b.left, b.streak));
        let mut memory = Vec::with_capacity(
            3 + 3 * groups.clone().count()
                + 2 * by_wait.len()
                + interiors.iter().map(|m| 1 + m.len()).sum::<usize>(),
        );
        memory.push(MEMORY_LAYOUT);
        memory.push(if self.last_change.is_finite() {
            self.last_change
        } else {
            -1.0
        });
        memory.push(groups.clone().count() as f64);
        for group in groups {
            let (left, streak) = (group[0].left, group[0].streak);
            memory.extend([left as f64, streak as f64, group.len() as f64]);
            for g in group {
                memory.extend([(g.key >> 32) as f64, (g.key as u32) as f64]);
            }
        }
        for m in &interiors {
            memory.push(m.len() as f64);
            memory.extend_from_slice(m);
        }
        memory
    }

    /// Takes what [`memory`](Self::memory) gave. The layouts of earlier builds are read too:
    /// `[−2, last_change, G, (key_high, key_low, solves_left)…, L₀, …]` from before the wait
    /// doubled (each row given up once), and with the interior points as new `[last_change,
    /// (key_high, key_low, solves_left)…]` and `[skip_from, skip_left, last_change]` (from
    /// before components were recognised by their rows); anything else (a damaged count
    /// among them) leaves the solver as new.
    fn set_memory(&mut self, memory: &[f64]) {
        self.given_up.clear();
        for interior in &mut self.interiors {
            interior.set_memory(&[]);
        }
        let key = |high: f64, low: f64| ((high as u64) << 32) | low as u64;
        let (last_change, interiors) = match memory {
            [layout, last_change, groups, rest @ ..] if *layout == MEMORY_LAYOUT => {
                match given_up_groups(*groups, rest, &mut self.given_up) {
                    Some(interiors) => (*last_change, interiors),
                    None => {
                        self.given_up.clear();
                        (-1.0, &[][..])
                    }
                }
            }
            [layout, last_change, given_up, rest @ ..] if *layout == MEMORY_LAYOUT_ONCE => {
                // (`as` saturates; a damaged count finds no rows and restores nothing.)
                let rows = (*given_up as usize).saturating_mul(3);
                match (rest.get(..rows), rest.get(rows..)) {
                    (Some(rows), Some(interiors)) => {
                        self.given_up.extend(rows.chunks_exact(3).map(|r| GivenUp {
                            key: key(r[0], r[1]),
                            left: r[2] as u32,
                            streak: 1,
                        }));
                        (*last_change, interiors)
                    }
                    _ => (-1.0, &[][..]),
                }
            }
            [_, _, last_change] => (*last_change, &[][..]),
            [last_change, rows @ ..] if rows.len() % 3 == 0 => {
                self.given_up.extend(rows.chunks_exact(3).map(|r| GivenUp {
                    key: key(r[0], r[1]),
                    left: r[2] as u32,
                    streak: 1,
                }));
                (*last_change, &[][..])
            }
            _ => (-1.0, &[][..]),
        };
        self.last_change = if last_change >= 0.0 {
            last_change
        } else {
            f64::INFINITY
        };
        self.given_up.sort_unstable_by_key(|g| g.key);
        let mut rest = interiors;
        for interior in &mut self.interiors {
            let Some((&len, after)) = rest.split_first() else {
                break;
            };
            let Some(own) = after.get(..len as usize) else {
                break;
            };
            interior.set_memory(own);
            rest = &after[len as usize..];
        }
    }
}

/// Reads `groups` groups of rows given up (see [`AutoSolver::memory`]) from the front of
/// `memory` into `into`; the rest, or `None` if a count is damaged or the memory ends first.
fn given_up_groups<'a>(
    groups: f64,
    mut memory: &'a [f64],
    into: &mut Vec<GivenUp>,
) -> Option<&'a [f64]> {
    let count = |x: f64| (x >= 0.0 && x.fract() == 0.0 && x <= u32::MAX as f64).then_some(x);
    for _ in 0..count(groups)? as usize {
        let [left, streak, n, rest @ ..] = memory else {
            return None;
        };
        let (left, streak, n) = (count(*left)?, count(*streak)?, count(*n)? as usize);
        let keys = rest.get(..n.checked_mul(2)?)?;
        into.extend(keys.chunks_exact(2).map(|k| GivenUp {
            key: ((k[0] as u64) << 32) | k[1] as u64,
            left: left as u32,
            streak: streak as u32,
        }));
        memory = &rest[2 * n..];
    }
    Some(memory)
}

/// The first number of [`AutoSolver`]'s memory in its current layout (earlier layouts began
/// with `last_change`, at least −1, or with [`MEMORY_LAYOUT_ONCE`]).
const MEMORY_LAYOUT: f64 = -3.0;

/// The first number of [`AutoSolver`]'s memory in the layout from before the wait before a
/// retry doubled (three numbers a row given up, no streak).
const MEMORY_LAYOUT_ONCE: f64 = -2.0;

impl GaussSeidelGroups {
    /// Gauss–Seidel on every component not skipped, by groups: each component of
    /// [`GROUP_ROWS`] rows or more alone, the smaller ones together in groups of about that
    /// many rows (so that a component stops being swept when it is finished, and one that
    /// Gauss–Seidel will not finish is given up by its own progress). Marks the components
    /// finished, writes their answers into `sol`, remembers the large ones given up in
    /// `next_given_up`, and returns the work done in passes over all of `p`'s rows (rounded
    /// up).
    fn solve(
        &mut self,
        on: &Sweep<'_>,
        finished: &mut [bool],
        next_given_up: &mut Vec<GivenUp>,
        sol: &mut ProjectionSolution,
    ) -> Result<usize, SolveError> {
        let Sweep {
            problem: p,
            components,
            skip,
            streak,
            ..
        } = *on;
        let m = p.rows();
        let count = finished.len();
        let size = |c: usize| components.rows_of(c).len();
        self.group.clear();
        self.group_start.clear();
        self.group_start.push(0);
        for c in (0..count).filter(|&c| !skip[c] && size(c) >= GROUP_ROWS) {
            self.group.push(c as u32);
            self.group_start.push(self.group.len());
        }
        let mut rows = 0;
        for c in (0..count).filter(|&c| !skip[c] && size(c) < GROUP_ROWS) {
            self.group.push(c as u32);
            rows += size(c);
            if rows >= GROUP_ROWS {
                self.group_start.push(self.group.len());
                rows = 0;
            }
        }
        if rows > 0 {
            self.group_start.push(self.group.len());
        }
        let groups = self.group_start.len() - 1;
        let grouped_rows: usize = self.group.iter().map(|&c| size(c as usize)).sum();
        let threads = if grouped_rows >= PARALLEL_GROUP_ROWS {
            self.sweepers.len().min(groups).max(1)
        } else {
            1
        };
        let sweepers = &mut self.sweepers[..threads];
        let next = AtomicUsize::new(0);
        let work = Groups {
            on: *on,
            group: &self.group,
            group_start: &self.group_start,
            next: &next,
            solution: DisjointSolution::new(sol),
        };
        // Each group is solved the same way whichever thread takes it (its own sub-problem,
        // from the same warm start): the answers do not depend on the threads.
        match sweepers {
            [one] => one.sweep(&work, count),
            [first, others @ ..] => std::thread::scope(|scope| {
                for s in others {
                    let work = &work;
                    scope.spawn(move || s.sweep(work, count));
                }
                first.sweep(&work, count);
            }),
            [] => unreachable!("at least one sweeper"),
        }
        let mut row_passes = 0;
        let mut error: Option<(usize, SolveError)> = None;
        self.given_up_groups.clear();
        for s in sweepers.iter_mut() {
            row_passes += s.row_passes;
            for &c in &s.finished {
                finished[c as usize] = true;
            }
            self.given_up_groups.extend_from_slice(&s.given_up);
            if let Some((g, e)) = s.error.take()
                && error.as_ref().is_none_or(|(first, _)| g < *first)
            {
                error = Some((g, e));
            }
        }
        if let Some((_, e)) = error {
            return Err(e);
        }
        // Remembered in the groups' order, as one thread would.
        self.given_up_groups.sort_unstable();
        for &g in &self.given_up_groups {
            let c = self.group[self.group_start[g]] as usize;
            let rows = components.rows_of(c);
            AutoSolver::give_up(next_given_up, p, rows, self.retry_after, streak[c]);
        }
        Ok(row_passes.div_ceil(m.max(1)))
    }
}

impl AutoSolver {
    /// Decides which components skip Gauss–Seidel: those of [`GROUP_ROWS`] rows or more
    /// whose rows were mostly (in a sample of up to 16) in a component given up, with
    /// solves left before the retry; their rows are remembered for the next solve with one
    /// solve fewer. Those whose wait is over keep their streak of give-ups for the retry.
    fn choose_skips(&mut self, p: &ProjectionProblem<'_>) {
        const SAMPLES: usize = 16;
        let count = self.finished.len();
        self.skip_gs.clear();
        self.skip_gs.resize(count, false);
        self.streak.clear();
        self.streak.resize(count, 0);
        if self.given_up.is_empty() {
            return;
        }
        let keys = p.jacobian.keys();
        for c in 0..count {
            let rows = self.components.rows_of(c);
            if rows.len() < GROUP_ROWS {
                continue;
            }
            let (mut found, mut left, mut streak) = (0, u32::MAX, 0);
            for k in 0..SAMPLES {
                let key = keys[rows[k * rows.len() / SAMPLES] as usize];
                if let Ok(at) = self.given_up.binary_search_by_key(&key, |g| g.key) {
                    found += 1;
                    left = left.min(self.given_up[at].left);
                    streak = streak.max(self.given_up[at].streak);
                }
            }
            if 2 * found > SAMPLES {
                if left > 0 {
                    self.skip_gs[c] = true;
                    Self::remember(&mut self.next_given_up, p, rows, left - 1, streak);
                } else {
                    self.streak[c] = streak;
                }
            }
        }
    }

    /// Adds `rows` (by key) with `left` solves before Gauss–Seidel tries them again, given up
    /// `streak` times in a row.
    fn remember(
        into: &mut Vec<GivenUp>,
        p: &ProjectionProblem<'_>,
        rows: &[u32],
        left: u32,
        streak: u32,
    ) {
        let keys = p.jacobian.keys();
        into.extend(rows.iter().map(|&i| GivenUp {
            key: keys[i as usize],
            left,
            streak,
        }));
    }

    /// Remembers the rows of a component Gauss–Seidel has just given up, after `streak` times
    /// in a row before: the wait before it tries again doubles with each (see
    /// [`AutoSettings::retry_after`]).
    fn give_up(
        into: &mut Vec<GivenUp>,
        p: &ProjectionProblem<'_>,
        rows: &[u32],
        retry_after: u32,
        streak: u32,
    ) {
        let wait = retry_wait(retry_after, streak);
        Self::remember(into, p, rows, wait, streak.saturating_add(1));
    }

    /// Whether the answer of the last [`solve_split`](Self::solve_split) violates row `i`, set
    /// aside (its `J v` is in `scratch_m`).
    fn needed_set_aside(&self, p: &ProjectionProblem<'_>, target: Target, i: usize) -> bool {
        self.set_aside[i] && p.b[i] + self.scratch_m[i] < -target.violation
    }

    /// Whether it violates any row set aside.
    fn needed_a_row_set_aside(&self, p: &ProjectionProblem<'_>, target: Target) -> bool {
        (0..p.rows()).any(|i| self.needed_set_aside(p, target, i))
    }

    /// Marks in `set_aside` the rows whose slack at `w` exceeds the factor times their reach
    /// (see [`AutoSettings::set_aside_factor`]), shared or their own (see
    /// [`AutoSettings::own_reach_ratio`]), and says which; the caller's multipliers (those
    /// that are positive and finite) go through `scratch_m`, their correction `Jᵀλ`
    /// through `scratch_n`, and each row's own reach is left in `scratch_m`.
    fn set_aside_rows(&mut self, p: &ProjectionProblem<'_>, worst_at_w: f64) -> Reach {
        let j = p.jacobian;
        self.scratch_m.clear();
        self.scratch_m.extend(
            self.warm
                .iter()
                .map(|&l| if l > 0.0 && l.is_finite() { l } else { 0.0 }),
        );
        self.scratch_n.clear();
        self.scratch_n.resize(p.dim(), 0.0);
        j.mul_transpose_add(&self.scratch_m, &mut self.scratch_n);
        // (Infinite before the first solve: every row is kept by the shared floor.)
        let floor = worst_at_w.max(LARGEST_CHANGE_SHARE * self.last_change);
        let factor = self.settings.set_aside_factor;
        let (correction, jw, own) = (&self.scratch_n, &self.jw, &mut self.scratch_m);
        let (mut kept_shared, mut kept_own) = (0usize, 0usize);
        self.set_aside.clear();
        self.set_aside.extend((0..p.rows()).map(|i| {
            let (c, a) = j.row(i);
            let predicted: f64 = c
                .iter()
                .zip(a)
                .map(|(&c, &a)| (a * correction[c]).abs())
                .sum();
            let slack = jw[i] + p.b[i];
            own[i] = factor * PREDICTED_MARGIN * predicted;
            let aside = slack > factor * floor.max(PREDICTED_MARGIN * predicted);
            kept_shared += usize::from(!aside);
            kept_own += usize::from(!(slack > own[i]));
            aside
        }));
        if kept_shared as f64 > self.settings.own_reach_ratio * kept_own as f64 {
            for ((aside, &own), (jw, b)) in self
                .set_aside
                .iter_mut()
                .zip(&self.scratch_m)
                .zip(self.jw.iter().zip(p.b))
            {
                *aside = jw + b > own;
            }
            Reach::Own
        } else if kept_shared < p.rows() {
            Reach::Shared
        } else {
            Reach::None
        }
    }

    /// Makes the rows set aside that the last answer violates join the others, and with
    /// them every row set aside within `hops` rows of them (rows sharing an unknown);
    /// returns how many the answer violates.
    fn join_needed(&mut self, p: &ProjectionProblem<'_>, target: Target, hops: usize) -> usize {
        let j = p.jacobian;
        self.front.clear();
        for i in 0..p.rows() {
            if self.needed_set_aside(p, target, i) {
                self.set_aside[i] = false;
                self.front.push(i as u32);
            }
        }
        let violated = self.front.len();
        if hops == 0 || violated == 0 {
            return violated;
        }
        if !self.indexed {
            self.jt.build_rows(j);
            self.indexed = true;
        }
        let Self {
            jt,
            reached,
            front,
            next_front: next,
            set_aside,
            ..
        } = self;
        reached.clear();
        reached.resize(p.dim(), false);
        for _ in 0..hops {
            next.clear();
            for &i in front.iter() {
                for &c in j.row(i as usize).0 {
                    if std::mem::replace(&mut reached[c], true) {
                        continue;
                    }
                    for &r in jt.rows_of(c) {
                        if std::mem::replace(&mut set_aside[r as usize], false) {
                            next.push(r);
                        }
                    }
                }
            }
            std::mem::swap(front, next);
            if front.is_empty() {
                break;
            }
        }
        violated
    }

    /// One solve, with the rows marked in `set_aside` set aside when `screened` (else none):
    /// the components of the rest, each answered by Gauss–Seidel or the interior point (the
    /// largest by the Newton method first in a `newton_round`: a round that took back a few
    /// rows), certified as a whole (rows set aside included, with zero multipliers). Leaves
    /// `J v` in `scratch_m`.
    fn solve_split(
        &mut self,
        p: &ProjectionProblem<'_>,
        target: Target,
        sol: &mut ProjectionSolution,
        screened: bool,
        newton_round: bool,
    ) -> Result<SolveReport, SolveError> {
        let m = p.rows();
        if !screened {
            self.set_aside.clear();
            self.set_aside.resize(m, false);
        }
        let any_aside = self.set_aside.iter().any(|&a| a);
        let count = self.components.split(p, &self.set_aside);
        self.finished.clear();
        self.finished.resize(count, false);
        self.next_given_up.clear();
        self.choose_skips(p);

        let mut report = SolveReport::default();
        let mut status = SolveStatus::Converged;
        let mut interior_answered = false;
        let mut newton_answered = false;
        if count == 1 && !any_aside {
            // The whole problem: no copy. Gauss–Seidel first unless it gave it up lately.
            if !self.skip_gs[0] {
                sol.lambda.copy_from_slice(&self.warm);
                let rep = self.gauss_seidel.sweepers[0]
                    .gauss_seidel
                    .solve(p, target, sol)?;
                report.add_work(&rep);
                self.finished[0] = rep.status.is_converged();
                if !self.finished[0] && m >= GROUP_ROWS {
                    Self::give_up(
                        &mut self.next_given_up,
                        p,
                        self.components.rows_of(0),
                        self.settings.retry_after as u32,
                        self.streak[0],
                    );
                }
            }
            if !self.finished[0] && newton_round {
                // A round that took back a few rows: the Newton method first, from the answer
                // the round corrects.
                if let Some(newton) = self.newton.as_mut() {
                    sol.lambda.copy_from_slice(&self.warm);
                    let rep = newton.solve(p, target, sol)?;
                    report.add_work(&rep);
                    newton_answered = rep.status.is_converged();
                }
            }
            if !self.finished[0] && !newton_answered {
                // Again, from the caller's warm start.
                sol.lambda.copy_from_slice(&self.warm);
                let rep = self.interiors[0].solve(p, target, sol)?;
                report.add_work(&rep);
                status = rep.status;
                interior_answered = true;
            }
        } else {
            sol.v.copy_from_slice(p.w);
            sol.lambda.iter_mut().for_each(|l| *l = 0.0);
            let Self {
                gauss_seidel,
                interiors: [first, second],
                newton,
                parts: [largest_part, rest_part],
                components,
                warm,
                skip_gs,
                streak,
                finished,
                to_interior,
                next_given_up,
                helper,
                ..
            } = self;
            let (components, warm, skip_gs, streak): (&Components, &[f64], &[bool], &[u32]) =
                (components, warm, skip_gs, streak);
            let by_size = |c: &usize| (components.rows_of(*c).len(), std::cmp::Reverse(*c));
            // The interior point takes the largest component on its own (it takes the
            // iterations it needs, not the most any component needs), the others together.
            // The largest that Gauss–Seidel skips goes to it whatever Gauss–Seidel makes of the
            // others: solved while they are swept (on the helper thread), then the others it
            // leaves; without one, the largest Gauss–Seidel leaves, solved with the others.
            // (Only where Gauss–Seidel sweeps on one thread: with more rows its groups take
            // every thread.)
            let swept_rows: usize = (0..count)
                .filter(|&c| !skip_gs[c])
                .map(|c| components.rows_of(c).len())
                .sum();
            let known = (swept_rows < PARALLEL_GROUP_ROWS)
                .then(|| (0..count).filter(|&c| skip_gs[c]).max_by_key(by_size))
                .flatten();
            let on = Sweep {
                problem: p,
                target,
                components,
                warm,
                skip: skip_gs,
                streak,
            };
            let (swept, largest) = match known {
                Some(c) => (None, Some(c)),
                None => {
                    let passes = gauss_seidel.solve(&on, finished, next_given_up, sol);
                    let largest = (0..count).filter(|&c| !finished[c]).max_by_key(by_size);
                    (Some(passes), largest)
                }
            };
            let largest = largest.map(|c| (c, largest_part.gather_one(components, p, warm, c)));
            let (largest_report, (passes, rest)) = both(
                helper.as_deref(),
                || {
                    largest.map(|(c, rows)| {
                        // In a round that took back a few rows, the Newton method first,
                        // from the answer the round corrects; its work counts either way.
                        let mut tried = SolveReport::default();
                        if let Some(newton) = newton.as_mut().filter(|_| newton_round) {
                            tried = Self::solve_gathered(largest_part, newton, m, rows, target)?;
                            if tried.status.is_converged() {
                                return Ok(tried);
                            }
                            largest_part.gather_one(components, p, warm, c);
                        }
                        let mut answer =
                            Self::solve_gathered(largest_part, first, m, rows, target)?;
                        answer.add_work(&tried);
                        Ok(answer)
                    })
                },
                || {
                    let passes = swept
                        .unwrap_or_else(|| gauss_seidel.solve(&on, finished, next_given_up, sol));
                    to_interior.clear();
                    to_interior.extend(
                        (0..count).map(|c| !finished[c] && largest.is_none_or(|(l, _)| l != c)),
                    );
                    let rest = to_interior.iter().any(|&t| t).then(|| {
                        let rows = rest_part.gather(components, p, warm, to_interior);
                        Self::solve_gathered(rest_part, second, m, rows, target)
                    });
                    (passes, rest)
                },
            );
            report.iterations += passes?;
            if let Some(a) = largest_report {
                let a = a?;
                report.add_work(&a);
                status = a.status;
                largest_part.scatter_all(sol);
                if a.solver == "newton" {
                    newton_answered = true;
                } else {
                    interior_answered = true;
                }
            }
            if let Some(b) = rest {
                let b = b?;
                report.add_work(&b);
                if status.is_converged() {
                    status = b.status;
                }
                rest_part.scatter_all(sol);
                interior_answered = true;
            }
        }
        let gs_answered = self.finished.iter().any(|&f| f);
        // Unknowns in no row have v = w; the whole answer is certified here.
        self.scratch_m.resize(m, 0.0);
        self.scratch_n.resize(p.dim(), 0.0);
        let cert = certify(
            p,
            &sol.v,
            &sol.lambda,
            &mut self.scratch_m,
            &mut self.scratch_n,
        );
        if status.is_converged() && !(cert.gap <= target.gap && cert.violation <= target.violation)
        {
            status = SolveStatus::MaxIterations;
        }
        report.solver = answered_by(gs_answered, interior_answered, newton_answered);
        report.status = status;
        report.gap = cert.gap;
        report.violation = cert.violation;
        // Active as the interior point counts it (a multiplier above its slack), whichever
        // solver answered the row: Gauss–Seidel's λ > 0 would count rows at a tiny
        // multiplier with their slack open.
        // (`scratch_m` holds J v.)
        report.active = (0..m)
            .filter(|&i| sol.lambda[i] > p.b[i] + self.scratch_m[i])
            .count();
        Ok(report)
    }
}

/// The report's name of the solvers that answered components: Gauss–Seidel, the interior
/// point, the Newton method (a round's largest component). At most 16 bytes, the run file's
/// field for it (`crates/io`'s step rows): the three together are `gs+ip+newton`.
fn answered_by(gauss_seidel: bool, interior: bool, newton: bool) -> &'static str {
    match (gauss_seidel, interior, newton) {
        (_, false, false) => "gauss-seidel",
        (false, true, false) => "interior",
        (true, true, false) => "gs+interior",
        (false, false, true) => "newton",
        (true, false, true) => "gs+newton",
        (false, true, true) => "interior+newton",
        (true, true, true) => "gs+ip+newton",
    }
}

/// `a` here and `b` on `helper` at once (without a helper, `b` after `a`); both results.
fn both<A, B: Send>(
    helper: Option<&Helper>,
    a: impl FnOnce() -> A,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    match helper {
        Some(helper) => helper.join_once(a, b),
        None => {
            let a = a();
            (a, b())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use moreau_core::ConstraintRows;

    /// `triples` small components (three unknowns pushed together, two rows each) and
    /// `chains` long chains of `chain_len` unknowns pushed together, which Gauss–Seidel does
    /// not finish in its budget: `(J, w, b)`.
    fn triples_and_chains(
        triples: usize,
        chains: usize,
        chain_len: usize,
    ) -> (ConstraintRows, Vec<f64>, Vec<f64>) {
        let n = 3 * triples + chains * chain_len;
        let mut rows = ConstraintRows::new(n);
        let (mut w, mut b) = (vec![0.0; n], Vec::new());
        let mut state = 12345u64;
        let mut random = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64)
        };
        let mut key = 0u64;
        let mut row = |rows: &mut ConstraintRows, b: &mut Vec<f64>, a: usize, gap: f64| {
            // x_{a+1} − x_a ≥ gap
            rows.push(key, 0.0, [(a, -1.0), (a + 1, 1.0)]);
            b.push(-gap);
            key += 1;
        };
        for t in 0..triples {
            let a = 3 * t;
            let push = 0.5 + random();
            (w[a], w[a + 2]) = (push, -push);
            row(&mut rows, &mut b, a, 0.1 * random());
            row(&mut rows, &mut b, a + 1, 0.1 * random());
        }
        for c in 0..chains {
            let start = 3 * triples + c * chain_len;
            for k in 0..chain_len {
                w[start + k] = -(k as f64) / chain_len as f64 + 0.1 * random();
                if k + 1 < chain_len {
                    row(&mut rows, &mut b, start + k, 0.05);
                }
            }
        }
        (rows, w, b)
    }

    /// Many small components (three unknowns pushed together, two rows each) and three long
    /// chains pushed together that Gauss–Seidel does not finish in its budget: more rows in
    /// Gauss–Seidel's groups than it sweeps on one thread, so with threads the groups are
    /// swept on all of them. Three solves in a row (the chains given up, then skipped, as
    /// remembered), on one, two and three threads: the same bits, reports and memory.
    #[test]
    fn gauss_seidels_groups_swept_on_threads_give_the_same_bits() {
        let (triples, chains, chain_len) = (9_000, 3, 400);
        let (rows, w, b) = triples_and_chains(triples, chains, chain_len);
        assert!(
            2 * triples >= PARALLEL_GROUP_ROWS,
            "the groups are swept on threads"
        );
        let p = ProjectionProblem {
            w: &w,
            jacobian: &rows,
            b: &b,
        };
        let t = Target {
            gap: 1e-6,
            violation: 1e-9,
        };
        let timeless = |r: SolveReport| SolveReport {
            time_analyse: 0.0,
            time_factorize: 0.0,
            ..r
        };
        let run = |threads: usize| {
            let mut auto = AutoSolver::new(AutoSettings {
                retry_after: 1,
                parallelism: Parallelism::threads(threads),
                ..AutoSettings::default()
            })
            .unwrap();
            let mut sol = ProjectionSolution::default();
            let mut out = Vec::new();
            for _ in 0..3 {
                let rep = auto.solve(&p, t, &mut sol).unwrap();
                assert!(
                    rep.status.is_converged() && rep.gap <= t.gap && rep.violation <= t.violation,
                    "{threads} threads: {rep:?}"
                );
                let bits = |x: &[f64]| x.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                out.push((
                    timeless(rep),
                    bits(&sol.v),
                    bits(&sol.lambda),
                    auto.memory(),
                ));
            }
            out
        };
        let one = run(1);
        assert_eq!(one[0].0.solver, "gs+interior", "{:?}", one[0].0);
        assert!(
            one[0].3.len() > 3 + 3 * chain_len,
            "the chains were given up"
        );
        for threads in [2, 3] {
            let other = run(threads);
            for (k, (a, b)) in one.iter().zip(&other).enumerate() {
                assert_eq!(a.0, b.0, "solve {k} on {threads} threads");
                assert!(a == b, "solve {k} on {threads} threads: other bits");
            }
        }
    }

    /// A chain Gauss–Seidel gives up at every try waits twice as long before each retry (1,
    /// 2, 4, 8, then 16 solves: `retry_after` = 1 and at most `MAX_RETRY_DOUBLINGS`
    /// doublings), on its own (the whole problem) and among small components (Gauss–Seidel's
    /// groups); every answer certified. (It was retried every `retry_after` solves: a crush
    /// that stays pressed paid a vain sweep of the whole crush every 16 steps.)
    #[test]
    fn gauss_seidel_waits_twice_as_long_each_time_it_gives_the_same_component_up() {
        let t = Target {
            gap: 1e-6,
            violation: 1e-9,
        };
        for triples in [0, 200] {
            let (rows, w, b) = triples_and_chains(triples, 1, 400);
            let p = ProjectionProblem {
                w: &w,
                jacobian: &rows,
                b: &b,
            };
            let mut auto = AutoSolver::new(AutoSettings {
                retry_after: 1,
                ..AutoSettings::default()
            })
            .unwrap();
            let mut sol = ProjectionSolution::default();
            let (mut tries, mut streak) = (Vec::new(), 0);
            for k in 0..60 {
                // From zero multipliers each time (from the last answer Gauss–Seidel would
                // finish at once).
                sol.lambda.iter_mut().for_each(|l| *l = 0.0);
                let rep = auto.solve(&p, t, &mut sol).unwrap();
                assert!(
                    rep.status.is_converged() && rep.gap <= t.gap && rep.violation <= t.violation,
                    "{triples} triples, solve {k}: {rep:?}"
                );
                // The chain's rows are remembered with the streak of its give-ups.
                let now = auto.given_up.iter().map(|g| g.streak).max().unwrap();
                assert!(
                    auto.given_up.len() >= 399,
                    "solve {k}: the chain remembered"
                );
                if now != streak {
                    assert_eq!(now, streak + 1, "solve {k}");
                    tries.push(k);
                    streak = now;
                }
            }
            // The waits between tries: 1, 2, 4, 8, 16, 16 solves.
            assert_eq!(tries, [0, 2, 5, 10, 19, 36, 53], "{triples} triples");
        }
    }

    /// Keys above 2⁵³ (a crowd's contact keys use all 64 bits) survive the trip through
    /// the f64 memory, with each row's wait and streak (rows of the same wait in one group),
    /// and the layouts of earlier builds still restore.
    #[test]
    fn the_memory_keeps_every_bit_of_the_keys_and_reads_the_old_form() {
        let mut auto = AutoSolver::new(AutoSettings::default()).unwrap();
        auto.last_change = 0.25;
        let given_up = |key, left, streak| GivenUp { key, left, streak };
        auto.given_up = vec![
            given_up(7, 16, 1),
            given_up((1 << 53) + 1, 5, 3),
            given_up(u64::MAX - 2, 16, 1),
        ];
        let memory = auto.memory();
        // The layout mark, last_change, two groups (wait 5, then 16) of one and two keys, and
        // each interior point's memory (new: its head alone).
        assert_eq!(memory.len(), 3 + (3 + 2) + (3 + 2 * 2) + 2 * (1 + 6));
        assert_eq!(memory[2..5], [2.0, 5.0, 3.0]);
        let mut restored = AutoSolver::new(AutoSettings::default()).unwrap();
        restored.set_memory(&memory);
        assert_eq!(restored.given_up, auto.given_up);
        assert_eq!(restored.last_change, 0.25);
        assert_eq!(restored.memory(), memory);
        // The rows in the earlier layouts' three numbers: each given up once.
        let once: Vec<f64> = auto
            .given_up
            .iter()
            .flat_map(|g| [(g.key >> 32) as f64, (g.key as u32) as f64, g.left as f64])
            .collect();
        let mut read_once = auto.given_up.clone();
        read_once.iter_mut().for_each(|g| g.streak = 1);
        // [−2, last_change, G, rows given up…, L₀, …] from before the wait doubled.
        let interiors = &memory[memory.len() - 2 * (1 + 6)..];
        let layout_once: Vec<f64> = [MEMORY_LAYOUT_ONCE, 0.5, 3.0]
            .into_iter()
            .chain(once.iter().copied())
            .chain(interiors.iter().copied())
            .collect();
        restored.set_memory(&layout_once);
        assert_eq!(restored.given_up, read_once);
        assert_eq!(restored.last_change, 0.5);
        // [last_change, rows given up…] of the layout before.
        let previous: Vec<f64> = std::iter::once(0.75).chain(once).collect();
        restored.set_memory(&previous);
        assert_eq!(restored.given_up, read_once);
        assert_eq!(restored.last_change, 0.75);
        // [skip_from, skip_left, last_change] of the earlier form.
        restored.set_memory(&[120.0, 3.0, 0.5]);
        assert!(restored.given_up.is_empty());
        assert_eq!(restored.last_change, 0.5);
        restored.set_memory(&[-1.0]);
        assert_eq!(restored.last_change, f64::INFINITY);
        // A group's count of keys beyond the memory restores nothing.
        let mut cut = memory.clone();
        cut[5] = 1e9;
        restored.set_memory(&cut);
        assert!(restored.given_up.is_empty());
        assert_eq!(restored.last_change, f64::INFINITY);
        // A damaged count of rows given up restores nothing (and does not overflow).
        let mut damaged = memory.clone();
        damaged[2] = 1e300;
        restored.set_memory(&damaged);
        assert!(restored.given_up.is_empty());
        assert_eq!(restored.last_change, f64::INFINITY);
    }

    /// When the Newton method does not finish a round (here it is given one direction), the
    /// interior point takes the round back from the answer the round corrects: certified,
    /// with the bits the interior point alone gives, and the Newton method's work counted.
    /// (A chain of 12 pushed at its head, its last person behind a stiff row far from binding
    /// at rest, which the first answer violates; Gauss–Seidel is given one pass, so the chain
    /// goes to the Newton-type solvers; beside it a far pair at rest makes a second
    /// component, so the round is solved by component.)
    #[test]
    fn a_round_the_newton_method_does_not_finish_goes_back_to_the_interior_point() {
        let n = 12;
        let mut rows = ConstraintRows::new(n + 3);
        for k in 0..n - 1 {
            rows.push(k as u64, 0.0, [(k, -1.0), (k + 1, 1.0)]);
        }
        rows.push(n as u64, 0.0, [(n - 1, -1000.0), (n, 1000.0)]);
        rows.push(n as u64 + 1, 0.0, [(n + 1, -1.0), (n + 2, 1.0)]);
        let mut b = vec![0.0; n + 1];
        b[n - 1] = 40.0;
        let mut w = vec![0.0; n + 3];
        w[0] = 1.0;
        let t = Target {
            gap: 1e-10,
            violation: 1e-9,
        };
        let solve = |newton: Option<NewtonSettings>| {
            // (Mehrotra's start every time, scaled by the caller's multipliers.)
            let mut auto = AutoSolver::with_solvers(
                AutoSettings {
                    first_order_passes: 1,
                    ..AutoSettings::default()
                },
                InteriorPointSettings {
                    warm_iterate: 0.0,
                    ..InteriorPointSettings::default()
                },
                GaussSeidelSettings::default(),
            )
            .unwrap();
            if let Some(settings) = newton {
                auto.newton = Some(Newton::new(settings).unwrap());
            } else {
                auto.newton = None;
            }
            let zero = vec![0.0; n + 3];
            let mut sol = ProjectionSolution::default();
            let rest = ProjectionProblem {
                w: &zero,
                jacobian: &rows,
                b: &b,
            };
            assert!(
                auto.solve(&rest, t, &mut sol)
                    .unwrap()
                    .status
                    .is_converged()
            );
            let p = ProjectionProblem {
                w: &w,
                jacobian: &rows,
                b: &b,
            };
            let rep = auto.solve(&p, t, &mut sol).unwrap();
            assert_eq!(auto.screen().rounds, 1, "{rep:?}");
            (rep, sol)
        };
        let (alone, alone_sol) = solve(None);
        let (newton, newton_sol) = solve(Some(NewtonSettings {
            max_iterations: 1,
            max_solves: 1,
            ..NewtonSettings::default()
        }));
        for (name, rep) in [("alone", &alone), ("after newton", &newton)] {
            assert_eq!(rep.status, SolveStatus::Converged, "{name}: {rep:?}");
            // (Gauss–Seidel answers the far pair.)
            assert_eq!(rep.solver, "gs+interior", "{name}: {rep:?}");
            assert!(
                rep.gap <= t.gap && rep.violation <= t.violation,
                "{name}: {rep:?}"
            );
        }
        assert!(
            newton.factorizations > alone.factorizations,
            "the Newton method's work counts: {newton:?} against {alone:?}"
        );
        // The interior point starts from what it would have started from without the Newton
        // method (the caller's multipliers set its start's scale): the same bits.
        let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&newton_sol.v), bits(&alone_sol.v));
        assert_eq!(bits(&newton_sol.lambda), bits(&alone_sol.lambda));
        let c = 1.04 / (n + 1) as f64;
        for (k, a) in newton_sol.v.iter().take(n).enumerate() {
            assert!((a - c).abs() <= 1e-6, "v[{k}] = {a}, closed form {c}");
        }
    }

    /// Every name the report can give fits the run file's 16 bytes for it (a longer one was
    /// cut there: `gs+interior+newton` was written `gs+interior+newt`).
    #[test]
    fn every_name_of_the_solvers_that_answered_fits_the_run_file() {
        let mut names = Vec::new();
        for k in 0..8 {
            names.push(answered_by(k & 1 != 0, k & 2 != 0, k & 4 != 0));
        }
        for name in &names {
            assert!(name.len() <= 16 && name.is_ascii(), "{name}");
        }
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), 7, "{names:?}");
    }
}
