//! `moreau run`: a scene (or the scene stored in a run file) to its horizon, to an HDF5 file.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use moreau_core::Num;
use moreau_crowd::{Scene, SimState, Simulation, limits};
use moreau_integrate::ErrorEstimate;
use moreau_io::{BackgroundWriter, Overwrite, RunFile, RunSink, RunWriter};
use moreau_record::{Interrupted, Record, Summary};

/// Arguments of `moreau run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The scene file (TOML). Give this, --from or --resume.
    #[arg(required_unless_present_any = ["from", "resume"], conflicts_with = "from")]
    scene: Option<PathBuf>,
    /// Go on with a run that was killed while writing OUT.h5, from the state saved with its
    /// last frame in the partial file it left (`.OUT.h5.partial`), or that SIGINT or SIGTERM
    /// stopped (OUT.h5 with status interrupted): with the scene and settings stored there; the
    /// frames it writes are those the run would have written.
    #[arg(long, value_name = "OUT.h5", conflicts_with_all = ["scene", "from", "output", "tol"])]
    resume: Option<PathBuf>,
    /// Take the scene stored in this run file: the run reproduces that file.
    #[arg(long, value_name = "RUN.h5")]
    from: Option<PathBuf>,
    /// The HDF5 run file to write. Without it the run only prints its summary.
    #[arg(short, long, value_name = "OUT.h5")]
    output: Option<PathBuf>,
    /// Replace the output file (and the --summary-json file) if it exists (without this, an
    /// existing file is an error). The old file stays whole until the new run ends.
    #[arg(long)]
    force: bool,
    /// No progress bar and no summary line (errors still go to stderr).
    #[arg(short, long)]
    quiet: bool,
    /// Write a JSON summary of the run to this file ('-' for stdout). Checked before the run:
    /// its directory must exist, it is replaced only with --force, and it may not name the
    /// scene, the --from file or the output.
    #[arg(long, value_name = "FILE")]
    summary_json: Option<PathBuf>,
    /// Adaptive steps: the local error allowed per step (m). It sets the step sizes (between
    /// 1e-6 s and min(0.5 s, output interval, horizon), starting from the scene's step) and
    /// the projection accuracy ε_k = max((θ·tol)² (μ_k/μ_max)³, 2·10⁻⁷ μ_k²) with θ = 0.1
    /// (the floor: what the solvers certify in double precision). Without it, the scene's
    /// fixed step.
    #[arg(long, value_name = "METRES", allow_hyphen_values = true)]
    tol: Option<f64>,
    /// The error estimate of the adaptive steps (velocity: cheaper at equal error on the
    /// measured crowds, see the README's work–precision) [default: the scene's
    /// `time.estimate`, else velocity].
    #[arg(long, value_enum, requires = "tol")]
    estimate: Option<Estimate>,
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
            let mut scene = Scene::from_run_file(&text, &origin)?;
            scene.solver.threads = limits::threads_here(scene.solver.threads);
            Ok((scene, origin))
        }
        _ => bail!("give a scene file or --from RUN.h5"),
    }
}

fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// Checks the output and the summary paths before anything is read or written: an output or
/// a summary never replaces an input (the scene, the --from file) or each other, and a summary
/// obeys the same rules as the output (its directory exists, --force to replace it).
fn check_paths(args: &RunArgs, overwrite: Overwrite) -> Result<()> {
    let inputs: Vec<(&str, &PathBuf)> = [("the scene file", &args.scene), ("--from", &args.from)]
        .into_iter()
        .filter_map(|(what, p)| p.as_ref().map(|p| (what, p)))
        .collect();
    if let Some(path) = &args.output {
        // Before the (possibly long) set-up: a bad path fails at once.
        moreau_io::check_output(path, overwrite)?;
        if let Some((what, _)) = inputs.iter().find(|(_, i)| moreau_io::same_file(path, i)) {
            bail!(
                "--output '{}' is {what}: a run never writes over its input",
                path.display()
            );
        }
    }
    if let Some(summary) = &args.summary_json
        && summary.as_os_str() != "-"
    {
        if let Some((what, _)) = inputs
            .iter()
            .find(|(_, i)| moreau_io::same_file(summary, i))
        {
            bail!(
                "--summary-json '{}' is {what}: a run never writes over its input",
                summary.display()
            );
        }
        if let Some(out) = &args.output
            && moreau_io::same_file(summary, out)
        {
            bail!(
                "--summary-json '{}' is the --output file: give the summary its own file",
                summary.display()
            );
        }
        moreau_io::check_output(summary, overwrite).map_err(|e| match e {
            moreau_io::IoError::Exists { path } => anyhow::anyhow!(
                "--summary-json file '{}' already exists; pass --force to overwrite it",
                path.display()
            ),
            other => anyhow::Error::from(other).context("--summary-json"),
        })?;
    }
    Ok(())
}

/// SIGINT and SIGTERM, caught for the run: the first one stops the run after its step, and the
/// run file is finished with status `interrupted`; a second one ends the process at once.
struct Signals {
    int: Arc<AtomicBool>,
    term: Arc<AtomicBool>,
}

