//! Broad phase: the cell grid against parry's BVH, on dense crowds with similar radii and on
//! crowds whose radii differ by 100×.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use moreau_crowd::{BroadPhase, CellGrid, TreeBroadPhase};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` disks at about 2.5 per m² (similar radii) or with radii spread log-uniformly in
/// [0.01, 1] at the same count per m².
fn crowd(n: usize, spread: bool) -> (Vec<f64>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
    let side = (n as f64 / 2.5).sqrt();
    let pos = (0..2 * n).map(|_| rng.random_range(0.0..side)).collect();
    let radius = (0..n)
        .map(|_| {
            if spread {
                0.01 * 100f64.powf(rng.random_range(0.0..1.0))
            } else {
                rng.random_range(0.18..0.22)
            }
        })
        .collect();
    (pos, radius)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("broad_phase");
    group.sample_size(10);
    for &n in &[2_000usize, 100_000] {
        for spread in [false, true] {
            let (pos, radius) = crowd(n, spread);
            let label = format!("{n}{}", if spread { "-radii1to100" } else { "" });
            let mut out = Vec::new();
            let mut grid = CellGrid::default();
            group.bench_with_input(BenchmarkId::new("grid", &label), &n, |b, _| {
                b.iter(|| grid.pairs(&pos, &radius, 0.05, &mut out))
            });
            let mut tree = TreeBroadPhase::default();
            group.bench_with_input(BenchmarkId::new("bvh", &label), &n, |b, _| {
                b.iter(|| tree.pairs(&pos, &radius, 0.05, &mut out))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
