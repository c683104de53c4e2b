//! `moreau example81`: Example 8.1 of Cao & Saoud against its closed form.

use anyhow::{Context, Result};
use moreau_core::{FnField, HalfSpace, HalfSpaces, Num};
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
    // Numbers shown by `{:?}`: 1e-300, not three hundred digits.
    anyhow::ensure!(
        a > 0.0 && a.is_finite(),
        "--a must be finite and > 0, got {a:?}"
    );
    anyhow::ensure!(b.is_finite(), "--b must be finite, got {b:?}");
    anyhow::ensure!(
        x0 >= 0.0 && x0.is_finite(),
        "--x0 must be finite and in C = [0, ∞), got {x0:?}"
    );
    anyhow::ensure!(
        h0 > 0.0 && h0.is_finite(),
        "--h must be finite and > 0, got {h0:?}"
    );
    anyhow::ensure!(
        t_end > 0.0 && t_end.is_finite(),
        "--t-end must be finite and > 0, got {t_end:?}"
    );
    // The table halves h six times: its finest run takes 64 t_end / h steps.
    let steps = 64.0 * t_end / h0;
    anyhow::ensure!(
        steps <= moreau_integrate::MAX_STEPS,
        "--t-end {t_end:?} with --h {h0:?}: the finest run of the table (h / 64) would take \
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
            .with_context(|| format!("run with h = {}", Num(h)))?;
        let order = prev.map_or(String::from("-"), |(ph, pe)| {
            format!("{:.3}", (pe / err).ln() / (ph / h).ln())
        });
        println!(
            "{:>12} {steps:>8} {err:>14.6e} {order:>8} {iters:>12} {eps:>12.2e}",
            step_cell(h)
        );
        prev = Some((h, err));
    }
    Ok(())
}

/// A step in the examples' tables: six decimals as ever, or in a few characters (`1e300`,
/// `1e-9`) where six decimals would print every digit or nothing.
fn step_cell(h: f64) -> String {
    if (1e-4..1e6).contains(&h) {
        format!("{h:.6}")
    } else {
        Num(h).to_string()
    }
}

/// Example 8.2's data: `x' ∈ τ − K x − ∂ψ(x) − N_C(x)`, `ψ = Σ μ_i |x_i|`, `C = [−1, 1]³`.
const K_82: [[f64; 3]; 3] = [[2.0, 0.3, 0.0], [0.3, 1.0, 0.2], [0.0, 0.2, 1.5]];
const TAU_82: [f64; 3] = [5.0, 0.3, -1.2];
const MU_82: [f64; 3] = [0.5, 0.6, 0.4];
const X0_82: [f64; 3] = [0.0, 0.8, 0.5];

/// One run of Example 8.2 with fixed steps `h` to `t_end`: the states at the step times, the
/// wall time, and the solver iterations.
fn run_8_2(
    selection: moreau_integrate::Selection,
    h: f64,
    t_end: f64,
    kappa: f64,
) -> Result<(Vec<[f64; 3]>, f64, usize)> {
    use moreau_core::{BoxSet, SeparableAbs};
    let field = FnField::new(3, |_t, x: &[f64], out: &mut [f64]| {
        for i in 0..3 {
            out[i] = TAU_82[i] - (0..3).map(|j| K_82[i][j] * x[j]).sum::<f64>();
        }
    });
    let mut boxset = BoxSet::new(vec![-1.0; 3], vec![1.0; 3])?;
    let correction = LinearizedProjection::new(
        Apgd::new(ApgdSettings::default())?,
        LinearizedSettings {
            max_violation: 1e-10,
            max_redo: 0,
        },
    )?;
    let mut scheme = Scheme::new(correction, EpsPolicy::new(kappa, 3.0)?)
        .with_convex_part(Box::new(SeparableAbs::new(MU_82.to_vec())?), selection);
    let mut x = X0_82;
    let mut states = vec![X0_82];
    let mut iterations = 0;
    let start = std::time::Instant::now();
    scheme.run(
        &field,
        &mut boxset,
        0.0,
        &mut x,
        &StepSequence::Fixed { h, t_end },
        |r, x| {
            states.push([x[0], x[1], x[2]]);
            iterations += r.iterations;
        },
    )?;
    Ok((states, start.elapsed().as_secs_f64(), iterations))
}

/// Example 8.2's error: the largest distance to the reference over the step times, `k h`
/// (the reference's state `k × stride`) and `t_end`, where both runs end (a last step
/// shortened to it lies on neither grid). Until session 38 the time `t_end` was left out
/// where `h` does not divide it, so a step of `t_end` or more compared the start only: an
/// error of 0 and an order of NaN.
fn error_8_2(states: &[[f64; 3]], reference: &[[f64; 3]], stride: usize) -> f64 {
    let distance =
        |x: &[f64; 3], r: &[f64; 3]| (0..3).map(|i| (x[i] - r[i]).powi(2)).sum::<f64>().sqrt();
    let (Some((x_end, before)), Some(r_end)) = (states.split_last(), reference.last()) else {
        return 0.0;
    };
    before
        .iter()
        .enumerate()
        .filter_map(|(k, x)| reference.get(k * stride).map(|r| distance(x, r)))
        .fold(distance(x_end, r_end), f64::max)
}

