//! What both FMI layers share: the component behind an instance pointer, the FMI state
//! machine (which function each state allows, checked at every entry), `with`, which checks
//! the pointer and the state, catches panics and turns errors into a status and a log line,
//! and the FMU-state entry points (get, set, free, serialize) over opaque pointers.

use std::ffi::{CStr, CString, c_char, c_int, c_uint, c_void};
use std::panic::{AssertUnwindSafe, catch_unwind};

use crate::FmuError;
use crate::runtime::{Instance, State};
use crate::snapshot::Snapshot;

/// `fmi2Status` / `fmi3Status` (the same values).
pub type Status = c_int;
/// OK.
pub const OK: Status = 0;
/// Error.
pub const ERROR: Status = 3;
/// Fatal.
pub const FATAL: Status = 4;

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
        "SetupExperiment" | "EnterInitializationMode" | "EnterConfigurationMode" => {
            &[Instantiated]
        }
        "ExitConfigurationMode" => &[Configuration],
        "ExitInitializationMode" => &[Initialization],
        "DoStep" => &[Stepping],
        "Terminate" => &[Stepping],
        "GetReal" | "GetInteger" | "GetBoolean" | "GetString" | "GetFloat64" | "GetInt32"
        | "GetUInt64" => ALIVE,
        "SetReal" | "SetInteger" | "SetBoolean" | "SetString" | "SetFloat64" | "SetInt32"
        | "SetUInt64" => SETTABLE,
        // Nothing sound to save once a call failed; but going back to a saved state is how a
        // master recovers from a failed step, so setting (and handling) states stays allowed.
        "GetFMUstate" | "GetFMUState" => ALIVE,
        "SetFMUstate" | "SetFMUState" | "FreeFMUstate" | "FreeFMUState"
        | "SerializedFMUstateSize" | "SerializedFMUStateSize" | "SerializeFMUstate"
        | "SerializeFMUState" | "DeSerializeFMUstate" | "DeserializeFMUState" => ANY,
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
    let outcome = catch_unwind(AssertUnwindSafe(|| {
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
                "{function}: internal error (panic); the instance is unusable"
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

/// What an `fmi2FMUstate` / `fmi3FMUState` points to: a tag (so that a pointer that is not a
/// state of this FMU is refused rather than read as one), the snapshot, and its serialized
/// form once asked for (size, then serialize: serialized once).
pub(crate) struct StateBox {
    tag: u64,
    snapshot: Snapshot,
    bytes: Option<Vec<u8>>,
}

const STATE_TAG: u64 = u64::from_le_bytes(*b"moreauST");

/// The state behind `state`, refusing null and pointers that are no state of this FMU.
///
/// # Safety
/// `state` is null or a pointer this FMU handed out as a state and has not freed.
unsafe fn state_box<'a>(state: *mut c_void) -> Result<&'a mut StateBox, FmuError> {
    if state.is_null() {
        return Err(FmuError::Null("FMUstate"));
    }
    // SAFETY: the caller's contract: a live state of this FMU (its tag is checked next, which
    // catches a pointer to something else that is at least 8 bytes).
    let b = unsafe { &mut *(state as *mut StateBox) };
    if b.tag != STATE_TAG {
        return Err(FmuError::Setting(
            "FMUstate does not point to a state of this FMU (freed already?)".into(),
        ));
    }
    Ok(b)
}

/// Puts `snapshot` behind `*slot`: a new state when `*slot` is null, else into the state it
/// points to (FMI: a non-null `*FMUstate` is a state of this instance to overwrite).
///
/// # Safety
/// `slot` is null or points to a pointer that is null or a live state of this FMU.
unsafe fn store(slot: *mut *mut c_void, snapshot: Snapshot) -> Result<(), FmuError> {
    if slot.is_null() {
        return Err(FmuError::Null("FMUstate"));
    }
    // SAFETY: `slot` points to the host's pointer variable.
    let slot = unsafe { &mut *slot };
    if slot.is_null() {
        *slot = Box::into_raw(Box::new(StateBox {
            tag: STATE_TAG,
            snapshot,
            bytes: None,
        })) as *mut c_void;
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
    // SAFETY: a state of this FMU (tag checked).
    let b = unsafe { state_box(*slot)? };
    b.tag = 0;
    // SAFETY: the state came from `Box::into_raw` in `store` and is freed once: its tag is
    // gone and the host's pointer is cleared.
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
/// (checked: this FMU's, its format; the scene is checked when it is set).
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
    // SAFETY: as the caller's contract.
    unsafe { store(slot, snapshot) }
}
