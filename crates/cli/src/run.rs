//! `moreau run`: a scene (or the scene stored in a run file) to its horizon, to an HDF5 file.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use moreau_crowd::{Scene, Simulation};
use moreau_integrate::ErrorEstimate;
use moreau_io::{Overwrite, RunFile, RunWriter};
use moreau_record::{Record, Summary};

/// Arguments of `moreau run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The scene file (TOML). Give this or --from.
    #[arg(required_unless_present = "from", conflicts_with = "from")]
    scene: Option<PathBuf>,
    /// Take the scene stored in this run file: the run reproduces that file.
    #[arg(long, value_name = "RUN.h5")]
    from: Option<PathBuf>,
    /// The HDF5 run file to write. Without it the run only prints its summary.
    #[arg(short, long, value_name = "OUT.h5")]
    output: Option<PathBuf>,
    /// Replace the output file if it exists (without this, an existing file is an error).
    #[arg(long)]
    force: bool,
    /// No progress bar and no summary line (errors still go to stderr).
    #[arg(short, long)]
    quiet: bool,
    /// Write a JSON summary of the run to this file ('-' for stdout).
    #[arg(long, value_name = "FILE")]
    summary_json: Option<PathBuf>,
    /// Adaptive steps: the local error allowed per step (m). It sets the step sizes (between
    /// 1e-6 s and min(0.5 s, output interval), starting from the scene's step) and the projection
    /// accuracy ε_k = (θ·tol)² (μ_k/μ_max)³ with θ = 0.1. Without it, the scene's fixed step.
    #[arg(long, value_name = "METRES")]
    tol: Option<f64>,
    /// The error estimate of the adaptive steps (velocity: cheaper at equal error on the
    /// measured crowds, see the README's work–precision).
    #[arg(long, value_enum, default_value_t = Estimate::Velocity, requires = "tol")]
    estimate: Estimate,
}

/// The error estimate of `--tol` runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Estimate {
    /// One step against two half steps (three projections per step).
    Doubling,
    /// The change of velocity between consecutive steps (one projection per step).
    Velocity,
}

impl Estimate {
    /// The integrator's name for it.
    pub fn error_estimate(self) -> ErrorEstimate {
        match self {
            Estimate::Doubling => ErrorEstimate::StepDoubling,
            Estimate::Velocity => ErrorEstimate::VelocityChange,
        }
    }
}

/// `scene` with adaptive steps of tolerance `tol` (the scene's `time.tol`, `time.estimate`).
pub fn adaptive(scene: &Scene, tol: f64, estimate: Estimate) -> Scene {
    let mut scene = scene.clone();
    scene.time.tol = Some(tol);
    scene.time.estimate = Some(estimate.error_estimate());
    scene
}

fn load_scene(args: &RunArgs) -> Result<(Scene, String)> {
    match (&args.scene, &args.from) {
        (Some(path), None) => Ok((Scene::from_file(path)?, path.display().to_string())),
        (None, Some(run)) => {
            let file = RunFile::open(run)?;
            let text = file.text("scene")?;
            let origin = format!("{} (attribute 'scene')", run.display());
            Ok((Scene::from_toml(&text, &origin)?, origin))
        }
        _ => bail!("give a scene file or --from RUN.h5"),
    }
}

fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// Runs `moreau run`. Errors before the run starts are returned (exit 2, nothing written);
/// a failure during the run is reported, recorded in the file, and gives exit code 1.
pub fn run(args: &RunArgs) -> Result<ExitCode> {
    let overwrite = if args.force {
        Overwrite::Allowed
    } else {
        Overwrite::Never
    };
    if let Some(path) = &args.output {
        // Before the (possibly long) set-up: a bad path fails at once.
        moreau_io::check_output(path, overwrite)?;
    }
    let (mut scene, origin) = load_scene(args)?;
    if let Some(tol) = args.tol {
        scene = adaptive(&scene, tol, args.estimate);
        scene.validate().context("--tol")?;
    }
    let mut sim = Simulation::new(scene).with_context(|| format!("scene {origin}"))?;
    let people = sim.total_people();
    let frame = sim.frame();
    if frame
        .ids
        .iter()
        .enumerate()
        .any(|(k, &id)| id as usize != k)
    {
        bail!("internal: people are not numbered 0..{people} at the start");
    }
    let mut writer = match &args.output {
        Some(path) => {
            let header = moreau_record::header(&sim, command_line());
            Some(RunWriter::create(path, &header, overwrite)?)
        }
        None => None,
    };

    let bar = if args.quiet || !std::io::stderr().is_terminal() {
        ProgressBar::hidden()
    } else {
        // Simulated milliseconds: the same bar for fixed and adaptive steps.
        let bar = ProgressBar::with_draw_target(
            Some((sim.scene().time.horizon * 1e3).round() as u64),
            ProgressDrawTarget::stderr_with_hz(10),
        );
        bar.set_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {msg}  ETA {eta}")
                .expect("a valid template")
                .progress_chars("=> "),
        );
        bar
    };

    let start = Instant::now();
    let mut progress = |report: &moreau_core::StepReport, stats: &moreau_core::RunStats, left| {
        if !bar.is_hidden() {
            bar.set_position((report.t * 1e3).round() as u64);
            let rate = stats.steps as f64 / bar.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!(
                "t = {:7.2} s  {:>8.1} steps/s  {left:>7} people left",
                report.t, rate,
            ));
        }
        Ok(())
    };
    let mut record = Record::new(writer.as_mut(), people).with_progress(&mut progress);
    let outcome = sim.run(&mut record);
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();

    let status = match &outcome {
        Ok(()) => "complete".to_string(),
        Err(e) => format!("failed: {e:#}"),
    };
    let summary = Summary::new(
        &sim,
        &record,
        origin,
        args.output.as_ref().map(|p| p.display().to_string()),
        status.clone(),
        wall,
    );
    let stats = &record.stats;
    let json = summary.to_json();
    let mut failed: Option<anyhow::Error> = outcome.err().map(anyhow::Error::from);
    if let Some(w) = writer
        && let Err(e) = w.finish(&status, &json)
    {
        failed.get_or_insert(e.into());
    }
    // After the run, a summary that cannot be written is a failure of the run (exit 1), not
    // bad input (exit 2): the HDF5 file is already complete.
    if let Some(target) = &args.summary_json
        && let Err(e) = write_summary(target, &json)
    {
        failed.get_or_insert(e);
    }
    if !args.quiet {
        println!(
            "{}: {people} people, {} steps in {wall:.2} s ({:.2} ms/step); {} passed an exit; \
             {:.0} solver iterations/step; max certified ε {:.2e} m², max violation {:.2e} m{}",
            summary.scene,
            stats.steps,
            summary.ms_per_step,
            summary.passed_exit,
            summary.iterations_per_step,
            stats.max_eps,
            stats.max_violation,
            args.output
                .as_ref()
                .map_or(String::new(), |p| format!("; wrote {}", p.display())),
        );
    }
    match failed {
        None => Ok(ExitCode::SUCCESS),
        Some(e) => {
            eprintln!(
                "moreau: error: {e:#} (simulated time reached: {} s)",
                sim.time()
            );
            Ok(ExitCode::from(1))
        }
    }
}

fn write_summary(target: &Path, json: &str) -> Result<()> {
    if target.as_os_str() == "-" {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{json}")?;
        return Ok(());
    }
    std::fs::write(target, format!("{json}\n"))
        .with_context(|| format!("writing the summary to '{}'", target.display()))
}
