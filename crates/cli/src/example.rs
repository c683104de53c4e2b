//! `moreau example81`: Example 8.1 of Cao & Saoud against its closed form.

use anyhow::{Context, Result};
use moreau_core::{FnField, HalfSpace, HalfSpaces};
use moreau_integrate::{EpsPolicy, LinearizedProjection, LinearizedSettings, Scheme, StepSequence};
use moreau_solve::{Apgd, ApgdSettings};

fn exact_8_1(a: f64, b: f64, x0: f64, t: f64) -> f64 {
    let k = a + 1.0;
    let xs = b / k;
    if b < 0.0 && (x0 <= 0.0 || t >= ((x0 - xs) / -xs).ln() / k) {
        return 0.0;
    }
    xs + (x0 - xs) * (-k * t).exp()
}

pub fn example_8_1(a: f64, b: f64, x0: f64, h0: f64, t_end: f64) -> Result<()> {
    anyhow::ensure!(a > 0.0, "a must be > 0, got {a}");
    anyhow::ensure!(x0 >= 0.0, "x0 must be in C = [0, ∞), got {x0}");
    anyhow::ensure!(
        h0 > 0.0 && h0.is_finite(),
        "--h must be finite and > 0, got {h0}"
    );
    anyhow::ensure!(
        t_end > 0.0 && t_end.is_finite(),
        "--t-end must be finite and > 0, got {t_end}"
    );
    // The table halves h six times: its finest run takes 64 t_end / h steps.
    let steps = 64.0 * t_end / h0;
    anyhow::ensure!(
        steps <= moreau_integrate::MAX_STEPS,
        "--t-end {t_end} with --h {h0}: the finest run of the table (h / 64) would take \
         {steps:.3e} steps, more than the limit of {:e} steps a run",
        moreau_integrate::MAX_STEPS
    );
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
        let mut half_line = HalfSpaces::new(vec![HalfSpace::new(vec![-1.0], 0.0)?])?;
        let correction = LinearizedProjection::new(
            Apgd::new(ApgdSettings::default())?,
            LinearizedSettings::default(),
        )?;
        let mut scheme = Scheme::new(correction, EpsPolicy::default());
        let mut x = [x0];
        let (mut err, mut iters, mut eps, mut steps) = (0.0_f64, 0usize, 0.0_f64, 0usize);
        scheme
            .run(
                &field,
                &mut half_line,
                0.0,
                &mut x,
                &StepSequence::Fixed { h, t_end },
                |r, x| {
                    err = err.max((x[0] - exact_8_1(a, b, x0, r.t)).abs());
                    iters += r.iterations;
                    eps = eps.max(r.eps);
                    steps += 1;
                },
            )
            .with_context(|| format!("run with h = {h}"))?;
        let order = prev.map_or(String::from("-"), |(ph, pe)| {
            format!("{:.3}", (pe / err).ln() / (ph / h).ln())
        });
        println!("{h:>12.6} {steps:>8} {err:>14.6e} {order:>8} {iters:>12} {eps:>12.2e}");
        prev = Some((h, err));
    }
    Ok(())
}
