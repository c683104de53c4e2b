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
        let solver = toml::to_string(&self.solver).expect("solver settings serialize");
        let text = format!(
            r#"
name = "hall-{n}"
seed = {seed}
[area]
outer = [[0.0, 0.0], [{side}, 0.0], [{side}, {lo}], [{x1}, {lo}], [{x1}, {hi}], [{side}, {hi}], [{side}, {side}], [0.0, {side}]]
[[exits]]
name = "door"
area = [[{x0}, {lo}], [{x1}, {lo}], [{x1}, {hi}], [{x0}, {hi}]]
action = "remove"
[[groups]]
name = "crowd"
count = {n}
spawn = [[0.0, 0.0], [{side}, 0.0], [{side}, {side}], [0.0, {side}]]
radius = {{ min = 0.18, max = 0.22 }}
speed = {{ min = 0.9, max = 1.3 }}
destination = "door"
[time]
horizon = {horizon}
step = {step}
output_interval = {output_interval}
[solver]
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
