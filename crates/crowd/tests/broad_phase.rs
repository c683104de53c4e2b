//! Both broad-phase backends, and the Verlet list over them, return exactly the brute-force pair set.

use moreau_crowd::{BroadPhase, BruteForce, CellGrid, TreeBroadPhase, VerletList};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn grid_and_tree_match_brute_force_on_random_scenes() {
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let (mut grid, mut tree, mut brute) =
        (CellGrid::default(), TreeBroadPhase::default(), BruteForce);
    let mut total_pairs = 0;
    for scene in 0..120 {
        let n = rng.random_range(2..400);
        // Every third scene has radii spread over 1:100.
        let (rmin, rmax): (f64, f64) = if scene % 3 == 0 {
            (0.01, 1.0)
        } else {
            (0.18, 0.22)
        };
        let side = rng.random_range(2.0..30.0);
        let pos: Vec<f64> = (0..2 * n).map(|_| rng.random_range(0.0..side)).collect();
        let radius: Vec<f64> = (0..n)
            .map(|_| {
                if rmax / rmin > 10.0 {
                    rmin * (rmax / rmin).powf(rng.random_range(0.0..1.0))
                } else {
                    rng.random_range(rmin..rmax)
                }
            })
            .collect();
        let margin = [0.0, 0.05, 0.5, -0.01][scene % 4];
        let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
        brute.pairs(&pos, &radius, margin, &mut a);
        grid.pairs(&pos, &radius, margin, &mut b);
        tree.pairs(&pos, &radius, margin, &mut c);
        assert_eq!(a, b, "grid differs on scene {scene} (n = {n})");
        assert_eq!(a, c, "tree differs on scene {scene} (n = {n})");
        total_pairs += a.len();
    }
    // The scenes are not trivially empty.
    assert!(total_pairs > 1000, "{total_pairs}");
}

#[test]
fn one_huge_disk_among_tiny_ones_is_found_by_both() {
    // Radii 1:100 with every small disk touching the big one.
    let mut pos = vec![0.0, 0.0];
    let mut radius = vec![1.0];
    for k in 0..50 {
        let a = k as f64 * 0.125;
        pos.extend([1.01 * a.cos(), 1.01 * a.sin()]);
        radius.push(0.01);
    }
    let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
    BruteForce.pairs(&pos, &radius, 1e-9, &mut a);
    CellGrid::default().pairs(&pos, &radius, 1e-9, &mut b);
    TreeBroadPhase::default().pairs(&pos, &radius, 1e-9, &mut c);
    assert!(a.iter().filter(|p| p.0 == 0).count() == 50);
    assert_eq!(a, b);
    assert_eq!(a, c);
}

#[test]
fn a_verlet_list_returns_the_brute_force_pairs_as_people_move_and_leave() {
    // A crowd walking in small random steps (phase 0: the list must be kept), then with a
    // long jump now and then and sometimes one person fewer (phase 1), then running (phase
    // 2: the list goes straight to the backend), with the crowd's kind of margins (and the
    // negative one of the check after a step): the pairs must be exactly the brute-force
    // pairs every time.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for backend in 0..2 {
        let inner: Box<dyn BroadPhase> = if backend == 0 {
            Box::new(CellGrid::default())
        } else {
            Box::new(TreeBroadPhase::default())
        };
        let mut verlet = VerletList::new(inner);
        let n0 = 300;
        let mut pos: Vec<f64> = (0..2 * n0).map(|_| rng.random_range(0.0..10.0)).collect();
        let mut radius: Vec<f64> = (0..n0).map(|_| rng.random_range(0.2..0.3)).collect();
        let (mut want, mut got) = (Vec::new(), Vec::new());
        let calls = 150;
        for phase in 0..3 {
            let (builds, mut total) = (verlet.builds(), 0);
            for call in 0..calls {
                let step = match phase {
                    1 if call % 37 == 36 => 0.3,
                    2 => 0.2,
                    _ => 0.012,
                };
                for x in pos.iter_mut() {
                    *x += rng.random_range(-step..step);
                }
                if phase == 1 && call % 50 == 49 {
                    let k = rng.random_range(0..radius.len());
                    radius.remove(k);
                    pos.drain(2 * k..2 * k + 2);
                }
                let margin = [0.04, 0.05, -1e-9, 0.02][call % 4];
                BruteForce.pairs(&pos, &radius, margin, &mut want);
                verlet.pairs(&pos, &radius, margin, &mut got);
                assert_eq!(want, got, "backend {backend}, phase {phase}, call {call}");
                total += want.len();
            }
            assert!(total > 20 * calls, "phase {phase}: {total}");
            let builds = verlet.builds() - builds;
            match phase {
                // Each build is the backend's full search: kept most of the time...
                0 => assert!((5..calls / 3).contains(&builds), "{builds} builds"),
                // ... and when everyone runs, the backend is asked every time.
                2 => assert!(builds > calls * 9 / 10, "{builds} builds"),
                _ => {}
            }
        }
    }
}

