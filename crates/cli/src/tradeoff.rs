//! `moreau tradeoff`: work–precision of fixed steps, adaptive steps at several tolerances and
//! each solver, against a fine reference: error (24) and evacuation-curve error against wall
//! time, written as JSON, Markdown and a log–log SVG.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use moreau_core::Num;
use moreau_crowd::{Scene, SolverKind};
use serde::Serialize;

use crate::run::Estimate;
use crate::study::{self, How, Leaving, sample};
use crate::svg::{LogLog, Series};

/// Arguments of `moreau tradeoff`.
#[derive(Debug, clap::Args)]
pub struct TradeoffArgs {
    /// The scene (its exits must keep everyone, `action = "continue"`).
    scene: PathBuf,
    /// The step of the reference run (s), with ε_k = 1e-5 μ³.
    #[arg(
        long,
        default_value_t = 0.01,
        value_parser = crate::positive,
        allow_hyphen_values = true
    )]
    reference_step: f64,
    /// Fixed steps to measure (s), with the scene's solver.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.02,0.05,0.1,0.2",
        value_parser = crate::positive,
        allow_hyphen_values = true
    )]
    steps: Vec<f64>,
    /// Adaptive tolerances to measure (m), with each error estimate.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.1,0.03,0.01,0.003",
        value_parser = crate::positive,
        allow_hyphen_values = true
    )]
    tols: Vec<f64>,
    /// Fixed steps to measure with Clarabel as the only solver (s).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.05,0.1",
        value_parser = crate::positive,
        allow_hyphen_values = true
    )]
    clarabel_steps: Vec<f64>,
    /// Compare at t_i = i T / samples.
    #[arg(long, default_value_t = 10, value_parser = crate::at_least_one)]
    samples: usize,
    /// Override the horizon T of the scene (s).
    #[arg(long, value_parser = crate::positive, allow_hyphen_values = true)]
    horizon: Option<f64>,
    /// Directory for tradeoff.json, tradeoff.md and tradeoff.svg.
    #[arg(short, long, default_value = "out/tradeoff")]
    out: PathBuf,
    /// Run nothing: redraw tradeoff.md and tradeoff.svg from the tradeoff.json in --out.
    #[arg(long)]
    replot: bool,
}

/// What a measurement was made with, beside its points (`tradeoff-settings.json`), so that
/// `--replot` writes the horizon and reference step that were measured, not those of its own
/// command line (a replot of T = 0.7 s said "T = 3 s", the scene's horizon).
#[derive(Debug, Serialize, serde::Deserialize)]
struct Measured {
    horizon: f64,
    reference_step: f64,
}

#[derive(Debug, Serialize, serde::Deserialize)]
struct Point {
    method: String,
    setting: f64,
    steps: usize,
    rejected: usize,
    wall_seconds: f64,
    /// Error (24); `None` (`null`) for a run that failed.
    error: Option<f64>,
    evacuation_error: usize,
    passed_exit: usize,
    /// Why the run stopped before its horizon (then the numbers above are not measured:
    /// zero, and no error); `None` for a run that finished.
    #[serde(default)]
    failed: Option<String>,
}

