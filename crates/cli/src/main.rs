//! The `moreau` driver binary: runs crowd scenes and the papers' examples.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use moreau_core::{FnField, HalfSpace, HalfSpaces};
use moreau_integrate::{EpsPolicy, LinearizedProjection, LinearizedSettings, Scheme, StepSequence};
use moreau_solve::{Apgd, ApgdSettings};

/// moreau: Moreau's catching-up scheme for first-order nonsmooth dynamics.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Runs a crowd scene to its horizon and prints a summary (HDF5 output comes next).
    Run {
        /// The scene file (TOML).
        scene: std::path::PathBuf,
        /// Print nothing but the final summary.
        #[arg(long)]
        quiet: bool,
    },
    /// Example 8.1 of Cao & Saoud: x' ∈ −a x + b − A(x) on C = [0, ∞), errors against the
    /// closed form for halving steps and the observed order.
    Example81 {
        /// The decay rate a > 0.
        #[arg(long, default_value_t = 1.0)]
        a: f64,
        /// The forcing b (b < 0 makes the boundary invariant).
        #[arg(long, default_value_t = -1.0, allow_hyphen_values = true)]
        b: f64,
        /// The initial state x0 ≥ 0.
        #[arg(long, default_value_t = 1.0)]
        x0: f64,
        /// The largest step; the table halves it six times.
        #[arg(long, default_value_t = 0.1)]
        h: f64,
        /// The horizon.
        #[arg(long, default_value_t = 3.0)]
        t_end: f64,
    },
}

fn exact_8_1(a: f64, b: f64, x0: f64, t: f64) -> f64 {
    let k = a + 1.0;
    let xs = b / k;
    if b < 0.0 && (x0 <= 0.0 || t >= ((x0 - xs) / -xs).ln() / k) {
        return 0.0;
    }
    xs + (x0 - xs) * (-k * t).exp()
}

fn example_8_1(a: f64, b: f64, x0: f64, h0: f64, t_end: f64) -> Result<()> {
    anyhow::ensure!(a > 0.0, "a must be > 0, got {a}");
    anyhow::ensure!(x0 >= 0.0, "x0 must be in C = [0, ∞), got {x0}");
    println!(
        "{:>12} {:>8} {:>14} {:>8} {:>12} {:>12}",
        "h", "steps", "max error", "order", "iterations", "max eps"
    );
    let mut prev: Option<(f64, f64)> = None;
    for j in 0..7 {
        let h = h0 / 2f64.powi(j);
        let field = FnField::new(1, move |_t, x: &[f64], out: &mut [f64]| {
            out[0] = -(a + 1.0) * x[0] + b
        });
        let half_line = HalfSpaces::new(vec![HalfSpace::new(vec![-1.0], 0.0)?])?;
        let correction = LinearizedProjection::new(
            half_line,
            Apgd::new(ApgdSettings::default())?,
            LinearizedSettings::default(),
        )?;
        let mut scheme = Scheme::new(field, correction, EpsPolicy::default());
        let mut x = [x0];
        let (mut err, mut iters, mut eps, mut steps) = (0.0_f64, 0usize, 0.0_f64, 0usize);
        scheme
            .run(0.0, &mut x, &StepSequence::Fixed { h, t_end }, |r, x| {
                err = err.max((x[0] - exact_8_1(a, b, x0, r.t)).abs());
                iters += r.iterations;
                eps = eps.max(r.eps);
                steps += 1;
            })
            .with_context(|| format!("run with h = {h}"))?;
        let order = prev.map_or(String::from("-"), |(ph, pe)| {
            format!("{:.3}", (pe / err).ln() / (ph / h).ln())
        });
        println!("{h:>12.6} {steps:>8} {err:>14.6e} {order:>8} {iters:>12} {eps:>12.2e}");
        prev = Some((h, err));
    }
    Ok(())
}

fn run_scene(path: &std::path::Path, quiet: bool) -> Result<()> {
    let scene = moreau_crowd::Scene::from_file(path)?;
    let mut sim = moreau_crowd::Simulation::new(scene)?;
    let start = std::time::Instant::now();
    let (mut steps, mut iterations, mut max_violation, mut max_eps, mut redone) =
        (0usize, 0usize, 0.0f64, 0.0f64, 0usize);
    let total = sim.total_people();
    let every = (1.0 / sim.scene().time.output_interval).round().max(1.0) as usize;
    let mut frame = 0usize;
    sim.run(
        |r| {
            steps += 1;
            iterations += r.iterations;
            max_violation = max_violation.max(r.violation);
            max_eps = max_eps.max(r.eps);
            redone += r.redone;
        },
        |f| {
            if !quiet && frame.is_multiple_of(every) {
                println!("t = {:6.2} s  people in scene {:5}", f.t, f.ids.len());
            }
            frame += 1;
        },
    )?;
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{}: {total} people, {steps} steps in {secs:.2} s ({:.2} ms/step, broad phase {:?}); {} passed an exit; \
         {:.0} solver iterations/step; max certified ε {max_eps:.2e} m², max violation {max_violation:.2e} m; {redone} steps redone",
        path.display(),
        1e3 * secs / steps.max(1) as f64,
        sim.broad_phase(),
        sim.exit_times().len(),
        iterations as f64 / steps.max(1) as f64,
    );
    Ok(())
}

fn run() -> Result<ExitCode> {
    let cli = Cli::parse();
    match cli.command {
        Command::Run { scene, quiet } => run_scene(&scene, quiet)?,
        Command::Example81 { a, b, x0, h, t_end } => example_8_1(a, b, x0, h, t_end)?,
    }
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    match run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("moreau: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
