//! A walkable area given as WKT (`area = "POLYGON (...)"`, `[area] wkt_file = ...`) is the
//! same scene as one given by its rings: same value, same walls, same TOML; a bad one fails
//! with the same field-named errors.

use std::path::PathBuf;

use moreau_crowd::{CrowdError, Scene};

/// The 10 m × 10 m room with a 2 m × 2 m pillar in the middle, by its rings.
const RINGS: &str = "[area]
outer = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
holes = [[[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0]]]
";

/// The same room as WKT (rings closed, as WKT has them).
const WKT: &str = "POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (4 4, 6 4, 6 6, 4 6, 4 4))";

/// A scene whose area is `area` (TOML: `area = "..."` or an `[area]` table).
fn scene_text(area: &str) -> String {
    format!(
        r#"name = "wkt"
seed = 3
{area}
[[exits]]
name = "door"
area = [[9.5, 4.0], [10.0, 4.0], [10.0, 6.0], [9.5, 6.0]]
action = "remove"

[[groups]]
name = "g"
count = 5
spawn = [[0.5, 0.5], [3.0, 0.5], [3.0, 9.5], [0.5, 9.5]]
radius = 0.2
speed = 1.0
destination = "door"

[time]
horizon = 2.0
step = 0.05
output_interval = 0.1
"#
    )
}

fn read(area: &str) -> Result<Scene, CrowdError> {
    Scene::from_toml(&scene_text(area), "<test>")
}

/// The error of reading a scene whose area is `area`, as text.
fn error(area: &str) -> String {
    match read(area) {
        Ok(_) => panic!("accepted: {area}"),
        Err(e) => e.to_string(),
    }
}

fn assert_mentions(msg: &str, needles: &[&str]) {
    for n in needles {
        assert!(msg.contains(n), "error does not mention {n:?}: {msg}");
    }
}

/// A directory of its own for this test process.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("moreau-wkt-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn an_area_as_wkt_is_the_same_scene_as_its_rings() {
    let rings = read(RINGS).unwrap();
    for area in [
        format!("area = {WKT:?}"),
        format!(
            "area = {:?}",
            WKT.replace("POLYGON (", "MULTIPOLYGON ((") + ")"
        ),
        format!("area = {:?}", WKT.to_lowercase().replace(", ", ",")),
    ] {
        let wkt = read(&area).unwrap();
        assert_eq!(wkt, rings, "{area}");
        assert_eq!(wkt.walls(), rings.walls(), "{area}");
        // Written back as rings, and read back to the same scene.
        let text = wkt.to_toml();
        assert!(
            text.contains("outer = ") && !text.contains("POLYGON"),
            "{text}"
        );
        assert_eq!(Scene::from_toml(&text, "<round trip>").unwrap(), wkt);
    }
    assert_eq!(rings.wkt(), WKT);
}

