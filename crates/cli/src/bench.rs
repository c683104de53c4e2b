//! `moreau bench`: the scale table of the performance issue. Dense evacuation halls
//! (≥ 2.5 people/m², one door) or crushed crowds (a hexagonal packing at 5 people/m² pushing
//! towards one point) of 10³…10⁶ people, each size in its own process (for its peak memory):
//! per step the median time and its stages, iterations, certified ε and violation, at the
//! accuracy `√ε ≤ 1e-3 r_min`, violation ≤ 1e-4 r_min; the fitted exponent of cost in N; and,
//! at one size, the step's own (warm) projection against cold solves of the same projection
//! by each solver asked for (Clarabel among them). Every measured step can be kept in a CSV
//! file (`--steps-csv`), for a per-step look at where a mean comes from.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use moreau_core::{Parallelism, StepReport};
use moreau_crowd::{
    Crush, Hall, Observer, ObserverError, Scene, SimState, Simulation, SolverKind, SolverSettings,
};
use moreau_solve::{ProjectionSolution, SolverTuning, Target};
use serde::{Deserialize, Serialize};

use crate::svg::fit_power;

/// Which crowd `moreau bench` measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
pub enum BenchScene {
    /// An evacuation hall: people spread at `--density` head for one door and leave.
    Hall,
    /// A crush: a hexagonal packing at `--density` (default 5) pushing towards one point.
    Crush,
}

/// Arguments of `moreau bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Crowd sizes.
    #[arg(long, value_delimiter = ',', default_value = "1000,10000,100000", value_parser = crate::crowd_size)]
    sizes: Vec<usize>,
    /// The crowd.
    #[arg(long, value_enum, default_value_t = BenchScene::Hall)]
    scene: BenchScene,
    /// People per m² (default: 2.6 in a hall, 5 in a crush).
    #[arg(long, value_parser = crate::positive)]
    density: Option<f64>,
    /// Steps before measuring: 100 steps (5 s) let the queues form, so the measured steps
    /// are jammed ones (10 gives the easy early phase, 0 measures from the start).
    #[arg(long, default_value_t = 100)]
    warmup: usize,
    /// Steps measured (200 with --warmup 0: a whole evacuation, free flow then jam).
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one)]
    steps: usize,
    /// At this size (0: never), after the measured steps, one more step, then its projection
    /// again from cold (a new solver, zero multipliers) by each of --compare. A size not in
    /// --sizes is added to them.
    #[arg(long, default_value_t = 40_000, value_parser = crate::crowd_size_or_zero)]
    compare_at: usize,
    /// The solvers of the cold comparison.
    #[arg(long, value_delimiter = ',', default_value = "clarabel")]
    compare: Vec<SolverKind>,
    /// Each solver of the cold comparison alone, without its fallback: a solve that misses
    /// the target is reported as such (with its time) instead of being finished by another.
    #[arg(long)]
    compare_alone: bool,
    /// The solver of the steps (`interior`, `newton`, `apgd`, `gauss-seidel`, `auto`,
    /// `clarabel`, …).
    #[arg(long, default_value = "interior")]
    kind: SolverKind,
    /// Threads for the projection (0: every core).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// After the warm-up, save the simulation's state here (`{size}` in the path: the crowd
    /// size), so that later measurements can start from the very same jam.
    #[arg(long)]
    save_state: Option<PathBuf>,
    /// Start from this saved state (`{size}`: the crowd size) instead of the warm-up: a
    /// `--save-state` of the same scene, size, density and solver. Before/after comparisons
    /// then measure the same steps, not states a few steps apart.
    #[arg(long, conflicts_with = "save_state")]
    from_state: Option<PathBuf>,
    /// Settings of the measured solver from a TOML file of tables as a scene's `[solver.*]`
    /// (`[auto]`, `[interior]`, `[newton]`, `[gauss_seidel]`, `[apgd]`; e.g. `[auto]` then
    /// `own_reach_ratio = inf`), so that one build measures a setting against its default.
    #[arg(long)]
    solver_tables: Option<PathBuf>,
    /// Write every measured step of every size to this CSV file (one row a step: `people`,
    /// `step`, `t`, its stages in ms, `solver`, `status`, `iterations`, `factorizations`,
    /// `rows`, `active`, `eps`, `eps_target`, `violation`), rewritten after each size, so
    /// that a bench stopped part way keeps the sizes measured. Its directory must exist
    /// (checked before any measurement); an existing file is replaced.
    #[arg(long, value_name = "FILE")]
    steps_csv: Option<PathBuf>,
    /// Internal: measure one size in this process and print its JSON row.
    #[arg(long, hide = true, value_parser = crate::at_least_one)]
    one: Option<usize>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Row {
    people: usize,
    area_m2: f64,
    rows_per_step: f64,
    active_per_step: f64,
    ms_median: f64,
    ms_mean: f64,
    ms_assemble: f64,
    ms_solve: f64,
    /// Within the solve: orderings and symbolic analyses.
    ms_analyse: f64,
    /// Within the solve: numeric factorizations and triangular solves.
    ms_factorize: f64,
    ms_other: f64,
    /// Solver iterations per step, mean (`auto`: Gauss–Seidel's passes over all the rows
    /// plus the interior point's iterations).
    iterations: f64,
    /// Numeric factorizations per step, mean (Newton-type solvers).
    #[serde(default)]
    factorizations: f64,
    max_eps: f64,
    max_violation: f64,
    peak_rss_mb: f64,
    setup_s: f64,
    solvers: Vec<(String, usize)>,
    /// The three slowest measured steps, slowest first.
    #[serde(default)]
    slowest: Vec<MeasuredStep>,
    /// Every measured step, in order.
    #[serde(default)]
    steps: Vec<MeasuredStep>,
    comparison: Option<Comparison>,
}

