//! Runs a scene and prints a summary line every 2 s of simulated time (a development aid).

use moreau_core::{RunStats, StepReport};
use moreau_crowd::{Frame, Observer, ObserverError};

#[derive(Default)]
struct Print(RunStats);

impl Observer for Print {
    fn step(&mut self, r: &StepReport) -> Result<(), ObserverError> {
        self.0.add(r);
        Ok(())
    }
    fn frame(&mut self, f: &Frame<'_>) -> Result<(), ObserverError> {
        if (f.t * 10.0).round() as i64 % 20 == 0 {
            println!("t = {:5.2}  people {}", f.t, f.ids.len());
        }
        Ok(())
    }
}

fn main() {
    let path = std::env::args()
        .nth(1)
        .expect("usage: run_scene SCENE.toml");
    let scene = moreau_crowd::Scene::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut sim = moreau_crowd::Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
    let start = std::time::Instant::now();
    let mut print = Print::default();
    sim.run(&mut print).unwrap_or_else(|e| panic!("{e}"));
    let s = &print.0;
    println!(
        "{} steps, {} iterations, max violation {:e}, max eps {:e}, exited {}, wall {:?}, solve {:.3}s",
        s.steps,
        s.iterations,
        s.max_violation,
        s.max_eps,
        sim.exit_records().len(),
        start.elapsed(),
        s.timings.solve
    );
}