/// Runs `moreau tradeoff`: success when every run reached its horizon, 1 when one failed
/// (recorded as failed, the others run).
pub fn tradeoff(args: &TradeoffArgs) -> Result<ExitCode> {
    let mut scene = Scene::from_file(&args.scene)?;
    crate::study::refuse_sources(&scene)?;
    if let Some(t) = args.horizon {
        scene.time.horizon = t;
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating '{}'", args.out.display()))?;
    if args.replot {
        let json = args.out.join("tradeoff.json");
        let text = std::fs::read_to_string(&json)
            .with_context(|| format!("reading '{}'", json.display()))?;
        let points: Vec<Point> =
            serde_json::from_str(&text).with_context(|| format!("parsing '{}'", json.display()))?;
        let settings = args.out.join(SETTINGS);
        let measured = match std::fs::read_to_string(&settings) {
            Ok(text) => serde_json::from_str(&text)
                .with_context(|| format!("parsing '{}'", settings.display()))?,
            // Written before the settings were kept: the command line's, as then.
            Err(_) => Measured {
                horizon: scene.time.horizon,
                reference_step: args.reference_step,
            },
        };
        write(args, &measured, &points)?;
        println!("wrote {}/tradeoff.md, tradeoff.svg", args.out.display());
        return Ok(ExitCode::SUCCESS);
    }
    let mut reference_scene = scene.clone();
    reference_scene.solver.eps_kappa = 1e-5;
    eprintln!("reference run, h = {} ...", Num(args.reference_step));
    let reference = sample(
        &reference_scene,
        &How::Fixed(args.reference_step),
        args.samples,
        Leaving::Refused,
    )
    .context("the reference run")?;

    let mut runs: Vec<(String, f64, Scene, How)> = Vec::new();
    let mut steps = args.steps.clone();
    steps.sort_by(|a, b| b.total_cmp(a));
    let mut clarabel_steps = args.clarabel_steps.clone();
    clarabel_steps.sort_by(|a, b| b.total_cmp(a));
    let mut tols = args.tols.clone();
    tols.sort_by(|a, b| b.total_cmp(a));
    for &h in &steps {
        // The scene's own solver, named as the scene names it (the label said "APGD" whatever
        // the scene chose).
        let label = format!("fixed step, {}", scene.solver.kind.as_str());
        runs.push((label, h, scene.clone(), How::Fixed(h)));
    }
    for &h in &clarabel_steps {
        let mut s = scene.clone();
        s.solver.kind = SolverKind::Clarabel;
        runs.push(("fixed step, Clarabel".into(), h, s, How::Fixed(h)));
    }
    for &tol in &tols {
        let mut clarabel = scene.clone();
        clarabel.solver.kind = SolverKind::Clarabel;
        runs.push((
            "adaptive, velocity change, Clarabel".into(),
            tol,
            clarabel,
            How::Adaptive(tol, Estimate::Velocity),
        ));
        runs.push((
            "adaptive, step doubling".into(),
            tol,
            scene.clone(),
            How::Adaptive(tol, Estimate::Doubling),
        ));
        runs.push((
            "adaptive, velocity change".into(),
            tol,
            scene.clone(),
            How::Adaptive(tol, Estimate::Velocity),
        ));
    }
    // Each run's point is written as soon as it is measured; a run that fails is recorded as
    // failed and the others still run: one uncertified projection loses nothing already
    // measured (the exit status says whether every run finished).
    let mut points = Vec::new();
    for (method, setting, s, how) in &runs {
        let r = match sample(s, how, args.samples, Leaving::Refused) {
            Ok(r) => r,
            Err(e) => {
                let why = format!("{e:#}");
                eprintln!(
                    "  {method:<36} {:<6} failed: {why}",
                    Num(*setting).to_string()
                );
                points.push(Point {
                    method: method.clone(),
                    setting: *setting,
                    steps: 0,
                    rejected: 0,
                    wall_seconds: 0.0,
                    error: None,
                    evacuation_error: 0,
                    passed_exit: 0,
                    failed: Some(why),
                });
                save(args, &scene, &points)?;
                continue;
            }
        };
        let (error, _) = study::error(&reference.states, &r.states);
        let evacuation_error = reference
            .passed
            .iter()
            .zip(&r.passed)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        eprintln!(
            "  {method:<36} {:<6} e = {error:9.4}  ΔN = {evacuation_error:3}  {:5} steps ({:4} rejected)  {:7.2} s",
            Num(*setting).to_string(),
            r.steps,
            r.rejected,
            r.wall
        );
        points.push(Point {
            method: method.clone(),
            setting: *setting,
            steps: r.steps,
            rejected: r.rejected,
            wall_seconds: r.wall,
            error: Some(error),
            evacuation_error,
            passed_exit: *r.passed.last().unwrap_or(&0),
            failed: None,
        });
        save(args, &scene, &points)?;
    }
    println!(
        "wrote {}/tradeoff.json, tradeoff.md, tradeoff.svg",
        args.out.display()
    );
    let failed = points.iter().filter(|p| p.failed.is_some()).count();
    if failed > 0 {
        eprintln!(
            "moreau: {failed} of {} runs failed (recorded as failed in {}/tradeoff.md)",
            points.len(),
            args.out.display()
        );
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}

/// The file beside tradeoff.json that says what it was measured with.
const SETTINGS: &str = "tradeoff-settings.json";

/// Writes tradeoff.json and its settings, then tradeoff.md and tradeoff.svg, from the points
/// measured so far.
fn save(args: &TradeoffArgs, scene: &Scene, points: &[Point]) -> Result<()> {
    let measured = Measured {
        horizon: scene.time.horizon,
        reference_step: args.reference_step,
    };
    std::fs::write(
        args.out.join("tradeoff.json"),
        serde_json::to_string_pretty(points)? + "\n",
    )?;
    std::fs::write(
        args.out.join(SETTINGS),
        serde_json::to_string_pretty(&measured)? + "\n",
    )?;
    write(args, &measured, points)
}

/// Writes tradeoff.md and tradeoff.svg from the measured points.
fn write(args: &TradeoffArgs, measured: &Measured, points: &[Point]) -> Result<()> {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Work–precision on `{}` (T = {} s) against a reference with h = {} and ε_k = 1e-5 μ³; \
         e = max_i |q_ref(t_i) − q(t_i)| (error (24)), ΔN = max_i |N_ref(t_i) − N(t_i)| \
         (people through the exit), wall time of one thread:\n",
        args.scene.display(),
        Num(measured.horizon),
        Num(measured.reference_step)
    );
    let _ = writeln!(
        md,
        "| method | step (s) or tol (m) | steps | rejected | e (m) | ΔN | wall (s) |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|");
    for p in points {
        let _ = match &p.failed {
            None => writeln!(
                md,
                "| {} | {} | {} | {} | {:.3} | {} | {:.2} |",
                p.method,
                Num(p.setting),
                p.steps,
                p.rejected,
                p.error.unwrap_or(f64::NAN),
                p.evacuation_error,
                p.wall_seconds
            ),
            Some(why) => writeln!(
                md,
                "| {} | {} | failed: {} | | | | |",
                p.method,
                Num(p.setting),
                why.replace('|', "\\|")
            ),
        };
    }
    std::fs::write(args.out.join("tradeoff.md"), md)?;

    let mut series: Vec<Series> = Vec::new();
    for p in points {
        // (A failed run has no error: it is left out.)
        let Some(error) = p.error else { continue };
        match series.iter_mut().find(|s| s.name == p.method) {
            Some(s) => s.points.push((p.wall_seconds, error)),
            None => series.push(Series {
                name: p.method.clone(),
                points: vec![(p.wall_seconds, error)],
                dashed: false,
            }),
        }
    }
    // Points stay in the order of their setting (steps, tolerances), largest first.
    let plot = LogLog {
        title: format!("Work–precision, {}", args.scene.display()),
        x_label: "wall time of the run (s)".into(),
        y_label: "error (24) against the reference (m)".into(),
        series,
    };
    std::fs::write(args.out.join("tradeoff.svg"), plot.render())?;
    Ok(())
}
