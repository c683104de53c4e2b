//! Issue 20, the FMU: a refused `setReal` keeps the old value, a communication step that
//! needs more internal steps than reasonable is refused before it starts, and numbers in its
//! messages are short.

use std::path::PathBuf;

use moreau_fmu::model::vr;
use moreau_fmu::runtime::{Instance, Level};

/// An instance of `data/scenes/room-60.toml`, initialized (state Stepping).
fn stepping() -> Instance {
    let scenes = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/scenes"));
    let mut inst = Instance::new(
        "robust".into(),
        Some(scenes.clone()),
        false,
        Box::new(|_, _| {}),
    );
    inst.settings.scene = scenes.join("room-60.toml").display().to_string();
    inst.enter_initialization().unwrap();
    inst.exit_initialization().unwrap();
    inst
}

#[test]
fn a_refused_set_real_of_speed_factor_minus_one_was_kept_and_failed_every_step() {
    let mut inst = stepping();
    inst.do_step(0.0, 0.1).unwrap();
    let err = inst
        .set_real(vr::SPEED_FACTOR, -1.0)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("speed_factor = -1") && err.contains("keeps its value 1"),
        "{err}"
    );
    assert_eq!(inst.get_real(vr::SPEED_FACTOR).unwrap(), 1.0);
    // The next step runs, with the old value.
    inst.do_step(0.1, 0.1).unwrap();
    let err = inst
        .set_real(vr::SPEED_FACTOR, f64::NAN)
        .unwrap_err()
        .to_string();
    assert!(err.contains("NaN"), "{err}");
    inst.do_step(0.2, 0.1).unwrap();
    // A fine value is taken.
    inst.set_real(vr::SPEED_FACTOR, 0.5).unwrap();
    assert_eq!(inst.get_real(vr::SPEED_FACTOR).unwrap(), 0.5);
    inst.do_step(0.3, 0.1).unwrap();
}

#[test]
fn do_step_of_1e300_never_returned() {
    let mut inst = stepping();
    let err = inst.do_step(0.0, 1e300).unwrap_err().to_string();
    assert!(
        err.contains("communicationStepSize = 1e300")
            && err.contains("internal steps")
            && err.contains("limit of 1e6"),
        "{err}"
    );
    assert!(err.len() < 300, "a short message: {err}");
    // Just within the limit is a step (not taken here: 10⁶ steps); the instance goes on.
    inst.do_step(0.0, 0.1).unwrap();
}

#[test]
fn the_log_printed_t_with_300_digits() {
    let mut inst = stepping();
    let err = inst.do_step(1e300, 0.1).unwrap_err().to_string();
    assert!(err.contains("currentCommunicationPoint = 1e300"), "{err}");
    assert!(err.len() < 200, "{err}");
}

#[test]
fn a_tol_no_step_meets_ran_at_the_smallest_step_without_a_word_to_the_host() {
    // `time.tol = 1e-12` keeps every step at the controller's smallest (10⁻⁶ s) whatever it
    // errs: `moreau run` warned once (session 36), the FMU said nothing. Now one warning (status
    // Warning, category logStatusWarning) on the first communication step that has one, even
    // with logging off, and none after it.
    let scenes = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/scenes"));
    let dir = std::env::temp_dir().join(format!("moreau-fmu-tol-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(scenes.join("room-60.toml")).unwrap();
    let run = |tol: &str| {
        let scene = dir.join(format!("tol-{tol}.toml"));
        let edited = text.replace(
            "output_interval = 0.1",
            &format!("output_interval = 0.1\ntol = {tol}"),
        );
        assert_ne!(edited, text);
        std::fs::write(&scene, edited).unwrap();
        let log = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
        let sink = log.clone();
        let mut inst = Instance::new(
            "tol".into(),
            Some(dir.clone()),
            false,
            Box::new(move |level, message| sink.borrow_mut().push((level, message.to_string()))),
        );
        inst.settings.scene = scene.display().to_string();
        inst.enter_initialization().unwrap();
        inst.exit_initialization().unwrap();
        for k in 0..3 {
            inst.do_step(k as f64 * 0.002, 0.002).unwrap();
        }
        log.take()
    };
    let log = run("1e-12");
    assert_eq!(log.len(), 1, "{log:?}");
    let (level, message) = &log[0];
    assert_eq!(*level, Level::Warning);
    for needle in ["DoStep", "the smallest step, 1e-6 s", "time.tol = 1e-12 m"] {
        assert!(message.contains(needle), "{needle:?} not in {message}");
    }
    // A tolerance the steps meet says nothing.
    assert_eq!(run("1e-3"), vec![]);
    std::fs::remove_dir_all(&dir).ok();
}
