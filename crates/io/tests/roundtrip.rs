//! The run file reads back what was written, refuses to overwrite, and leaves nothing behind
//! when it cannot be created.

use std::path::PathBuf;

use moreau_core::{SolveStatus, StepReport};
use moreau_io::{ContactRow, IoError, Overwrite, RunFile, RunHeader, RunWriter, StepRow};

/// `name` in a directory of its own: tests run in parallel, and one checks that its directory
/// holds no `.partial` file while another may be laying one out. Under cargo's scratch
/// directory for integration tests (in `target/`), emptied first: nothing piles up in /tmp.
fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("moreau-io-{name}.d"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    let _ = std::fs::remove_file(&p);
    p
}

fn header(n: usize) -> RunHeader {
    RunHeader {
        version: "0.1.0".into(),
        scene_name: "unit".into(),
        scene: "name = \"unit\"\n# with a newline".into(),
        seed: 42,
        solver: "kind = \"apgd\"".into(),
        command: "moreau run unit.toml".into(),
        wkt_geometry: "POLYGON ((0 0, 1 0, 1 1, 0 1, 0 0))".into(),
        fps: 10.0,
        radii: (0..n).map(|i| 0.1 + 0.01 * i as f64).collect(),
        groups: (0..n).map(|i| (i % 2) as i64).collect(),
        walls: vec![[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 1.0, 1.0]],
        contacts: false,
        moving_names: Vec::new(),
        moving_body: Vec::new(),
        exit_names: vec!["door".into(), "back door".into()],
    }
}

fn report(step: usize, t: f64) -> StepReport {
    StepReport {
        step,
        t,
        mu: 0.05,
        eps_target: 1e-6,
        eps: 1e-7 * step as f64,
        violation: 1e-9,
        iterations: 10 + step,
        assembled: 3,
        active: 1,
        redone: 0,
        status: SolveStatus::Converged,
        solver: "apgd",
        ..Default::default()
    }
}

#[test]
fn a_run_file_reads_back_what_was_written() {
    let path = scratch("roundtrip.h5");
    let h = header(3);
    let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
    w.frame(0.0, &[0, 1, 2], &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        .unwrap();
    w.step(&report(0, 0.05));
    w.step(&report(1, 0.1));
    w.exit(1, 1, 0.07).unwrap();
    // Person 1 has left: frames hold the others, the dense array NaN in its place.
    w.frame(0.1, &[0, 2], &[0.11, 0.21, 0.51, 0.61]).unwrap();
    w.step(&report(2, 0.15));
    w.finish("complete", "{\"steps\": 3}").unwrap();

    let f = RunFile::open(&path).unwrap();
    assert_eq!(f.header().unwrap(), h);
    assert_eq!(f.status().unwrap(), "complete");
    assert_eq!(f.summary().unwrap(), "{\"steps\": 3}");
    assert_eq!(f.frame_times().unwrap(), vec![0.0, 0.1]);
    assert_eq!(f.frame_counts().unwrap(), vec![3, 2]);
    let p1 = f.positions(1).unwrap();
    assert_eq!(p1[0..2], [0.11, 0.21]);
    assert!(p1[2].is_nan() && p1[3].is_nan());
    assert_eq!(p1[4..6], [0.51, 0.61]);
    let traj = f.trajectory().unwrap();
    assert_eq!(traj.len(), 5);
    assert_eq!((traj[3].id, traj[3].frame, traj[3].x), (0, 1, 0.11));
    let steps = f.steps().unwrap();
    assert_eq!(steps.len(), 3);
    assert_eq!(steps[2].iterations, 12);
    assert_eq!(steps[1].status.as_str(), "converged");
    assert_eq!(steps[1].solver.as_str(), "apgd");
    let exits = f.exits().unwrap();
    assert_eq!(
        (exits.len(), exits[0].id, exits[0].exit, exits[0].t),
        (1, 1, 1, 0.07)
    );
    // The temporary name used while laying out is gone.
    let dir = path.parent().unwrap();
    assert!(std::fs::read_dir(dir).unwrap().all(|e| {
        !e.unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".partial")
    }));
    let text = f.describe().unwrap();
    assert!(
        text.contains("/trajectory") && text.contains("@fps") && text.contains("@wkt_geometry")
    );
}

