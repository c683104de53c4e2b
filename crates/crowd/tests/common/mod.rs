//! Checks shared by the crowd tests, computed independently of the crate's broad phase and
//! solvers: overlaps by a plain hash of cells, and each step's answer against Clarabel.
#![allow(dead_code)]

use std::collections::HashMap;

use moreau_core::StepReport;
use moreau_crowd::{Scene, Simulation};
use moreau_solve::{
    ClarabelReference, ClarabelSettings, ProjectionSolution, ProjectionSolver, Target,
};

/// The largest overlap between two disks, and of a disk with a wall; panics if a centre left
/// the walkable area. Pairs come from a hash of square cells of side `2 r_max`.
pub fn worst_overlap(scene: &Scene, pos: &[f64], radii: &[f64]) -> (f64, f64) {
    let n = radii.len();
    let cell = 2.0 * radii.iter().copied().fold(0.0, f64::max).max(1e-12);
    let key = |i: usize| {
        (
            (pos[2 * i] / cell).floor() as i64,
            (pos[2 * i + 1] / cell).floor() as i64,
        )
    };
    let mut cells: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for i in 0..n {
        cells.entry(key(i)).or_default().push(i);
    }
    let mut disks: f64 = f64::NEG_INFINITY;
    for i in 0..n {
        let (cx, cy) = key(i);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &j in cells.get(&(cx + dx, cy + dy)).map_or(&[][..], |v| v) {
                    if j <= i {
                        continue;
                    }
                    let d = ((pos[2 * i] - pos[2 * j]).powi(2)
                        + (pos[2 * i + 1] - pos[2 * j + 1]).powi(2))
                    .sqrt();
                    disks = disks.max(radii[i] + radii[j] - d);
                }
            }
        }
    }
    let walls = scene.walls();
    let mut wall: f64 = f64::NEG_INFINITY;
    for i in 0..n {
        let p = [pos[2 * i], pos[2 * i + 1]];
        assert!(
            scene.walkable(p),
            "person {i} left the walkable area: {p:?}"
        );
        for w in &walls {
            wall = wall.max(radii[i] - w.distance(p));
        }
    }
    (disks, wall)
}

/// Asserts that the configuration is finite and overlaps (disks and walls) by no more than the
/// step's certified violation: the linearized gaps under-estimate the convex true gaps.
pub fn assert_feasible(scene: &Scene, sim: &Simulation, report: &StepReport) {
    let f = sim.frame();
    assert!(
        f.positions.iter().all(|x| x.is_finite()),
        "step {}: a position is not finite",
        report.step
    );
    assert!(report.eps.is_finite() && report.violation.is_finite());
    assert!(
        report.status.is_converged(),
        "step {}: {:?}",
        report.step,
        report.status
    );
    let (d, w) = worst_overlap(scene, f.positions, f.radii);
    assert!(
        report.violation <= scene.solver.max_violation,
        "step {}: violation {} above the scene's bound",
        report.step,
        report.violation
    );
    assert!(
        d <= report.violation + 1e-12 && w <= report.violation + 1e-12,
        "step {} (t = {}): overlaps {d} between disks, {w} with walls; certified {}",
        report.step,
        report.t,
        report.violation
    );
}

