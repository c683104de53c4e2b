//! A fuzzer of scene files (proptest): mutated scenes go through the parser, validation,
//! `Simulation::new` and five steps, which must answer every one with a value or an error,
//! never a panic or an abort, and quickly: each case has a minute on a thread of its own, so
//! a run that never ends fails the test with its scene. The seeds are
//! `tests/fuzz-corpus/*.toml` (valid scenes and every input that once crashed); the mutations
//! set numbers to extremes (0, −1, NaN, ±∞, 1e±308, 5e-324, …), drop and retype keys, choose
//! the solver, the broad phase and the desired velocity, move polygon vertices, and cut or
//! splice the text. Failing cases are kept in `fuzz_scenes.proptest-regressions` (replayed
//! first).
//!
//! CI runs it for `MOREAU_FUZZ_SECONDS` (default 30 s); the README's testing section gives the
//! 10-minute command. Sizes are capped (≤ 3,000 people, grids within the library's limit) so
//! that each accepted scene builds in well under a second.

use std::time::{Duration, Instant};

use moreau_crowd::{Scene, Simulation};
use proptest::prelude::*;
use proptest::test_runner::{
    Config, FileFailurePersistence, RngAlgorithm, TestCaseError, TestRng, TestRunner,
};
use toml::Value;

fn corpus() -> Vec<(String, String)> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/fuzz-corpus");
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read_to_string(&p).unwrap(),
            )
        })
        .collect()
}

/// One edit of a scene.
#[derive(Debug, Clone)]
enum Mutation {
    /// Sets the number at path `which` (of [`PATHS`]) to `value`.
    Number(usize, f64),
    /// Sets the integer at path `which` to `value`.
    Integer(usize, i64),
    /// Removes the key at path `which`.
    Remove(usize),
    /// Puts a string where the value at path `which` is.
    Retype(usize),
    /// Moves vertex `k` of polygon `which` (of [`POLYGONS`]) to `(x, y)`.
    Vertex(usize, usize, f64, f64),
    /// Drops vertex `k` of polygon `which`.
    DropVertex(usize, usize),
    /// Sets the word at path `which` (of [`WORDS`]) to its choice `k`.
    Word(usize, usize),
}

/// The keys that take a word, and the words each takes (every solver, so that the solvers'
/// stops are reached from hostile tolerances and steps too; until session 37 every mutated
/// scene ran the corpus' `auto`).
const WORDS: &[(&str, &[&str])] = &[
    (
        "solver.kind",
        &[
            "auto",
            "interior",
            "newton",
            "gauss-seidel",
            "apgd",
            "clarabel",
        ],
    ),
    ("solver.broad_phase", &["auto", "grid", "bvh"]),
    ("model.desired_velocity", &["classic", "lipschitz"]),
];

const PATHS: &[&str] = &[
    "time.horizon",
    "time.step",
    "time.output_interval",
    "time.tol",
    "solver.eps_kappa",
    "solver.max_violation",
    "solver.grid_cell",
    "solver.threads",
    "groups.0.count",
    "groups.0.radius",
    "groups.0.speed",
    "seed",
    "exits.0.name",
    "groups.0.destination",
    "groups.0.release",
    "exits.0.closes.0",
    "exits.0.opens.1",
    "moving.0.keyframes.1.t",
    "moving.0.keyframes.1.angle",
    "moving.0.pivot.0",
    "moving.1.keyframes.1.offset.1",
    "model.field_update",
    "sources.0.rate",
];

const POLYGONS: &[&str] = &[
    "area.outer",
    "exits.0.area",
    "exits.0.target",
    "groups.0.spawn",
    "moving.1.polygon",
    "moving.0.line",
];

fn extreme() -> impl Strategy<Value = f64> {
    prop_oneof![
        3 => prop::sample::select(vec![
            0.0, -0.0, -1.0, 1e-300, 5e-324, 1e308, -1e308, 1e300, f64::NAN, f64::INFINITY,
            f64::NEG_INFINITY, 1e15, 1e16, -1e15, 1e-6, 1e-3, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0,
            10.0, 1e3, 1e7, f64::MIN_POSITIVE, f64::EPSILON,
        ]),
        1 => -1e3..1e3f64,
        1 => any::<f64>(),
    ]
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let path = 0..PATHS.len();
    let poly = 0..POLYGONS.len();
    prop_oneof![
        4 => (path.clone(), extreme()).prop_map(|(p, v)| Mutation::Number(p, v)),
        2 => (path.clone(), prop::sample::select(vec![
            0i64, -1, 1, 2, 5, 100, 3000, 1 << 31, i64::MAX, i64::MIN, 1 << 40,
        ])).prop_map(|(p, v)| Mutation::Integer(p, v)),
        1 => path.clone().prop_map(Mutation::Remove),
        1 => path.prop_map(Mutation::Retype),
        3 => (poly.clone(), 0..16usize, extreme(), extreme())
            .prop_map(|(p, k, x, y)| Mutation::Vertex(p, k, x, y)),
        1 => (poly, 0..16usize).prop_map(|(p, k)| Mutation::DropVertex(p, k)),
        2 => (0..WORDS.len(), 0..6usize).prop_map(|(p, k)| Mutation::Word(p, k)),
    ]
}

