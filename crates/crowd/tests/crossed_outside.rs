//! The crowd's check after a step (`crossed_outside`, its own fast version of the core's
//! default): on a constructed configuration with known overlaps it counts exactly the
//! overlapping pairs that were not assembled, against an O(N²) count.

mod common;

use moreau_core::ConstraintRows;
use moreau_crowd::Simulation;

#[test]
fn crossed_outside_counts_the_overlaps_that_were_not_assembled() {
    let groups = common::spawn(40, "0.2", "1.0");
    let mut sim = Simulation::new(common::room(1.0, 0.05, 5.0, &groups)).unwrap();
    // Push three people onto a neighbour (overlaps of 5 cm), through a saved state.
    let mut state = sim.state();
    let moved = [(1, 0), (3, 2), (5, 4)];
    {
        let (q, _) = state.people.split_mut();
        for &(a, b) in &moved {
            q[2 * a] = q[2 * b] + 0.35;
            q[2 * a + 1] = q[2 * b + 1];
        }
    }
    sim.restore(&state).unwrap();
    let (q, r) = (
        sim.people().positions().to_vec(),
        sim.people().radii().to_vec(),
    );
    let tol = 1e-6;
    let mut overlapping = 0;
    for i in 0..r.len() {
        for j in i + 1..r.len() {
            let d = (q[2 * i] - q[2 * j]).hypot(q[2 * i + 1] - q[2 * j + 1]);
            if d - r[i] - r[j] < -tol {
                overlapping += 1;
            }
        }
    }
    assert!(
        overlapping >= moved.len(),
        "{overlapping} overlaps constructed"
    );
    let dim = q.len();
    // Nothing assembled: every overlap is outside.
    assert_eq!(
        sim.crossed_outside(&ConstraintRows::new(dim), tol),
        overlapping
    );
    // Everything within reach assembled: nothing is.
    let mut rows = ConstraintRows::new(dim);
    sim.contacts(0.0, &mut rows);
    assert_eq!(sim.crossed_outside(&rows, tol), 0);
    // The overlaps of one moved pair left out: exactly theirs are counted.
    let mut partial = ConstraintRows::new(dim);
    let (a, b) = (sim.people().ids()[1], sim.people().ids()[0]);
    let key = moreau_crowd::ContactKind::PersonPerson.key(a.min(b), a.max(b));
    for i in 0..rows.len() {
        if rows.keys()[i] != key {
            let (cols, coefs) = rows.row(i);
            partial.push(
                rows.keys()[i],
                rows.values()[i],
                cols.iter().copied().zip(coefs.iter().copied()),
            );
        }
    }
    assert_eq!(
        partial.len() + 1,
        rows.len(),
        "the pair (1, 0) is a contact"
    );
    assert_eq!(sim.crossed_outside(&partial, tol), 1);
}

/// Moves everyone by `step` (a function of the person) and returns the new positions.
fn moved(q: &[f64], step: impl Fn(usize) -> [f64; 2]) -> Vec<f64> {
    let mut next = q.to_vec();
    for i in 0..q.len() / 2 {
        let s = step(i);
        next[2 * i] += s[0];
        next[2 * i + 1] += s[1];
    }
    next
}

/// Sets the positions (through a saved state) and counts the contacts outside `rows`.
fn crossed_at(sim: &mut Simulation, q: &[f64], rows: &ConstraintRows, tol: f64) -> usize {
    let mut state = sim.state();
    state.people.split_mut().0.copy_from_slice(q);
    sim.restore(&state).unwrap();
    sim.crossed_outside(rows, tol)
}

/// The bound that spares a step its check (`left_out_stay_feasible`) holds only when no
/// contact left out can have crossed: everyone moving up to half the margin keeps every left-
/// out pair apart (and the check agrees), and two people who were just beyond the margin,
/// moved straight at each other by a little more than half of it, overlap, which the bound
/// must not rule out (a bound that forgot a pair gap moves with both people would).
#[test]
fn the_check_is_skipped_only_when_no_contact_left_out_can_have_crossed() {
    let groups = common::spawn(60, "0.2", "1.0");
    let mut sim = Simulation::new(common::room(1.0, 0.05, 5.0, &groups)).unwrap();
    let q = sim.people().positions().to_vec();
    let r = sim.people().radii().to_vec();
    let (margin, tol) = (0.1, 1e-6);
    let mut rows = ConstraintRows::new(q.len());
    sim.contacts(margin, &mut rows);

    // Everyone moves by just under (margin + tol) / 2, each in their own direction.
    let d = 0.5 * (margin + tol) * (1.0 - 1e-6);
    for turn in 0..8 {
        let next = moved(&q, |i| {
            let a = 0.7 * i as f64 + turn as f64;
            [d * a.cos(), d * a.sin()]
        });
        assert!(
            sim.left_out_stay_feasible(&next, margin, tol),
            "turn {turn}"
        );
        assert_eq!(crossed_at(&mut sim, &next, &rows, tol), 0, "turn {turn}");
        crossed_at(&mut sim, &q, &rows, tol);
    }

    // The closest pair left out (gap above the margin), moved straight at each other.
    let n = r.len();
    let gap =
        |i: usize, j: usize| (q[2 * i] - q[2 * j]).hypot(q[2 * i + 1] - q[2 * j + 1]) - r[i] - r[j];
    let (i, j) = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .filter(|&(i, j)| gap(i, j) > margin)
        .min_by(|a, b| gap(a.0, a.1).total_cmp(&gap(b.0, b.1)))
        .unwrap();
    let g = gap(i, j);
    assert!(g < 2.0 * margin, "a pair just beyond the margin: {g}");
    let e = [
        (q[2 * j] - q[2 * i]) / (g + r[i] + r[j]),
        (q[2 * j + 1] - q[2 * i + 1]) / (g + r[i] + r[j]),
    ];
    // Each moves by (g + 2 tol) / 2 ≤ g: more than half the margin, less than all of it.
    let d = 0.5 * (g + 2.0 * tol);
    assert!(d < margin + tol && 2.0 * d > margin + tol);
    let next = moved(&q, |k| match k {
        k if k == i => [d * e[0], d * e[1]],
        k if k == j => [-d * e[0], -d * e[1]],
        _ => [0.0, 0.0],
    });
    assert!(!sim.left_out_stay_feasible(&next, margin, tol));
    assert_eq!(crossed_at(&mut sim, &next, &rows, tol), 1);
    // A position that is not a number never passes.
    let mut broken = q.clone();
    broken[3] = f64::NAN;
    assert!(!sim.left_out_stay_feasible(&broken, margin, tol));
}