impl Signals {
    fn install() -> Result<Self> {
        use signal_hook::consts::{SIGINT, SIGTERM};
        use signal_hook::flag::{register, register_conditional_shutdown};
        let me = Self {
            int: Arc::new(AtomicBool::new(false)),
            term: Arc::new(AtomicBool::new(false)),
        };
        // The shutdown hooks see the flag before the flag hooks set it: only the second
        // signal ends the process.
        register_conditional_shutdown(SIGINT, 130, Arc::clone(&me.int))?;
        register_conditional_shutdown(SIGTERM, 143, Arc::clone(&me.term))?;
        register(SIGINT, Arc::clone(&me.int))?;
        register(SIGTERM, Arc::clone(&me.term))?;
        Ok(me)
    }

    /// The signal that arrived, if any.
    fn caught(&self) -> Option<Interrupted> {
        if self.int.load(Ordering::Relaxed) {
            Some(Interrupted("SIGINT"))
        } else if self.term.load(Ordering::Relaxed) {
            Some(Interrupted("SIGTERM"))
        } else {
            None
        }
    }
}

/// The status a run file ends with for a run that ended with `outcome`.
fn status_of(outcome: &Result<(), moreau_crowd::CrowdError>) -> (String, Option<Interrupted>) {
    match outcome {
        Ok(()) => ("complete".into(), None),
        Err(moreau_crowd::CrowdError::Observer(e)) if e.downcast_ref::<Interrupted>().is_some() => {
            (
                "interrupted".into(),
                e.downcast_ref::<Interrupted>().copied(),
            )
        }
        // The moving geometry left no room: an answer about the scene, not a failure of the
        // program (the error names the people and bodies; the file keeps every frame so far).
        Err(moreau_crowd::CrowdError::Infeasible(_)) => ("infeasible".into(), None),
        Err(e) => (failed_status(&format!("{e:#}")), None),
    }
}

/// `failed: …`, and `failed: disk full: …` when the system said so.
fn failed_status(error: &str) -> String {
    if error.contains("No space left on device") || error.contains("errno = 28") {
        format!("failed: disk full: {error}")
    } else {
        format!("failed: {error}")
    }
}

/// A new run: the scene (file, or stored in --from), its simulation and its writer.
fn started(
    args: &RunArgs,
    overwrite: Overwrite,
) -> Result<(Simulation, Option<RunWriter>, String)> {
    let (mut scene, origin) = load_scene(args)?;
    if let Some(tol) = args.tol {
        // The scene's own estimate stays unless --estimate names another (--tol alone put
        // the flag's default in place of a scene's `step-doubling`).
        let estimate = args.estimate.unwrap_or(match scene.time.estimate {
            Some(ErrorEstimate::StepDoubling) => Estimate::Doubling,
            _ => Estimate::Velocity,
        });
        scene = adaptive(&scene, tol, estimate);
        scene.validate().context("--tol")?;
    }
    let sim = Simulation::new(scene).with_context(|| format!("scene {origin}"))?;
    let people = sim.total_people();
    if sim
        .frame()
        .ids
        .iter()
        .enumerate()
        .any(|(k, &id)| id as usize != k)
    {
        bail!("internal: people are not numbered 0..{people} at the start");
    }
    let writer = match &args.output {
        Some(path) => {
            let header = moreau_record::header(&sim, command_line());
            Some(RunWriter::create(path, &header, overwrite)?)
        }
        None => None,
    };
    Ok((sim, writer, origin))
}

/// A killed run taken up again: the scene stored in its partial file, the simulation restored
/// to the state saved with its last frame, the writer cut back to that frame.
fn resumed(
    out: &Path,
    overwrite: Overwrite,
) -> Result<(Simulation, Option<RunWriter>, String, String)> {
    // The run ends by moving its file to `out`: an existing file there is replaced only with
    // --force, and that is known now, not after the run (when there is a run to go on with).
    if moreau_io::partial_path(out).is_file() {
        moreau_io::check_output(out, overwrite)?;
    }
    let r = RunWriter::resume(out, overwrite)?;
    let origin = format!("{} (resumed)", r.writer.partial().display());
    let mut scene = Scene::from_run_file(&r.header.scene, &origin)?;
    // (Saved on a machine with more cores: goes on with what this one has.)
    scene.solver.threads = limits::threads_here(scene.solver.threads);
    let mut sim = Simulation::new(scene).with_context(|| format!("scene {origin}"))?;
    let state =
        SimState::from_bytes(&r.state).with_context(|| format!("the state saved in {origin}"))?;
    sim.restore(&state)
        .with_context(|| format!("restoring the state saved in {origin}"))?;
    // The summary's scene: the run's file (its partial name is gone when the run ends).
    let origin = format!("{} (resumed)", out.display());
    Ok((sim, Some(r.writer), origin, r.note))
}

