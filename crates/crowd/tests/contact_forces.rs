//! The contact forces a frame reports: they balance each person's change of velocity
//! (`v − w = Σ λ n`, with the normals recomputed from the positions and the walls), and they
//! agree with an independent solve of the same projection (Clarabel), within what the step's
//! certificate allows.

mod common;

use moreau_crowd::{ContactKind, Simulation};
use moreau_solve::{
    ClarabelReference, ClarabelSettings, ProjectionSolution, ProjectionSolver, Target, certify,
};

/// 60 people pushing through a 0.8 m door: contacts between people and with the walls.
fn jam() -> Simulation {
    let groups = common::spawn(60, "0.2", "1.2");
    let mut scene = common::room(0.8, 0.05, 10.0, &groups);
    scene.output.contacts = true;
    Simulation::new(scene).unwrap()
}

#[test]
fn contact_forces_balance_every_persons_change_of_velocity() {
    let mut sim = jam();
    sim.advance_to(2.0, &mut ()).unwrap();
    let n_ids = sim.total_people();
    let mu = 0.05;
    let (mut checked, mut pairs, mut walls) = (0, 0, 0);
    for _ in 0..10 {
        // Before the step: positions and desired velocities, by id.
        let mut q0 = vec![f64::NAN; 2 * n_ids];
        sim.frame().positions_by_id(&mut q0);
        let mut w_index = vec![0.0; sim.people().len() * 2];
        sim.desired_velocities(&mut w_index);
        let mut w = vec![f64::NAN; 2 * n_ids];
        for (k, &id) in sim.people().ids().iter().enumerate() {
            w[2 * id as usize] = w_index[2 * k];
            w[2 * id as usize + 1] = w_index[2 * k + 1];
        }
        let report = sim.step(mu).unwrap();
        let frame = sim.frame();
        let mut q1 = vec![f64::NAN; 2 * n_ids];
        frame.positions_by_id(&mut q1);

        // Σ λ n per person, the normals from the positions at the start of the step.
        let mut push = vec![0.0; 2 * n_ids];
        let segments = sim.walls().segments();
        for c in frame.contact_forces() {
            let a = c.a as usize;
            let pa = [q0[2 * a], q0[2 * a + 1]];
            match c.kind {
                ContactKind::PersonPerson => {
                    let b = c.b as usize;
                    let d = [pa[0] - q0[2 * b], pa[1] - q0[2 * b + 1]];
                    let len = d[0].hypot(d[1]);
                    for k in 0..2 {
                        push[2 * a + k] += c.lambda * d[k] / len;
                        push[2 * b + k] -= c.lambda * d[k] / len;
                    }
                    pairs += 1;
                }
                ContactKind::PersonWall => {
                    let closest = segments[c.b as usize].closest(pa);
                    let d = [pa[0] - closest[0], pa[1] - closest[1]];
                    let len = d[0].hypot(d[1]);
                    for k in 0..2 {
                        push[2 * a + k] += c.lambda * d[k] / len;
                    }
                    walls += 1;
                }
                ContactKind::MovingWall => panic!("the room has no moving bodies"),
            }
        }
        // ½|v − w − Jᵀλ|² ≤ gap = ε/(2μ²) for the certified pair (the gap is that plus
        // λᵀs ≥ 0), summed over the people still present.
        let mut residual = 0.0;
        for id in 0..n_ids {
            if q1[2 * id].is_nan() {
                continue; // left in this step
            }
            for k in 0..2 {
                let v = (q1[2 * id + k] - q0[2 * id + k]) / mu;
                residual += (v - w[2 * id + k] - push[2 * id + k]).powi(2);
            }
            checked += 1;
        }
        let bound = report.eps / (mu * mu);
        assert!(
            residual <= bound * (1.0 + 1e-6) + 1e-20,
            "step {}: Σ|v − w − Σλn|² = {residual:e} > ε/μ² = {bound:e}",
            report.step
        );
    }
    assert!(
        pairs > 50 && walls > 5,
        "a jam has contacts: {pairs} pairs, {walls} walls"
    );
    assert!(checked > 300);
}

#[test]
fn contact_forces_agree_with_clarabel_on_the_same_projection() {
    let mut sim = jam();
    sim.advance_to(3.0, &mut ()).unwrap();
    let report = sim.step(0.05).unwrap();
    let p = sim.last_projection();
    let lambda = sim.last_multipliers();
    let mut v = p.w.to_vec();
    let clamped: Vec<f64> = lambda.iter().map(|l| l.max(0.0)).collect();
    p.jacobian.mul_transpose_add(&clamped, &mut v);

    let mut clarabel = ClarabelReference::new(ClarabelSettings::default());
    let mut reference = ProjectionSolution::default();
    let target = Target {
        gap: 1e-12,
        violation: 1e-12,
    };
    let r = clarabel.solve(&p, target, &mut reference).unwrap();
    let (mut sm, mut sn) = (vec![0.0; p.rows()], vec![0.0; p.dim()]);
    let c_ref = certify(&p, &reference.v, &reference.lambda, &mut sm, &mut sn);
    // Strong convexity: ½|v − v*|² ≤ gap(v, λ) for each certified pair against the exact v*.
    let c_ours = certify(&p, &v, lambda, &mut sm, &mut sn);
    assert!(c_ours.gap <= 1e-5, "{c_ours:?}");
    let dist: f64 = v
        .iter()
        .zip(&reference.v)
        .map(|(a, b)| (a - b) * (a - b))
        .sum();
    assert!(
        dist.sqrt() <= (2.0 * c_ours.gap).sqrt() + (2.0 * c_ref.gap).sqrt() + 1e-9,
        "|v − v_clarabel| = {:e}, gaps {:e} and {:e} ({:?})",
        dist.sqrt(),
        c_ours.gap,
        c_ref.gap,
        r.status
    );
    // The multipliers as a dual point: D(λ) = −½|Jᵀλ|² − λᵀ(b + J w) is within our gap of
    // Clarabel's optimum P(v*) = ½|v* − w|², and never above it (weak duality).
    let dual = |l: &[f64]| {
        let mut jtl = vec![0.0; p.dim()];
        p.jacobian.mul_transpose_add(l, &mut jtl);
        let mut jw = vec![0.0; p.rows()];
        p.jacobian.mul(p.w, &mut jw);
        -0.5 * jtl.iter().map(|x| x * x).sum::<f64>()
            - l.iter()
                .zip(p.b.iter().zip(&jw))
                .map(|(l, (b, jw))| l * (b + jw))
                .sum::<f64>()
    };
    let primal_ref: f64 = 0.5
        * reference
            .v
            .iter()
            .zip(p.w)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>();
    let d_ours = dual(&clamped);
    assert!(
        d_ours <= primal_ref + c_ref.gap + 1e-12
            && primal_ref - d_ours <= c_ours.gap + c_ref.gap + 1e-12,
        "D(λ) = {d_ours:e}, P(v*) = {primal_ref:e}, gaps {:e}, {:e}",
        c_ours.gap,
        c_ref.gap
    );
    let active = clamped.iter().filter(|&&l| l > 0.0).count();
    assert!(
        active > 20 && report.active > 20,
        "{active} contacts pushing"
    );
}