/// A measured step: what `--steps-csv` writes, and what says where a mean far above the
/// median comes from.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct MeasuredStep {
    step: usize,
    /// The time at its end (s).
    t: f64,
    ms: f64,
    ms_assemble: f64,
    ms_solve: f64,
    ms_analyse: f64,
    ms_factorize: f64,
    solver: String,
    status: String,
    iterations: usize,
    factorizations: usize,
    rows: usize,
    active: usize,
    eps: f64,
    eps_target: f64,
    violation: f64,
}

impl MeasuredStep {
    fn new(r: &StepReport) -> Self {
        Self {
            step: r.step,
            t: r.t,
            ms: 1e3 * r.timings.total,
            ms_assemble: 1e3 * r.timings.assemble,
            ms_solve: 1e3 * r.timings.solve,
            ms_analyse: 1e3 * r.timings.solve_analyse,
            ms_factorize: 1e3 * r.timings.solve_factorize,
            solver: r.solver.to_string(),
            status: r.status.as_str().to_string(),
            iterations: r.iterations,
            factorizations: r.factorizations,
            rows: r.assembled,
            active: r.active,
            eps: r.eps,
            eps_target: r.eps_target,
            violation: r.violation,
        }
    }
}

/// `x` in the shortest form that reads back the same `f64`: plain where that is short,
/// scientific for the very small and very large (`1.3877787807814457e-19`, not eighteen zeros).
fn number(x: f64) -> String {
    if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// The CSV of `--steps-csv`: a header, then each row's steps.
fn steps_csv(rows: &[Row]) -> String {
    let mut out = String::from(
        "people,step,t,ms,ms_assemble,ms_solve,ms_analyse,ms_factorize,solver,status,\
         iterations,factorizations,rows,active,eps,eps_target,violation\n",
    );
    for row in rows {
        for s in &row.steps {
            let x = [
                s.t,
                s.ms,
                s.ms_assemble,
                s.ms_solve,
                s.ms_analyse,
                s.ms_factorize,
            ];
            let [t, ms, assemble, solve, analyse, factorize] = x.map(number);
            let [eps, eps_target, violation] = [s.eps, s.eps_target, s.violation].map(number);
            out.push_str(&format!(
                "{},{},{t},{ms},{assemble},{solve},{analyse},{factorize},{},{},{},{},{},{},\
                 {eps},{eps_target},{violation}\n",
                row.people,
                s.step,
                s.solver,
                s.status,
                s.iterations,
                s.factorizations,
                s.rows,
                s.active,
            ));
        }
    }
    out
}

#[derive(Debug, Serialize, Deserialize)]
struct Comparison {
    target_gap: f64,
    warm_ms: f64,
    warm_gap: f64,
    warm_solver: String,
    warm_iterations: usize,
    cold: Vec<Cold>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Cold {
    kind: String,
    answered_by: String,
    ms: f64,
    gap: f64,
    status: String,
    iterations: usize,
}

/// The tables of `--solver-tables` (none: the defaults), each checked.
fn solver_tables(path: Option<&Path>) -> Result<SolverTuning> {
    let Some(path) = path else {
        return Ok(SolverTuning::default());
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading --solver-tables {}", path.display()))?;
    let tuning: SolverTuning =
        toml::from_str(&text).with_context(|| format!("--solver-tables {}", path.display()))?;
    if let Err((table, e)) = tuning.validate() {
        bail!("--solver-tables {}: [{table}] {e}", path.display());
    }
    Ok(tuning)
}

/// The scene of `n` people at the table's accuracy: `√ε ≤ 1e-3 r_min` at μ = 0.05, i.e.
/// `κ μ³ = (1e-3 r_min)²`, and violation ≤ 1e-4 r_min, with r_min = 0.18 m.
fn scene(args: &BenchArgs, n: usize) -> Result<Scene> {
    let r_min: f64 = 0.18;
    // Far beyond any measured step, and the same whatever --warmup and --steps are: the
    // horizon is part of the scene (its hash), so a state saved after one warm-up can be
    // restored to measure any number of steps. (Measured steps do not depend on it: the
    // rows, iterations and certified ε of the scale table's rows are unchanged.)
    let horizon = 1000.0;
    let tables = solver_tables(args.solver_tables.as_deref())?;
    let solver = |side: f64| SolverSettings {
        kind: args.kind,
        threads: args.threads,
        interior: tables.interior,
        newton: tables.newton,
        gauss_seidel: tables.gauss_seidel,
        apgd: tables.apgd,
        auto: tables.auto,
        eps_kappa: (1e-3 * r_min).powi(2) / 0.05f64.powi(3),
        max_violation: 1e-4 * r_min,
        grid_cell: (side / 400.0).max(0.25),
        ..SolverSettings::default()
    };
    Ok(match args.scene {
        BenchScene::Hall => {
            let mut hall = Hall::new(n, args.density.unwrap_or(2.6));
            hall.horizon = horizon;
            hall.solver = solver(hall.side());
            hall.scene()?
        }
        BenchScene::Crush => {
            let mut crush = Crush::new(n);
            crush.density = args.density.unwrap_or(crush.density);
            crush.horizon = horizon;
            crush.solver = solver((n as f64 / crush.density).sqrt());
            crush.scene()?
        }
    })
}

fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).map(|kb| kb.parse::<f64>().ok()))
                .flatten()
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    if v.is_empty() {
        f64::NAN
    } else {
        v[v.len() / 2]
    }
}

