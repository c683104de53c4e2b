//! Random sequences of FMI 2 and FMI 3 calls with hostile arguments, as a careless master
//! makes them (steps before initialization, times that go back, NaN and 1e308 values, unknown
//! value references, wrong array lengths, states taken, set, freed, serialized and read back
//! damaged, resets and terminations at any point): every call answers with a status, never a
//! crash or an abort of the host nor a panic (FATAL), every refused FMI 3 call leaves a log
//! line (FMI 2's logger is variadic, which a Rust test cannot be), and each instance is freed
//! cleanly at the end. Half the instances are given resources as the FMU of a scene, whose
//! `scene` parameter refuses scenes with other exits or bodies. The FMU runs inside the
//! master's process (fmpy's Python): a panic that escaped it, or memory it corrupted, would
//! take the host down.
//!
//! Deterministic sequences (seeded by their number; even ones FMI 3, odd ones FMI 2) for
//! `MOREAU_FUZZ_SECONDS` (default 10 s).
// The FMI entry points are a C ABI: raw pointers, as a host passes them.
#![allow(unsafe_code)]

use std::cell::RefCell;
use std::ffi::{CString, c_void};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use moreau_fmu::model::vr;

mod support;
use support::{DISCARD, ERROR, OK, WARNING};

/// A small deterministic generator (SplitMix64): the crate has no random-number dependency.
struct Rng(u64);

impl Rng {
    fn seed(seed: u64) -> Self {
        Self(seed)
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    /// Uniform in `[lo, hi)`.
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn chance(&mut self, p: f64) -> bool {
        self.uniform(0.0, 1.0) < p
    }
}

fn scenes() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data"))
}

/// A scene FMU's resources: a directory holding only `room-two-exits.toml` (made once).
fn scene_fmu_resources() -> &'static std::path::Path {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join("moreau-fmu-fuzz-resources");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let scene = "room-two-exits.toml";
        std::fs::copy(scenes().join("scenes").join(scene), dir.join(scene)).unwrap();
        dir
    })
}

/// A number a careless master might pass.
fn hostile(rng: &mut Rng) -> f64 {
    const SPECIAL: [f64; 14] = [
        0.0,
        -0.0,
        -1.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e308,
        -1e308,
        5e-324,
        1e-300,
        0.05,
        0.1,
        0.5,
        1.0,
    ];
    match rng.below(3) {
        0 => SPECIAL[rng.below(SPECIAL.len())],
        1 => rng.uniform(-2.0, 3.0),
        _ => rng.uniform(0.0, 0.4),
    }
}

/// A value reference: the model's, the moving body's, an exit's, or none of them.
fn reference(rng: &mut Rng) -> u32 {
    const REFS: [u32; 25] = [
        vr::SCENE,
        vr::STEP,
        vr::EPS_KAPPA,
        vr::DESIRED_SPEED_FACTOR,
        vr::N_PEOPLE,
        vr::SPEED_FACTOR,
        vr::DOOR_OPEN,
        vr::PEOPLE_INSIDE,
        vr::PEOPLE_EVACUATED,
        vr::MEAN_SPEED,
        vr::MIN_GAP,
        vr::EPS,
        vr::INTERNAL_STEPS,
        vr::POSITIONS,
        vr::RADII,
        vr::MOVING,
        vr::MOVING + 1,
        vr::EXIT_OPEN,
        vr::EXIT_OPEN + 1,
        vr::EXIT_PASSED,
        vr::EXIT_PASSED + 1,
        vr::EXIT_END,
        0,
        999,
        u32::MAX,
    ];
    REFS[rng.below(REFS.len())]
}

