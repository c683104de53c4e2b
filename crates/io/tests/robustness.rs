//! Issue 20, the run file: a frame is written whole or not at all (a full disk left phantom
//! rows), an old file stays whole until the new run ends (`--force` replaced it at the start),
//! the second writer of a path is refused (two runs silently lost one file), and a file being
//! written opens for reading.

use std::path::{Path, PathBuf};

use moreau_core::{SolveStatus, StepReport};
use moreau_io::{
    ContactRow, FailPoint, IoError, Overwrite, RunFile, RunHeader, RunWriter, partial_path,
};

/// `name` in a directory of its own (tests run in parallel), under cargo's scratch directory
/// for integration tests (in `target/`), emptied first: nothing piles up in /tmp.
fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("moreau-io-rb-{name}.d"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn header(n: usize, contacts: bool) -> RunHeader {
    RunHeader {
        version: "0.1.0".into(),
        scene_name: "unit".into(),
        scene: "name = \"unit\"".into(),
        seed: 1,
        solver: "kind = \"apgd\"".into(),
        command: "moreau run unit.toml".into(),
        wkt_geometry: "POLYGON ((0 0, 9 0, 9 9, 0 9, 0 0))".into(),
        fps: 10.0,
        radii: vec![0.2; n],
        groups: vec![0; n],
        walls: vec![[0.0, 0.0, 9.0, 0.0]],
        contacts,
        moving_names: Vec::new(),
        moving_body: Vec::new(),
        exit_names: vec!["out".into()],
    }
}

fn report(step: usize) -> StepReport {
    StepReport {
        step,
        t: 0.05 * (step + 1) as f64,
        mu: 0.05,
        status: SolveStatus::Converged,
        solver: "apgd",
        ..Default::default()
    }
}

/// Frame `k` of `n` people (everyone present), with two steps and, from frame 1 on, a contact.
fn write_frame(w: &mut RunWriter, k: usize, n: usize) -> Result<(), IoError> {
    if k > 0 {
        w.step(&report(2 * k - 2));
        w.step(&report(2 * k - 1));
        w.exit(0, 0, 0.1 * k as f64)?;
    }
    let ids: Vec<u32> = (0..n as u32).collect();
    let q: Vec<f64> = (0..2 * n)
        .map(|i| 1.0 + i as f64 + 0.01 * k as f64)
        .collect();
    if w.records_contacts() {
        let row = ContactRow {
            frame: 0,
            kind: ContactRow::PERSON_PERSON,
            a: 0,
            b: 1,
            lambda: 0.5,
        };
        w.contacts([row], &vec![0.5; w.people()])?;
    }
    w.frame(0.1 * k as f64, &ids, &q)
}

/// Every dataset of a failed file holds exactly `frames` whole frames of `n` people.
fn assert_whole_frames(path: &Path, frames: usize, n: usize, contacts: bool) {
    let f = RunFile::open(path).unwrap();
    assert_eq!(f.frame_times().unwrap().len(), frames, "frames/time");
    assert_eq!(f.frame_counts().unwrap().len(), frames, "frames/count");
    let traj = f.trajectory().unwrap();
    assert_eq!(traj.len(), frames * n, "trajectory rows");
    // No phantom row: every row is a person of a written frame at its written position.
    for r in &traj {
        assert!((r.frame as usize) < frames, "{r:?}");
        assert!(r.x >= 1.0, "a zero row (never written): {r:?}");
    }
    assert!(f.positions(frames - 1).is_ok());
    assert!(
        f.positions(frames).is_err(),
        "a frames/positions row too many"
    );
    if contacts {
        assert_eq!(f.contacts().unwrap().len(), frames, "contacts rows");
        assert!(
            f.pressure(frames).is_err(),
            "a frames/pressure row too many"
        );
    }
    // The steps and exits of the whole frames (the ones pending at the failure follow them
    // when the run is finished: they happened).
    assert!(f.steps().unwrap().len() >= 2 * (frames - 1));
    assert!(f.status().unwrap().starts_with("failed"));
}

#[test]
fn a_full_disk_in_the_middle_of_a_frame_left_phantom_rows() {
    let n = 150;
    for contacts in [false, true] {
        for dataset in [
            "people/id",
            "people/radius",
            "trajectory",
            "frames/positions",
            "frames/time",
            "frames/count",
            "contacts",
            "frames/pressure",
            "steps",
            "exits",
            "flush",
        ] {
            if !contacts && (dataset == "contacts" || dataset == "frames/pressure") {
                continue;
            }
            let path = scratch(&format!("full-{contacts}-{}.h5", dataset.replace('/', "-")));
            let mut w = RunWriter::create(&path, &header(n, contacts), Overwrite::Never).unwrap();
            w.fail_at(FailPoint {
                frame: 3,
                dataset: dataset.into(),
            });
            for k in 0..3 {
                write_frame(&mut w, k, n).unwrap();
            }
            // Somebody enters with frame 3: the per-person datasets grow with it.
            w.enter(n as u32, 0.3, 0.0, 7).unwrap();
            let err = write_frame(&mut w, 3, n).unwrap_err().to_string();
            assert!(
                err.contains("No space left on device")
                    && err.contains(dataset)
                    && err.contains("keeps its 3 whole frames"),
                "{dataset}: {err}"
            );
            assert_eq!(w.frames(), 3);
            w.finish("failed: disk full", "{}").unwrap();
            assert_whole_frames(&path, 3, n, contacts);
            // The newcomer happened: the end of the run writes them, in every per-person
            // dataset alike.
            let mut open = hdf5::File::with_options();
            open.with_fapl(|p| p.file_locking(false));
            let f = open.open(&path).unwrap();
            let rows = |name: &str| f.dataset(name).unwrap().shape()[0];
            assert_eq!(rows("people/id"), n + 1, "{dataset}");
            assert_eq!(rows("people/radius"), n + 1, "{dataset}");
            assert_eq!(rows("people/exit_time"), n + 1, "{dataset}");
            assert_eq!(rows("people/entry_time"), n + 1, "{dataset}");
            let groups: Vec<i64> = f.dataset("people/group").unwrap().read_raw().unwrap();
            assert_eq!(groups.len(), n + 1, "{dataset}");
            assert_eq!(groups[n], 7, "{dataset}");
            assert_eq!(
                f.dataset("frames/positions").unwrap().shape(),
                [3, n + 1, 2]
            );
        }
    }
}

#[test]
fn force_replaced_the_old_file_when_the_run_started() {
    let path = scratch("old.h5");
    std::fs::write(&path, b"a complete earlier run").unwrap();
    let mut w = RunWriter::create(&path, &header(2, false), Overwrite::Allowed).unwrap();
    write_frame(&mut w, 0, 2).unwrap();
    // While the run goes (and if it is killed now), the old file is whole, and the new one is
    // at its temporary name.
    assert_eq!(std::fs::read(&path).unwrap(), b"a complete earlier run");
    assert_eq!(w.partial(), partial_path(&path));
    assert!(w.partial().is_file());
    assert_eq!(
        RunFile::open(w.partial()).unwrap().status().unwrap(),
        "running"
    );
    w.finish("complete", "{}").unwrap();
    assert_eq!(RunFile::open(&path).unwrap().status().unwrap(), "complete");
    assert!(!partial_path(&path).exists());
    assert!(!moreau_io::lock_path(&path).exists());
}

#[test]
fn two_writers_of_one_path_both_succeeded_and_one_file_was_lost() {
    let path = scratch("twice.h5");
    let first = RunWriter::create(&path, &header(2, false), Overwrite::Allowed).unwrap();
    for overwrite in [Overwrite::Allowed, Overwrite::Never] {
        let second = RunWriter::create(&path, &header(2, false), overwrite).unwrap_err();
        assert!(matches!(second, IoError::Busy { .. }), "{second}");
        assert!(
            second.to_string().contains("another run is writing"),
            "{second}"
        );
    }
    first.finish("complete", "{}").unwrap();
    // Once the first has ended, the path is free again (with --force, as it exists now).
    let again = RunWriter::create(&path, &header(2, false), Overwrite::Allowed).unwrap();
    again.finish("complete", "{}").unwrap();
}

#[test]
fn a_partial_file_left_by_a_killed_run_is_replaced_only_with_force() {
    let path = scratch("killed.h5");
    let partial = partial_path(&path);
    std::fs::write(&partial, b"frames of a killed run").unwrap();
    let err = RunWriter::create(&path, &header(2, false), Overwrite::Never).unwrap_err();
    assert!(matches!(err, IoError::Stale { .. }), "{err}");
    assert!(err.to_string().contains("--force"), "{err}");
    assert_eq!(std::fs::read(&partial).unwrap(), b"frames of a killed run");
    let w = RunWriter::create(&path, &header(2, false), Overwrite::Allowed).unwrap();
    w.finish("complete", "{}").unwrap();
    assert!(!partial.exists());
}

#[test]
fn inspect_on_a_directory_said_no_such_file() {
    let dir = scratch("dir.h5");
    std::fs::create_dir_all(&dir).unwrap();
    let err = RunFile::open(&dir).unwrap_err().to_string();
    assert!(err.contains("is a directory"), "{err}");
    let missing = scratch("missing.h5");
    let err = RunFile::open(&missing).unwrap_err().to_string();
    assert!(err.contains("no such file"), "{err}");
}

/// Frames `0..frames` of `n` people, each followed by the state "state after frame k".
fn frames_with_states(w: &mut RunWriter, frames: usize, n: usize) {
    for k in 0..frames {
        write_frame(w, k, n).unwrap();
        w.save_state(format!("state after frame {k}").as_bytes())
            .unwrap();
    }
}

/// A run killed after frames it wrote past its last saved state: resuming cuts every dataset
/// back to that state (frames, trajectory, contacts, pressure, steps, exits), gives back the
/// state's bytes and the header, and the run goes on from there to a whole file at its name.
#[test]
fn a_killed_run_resumes_from_the_state_saved_with_its_last_frame() {
    let (n, path) = (3, scratch("resume.h5"));
    let h = header(n, true);
    {
        let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
        frames_with_states(&mut w, 3, n);
        // A state between frames is refused (it would not match the rows).
        w.step(&report(99));
        assert!(w.save_state(b"between").is_err());
        // Frame 3 is written, then the run "dies" before saving its state.
        write_frame(&mut w, 3, n).unwrap();
        std::mem::forget(w); // no finish, no close: as SIGKILL leaves it (the lock is released below)
    }
    let _ = std::fs::remove_file(moreau_io::lock_path(&path));
    assert!(!path.exists() && partial_path(&path).exists());
    assert_eq!(
        RunFile::open(&partial_path(&path))
            .unwrap()
            .frame_times()
            .unwrap()
            .len(),
        4
    );

    let r = RunWriter::resume(&path, Overwrite::Never).unwrap();
    assert_eq!(r.state, b"state after frame 2");
    assert_eq!(r.header, h);
    let mut w = r.writer;
    assert_eq!(w.frames(), 3);
    // The run goes on: frame 3 again, then frame 4.
    write_frame(&mut w, 3, n).unwrap();
    write_frame(&mut w, 4, n).unwrap();
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&path).unwrap();
    assert_eq!(
        f.frame_times().unwrap(),
        vec![0.0, 0.1, 0.2, 0.30000000000000004, 0.4]
    );
    assert_eq!(f.trajectory().unwrap().len(), 5 * n);
    assert_eq!(f.contacts().unwrap().len(), 5);
    assert_eq!(f.steps().unwrap().len(), 8);
    assert_eq!(f.exits().unwrap().len(), 4);
    assert!(f.pressure(4).unwrap().is_some() && f.pressure(5).is_err());
    assert!(!partial_path(&path).exists());

    // Nothing to resume: a clear error naming the partial file it looked for.
    let err = RunWriter::resume(&scratch("nothing.h5"), Overwrite::Never).unwrap_err();
    assert!(err.to_string().contains("nothing to resume"), "{err}");
}