/// `path` with `{size}` replaced by the crowd size, and `{n}` (the first name of the
/// placeholder, which clap's help cannot show: it turns it into a line break).
fn for_size(path: &Path, n: usize) -> PathBuf {
    let n = n.to_string();
    PathBuf::from(
        (path.to_string_lossy())
            .replace("{size}", &n)
            .replace("{n}", &n),
    )
}

/// Keeps every step report.
#[derive(Default)]
struct Reports(Vec<StepReport>);

impl Observer for Reports {
    fn step(&mut self, report: &StepReport) -> Result<(), ObserverError> {
        self.0.push(report.clone());
        Ok(())
    }
}

fn measure(args: &BenchArgs, n: usize) -> Result<Row> {
    let start = Instant::now();
    let scene = scene(args, n)?;
    let area = {
        let (lo, hi) = moreau_crowd::Polygon {
            vertices: scene.area.outer.clone(),
        }
        .bounds();
        (hi[0] - lo[0]) * (hi[1] - lo[1])
    };
    let mut sim = Simulation::new(scene)?;
    let setup = start.elapsed().as_secs_f64();
    let end = match &args.from_state {
        Some(path) => {
            let path = for_size(path, n);
            let bytes = std::fs::read(&path)
                .with_context(|| format!("reading the state '{}'", path.display()))?;
            SimState::from_bytes(&bytes)
                .and_then(|state| sim.restore(&state))
                .with_context(|| format!("restoring the state '{}'", path.display()))?;
            sim.time() + 0.05 * args.steps as f64
        }
        None => {
            sim.advance_to(0.05 * args.warmup as f64, &mut ())?;
            0.05 * (args.warmup + args.steps) as f64
        }
    };
    if let Some(path) = &args.save_state {
        let path = for_size(path, n);
        crate::run::write_whole(&path, &sim.state().to_bytes())
            .with_context(|| format!("saving the state to '{}'", path.display()))?;
    }
    let mut measured = Reports::default();
    sim.advance_to(end, &mut measured)?;
    let mut stats = moreau_core::RunStats::default();
    let (mut rows, mut active) = (0.0, 0.0);
    let (mut total, mut assemble, mut solve) = (Vec::new(), Vec::new(), Vec::new());
    let (mut analyse, mut factorize) = (Vec::new(), Vec::new());
    for r in &measured.0 {
        stats.add(r);
        total.push(1e3 * r.timings.total);
        assemble.push(1e3 * r.timings.assemble);
        solve.push(1e3 * r.timings.solve);
        analyse.push(1e3 * r.timings.solve_analyse);
        factorize.push(1e3 * r.timings.solve_factorize);
        rows += r.assembled as f64;
        active += r.active as f64;
    }
    let k = args.steps.max(1) as f64;
    let comparison = if n == args.compare_at {
        Some(compare(
            &mut sim,
            &args.compare,
            args.compare_alone,
            args.threads,
        )?)
    } else {
        None
    };
    let steps: Vec<MeasuredStep> = measured.0.iter().map(MeasuredStep::new).collect();
    let mut slowest = steps.clone();
    slowest.sort_by(|a, b| b.ms.total_cmp(&a.ms));
    slowest.truncate(3);
    let (t, a, s) = (median(total), median(assemble), median(solve));
    Ok(Row {
        people: n,
        area_m2: area,
        rows_per_step: rows / k,
        active_per_step: active / k,
        ms_median: t,
        ms_mean: 1e3 * stats.timings.total / k,
        ms_assemble: a,
        ms_solve: s,
        ms_analyse: median(analyse),
        ms_factorize: median(factorize),
        ms_other: t - a - s,
        iterations: stats.iterations_per_step(),
        factorizations: stats.factorizations_per_step(),
        max_eps: stats.max_eps,
        max_violation: stats.max_violation,
        peak_rss_mb: peak_rss_mb(),
        setup_s: setup,
        solvers: stats
            .solvers
            .iter()
            .map(|&(s, n)| (s.to_string(), n))
            .collect(),
        slowest,
        steps,
        comparison,
    })
}

