//! The evacuation hall shared by the benchmarks and the large tests: one generator instead of
//! a TOML template in each of them.

use crate::error::CrowdError;
use crate::scene::{Scene, SolverSettings};

/// A square hall of `people / density` m² with one door in the middle of its right wall;
/// behind it a 0.5 m exit area removes whoever reaches it. People (radii 0.18–0.22 m, desired
/// speeds 0.9–1.3 m/s) spawn anywhere in the hall and head for the door.
#[derive(Debug, Clone, PartialEq)]
pub struct Hall {
    /// People in the hall.
    pub people: usize,
    /// People per m².
    pub density: f64,
    /// Door width (m).
    pub door: f64,
    /// Seed of the placement.
    pub seed: u64,
    /// Step (s).
    pub step: f64,
    /// Horizon (s).
    pub horizon: f64,
    /// Frame interval (s).
    pub output_interval: f64,
    /// The `[solver]` table.
    pub solver: SolverSettings,
}

impl Hall {
    /// `people` at `density` per m², a door of `max(side / 20, 2)` m, seed 2026, 0.05 s steps
    /// over 1 s, the default solver settings.
    pub fn new(people: usize, density: f64) -> Self {
        let side = (people as f64 / density).sqrt();
        Self {
            people,
            density,
            door: (side / 20.0).max(2.0),
            seed: 2026,
            step: 0.05,
            horizon: 1.0,
            output_interval: 0.05,
            solver: SolverSettings::default(),
        }
    }

    /// The side of the square (m).
    pub fn side(&self) -> f64 {
        (self.people as f64 / self.density).sqrt()
    }

    /// The scene, validated like a scene file.
    pub fn scene(&self) -> Result<Scene, CrowdError> {
        let side = self.side();
        let (lo, hi) = (side / 2.0 - self.door / 2.0, side / 2.0 + self.door / 2.0);
        let (x0, x1) = (side + 0.5, side + 1.0);
        let solver = solver_section(&self.solver);
        let text = format!(
            r#"
name = "hall-{n}"
seed = {seed}
[area]
outer = [[0.0, 0.0], [{side:?}, 0.0], [{side:?}, {lo:?}], [{x1:?}, {lo:?}], [{x1:?}, {hi:?}], [{side:?}, {hi:?}], [{side:?}, {side:?}], [0.0, {side:?}]]
[[exits]]
name = "door"
area = [[{x0:?}, {lo:?}], [{x1:?}, {lo:?}], [{x1:?}, {hi:?}], [{x0:?}, {hi:?}]]
action = "remove"
[[groups]]
name = "crowd"
count = {n}
spawn = [[0.0, 0.0], [{side:?}, 0.0], [{side:?}, {side:?}], [0.0, {side:?}]]
radius = {{ min = 0.18, max = 0.22 }}
speed = {{ min = 0.9, max = 1.3 }}
destination = "door"
[time]
horizon = {horizon}
step = {step}
output_interval = {output_interval}
{solver}"#,
            n = self.people,
            seed = self.seed,
            horizon = self.horizon,
            step = self.step,
            output_interval = self.output_interval,
        );
        Scene::from_toml(&text, &format!("hall of {} people", self.people))
    }
}

/// A crowd pressed together: people on a hexagonal lattice at `density` per m² (5 by default:
/// 0.48 m between centres) with radii of 0.995 × half the spacing (gaps of 2.4 mm), filling a
/// square room, all pushing at 1 m/s towards a small area at its centre (the one or two
/// lattice sites inside that area left empty). From the first steps almost every pair of
/// neighbours is in contact: the state of a crush, where nearly every row of the projection
/// is active.
#[derive(Debug, Clone, PartialEq)]
pub struct Crush {
    /// People on the lattice.
    pub people: usize,
    /// People per m².
    pub density: f64,
    /// Radius (m); `None`: 0.995 × half the lattice spacing.
    pub radius: Option<f64>,
    /// Step (s).
    pub step: f64,
    /// Horizon (s).
    pub horizon: f64,
    /// The `[solver]` table.
    pub solver: SolverSettings,
}

impl Crush {
    /// `people` at 5 per m², nearly touching, 0.05 s steps over 1 s, the default solver.
    pub fn new(people: usize) -> Self {
        Self {
            people,
            density: 5.0,
            radius: None,
            step: 0.05,
            horizon: 1.0,
            solver: SolverSettings::default(),
        }
    }

    /// The scene, validated like a scene file.
    pub fn scene(&self) -> Result<Scene, CrowdError> {
        // Hexagonal lattice: rows `d √3/2` apart, every other row shifted by `d/2`; one
        // person per `d² √3/2` m².
        let d = (2.0 / (3f64.sqrt() * self.density)).sqrt();
        let dy = d * 3f64.sqrt() / 2.0;
        let radius = self.radius.unwrap_or(0.995 * d / 2.0);
        let per_row = ((self.people as f64 * dy / d).sqrt().ceil() as usize).max(1);
        let rows = self.people.div_ceil(per_row);
        let margin = d / 2.0 + radius;
        let (w, h) = (
            (per_row as f64 - 0.5) * d + 2.0 * margin,
            (rows as f64 - 1.0) * dy + 2.0 * margin,
        );
        let side = w.max(h);
        let (c0, c1) = (side / 2.0 - 0.25, side / 2.0 + 0.25);
        // The lattice sites inside the centre's exit area stay empty: whoever stood there
        // would be counted out before the first step (the scene check refuses it).
        let positions: Vec<String> = (0..self.people)
            .map(|k| {
                let (r, c) = (k / per_row, k % per_row);
                let x = margin + c as f64 * d + if r % 2 == 1 { d / 2.0 } else { 0.0 };
                let y = margin + r as f64 * dy + (side - h) / 2.0;
                (x, y)
            })
            .filter(|&(x, y)| !((c0..=c1).contains(&x) && (c0..=c1).contains(&y)))
            .map(|(x, y)| format!("[{x:?}, {y:?}]"))
            .collect();
        let solver = solver_section(&self.solver);
        let text = format!(
            r#"
name = "crush-{n}"
seed = 1
[area]
outer = [[0.0, 0.0], [{side:?}, 0.0], [{side:?}, {side:?}], [0.0, {side:?}]]
[[exits]]
name = "centre"
area = [[{c0:?}, {c0:?}], [{c1:?}, {c0:?}], [{c1:?}, {c1:?}], [{c0:?}, {c1:?}]]
action = "continue"
target = [[{c0:?}, {c0:?}], [{c1:?}, {c0:?}], [{c1:?}, {c1:?}], [{c0:?}, {c1:?}]]
[[groups]]
name = "crowd"
positions = [{positions}]
radius = {radius:?}
speed = 1.0
destination = "centre"
[time]
horizon = {horizon}
step = {step}
output_interval = {step}
{solver}"#,
            n = self.people,
            positions = positions.join(", "),
            radius = radius,
            horizon = self.horizon,
            step = self.step,
        );
        Scene::from_toml(&text, &format!("crush of {} people", self.people))
    }
}

/// `[solver]` and its tables (`[solver.auto]`, …): the settings serialized under their key,
/// so that a table is not written at the top level.
fn solver_section(solver: &SolverSettings) -> String {
    #[derive(serde::Serialize)]
    struct Section<'a> {
        solver: &'a SolverSettings,
    }
    toml::to_string(&Section { solver }).expect("solver settings serialize")
}