/// Re-solves the step just taken with Clarabel at a tight tolerance and asserts that the two
/// velocities are within the sum of their certified radii (½|v − v*|² ≤ gap + |λ*|₁·violation
/// for each answer). `before` are the positions before the step (nobody removed by it).
/// Returns |Δv| / certified radius.
pub fn assert_matches_clarabel(sim: &Simulation, before: &[f64], report: &StepReport) -> f64 {
    let mu = report.mu;
    let after = sim.frame().positions;
    assert_eq!(
        before.len(),
        after.len(),
        "compare only steps where nobody left"
    );
    let v_fast: Vec<f64> = before
        .iter()
        .zip(after)
        .map(|(a, b)| (b - a) / mu)
        .collect();
    let problem = sim.last_projection();
    let mut reference = ClarabelReference::new(ClarabelSettings {
        tolerance: 1e-11,
        max_iterations: 200,
    });
    let mut sol = ProjectionSolution::default();
    let rc = reference
        .solve(
            &problem,
            Target {
                gap: 1e-8,
                violation: 1e-9,
            },
            &mut sol,
        )
        .unwrap();
    // The bound below uses Clarabel's certificate of its own answer, which holds whatever its
    // status; it only has to be tight enough to make the comparison mean something.
    assert!(rc.gap <= 1e-6 && rc.violation <= 1e-7, "{rc:?}");
    let l1: f64 = sol.lambda.iter().sum();
    let radius_fast = (2.0 * (report.eps / (2.0 * mu * mu) + l1 * report.violation / mu)).sqrt();
    let radius_ref = (2.0 * (rc.gap + l1 * rc.violation)).sqrt();
    let dist = v_fast
        .iter()
        .zip(&sol.v)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        dist <= radius_fast + radius_ref + 1e-9,
        "step {}: |v_fast − v_clarabel| = {dist} > {radius_fast} + {radius_ref}",
        report.step
    );
    dist / (radius_fast + radius_ref)
}

/// A 6 m × 6 m room with a door of width `door` in the middle of its right wall (0.2 m thick)
/// and a corridor to x = 8 whose end removes people; `groups` is TOML for `[[groups]]`.
pub fn room(door: f64, step: f64, horizon: f64, groups: &str) -> Scene {
    let (lo, hi) = (3.0 - door / 2.0, 3.0 + door / 2.0);
    let text = format!(
        r#"
name = "extremes"
seed = 7
[area]
outer = [[0.0, 0.0], [6.0, 0.0], [6.0, {lo}], [6.2, {lo}], [6.2, 0.0], [8.0, 0.0],
         [8.0, 6.0], [6.2, 6.0], [6.2, {hi}], [6.0, {hi}], [6.0, 6.0], [0.0, 6.0]]
[[exits]]
name = "out"
area = [[7.5, 0.0], [8.0, 0.0], [8.0, 6.0], [7.5, 6.0]]
action = "remove"
{groups}
[time]
horizon = {horizon}
step = {step}
output_interval = {step}
[solver]
eps_kappa = 1e-3
max_violation = 1e-6
grid_cell = 0.1
"#
    );
    Scene::from_toml(&text, "extremes").unwrap()
}

pub fn spawn(count: usize, radius: &str, speed: &str) -> String {
    format!(
        r#"[[groups]]
name = "crowd"
count = {count}
spawn = [[0.0, 0.0], [6.0, 0.0], [6.0, 6.0], [0.0, 6.0]]
radius = {radius}
speed = {speed}
destination = "out"
"#
    )
}

pub fn listed(name: &str, positions: &[[f64; 2]], radius: f64, speed: f64) -> String {
    let list: Vec<String> = positions
        .iter()
        .map(|p| format!("[{:?}, {:?}]", p[0], p[1]))
        .collect();
    format!(
        "[[groups]]\nname = \"{name}\"\npositions = [{}]\nradius = {radius:?}\nspeed = {speed:?}\ndestination = \"out\"\n",
        list.join(", ")
    )
}

/// Where the person who starts at `p` is stored (people are numbered along a space-filling
/// curve, not in the order the scene lists them); panics if nobody starts there.
pub fn start_index(scene: &Scene, p: [f64; 2]) -> usize {
    let sim = Simulation::new(scene.clone()).unwrap();
    let q = sim.frame().positions;
    (0..q.len() / 2)
        .find(|&k| q[2 * k] == p[0] && q[2 * k + 1] == p[1])
        .expect("somebody starts there")
}

/// The steps of the scene's fixed stepping from 0 to its horizon (`moreau_integrate::fixed_step`),
/// for tests that check every step.
pub fn steps(scene: &Scene) -> Vec<f64> {
    let (h, horizon) = (scene.time.step, scene.time.horizon);
    let (mut t, mut out) = (0.0, Vec::new());
    while let Some(mu) = moreau_integrate::fixed_step(h, horizon - t) {
        out.push(mu);
        t += mu;
    }
    out
}
