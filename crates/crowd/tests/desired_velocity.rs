//! The Lipschitz desired velocity (`[model] desired_velocity = "lipschitz"`) has no jump
//! where the classic one has them: where the wall slide starts, and on arrival.

mod common;

use moreau_crowd::{DesiredVelocityKind, Simulation};

/// The desired velocity of one person of radius 0.2 heading for the door of the test room,
/// at `x` along the line y = 1 next to the right wall (x = 6): the goal lies up and to the
/// right, so the wall slide turns it upwards.
fn along_the_wall(kind: DesiredVelocityKind, xs: &[f64]) -> Vec<[f64; 2]> {
    let groups = common::listed("one", &[[5.0, 1.0]], 0.2, 1.0);
    let mut scene = common::room(1.0, 0.05, 1.0, &groups);
    scene.model.desired_velocity = kind;
    let mut sim = Simulation::new(scene).unwrap();
    xs.iter()
        .map(|&x| {
            let mut state = sim.state();
            state.people.split_mut().0[0] = x;
            sim.restore(&state).unwrap();
            let mut u = [0.0; 2];
            sim.desired_velocities(&mut u);
            u
        })
        .collect()
}

#[test]
fn the_lipschitz_wall_slide_has_no_jump_where_the_classic_one_has() {
    // From 9 cm to 1 mm beyond the radius, in steps of 0.1 mm.
    let xs: Vec<f64> = (0..=890)
        .map(|k| 6.0 - 0.2 - 0.09 + 1e-4 * k as f64)
        .collect();
    let largest_jump = |u: &[[f64; 2]]| {
        u.windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .fold(0.0, f64::max)
    };
    let classic = along_the_wall(DesiredVelocityKind::Classic, &xs);
    let smooth = along_the_wall(DesiredVelocityKind::Lipschitz, &xs);
    // Classic: the part into the wall vanishes at once at 5 cm.
    assert!(largest_jump(&classic) > 0.1, "{}", largest_jump(&classic));
    // Lipschitz: at most speed / WALL_RANGE = 20 per metre (plus the direction field's own
    // variation): 2e-3 per 0.1 mm.
    assert!(largest_jump(&smooth) < 3e-3, "{}", largest_jump(&smooth));
    // Both slide fully in contact with the wall: nothing into it (x > 0 is into the wall).
    let touching = |kind| along_the_wall(kind, &[6.0 - 0.2])[0];
    assert!(touching(DesiredVelocityKind::Classic)[0].abs() <= 1e-12);
    assert!(touching(DesiredVelocityKind::Lipschitz)[0].abs() <= 1e-12);
    // At 1 mm the Lipschitz slide is 98 % done.
    let into = |u: &[f64; 2]| u[0].max(0.0);
    assert!(into(smooth.last().unwrap()) <= 0.021 * into(&smooth[0]));
    // Far from the wall both are the plain descent direction.
    assert_eq!(classic[0], smooth[0]);
}