/// One more step (its projection warm-started from the previous step), then the same
/// projection from cold by each of `kinds`.
fn compare(
    sim: &mut Simulation,
    kinds: &[SolverKind],
    alone: bool,
    threads: usize,
) -> Result<Comparison> {
    let mu = 0.05;
    let mut last = Reports::default();
    sim.advance_to(sim.time() + mu, &mut last)?;
    let r = last.0.pop().context("no step taken")?;
    let problem = sim.last_projection();
    let target = Target {
        gap: r.eps_target / (2.0 * mu * mu),
        violation: sim.scene().solver.max_violation / mu,
    };
    let mut cold = Vec::new();
    for &kind in kinds {
        let parallelism = Parallelism::threads(threads);
        let mut solver = if alone {
            kind.build_alone(parallelism)?
        } else {
            kind.build(parallelism, problem.dim())?
        };
        let mut sol = ProjectionSolution::default();
        let start = Instant::now();
        let rep = solver.solve(&problem, target, &mut sol)?;
        cold.push(Cold {
            kind: kind.as_str().into(),
            answered_by: rep.solver.into(),
            ms: 1e3 * start.elapsed().as_secs_f64(),
            gap: rep.gap,
            status: rep.status.as_str().into(),
            iterations: rep.iterations,
        });
    }
    Ok(Comparison {
        target_gap: target.gap,
        warm_ms: 1e3 * r.timings.solve,
        warm_gap: r.eps / (2.0 * mu * mu),
        warm_solver: r.solver.into(),
        warm_iterations: r.iterations,
        cold,
    })
}