/// The grid on threads (from 10,000 disks its rows of cells are swept in bands) returns the
/// one-thread grid's pairs, and every pair the brute force finds for a sample of the disks.
#[test]
fn the_grid_on_threads_finds_the_same_pairs() {
    use moreau_core::Parallelism;
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let n = 30_000;
    let side = 150.0;
    let pos: Vec<f64> = (0..2 * n).map(|_| rng.random_range(0.0..side)).collect();
    let radius: Vec<f64> = (0..n).map(|_| rng.random_range(0.18..0.25)).collect();
    let margin = 0.1;
    let mut one = Vec::new();
    CellGrid::default().pairs(&pos, &radius, margin, &mut one);
    assert!(one.len() > 10_000, "{} pairs", one.len());
    for threads in [2, 3, 7] {
        let mut many = Vec::new();
        CellGrid::on_threads(Parallelism::threads(threads)).pairs(&pos, &radius, margin, &mut many);
        assert_eq!(one, many, "{threads} threads");
    }
    // The brute force's pairs of the first 500 disks with any other.
    let gap = |i: usize, j: usize| {
        let (dx, dy) = (pos[2 * i] - pos[2 * j], pos[2 * i + 1] - pos[2 * j + 1]);
        (dx * dx + dy * dy).sqrt() - radius[i] - radius[j]
    };
    for i in 0..500 {
        for j in 0..n {
            let listed = one
                .binary_search(&(i.min(j) as u32, i.max(j) as u32))
                .is_ok();
            assert_eq!(i != j && gap(i, j) <= margin, listed, "pair ({i}, {j})");
        }
    }
}

/// Regression: a person very far from the rest (a damaged saved state put one at 10³⁰⁶ m)
/// made the grid's cap on its cell count size one side by the other's span: the cell count
/// overflowed and the grid indexed out of its cells (a panic). Far apart, or spread along a
/// strip a million times longer than wide, the grid finds the brute-force pairs.
#[test]
fn a_person_far_from_the_rest_does_not_overflow_the_grid() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let crowd = |rng: &mut ChaCha8Rng, n: usize, len: f64| -> Vec<f64> {
        (0..n)
            .flat_map(|_| [rng.random_range(0.0..len), rng.random_range(0.0..2.0)])
            .collect()
    };
    let mut cases = Vec::new();
    for far in [1e306, -1e306, 1e154, 1e30] {
        let mut pos = crowd(&mut rng, 200, 20.0);
        pos[10] = far;
        cases.push(pos);
    }
    let mut both = crowd(&mut rng, 200, 20.0);
    (both[10], both[11], both[20], both[21]) = (1e300, -1e300, -1e300, 1e300);
    cases.push(both);
    cases.push(crowd(&mut rng, 300, 2e6));
    for (k, pos) in cases.iter().enumerate() {
        let radius = vec![0.25; pos.len() / 2];
        let (mut a, mut b, mut c) = (Vec::new(), Vec::new(), Vec::new());
        BruteForce.pairs(pos, &radius, 0.1, &mut a);
        CellGrid::default().pairs(pos, &radius, 0.1, &mut b);
        TreeBroadPhase::default().pairs(pos, &radius, 0.1, &mut c);
        assert_eq!(a, b, "grid, case {k}");
        assert_eq!(a, c, "tree, case {k}");
        assert!(k == 5 || !a.is_empty(), "case {k} has pairs to find");
    }
}
