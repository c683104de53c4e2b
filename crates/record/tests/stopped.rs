//! A run stopped after a step (Ctrl-C, SIGTERM: the progress callback says stop) leaves a file
//! that ends at that step: its frame when the step reached an output time, and the exits and
//! entries of the step.

use std::path::PathBuf;

use moreau_core::{RunStats, StepReport};
use moreau_crowd::{ObserverError, Scene, Simulation};
use moreau_io::{Overwrite, RunFile, RunSink, RunWriter};
use moreau_record::{Progress, Record, header, run_to_horizon};

/// The gate-inflow scene to 16 s: people waiting at the start, others entering, some leaving
/// (steps of 0.05 s, a frame every 0.1 s).
fn scene() -> Scene {
    let mut scene = Scene::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/scenes/gate-inflow.toml"
    ))
    .unwrap();
    scene.time.horizon = 16.0;
    assert_eq!((scene.time.step, scene.time.output_interval), (0.05, 0.1));
    scene
}

/// For each step of an uninterrupted run (counted from 1): whether somebody left in it, and
/// whether somebody entered.
fn events_by_step() -> Vec<(bool, bool)> {
    let mut sim = Simulation::new(scene()).unwrap();
    let mut out = Vec::new();
    let (mut exits, mut people) = (0, sim.total_people());
    while sim.advance_step(16.0, &mut ()).unwrap().is_some() {
        out.push((
            sim.exit_records().len() > exits,
            sim.total_people() > people,
        ));
        (exits, people) = (sim.exit_records().len(), sim.total_people());
    }
    out
}

/// Runs the scene into a file, the progress callback stopping the run after step `stop`;
/// returns the simulation and the file.
fn stopped_after(stop: usize) -> (Simulation, RunFile) {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("moreau-record-stopped.d");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("stopped-{stop}.h5"));
    let _ = std::fs::remove_file(&path);
    let mut sim = Simulation::new(scene()).unwrap();
    let mut w = RunWriter::create(&path, &header(&sim, "test".into()), Overwrite::Never).unwrap();
    let mut steps = 0;
    let mut progress = |_: &StepReport, _: &RunStats, _: usize| -> Result<(), ObserverError> {
        steps += 1;
        match steps == stop {
            true => Err("interrupted".into()),
            false => Ok(()),
        }
    };
    let people = sim.total_people();
    let progress: &mut Progress<'_> = &mut progress;
    let mut rec = Record::new(Some(&mut w as &mut dyn RunSink), people).with_progress(progress);
    let outcome = run_to_horizon(&mut sim, &mut rec);
    assert!(outcome.is_err(), "the run was not stopped");
    w.finish("interrupted", "{}").unwrap();
    (sim, RunFile::open(&path).unwrap())
}

#[test]
fn a_run_stopped_at_a_step_on_an_output_time_lost_that_frame_and_the_steps_exits() {
    let events = events_by_step();
    let first_exit = 1 + events
        .iter()
        .position(|e| e.0)
        .expect("somebody leaves by 16 s");
    let first_entry = 1 + events.iter().position(|e| e.1).expect("somebody enters");
    // Steps 2k end on the frame of 0.1·k s; odd ones between frames.
    let mut stops = vec![first_exit, first_entry, 2 * (first_exit / 2) + 2, 7];
    stops.sort_unstable();
    stops.dedup();
    for stop in stops {
        let (sim, file) = stopped_after(stop);
        assert_eq!(sim.steps(), stop);
        assert_eq!(file.steps().unwrap().len(), stop, "steps after step {stop}");
        // The frames of 0, 0.1, … up to the step's time: the last one at the step's own time
        // when the step reached an output time (SIGTERM at such a step left it out).
        let times = file.frame_times().unwrap();
        assert_eq!(
            times.len(),
            1 + stop / 2,
            "frames after step {stop}: {times:?}"
        );
        if stop % 2 == 0 {
            assert_eq!(*times.last().unwrap(), sim.time(), "step {stop}");
        }
        // The step's exits and entries are in the file as in the simulation.
        let exits: Vec<(u32, f64)> = file
            .exits()
            .unwrap()
            .iter()
            .map(|r| (r.id as u32, r.t))
            .collect();
        let recorded: Vec<(u32, f64)> = sim.exit_records().iter().map(|r| (r.id, r.t)).collect();
        assert_eq!(exits, recorded, "exits after step {stop}");
        assert_eq!(
            file.header().unwrap().radii.len(),
            sim.total_people(),
            "people after step {stop}"
        );
    }
}