/// The value at a dotted path (list indices as numbers), if there.
fn at<'a>(root: &'a mut Value, path: &str) -> Option<&'a mut Value> {
    let mut node = root;
    for part in path.split('.') {
        node = match node {
            Value::Table(t) => t.get_mut(part)?,
            Value::Array(a) => a.get_mut(part.parse::<usize>().ok()?)?,
            _ => return None,
        };
    }
    Some(node)
}

fn set(root: &mut Value, path: &str, value: Value) {
    let (parent, last) = path.rsplit_once('.').unwrap_or(("", path));
    let node = if parent.is_empty() {
        Some(root)
    } else {
        at(root, parent)
    };
    match node {
        Some(Value::Table(t)) => {
            t.insert(last.to_string(), value);
        }
        Some(Value::Array(a)) => {
            if let Some(slot) = last.parse::<usize>().ok().and_then(|i| a.get_mut(i)) {
                *slot = value;
            }
        }
        _ => {}
    }
}

fn apply(root: &mut Value, m: &Mutation) {
    match *m {
        Mutation::Number(p, v) => set(root, PATHS[p], Value::Float(v)),
        Mutation::Integer(p, v) => {
            // Sizes capped so that an accepted scene builds fast (see the module's doc).
            let v = if PATHS[p] == "groups.0.count" {
                v.min(3000)
            } else {
                v
            };
            set(root, PATHS[p], Value::Integer(v))
        }
        Mutation::Remove(p) => {
            let (parent, last) = PATHS[p].rsplit_once('.').unwrap_or(("", PATHS[p]));
            let node = if parent.is_empty() {
                Some(&mut *root)
            } else {
                at(root, parent)
            };
            if let Some(Value::Table(t)) = node {
                t.remove(last);
            }
        }
        Mutation::Retype(p) => set(root, PATHS[p], Value::String("x".into())),
        Mutation::Vertex(p, k, x, y) => {
            if let Some(Value::Array(v)) = at(root, POLYGONS[p])
                && !v.is_empty()
            {
                let k = k % v.len();
                v[k] = Value::Array(vec![Value::Float(x), Value::Float(y)]);
            }
        }
        Mutation::Word(p, k) => {
            let (path, words) = WORDS[p];
            let (table, key) = path.rsplit_once('.').unwrap();
            // A scene without the table (no `[model]`, say) is given one.
            if let Value::Table(t) = root
                && !t.contains_key(table)
            {
                t.insert(table.into(), Value::Table(toml::map::Map::new()));
            }
            if let Some(Value::Table(t)) = at(root, table) {
                t.insert(key.into(), Value::String(words[k % words.len()].into()));
            }
        }
        Mutation::DropVertex(p, k) => {
            if let Some(Value::Array(v)) = at(root, POLYGONS[p])
                && !v.is_empty()
            {
                let k = k % v.len();
                v.remove(k);
            }
        }
    }
}

/// Whether a message prints a number with more digits in a row than any `f64` needs (17
/// significant digits, 20 for a `u64`): Rust's `{}` writes 1e300 with three hundred, which
/// buried the error (a radius of 1e300, a speed factor of 1e300; regression).
fn buried_number(message: &str) -> bool {
    let mut run = 0;
    message.chars().any(|c| {
        run = if c.is_ascii_digit() { run + 1 } else { 0 };
        run > 24
    })
}

/// A valid scene's text → whatever it becomes: a clean error whose message prints its numbers
/// in a few characters, or a simulation that must be able to report its first frame.
fn check(text: &str) -> Result<(), TestCaseError> {
    let scene = match Scene::from_toml(text, "<fuzz>") {
        Ok(scene) => scene,
        // (A parse error quotes the fuzzer's own line.)
        Err(moreau_crowd::CrowdError::Parse { .. }) => return Ok(()),
        Err(e) => {
            let message = e.to_string();
            prop_assert!(!buried_number(&message), "{message}");
            return Ok(());
        }
    };
    // Too big to build quickly, though valid (the fuzzer's cap, not the library's).
    if scene.groups.iter().any(|g| g.count.unwrap_or(0) > 3000) {
        return Ok(());
    }
    let horizon = scene.time.horizon;
    let built = Simulation::new(scene);
    if let Err(e) = &built {
        let message = e.to_string();
        prop_assert!(!buried_number(&message), "{message}");
    }
    if let Ok(mut sim) = built {
        let frame = sim.frame();
        prop_assert!(frame.positions.iter().all(|x| x.is_finite()));
        // Every scene that builds takes a few steps too (the broad phase, the fields, the
        // step limit, the contacts with moving bodies, an infeasible step's diagnosis):
        // values or errors, never a panic (until session 30 only scenes with moving bodies
        // stepped).
        for _ in 0..5 {
            match sim.advance_step(horizon, &mut ()) {
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(e) => {
                    let message = e.to_string();
                    prop_assert!(!buried_number(&message), "{message}");
                    break;
                }
            }
        }
    }
    Ok(())
}

