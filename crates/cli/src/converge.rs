//! `moreau converge`: the convergence experiment of Bernicot & Venel §5 (error (24) against a
//! fine reference, fitted order), written as JSON, Markdown and a log–log SVG.

use moreau_core::Num;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use moreau_crowd::Scene;
use serde::Serialize;

use crate::study::{How, Leaving, error, error_in_room, sample};
use crate::svg::{LogLog, Series, fit_power, order_interval};

/// Whom error (24) counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Count {
    /// Everyone, wherever they are (the paper's (24); exits must keep everyone).
    All,
    /// At each t_i, the people who have passed no exit in either run (exits may remove
    /// people); the rows also give how many had passed in one run and not the other.
    InRoom,
}

/// Arguments of `moreau converge`.
#[derive(Debug, clap::Args)]
pub struct ConvergeArgs {
    /// The scene (with `--count all` its exits must keep everyone, `action = "continue"`).
    scene: PathBuf,
    /// Whom the error counts: everyone (the paper's (24)) or the people still in the room.
    #[arg(long, value_enum, default_value_t = Count::All)]
    count: Count,
    /// The step sizes to measure (s).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.02,0.025,0.04,0.05,0.0625,0.08,0.1,0.2,0.5",
        value_parser = crate::positive,
        allow_hyphen_values = true
    )]
    steps: Vec<f64>,
    /// The step of the reference run (s).
    #[arg(
        long,
        default_value_t = 0.01,
        value_parser = crate::positive,
        allow_hyphen_values = true
    )]
    h_min: f64,
    /// Compare at t_i = i T / samples, i = 1..samples (every step must divide T / samples).
    #[arg(long, default_value_t = 10, value_parser = crate::at_least_one)]
    samples: usize,
    /// Override the horizon T of the scene (s).
    #[arg(long, value_parser = crate::positive, allow_hyphen_values = true)]
    horizon: Option<f64>,
    /// Override κ in ε_k = κ μ³ (default: the scene's).
    #[arg(long, value_parser = crate::positive, allow_hyphen_values = true)]
    eps_kappa: Option<f64>,
    /// Directory for converge.json, converge.md and converge.svg.
    #[arg(short, long, default_value = "out/converge")]
    out: PathBuf,
    /// No progress lines.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Debug, Serialize)]
struct Row {
    h: f64,
    steps: usize,
    /// Error (24); `None` (`null`) for a run that failed.
    error: Option<f64>,
    error_per_person_max: f64,
    iterations_per_step: f64,
    max_eps: f64,
    max_violation: f64,
    wall_seconds: f64,
    /// With `--count in-room`: the most people, at one t_i, through an exit in one run and
    /// not in the other (0 with `--count all`).
    passed_mismatch: usize,
    /// Why the run failed (`None` for a run that reached the horizon).
    failed: Option<String>,
}

#[derive(Debug, Serialize)]
struct Fit {
    points: String,
    order: f64,
    /// Half-width of the 95 % confidence interval of the order (least squares in log–log).
    order_95: Option<f64>,
    constant: f64,
    r2: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    scene: String,
    people: usize,
    horizon: f64,
    h_min: f64,
    samples: usize,
    eps_kappa: f64,
    count: Count,
    error_definition: String,
    rows: Vec<Row>,
    fits: Vec<Fit>,
}

