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