/// One instance driven by `calls` random calls (most sequences first set a scene and
/// initialize, as a master would, then go astray); adds the calls answered OK, by kind, to
/// `answered`. Returns whether the instance refused a scene its variables do not declare (as
/// FMI 3's log says).
fn sequence(seed: u64, calls: usize, answered: &mut [usize; KINDS]) -> bool {
    let mut rng = Rng::seed(seed);
    let log = Box::new(RefCell::new(Vec::<String>::new()));
    let v3 = seed.is_multiple_of(2);
    let logging_on = rng.chance(0.5);
    // Half the instances are the FMU of a scene (`package.py --scene`): resources holding
    // the two-exit room, which refuses scenes with other exits or bodies.
    let resources = rng.chance(0.5).then(scene_fmu_resources);
    let api = support::instantiate_in(v3, &log, logging_on, resources);
    let scenes = scenes();
    let scene_names = [
        scenes.join("fmu/corridor-door.toml"),
        scenes.join("scenes/room-60.toml"),
        scenes.join("scenes/room-two-exits.toml"),
        scenes.join("scenes/no-such-scene.toml"),
        scenes.join("fmu"),
    ];
    let mut states: Vec<*mut c_void> = Vec::new();
    let mut saved: Vec<Vec<u8>> = Vec::new();
    let mut t = 0.0;
    let proper = rng.chance(0.8);
    for call in 0..calls {
        let before = log.borrow().len();
        let what = match call {
            0 if proper => 0,
            1 if proper => 1,
            2 if proper => 2,
            _ => rng.below(KINDS),
        };
        // SAFETY (every call below): the instance is live; each array holds as many values
        // as its length says; each state pointer is a live state of this instance.
        let status = unsafe {
            match what {
                0 => {
                    let text = match if call == 0 {
                        rng.below(3)
                    } else {
                        rng.below(7)
                    } {
                        5 => CString::new("\u{1}garbage").unwrap(),
                        // The default: the resources' scene, or an error without them.
                        6 => CString::default(),
                        k => CString::new(scene_names[k].display().to_string()).unwrap(),
                    };
                    api.set_scene(&text)
                }
                1 => {
                    t = if rng.chance(0.8) {
                        0.0
                    } else {
                        hostile(&mut rng)
                    };
                    let tol = rng.chance(0.5).then(|| hostile(&mut rng));
                    let stop = rng.chance(0.3).then(|| hostile(&mut rng));
                    api.enter_initialization(tol, t, stop)
                }
                2 => api.exit_initialization(),
                3..=5 => {
                    let at = if rng.chance(0.85) {
                        t
                    } else {
                        hostile(&mut rng)
                    };
                    let h = if rng.chance(0.8) {
                        [0.05, 0.1, 0.25][rng.below(3)]
                    } else {
                        hostile(&mut rng)
                    };
                    let status = api.do_step(at, h);
                    if status == OK {
                        t = at + h;
                    }
                    status
                }
                6 | 7 => {
                    let r = reference(&mut rng);
                    let n = rng.below(3);
                    let values: Vec<f64> = (0..n).map(|_| hostile(&mut rng)).collect();
                    api.set_real(r, &values)
                }
                8 => {
                    let refs: Vec<u32> = (0..rng.below(4)).map(|_| reference(&mut rng)).collect();
                    let mut out = vec![0.0; rng.below(200)];
                    api.get_real(&refs, &mut out)
                }
                9 => {
                    let refs: Vec<u32> = (0..rng.below(3)).map(|_| reference(&mut rng)).collect();
                    let mut out = vec![0; rng.below(3)];
                    api.get_integer(&refs, &mut out)
                }
                10 => {
                    let mut state = std::ptr::null_mut();
                    let status = api.get_state(&mut state);
                    if status == OK {
                        states.push(state);
                    }
                    status
                }
                11 if !states.is_empty() => {
                    let s = states[rng.below(states.len())];
                    api.set_state(s)
                }
                12 if !states.is_empty() => {
                    let mut s = states.swap_remove(rng.below(states.len()));
                    api.free_state(&mut s)
                }
                13 if !states.is_empty() => {
                    let s = states[rng.below(states.len())];
                    match api.serialize(s) {
                        Ok(bytes) => {
                            saved.push(bytes);
                            OK
                        }
                        Err(status) => status,
                    }
                }
                14 if !saved.is_empty() => {
                    let mut bytes = saved[rng.below(saved.len())].clone();
                    match rng.below(3) {
                        0 => {}
                        1 => {
                            for _ in 0..1 + rng.below(3) {
                                let at = rng.below(bytes.len());
                                bytes[at] = rng.next() as u8;
                            }
                        }
                        _ => bytes.truncate(rng.below(bytes.len())),
                    }
                    let mut state = std::ptr::null_mut();
                    let status = api.deserialize(&bytes, &mut state);
                    if status == OK {
                        states.push(state);
                    }
                    status
                }
                15 => {
                    t = 0.0;
                    api.reset()
                }
                16 => api.terminate(),
                17 => {
                    let r = reference(&mut rng);
                    let values: Vec<i32> = (0..rng.below(3))
                        .map(|_| [0, 1, 2, -1][rng.below(4)])
                        .collect();
                    api.set_boolean(r, &values)
                }
                18 => {
                    let refs: Vec<u32> = (0..rng.below(3)).map(|_| reference(&mut rng)).collect();
                    let mut out = vec![0; rng.below(3)];
                    api.get_boolean(&refs, &mut out)
                }
                _ => api.other(),
            }
        };
        assert!(
            [OK, WARNING, DISCARD, ERROR].contains(&status),
            "seed {seed}, call {call} ({what}): status {status}"
        );
        if status == ERROR && v3 {
            assert!(
                log.borrow().len() > before,
                "seed {seed}, call {call} ({what}): refused without a log line"
            );
        } else if status == OK {
            answered[what] += 1;
        }
    }
    for mut s in states {
        // SAFETY: live states of this instance, each freed once.
        let status = unsafe { api.free_state(&mut s) };
        assert_eq!(status, OK, "seed {seed}: freeing a state");
    }
    // (Its log outlives it.)
    api.free();
    // No number printed with every digit (Rust's `{}` writes 1e300 with three hundred).
    for line in log.borrow().iter() {
        let mut run = 0;
        let buried = line.chars().any(|c| {
            run = if c.is_ascii_digit() { run + 1 } else { 0 };
            run > 24
        });
        assert!(!buried, "seed {seed}: a log line buries a number: {line}");
    }
    let refused = log
        .borrow()
        .iter()
        .any(|line| line.contains("the FMU declares"));
    drop(log);
    refused
}

/// The kinds of call a sequence draws from (see `sequence`).
const KINDS: usize = 19;

#[test]
fn random_call_sequences_get_a_status_and_a_log_line_never_a_crash() {
    let seconds: u64 = std::env::var("MOREAU_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let deadline = Instant::now() + Duration::from_secs(seconds);
    let (mut sequences, mut answered, mut refused) = (0u64, [0; KINDS], 0);
    // (However short the time, on until a scene FMU has refused a scene, within reason.)
    while sequences < 8 || Instant::now() < deadline || (refused == 0 && sequences < 2_000) {
        refused += usize::from(sequence(sequences, 60, &mut answered));
        sequences += 1;
    }
    println!(
        "{sequences} sequences of 60 calls; answered OK, by kind: {answered:?}; {refused} \
         scene FMUs refused another scene"
    );
    assert!(
        refused > 0,
        "no scene FMU refused a scene in {sequences} sequences"
    );
    // Not all refused: the sequences step, and take, set, serialize and read back states.
    for (kind, what) in [
        (3, "steps"),
        (10, "states taken"),
        (11, "states set"),
        (14, "states read back"),
    ] {
        assert!(
            answered[kind] > 0,
            "no {what} in {sequences} sequences: {answered:?}"
        );
    }
}
