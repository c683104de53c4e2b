//! What both FMI layers share: the component behind an instance pointer, the FMI state
//! machine (which function each state allows, checked at every entry), `with`, which checks
//! the pointer and the state, catches panics and turns errors into a status and a log line,
//! and the FMU-state entry points (get, set, free, serialize) over opaque pointers.

use std::cell::{Cell, RefCell};
use std::ffi::{CStr, CString, c_char, c_int, c_uint, c_void};
use std::panic::{AssertUnwindSafe, UnwindSafe, catch_unwind};
use std::sync::Once;

use crate::FmuError;
use crate::runtime::{Instance, State};
use crate::snapshot::Snapshot;

/// `fmi2Status` / `fmi3Status` (the same values).
pub type Status = c_int;
/// OK.
pub const OK: Status = 0;
/// Warning.
pub const WARNING: Status = 1;
/// Error.
pub const ERROR: Status = 3;
/// Fatal.
pub const FATAL: Status = 4;

thread_local! {
    /// Whether this thread is inside an FMI call (its panics are the FMU's to report).
    static INSIDE: Cell<bool> = const { Cell::new(false) };
    /// The message of the last panic caught inside an FMI call on this thread.
    static PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// `catch_unwind` for the FMI entry points, without Rust's "thread panicked at" on the host's
/// standard error: a panic inside an FMI call is recorded (its message goes to the FMI logger,
/// through [`panic_message`]); panics anywhere else in the host process still reach the hook
/// that was there before.
pub(crate) fn quiet_catch<R>(f: impl FnOnce() -> R + UnwindSafe) -> std::thread::Result<R> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let before = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if INSIDE.with(Cell::get) {
                let message = info
                    .payload()
                    .downcast_ref::<String>()
                    .map(String::as_str)
                    .or_else(|| info.payload().downcast_ref::<&str>().copied())
                    .unwrap_or("(no message)");
                let at = info
                    .location()
                    .map_or(String::new(), |l| format!(" at {}:{}", l.file(), l.line()));
                PANIC.with(|p| *p.borrow_mut() = Some(format!("{message}{at}")));
            } else {
                before(info);
            }
        }));
    });
    let outer = INSIDE.with(|i| i.replace(true));
    let result = catch_unwind(f);
    INSIDE.with(|i| i.set(outer));
    result
}

/// The message of the last panic [`quiet_catch`] caught on this thread.
pub(crate) fn panic_message() -> String {
    PANIC
        .with(|p| p.borrow_mut().take())
        .unwrap_or_else(|| "no message".into())
}

/// What an `fmi2Component` points to.
pub(crate) struct Component {
    pub(crate) instance: Instance,
    pub(crate) strings: Vec<CString>,
}

pub(crate) fn c_text(s: &str) -> CString {
    CString::new(s.replace('\0', " ")).expect("no NUL left")
}

use State::{Configuration, Error, Initialization, Instantiated, Stepping, Terminated};

/// Every state.
const ANY: &[State] = &[
    Instantiated,
    Configuration,
    Initialization,
    Stepping,
    Terminated,
    Error,
];
/// Every state but Error.
const ALIVE: &[State] = &[
    Instantiated,
    Configuration,
    Initialization,
    Stepping,
    Terminated,
];
/// Where values may be set (which variable in which state: the runtime's check).
const SETTABLE: &[State] = &[Instantiated, Configuration, Initialization, Stepping];

/// The states in which the FMI function `function` (`fmi2…` or `fmi3…`) may be called: the
/// co-simulation state machines of FMI 2.0 (§4.2.4) and FMI 3.0 (§4.2), folded onto
/// [`State`]. Which variable may be set or read in which state is the runtime's finer check.
pub(crate) fn allowed(function: &str) -> &'static [State] {
    match function.get(4..).unwrap_or("") {
        "SetupExperiment" | "EnterInitializationMode" | "EnterConfigurationMode" => &[Instantiated],
        "ExitConfigurationMode" => &[Configuration],
        "ExitInitializationMode" => &[Initialization],
        "DoStep" => &[Stepping],
        "Terminate" => &[Stepping],
        // FMI 2.0's state table allows its getters in the error state too ("values usable
        // for debugging only", as the Reference FMUs' masks have it); FMI 3.0 (§2.3.1) puts
        // an FMU whose call returned fmi3Error in Terminated, where its getters are allowed
        // ("retrieved values should only be used for debugging purposes"). The values are
        // those of the last step that succeeded.
        "GetReal" | "GetInteger" | "GetBoolean" | "GetString" | "GetFloat64" | "GetInt32"
        | "GetUInt64" => ANY,
        "SetReal" | "SetInteger" | "SetBoolean" | "SetString" | "SetFloat64" | "SetInt32"
        | "SetUInt64" => SETTABLE,
        // Nothing sound to save once a call failed; but going back to a saved state is how a
        // master recovers from a failed step, so setting (and handling) states stays allowed.
        "GetFMUstate" | "GetFMUState" => ALIVE,
        "SetFMUstate"
        | "SetFMUState"
        | "FreeFMUstate"
        | "FreeFMUState"
        | "SerializedFMUstateSize"
        | "SerializedFMUStateSize"
        | "SerializeFMUstate"
        | "SerializeFMUState"
        | "DeSerializeFMUstate"
        | "DeserializeFMUState" => ANY,
        // Logging, reset, the status queries, and the functions this FMU does not provide
        // (they answer that, in any state).
        _ => ANY,
    }
}