/// A run killed inside `finish`, after it wrote `people/exit_time`: the resumed run's
/// `finish` failed on the dataset already there ("unknown library error"), and the file was
/// moved to its name half finished.
#[test]
fn a_run_killed_while_finishing_failed_to_resume() {
    let (n, path) = (3, scratch("killed-finishing.h5"));
    let h = header(n, false);
    {
        let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
        frames_with_states(&mut w, 2, n);
        std::mem::forget(w);
    }
    let _ = std::fs::remove_file(moreau_io::lock_path(&path));
    {
        // As the killed run's `finish` left it (its writer still open in this process).
        let mut b = hdf5::File::with_options();
        b.with_fapl(|p| p.file_locking(false));
        let f = b.open_rw(partial_path(&path)).unwrap();
        f.new_dataset_builder()
            .with_data(&[f64::NAN; 3])
            .create("people/exit_time")
            .unwrap();
    }
    let mut w = RunWriter::resume(&path, Overwrite::Never).unwrap().writer;
    write_frame(&mut w, 2, n).unwrap();
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&path).unwrap();
    assert_eq!(f.frame_times().unwrap().len(), 3);
    assert_eq!(f.exits().unwrap().len(), 2);
}

/// A run stopped by SIGINT or SIGTERM finishes its file as `interrupted`, with its saved
/// state: `--resume` said "nothing to resume" (only a SIGKILL's partial file went on), so a
/// batch system's time limit lost the run. It goes on from its last saved state; a complete
/// file is still not resumed.
#[test]
fn a_run_stopped_by_a_signal_could_not_be_resumed() {
    let (n, path) = (3, scratch("interrupted.h5"));
    let h = header(n, false);
    let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
    frames_with_states(&mut w, 3, n);
    w.step(&report(4));
    w.finish("interrupted", "{}").unwrap();
    assert_eq!(
        RunFile::open(&path).unwrap().text("status").unwrap(),
        "interrupted"
    );

    let r = RunWriter::resume(&path, Overwrite::Never).unwrap();
    assert_eq!(r.state, b"state after frame 2");
    assert!(!path.exists() && partial_path(&path).exists());
    assert_eq!(
        RunFile::open(&partial_path(&path))
            .unwrap()
            .text("status")
            .unwrap(),
        "running"
    );
    let mut w = r.writer;
    assert_eq!(w.frames(), 3);
    write_frame(&mut w, 3, n).unwrap();
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&path).unwrap();
    assert_eq!(f.text("status").unwrap(), "complete");
    assert_eq!(f.frame_times().unwrap().len(), 4);
    assert_eq!(f.steps().unwrap().len(), 6);
    // A complete run is not resumed.
    let e = RunWriter::resume(&path, Overwrite::Never).unwrap_err();
    assert!(e.to_string().contains("nothing to resume"), "{e}");
}