#[test]
fn contact_forces_read_back_frame_by_frame() {
    let path = scratch("contacts.h5");
    let h = RunHeader {
        contacts: true,
        ..header(3)
    };
    let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
    assert!(w.records_contacts());
    // The first frame: no step yet, no contacts given (the pressure row stays NaN).
    w.frame(0.0, &[0, 1, 2], &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        .unwrap();
    let pair = ContactRow {
        frame: -1,
        kind: ContactRow::PERSON_PERSON,
        a: 0,
        b: 2,
        lambda: 0.25,
    };
    let wall = ContactRow {
        kind: ContactRow::PERSON_WALL,
        a: 2,
        b: 1,
        lambda: 0.5,
        ..pair
    };
    w.contacts([pair, wall], &[0.25, f64::NAN, 0.75]).unwrap();
    w.frame(0.1, &[0, 2], &[0.11, 0.21, 0.51, 0.61]).unwrap();
    // A pressure of the wrong length is refused and names both sizes.
    let err = w.contacts([], &[0.0; 2]).unwrap_err();
    assert!(
        err.to_string().contains("2 people") && err.to_string().contains("3"),
        "{err}"
    );
    w.finish("complete", "{}").unwrap();

    let f = RunFile::open(&path).unwrap();
    assert_eq!(f.header().unwrap(), h);
    assert_eq!(f.walls().unwrap(), h.walls);
    let rows = f.contacts().unwrap();
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[0], ContactRow { frame: 1, ..pair });
    assert_eq!(rows[1], ContactRow { frame: 1, ..wall });
    assert!(f.pressure(0).unwrap().unwrap().iter().all(|p| p.is_nan()));
    let p1 = f.pressure(1).unwrap().unwrap();
    assert_eq!((p1[0], p1[2]), (0.25, 0.75));
    assert!(p1[1].is_nan());
    assert!(f.describe().unwrap().contains("/contacts"));

    // Without contacts: no datasets, and the reader says so.
    let plain = scratch("no-contacts.h5");
    let mut w = RunWriter::create(&plain, &header(1), Overwrite::Never).unwrap();
    w.contacts([pair], &[1.0]).unwrap();
    w.frame(0.0, &[0], &[0.0, 0.0]).unwrap();
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&plain).unwrap();
    assert!(!f.has_contacts());
    assert!(f.contacts().unwrap().is_empty() && f.pressure(0).unwrap().is_none());
}

#[test]
fn an_existing_output_is_never_overwritten_without_permission() {
    let path = scratch("exists.h5");
    std::fs::write(&path, b"precious").unwrap();
    let err = RunWriter::create(&path, &header(2), Overwrite::Never).unwrap_err();
    assert!(matches!(err, IoError::Exists { .. }), "{err}");
    assert!(err.to_string().contains("--force"), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), b"precious");
    let w = RunWriter::create(&path, &header(2), Overwrite::Allowed).unwrap();
    w.finish("complete", "{}").unwrap();
    assert_eq!(RunFile::open(&path).unwrap().status().unwrap(), "complete");
}

#[test]
fn a_bad_output_path_names_the_problem_and_creates_nothing() {
    let dir = scratch("no-such-dir");
    let path = dir.join("out.h5");
    let err = RunWriter::create(&path, &header(2), Overwrite::Allowed).unwrap_err();
    assert!(err.to_string().contains("does not exist"), "{err}");
    assert!(!dir.exists());
    let dir = scratch("a-directory");
    std::fs::create_dir_all(&dir).unwrap();
    let err = RunWriter::create(&dir, &header(2), Overwrite::Allowed).unwrap_err();
    assert!(err.to_string().contains("is a directory"), "{err}");
}

#[test]
fn a_frame_with_an_unknown_person_is_refused() {
    let path = scratch("unknown.h5");
    let mut w = RunWriter::create(&path, &header(2), Overwrite::Never).unwrap();
    let err = w.frame(0.0, &[0, 5], &[0.0, 0.0, 1.0, 1.0]).unwrap_err();
    assert!(err.to_string().contains("person 5"), "{err}");
    assert!(w.exit(7, 0, 1.0).is_err());
}

/// `/people/id`, `/people/radius`, `/people/exit_time` and the people axis of
/// `/frames/positions`, read with HDF5 directly.
fn people_datasets(path: &std::path::Path) -> (Vec<i64>, Vec<f64>, Vec<f64>, Vec<usize>) {
    // Without HDF5's file locking, as the crate opens files (a RunFile of it may be open).
    let mut open = hdf5::File::with_options();
    open.with_fapl(|p| p.file_locking(false));
    let f = open.open(path).unwrap();
    let read = |name: &str| f.dataset(name).unwrap();
    (
        read("people/id").read_raw().unwrap(),
        read("people/radius").read_raw().unwrap(),
        read("people/exit_time").read_raw().unwrap(),
        read("frames/positions").shape(),
    )
}