/// `moreau example82`: Example 8.2 (dry friction in a box) by the explicit selection and by
/// the semi-implicit prox, error against a fine semi-implicit reference and wall time for
/// halving steps: one work–precision table and plot (DESIGN §6).
pub fn example_8_2(h0: f64, t_end: f64, out: &std::path::Path) -> Result<()> {
    use moreau_integrate::Selection;
    anyhow::ensure!(
        h0 > 0.0 && h0.is_finite(),
        "--h must be finite and > 0, got {h0:?}"
    );
    anyhow::ensure!(
        t_end > 0.0 && t_end.is_finite(),
        "--t-end must be finite and > 0, got {t_end:?}"
    );
    let levels = 7;
    let fine = 2usize.pow(levels + 2);
    let h_ref = h0 / fine as f64;
    // The reference's step is h / 512: from a step longer than the horizon it would be no
    // reference (`--h 1e300` compared every run with one step of `t_end`).
    anyhow::ensure!(
        h0 <= t_end,
        "--h {} is longer than --t-end {}: the reference run (h / {fine}) would not be fine",
        Num(h0),
        Num(t_end)
    );
    // The reference run takes `fine × t_end / h` steps.
    let steps = t_end / h_ref;
    anyhow::ensure!(
        steps <= moreau_integrate::MAX_STEPS,
        "--t-end {} with --h {}: the reference run (h / {fine}) would take {steps:.3e} steps, \
         more than the limit of {:e} steps a run",
        Num(t_end),
        Num(h0),
        moreau_integrate::MAX_STEPS
    );
    let (reference, _, _) =
        run_8_2(Selection::SemiImplicit, h_ref, t_end, 1e-6).context("the reference run")?;
    std::fs::create_dir_all(out).with_context(|| format!("creating '{}'", out.display()))?;
    let mut md = format!(
        "Example 8.2 of Cao & Saoud, T = {}, reference: semi-implicit with h = {h_ref:e}, \
         ε_k = 10⁻⁶ μ³; runs with ε_k = μ³. Error: max over the step times of |x_h − x_ref|.\n\n\
         | selection | h | steps | error | order | wall (s) | iterations |\n|---|---|---|---|---|---|---|\n",
        Num(t_end)
    );
    println!(
        "{:>14} {:>10} {:>7} {:>12} {:>7} {:>10} {:>10}",
        "selection", "h", "steps", "error", "order", "wall s", "iterations"
    );
    let mut series = Vec::new();
    for (name, selection) in [
        ("explicit", Selection::Explicit),
        ("semi-implicit", Selection::SemiImplicit),
    ] {
        let mut points = Vec::new();
        let mut prev: Option<(f64, f64)> = None;
        for j in 0..levels {
            let h = h0 / 2f64.powi(j as i32);
            let (states, wall, iterations) = run_8_2(selection, h, t_end, 1.0)
                .with_context(|| format!("{name}, h = {}", Num(h)))?;
            let error = error_8_2(&states, &reference, fine >> j);
            let order = match prev {
                Some((ph, pe)) if pe > 0.0 && error > 0.0 => {
                    format!("{:.2}", (pe / error).ln() / (ph / h).ln())
                }
                _ => "-".to_string(),
            };
            println!(
                "{name:>14} {:>10} {:>7} {error:>12.4e} {order:>7} {wall:>10.4} {iterations:>10}",
                step_cell(h),
                states.len() - 1
            );
            md.push_str(&format!(
                "| {name} | {} | {} | {error:.4e} | {order} | {wall:.4} | {iterations} |\n",
                Num(h),
                states.len() - 1
            ));
            points.push((wall.max(1e-6), error));
            prev = Some((h, error));
        }
        series.push(crate::svg::Series {
            name: name.into(),
            points,
            dashed: false,
        });
    }
    let plot = crate::svg::LogLog {
        title: "Example 8.2: work–precision, explicit selection against semi-implicit prox".into(),
        x_label: "wall time (s)".into(),
        y_label: "error".into(),
        series,
    };
    std::fs::write(out.join("example82.md"), md)?;
    std::fs::write(out.join("example82.svg"), plot.render())?;
    println!("wrote {}/example82.md, example82.svg", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::error_8_2;

    #[test]
    fn a_last_step_cut_short_was_left_out_of_example_8_2s_error() {
        // A run of steps h to t_end = 2.5 h against a reference of h / 2: states at 0, h, 2h
        // and t_end; the reference at 0, h/2, …, 2h and t_end (index 5). The state at t_end
        // matched the reference's index 3 × 2 = 6, which is past its end, and was dropped.
        let reference = [[0.0; 3], [9.0; 3], [1.0; 3], [9.0; 3], [2.0; 3], [3.0; 3]];
        let exact = [[0.0; 3], [1.0; 3], [2.0; 3], [3.0; 3]];
        assert_eq!(error_8_2(&exact, &reference, 2), 0.0);
        let off_at_end = [[0.0; 3], [1.0; 3], [2.0; 3], [3.0, 3.0, 3.5]];
        assert_eq!(error_8_2(&off_at_end, &reference, 2), 0.5);
        let off_before = [[0.0; 3], [1.0, 1.25, 1.0], [2.0; 3], [3.0; 3]];
        assert_eq!(error_8_2(&off_before, &reference, 2), 0.25);
        // One step of the whole span: the start and the end.
        assert_eq!(error_8_2(&[[0.0; 3], [3.0, 3.0, 4.0]], &reference, 6), 1.0);
    }
}
