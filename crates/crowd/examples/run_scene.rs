//! Runs a scene and prints a summary line per output frame (a development aid).
fn main() {
    let path = std::env::args()
        .nth(1)
        .expect("usage: run_scene SCENE.toml");
    let scene = moreau_crowd::Scene::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut sim = moreau_crowd::Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
    let start = std::time::Instant::now();
    let (mut iters, mut steps, mut maxv, mut maxeps, mut solve) =
        (0usize, 0usize, 0.0f64, 0.0f64, 0.0f64);
    sim.run::<moreau_crowd::CrowdError>(
        |_, r| {
            iters += r.iterations;
            steps += 1;
            maxv = maxv.max(r.violation);
            maxeps = maxeps.max(r.eps);
            solve += r.timings.solve;
            Ok(())
        },
        |f| {
            if (f.t * 10.0).round() as i64 % 20 == 0 {
                println!("t = {:5.2}  people {}", f.t, f.ids.len());
            }
            Ok(())
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    println!(
        "{steps} steps, {iters} iterations, max violation {maxv:e}, max eps {maxeps:e}, exited {}, wall {:?}, solve {solve:.3}s",
        sim.exit_times().len(),
        start.elapsed()
    );
}