#[test]
fn people_who_enter_during_the_run_extend_the_file() {
    let path = scratch("entering.h5");
    let h = header(2);
    let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
    assert_eq!(w.people(), 2);
    w.frame(0.0, &[0, 1], &[0.1, 0.2, 0.3, 0.4]).unwrap();
    w.step(&report(0, 0.05));
    w.enter(2, 0.3, 0.05, 2).unwrap();
    // Ids come in order: the next is 3, not 5.
    let err = w.enter(5, 0.3, 0.05, 2).unwrap_err().to_string();
    assert!(
        err.contains("person 5") && err.contains("next id is 3"),
        "{err}"
    );
    w.frame(0.1, &[0, 1, 2], &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        .unwrap();
    // Person 3 enters and leaves between two frames: in the file all the same.
    w.enter(3, 0.35, 0.1, 3).unwrap();
    w.exit(3, 0, 0.15).unwrap();
    w.enter(4, 0.4, 0.15, 2).unwrap();
    assert_eq!(w.people(), 5);
    w.frame(0.2, &[0, 2, 4], &[0.11, 0.21, 0.51, 0.61, 0.7, 0.8])
        .unwrap();
    // Person 5 enters after the last frame: the end of the run writes them.
    w.enter(5, 0.45, 0.25, 3).unwrap();
    w.finish("complete", "{}").unwrap();

    let f = RunFile::open(&path).unwrap();
    let read = f.header().unwrap();
    assert_eq!(read.radii, [0.1, 0.11, 0.3, 0.35, 0.4, 0.45]);
    assert_eq!(f.frame_counts().unwrap(), vec![2, 3, 3]);
    // Earlier frames hold NaN for those who came later.
    let p0 = f.positions(0).unwrap();
    assert_eq!(p0.len(), 12);
    assert_eq!(p0[..4], [0.1, 0.2, 0.3, 0.4]);
    assert!(p0[4..].iter().all(|x| x.is_nan()), "{p0:?}");
    let p2 = f.positions(2).unwrap();
    assert_eq!(p2[8..10], [0.7, 0.8]);
    assert!(p2[2..4].iter().chain(&p2[6..8]).all(|x| x.is_nan()));
    let ids: Vec<i64> = f.trajectory().unwrap().iter().map(|r| r.id).collect();
    assert_eq!(ids, [0, 1, 0, 1, 2, 0, 2, 4]);
    let (id, radius, exit_time, positions) = people_datasets(&path);
    assert_eq!(id, [0, 1, 2, 3, 4, 5]);
    assert_eq!(radius, read.radii);
    assert_eq!(exit_time[3], 0.15);
    assert_eq!(exit_time.iter().filter(|t| t.is_nan()).count(), 5);
    assert_eq!(positions, [3, 6, 2]);
    // When each entered, 0 for those there at the start (the file had no entry times: a
    // plot of N(t) took a person's first frame, and missed those who came and went between
    // frames).
    assert_eq!(
        f.entry_times().unwrap(),
        Some(vec![0.0, 0.0, 0.05, 0.1, 0.15, 0.25])
    );
    // Each one's group, those at the start from the header, newcomers their source's (the
    // file said nobody's: per-group analyses could not be made from it).
    assert_eq!(f.groups().unwrap(), Some(vec![0, 1, 2, 3, 2, 3]));
    assert_eq!(read.groups, [0, 1, 2, 3, 2, 3]);
}

/// Files of format `moreau-run/3` (before `/exits` said which exit) still read: their rows
/// with exit −1, no exit names. Made here by taking a new file back to that layout.
#[test]
fn a_file_of_format_3_reads_its_exits_with_no_exit() {
    #[derive(hdf5::H5Type, Clone, Copy)]
    #[repr(C)]
    struct ExitRowV3 {
        id: i64,
        t: f64,
    }
    let path = scratch("format3.h5");
    let mut w = RunWriter::create(&path, &header(2), Overwrite::Never).unwrap();
    w.frame(0.0, &[0, 1], &[0.1, 0.2, 0.3, 0.4]).unwrap();
    w.exit(0, 1, 0.05).unwrap();
    w.frame(0.1, &[1], &[0.3, 0.4]).unwrap();
    w.finish("complete", "{}").unwrap();
    rewrite(
        &path,
        "exits",
        &[ExitRowV3 { id: 0, t: 0.05 }],
        "moreau-run/3",
    );
    let f = RunFile::open(&path).unwrap();
    let exits = f.exits().unwrap();
    assert_eq!(
        (exits.len(), exits[0].id, exits[0].exit, exits[0].t),
        (1, 0, -1, 0.05)
    );
    assert!(f.header().unwrap().exit_names.is_empty());
    // The same file in this format reads the exit and its name.
    let again = scratch("format4.h5");
    let mut w = RunWriter::create(&again, &header(2), Overwrite::Never).unwrap();
    w.frame(0.0, &[0, 1], &[0.1, 0.2, 0.3, 0.4]).unwrap();
    w.exit(0, 1, 0.05).unwrap();
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&again).unwrap();
    let header = f.header().unwrap();
    assert_eq!(f.exits().unwrap()[0].exit, 1);
    assert_eq!(header.exit_names[1], "back door");
}