/// `.NAME.partial` appears only once laid out and flushed: a run killed while creating it left
/// 96 bytes there that nothing could open. What a kill leaves under the name it is laid out
/// under is removed by the next run.
#[test]
fn a_run_killed_while_creating_its_file_left_a_partial_nothing_could_open() {
    let (n, path) = (3, scratch("killed-creating.h5"));
    let new = path.with_file_name(".killed-creating.h5.new");
    std::fs::write(&new, [0u8; 96]).unwrap();
    let mut w = RunWriter::create(&path, &header(n, false), Overwrite::Never).unwrap();
    assert!(!new.exists(), "the leftover of a killed creation stays");
    assert!(partial_path(&path).exists());
    // Readable as soon as it has its name, before any frame.
    assert_eq!(
        RunFile::open(&partial_path(&path))
            .unwrap()
            .frame_times()
            .unwrap()
            .len(),
        0
    );
    write_frame(&mut w, 0, n).unwrap();
    w.finish("complete", "{}").unwrap();
    assert!(!new.exists() && !partial_path(&path).exists());
    assert_eq!(
        RunFile::open(&path).unwrap().frame_times().unwrap().len(),
        1
    );
}

/// The same frames through a writer on its own thread give the same file as through one in
/// the caller's thread; a write that fails there stops the run at a later frame or at the
/// end, and the file keeps its whole frames.
#[test]
fn a_background_writer_writes_the_same_file_and_reports_its_failures() {
    use moreau_io::{BackgroundWriter, RunSink};
    let n = 3;
    let write = |w: &mut dyn RunSink, k: usize| -> Result<(), IoError> {
        if k > 0 {
            w.step(&report(2 * k - 2));
            w.step(&report(2 * k - 1));
            w.exit(0, 0, 0.1 * k as f64)?;
        }
        let row = ContactRow {
            frame: 0,
            kind: ContactRow::PERSON_PERSON,
            a: 0,
            b: 1,
            lambda: 0.5 + k as f64,
        };
        w.contact_rows(&mut std::iter::once(row), &vec![0.5; n])?;
        let q: Vec<f64> = (0..2 * n)
            .map(|i| 1.0 + i as f64 + 0.01 * k as f64)
            .collect();
        w.frame(0.1 * k as f64, &[0, 1, 2], &q)?;
        w.save_state(format!("after {k}").into_bytes())
    };
    let (direct, threaded) = (scratch("direct.h5"), scratch("threaded.h5"));
    let mut a = RunWriter::create(&direct, &header(n, true), Overwrite::Never).unwrap();
    let mut b = BackgroundWriter::new(
        RunWriter::create(&threaded, &header(n, true), Overwrite::Never).unwrap(),
    );
    for k in 0..6 {
        write(&mut a, k).unwrap();
        write(&mut b, k).unwrap();
    }
    a.step(&report(99));
    b.step(&report(99));
    // A state saved with a step not yet in a frame is refused by both (the background writer
    // took it while the frame at a horizon off the output times went unwritten), and the
    // file goes on.
    for sink in [&mut a as &mut dyn RunSink, &mut b] {
        let err = sink
            .save_state(b"between".to_vec())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("a state saved between frames (1 steps"),
            "{err}"
        );
    }
    a.finish("complete", "{}").unwrap();
    b.finish("complete", "{}").unwrap();
    let (fa, fb) = (
        RunFile::open(&direct).unwrap(),
        RunFile::open(&threaded).unwrap(),
    );
    assert_eq!(fa.frame_times().unwrap(), fb.frame_times().unwrap());
    assert_eq!(fa.trajectory().unwrap(), fb.trajectory().unwrap());
    assert_eq!(fa.steps().unwrap(), fb.steps().unwrap());
    assert_eq!(fa.steps().unwrap().len(), 11);
    assert_eq!(fa.exits().unwrap(), fb.exits().unwrap());
    assert_eq!(fa.contacts().unwrap(), fb.contacts().unwrap());
    for k in 0..6 {
        assert_eq!(fa.positions(k).unwrap(), fb.positions(k).unwrap());
        assert_eq!(fa.pressure(k).unwrap(), fb.pressure(k).unwrap());
    }

    // A full disk at frame 2 on the writing thread: reported by a later call or by finish.
    let failing = scratch("failing.h5");
    let mut w = RunWriter::create(&failing, &header(n, true), Overwrite::Never).unwrap();
    w.fail_at(FailPoint {
        frame: 2,
        dataset: "steps".into(),
    });
    let mut b = BackgroundWriter::new(w);
    let first_error = (0..8).find_map(|k| write(&mut b, k).err());
    let finished = b.finish("failed: disk full", "{}");
    let error = first_error
        .or(finished.err())
        .expect("the failure is reported");
    assert!(
        error.to_string().contains("No space left on device"),
        "{error}"
    );
    let f = RunFile::open(&partial_path(&failing))
        .or_else(|_| RunFile::open(&failing))
        .unwrap();
    assert_eq!(f.frame_times().unwrap().len(), 2, "whole frames only");
}

