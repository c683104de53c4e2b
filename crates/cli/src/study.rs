//! What the convergence and work–precision studies share: a run sampled at `t_i = i T / K`
//! (everyone's position by id, the people through an exit), what it cost, and error (24).

use std::time::Instant;

use anyhow::{Result, ensure};
use moreau_core::StepReport;
use moreau_crowd::{Scene, Simulation};

use crate::run::{Estimate, controller};

/// How a run chooses its steps.
pub enum How {
    /// Fixed steps of this size (it must divide `T / K`).
    Fixed(f64),
    /// Adaptive steps with this tolerance and estimate.
    Adaptive(f64, Estimate),
}

/// One run sampled at `t_i = i T / K`, `i = 0..=K`, and its cost.
pub struct Sampled {
    /// Positions `[x0, y0, …]` by person id at each `t_i`.
    pub states: Vec<Vec<f64>>,
    /// People through an exit by each `t_i`.
    pub passed: Vec<usize>,
    /// Accepted steps.
    pub steps: usize,
    /// Rejected trial steps (adaptive runs).
    pub rejected: usize,
    /// Solver iterations in all.
    pub iterations: usize,
    /// Largest certified ε.
    pub max_eps: f64,
    /// Largest violation.
    pub max_violation: f64,
    /// Wall time of the stepping (s).
    pub wall: f64,
}

/// Runs `scene` with `how`, sampled `samples` times; everyone must stay in the scene
/// (exits with `action = "continue"`) so that runs compare person by person.
pub fn sample(scene: &Scene, how: &How, samples: usize) -> Result<Sampled> {
    ensure!(samples >= 1, "--samples must be ≥ 1");
    let mut scene = scene.clone();
    let interval = scene.time.horizon / samples as f64;
    scene.time.output_interval = interval;
    if let How::Fixed(h) = how {
        let per = interval / h;
        ensure!(
            (per - per.round()).abs() < 1e-9 && per.round() >= 1.0,
            "step {h} does not divide the sampling interval {interval} (T / samples)"
        );
        scene.time.step = *h;
    }
    let mut sim = Simulation::new(scene.clone())?;
    let n = sim.total_people();
    let grab = |sim: &Simulation| -> Result<Vec<f64>> {
        let f = sim.frame();
        ensure!(
            f.ids.len() == n,
            "people left the scene at t = {}: the study compares everyone at every t_i, use \
             exits with action = \"continue\"",
            f.t
        );
        let mut q = vec![0.0; 2 * n];
        for (k, &id) in f.ids.iter().enumerate() {
            q[2 * id as usize] = f.positions[2 * k];
            q[2 * id as usize + 1] = f.positions[2 * k + 1];
        }
        Ok(q)
    };
    let start = Instant::now();
    let mut out = Sampled {
        states: vec![grab(&sim)?],
        passed: vec![0],
        steps: 0,
        rejected: 0,
        iterations: 0,
        max_eps: 0.0,
        max_violation: 0.0,
        wall: 0.0,
    };
    let count = |out: &mut Sampled, r: &StepReport| {
        out.steps += 1;
        out.iterations += r.iterations;
        out.max_eps = out.max_eps.max(r.eps);
        out.max_violation = out.max_violation.max(r.violation);
    };
    match how {
        How::Fixed(_) => {
            for (mu, frame) in sim.schedule() {
                let r = sim.step(mu)?;
                count(&mut out, &r);
                if frame {
                    out.states.push(grab(&sim)?);
                    out.passed.push(sim.exit_times().len());
                }
            }
        }
        How::Adaptive(tol, estimate) => {
            let mut c = controller(&scene, *tol, *estimate)?;
            for i in 1..=samples {
                let next = (i as f64 * interval).min(scene.time.horizon);
                while sim.time() < next {
                    let s = sim.step_adaptive(&mut c, next)?;
                    count(&mut out, &s.report);
                    out.rejected += s.rejected;
                }
                out.states.push(grab(&sim)?);
                out.passed.push(sim.exit_times().len());
            }
        }
    }
    out.wall = start.elapsed().as_secs_f64();
    ensure!(
        out.states.len() == samples + 1,
        "expected {} states, got {}",
        samples + 1,
        out.states.len()
    );
    Ok(out)
}

/// Error (24) of Bernicot & Venel: `max_{i ≥ 1} |q_ref(t_i) − q(t_i)|` (Euclidean, all
/// coordinates), and the largest distance of one person to their reference position.
pub fn error(reference: &[Vec<f64>], states: &[Vec<f64>]) -> (f64, f64) {
    let (mut whole, mut person) = (0.0f64, 0.0f64);
    for (a, b) in reference.iter().zip(states).skip(1) {
        let mut d2 = 0.0;
        for (pa, pb) in a.chunks(2).zip(b.chunks(2)) {
            let d = (pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2);
            d2 += d;
            person = person.max(d.sqrt());
        }
        whole = whole.max(d2.sqrt());
    }
    (whole, person)
}