#[test]
fn a_wkt_file_is_read_relative_to_the_scene_file() {
    let dir = scratch("file");
    std::fs::create_dir_all(dir.join("geometry")).unwrap();
    std::fs::write(dir.join("geometry/room.wkt"), format!("{WKT}\n")).unwrap();
    let text = scene_text("[area]\nwkt_file = \"geometry/room.wkt\"\n");
    std::fs::write(dir.join("scene.toml"), &text).unwrap();

    let rings = read(RINGS).unwrap();
    assert_eq!(Scene::from_file(dir.join("scene.toml")).unwrap(), rings);
    assert_eq!(Scene::from_toml_in(&text, "<test>", &dir).unwrap(), rings);
    // from_toml reads it relative to the current directory (the crate's, under cargo test),
    // where it is not.
    let msg = Scene::from_toml(&text, "<test>").unwrap_err().to_string();
    assert_mentions(
        &msg,
        &[
            "at area.wkt_file = geometry/room.wkt",
            "cannot read geometry/room.wkt",
        ],
    );

    // A file that starts with a byte-order mark (as editors on Windows write UTF-8) was
    // refused as "non-ascii word".
    std::fs::write(dir.join("geometry/room.wkt"), format!("\u{feff}{WKT}\n")).unwrap();
    assert_eq!(Scene::from_file(dir.join("scene.toml")).unwrap(), rings);

    // A file that holds something else says which file and what.
    std::fs::write(dir.join("geometry/room.wkt"), "POINT (1 2)").unwrap();
    let msg = Scene::from_file(dir.join("scene.toml"))
        .unwrap_err()
        .to_string();
    assert_mentions(
        &msg,
        &[
            "at area.wkt_file = geometry/room.wkt",
            "room.wkt holds POINT (1 2): a POINT: the walkable area is a POLYGON",
        ],
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_invalid_polygon_in_wkt_gets_the_errors_of_its_rings() {
    // A bow tie: the outer ring crosses itself.
    assert_mentions(
        &error("area = \"POLYGON ((0 0, 10 10, 10 0, 0 8, 0 0))\""),
        &["at area.outer", "the boundary crosses itself"],
    );
    // A hole reaching out of the room.
    assert_mentions(
        &error("area = \"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (4 4, 12 4, 12 6, 4 6, 4 4))\""),
        &[
            "at area.holes[0]",
            "[12.0, 4.0]",
            "hole vertex outside the outer polygon",
        ],
    );
    // Two vertices once the closing one is dropped.
    assert_mentions(
        &error("area = \"POLYGON ((0 0, 10 0, 0 0))\""),
        &["at area.outer", "2 vertices", "at least 3"],
    );
    // Infinite coordinates parse as numbers and are refused as such.
    assert_mentions(
        &error("area = \"POLYGON ((0 0, +inf 0, 10 10, 0 0))\""),
        &["at area.outer[1]", "finite"],
    );
    // A ring left open.
    assert_mentions(
        &error("area = \"POLYGON ((0 0, 10 0, 10 10, 0 10))\""),
        &[
            "at area = POLYGON",
            "ring 0 (the outer boundary) is not closed",
        ],
    );
}

#[test]
fn the_area_table_keeps_serdes_errors_with_their_line() {
    // Rings and a file at once.
    let msg = error("[area]\nouter = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]\nwkt_file = \"a.wkt\"\n");
    assert_mentions(&msg, &["line 3", "not both"]);
    // A misspelt key: named, with its line, as for every other table.
    let msg = error("[area]\noutr = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]\n");
    assert_mentions(
        &msg,
        &[
            "line 4",
            "unknown field `outr`",
            "expected one of `outer`, `holes`, `wkt_file`",
        ],
    );
    // Neither rings nor a file.
    assert_mentions(&error("[area]\nholes = []\n"), &["missing field `outer`"]);
    // Not a string nor a table.
    assert_mentions(
        &error("area = 5"),
        &["line 3", "invalid type: integer `5`", "WKT string"],
    );
}

#[test]
fn a_scene_read_by_serde_alone_is_not_valid_until_its_wkt_is_read() {
    // The WKT is read by Scene::from_toml and Scene::from_file; a scene deserialized
    // otherwise keeps it unread and says so rather than failing on an empty polygon.
    let scene: Scene = toml::from_str(&scene_text(&format!("area = {WKT:?}"))).unwrap();
    let msg = scene.validate().unwrap_err().to_string();
    assert_mentions(&msg, &["at area = POLYGON ((0 0,", "WKT not read"]);
}

#[test]
fn mutated_wkt_gives_an_error_or_a_scene_whose_wkt_reads_back_to_it() {
    use proptest::prelude::*;
    use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

    // The room's WKT cut somewhere, a few WKT-ish characters put there, the rest kept or not.
    let piece = prop::collection::vec(
        prop::sample::select(vec![
            '(', ')', ',', ' ', '0', '1', '9', '.', '-', '+', 'e', 'Z', 'M', 'P',
        ]),
        0..8,
    );
    let strategy = (0..=WKT.len(), piece, any::<bool>());
    let mut runner = TestRunner::new_with_rng(
        Config {
            cases: 4000,
            failure_persistence: None,
            ..Config::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &[7; 32]),
    );
    let (accepted, refused) = (std::cell::Cell::new(0), std::cell::Cell::new(0));
    runner
        .run(&strategy, |(cut, piece, keep_rest)| {
            let piece: String = piece.into_iter().collect();
            let rest = if keep_rest { &WKT[cut..] } else { "" };
            let text = format!("{}{piece}{rest}", &WKT[..cut]);
            match read(&format!("area = {text:?}")) {
                Ok(scene) => {
                    accepted.set(accepted.get() + 1);
                    let again = read(&format!("area = {:?}", scene.wkt())).unwrap();
                    prop_assert_eq!(again, scene, "{}", text);
                }
                Err(e) => {
                    refused.set(refused.get() + 1);
                    // The TOML is valid: every refusal is a value's, naming its field (the
                    // area's, or one the new area no longer fits).
                    prop_assert!(matches!(e, CrowdError::Invalid { .. }), "{}: {}", text, e);
                }
            }
            Ok(())
        })
        .unwrap();
    // Both outcomes were met (a mutation that keeps the text whole is accepted).
    let (accepted, refused) = (accepted.get(), refused.get());
    assert!(
        accepted > 0 && refused > 0,
        "{accepted} accepted, {refused} refused"
    );
    eprintln!("{accepted} accepted, {refused} refused");
}

/// The 10 m room's `[area]` with `holes`, by their rings.
fn with_holes(holes: &str) -> String {
    format!(
        "[area]\nouter = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]\nholes = {holes}\n"
    )
}

#[test]
fn an_obstacle_against_the_right_or_top_wall_was_refused_as_outside() {
    // The even–odd test is half-open: a hole's vertex on the outer ring's right or top edge
    // counted as outside ("hole vertex outside the outer polygon"), on its left or bottom edge
    // as inside. Obstacles against walls are common (JuPedSim geometries).
    for hole in [
        "[[0.0, 2.0], [1.0, 2.0], [1.0, 3.0], [0.0, 3.0]]",
        "[[9.0, 2.0], [10.0, 2.0], [10.0, 3.0], [9.0, 3.0]]",
        "[[2.0, 0.0], [3.0, 0.0], [3.0, 1.0], [2.0, 1.0]]",
        "[[2.0, 9.0], [3.0, 9.0], [3.0, 10.0], [2.0, 10.0]]",
    ] {
        read(&with_holes(&format!("[{hole}]"))).unwrap_or_else(|e| panic!("{hole}: {e}"));
    }
    // Two obstacles side by side touch; a corner of the room is still outside.
    read(&with_holes(
        "[[[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]], [[3.0, 2.0], [4.0, 2.0], [4.0, 3.0], [3.0, 3.0]]]",
    ))
    .unwrap();
    assert_mentions(
        &error(&with_holes(
            "[[[9.0, 2.0], [10.5, 2.0], [10.5, 3.0], [9.0, 3.0]]]",
        )),
        &[
            "at area.holes[0]",
            "[10.5, 2.0]",
            "outside the outer polygon",
        ],
    );
}

#[test]
fn a_hole_running_outside_the_room_between_vertices_on_its_walls_was_taken() {
    // A room with a door's gap cut in its bottom wall (the outer ring's notch 4 → 6, 0 → 0.5)
    // and an obstacle whose bottom edge closes the gap: every vertex on or inside the outer
    // ring, no edge crossing it, but the edge 4 → 6 at y = 0 runs outside. It ran, and PedPy's
    // Voronoi cells raised "TopologyException: side location conflict" on the run file.
    let notched = |hole: &str| {
        format!(
            "[area]\nouter = [[0.0, 0.0], [4.0, 0.0], [4.0, 0.5], [6.0, 0.5], [6.0, 0.0], \
             [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]\nholes = [{hole}]\n"
        )
    };
    assert_mentions(
        &error(&notched("[[4.0, 0.0], [6.0, 0.0], [6.0, 3.0], [4.0, 3.0]]")),
        &[
            "at area.holes[0]",
            "runs outside the outer polygon",
            "[5.0, 0.0]",
        ],
    );
    // An edge whose midpoint is on the ring: the bottom edge 0 → 8 at y = 0 has its middle
    // at the notch's corner (4, 0), and runs outside from there to (6, 0).
    assert_mentions(
        &error(&notched("[[0.0, 0.0], [8.0, 0.0], [8.0, 3.0], [0.0, 3.0]]")),
        &[
            "at area.holes[0]",
            "runs outside the outer polygon",
            "[5.0, 0.0]",
        ],
    );
    // An obstacle beside the gap, against the wall, is still taken.
    read(&notched("[[1.0, 0.0], [3.0, 0.0], [3.0, 3.0], [1.0, 3.0]]")).unwrap();
}

#[test]
fn overlapping_and_nested_holes_ran_and_their_file_failed_in_pedpy() {
    // Holes that overlap, lie in one another, or leave the room between their vertices were
    // taken; the run file's area then failed in PedPy ("Holes need to be inside the walkable
    // area"). Now refused by name.
    assert_mentions(
        &error(&with_holes(
            "[[[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]], [[2.5, 2.5], [3.5, 2.5], [3.5, 3.5], [2.5, 3.5]]]",
        )),
        &[
            "at area.holes[1]",
            "crosses area.holes[0]'s edge",
            "merge them",
        ],
    );
    assert_mentions(
        &error(&with_holes(
            "[[[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0]], [[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]]]",
        )),
        &["at area.holes[1]", "it lies in area.holes[0]"],
    );
    assert_mentions(
        &error(&with_holes(
            "[[[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]], [[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0]]]",
        )),
        &["at area.holes[1]", "area.holes[0] lies in it"],
    );
    // A triangle inscribed in a square: no vertex inside it, no edge crossing.
    assert_mentions(
        &error(&with_holes(
            "[[[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0]], [[3.0, 1.0], [5.0, 3.0], [1.0, 3.0]]]",
        )),
        &["at area.holes[1]", "it lies in area.holes[0]"],
    );
    // The same hole twice, either way round: every point of each on the other's boundary,
    // none inside, and it ran (the file's area then had a self-intersection in shapely).
    for second in [
        "[[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]]",
        "[[2.0, 3.0], [3.0, 3.0], [3.0, 2.0], [2.0, 2.0]]",
    ] {
        assert_mentions(
            &error(&with_holes(&format!(
                "[[[2.0, 2.0], [3.0, 2.0], [3.0, 3.0], [2.0, 3.0]], {second}]"
            ))),
            &["at area.holes[1]", "it is area.holes[0] again"],
        );
    }
    // An L-shaped room whose triangular hole has its vertices inside but an edge through the
    // notch.
    let msg = error(
        "[area]\nouter = [[0.0, 0.0], [8.0, 0.0], [8.0, 3.0], [3.0, 3.0], [3.0, 8.0], [0.0, 8.0]]\n\
         holes = [[[2.0, 2.0], [5.0, 2.0], [2.0, 5.0]]]\n",
    );
    assert_mentions(
        &msg,
        &["at area.holes[0]", "crosses the outer boundary's edge"],
    );
}

#[test]
fn a_ring_with_its_closing_vertex_was_refused_as_crossing_itself() {
    // A repeated vertex is an edge of zero length; the crossing check then took its
    // neighbours for non-adjacent edges and said "the boundary crosses itself".
    let msg =
        error("[area]\nouter = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.0, 0.0]]\n");
    assert_mentions(
        &msg,
        &[
            "at area.outer[4]",
            "repeats the first vertex",
            "leave the closing vertex out",
        ],
    );
    assert!(!msg.contains("crosses itself"), "{msg}");
    let msg = error(
        "[area]\nouter = [[0.0, 0.0], [10.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]\n",
    );
    assert_mentions(&msg, &["at area.outer[2]", "repeats the vertex before it"]);
    // WKT may repeat a point (OGC allows it): the same scene as without it.
    let repeated = read(
        "area = \"POLYGON ((0 0, 10 0, 10 0, 10 10, 0 10, 0 0), (4 4, 6 4, 6 6, 4 6, 4 6, 4 4))\"",
    )
    .unwrap();
    assert_eq!(repeated, read(RINGS).unwrap());
    assert_mentions(
        &error("area = \"POLYGON ((0 0, 0 0))\""),
        &["at area = POLYGON", "ring 0 is the one point (0 0)"],
    );
}

#[test]
fn a_room_3e8_m_from_the_origin_had_a_door_of_zero_area() {
    // The shoelace formula about the origin cancelled every digit of a small polygon far
    // from it: a 0.5 m² door at x = 3·10⁸ m had area −2 or 0 ("polygon has zero area"), a
    // 36 m² room at 10⁹ m none; scenes may lie within ±10¹⁵ m.
    for shift in [3e8, 1e9, 1e12] {
        let ring = |v: &[[f64; 2]]| {
            let pts: Vec<String> = v
                .iter()
                .map(|p| format!("[{:?}, {:?}]", p[0] + shift, p[1] + shift))
                .collect();
            format!("[{}]", pts.join(", "))
        };
        let text = scene_text(&with_holes("[]"))
            .replace(
                "outer = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]",
                &format!(
                    "outer = {}",
                    ring(&[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
                ),
            )
            .replace(
                "area = [[9.5, 4.0], [10.0, 4.0], [10.0, 6.0], [9.5, 6.0]]",
                &format!(
                    "area = {}",
                    ring(&[[9.5, 4.0], [10.0, 4.0], [10.0, 6.0], [9.5, 6.0]])
                ),
            )
            .replace(
                "spawn = [[0.5, 0.5], [3.0, 0.5], [3.0, 9.5], [0.5, 9.5]]",
                &format!(
                    "spawn = {}",
                    ring(&[[0.5, 0.5], [3.0, 0.5], [3.0, 9.5], [0.5, 9.5]])
                ),
            );
        Scene::from_toml(&text, "<test>").unwrap_or_else(|e| panic!("{shift}: {e}"));
    }
}
