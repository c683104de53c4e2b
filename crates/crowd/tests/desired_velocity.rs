//! The Lipschitz desired velocity (`[model] desired_velocity = "lipschitz"`, the default) has
//! no jump where the classic one (`desired_velocity = "classic"`) has them: where the wall
//! slide starts, and on arrival. Scenes say which one they ran with when serialized, and a run
//! file's scene that does not (stored when the classic one was the default) is read as classic.

mod common;

use moreau_crowd::{DesiredVelocityKind, Scene, Simulation};

/// The test room with one person of radius 0.2 at (5, 1), as TOML text with `model` as its
/// `[model]` table (`None`: no table).
fn one_person_room(model: Option<&str>) -> String {
    let groups = common::listed("one", &[[5.0, 1.0]], 0.2, 1.0);
    let mut table: toml::Table =
        toml::from_str(&common::room(1.0, 0.05, 1.0, &groups).to_toml()).expect("a scene's TOML");
    table.remove("model");
    if let Some(model) = model {
        table.insert(
            "model".into(),
            toml::from_str(model).expect("a [model] table"),
        );
    }
    toml::to_string(&table).unwrap()
}

/// The desired velocity of one person of radius 0.2 heading for the door of the test room,
/// at `x` along the line y = 1 next to the right wall (x = 6): the goal lies up and to the
/// right, so the wall slide turns it upwards.
fn along_the_wall(kind: DesiredVelocityKind, xs: &[f64]) -> Vec<[f64; 2]> {
    let groups = common::listed("one", &[[5.0, 1.0]], 0.2, 1.0);
    let mut scene = common::room(1.0, 0.05, 1.0, &groups);
    scene.model.desired_velocity = kind;
    along_the_wall_of(scene, xs)
}

/// [`along_the_wall`] in `scene`, one person of radius 0.2 at (5, 1).
fn along_the_wall_of(scene: Scene, xs: &[f64]) -> Vec<[f64; 2]> {
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

/// From 9 cm to 1 mm beyond the radius of a person at x next to the wall x = 6, in steps of
/// 0.1 mm.
fn approaching_the_wall() -> Vec<f64> {
    (0..=890)
        .map(|k| 6.0 - 0.2 - 0.09 + 1e-4 * k as f64)
        .collect()
}

/// The largest change of the desired velocity between two neighbouring positions (m/s).
fn largest_jump(u: &[[f64; 2]]) -> f64 {
    u.windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .fold(0.0, f64::max)
}

#[test]
fn the_lipschitz_wall_slide_has_no_jump_where_the_classic_one_has() {
    let xs = approaching_the_wall();
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

#[test]
fn a_scene_without_a_model_table_follows_the_lipschitz_desired_velocity() {
    let text = one_person_room(None);
    assert!(!text.contains("model"), "{text}");
    let scene = Scene::from_toml(&text, "no [model]").unwrap();
    assert_eq!(scene.model.desired_velocity, DesiredVelocityKind::Lipschitz);
    let xs = approaching_the_wall();
    let u = along_the_wall_of(scene, &xs);
    assert_eq!(u, along_the_wall(DesiredVelocityKind::Lipschitz, &xs));
    assert!(largest_jump(&u) < 3e-3, "{}", largest_jump(&u));
}

#[test]
fn desired_velocity_classic_still_gives_the_old_jumps() {
    let text = one_person_room(Some("desired_velocity = \"classic\""));
    let scene = Scene::from_toml(&text, "classic").unwrap();
    assert_eq!(scene.model.desired_velocity, DesiredVelocityKind::Classic);
    let xs = approaching_the_wall();
    let u = along_the_wall_of(scene, &xs);
    assert_eq!(u, along_the_wall(DesiredVelocityKind::Classic, &xs));
    // The part into the wall vanishes at once at 5 cm, as before the default changed.
    assert!(largest_jump(&u) > 0.1, "{}", largest_jump(&u));
}

#[test]
fn a_serialized_scene_names_its_desired_velocity_even_the_default() {
    for (kind, name) in [
        (DesiredVelocityKind::Lipschitz, "lipschitz"),
        (DesiredVelocityKind::Classic, "classic"),
    ] {
        let mut scene = Scene::from_toml(&one_person_room(None), "room").unwrap();
        scene.model.desired_velocity = kind;
        let text = scene.to_toml();
        let table: toml::Table = toml::from_str(&text).unwrap();
        assert_eq!(
            table["model"]["desired_velocity"].as_str(),
            Some(name),
            "{text}"
        );
        assert_eq!(Scene::from_toml(&text, "again").unwrap(), scene);
        assert_eq!(Scene::from_run_file(&text, "run file").unwrap(), scene);
    }
}

#[test]
fn a_run_file_scene_without_a_desired_velocity_ran_with_the_classic_one() {
    // Stored before the default changed: no [model], or a [model] without the kind.
    for model in [None, Some("field_update = 1.0")] {
        let text = one_person_room(model);
        let stored = Scene::from_run_file(&text, "old run file").unwrap();
        assert_eq!(stored.model.desired_velocity, DesiredVelocityKind::Classic);
        // Read as a scene file, the same text follows today's default.
        let file = Scene::from_toml(&text, "scene file").unwrap();
        assert_eq!(file.model.desired_velocity, DesiredVelocityKind::Lipschitz);
        assert_eq!(stored.model.field_update, file.model.field_update);
    }
}

/// Regression: the Lipschitz desired velocity slowed people down over their last metre to the
/// target area by the distance of the field's cell they stood in, so the speed fell in a
/// staircase of 0.1 m/s steps at each 0.1 m cell edge (not Lipschitz, against
/// seeds/000 (8)). One person of the paper's room walks through the door and on to the target
/// area (x ≥ 14) in steps of 5 ms (at most 5 mm each): in the open corridor (x > 12.5, no
/// wall within reach) the desired speed falls from 1 to near 0 by at most 0.005 a step, as
/// a slowing over 1 m at 1 m/s does.
#[test]
fn the_arrival_slowdown_was_a_staircase_of_cell_distances() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/room-150.toml"
    ))
    .unwrap()
    .replace("count = 150", "count = 1")
    .replace(
        "spawn = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]",
        "spawn = [[8.5, 4.5], [9.5, 4.5], [9.5, 5.5], [8.5, 5.5]]",
    );
    assert!(
        text.contains("spawn = [[8.5, 4.5]"),
        "the room's spawn area moved"
    );
    let scene = Scene::from_toml(&text, "one person").unwrap();
    assert_eq!(scene.model.desired_velocity, DesiredVelocityKind::Lipschitz);
    let mut sim = Simulation::new(scene).unwrap();
    // (x, desired speed) after each step in the corridor.
    let mut walk = Vec::new();
    let mut u = [0.0; 2];
    for _ in 0..1200 {
        sim.step(0.005).unwrap();
        sim.desired_velocities(&mut u);
        let x = sim.frame().positions[0];
        if x > 12.5 {
            walk.push((x, u[0].hypot(u[1])));
        }
    }
    let slowest = walk.iter().map(|w| w.1).fold(f64::INFINITY, f64::min);
    assert!(slowest < 0.2, "never slowed down: {slowest}");
    let jump = walk
        .windows(2)
        .map(|w| (w[1].1 - w[0].1).abs())
        .fold(0.0, f64::max);
    assert!(
        jump < 0.006,
        "the desired speed jumped by {jump} in one step"
    );
}
