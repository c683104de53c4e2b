//! The `moreau` driver binary: runs crowd scenes to HDF5, inspects run files, and runs the
//! papers' examples. It translates between the command line, the crates and the files; it
//! does not simulate.

mod bench;
mod converge;
mod example;
mod run;
mod study;
mod svg;
mod tradeoff;
mod view;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

const EXIT_CODES: &str = "\
Exit codes:
  0    the run reached its horizon (or the command succeeded)
  1    the run failed: it stopped before its horizon (a step failed, or writing the output
       failed; the output keeps every whole frame written so far and its attribute `status`
       says why, e.g. `failed: disk full: ...`), or its summary could not be written
  2    bad input: command line, scene file, or output path; nothing was written
  130  interrupted by SIGINT (Ctrl-C), 143 by SIGTERM: the run stopped after its step and
       the output holds it so far, with status `interrupted` (a second signal ends at once)

The output is written as .NAME.partial beside NAME and moved to NAME when the run ends (or is
interrupted): an older NAME stays whole until then. A run killed outright (SIGKILL, power
loss) leaves its frames in .NAME.partial (status `running`), which `moreau inspect`, h5py and
PedPy open; a later run to NAME refuses to replace it without --force.";

const TRADEOFF_EXIT_CODES: &str = "\
Exit codes:
  0    every run reached its horizon; tradeoff.json, .md and .svg written
  1    a run failed (e.g. a projection its solver could not certify): it is in tradeoff.json
       and tradeoff.md as failed, with why, and left out of the plot; the others were run
  2    bad input (command line, scene file, output directory), or the reference run failed

The three files are rewritten after each run: an interrupted study keeps the runs it measured.";

const CONVERGE_EXIT_CODES: &str = "\
Exit codes:
  0    every run reached the horizon; converge.json, .md and .svg written
  1    a run failed (e.g. a step that does not divide T / samples, or a projection its solver
       could not certify): it is in converge.json (error null) and converge.md as failed, with
       why, and left out of the fits and the plot; the others were run
  2    bad input (command line, scene file, output directory), or the reference run failed

The three files are rewritten after each run: an interrupted study keeps the runs it measured.";

/// moreau: Moreau's catching-up scheme for first-order nonsmooth dynamics, with crowds of
/// rigid disks that never overlap.
#[derive(Debug, Parser)]
#[command(name = "moreau", version, long_about = None, after_help = EXIT_CODES)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Runs a crowd scene to its horizon, writing an HDF5 run file as it goes.
    ///
    /// The file is flushed at every output frame: a run killed at any moment leaves a file
    /// that h5py and PedPy open up to its last frame. A progress bar (simulated time,
    /// steps/s, people left, ETA) shows on a terminal.
    #[command(after_help = EXIT_CODES)]
    Run(run::RunArgs),
    /// The convergence experiment of Bernicot & Venel §5: error (24) of each step size
    /// against a fine reference, the fitted order, as JSON, Markdown and a log–log SVG. A run
    /// that fails is recorded as failed and the others still run (exit status 1).
    #[command(after_help = CONVERGE_EXIT_CODES)]
    Converge(converge::ConvergeArgs),
    /// Work–precision: error against wall time for fixed steps, adaptive steps at several
    /// tolerances and each solver, against a fine reference; JSON, Markdown and SVG. A run
    /// that fails is recorded as failed and the others still run (exit status 1).
    #[command(after_help = TRADEOFF_EXIT_CODES)]
    Tradeoff(tradeoff::TradeoffArgs),
    /// The scale table: dense evacuation halls of 10³…10⁶ people, per-step time and stages,
    /// iterations, certified ε, violation, peak memory; the cost exponent; Clarabel at 40k.
    Bench(bench::BenchArgs),
    /// Writes one self-contained HTML page that plays a run: walls, exits, people to scale
    /// coloured by speed or pressure, play/pause, speed, a time slider, the step's certified
    /// ε and violation per frame. No server, no network: open it in any browser.
    #[command(after_help = EXIT_CODES)]
    View(view::ViewArgs),
    /// Prints what a run file holds: the run, its status, datasets and attributes.
    #[command(after_help = EXIT_CODES)]
    Inspect {
        /// The run file (HDF5).
        file: PathBuf,
    },
    /// Example 8.2 of Cao & Saoud (dry friction in a box): explicit selection against
    /// semi-implicit prox, error and wall time for halving steps (work–precision table and SVG).
    Example82 {
        /// The largest step; the table halves it six times.
        #[arg(long, default_value_t = 0.1, allow_hyphen_values = true)]
        h: f64,
        /// The horizon.
        #[arg(long, default_value_t = 5.0, allow_hyphen_values = true)]
        t_end: f64,
        /// Directory for example82.md and example82.svg.
        #[arg(short, long, default_value = "out/example82")]
        out: PathBuf,
    },
    /// Example 8.1 of Cao & Saoud: x' ∈ −a x + b − A(x) on C = [0, ∞), errors against the
    /// closed form for halving steps and the observed order.
    Example81 {
        /// The decay rate a > 0.
        #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
        a: f64,
        /// The forcing b (b < 0 makes the boundary invariant).
        #[arg(long, default_value_t = -1.0, allow_hyphen_values = true)]
        b: f64,
        /// The initial state x0 ≥ 0.
        #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
        x0: f64,
        /// The largest step; the table halves it six times.
        #[arg(long, default_value_t = 0.1, allow_hyphen_values = true)]
        h: f64,
        /// The horizon.
        #[arg(long, default_value_t = 3.0, allow_hyphen_values = true)]
        t_end: f64,
    },
}

