//! `moreau bench`: the scale table of the performance issue. Dense evacuation halls
//! (≥ 2.5 people/m², one door) of 10³…10⁶ people, each size in its own process (for its peak
//! memory): per step the median time and its stages, iterations, certified ε and violation,
//! at the accuracy `√ε ≤ 1e-3 r_min`, violation ≤ 1e-4 r_min; the fitted exponent of cost in
//! N; and, at one size, the fast solver against Clarabel on the same projection.

use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use moreau_core::StepReport;
use moreau_crowd::{Hall, Observer, ObserverError, Scene, Simulation, SolverKind, SolverSettings};
use moreau_solve::{
    ClarabelReference, ClarabelSettings, ProjectionSolution, ProjectionSolver, Target,
};
use serde::{Deserialize, Serialize};

use crate::svg::fit_power;

/// Arguments of `moreau bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Crowd sizes.
    #[arg(long, value_delimiter = ',', default_value = "1000,10000,100000")]
    sizes: Vec<usize>,
    /// People per m².
    #[arg(long, default_value_t = 2.6)]
    density: f64,
    /// Steps before measuring: 100 steps (5 s) let the queues form, so the measured steps
    /// are jammed ones (10 gives the easy early phase).
    #[arg(long, default_value_t = 100)]
    warmup: usize,
    /// Steps measured.
    #[arg(long, default_value_t = 5)]
    steps: usize,
    /// Also solve one projection with Clarabel at this size (0: never) and compare.
    #[arg(long, default_value_t = 40_000)]
    clarabel_at: usize,
    /// The fast solver measured (`interior`, `apgd`, `auto`, `clarabel`).
    #[arg(long, default_value = "interior")]
    kind: SolverKind,
    /// Threads for the projection (0: every core).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Internal: measure one size in this process and print its JSON row.
    #[arg(long, hide = true)]
    one: Option<usize>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Row {
    people: usize,
    area_m2: f64,
    rows_per_step: f64,
    active_per_step: f64,
    ms_median: f64,
    ms_assemble: f64,
    ms_solve: f64,
    /// Within the solve: orderings and symbolic analyses.
    #[serde(default)]
    ms_analyse: f64,
    /// Within the solve: numeric factorizations and triangular solves.
    #[serde(default)]
    ms_factorize: f64,
    ms_other: f64,
    iterations: f64,
    max_eps: f64,
    max_violation: f64,
    peak_rss_mb: f64,
    setup_s: f64,
    clarabel: Option<Comparison>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Comparison {
    fast_ms: f64,
    fast_gap: f64,
    clarabel_ms: f64,
    clarabel_gap: f64,
    clarabel_status: String,
    target_gap: f64,
}

/// The hall of `n` people at the table's accuracy: `√ε ≤ 1e-3 r_min` at μ = 0.05, i.e.
/// `κ μ³ = (1e-3 r_min)²`, and violation ≤ 1e-4 r_min.
fn hall(args: &BenchArgs, n: usize) -> Result<Scene> {
    let r_min: f64 = 0.18;
    let mut hall = Hall::new(n, args.density);
    hall.horizon = 0.05 * (args.warmup + args.steps + 1) as f64;
    hall.solver = SolverSettings {
        kind: args.kind,
        threads: args.threads,
        eps_kappa: (1e-3 * r_min).powi(2) / 0.05f64.powi(3),
        max_violation: 1e-4 * r_min,
        grid_cell: (hall.side() / 400.0).max(0.25),
        ..SolverSettings::default()
    };
    Ok(hall.scene()?)
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

fn measure(args: &BenchArgs, n: usize) -> Result<Row> {
    let start = Instant::now();
    let scene = hall(args, n)?;
    let side = (n as f64 / args.density).sqrt();
    let mut sim = Simulation::new(scene)?;
    let setup = start.elapsed().as_secs_f64();
    sim.advance_to(0.05 * args.warmup as f64, &mut ())?;
    let mut measured = Reports::default();
    sim.advance_to(0.05 * (args.warmup + args.steps) as f64, &mut measured)?;
    let (mut total, mut assemble, mut solve) = (Vec::new(), Vec::new(), Vec::new());
    let (mut analyse, mut factorize) = (Vec::new(), Vec::new());
    let (mut rows, mut active, mut iterations, mut eps, mut viol) = (0.0, 0.0, 0.0, 0.0f64, 0.0f64);
    for r in &measured.0 {
        total.push(1e3 * r.timings.total);
        assemble.push(1e3 * r.timings.assemble);
        solve.push(1e3 * r.timings.solve);
        analyse.push(1e3 * r.timings.solve_analyse);
        factorize.push(1e3 * r.timings.solve_factorize);
        rows += r.assembled as f64;
        active += r.active as f64;
        iterations += r.iterations as f64;
        eps = eps.max(r.eps);
        viol = viol.max(r.violation);
    }
    let k = args.steps.max(1) as f64;
    let clarabel = if n == args.clarabel_at {
        Some(compare(&mut sim)?)
    } else {
        None
    };
    let (t, a, s) = (median(total), median(assemble), median(solve));
    Ok(Row {
        people: n,
        area_m2: side * side,
        rows_per_step: rows / k,
        active_per_step: active / k,
        ms_median: t,
        ms_assemble: a,
        ms_solve: s,
        ms_analyse: median(analyse),
        ms_factorize: median(factorize),
        ms_other: t - a - s,
        iterations: iterations / k,
        max_eps: eps,
        max_violation: viol,
        peak_rss_mb: peak_rss_mb(),
        setup_s: setup,
        clarabel,
    })
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

/// One more step with the fast solver, then its projection again with Clarabel.
fn compare(sim: &mut Simulation) -> Result<Comparison> {
    let mu = 0.05;
    let mut last = Reports::default();
    sim.advance_to(sim.time() + mu, &mut last)?;
    let r = last.0.pop().context("no step taken")?;
    let problem = sim.last_projection();
    let target = Target {
        gap: r.eps_target / (2.0 * mu * mu),
        violation: sim.scene().solver.max_violation / mu,
    };
    let mut clarabel = ClarabelReference::new(ClarabelSettings::default());
    let mut sol = ProjectionSolution::default();
    let start = Instant::now();
    let rep = clarabel.solve(&problem, target, &mut sol)?;
    Ok(Comparison {
        fast_ms: 1e3 * r.timings.solve,
        fast_gap: r.eps / (2.0 * mu * mu),
        clarabel_ms: 1e3 * start.elapsed().as_secs_f64(),
        clarabel_gap: rep.gap,
        clarabel_status: rep.status.as_str().into(),
        target_gap: target.gap,
    })
}

/// Runs `moreau bench`.
pub fn bench(args: &BenchArgs) -> Result<()> {
    if let Some(n) = args.one {
        let row = measure(args, n)?;
        println!("{}", serde_json::to_string(&row)?);
        return Ok(());
    }
    let exe = std::env::current_exe().context("locating the moreau binary")?;
    let mut rows: Vec<Row> = Vec::new();
    println!(
        "{:>9} {:>8} {:>9} {:>9} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>9} {:>9} {:>8} {:>7}",
        "people",
        "m²",
        "rows",
        "active",
        "ms/step",
        "assemble",
        "solve",
        "analyse",
        "factor",
        "other",
        "iter",
        "max ε",
        "max viol",
        "RSS MB",
        "setup s"
    );
    let mut sizes = args.sizes.clone();
    if args.clarabel_at > 0 && !sizes.contains(&args.clarabel_at) {
        sizes.push(args.clarabel_at);
        sizes.sort_unstable();
    }
    for &n in &sizes {
        let out = Command::new(&exe)
            .args([
                "bench",
                "--one",
                &n.to_string(),
                "--density",
                &args.density.to_string(),
                "--warmup",
                &args.warmup.to_string(),
                "--steps",
                &args.steps.to_string(),
                "--clarabel-at",
                &args.clarabel_at.to_string(),
                "--kind",
                args.kind.as_str(),
                "--threads",
                &args.threads.to_string(),
            ])
            .output()
            .with_context(|| format!("running the {n}-people measurement"))?;
        if !out.status.success() {
            bail!(
                "the {n}-people measurement failed: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        let row: Row = serde_json::from_slice(&out.stdout)?;
        println!(
            "{:>9} {:>8.0} {:>9.0} {:>9.0} {:>10.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>8.0} {:>9.2e} {:>9.2e} {:>8.0} {:>7.1}",
            row.people,
            row.area_m2,
            row.rows_per_step,
            row.active_per_step,
            row.ms_median,
            row.ms_assemble,
            row.ms_solve,
            row.ms_analyse,
            row.ms_factorize,
            row.ms_other,
            row.iterations,
            row.max_eps,
            row.max_violation,
            row.peak_rss_mb,
            row.setup_s
        );
        rows.push(row);
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
        if let Some(c) = &row.clarabel {
            println!(
                "{} people, one projection to gap ≤ {:.2e}: fast solver {:.1} ms (gap {:.2e}), Clarabel {:.1} ms (gap {:.2e}, {}): {:.1}× ",
                row.people,
                c.target_gap,
                c.fast_ms,
                c.fast_gap,
                c.clarabel_ms,
                c.clarabel_gap,
                c.clarabel_status,
                c.clarabel_ms / c.fast_ms
            );
        }
    }
    Ok(())
}