/// Runs `f` on the component behind `c` once the state machine allows `function`: null,
/// a state that does not allow it, panics and errors become an error status (logged); a
/// failed step also puts the instance in the error state, a panic makes it unusable.
pub(crate) fn with(
    c: *mut c_void,
    function: &'static str,
    f: impl FnOnce(&mut Component) -> Result<(), FmuError>,
) -> Status {
    if c.is_null() {
        return ERROR;
    }
    // SAFETY: a non-null fmi2Component is a pointer fmi2Instantiate returned and
    // fmi2FreeInstance has not freed (the standard's contract with the host).
    let component = unsafe { &mut *(c as *mut Component) };
    let outcome = quiet_catch(AssertUnwindSafe(|| {
        component.instance.expect(function, allowed(function))?;
        f(component)
    }));
    match outcome {
        Ok(Ok(())) => OK,
        Ok(Err(e)) => {
            match &e {
                FmuError::State { function: f, .. } if f.as_str() == function => {
                    component.instance.error(&e.to_string())
                }
                _ => component.instance.error(&format!("{function}: {e}")),
            }
            if matches!(e, FmuError::Crowd(_)) && function.ends_with("DoStep") {
                component.instance.state = State::Error;
            }
            ERROR
        }
        Err(_) => {
            component.instance.state = State::Error;
            component.instance.error(&format!(
                "{function}: internal error (panic: {}); the instance is unusable",
                panic_message()
            ));
            FATAL
        }
    }
}

/// `(vr, nvr)` as a slice, refusing null pointers.
pub(crate) unsafe fn refs<'a>(vr: *const c_uint, nvr: usize) -> Result<&'a [c_uint], FmuError> {
    if nvr == 0 {
        return Ok(&[]);
    }
    if vr.is_null() {
        return Err(FmuError::Null("vr"));
    }
    // SAFETY: the host passes `nvr` value references at `vr`.
    Ok(unsafe { std::slice::from_raw_parts(vr, nvr) })
}

pub(crate) unsafe fn values<'a, T>(value: *const T, n: usize) -> Result<&'a [T], FmuError> {
    if n == 0 {
        return Ok(&[]);
    }
    if value.is_null() {
        return Err(FmuError::Null("value"));
    }
    // SAFETY: the host passes `n` values at `value`.
    Ok(unsafe { std::slice::from_raw_parts(value, n) })
}

pub(crate) unsafe fn values_mut<'a, T>(value: *mut T, n: usize) -> Result<&'a mut [T], FmuError> {
    if n == 0 {
        return Ok(&mut []);
    }
    if value.is_null() {
        return Err(FmuError::Null("value"));
    }
    // SAFETY: the host provides room for `n` values at `value`.
    Ok(unsafe { std::slice::from_raw_parts_mut(value, n) })
}

pub(crate) unsafe fn text<'a>(s: *const c_char, what: &'static str) -> Result<&'a str, FmuError> {
    if s.is_null() {
        return Err(FmuError::Null(what));
    }
    // SAFETY: the host passes a NUL-terminated string.
    unsafe { CStr::from_ptr(s) }
        .to_str()
        .map_err(|_| FmuError::Setting(format!("{what} is not UTF-8")))
}

/// `fmi2SetDebugLogging` / `fmi3SetDebugLogging`: logging on or off, for the `n` categories
/// at `categories` (all of them for none). The categories were ignored: with only
/// `logStatusError` asked for, informational lines still came, and an unknown category was
/// taken.
///
/// # Safety
/// `categories` holds `n` NUL-terminated strings (the host's contract).
pub(crate) unsafe fn set_debug_logging(
    comp: &mut Component,
    on: bool,
    n: usize,
    categories: *const *const c_char,
) -> Result<(), FmuError> {
    // SAFETY: the host's `n` pointers.
    let names = unsafe { values(categories, n) }?;
    let mut all = names.is_empty();
    for &name in names {
        // SAFETY: each a NUL-terminated string.
        match unsafe { text(name, "categories") }? {
            "logAll" => all = true,
            "logStatusWarning" | "logStatusError" => {}
            other => {
                return Err(FmuError::Setting(format!(
                    "log category '{other}': the categories are logStatusWarning, \
                     logStatusError and logAll"
                )));
            }
        }
    }
    comp.instance.logging_on = on && all;
    Ok(())
}

/// Reads one value per scalar reference: `nvr` references at `vr`, `n_values` slots at
/// `value` (FMI 2 passes `nvr` for both), each filled by `get`.
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` values (the host's contract).
pub(crate) unsafe fn get_scalars<T>(
    comp: &mut Component,
    vr: *const c_uint,
    nvr: usize,
    value: *mut T,
    n_values: usize,
    mut get: impl FnMut(&mut Instance, u32) -> Result<T, FmuError>,
) -> Result<(), FmuError> {
    if nvr != n_values {
        return Err(FmuError::Setting(format!(
            "nValues = {n_values} for {nvr} scalar references"
        )));
    }
    // SAFETY: the host's arrays, as above.
    let (refs, out) = unsafe { (refs(vr, nvr)?, values_mut(value, n_values)?) };
    for (slot, &r) in out.iter_mut().zip(refs) {
        *slot = get(&mut comp.instance, r)?;
    }
    Ok(())
}

/// Sets one value per scalar reference through `set` (see [`get_scalars`]).
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` values.
pub(crate) unsafe fn set_scalars<T: Copy>(
    comp: &mut Component,
    vr: *const c_uint,
    nvr: usize,
    value: *const T,
    n_values: usize,
    mut set: impl FnMut(&mut Instance, u32, T) -> Result<(), FmuError>,
) -> Result<(), FmuError> {
    if nvr != n_values {
        return Err(FmuError::Setting(format!(
            "nValues = {n_values} for {nvr} scalar references"
        )));
    }
    // SAFETY: the host's arrays, as above.
    let (refs, vals) = unsafe { (refs(vr, nvr)?, values(value, n_values)?) };
    for (&r, &v) in refs.iter().zip(vals) {
        set(&mut comp.instance, r, v)?;
    }
    Ok(())
}