fn inspect(path: &std::path::Path) -> Result<()> {
    let f = moreau_io::RunFile::open(path)?;
    let partial = path
        .file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('.') && n.ends_with(".partial"));
    let h = f.header()?;
    let times = f.frame_times()?;
    let counts = f.frame_counts()?;
    let steps = f.steps()?;
    println!("{}", path.display());
    println!(
        "  scene {:?}, seed {}, written by moreau {}",
        h.scene_name, h.seed, h.version
    );
    let status = f.status()?;
    println!(
        "  status: {status}{}",
        if partial && status == "running" {
            " (a partial file: its run is still going, or was killed)"
        } else {
            ""
        }
    );
    println!(
        "  {} people; {} frames at {} fps{}; {} steps; {} passed an exit",
        h.radii.len(),
        times.len(),
        h.fps,
        match (times.first(), times.last(), counts.last()) {
            (Some(a), Some(b), Some(n)) => format!(
                " (t = {} .. {} s, {n} present at the end)",
                moreau_core::Num(*a),
                moreau_core::Num(*b)
            ),
            _ => String::new(),
        },
        steps.len(),
        exits_by_name(&f.exits()?, &h.exit_names),
    );
    if let Some(worst) = steps.iter().map(|s| s.violation).reduce(f64::max) {
        let eps = steps.iter().map(|s| s.eps).fold(0.0, f64::max);
        println!("  max certified ε {eps:.3e} m², max violation {worst:.3e} m");
    }
    if h.contacts {
        let contacts = f.contacts()?;
        let walls = contacts
            .iter()
            .filter(|c| {
                c.kind == moreau_io::ContactRow::PERSON_WALL
                    || c.kind == moreau_io::ContactRow::PERSON_MOVING_WALL
            })
            .count();
        match contacts.iter().max_by(|a, b| a.lambda.total_cmp(&b.lambda)) {
            Some(top) => println!(
                "  contacts: {} over {} frames ({walls} with walls or moving bodies); largest λ {:.3e} m/s \
                 (person {}, frame {}); pressure per person in /frames/pressure",
                contacts.len(),
                times.len(),
                top.lambda,
                top.a,
                top.frame
            ),
            None => println!("  contacts: recorded, none pushed"),
        }
    }
    println!("  command: {}", h.command);
    print!("{}", f.describe()?);
    Ok(())
}

fn run() -> Result<ExitCode> {
    let cli = Cli::parse();
    match cli.command {
        Command::Run(args) => run::run(&args),
        Command::Converge(args) => converge::converge(&args),
        Command::Bench(args) => bench::bench(&args).map(|()| ExitCode::SUCCESS),
        Command::Tradeoff(args) => tradeoff::tradeoff(&args),
        Command::View(args) => view::view(&args).map(|()| ExitCode::SUCCESS),
        Command::Inspect { file } => inspect(&file).map(|()| ExitCode::SUCCESS),
        Command::Example82 { h, t_end, out } => {
            example::example_8_2(h, t_end, &out).map(|()| ExitCode::SUCCESS)
        }
        Command::Example81 { a, b, x0, h, t_end } => {
            example::example_8_1(a, b, x0, h, t_end).map(|()| ExitCode::SUCCESS)
        }
    }
}

/// A command-line number that must be finite and > 0 (clap names the flag and the value).
pub fn positive(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x > 0.0 && x.is_finite() => Ok(x),
        Ok(_) => Err("must be finite and > 0".into()),
        Err(e) => Err(format!("not a number: {e}")),
    }
}

/// A count of at least one (crowd sizes, measured steps).
pub fn at_least_one(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("not a whole number: {e}")),
    }
}

/// A crowd size: at least one person, at most a scene's limit (`moreau bench --sizes
/// 18446744073709551615` measured every smaller size, minutes of them, before refusing it).
pub fn crowd_size(text: &str) -> Result<usize, String> {
    let n = at_least_one(text)?;
    if n as f64 > moreau_crowd::limits::MAX_PEOPLE {
        return Err(format!(
            "more than the limit of {:e} people a scene",
            moreau_crowd::limits::MAX_PEOPLE
        ));
    }
    Ok(n)
}

/// A crowd size, or 0 for none.
pub fn crowd_size_or_zero(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(0) => Ok(0),
        _ => crowd_size(text),
    }
}

/// An error with its causes, each said once (a cause whose text its parent already quotes,
/// as the OS's and HDF5's often are, is not repeated).
pub fn error_text(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

/// A closed standard output (`moreau inspect F | head -1`) ends the program quietly, as it
/// does `cat`: Rust's `println!` panics on a broken pipe; this hook turns that one panic into
/// a silent exit 0 and leaves every other panic to the default hook.
fn quiet_broken_pipes() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let message = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.starts_with("failed printing to stdout") && message.contains("Broken pipe") {
            std::process::exit(0);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_broken_pipes();
    match run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("moreau: error: {}", error_text(&e));
            ExitCode::from(2)
        }
    }
}

/// How many passed an exit, and through which when the file says (format `moreau-run/4`) and
/// there is more than one: `60 (door 35, back 25)`.
fn exits_by_name(exits: &[moreau_io::ExitRow], names: &[String]) -> String {
    let mut counts = vec![0usize; names.len()];
    for e in exits {
        if let Some(c) = usize::try_from(e.exit).ok().and_then(|i| counts.get_mut(i)) {
            *c += 1;
        }
    }
    if names.len() < 2 {
        return exits.len().to_string();
    }
    let each: Vec<String> = names
        .iter()
        .zip(&counts)
        .map(|(name, n)| format!("{name} {n}"))
        .collect();
    format!("{} ({})", exits.len(), each.join(", "))
}