/// How long one case may take before it counts as a hang: an accepted scene builds in well
/// under a second and takes five steps (session 36 found runs that never ended: a step
/// retried forever at the smallest step, multiplier updates forever at a target gap of ∞).
const BUDGET: Duration = Duration::from_secs(60);

/// The first scene that took longer than [`BUDGET`]: once one has, every case passes at once
/// (shrinking would leave a spinning thread per try) and the run fails with it.
static HUNG: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

/// [`check`] on a thread of its own, given [`BUDGET`]: a panic is a failure, as is a case
/// that does not end (its thread is left running).
fn check_in_time(text: &str) -> Result<(), TestCaseError> {
    if HUNG.lock().unwrap().is_some() {
        return Ok(());
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let owned = text.to_string();
    std::thread::spawn(move || {
        let _ = tx.send(std::panic::catch_unwind(|| check(&owned)));
    });
    match rx.recv_timeout(BUDGET) {
        Ok(Ok(outcome)) => outcome,
        Ok(Err(_)) => Err(TestCaseError::fail("panicked")),
        Err(_) => {
            *HUNG.lock().unwrap() = Some(text.to_string());
            Err(TestCaseError::fail(format!("took more than {BUDGET:?}")))
        }
    }
}

/// The runner of batch `batch`: 64 cases from a random stream of its own (a runner counts
/// the cases it passed and runs none once it has its 64, so every batch needs a new one;
/// seeded by the batch number, a run is reproducible).
fn runner(batch: u64) -> TestRunner {
    let file = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fuzz_scenes.proptest-regressions"
    );
    let mut seed = [0u8; 32];
    seed[..8].copy_from_slice(&batch.to_le_bytes());
    TestRunner::new_with_rng(
        Config {
            cases: 64,
            failure_persistence: Some(Box::new(FileFailurePersistence::Direct(file))),
            source_file: Some(file),
            ..Config::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &seed),
    )
}

#[test]
fn the_corpus_gives_values_or_errors() {
    for (name, text) in corpus() {
        let outcome = check_in_time(&text);
        assert!(outcome.is_ok(), "{name}: {outcome:?}");
    }
}

#[test]
fn mutated_scenes_give_values_or_errors_never_panics() {
    let seconds: u64 = std::env::var("MOREAU_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(30);
    let corpus = corpus();
    let deadline = Instant::now() + Duration::from_secs(seconds);
    let strategy = (
        0..corpus.len(),
        prop::collection::vec(mutation(), 1..5),
        prop_oneof![4 => Just(None), 1 => (0.0..1.0f64, any::<u8>()).prop_map(Some)],
    );
    let mut cases = 0u64;
    // Batches of 64 cases until the time is up, each from its own runner (a runner that has
    // passed its 64 cases runs no more: the first version of this loop counted 5·10⁹ "cases"
    // in 10 minutes and ran 64).
    while cases == 0 || Instant::now() < deadline {
        let mut runner = runner(cases / 64);
        let outcome = runner.run(&strategy, |(seed, mutations, splice)| {
            let (_, text) = &corpus[seed];
            let mut text = match toml::from_str::<Value>(text) {
                Ok(mut root) => {
                    for m in &mutations {
                        apply(&mut root, m);
                    }
                    toml::to_string(&root).unwrap_or_default()
                }
                Err(_) => text.clone(),
            };
            // Sometimes cut the text at a character and put a byte there.
            if let Some((at, byte)) = splice {
                let mut cut = (at * text.len() as f64) as usize;
                while !text.is_char_boundary(cut) {
                    cut -= 1;
                }
                text.truncate(cut);
                text.push(char::from(byte));
            }
            check_in_time(&text)
        });
        if let Some(text) = HUNG.lock().unwrap().take() {
            panic!("a scene took more than {BUDGET:?} (a hang?):\n{text}");
        }
        if let Err(e) = outcome {
            panic!("{e}");
        }
        cases += 64;
    }
    println!("{cases} mutated scenes in {seconds} s");
    // Each case parses, validates and builds a simulation: thousands a second at most.
    assert!(
        cases < 100_000 * seconds.max(1),
        "{cases} cases in {seconds} s: the runner is not running them"
    );
}