/// Runs `moreau run`. Errors before the run starts are returned (exit 2, nothing written);
/// a failure during the run is reported, recorded in the file, and gives exit code 1; a run
/// stopped by SIGINT or SIGTERM is finished with status `interrupted` (exit 130, 143).
pub fn run(args: &RunArgs) -> Result<ExitCode> {
    let overwrite = if args.force {
        Overwrite::Allowed
    } else {
        Overwrite::Never
    };
    check_paths(args, overwrite)?;
    // Caught before the output is created: a signal in the first milliseconds ended the
    // process with its default action, leaving a partial file nothing could open.
    let signals = Signals::install()?;
    let (mut sim, writer, origin, totals) = match &args.resume {
        Some(out) => resumed(out, overwrite)?,
        None => {
            let (sim, writer, origin) = started(args, overwrite)?;
            (sim, writer, origin, String::new())
        }
    };
    let people = sim.total_people();
    let output = args.output.as_ref().or(args.resume.as_ref());
    // The file is written on a thread of its own: the steps do not wait for the disk.
    let mut writer = writer.map(BackgroundWriter::new);

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
    let mut unmet = moreau_crowd::ToleranceWarning::new(&sim.scene().time);
    // The steps counted before this process's first (a resumed run's totals): the rate is
    // this process's steps over its time.
    let mut steps_before: Option<usize> = None;
    let mut progress = |report: &moreau_core::StepReport, stats: &moreau_core::RunStats, left| {
        // SIGINT or SIGTERM: stop after this step (the file is finished as interrupted).
        if let Some(signal) = signals.caught() {
            return Err(Box::new(signal) as moreau_crowd::ObserverError);
        }
        // A step accepted above the tolerance is one at the smallest step: a tolerance this
        // small keeps the run at that step (hours for a long horizon). Said once, not fatal.
        if let Some(message) = unmet.first(report) {
            bar.suspend(|| eprintln!("moreau: warning: {message}"));
        }
        if !bar.is_hidden() {
            bar.set_position((report.t * 1e3).round() as u64);
            let before = *steps_before.get_or_insert(stats.steps.saturating_sub(1));
            let rate = (stats.steps - before) as f64 / bar.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!(
                "t = {:7.2} s  {:>8.1} steps/s  {left:>7} people left",
                report.t, rate,
            ));
        }
        Ok(())
    };
    // A resumed run goes on from the totals saved with its state: its summary is the whole
    // run's (it counted only the steps after the resume).
    let mut record = Record::new(writer.as_mut().map(|w| w as &mut dyn RunSink), people)
        .resuming(&totals)
        .with_progress(&mut progress);
    let outcome = moreau_record::run_to_horizon(&mut sim, &mut record);
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();

    let (status, interrupted) = status_of(&outcome);
    let summary = Summary::new(
        &sim,
        &record,
        origin,
        output.map(|p| p.display().to_string()),
        status.clone(),
        wall,
    );
    let stats = &record.stats;
    let json = summary.to_json();
    // People a source could not place are in no frame and no count but this one.
    if let Some(message) = summary.waiting_warning() {
        for line in message.lines() {
            eprintln!("moreau: warning: {line}");
        }
    }
    let mut failed: Option<anyhow::Error> = match interrupted {
        Some(_) => None,
        None => outcome.err().map(anyhow::Error::from),
    };
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
            "{}: {} people, {} steps in {:.2} s ({:.2} ms/step); {} passed an exit; \
             {:.0} solver iterations/step; max certified ε {:.2e} m², max violation {:.2e} m{}",
            summary.scene,
            // Everyone in the run, those from sources too (the count at the start said 0 for
            // a scene of sources only, where the summary said 6).
            summary.people,
            stats.steps,
            summary.wall_seconds,
            summary.ms_per_step,
            summary.passed_exit,
            summary.iterations_per_step,
            stats.max_eps,
            stats.max_violation,
            output
                .as_ref()
                .map_or(String::new(), |p| format!("; wrote {}", p.display())),
        );
    }
    if let Some(signal) = interrupted {
        eprintln!(
            "moreau: {signal} at simulated time {} s{}",
            Num(sim.time()),
            output.map_or(String::new(), |p| format!(
                "; '{}' holds the run so far (status interrupted)",
                p.display()
            ))
        );
        if let Some(e) = &failed {
            eprintln!("moreau: error: {}", crate::error_text(e));
        }
        return Ok(ExitCode::from(if signal.0 == "SIGINT" { 130 } else { 143 }));
    }
    match failed {
        None => Ok(ExitCode::SUCCESS),
        Some(e) => {
            eprintln!(
                "moreau: error: {} (simulated time reached: {} s)",
                crate::error_text(&e),
                Num(sim.time())
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
    // Whole or not at all (checked before the run: replacing an existing file was allowed
    // with --force).
    write_whole(target, format!("{json}\n").as_bytes())
        .with_context(|| format!("writing the summary to '{}'", target.display()))
}

/// Writes `bytes` to `target` whole or not at all: beside it, then moved over it; nothing is
/// left beside it on failure.
pub(crate) fn write_whole(target: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let name = target
        .file_name()
        .map_or("file".into(), |n| n.to_string_lossy());
    let temporary = target.with_file_name(format!(".{name}.{}.partial", std::process::id()));
    let written =
        std::fs::write(&temporary, bytes).and_then(|()| std::fs::rename(&temporary, target));
    if written.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    written
}