/// Runs `moreau converge`: success when every run reached the horizon, 1 when one failed
/// (recorded as failed, the others run).
pub fn converge(args: &ConvergeArgs) -> Result<ExitCode> {
    let mut scene = Scene::from_file(&args.scene)?;
    crate::study::refuse_sources(&scene)?;
    if let Some(t) = args.horizon {
        scene.time.horizon = t;
    }
    if let Some(k) = args.eps_kappa {
        scene.solver.eps_kappa = k;
    }
    if let Some(t) = args.horizon
        && !(t > 0.0 && t.is_finite())
    {
        bail!("--horizon {}: must be finite and > 0", moreau_core::Num(t));
    }
    if args.steps.iter().any(|&h| !(h > args.h_min)) {
        bail!(
            "every step must be larger than --h-min {}",
            moreau_core::Num(args.h_min)
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating '{}'", args.out.display()))?;

    let say = |s: String| {
        if !args.quiet {
            eprintln!("{s}");
        }
    };
    say(format!("reference run, h_min = {} ...", Num(args.h_min)));
    let leaving = match args.count {
        Count::All => Leaving::Refused,
        Count::InRoom => Leaving::Allowed,
    };
    let reference = sample(&scene, &How::Fixed(args.h_min), args.samples, leaving)
        .with_context(|| format!("reference run with h_min = {}", Num(args.h_min)))?;
    say(format!("  {} steps", reference.steps));
    let n = reference.states[0].len() / 2;
    let mut report = Report {
        scene: args.scene.display().to_string(),
        people: n,
        horizon: scene.time.horizon,
        h_min: args.h_min,
        samples: args.samples,
        eps_kappa: scene.solver.eps_kappa,
        count: args.count,
        error_definition: match args.count {
            Count::All => "e_h = max_{i=1..samples} |q_{h_min}(t_i) - q_h(t_i)|_2 over everyone, t_i = i T / samples (Bernicot & Venel (24))",
            Count::InRoom => "e_h = max_{i=1..samples} |q_{h_min}(t_i) - q_h(t_i)|_2 over the people who passed no exit by t_i in either run, t_i = i T / samples ((24) restricted to the room)",
        }
        .into(),
        rows: Vec::new(),
        fits: Vec::new(),
    };
    // Each run's row is written as soon as it is measured; a run that fails is recorded as
    // failed and the others still run (the exit status says whether every run finished).
    for &h in &args.steps {
        let run = match sample(&scene, &How::Fixed(h), args.samples, leaving) {
            Ok(run) => run,
            Err(e) => {
                let why = format!("{e:#}");
                say(format!("  h = {:<7} failed: {why}", Num(h).to_string()));
                report.rows.push(Row {
                    h,
                    steps: 0,
                    error: None,
                    error_per_person_max: 0.0,
                    iterations_per_step: 0.0,
                    max_eps: 0.0,
                    max_violation: 0.0,
                    wall_seconds: 0.0,
                    passed_mismatch: 0,
                    failed: Some(why),
                });
                report.fits = fits(&report.rows, args.h_min);
                write(&args.out, &report)?;
                continue;
            }
        };
        // (24): e_h = max_i |q_hmin(t_i) − q_h(t_i)|, Euclidean norm over all coordinates (or
        // over the people still in the room).
        let (error, per_person, passed_mismatch) = match args.count {
            Count::All => {
                let (e, p) = error(&reference.states, &run.states);
                (e, p, 0)
            }
            Count::InRoom => error_in_room(&reference, &run),
        };
        let (steps, wall) = (run.steps, run.wall);
        let it = run.iterations as f64 / steps.max(1) as f64;
        say(format!(
            "  h = {:<7} e_h = {error:.4e}  ({steps} steps, {it:.0} iterations/step, {wall:.1} s)",
            Num(h).to_string()
        ));
        report.rows.push(Row {
            h,
            steps,
            error: Some(error),
            error_per_person_max: per_person,
            iterations_per_step: it,
            max_eps: run.max_eps,
            max_violation: run.max_violation,
            wall_seconds: wall,
            passed_mismatch,
            failed: None,
        });
        report.fits = fits(&report.rows, args.h_min);
        write(&args.out, &report)?;
    }
    if args.steps.is_empty() {
        write(&args.out, &report)?;
    }
    for f in &report.fits {
        println!(
            "observed order ({}): {:.3}{} (R² = {:.3})",
            f.points,
            f.order,
            f.order_95
                .map_or(String::new(), |w| format!(" ± {w:.3} (95 %)")),
            f.r2
        );
    }
    println!(
        "wrote {}/converge.json, converge.md, converge.svg",
        args.out.display()
    );
    let failed = report.rows.iter().filter(|r| r.failed.is_some()).count();
    if failed > 0 {
        eprintln!(
            "moreau: {failed} of {} runs failed (recorded as failed in {}/converge.md)",
            report.rows.len(),
            args.out.display()
        );
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}

/// The measured points `(h, e_h)`: the runs that did not fail.
fn measured(rows: &[Row]) -> Vec<(f64, f64)> {
    rows.iter()
        .filter_map(|r| r.error.map(|e| (r.h, e)))
        .collect()
}

/// The fitted orders over every measured step and over those ≥ 4 h_min.
fn fits(rows: &[Row], h_min: f64) -> Vec<Fit> {
    let all = measured(rows);
    let far: Vec<(f64, f64)> = all
        .iter()
        .copied()
        .filter(|(h, _)| *h >= 4.0 * h_min)
        .collect();
    let mut fits = Vec::new();
    for (label, pts) in [("all steps", &all), ("h ≥ 4 h_min", &far)] {
        if let Some((order, constant, r2)) = fit_power(pts) {
            fits.push(Fit {
                points: label.into(),
                order,
                order_95: order_interval(pts),
                constant,
                r2,
            });
        }
    }
    fits
}

fn write(dir: &Path, report: &Report) -> Result<()> {
    std::fs::write(
        dir.join("converge.json"),
        serde_json::to_string_pretty(report)? + "\n",
    )?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Convergence on `{}` ({} people, T = {} s, h_min = {}, ε_k = {:e} μ³), error (24) at t_i = iT/{}, {}:\n",
        report.scene,
        report.people,
        Num(report.horizon),
        Num(report.h_min),
        report.eps_kappa,
        report.samples,
        match report.count {
            Count::All => "over everyone",
            Count::InRoom => "over the people still in the room",
        }
    );
    let _ = writeln!(
        md,
        "| h (s) | steps | e_h (m) | worst person (m) | iterations/step | max ε (m²) | max violation (m) | wall (s) | passed in one run only |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|");
    for r in &report.rows {
        let (Some(error), None) = (r.error, &r.failed) else {
            let why = r.failed.as_deref().unwrap_or("no error");
            let _ = writeln!(md, "| {} | | failed: {} | | | | | | |", Num(r.h), why);
            continue;
        };
        let _ = writeln!(
            md,
            "| {} | {} | {:.4e} | {:.4e} | {:.0} | {:.2e} | {:.2e} | {:.2} | {} |",
            Num(r.h),
            r.steps,
            error,
            r.error_per_person_max,
            r.iterations_per_step,
            r.max_eps,
            r.max_violation,
            r.wall_seconds,
            r.passed_mismatch
        );
    }
    let _ = writeln!(md);
    for f in &report.fits {
        let _ = writeln!(
            md,
            "Fitted order ({}): **{:.3}**{}, R² = {:.3}.",
            f.points,
            f.order,
            f.order_95
                .map_or(String::new(), |w| format!(" ± {w:.3} (95 %)")),
            f.r2
        );
    }
    std::fs::write(dir.join("converge.md"), md)?;

    // (A failed run has no error: it is left out.)
    let measured = measured(&report.rows);
    let mut series = vec![Series {
        name: "e_h (measured)".into(),
        points: measured.clone(),
        dashed: false,
    }];
    if let Some(f) = report.fits.first() {
        series.push(Series {
            name: format!("fit: order {:.2}", f.order),
            points: measured
                .iter()
                .map(|&(h, _)| (h, f.constant.exp() * h.powf(f.order)))
                .collect(),
            dashed: true,
        });
        // Order 1/2 through the middle point, for comparison with the paper.
        let (hm, em) = measured[measured.len() / 2];
        series.push(Series {
            name: "order 1/2 (paper)".into(),
            points: measured
                .iter()
                .map(|&(h, _)| (h, em * (h / hm).sqrt()))
                .collect(),
            dashed: true,
        });
    }
    let plot = LogLog {
        title: format!("Convergence, {} ({} people)", report.scene, report.people),
        x_label: "step h (s)".into(),
        y_label: "error e_h (m)".into(),
        series,
    };
    std::fs::write(dir.join("converge.svg"), plot.render())?;
    Ok(())
}
