//! What both FMI layers share: the component behind an instance pointer, and `with`, which
//! checks the pointer, catches panics and turns errors into a status and a log line.

use std::ffi::{CStr, CString, c_char, c_int, c_uint, c_void};
use std::panic::{AssertUnwindSafe, catch_unwind};

use crate::FmuError;
use crate::runtime::{Instance, State};

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

/// Runs `f` on the component behind `c`: null, panics and errors become `fmi2Error` (errors
/// logged); `fatal` errors also put the instance in the error state.
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
        if component.instance.state == State::Error
            && !matches!(
                function,
                "fmi2Reset" | "fmi2GetRealStatus" | "fmi2GetBooleanStatus" | "fmi3Reset"
            )
        {
            return Err(FmuError::State {
                function: function.to_string(),
                state: State::Error,
            });
        }
        f(component)
    }));
    match outcome {
        Ok(Ok(())) => OK,
        Ok(Err(e)) => {
            component.instance.error(&format!("{function}: {e}"));
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
