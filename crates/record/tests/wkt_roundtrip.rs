//! The walkable area survives its trip through a run file: the `wkt_geometry` a run writes,
//! read back as a scene's `area = "..."`, gives the same scene and the same walls, bit for
//! bit.

use moreau_crowd::{Scene, Segment, Simulation};
use moreau_io::{Overwrite, RunFile, RunSink, RunWriter};
use moreau_record::{Record, Summary};

/// A room with two tables (holes), shortened (3 people a group, 1 s), with the tables moved
/// by (1/3, 1/7) m: coordinates with every digit of an `f64` in use.
fn small_room_with_holes() -> Scene {
    let mut scene = Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/room-two-exits.toml"
    ))
    .unwrap();
    assert_eq!(scene.area.holes.len(), 2);
    for p in scene.area.holes.iter_mut().flatten() {
        *p = [p[0] + 1.0 / 3.0, p[1] + 1.0 / 7.0];
    }
    scene.time.horizon = 1.0;
    for g in &mut scene.groups {
        g.count = Some(3);
    }
    scene.validate().unwrap();
    scene
}

/// A segment's ends, bit for bit.
fn bits(s: &Segment) -> [u64; 4] {
    [s.a[0], s.a[1], s.b[0], s.b[1]].map(f64::to_bits)
}

#[test]
fn the_run_files_wkt_reads_back_to_the_same_area_and_walls() {
    let scene = small_room_with_holes();
    let dir = std::env::temp_dir().join(format!("moreau-record-wkt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("room.h5");

    // The run, as `moreau run` writes it.
    let mut sim = Simulation::new(scene.clone()).unwrap();
    let header = moreau_record::header(&sim, "wkt_roundtrip".into());
    let mut writer = RunWriter::create(&path, &header, Overwrite::Allowed).unwrap();
    let mut record = Record::new(Some(&mut writer as &mut dyn RunSink), sim.total_people());
    moreau_record::run_to_horizon(&mut sim, &mut record).unwrap();
    let summary = Summary::new(&sim, &record, "test".into(), None, "complete".into(), 0.0);
    drop(record);
    writer.finish("complete", &summary.to_json()).unwrap();

    let file = RunFile::open(&path).unwrap();
    let wkt = file.text("wkt_geometry").unwrap();
    assert_eq!(wkt, scene.wkt());
    assert_eq!(wkt.matches("), (").count(), 2, "two holes: {wkt}");
    assert!(wkt.contains("4.333333333333333 2.642857142857143"), "{wkt}");
    let file_walls = file.walls().unwrap();

    // The scene again, with its area as that WKT.
    let mut table: toml::Table = toml::from_str(&scene.to_toml()).unwrap();
    table.insert("area".into(), toml::Value::String(wkt.clone()));
    let text = toml::to_string(&table).unwrap();
    assert!(text.contains("area = \"POLYGON (("), "{text}");
    let again = Scene::from_toml(&text, "<wkt from the run file>").unwrap();

    assert_eq!(again.area, scene.area);
    assert_eq!(again, scene);
    let (walls, walls_again) = (scene.walls(), again.walls());
    assert_eq!(walls.len(), 20 + 4 + 4);
    assert_eq!(
        walls.iter().map(bits).collect::<Vec<_>>(),
        walls_again.iter().map(bits).collect::<Vec<_>>()
    );
    // And the walls of its simulation are those the run file holds.
    let sim_again = Simulation::new(again).unwrap();
    let from_sim: Vec<[u64; 4]> = sim_again.walls().segments().iter().map(bits).collect();
    let from_file: Vec<[u64; 4]> = file_walls.iter().map(|w| w.map(f64::to_bits)).collect();
    assert_eq!(from_sim, from_file);
    std::fs::remove_dir_all(&dir).unwrap();
}