/// A run whose people enter as it goes, killed after a frame it wrote past its last saved
/// state: resuming cuts the people back to those of the saved frame too, and the people who
/// enter again get the same ids.
#[test]
fn a_killed_run_with_people_entering_resumes_with_the_people_of_its_saved_state() {
    let path = scratch("resume-entering.h5");
    // Frame k has the 2 people of the start and k who entered (ids 2..2 + k).
    let write = |w: &mut RunWriter, k: usize| -> Result<(), IoError> {
        if k > 0 {
            w.step(&report(k - 1));
            w.enter((k + 1) as u32, k as f64 / 10.0, 0.1 * k as f64, k as u32)?;
        }
        let ids: Vec<u32> = (0..2 + k as u32).collect();
        let q: Vec<f64> = (0..2 * ids.len()).map(|i| 1.0 + i as f64).collect();
        w.frame(0.1 * k as f64, &ids, &q)
    };
    let h = header(2, false);
    {
        let mut w = RunWriter::create(&path, &h, Overwrite::Never).unwrap();
        for k in 0..3 {
            write(&mut w, k).unwrap();
            w.save_state(format!("after {k}").as_bytes()).unwrap();
        }
        // People who entered since the last frame: not a state to save.
        w.enter(4, 0.5, 0.3, 1).unwrap();
        let err = w.save_state(b"between").unwrap_err().to_string();
        assert!(err.contains("1 people not yet written"), "{err}");
        w.step(&report(3));
        w.frame(0.3, &[0, 1, 2, 3, 4], &[1.0; 10]).unwrap();
        std::mem::forget(w); // killed: no finish
    }
    let _ = std::fs::remove_file(moreau_io::lock_path(&path));
    assert_eq!(
        RunFile::open(&partial_path(&path))
            .unwrap()
            .header()
            .unwrap()
            .radii
            .len(),
        5
    );
    let r = RunWriter::resume(&path, Overwrite::Never).unwrap();
    assert_eq!(r.state, b"after 2");
    assert_eq!(r.header.radii, [0.2, 0.2, 0.1, 0.2]);
    assert_eq!(r.header.groups, [0, 0, 1, 2]);
    let mut w = r.writer;
    assert_eq!((w.frames(), w.people()), (3, 4));
    for k in 3..5 {
        write(&mut w, k).unwrap();
    }
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&path).unwrap();
    assert_eq!(f.header().unwrap().radii, [0.2, 0.2, 0.1, 0.2, 0.3, 0.4]);
    assert_eq!(f.groups().unwrap(), Some(vec![0, 0, 1, 2, 3, 4]));
    assert_eq!(f.frame_counts().unwrap(), vec![2, 3, 4, 5, 6]);
    assert_eq!(f.positions(4).unwrap().len(), 12);
    assert!(f.positions(0).unwrap()[4..].iter().all(|x| x.is_nan()));
    assert_eq!(f.trajectory().unwrap().len(), 2 + 3 + 4 + 5 + 6);
}

