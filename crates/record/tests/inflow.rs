//! A run whose people enter as it goes, recorded into its run file (directly, and through the
//! writer thread `moreau run` uses): the file holds every person who was ever in the run, with
//! their radius, trajectory and exit, and people simply appear in later frames.

use std::path::{Path, PathBuf};

use moreau_crowd::{Scene, Simulation};
use moreau_io::{BackgroundWriter, Overwrite, RunFile, RunSink, RunWriter};
use moreau_record::{Record, header, run_to_horizon};

/// `name` in a directory of its own, under cargo's scratch directory for integration tests
/// (in `target/`), emptied first: nothing piles up in /tmp.
fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("moreau-record-{name}.d"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// The gate-inflow scene to 16 s: 20 people waiting at the start, 48 entering, some leaving.
fn scene() -> Scene {
    let mut scene = Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/gate-inflow.toml"
    ))
    .unwrap();
    scene.time.horizon = 16.0;
    scene
}

/// Runs the scene into `path`, through the writer thread or not; returns the simulation.
fn record(path: &Path, threaded: bool) -> Simulation {
    let mut sim = Simulation::new(scene()).unwrap();
    let writer = RunWriter::create(path, &header(&sim, "test".into()), Overwrite::Never).unwrap();
    let people = sim.total_people();
    if threaded {
        let mut w = BackgroundWriter::new(writer);
        let mut rec = Record::new(Some(&mut w as &mut dyn RunSink), people);
        run_to_horizon(&mut sim, &mut rec).unwrap();
        w.finish("complete", "{}").unwrap();
    } else {
        let mut w = writer;
        let mut rec = Record::new(Some(&mut w as &mut dyn RunSink), people);
        run_to_horizon(&mut sim, &mut rec).unwrap();
        w.finish("complete", "{}").unwrap();
    }
    sim
}

#[test]
fn the_run_file_holds_everyone_who_entered() {
    let path = scratch("inflow.h5");
    let sim = record(&path, false);
    let (start, total) = (20, sim.total_people());
    assert_eq!(total, start + 48, "3 a second for 16 s");
    assert!(
        !sim.exit_records().is_empty(),
        "nobody left: the test would not see exits"
    );

    let f = RunFile::open(&path).unwrap();
    let radii = f.header().unwrap().radii;
    assert_eq!(radii.len(), total);
    let people = sim.people();
    for (i, &id) in people.ids().iter().enumerate() {
        assert_eq!(radii[id as usize], people.radii()[i], "radius of {id}");
    }
    let exits: Vec<(u32, f64)> = f
        .exits()
        .unwrap()
        .iter()
        .map(|r| (r.id as u32, r.t))
        .collect();
    let recorded: Vec<(u32, f64)> = sim.exit_records().iter().map(|r| (r.id, r.t)).collect();
    assert_eq!(exits, recorded);

    // Every trajectory row is the dense array at (frame, id); every person is in some frame,
    // the newcomers from a later frame than the one before them.
    let traj = f.trajectory().unwrap();
    let frames = f.frame_times().unwrap().len();
    let mut first = vec![usize::MAX; total];
    let mut per_frame = vec![0i64; frames];
    let mut dense = Vec::new();
    let mut at = usize::MAX;
    for r in &traj {
        let (id, frame) = (r.id as usize, r.frame as usize);
        if frame != at {
            dense = f.positions(frame).unwrap();
            assert_eq!(dense.len(), 2 * total);
            at = frame;
        }
        assert_eq!([dense[2 * id], dense[2 * id + 1]], [r.x, r.y]);
        first[id] = first[id].min(frame);
        per_frame[frame] += 1;
    }
    assert_eq!(per_frame, f.frame_counts().unwrap());
    assert!(first[..start].iter().all(|&k| k == 0));
    assert!(first.iter().all(|&k| k < frames), "somebody is in no frame");
    assert!(
        first[start..].windows(2).all(|w| w[0] <= w[1]) && first[start] > 0,
        "{first:?}"
    );
    // The frames before a newcomer's first hold NaN for them.
    let last = total - 1;
    let before = f.positions(first[last] - 1).unwrap();
    assert!(before[2 * last].is_nan() && before[2 * last + 1].is_nan());

    // The writer thread `moreau run` uses writes the same.
    let threaded = scratch("inflow-threaded.h5");
    record(&threaded, true);
    let g = RunFile::open(&threaded).unwrap();
    assert_eq!(g.header().unwrap().radii, radii);
    assert_eq!(g.trajectory().unwrap(), traj);
    assert_eq!(g.exits().unwrap(), f.exits().unwrap());
}
