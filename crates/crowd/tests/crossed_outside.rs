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