/// Reads String variables; the pointers stay valid until the next call on this instance.
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` pointers.
pub(crate) unsafe fn get_strings(
    comp: &mut Component,
    vr: *const c_uint,
    nvr: usize,
    value: *mut *const c_char,
    n_values: usize,
) -> Result<(), FmuError> {
    // SAFETY: the host's arrays, as above.
    let refs = unsafe { refs(vr, nvr)? };
    comp.strings.clear();
    for &r in refs {
        let s = comp.instance.get_string(r)?;
        comp.strings.push(c_text(&s));
    }
    if refs.len() != n_values {
        return Err(FmuError::Setting(format!(
            "nValues = {n_values} for {nvr} scalar references"
        )));
    }
    // SAFETY: room for `n_values` pointers.
    let out = unsafe { values_mut(value, n_values)? };
    for (slot, s) in out.iter_mut().zip(&comp.strings) {
        *slot = s.as_ptr();
    }
    Ok(())
}

/// Sets String variables.
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` NUL-terminated strings.
pub(crate) unsafe fn set_strings(
    comp: &mut Component,
    vr: *const c_uint,
    nvr: usize,
    value: *const *const c_char,
    n_values: usize,
) -> Result<(), FmuError> {
    // SAFETY: the host's arrays; each string is checked by `text`.
    unsafe {
        set_scalars(comp, vr, nvr, value, n_values, |inst, r, v| {
            inst.set_string(r, text(v, "value")?)
        })
    }
}

// ---- FMU states ---------------------------------------------------------------------------

/// What an `fmi2FMUstate` / `fmi3FMUState` points to: a tag first (so that a pointer that is
/// not a state of this FMU is refused rather than read as one), the snapshot, and its
/// serialized form once asked for (size, then serialize: serialized once).
#[repr(C)]
pub(crate) struct StateBox {
    tag: u64,
    snapshot: Snapshot,
    bytes: Option<Vec<u8>>,
}

const STATE_TAG: u64 = u64::from_le_bytes(*b"moreauST");

/// The states this FMU has handed out and not freed, by address (any instance's, in this
/// process): a pointer is read as a state only if it is one of them, so a host variable left
/// uninitialized, or a state already freed, is never read (it crashed the host).
static LIVE_STATES: std::sync::Mutex<std::collections::BTreeSet<usize>> =
    std::sync::Mutex::new(std::collections::BTreeSet::new());

fn live_states() -> std::sync::MutexGuard<'static, std::collections::BTreeSet<usize>> {
    LIVE_STATES.lock().unwrap_or_else(|e| e.into_inner())
}

/// Whether `state` is a state this FMU handed out and has not freed.
fn is_live(state: *mut c_void) -> bool {
    live_states().contains(&(state as usize))
}

/// The state behind `state`, refusing null and pointers that are no state of this FMU.
///
/// # Safety
/// `state` is null or a pointer this FMU handed out as a state and has not freed.
unsafe fn state_box<'a>(state: *mut c_void) -> Result<&'a mut StateBox, FmuError> {
    if state.is_null() {
        return Err(FmuError::Null("FMUstate"));
    }
    if !is_live(state) {
        return Err(FmuError::Setting(
            "FMUstate does not point to a state of this FMU (freed already?)".into(),
        ));
    }
    // SAFETY: the caller's contract: at least the 8 bytes of a tag are readable there. Only
    // the tag (first field of a `repr(C)` struct) is read before it is known to be ours.
    let tag = unsafe { std::ptr::read_unaligned(state as *const u64) };
    if tag != STATE_TAG {
        return Err(FmuError::Setting(
            "FMUstate does not point to a state of this FMU (freed already?)".into(),
        ));
    }
    // SAFETY: the tag says it is a live `StateBox` this FMU made (the caller's contract).
    Ok(unsafe { &mut *(state as *mut StateBox) })
}

/// Puts `snapshot` behind `*slot`: into the state it points to when that is a live state of
/// this FMU (FMI: a non-null `*FMUstate` is a state to overwrite; fmpy and the Reference-FMUs
/// reuse it so), else a new state. A pointer that is no live state (an uninitialized
/// variable, a state freed already) is never read: it crashed the host.
///
/// # Safety
/// `slot` is null or points to the host's pointer variable.
unsafe fn store(slot: *mut *mut c_void, snapshot: Snapshot) -> Result<(), FmuError> {
    if slot.is_null() {
        return Err(FmuError::Null("FMUstate"));
    }
    // SAFETY: `slot` points to the host's pointer variable.
    let slot = unsafe { &mut *slot };
    if !is_live(*slot) {
        let state = Box::into_raw(Box::new(StateBox {
            tag: STATE_TAG,
            snapshot,
            bytes: None,
        })) as *mut c_void;
        live_states().insert(state as usize);
        *slot = state;
    } else {
        // SAFETY: a state of this FMU (the caller's contract; the tag is checked).
        let b = unsafe { state_box(*slot)? };
        b.snapshot = snapshot;
        b.bytes = None;
    }
    Ok(())
}

/// `fmi2GetFMUstate` / `fmi3GetFMUState`.
///
/// # Safety
/// `slot` points to the host's `FMUstate` variable (null, or a state of this FMU).
pub(crate) unsafe fn get_state(
    comp: &mut Component,
    slot: *mut *mut c_void,
) -> Result<(), FmuError> {
    if slot.is_null() {
        return Err(FmuError::Null("FMUstate"));
    }
    let snapshot = comp.instance.snapshot()?;
    // SAFETY: as the caller's contract.
    unsafe { store(slot, snapshot) }
}

