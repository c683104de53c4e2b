//! What the convergence and work–precision studies share: a run sampled at `t_i = i T / K`
//! (everyone's position by id, the people through an exit), what it cost, and error (24).

use std::time::Instant;

use anyhow::{Result, ensure};
use moreau_core::{RunStats, StepReport};
use moreau_crowd::{
    ExitRecord, Frame, Observer, ObserverError, Scene, Simulation, ToleranceWarning,
};

use crate::run::{Estimate, adaptive};

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
    /// Whether person `id` passed an exit by each `t_i` (`[i][id]`).
    pub passed_by_id: Vec<Vec<bool>>,
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

/// Collects everyone's position by id at every frame (the sampling times), and the steps.
struct Samples {
    people: usize,
    leaving: Leaving,
    states: Vec<Vec<f64>>,
    passed: Vec<usize>,
    passed_by_id: Vec<Vec<bool>>,
    through: Vec<bool>,
    exits: usize,
    stats: RunStats,
    /// The one warning that adaptive steps miss `time.tol`.
    unmet: ToleranceWarning,
}

/// Whether a study accepts people who leave the scene at an exit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Leaving {
    /// Everyone must stay (error (24) compares everyone at every `t_i`).
    Refused,
    /// People may leave (their positions are NaN from then on).
    Allowed,
}

impl Observer for Samples {
    fn step(&mut self, report: &StepReport) -> Result<(), ObserverError> {
        self.stats.add(report);
        // As `moreau run` says it: a tolerance no step meets keeps the run at the smallest
        // step, for hours on a long horizon.
        if let Some(message) = self.unmet.first(report) {
            eprintln!("moreau: warning: {message}");
        }
        Ok(())
    }
    fn exit(&mut self, record: &ExitRecord) -> Result<(), ObserverError> {
        self.exits += 1;
        if let Some(p) = self.through.get_mut(record.id as usize) {
            *p = true;
        }
        Ok(())
    }
    fn frame(&mut self, f: &Frame<'_>) -> Result<(), ObserverError> {
        if self.leaving == Leaving::Refused && f.ids.len() != self.people {
            return Err(format!(
                "people left the scene at t = {}: the study compares everyone at every t_i, use \
                 exits with action = \"continue\"",
                moreau_core::Num(f.t)
            )
            .into());
        }
        let mut q = vec![0.0; 2 * self.people];
        f.positions_by_id(&mut q);
        self.states.push(q);
        self.passed.push(self.exits);
        self.passed_by_id.push(self.through.clone());
        Ok(())
    }
}

/// Runs `scene` with `how`, sampled `samples` times; unless `leaving` allows it, everyone must
/// stay in the scene (exits with `action = "continue"`) so that runs compare person by person.
/// The studies compare the same people from run to run; people from a scene's sources enter
/// at step times, so at other times in each run, and were left out of the comparison
/// (`converge --count in-room` said 0 people and an error of 0 on a scene of sources only).
/// Refused until they are compared.
pub fn refuse_sources(scene: &Scene) -> Result<()> {
    ensure!(
        scene.sources.is_empty(),
        "the scene has [[sources]] ({}): the studies compare the people at the start from run to \
         run, and do not compare people who enter yet",
        scene
            .sources
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}

pub fn sample(scene: &Scene, how: &How, samples: usize, leaving: Leaving) -> Result<Sampled> {
    ensure!(samples >= 1, "--samples must be ≥ 1");
    let mut scene = scene.clone();
    let interval = scene.time.horizon / samples as f64;
    scene.time.output_interval = interval;
    match how {
        How::Fixed(h) => {
            let per = interval / h;
            ensure!(
                (per - per.round()).abs() < 1e-9 && per.round() >= 1.0,
                "step {} does not divide the sampling interval {} (T / samples)",
                moreau_core::Num(*h),
                moreau_core::Num(interval)
            );
            scene.time.step = *h;
            scene.time.tol = None;
        }
        How::Adaptive(tol, estimate) => scene = adaptive(&scene, *tol, *estimate),
    }
    let mut sim = Simulation::new(scene)?;
    let mut samples_seen = Samples {
        people: sim.total_people(),
        leaving,
        states: Vec::new(),
        passed: Vec::new(),
        passed_by_id: Vec::new(),
        through: vec![false; sim.total_people()],
        exits: 0,
        stats: RunStats::default(),
        unmet: ToleranceWarning::new(&sim.scene().time),
    };
    let start = Instant::now();
    sim.run(&mut samples_seen)?;
    let wall = start.elapsed().as_secs_f64();
    let Samples {
        states,
        passed,
        passed_by_id,
        stats,
        ..
    } = samples_seen;
    ensure!(
        states.len() == samples + 1,
        "expected {} states, got {}",
        samples + 1,
        states.len()
    );
    Ok(Sampled {
        states,
        passed,
        passed_by_id,
        steps: stats.steps,
        rejected: stats.rejected,
        iterations: stats.iterations,
        max_eps: stats.max_eps,
        max_violation: stats.max_violation,
        wall,
    })
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

/// Error (24) restricted to the people still in the room: at each `t_i`, those who have
/// passed no exit in either run; with the largest distance of one of them, and the largest
/// number of people who had passed an exit in one run but not in the other.
pub fn error_in_room(reference: &Sampled, run: &Sampled) -> (f64, f64, usize) {
    let (mut whole, mut person, mut mismatch) = (0.0f64, 0.0f64, 0usize);
    let rows = reference
        .states
        .iter()
        .zip(&run.states)
        .zip(reference.passed_by_id.iter().zip(&run.passed_by_id))
        .skip(1);
    for ((a, b), (pa, pb)) in rows {
        let mut d2 = 0.0;
        let mut differ = 0;
        for id in 0..pa.len() {
            if pa[id] != pb[id] {
                differ += 1;
            }
            if pa[id] || pb[id] {
                continue;
            }
            let d = (a[2 * id] - b[2 * id]).powi(2) + (a[2 * id + 1] - b[2 * id + 1]).powi(2);
            d2 += d;
            person = person.max(d.sqrt());
        }
        whole = whole.max(d2.sqrt());
        mismatch = mismatch.max(differ);
    }
    (whole, person, mismatch)
}
