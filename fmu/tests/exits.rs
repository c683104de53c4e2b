//! Each exit of the scene as an input (`exit_open.<name>`, value reference 2000 + its index;
//! exit 0's is `door_open`) and an output (`passed.<name>`, 3000 + its index), through the
//! FMI 2 and FMI 3 C API: a closed exit lets nobody out until it opens, an exit the scene does
//! not have is refused with a log line and changes nothing, and an FMU state restores the
//! inputs with the run.
// The FMI entry points are a C ABI: raw pointers, as a host passes them.
#![allow(unsafe_code)]

use std::cell::RefCell;
use std::ffi::{CString, c_int};

use moreau_fmu::model::vr;

mod support;
use support::{Api, ERROR, OK};

const WEST: u32 = 0;
const EAST: u32 = 1;

/// An instance on `data/scenes/room-two-exits.toml`, initialized at t = 0.
fn stepping(v3: bool, log: &RefCell<Vec<String>>) -> Api {
    let api = support::instantiate(v3, log, false);
    let scene = CString::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/scenes/room-two-exits.toml"
    ))
    .unwrap();
    // SAFETY: the live instance; one string, alive through the call.
    assert_eq!(unsafe { api.set_scene(&scene) }, OK);
    assert_eq!(api.enter_initialization(None, 0.0, None), OK);
    assert_eq!(api.exit_initialization(), OK);
    api
}

fn open(api: Api, exit: u32) -> bool {
    let mut out = vec![0; 1];
    // SAFETY: the live instance; one reference, room for one value.
    assert_eq!(
        unsafe { api.get_boolean(&[vr::EXIT_OPEN + exit], &mut out) },
        OK
    );
    out[0] != 0
}

fn set_open(api: Api, exit: u32, value: bool) -> c_int {
    // SAFETY: the live instance; one reference, one value.
    unsafe { api.set_boolean(vr::EXIT_OPEN + exit, &[value.into()]) }
}

fn passed(api: Api, exit: u32) -> i32 {
    let mut out = vec![0; 1];
    // SAFETY: the live instance; one reference, room for one value.
    assert_eq!(
        unsafe { api.get_integer(&[vr::EXIT_PASSED + exit], &mut out) },
        OK
    );
    out[0]
}

/// Steps from `t` to `t_end` in communication steps of 1 s.
fn run(api: Api, t: f64, t_end: f64) {
    let mut at = t;
    while at < t_end - 1e-9 {
        // SAFETY: the live instance.
        assert_eq!(unsafe { api.do_step(at, 1.0) }, OK);
        at += 1.0;
    }
}

#[test]
fn a_closed_exit_lets_nobody_out_and_a_state_restores_the_exits_inputs() {
    for v3 in [false, true] {
        let log = RefCell::new(Vec::new());
        let api = stepping(v3, &log);
        // Exit 0's input is door_open's.
        assert!(open(api, WEST) && open(api, EAST));
        assert_eq!(set_open(api, WEST, false), OK);
        let mut door = vec![1; 1];
        // SAFETY: the live instance; one reference, room for one value.
        assert_eq!(unsafe { api.get_boolean(&[vr::DOOR_OPEN], &mut door) }, OK);
        assert_eq!(door[0], 0);
        assert_eq!(set_open(api, WEST, true), OK);
        // The scene has two exits: a third is refused, naming them, and nothing changes.
        assert_eq!(set_open(api, 2, false), ERROR);
        if v3 {
            let said = log.borrow().join("\n");
            assert!(said.contains("2 exits"), "{said}");
        }
        assert!(open(api, WEST) && open(api, EAST));

        assert_eq!(set_open(api, EAST, false), OK);
        let mut closed = std::ptr::null_mut();
        // SAFETY: the live instance; a state pointer to fill.
        assert_eq!(unsafe { api.get_state(&mut closed) }, OK);
        run(api, 0.0, 8.0);
        assert_eq!(passed(api, EAST), 0);
        let west = passed(api, WEST);
        assert!(west > 0);
        assert_eq!(set_open(api, EAST, true), OK);
        run(api, 8.0, 20.0);
        assert!(passed(api, EAST) > 0);
        assert_eq!(passed(api, WEST) + passed(api, EAST), 60);

        // Back to the start with the east exit closed: closed again, and the same run.
        // SAFETY: a live state of this instance.
        assert_eq!(unsafe { api.set_state(closed) }, OK);
        assert!(!open(api, EAST) && passed(api, EAST) == 0);
        run(api, 0.0, 8.0);
        assert_eq!((passed(api, WEST), passed(api, EAST)), (west, 0));
        // SAFETY: the live state, freed once.
        assert_eq!(unsafe { api.free_state(&mut closed) }, OK);
        api.free();
    }
}

/// A directory standing for a scene FMU's `resources/`, holding `files` copied from
/// `data/scenes/` (emptied first, one per name).
fn resources(name: &str, files: &[&str]) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("moreau-fmu-resources-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for f in files {
        std::fs::copy(scene_file(f), dir.join(f)).unwrap();
    }
    dir
}

fn scene_file(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/scenes")
        .join(name)
}

/// A scene FMU (`package.py --scene`) declares its scene's exits and moving bodies by index;
/// another scene loaded through the `scene` parameter would answer `passed.west` with its own
/// exit 0 (regression: it did, under the old names, with nothing said).
#[test]
fn a_scene_fmu_refuses_a_scene_whose_exits_or_bodies_it_does_not_declare() {
    use moreau_fmu::model::{CrowdModel, Settings};
    let build = |scene: &std::path::Path, dir: &std::path::Path| {
        let settings = Settings {
            scene: scene.display().to_string(),
            ..Settings::default()
        };
        CrowdModel::new(&settings, Some(dir)).map(|_| ())
    };
    let two_exits = resources("two-exits", &["room-two-exits.toml"]);
    // The room: one exit `door`, no bodies.
    let err = build(&scene_file("room-150.toml"), &two_exits)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(
            r#"its exits are ["door"], the FMU declares exit_open/passed for ["west", "east"]"#
        ) && err.contains("room-150.toml")
            && err.contains("resources/room-two-exits.toml")
            && !err.contains("moving bodies"),
        "{err}"
    );
    // A moving body the FMU has no input for.
    let err = build(&scene_file("rotating-bar.toml"), &two_exits)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(r#"its moving bodies are ["bar"], the FMU declares moving for []"#),
        "{err}"
    );
    // The same exits, in a variant of the scene (fewer people, as a sweep writes it): taken.
    let variant = two_exits.join("variant");
    std::fs::create_dir_all(&variant).unwrap();
    let text = std::fs::read_to_string(scene_file("room-two-exits.toml"))
        .unwrap()
        .replace("count = 30", "count = 12");
    std::fs::write(variant.join("scene.toml"), text).unwrap();
    build(&variant.join("scene.toml"), &two_exits).unwrap();
    // The exits swapped: the names by index differ.
    let text = std::fs::read_to_string(scene_file("room-two-exits.toml"))
        .unwrap()
        .replace("name = \"west\"", "name = \"tmp\"")
        .replace("name = \"east\"", "name = \"west\"")
        .replace("name = \"tmp\"", "name = \"east\"");
    std::fs::write(variant.join("swapped.toml"), text).unwrap();
    assert!(build(&variant.join("swapped.toml"), &two_exits).is_err());
    // The room's FMU declares no scene's variables: it runs any scene.
    let room = resources("room", &["room-150.toml"]);
    build(&scene_file("room-two-exits.toml"), &room).unwrap();
    build(&scene_file("rotating-bar.toml"), &room).unwrap();
}