/// `fmi2SetFMUstate` / `fmi3SetFMUState`.
///
/// # Safety
/// `state` is a state of this FMU, not freed.
pub(crate) unsafe fn set_state(comp: &mut Component, state: *mut c_void) -> Result<(), FmuError> {
    // SAFETY: as the caller's contract.
    let b = unsafe { state_box(state)? };
    comp.instance.restore(&b.snapshot)?;
    comp.instance.info("FMU state restored");
    Ok(())
}

/// `fmi2FreeFMUstate` / `fmi3FreeFMUState`: frees `*slot` and sets it to null (a null
/// `*slot` is nothing to free).
///
/// # Safety
/// `slot` points to the host's `FMUstate` variable (null, or a state of this FMU).
pub(crate) unsafe fn free_state(slot: *mut *mut c_void) -> Result<(), FmuError> {
    if slot.is_null() {
        return Err(FmuError::Null("FMUstate"));
    }
    // SAFETY: `slot` points to the host's pointer variable.
    let slot = unsafe { &mut *slot };
    if slot.is_null() {
        return Ok(());
    }
    // SAFETY: a state of this FMU (live, tag checked).
    let b = unsafe { state_box(*slot)? };
    b.tag = 0;
    live_states().remove(&(*slot as usize));
    // SAFETY: the state came from `Box::into_raw` in `store` and is freed once: it is no
    // longer live, its tag is gone and the host's pointer is cleared.
    drop(unsafe { Box::from_raw(*slot as *mut StateBox) });
    *slot = std::ptr::null_mut();
    Ok(())
}

/// The serialized form of the state behind `state`, made once.
///
/// # Safety
/// `state` is a state of this FMU, not freed.
unsafe fn serialized<'a>(state: *mut c_void) -> Result<&'a [u8], FmuError> {
    // SAFETY: as the caller's contract.
    let b = unsafe { state_box(state)? };
    let snapshot = &b.snapshot;
    Ok(b.bytes.get_or_insert_with(|| snapshot.to_bytes()))
}

/// `fmi2SerializedFMUstateSize` / `fmi3SerializedFMUStateSize`.
///
/// # Safety
/// `state` is a state of this FMU; `size` points to one `size_t`.
pub(crate) unsafe fn state_size(state: *mut c_void, size: *mut usize) -> Result<(), FmuError> {
    // SAFETY: as the caller's contract.
    let (bytes, out) = unsafe { (serialized(state)?, values_mut(size, 1)?) };
    out[0] = bytes.len();
    Ok(())
}

/// `fmi2SerializeFMUstate` / `fmi3SerializeFMUState`: `size` must be the size
/// [`state_size`] gave.
///
/// # Safety
/// `state` is a state of this FMU; `out` has room for `size` bytes.
pub(crate) unsafe fn serialize_state(
    state: *mut c_void,
    out: *mut u8,
    size: usize,
) -> Result<(), FmuError> {
    // SAFETY: as the caller's contract.
    let bytes = unsafe { serialized(state)? };
    if size != bytes.len() {
        return Err(FmuError::Setting(format!(
            "size = {size}: the serialized state is {} bytes (SerializedFMUstateSize)",
            bytes.len()
        )));
    }
    // SAFETY: room for `size` bytes at `out`.
    unsafe { values_mut(out, size)? }.copy_from_slice(bytes);
    Ok(())
}

/// `fmi2DeSerializeFMUstate` / `fmi3DeserializeFMUState`: a state from its serialized form
/// (checked: this FMU's, its format; the scene is checked when it is set), into the live
/// state `*slot` holds, else a new one.
///
/// # Safety
/// `bytes` holds `size` bytes; `slot` points to the host's `FMUstate` variable.
pub(crate) unsafe fn deserialize_state(
    bytes: *const u8,
    size: usize,
    slot: *mut *mut c_void,
) -> Result<(), FmuError> {
    if size == 0 {
        return Err(FmuError::Setting(
            "size = 0: an empty serialized state".into(),
        ));
    }
    // SAFETY: `size` bytes at `bytes`.
    let snapshot = Snapshot::from_bytes(unsafe { values(bytes, size)? })?;
    // A live state of this FMU in `*slot` is reused, as fmpy (`deSerializeFMUstate(bytes,
    // state)`) and the Reference-FMUs do; anything else is never read (an uninitialized
    // variable crashed the host) and a new state is made.
    // SAFETY: as the caller's contract.
    unsafe { store(slot, snapshot) }
}

#[cfg(test)]
mod tests {
    use std::cell::RefCell;
    use std::path::PathBuf;
    use std::rc::Rc;

    use super::*;
    use crate::model::vr;