/// A file written before `/people/group` (killed, then resumed by this code): its people get
/// −1 (not known), those who enter from the resume on their group, and every per-person
/// dataset keeps one row a person.
#[test]
fn a_killed_file_without_groups_resumes_with_unknown_groups_for_its_people() {
    let (n, path) = (2, scratch("resume-no-groups.h5"));
    {
        let mut w = RunWriter::create(&path, &header(n, false), Overwrite::Never).unwrap();
        for k in 0..2 {
            write_frame(&mut w, k, n).unwrap();
            w.save_state(b"state").unwrap();
        }
        std::mem::forget(w); // killed: no finish
    }
    let _ = std::fs::remove_file(moreau_io::lock_path(&path));
    {
        let mut open = hdf5::File::with_options();
        open.with_fapl(|p| p.file_locking(false));
        let f = open.open_rw(partial_path(&path)).unwrap();
        f.unlink("people/group").unwrap();
    }
    let r = RunWriter::resume(&path, Overwrite::Never).unwrap();
    assert!(r.header.groups.is_empty(), "{:?}", r.header.groups);
    let mut w = r.writer;
    w.step(&report(2));
    w.enter(n as u32, 0.3, 0.15, 5).unwrap();
    w.frame(0.2, &[0, 1, 2], &[1.0; 6]).unwrap();
    w.finish("complete", "{}").unwrap();
    let f = RunFile::open(&path).unwrap();
    assert_eq!(f.groups().unwrap(), Some(vec![-1, -1, 5]));
    assert_eq!(f.header().unwrap().radii.len(), 3);
}

