//! Contact assembly against many walls: 10,000 people in the evacuation hall with its 8
//! walls, and the same hall with 248 small square pillars (1,000 wall segments in all). Disk–
//! wall rows come from the walls' grid index, so the second costs about what the first does
//! (the bar: within 2×), where a loop over every wall for every person would cost
//! ~125× more in its wall part.
//!
//! `cargo bench -p moreau-crowd --bench walls`

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use moreau_core::ConstraintRows;
use moreau_crowd::{Hall, Scene, Simulation};

const PEOPLE: usize = 10_000;
const MU: f64 = 0.05;

/// The hall, with `pillars` squares of side 0.1 m on a regular grid.
fn hall(pillars: usize) -> Scene {
    let mut scene = Hall::new(PEOPLE, 2.6).scene().expect("a valid hall");
    let side = Hall::new(PEOPLE, 2.6).side();
    let per_row = (pillars as f64).sqrt().ceil() as usize;
    let gap = side / (per_row + 1) as f64;
    for k in 0..pillars {
        let (x, y) = (
            gap * (1 + k % per_row) as f64,
            gap * (1 + k / per_row) as f64,
        );
        scene
            .area
            .holes
            .push(vec![[x, y], [x + 0.1, y], [x + 0.1, y + 0.1], [x, y + 0.1]]);
    }
    scene
}

fn walls(c: &mut Criterion) {
    let mut group = c.benchmark_group("walls");
    group.sample_size(20);
    for pillars in [0usize, 248] {
        let mut sim = Simulation::new(hall(pillars)).expect("the hall builds");
        let walls = sim.walls().len();
        assert_eq!(walls, 8 + 4 * pillars);
        sim.advance_to(10.0 * MU, &mut ())
            .expect("the warm-up steps");
        let mut w = vec![0.0; sim.people().positions().len()];
        sim.desired_velocities(&mut w);
        let margin = sim.contact_margin(&w, MU);
        let mut rows = ConstraintRows::default();
        group.bench_with_input(
            BenchmarkId::new("assemble", format!("{walls}-walls")),
            &walls,
            |b, _| b.iter(|| sim.contacts(margin, &mut rows)),
        );
        group.bench_with_input(
            BenchmarkId::new("desired-velocity", format!("{walls}-walls")),
            &walls,
            |b, _| b.iter(|| sim.desired_velocities(&mut w)),
        );
    }
    group.finish();
}

criterion_group!(benches, walls);
criterion_main!(benches);