/// `path`'s dataset `name` replaced by `rows`, and its format attribute set to `format`.
fn rewrite<T: hdf5::H5Type>(path: &std::path::Path, name: &str, rows: &[T], format: &str) {
    use hdf5::types::VarLenUnicode;
    let file = hdf5::File::open_rw(path).unwrap();
    file.unlink(name).unwrap();
    file.new_dataset_builder()
        .with_data(rows)
        .create(name)
        .unwrap();
    file.delete_attr("format").unwrap();
    file.new_attr::<VarLenUnicode>()
        .create("format")
        .unwrap()
        .write_scalar(&format.parse::<VarLenUnicode>().unwrap())
        .unwrap();
}

/// Files written before 2026-11-21 have no `time_solve_analyse` or `time_solve_factorize` in
/// `/steps`; HDF5 read them as 0 s with nothing said (regression). They read as NaN, not
/// measured, and every other member as written.
#[test]
fn a_steps_table_written_before_the_solves_timings_reads_them_as_not_measured() {
    use hdf5::types::FixedAscii;
    #[derive(hdf5::H5Type, Clone, Copy)]
    #[repr(C)]
    struct OldStepRow {
        step: i64,
        t: f64,
        mu: f64,
        eps_target: f64,
        eps: f64,
        violation: f64,
        iterations: i64,
        assembled: i64,
        active: i64,
        redone: i64,
        status: FixedAscii<16>,
        solver: FixedAscii<16>,
        time_predict: f64,
        time_assemble: f64,
        time_solve: f64,
        time_verify: f64,
        time_total: f64,
    }
    let timed = |step, t| {
        let mut r = report(step, t);
        r.timings.predict = 1e-3;
        r.timings.assemble = 2e-3;
        r.timings.solve = 3e-3;
        r.timings.solve_analyse = 1e-4;
        r.timings.solve_factorize = 2e-4;
        r.timings.verify = 4e-3;
        r.timings.total = 1e-2;
        r
    };
    let path = scratch("untimed-solves.h5");
    let mut w = RunWriter::create(&path, &header(2), Overwrite::Never).unwrap();
    w.frame(0.0, &[0, 1], &[0.1, 0.2, 0.3, 0.4]).unwrap();
    w.step(&timed(0, 0.05));
    w.step(&timed(1, 0.1));
    w.finish("complete", "{}").unwrap();
    let written = RunFile::open(&path).unwrap().steps().unwrap();
    assert_eq!(written[1].time_solve_factorize, 2e-4);
    // The same rows without the two members (HDF5 converts compounds by member name).
    let old: Vec<OldStepRow> = hdf5::File::open(&path)
        .unwrap()
        .dataset("steps")
        .unwrap()
        .read_raw()
        .unwrap();
    rewrite(&path, "steps", &old, "moreau-run/1");
    let read = RunFile::open(&path).unwrap().steps().unwrap();
    assert_eq!(read.len(), 2);
    for (r, w) in read.iter().zip(&written) {
        assert!(r.time_solve_analyse.is_nan() && r.time_solve_factorize.is_nan());
        let unmeasured = StepRow {
            time_solve_analyse: w.time_solve_analyse,
            time_solve_factorize: w.time_solve_factorize,
            ..*r
        };
        assert_eq!(&unmeasured, w);
    }
}

/// A row member the reader needs and the file lacks is an error naming it, not zeros:
/// `/exits` of format 4 without its `exit` column read as exit 0 for everyone (regression).
#[test]
fn a_table_without_a_member_its_format_has_is_refused_naming_the_member() {
    #[derive(hdf5::H5Type, Clone, Copy)]
    #[repr(C)]
    struct NoExit {
        id: i64,
        t: f64,
    }
    let path = scratch("no-exit-member.h5");
    let mut w = RunWriter::create(&path, &header(2), Overwrite::Never).unwrap();
    w.frame(0.0, &[0, 1], &[0.1, 0.2, 0.3, 0.4]).unwrap();
    w.exit(0, 1, 0.05).unwrap();
    w.finish("complete", "{}").unwrap();
    rewrite(
        &path,
        "exits",
        &[NoExit { id: 0, t: 0.05 }],
        moreau_io::FORMAT,
    );
    let err = RunFile::open(&path)
        .unwrap()
        .exits()
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("dataset 'exits' has no member exit (its rows have id, t)"),
        "{err}"
    );
}