/// A run stopped after step 37 and resumed from its last saved state (the frame of 1.8 s):
/// the resumed run's totals, which its summary prints and stores, are the whole run's, as an
/// uninterrupted run adds them up (they counted only the steps after the resume, and the
/// frames from the resumed one).
#[test]
fn a_resumed_runs_summary_counted_only_the_steps_after_the_resume() {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("moreau-record-stopped.d");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("resumed.h5");
    let _ = std::fs::remove_file(&path);
    let _ = std::fs::remove_file(moreau_io::partial_path(&path));

    let mut whole = Simulation::new(scene()).unwrap();
    let mut straight = Record::new(None, whole.total_people());
    run_to_horizon(&mut whole, &mut straight).unwrap();

    {
        let mut sim = Simulation::new(scene()).unwrap();
        let mut w =
            RunWriter::create(&path, &header(&sim, "test".into()), Overwrite::Never).unwrap();
        let mut steps = 0;
        let mut progress = |_: &StepReport, _: &RunStats, _: usize| -> Result<(), ObserverError> {
            steps += 1;
            match steps == 37 {
                true => Err("interrupted".into()),
                false => Ok(()),
            }
        };
        let progress: &mut Progress<'_> = &mut progress;
        let people = sim.total_people();
        let mut rec = Record::new(Some(&mut w as &mut dyn RunSink), people).with_progress(progress);
        assert!(run_to_horizon(&mut sim, &mut rec).is_err());
        drop(rec);
        w.finish("interrupted", "{}").unwrap();
    }
    let r = RunWriter::resume(&path, Overwrite::Never).unwrap();
    let mut w = r.writer;
    let mut sim = Simulation::new(scene()).unwrap();
    sim.restore(&moreau_crowd::SimState::from_bytes(&r.state).unwrap())
        .unwrap();
    assert_eq!(sim.steps(), 36, "resumed from the frame before the stop");
    let people = sim.total_people();
    let mut rec = Record::new(Some(&mut w as &mut dyn RunSink), people).resuming(&r.note);
    run_to_horizon(&mut sim, &mut rec).unwrap();
    let (a, b) = (&rec.stats, &straight.stats);
    assert_eq!(
        (
            a.steps,
            a.iterations,
            a.factorizations,
            a.redone,
            a.rejected
        ),
        (
            b.steps,
            b.iterations,
            b.factorizations,
            b.redone,
            b.rejected
        )
    );
    assert_eq!((a.max_eps, a.max_violation), (b.max_eps, b.max_violation));
    assert_eq!(a.solvers, b.solvers);
    assert_eq!((rec.frames, rec.exits), (straight.frames, straight.exits));
    // Its wall time is the whole run's too: the summary's ms a step and steps a second divided
    // the whole run's steps by the resumed part's seconds (2× too fast, resumed half way).
    let note: serde_json::Value = serde_json::from_str(&r.note).unwrap();
    let before = note["wall_seconds"].as_f64().unwrap();
    assert!(before > 0.0, "{note}");
    assert!(rec.wall_seconds() >= before);
    let summary = moreau_record::Summary::new(&sim, &rec, "s".into(), None, "complete".into(), 0.5);
    assert_eq!(summary.wall_seconds, 0.5 + before);
    assert_eq!(summary.ms_per_step, 1e3 * (0.5 + before) / b.steps as f64);
    // A note that is no totals (files before) leaves them at zero.
    let fresh = Record::new(None, 3).resuming("");
    assert_eq!((fresh.stats.steps, fresh.frames), (0, 0));
}