/// Regression: the saved state's marks (how many rows each dataset had when the state was
/// saved) were taken as they were, so a damaged mark beyond its dataset's rows made resuming
/// grow the dataset with empty rows instead of cutting it back. Now it is refused, naming the
/// mark, its value and the dataset, and the file keeps every frame it had.
#[test]
fn a_saved_states_mark_beyond_its_dataset_is_refused_and_changes_nothing() {
    let (n, path) = (3, scratch("damaged-mark.h5"));
    {
        let mut w = RunWriter::create(&path, &header(n, true), Overwrite::Never).unwrap();
        for k in 0..3 {
            write_frame(&mut w, k, n).unwrap();
            w.save_state(b"state").unwrap();
        }
        write_frame(&mut w, 3, n).unwrap();
        std::mem::forget(w);
    }
    let _ = std::fs::remove_file(moreau_io::lock_path(&path));
    let partial = partial_path(&path);
    // (As the writer opens it: the killed writer's handle is still open in this process.)
    let open_rw = || {
        let mut b = hdf5::File::with_options();
        b.with_fapl(|p| p.file_locking(false));
        b.open_rw(&partial).unwrap()
    };
    for (mark, value, dataset) in [
        ("frames", 99u64, "frames/time"),
        ("trajectory_rows", 1_000_000, "trajectory"),
        ("contact_rows", 7_000, "contacts"),
    ] {
        let before = {
            let f = open_rw();
            let attr = f.group("state").unwrap().attr(mark).unwrap();
            let before: u64 = attr.read_scalar().unwrap();
            attr.write_scalar(&value).unwrap();
            before
        };
        let err = RunWriter::resume(&path, Overwrite::Never)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("'state/{mark}' = {value}")) && err.contains(dataset),
            "{err}"
        );
        let f = RunFile::open(&partial).unwrap();
        assert_eq!(f.frame_times().unwrap().len(), 4, "{mark}: frames kept");
        assert_eq!(f.trajectory().unwrap().len(), 4 * n, "{mark}: rows kept");
        drop(f);
        let f = open_rw();
        f.group("state")
            .unwrap()
            .attr(mark)
            .unwrap()
            .write_scalar(&before)
            .unwrap();
    }
    // Undamaged, it resumes.
    let r = RunWriter::resume(&path, Overwrite::Never).unwrap();
    assert_eq!(r.writer.frames(), 3);
}
