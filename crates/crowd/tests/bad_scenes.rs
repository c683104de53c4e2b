//! Every bad scene in `tests/bad-scenes/` fails with a clear error naming the field and value.

use moreau_crowd::{Scene, Simulation};

/// Reads, validates and builds a scene; the first error, as text.
fn error_of(file: &str) -> String {
    let path = format!(
        "{}/../../tests/bad-scenes/{file}",
        env!("CARGO_MANIFEST_DIR")
    );
    match Scene::from_file(&path).and_then(Simulation::new) {
        Ok(_) => panic!("{file} was accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_scenes_give_errors_that_name_the_field_and_value() {
    let cases = [
        (
            "negative-radius.toml",
            &["groups[0].radius", "-0.2", "> 0"][..],
        ),
        ("nan-speed.toml", &["groups[0].speed", "NaN"]),
        (
            "duplicate-group-name.toml",
            &["groups[1].name", "= g", "duplicate group name"],
        ),
        (
            "source-named-like-a-group.toml",
            &["sources[0].name", "waiting", "a group has this name"],
        ),
        (
            // Regression: "expected a number, or a range" at `[[groups]]`, `speed` never named.
            "missing-speed.toml",
            &["line 14", "missing field `speed`"],
        ),
        (
            // Regression: taken, `mean` ignored.
            "radius-range-extra-key.toml",
            &[
                "line 18",
                "mean = 0.22",
                "a range `{ min = …, max = … }` with no other key",
            ],
        ),
        (
            // Regression: "data did not match any variant of untagged enum Quantity".
            "speed-in-words.toml",
            &["line 19", "\"fast\"", "expected a number, or a range"],
        ),
        (
            "overlapping-positions.toml",
            &[
                "groups[0].positions[1]",
                "[1.3, 1.0]",
                "overlaps the person at [1.0, 1.0]",
            ],
        ),
        (
            "group-cannot-fit.toml",
            &["groups[0].count", "500", "people fit in the spawn region"],
        ),
        (
            "person-outside.toml",
            &["groups[0].positions[0]", "[7.0, 1.0]", "walkable area"],
        ),
        (
            "person-in-wall.toml",
            &["groups[0].positions[0]", "[0.1, 3.0]", "walkable area"],
        ),
        ("zero-step.toml", &["time.step", "0", "> 0"]),
        (
            "max-violation-a-radius.toml",
            &[
                "solver.max_violation",
                "0.3",
                "below the smallest radius, 0.15 m (groups[0].radius)",
            ],
        ),
        (
            "too-many-threads.toml",
            &["solver.threads", "100000", "at most 1024"],
        ),
        (
            "unknown-destination.toml",
            &[
                "groups[0].destination",
                "window",
                "no exit has this name (the exits: door)",
            ],
        ),
        (
            // Regression: said only "only 0 people fit in the spawn region (16.00 m²) after
            // 30000 random tries", not why.
            "spawn-outside-area.toml",
            &[
                "groups[0].count",
                "only 0 people fit",
                "none fell inside both the spawn region and the walkable area",
                "does groups[0].spawn lie in [area]?",
            ],
        ),
        (
            "unreachable-destination.toml",
            &["groups[0].destination", "door", "unreachable"],
        ),
        (
            "exit-narrower-than-a-cell.toml",
            &["exits[0]", "door", "solver.grid_cell (now 0.1) smaller"],
        ),
        (
            "estimate-without-tol.toml",
            &["time.estimate", "step-doubling", "give time.tol too"],
        ),
        (
            "exit-empty-name.toml",
            &["exits[0].name", "\"\"", "an exit needs a name"],
        ),
        (
            "moving-named-like-a-panel.toml",
            &["moving[0].name", "exit:door", "the panels of exits"],
        ),
        (
            "position-three-numbers.toml",
            &[
                "groups[0].positions[0]",
                "[1.0, 1.0, 5.0]",
                "3 elements given",
            ],
        ),
        (
            "segment-three-points.toml",
            &[
                "exits[0].segment",
                "3 elements given: a segment is two points",
            ],
        ),
        (
            "source-in-an-exit-that-opens-later.toml",
            &[
                "sources[0].area",
                "the exit 'door' already counts people out",
            ],
        ),
        (
            "group-in-an-exit-that-opens-later.toml",
            &[
                "exits[0].area",
                "person 0 of groups[0] starts at [8.08, 1.7]",
            ],
        ),
        (
            "moving-too-fast.toml",
            &[
                "moving[0].keyframes[1].t",
                "0.50000001",
                "below the 1e-9 s a run allows",
            ],
        ),
        ("unknown-key.toml", &["unknown field", "colour"]),
        (
            "solver-interior-step-fraction.toml",
            &["solver.interior.step_fraction", "2", "must be in (0, 1)"],
        ),
        (
            "solver-unknown-setting.toml",
            &["unknown field", "max_update", "max_updates"],
        ),
        ("empty-polygon.toml", &["area.outer", "0 vertices"]),
        ("no-groups.toml", &["groups", "no people"]),
        (
            "wkt-unclosed-parenthesis.toml",
            &[
                "at area = POLYGON ((0 0, 6 0, 6 6, 0 6, 0 0)",
                "not valid WKT",
                "Missing closing parenthesis",
            ],
        ),
        (
            "wkt-file-missing.toml",
            &[
                "at area.wkt_file = no-such-room.wkt",
                "cannot read",
                "bad-scenes/no-such-room.wkt",
            ],
        ),
        (
            "wkt-linestring.toml",
            &[
                "at area = LINESTRING (0 0, 6 0, 6 6, 0 6)",
                "a LINESTRING: the walkable area is a POLYGON",
            ],
        ),
        ("negative-release.toml", &["groups[0].release", "-1", "≥ 0"]),
        ("source-rate-zero.toml", &["sources[0].rate", "0", "> 0"]),
        (
            "source-outside.toml",
            &[
                "sources[0].area",
                "[-1.0, 0.0]",
                "outside the walkable area",
            ],
        ),
        (
            "source-unknown-destination.toml",
            &["sources[0].destination", "window", "(the exits: "],
        ),
        (
            "source-too-many.toml",
            &["sources[0].rate", "1000000", "more than the limit of 1e7"],
        ),
        (
            "source-stop-before-start.toml",
            &["sources[0].stop", "1", "> start = 1.5"],
        ),
        (
            "source-no-room.toml",
            &["sources[0].area", "radius 0.2", "clear of the walls"],
        ),
    ];
    let on_disk = std::fs::read_dir(format!(
        "{}/../../tests/bad-scenes",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
    .count();
    assert_eq!(on_disk, cases.len(), "every bad scene file has a case");
    for (file, needles) in cases {
        let msg = error_of(file);
        for n in needles {
            assert!(
                msg.contains(n),
                "{file}: error does not mention {n:?}: {msg}"
            );
        }
    }
}

#[test]
fn the_reference_scenes_are_valid_and_round_trip() {
    for name in ["room-150", "dense-2000", "gate-inflow"] {
        let path = format!(
            "{}/../../data/scenes/{name}.toml",
            env!("CARGO_MANIFEST_DIR")
        );
        let scene = Scene::from_file(&path).unwrap();
        let again = Scene::from_toml(&scene.to_toml(), "<round trip>").unwrap();
        assert_eq!(scene, again);
    }
}

#[test]
fn dense_scene_is_dense_and_has_a_bottleneck() {
    let path = format!(
        "{}/../../data/scenes/dense-2000.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let sim = Simulation::new(Scene::from_file(&path).unwrap()).unwrap();
    let n = sim.total_people();
    assert_eq!(n, 2000);
    // 2,000 people in the 40 m × 20 m hall.
    assert!(n as f64 / 800.0 >= 2.5);
}