    fn scenes() -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/scenes"))
    }

    /// A component on the room (or `scene`), with the log lines it sends.
    fn component(scene: Option<&str>) -> (Box<Component>, Rc<RefCell<Vec<String>>>) {
        let lines = Rc::new(RefCell::new(Vec::new()));
        let sink = lines.clone();
        let mut instance = Instance::new(
            "test".into(),
            Some(scenes()),
            false,
            Box::new(move |_, m: &str| sink.borrow_mut().push(m.to_string())),
        );
        if let Some(s) = scene {
            instance.settings.scene = scenes().join(s).display().to_string();
        }
        let comp = Box::new(Component {
            instance,
            strings: Vec::new(),
        });
        (comp, lines)
    }

    #[test]
    fn debug_logging_ignored_its_categories() {
        // Only logStatusError asked for: informational lines kept coming, and an unknown
        // category was taken.
        let (mut comp, lines) = component(None);
        let names = |v: &[&std::ffi::CStr]| v.iter().map(|c| c.as_ptr()).collect::<Vec<_>>();
        let errors_only = names(&[c"logStatusError"]);
        // SAFETY: our array of NUL-terminated strings.
        unsafe { set_debug_logging(&mut comp, true, 1, errors_only.as_ptr()) }.unwrap();
        comp.instance.info("an informational line");
        assert!(lines.borrow().is_empty(), "{:?}", lines.borrow());
        comp.instance.error("an error");
        assert_eq!(lines.borrow().len(), 1);
        let all = names(&[c"logStatusWarning", c"logAll"]);
        // SAFETY: as above.
        unsafe { set_debug_logging(&mut comp, true, 2, all.as_ptr()) }.unwrap();
        comp.instance.info("an informational line");
        assert_eq!(lines.borrow().len(), 2);
        // No categories: all of them.
        // SAFETY: no names are read.
        unsafe { set_debug_logging(&mut comp, true, 0, std::ptr::null()) }.unwrap();
        assert!(comp.instance.logging_on);
        let unknown = names(&[c"logEverything"]);
        // SAFETY: as above.
        let e = unsafe { set_debug_logging(&mut comp, true, 1, unknown.as_ptr()) }.unwrap_err();
        assert!(
            e.to_string().contains("log category 'logEverything'"),
            "{e}"
        );
    }

    fn stepping(scene: Option<&str>) -> (Box<Component>, Rc<RefCell<Vec<String>>>) {
        let (mut comp, lines) = component(scene);
        comp.instance.enter_initialization().unwrap();
        comp.instance.exit_initialization().unwrap();
        (comp, lines)
    }

    fn ptr(comp: &mut Component) -> *mut c_void {
        comp as *mut Component as *mut c_void
    }

    /// What a master reads: every scalar output and the FMI 3 positions.
    fn outputs(comp: &mut Component) -> (Vec<i32>, Vec<f64>, Vec<f64>) {
        let inst = &mut comp.instance;
        let ints = [vr::PEOPLE_INSIDE, vr::PEOPLE_EVACUATED, vr::INTERNAL_STEPS]
            .map(|r| inst.get_integer(r).unwrap())
            .to_vec();
        let mut reals: Vec<f64> = [vr::MEAN_SPEED, vr::MIN_GAP, vr::EPS]
            .map(|r| inst.get_real(r).unwrap())
            .to_vec();
        reals.push(inst.time().unwrap());
        let mut q = vec![0.0; inst.array_len(vr::POSITIONS).unwrap()];
        inst.get_array(vr::POSITIONS, &mut q).unwrap();
        (ints, reals, q)
    }

    fn steps(comp: &mut Component, from: f64, n: usize, h: f64) {
        for k in 0..n {
            comp.instance.do_step(from + k as f64 * h, h).unwrap();
        }
    }

    #[test]
    fn each_call_is_refused_outside_the_states_the_standard_allows_it_in() {
        let (mut comp, lines) = component(None);
        let c = ptr(&mut comp);
        let mut ran = false;
        assert_eq!(
            with(c, "fmi2DoStep", |_| {
                ran = true;
                Ok(())
            }),
            ERROR
        );
        assert!(!ran, "the glue refuses before the runtime is asked");
        assert_eq!(
            lines.borrow().last().unwrap(),
            "fmi2DoStep is not allowed in state Instantiated (only in Stepping)"
        );
        assert_eq!(with(c, "fmi3ExitConfigurationMode", |_| Ok(())), ERROR);
        assert!(
            lines
                .borrow()
                .last()
                .unwrap()
                .contains("only in Configuration")
        );
        assert_eq!(with(c, "fmi2SetupExperiment", |_| Ok(())), OK);
        assert_eq!(with(c, "fmi2GetFMUstate", |_| Ok(())), OK);

        comp.instance.state = State::Terminated;
        let c = ptr(&mut comp);
        assert_eq!(with(c, "fmi2DoStep", |_| Ok(())), ERROR);
        assert_eq!(with(c, "fmi3SetFloat64", |_| Ok(())), ERROR);
        assert!(lines.borrow().last().unwrap().contains("Configuration"));
        // FMI 2 has no Configuration mode: its refusals named it.
        assert_eq!(with(c, "fmi2SetReal", |_| Ok(())), ERROR);
        let line = lines.borrow().last().unwrap().clone();
        assert!(
            line.starts_with("fmi2SetReal is not allowed in state Terminated (only in")
                && !line.contains("Configuration"),
            "{line}"
        );
        assert_eq!(with(c, "fmi2GetReal", |_| Ok(())), OK);

        // After a failed call: reset, status and going back to a saved state only.
        comp.instance.state = State::Error;
        let c = ptr(&mut comp);
        for refused in [
            "fmi2DoStep",
            "fmi3DoStep",
            "fmi2GetFMUstate",
            "fmi3GetFMUState",
        ] {
            assert_eq!(with(c, refused, |_| Ok(())), ERROR, "{refused}");
        }
        for fine in [
            // FMI 2.0 allows its getters after an error, for debugging, and FMI 3.0 puts the
            // FMU in Terminated, where its getters are allowed; both were refused.
            "fmi2GetReal",
            "fmi2GetInteger",
            "fmi3GetFloat64",
            "fmi3GetUInt64",
            "fmi2SetFMUstate",
            "fmi2FreeFMUstate",
            "fmi2DeSerializeFMUstate",
            "fmi3SetFMUState",
            "fmi3SerializeFMUState",
            "fmi2Reset",
            "fmi2GetRealStatus",
        ] {
            assert_eq!(with(c, fine, |_| Ok(())), OK, "{fine}");
        }
        assert_eq!(with(std::ptr::null_mut(), "fmi2Reset", |_| Ok(())), ERROR);
    }

    #[test]
    fn a_state_set_back_gives_what_followed_it_bit_for_bit() {
        let (mut comp, _) = stepping(None);
        steps(&mut comp, 0.0, 4, 0.5);
        let at_2s = outputs(&mut comp);
        let mut slot: *mut c_void = std::ptr::null_mut();
        // SAFETY: a slot of ours; the state is freed below.
        unsafe { get_state(&mut comp, &mut slot).unwrap() };
        assert!(!slot.is_null());

        comp.instance.set_boolean(vr::DOOR_OPEN, false).unwrap();
        steps(&mut comp, 2.0, 4, 0.5);
        let closed = outputs(&mut comp);

        // SAFETY: the live state from above.
        unsafe { set_state(&mut comp, slot).unwrap() };
        assert_eq!(outputs(&mut comp), at_2s, "the outputs at the saved point");
        assert!(
            comp.instance.get_boolean(vr::DOOR_OPEN).unwrap(),
            "inputs too"
        );
        comp.instance.set_boolean(vr::DOOR_OPEN, false).unwrap();
        steps(&mut comp, 2.0, 4, 0.5);
        assert_eq!(outputs(&mut comp), closed, "the same inputs: the same run");

        // Getting into a live state overwrites it in place.
        let before = slot;
        // SAFETY: as above.
        unsafe { get_state(&mut comp, &mut slot).unwrap() };
        assert_eq!(slot, before);
        // SAFETY: as above; freed once, then the slot is null and freeing it is a no-op.
        unsafe {
            free_state(&mut slot).unwrap();
            assert!(slot.is_null());
            free_state(&mut slot).unwrap();
        }
    }

    #[test]
    fn a_serialized_state_restores_into_a_new_instance_of_the_scene_only() {
        let (mut comp, _) = stepping(None);
        steps(&mut comp, 0.0, 6, 0.5);
        let mut slot: *mut c_void = std::ptr::null_mut();
        let mut size = 0usize;
        // SAFETY: our slot, size and buffer.
        let bytes = unsafe {
            get_state(&mut comp, &mut slot).unwrap();
            state_size(slot, &mut size).unwrap();
            let mut bytes = vec![0u8; size];
            let short = serialize_state(slot, bytes.as_mut_ptr(), size - 1);
            assert!(
                short
                    .unwrap_err()
                    .to_string()
                    .contains(&format!("{size} bytes"))
            );
            serialize_state(slot, bytes.as_mut_ptr(), size).unwrap();
            free_state(&mut slot).unwrap();
            bytes
        };
        steps(&mut comp, 3.0, 4, 0.5);
        let straight = outputs(&mut comp);

        // A new instance of the same scene, never initialized: the state puts it in step mode.
        let (mut again, _) = component(None);
        // SAFETY: the bytes above; our slot.
        unsafe {
            deserialize_state(bytes.as_ptr(), bytes.len(), &mut slot).unwrap();
            set_state(&mut again, slot).unwrap();
        }
        assert_eq!(again.instance.state, State::Stepping);
        steps(&mut again, 3.0, 4, 0.5);
        assert_eq!(outputs(&mut again), straight);

        // Another scene: refused with a log line, and that instance goes on unchanged.
        let (mut other, lines) = stepping(Some("room-60.toml"));
        steps(&mut other, 0.0, 2, 0.5);
        let c = ptr(&mut other);
        // SAFETY: the live state.
        let status = with(c, "fmi2SetFMUstate", |comp| unsafe {
            set_state(comp, slot)
        });
        assert_eq!(status, ERROR);
        let line = lines.borrow().last().unwrap().clone();
        assert!(
            line.contains("saved from another scene") && line.contains("room-60.toml"),
            "{line}"
        );
        assert_eq!(other.instance.time(), Some(1.0));
        steps(&mut other, 1.0, 1, 0.5);

        // Another desired speed factor: refused, the factors in a few characters (1e-300 was
        // printed with three hundred digits; regression).
        let (mut slow, lines) = component(None);
        slow.instance
            .set_real(vr::DESIRED_SPEED_FACTOR, 1e-300)
            .unwrap();
        let c = ptr(&mut slow);
        // SAFETY: the live state.
        let status = with(c, "fmi2SetFMUstate", |comp| unsafe {
            set_state(comp, slot)
        });
        assert_eq!(status, ERROR);
        let line = lines.borrow().last().unwrap().clone();
        assert!(
            line.contains("saved with desired_speed_factor = 1, this instance has 1e-300"),
            "{line}"
        );

        // Damaged or foreign bytes are refused when deserialized, naming what is wrong.
        let mut fresh: *mut c_void = std::ptr::null_mut();
        // SAFETY: slices of ours.
        unsafe {
            let e = deserialize_state(bytes.as_ptr(), bytes.len() - 3, &mut fresh).unwrap_err();
            assert!(e.to_string().starts_with("serializedState:"), "{e}");
            let junk = [7u8; 64];
            let e = deserialize_state(junk.as_ptr(), junk.len(), &mut fresh).unwrap_err();
            assert!(
                e.to_string().contains("not start as a state of this FMU"),
                "{e}"
            );
            let mut newer = bytes.clone();
            newer[8] = 99;
            let e = deserialize_state(newer.as_ptr(), newer.len(), &mut fresh).unwrap_err();
            assert!(e.to_string().contains("format 99"), "{e}");
            assert!(fresh.is_null());
            free_state(&mut slot).unwrap();
        }
    }

    #[test]
    fn a_state_variable_that_held_no_live_state_was_read_as_one() {
        // A host's `FMUstate` variable left uninitialized (or holding a state freed already)
        // was read as a state (its tag at that address): a crash, or a use after free. Only
        // a live state of this FMU is read and reused (as fmpy and the Reference-FMUs reuse
        // one); anything else gets a new state and is never read.
        let (mut comp, _) = stepping(None);
        steps(&mut comp, 0.0, 4, 0.5);
        let at_two = outputs(&mut comp);
        let (mut early, mut late): (*mut c_void, *mut c_void) =
            (std::ptr::null_mut(), std::ptr::null_mut());
        let mut size = 0usize;
        // SAFETY: our slots, size and buffers; `junk` and the freed pointer are never read.
        unsafe {
            let (mut back, _) = stepping(None);
            steps(&mut back, 0.0, 2, 0.5);
            get_state(&mut back, &mut early).unwrap();
            get_state(&mut comp, &mut late).unwrap();
            state_size(late, &mut size).unwrap();
            let mut bytes = vec![0u8; size];
            serialize_state(late, bytes.as_mut_ptr(), size).unwrap();
            // Into a variable holding what is no state at all, with this FMU's tag at its
            // start (it was taken for a state and overwritten): a new state.
            let mut junk = [0u64; 64];
            junk[0] = STATE_TAG;
            let junk_ptr = junk.as_mut_ptr() as *mut c_void;
            let mut slot = junk_ptr;
            deserialize_state(bytes.as_ptr(), size, &mut slot).unwrap();
            assert_ne!(slot, junk_ptr);
            assert_eq!(junk[1..], [0u64; 63][..], "the junk was written to");
            set_state(&mut comp, slot).unwrap();
            assert_eq!(outputs(&mut comp), at_two);
            // A state freed already is not live: refused by set and free, never read.
            let mut freed = slot;
            free_state(&mut slot).unwrap();
            assert!(set_state(&mut comp, freed).is_err());
            assert!(free_state(&mut freed).is_err());
            // Into a live state: reused in place (what the host asked, as with GetFMUstate).
            let mut reused = early;
            deserialize_state(bytes.as_ptr(), size, &mut reused).unwrap();
            assert_eq!(reused, early);
            set_state(&mut comp, early).unwrap();
            assert_eq!(outputs(&mut comp), at_two);
            for s in [&mut early, &mut late] {
                free_state(s).unwrap();
            }
        }
    }

    #[test]
    fn a_step_past_the_stop_time_the_experiment_set_up_was_taken() {
        use crate::fmi2::{
            fmi2DoStep, fmi2EnterInitializationMode, fmi2ExitInitializationMode,
            fmi2SetupExperiment,
        };
        use crate::fmi3::{fmi3EnterInitializationMode, fmi3ExitInitializationMode};
        // FMI 2.0 §4.2.1: "if the environment tries to compute past stopTime the FMU has to
        // return fmi2Error". Both FMUs stepped on to t = 6 with stopTime = 1.
        let (mut comp, lines) = component(None);
        let c = ptr(&mut comp);
        assert_eq!(fmi2SetupExperiment(c, 0, 0.0, 0.0, 1, 1.0), OK);
        assert_eq!(fmi2EnterInitializationMode(c), OK);
        assert_eq!(fmi2ExitInitializationMode(c), OK);
        assert_eq!(fmi2DoStep(c, 0.0, 0.5, 1), OK);
        // 0.5 + 0.500001 ends within the Reference-FMUs' isClose (10⁻⁵) of the stop time: a
        // host counting time in single precision gets there.
        assert_eq!(fmi2DoStep(c, 0.5, 0.5 + 1e-6, 1), OK);
        let t = comp.instance.time().unwrap();
        assert_eq!(fmi2DoStep(c, t, 0.5, 1), ERROR);
        assert_eq!(comp.instance.time(), Some(t));
        let line = lines.borrow().last().unwrap().clone();
        assert!(line.contains("after stopTime = 1 s"), "{line}");
        // Without a stop time (stopTimeDefined false) it steps on.
        let (mut free, _) = component(None);
        let c = ptr(&mut free);
        assert_eq!(fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 1.0), OK);
        assert_eq!(fmi2EnterInitializationMode(c), OK);
        assert_eq!(fmi2ExitInitializationMode(c), OK);
        assert_eq!(fmi2DoStep(c, 0.0, 1.5, 1), OK);
        // FMI 3 sets it entering initialization; a stop before the start is refused.
        let (mut three, lines) = component(None);
        let c = ptr(&mut three);
        assert_eq!(
            fmi3EnterInitializationMode(c, false, 0.0, 2.0, true, 1.0),
            ERROR
        );
        let line = lines.borrow().last().unwrap().clone();
        assert!(
            line.contains("stopTime = 1: before startTime = 2"),
            "{line}"
        );
        assert_eq!(
            fmi3EnterInitializationMode(c, false, 0.0, 0.0, true, 0.75),
            OK
        );
        assert_eq!(fmi3ExitInitializationMode(c), OK);
        assert!(three.instance.do_step(0.0, 0.5).is_ok());
        let e = three.instance.do_step(0.5, 0.5).unwrap_err().to_string();
        assert!(e.contains("after stopTime = 0.75 s"), "{e}");
        assert!(three.instance.do_step(0.5, 0.25).is_ok());
    }

    #[test]
    fn time_was_an_unknown_value_reference_though_fmi3_declares_it() {
        // FMI 3's model description declares `time` (value reference 0, independent): getting
        // and setting it said "unknown value reference 0".
        let (mut comp, _) = component(None);
        comp.instance.set_start_time(2.0);
        assert_eq!(comp.instance.get_real(vr::TIME).unwrap(), 2.0);
        comp.instance.enter_initialization().unwrap();
        comp.instance.exit_initialization().unwrap();
        steps(&mut comp, 2.0, 3, 0.5);
        assert_eq!(comp.instance.get_real(vr::TIME).unwrap(), 3.5);
        let e = comp
            .instance
            .set_real(vr::TIME, 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("independent variable"), "{e}");
        assert_eq!(comp.instance.time(), Some(3.5));
    }

    #[test]
    fn a_failed_step_is_undone_by_going_back_to_a_saved_state() {
        let (mut comp, _) = stepping(None);
        steps(&mut comp, 0.0, 2, 0.5);
        let saved = comp.instance.snapshot().unwrap();
        comp.instance.state = State::Error; // as after a failed step
        let mut slot: *mut c_void = std::ptr::null_mut();
        let c = ptr(&mut comp);
        // SAFETY: our slot.
        assert_eq!(
            with(c, "fmi2GetFMUstate", |comp| unsafe {
                get_state(comp, &mut slot)
            }),
            ERROR
        );
        // SAFETY: our slot, then the live state.
        unsafe {
            store(&mut slot, saved).unwrap();
            assert_eq!(with(c, "fmi2SetFMUstate", |comp| set_state(comp, slot)), OK);
            free_state(&mut slot).unwrap();
        }
        assert_eq!(comp.instance.state, State::Stepping);
        steps(&mut comp, 1.0, 1, 0.5);
    }

    #[test]
    fn a_pointer_that_is_no_state_of_this_fmu_is_refused() {
        let (mut comp, _) = stepping(None);
        let mut not_a_state = [0u64; 8];
        let p = not_a_state.as_mut_ptr() as *mut c_void;
        // SAFETY: 64 readable bytes; the tag check refuses them before anything else is read.
        let e = unsafe { set_state(&mut comp, p) }.unwrap_err();
        assert!(
            e.to_string().contains("not point to a state of this FMU"),
            "{e}"
        );
        // SAFETY: null is refused.
        let e = unsafe { set_state(&mut comp, std::ptr::null_mut()) }.unwrap_err();
        assert!(e.to_string().contains("FMUstate is a null pointer"), "{e}");
    }

    #[test]
    fn n_people_is_the_scenes_count_and_another_value_is_refused() {
        let (mut comp, _) = component(Some("room-60.toml"));
        assert_eq!(comp.instance.get_uint64(vr::N_PEOPLE).unwrap(), 60);
        assert_eq!(
            comp.instance.array_len(vr::RADII).ok(),
            None,
            "an output: not yet"
        );
        comp.instance.enter_configuration().unwrap();
        comp.instance.set_uint64(vr::N_PEOPLE, 150).unwrap();
        comp.instance.exit_configuration().unwrap();
        comp.instance.enter_initialization().unwrap();
        let e = comp.instance.exit_initialization().unwrap_err().to_string();
        assert!(
            e.starts_with("n_people = 150: the scene") && e.contains("has 60 people"),
            "{e}"
        );
        // Not settable once initializing.
        let e = comp
            .instance
            .set_uint64(vr::N_PEOPLE, 60)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("n_people cannot be set in state Initialization"),
            "{e}"
        );
    }
}