/// Runs `moreau bench`.
pub fn bench(args: &BenchArgs) -> Result<()> {
    if let Some(n) = args.one {
        let row = measure(args, n)?;
        println!("{}", serde_json::to_string(&row)?);
        return Ok(());
    }
    // Read here too, so that a bad file fails before any measurement.
    solver_tables(args.solver_tables.as_deref())?;
    if let Some(path) = &args.steps_csv {
        moreau_io::check_output(path, moreau_io::Overwrite::Allowed).context("--steps-csv")?;
    }
    let exe = std::env::current_exe().context("locating the moreau binary")?;
    let mut rows: Vec<Row> = Vec::new();
    println!(
        "{:>9} {:>8} {:>9} {:>9} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>7} {:>6} {:>9} {:>9} {:>8} {:>7}",
        "people",
        "m²",
        "rows",
        "active",
        "ms/step",
        "mean",
        "assemble",
        "solve",
        "analyse",
        "factor",
        "other",
        "iter",
        "fact",
        "max ε",
        "max viol",
        "RSS MB",
        "setup s"
    );
    let mut sizes = args.sizes.clone();
    if args.compare_at > 0 && !sizes.contains(&args.compare_at) {
        sizes.push(args.compare_at);
        sizes.sort_unstable();
    }
    let compare: Vec<&str> = args.compare.iter().map(|k| k.as_str()).collect();
    for &n in &sizes {
        let mut cmd = Command::new(&exe);
        cmd.args([
            "bench",
            "--one",
            &n.to_string(),
            "--scene",
            match args.scene {
                BenchScene::Hall => "hall",
                BenchScene::Crush => "crush",
            },
            "--warmup",
            &args.warmup.to_string(),
            "--steps",
            &args.steps.to_string(),
            "--compare-at",
            &args.compare_at.to_string(),
            "--compare",
            &compare.join(","),
            "--kind",
            args.kind.as_str(),
            "--threads",
            &args.threads.to_string(),
        ]);
        if let Some(d) = args.density {
            cmd.args(["--density", &d.to_string()]);
        }
        if args.compare_alone {
            cmd.arg("--compare-alone");
        }
        if let Some(path) = &args.save_state {
            cmd.arg("--save-state").arg(path);
        }
        if let Some(path) = &args.from_state {
            cmd.arg("--from-state").arg(path);
        }
        if let Some(path) = &args.solver_tables {
            cmd.arg("--solver-tables").arg(path);
        }
        let out = cmd
            .output()
            .with_context(|| format!("running the {n}-people measurement"))?;
        if !out.status.success() {
            bail!(
                "the {n}-people measurement failed: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        // What the measurement said on its standard error (nothing, normally) is passed on.
        std::io::stderr().write_all(&out.stderr)?;
        let row: Row = serde_json::from_slice(&out.stdout)?;
        println!(
            "{:>9} {:>8.0} {:>9.0} {:>9.0} {:>10.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>7.1} {:>6.1} {:>9.2e} {:>9.2e} {:>8.0} {:>7.1}",
            row.people,
            row.area_m2,
            row.rows_per_step,
            row.active_per_step,
            row.ms_median,
            row.ms_mean,
            row.ms_assemble,
            row.ms_solve,
            row.ms_analyse,
            row.ms_factorize,
            row.ms_other,
            row.iterations,
            row.factorizations,
            row.max_eps,
            row.max_violation,
            row.peak_rss_mb,
            row.setup_s
        );
        rows.push(row);
        if let Some(path) = &args.steps_csv {
            crate::run::write_whole(path, steps_csv(&rows).as_bytes())
                .with_context(|| format!("writing --steps-csv '{}'", path.display()))?;
        }
    }
    let measured: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| args.sizes.contains(&r.people))
        .map(|r| (r.people as f64, r.ms_median))
        .collect();
    if let Some((p, _, r2)) = fit_power(&measured) {
        println!(
            "cost ~ N^{p:.3} (R² = {r2:.3}) over {} sizes",
            measured.len()
        );
    }
    for row in &rows {
        let solvers: Vec<String> = row
            .solvers
            .iter()
            .map(|(s, n)| format!("{s} {n}"))
            .collect();
        println!(
            "{} people: steps answered by {}",
            row.people,
            solvers.join(", ")
        );
        if !row.slowest.is_empty() {
            let slow: Vec<String> = row
                .slowest
                .iter()
                .map(|s| {
                    format!(
                        "step {} {:.1} ms ({}, {} it, {} fact, {} rows)",
                        s.step, s.ms, s.solver, s.iterations, s.factorizations, s.rows
                    )
                })
                .collect();
            println!("{} people: slowest {}", row.people, slow.join("; "));
        }
        if let Some(c) = &row.comparison {
            println!(
                "{} people, one projection to gap ≤ {:.2e}, the step after the {} measured (the \
                 warm ratio moves with that window): the step's own (warm) {:.1} ms by {} ({} \
                 iterations, gap {:.2e})",
                row.people,
                c.target_gap,
                args.steps,
                c.warm_ms,
                c.warm_solver,
                c.warm_iterations,
                c.warm_gap
            );
            for k in &c.cold {
                println!(
                    "    cold {:<12} {:>10.1} ms  {:>5} it  gap {:.2e}  {} (by {})  {:.1}× the warm step",
                    k.kind,
                    k.ms,
                    k.iterations,
                    k.gap,
                    k.status,
                    k.answered_by,
                    k.ms / c.warm_ms
                );
            }
        }
    }
    Ok(())
}