#[cfg(test)]
mod quiet_panics {
    use std::cell::RefCell;
    use std::rc::Rc;

    use super::*;

    /// Issue 20: a panic caught at an FMI entry still printed Rust's "thread '…' panicked at"
    /// on the host's standard error. Run in a child process (this test binary again), whose
    /// standard error is read whole.
    #[test]
    fn a_caught_panic_printed_panicked_at_on_the_hosts_stderr() {
        if std::env::var_os("MOREAU_FMU_PANIC_CHILD").is_some() {
            let lines = Rc::new(RefCell::new(Vec::new()));
            let sink = lines.clone();
            let mut comp = Component {
                instance: Instance::new(
                    "panics".into(),
                    None,
                    false,
                    Box::new(move |_, m: &str| sink.borrow_mut().push(m.to_string())),
                ),
                strings: Vec::new(),
            };
            let c = &mut comp as *mut Component as *mut c_void;
            let status = with(c, "fmi2SetupExperiment", |_| panic!("boom in the model"));
            assert_eq!(status, FATAL);
            println!("LOG: {}", lines.borrow().last().unwrap());
            // Panics outside an FMI call still reach the hook that was there before.
            let outside = std::panic::catch_unwind(|| panic!("outside the FMU"));
            assert!(outside.is_err());
            return;
        }
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "glue::quiet_panics::a_caught_panic_printed_panicked_at_on_the_hosts_stderr",
                "--nocapture",
                "--test-threads=1",
            ])
            .env("MOREAU_FMU_PANIC_CHILD", "1")
            .output()
            .unwrap();
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr),
        );
        assert!(out.status.success(), "{stdout}\n{stderr}");
        assert!(
            stdout.contains(
                "LOG: fmi2SetupExperiment: internal error (panic: boom in the model at fmu/src/glue.rs"
            ),
            "the panic's message goes to the FMI logger: {stdout}"
        );
        assert!(
            !stderr.contains("boom in the model"),
            "the host's stderr saw the FMU's panic: {stderr}"
        );
        assert!(
            stderr.contains("outside the FMU"),
            "panics outside the FMU keep the default hook: {stderr}"
        );
    }
}
