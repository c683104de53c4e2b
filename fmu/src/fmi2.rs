//! FMI 2.0 co-simulation glue: the 34 functions of the standard. Every entry point checks its
//! pointers and the instance state, catches panics, and turns errors into `fmi2Error` and a
//! log line; the work is the runtime's.

use std::ffi::{c_char, c_int, c_uint, c_void};
use std::panic::AssertUnwindSafe;
use std::sync::LazyLock;

use crate::FmuError;
use crate::glue::{
    Component, ERROR, OK, Status, WARNING, c_text, deserialize_state, free_state, get_scalars,
    get_state, get_strings, serialize_state, set_scalars, set_state, set_strings, state_size, text,
    values_mut, with,
};
use crate::runtime::{Instance, Level, State};

const CO_SIMULATION: c_int = 1;
const LAST_SUCCESSFUL_TIME: c_int = 2;
const TERMINATED: c_int = 3;

/// The FMI 2 model description, as shipped in the FMU.
pub const MODEL_DESCRIPTION: &str = include_str!("../fmi2/modelDescription.xml");

/// The GUID the model description declares: `fmi2Instantiate` accepts no other.
pub static GUID: LazyLock<&'static str> =
    LazyLock::new(|| crate::xml_attribute(MODEL_DESCRIPTION, "guid"));

type Logger = Option<
    unsafe extern "C" fn(*mut c_void, *const c_char, Status, *const c_char, *const c_char, ...),
>;

/// `fmi2CallbackFunctions`.
#[repr(C)]
#[derive(Debug)]
pub struct CallbackFunctions {
    logger: Logger,
    allocate_memory: Option<unsafe extern "C" fn(usize, usize) -> *mut c_void>,
    free_memory: Option<unsafe extern "C" fn(*mut c_void)>,
    step_finished: Option<unsafe extern "C" fn(*mut c_void, Status)>,
    component_environment: *mut c_void,
}

// ---- Common functions ------------------------------------------------------------------

/// `fmi2GetTypesPlatform`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2GetTypesPlatform() -> *const c_char {
    c"default".as_ptr()
}

/// `fmi2GetVersion`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2GetVersion() -> *const c_char {
    c"2.0".as_ptr()
}

/// `fmi2SetDebugLogging`.
///
/// # Safety
/// `categories` holds `n` NUL-terminated strings, as the standard defines them.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetDebugLogging(
    c: *mut c_void,
    logging_on: c_int,
    n: usize,
    categories: *const *const c_char,
) -> Status {
    // SAFETY: the host's `n` category names.
    with(c, "fmi2SetDebugLogging", |comp| unsafe {
        crate::glue::set_debug_logging(comp, logging_on != 0, n, categories)
    })
}

/// `fmi2Instantiate`: null (and a log line when possible) for a wrong GUID, a type other than
/// co-simulation, or missing callbacks.
///
/// # Safety
/// The pointers are the host's, as the standard defines them.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2Instantiate(
    instance_name: *const c_char,
    fmu_type: c_int,
    guid: *const c_char,
    resource_location: *const c_char,
    functions: *const CallbackFunctions,
    _visible: c_int,
    logging_on: c_int,
) -> *mut c_void {
    let made = crate::glue::quiet_catch(AssertUnwindSafe(|| {
        if functions.is_null() {
            return None;
        }
        // SAFETY: non-null, points to the host's callback struct.
        let callbacks = unsafe { &*functions };
        let logger = callbacks.logger;
        let env = callbacks.component_environment;
        // SAFETY: the host's strings.
        let name = unsafe { text(instance_name, "instanceName") }
            .unwrap_or("?")
            .to_string();
        let c_name = c_text(&name);
        let log = move |level: Level, message: &str| {
            if let Some(logger) = logger {
                let (status, category) = match level {
                    Level::Info => (OK, c"logAll"),
                    Level::Warning => (WARNING, c"logStatusWarning"),
                    Level::Error => (ERROR, c"logStatusError"),
                };
                let message = c_text(message);
                // SAFETY: the host's logger; the message is passed as "%s" and an argument, so
                // no '%' in it is interpreted.
                unsafe {
                    logger(
                        env,
                        c_name.as_ptr(),
                        status,
                        category.as_ptr(),
                        c"%s".as_ptr(),
                        message.as_ptr(),
                    )
                };
            }
        };
        let fail = |message: String| {
            log(Level::Error, &format!("fmi2Instantiate: {message}"));
            None
        };
        if instance_name.is_null() {
            return fail("instanceName is a null pointer".into());
        }
        if fmu_type != CO_SIMULATION {
            return fail(format!(
                "fmuType = {fmu_type}: this FMU is for co-simulation only"
            ));
        }
        // SAFETY: the host's string.
        let given = match unsafe { text(guid, "fmuGUID") } {
            Ok(g) => g,
            Err(e) => return fail(e.to_string()),
        };
        if given != *GUID {
            return fail(format!("wrong GUID {given}: this binary is {}", *GUID));
        }
        let resources = if resource_location.is_null() {
            None
        } else {
            // SAFETY: the host's string.
            unsafe { text(resource_location, "fmuResourceLocation") }
                .ok()
                .map(crate::resource_path)
        };
        let instance = Instance::new(name, resources, logging_on != 0, Box::new(log));
        instance.info("instantiated");
        Some(Box::into_raw(Box::new(Component {
            instance,
            strings: Vec::new(),
        })) as *mut c_void)
    }));
    made.ok().flatten().unwrap_or(std::ptr::null_mut())
}

/// `fmi2FreeInstance`.
///
/// # Safety
/// `c` is null or a component from `fmi2Instantiate`, not freed yet.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2FreeInstance(c: *mut c_void) {
    if c.is_null() {
        return;
    }
    let _ = crate::glue::quiet_catch(AssertUnwindSafe(|| {
        // SAFETY: see above; ownership returns to Rust and is dropped.
        drop(unsafe { Box::from_raw(c as *mut Component) });
    }));
}

/// `fmi2SetupExperiment`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2SetupExperiment(
    c: *mut c_void,
    _tolerance_defined: c_int,
    _tolerance: f64,
    start_time: f64,
    stop_time_defined: c_int,
    stop_time: f64,
) -> Status {
    with(c, "fmi2SetupExperiment", |comp| {
        comp.instance
            .expect("fmi2SetupExperiment", &[State::Instantiated])?;
        if !start_time.is_finite() {
            return Err(FmuError::Setting(format!(
                "startTime = {start_time}: not a finite number"
            )));
        }
        comp.instance.set_start_time(start_time);
        comp.instance
            .set_stop_time((stop_time_defined != 0).then_some(stop_time))
    })
}

/// `fmi2EnterInitializationMode`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2EnterInitializationMode(c: *mut c_void) -> Status {
    with(c, "fmi2EnterInitializationMode", |comp| {
        comp.instance.enter_initialization()
    })
}

/// `fmi2ExitInitializationMode`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2ExitInitializationMode(c: *mut c_void) -> Status {
    with(c, "fmi2ExitInitializationMode", |comp| {
        comp.instance.exit_initialization()
    })
}

/// `fmi2Terminate`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2Terminate(c: *mut c_void) -> Status {
    with(c, "fmi2Terminate", |comp| comp.instance.terminate())
}

/// `fmi2Reset`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2Reset(c: *mut c_void) -> Status {
    with(c, "fmi2Reset", |comp| {
        comp.instance.reset();
        Ok(())
    })
}

// ---- Getting and setting values --------------------------------------------------------

/// `fmi2GetReal`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements, as the standard defines.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetReal(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *mut f64,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2GetReal", |comp| unsafe {
        get_scalars(comp, vr, nvr, value, nvr, Instance::get_real)
    })
}

/// `fmi2GetInteger`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetInteger(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *mut c_int,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2GetInteger", |comp| unsafe {
        get_scalars(comp, vr, nvr, value, nvr, Instance::get_integer)
    })
}

/// `fmi2GetBoolean`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetBoolean(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *mut c_int,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2GetBoolean", |comp| unsafe {
        get_scalars(comp, vr, nvr, value, nvr, |inst, r| {
            Ok(inst.get_boolean(r)? as c_int)
        })
    })
}

/// `fmi2GetString`: the strings stay valid until the next call on this instance.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetString(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *mut *const c_char,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2GetString", |comp| unsafe {
        get_strings(comp, vr, nvr, value, nvr)
    })
}

/// `fmi2SetReal`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetReal(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *const f64,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SetReal", |comp| unsafe {
        set_scalars(comp, vr, nvr, value, nvr, Instance::set_real)
    })
}

/// `fmi2SetInteger`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetInteger(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *const c_int,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SetInteger", |comp| unsafe {
        set_scalars(comp, vr, nvr, value, nvr, Instance::set_integer)
    })
}

/// `fmi2SetBoolean`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetBoolean(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *const c_int,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SetBoolean", |comp| unsafe {
        set_scalars(comp, vr, nvr, value, nvr, |inst, r, v| {
            inst.set_boolean(r, v != 0)
        })
    })
}

/// `fmi2SetString`.
///
/// # Safety
/// `vr` and `value` hold `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetString(
    c: *mut c_void,
    vr: *const c_uint,
    nvr: usize,
    value: *const *const c_char,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SetString", |comp| unsafe {
        set_strings(comp, vr, nvr, value, nvr)
    })
}

// ---- FMU states (canGetAndSetFMUstate, canSerializeFMUstate) ------------------------------

/// `fmi2GetFMUstate`: a new state in `*state` when it is null, else overwrites that state.
///
/// # Safety
/// `state` points to the host's `fmi2FMUstate` (null or a state of this FMU).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetFMUstate(c: *mut c_void, state: *mut *mut c_void) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2GetFMUstate", |comp| unsafe {
        get_state(comp, state)
    })
}

/// `fmi2SetFMUstate`: refused (error, log line, nothing changes) for a state of another scene.
///
/// # Safety
/// `state` is a state of this FMU, not freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetFMUstate(c: *mut c_void, state: *mut c_void) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SetFMUstate", |comp| unsafe {
        set_state(comp, state)
    })
}

/// `fmi2FreeFMUstate`: frees `*state` and sets it to null.
///
/// # Safety
/// `state` points to the host's `fmi2FMUstate` (null or a state of this FMU).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2FreeFMUstate(c: *mut c_void, state: *mut *mut c_void) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2FreeFMUstate", |_| unsafe { free_state(state) })
}

/// `fmi2SerializedFMUstateSize`.
///
/// # Safety
/// `state` is a state of this FMU; `size` points to one `size_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SerializedFMUstateSize(
    c: *mut c_void,
    state: *mut c_void,
    size: *mut usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SerializedFMUstateSize", |_| unsafe {
        state_size(state, size)
    })
}

/// `fmi2SerializeFMUstate`: `size` is what `fmi2SerializedFMUstateSize` said.
///
/// # Safety
/// `state` is a state of this FMU; `bytes` has room for `size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SerializeFMUstate(
    c: *mut c_void,
    state: *mut c_void,
    bytes: *mut c_char,
    size: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2SerializeFMUstate", |_| unsafe {
        serialize_state(state, bytes as *mut u8, size)
    })
}

/// `fmi2DeSerializeFMUstate`: checks that the bytes are a state of this FMU and format; the
/// scene is checked by `fmi2SetFMUstate`.
///
/// # Safety
/// `bytes` holds `size` bytes; `state` points to the host's `fmi2FMUstate`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2DeSerializeFMUstate(
    c: *mut c_void,
    bytes: *const c_char,
    size: usize,
    state: *mut *mut c_void,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi2DeSerializeFMUstate", |_| unsafe {
        deserialize_state(bytes as *const u8, size, state)
    })
}

// ---- What this FMU does not provide ----------------------------------------------------

macro_rules! unsupported {
    ($name:ident, $fmi:literal, ($($arg:ident: $ty:ty),*)) => {
        #[doc = concat!("`", $fmi, "`: not supported (an error and a log line).")]
        #[unsafe(no_mangle)]
        pub extern "C" fn $name(c: *mut c_void, $($arg: $ty),*) -> Status {
            $(let _ = $arg;)*
            with(c, $fmi, |_| Err(FmuError::Unsupported($fmi)))
        }
    };
}

unsupported!(fmi2GetDirectionalDerivative, "fmi2GetDirectionalDerivative", (unknown: *const c_uint, n_unknown: usize, known: *const c_uint, n_known: usize, dv_known: *const f64, dv_unknown: *mut f64));
unsupported!(fmi2SetRealInputDerivatives, "fmi2SetRealInputDerivatives", (vr: *const c_uint, nvr: usize, order: *const c_int, value: *const f64));
unsupported!(fmi2GetRealOutputDerivatives, "fmi2GetRealOutputDerivatives", (vr: *const c_uint, nvr: usize, order: *const c_int, value: *mut f64));
unsupported!(fmi2CancelStep, "fmi2CancelStep", ());
unsupported!(fmi2GetStatus, "fmi2GetStatus", (kind: c_int, value: *mut Status));
unsupported!(fmi2GetIntegerStatus, "fmi2GetIntegerStatus", (kind: c_int, value: *mut c_int));
unsupported!(fmi2GetStringStatus, "fmi2GetStringStatus", (kind: c_int, value: *mut *const c_char));

// ---- Co-simulation ---------------------------------------------------------------------

/// `fmi2DoStep`: steps the model to `t + h` with its internal steps.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2DoStep(c: *mut c_void, t: f64, h: f64, _no_set_prior: c_int) -> Status {
    with(c, "fmi2DoStep", |comp| comp.instance.do_step(t, h))
}

/// `fmi2GetRealStatus`: `fmi2LastSuccessfulTime` only.
///
/// # Safety
/// `value` points to one Real.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetRealStatus(c: *mut c_void, kind: c_int, value: *mut f64) -> Status {
    with(c, "fmi2GetRealStatus", |comp| {
        if kind != LAST_SUCCESSFUL_TIME {
            return Err(FmuError::Setting(format!(
                "status kind {kind} has no Real value"
            )));
        }
        // SAFETY: room for one value.
        let out = unsafe { values_mut(value, 1)? };
        out[0] = comp
            .instance
            .time()
            .unwrap_or(comp.instance.settings.start_time);
        Ok(())
    })
}

/// `fmi2GetBooleanStatus`: `fmi2Terminated` only (always false: the FMU never asks to stop).
///
/// # Safety
/// `value` points to one Boolean.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetBooleanStatus(
    c: *mut c_void,
    kind: c_int,
    value: *mut c_int,
) -> Status {
    with(c, "fmi2GetBooleanStatus", |_| {
        if kind != TERMINATED {
            return Err(FmuError::Setting(format!(
                "status kind {kind} has no Boolean value"
            )));
        }
        // SAFETY: room for one value.
        let out = unsafe { values_mut(value, 1)? };
        out[0] = 0;
        Ok(())
    })
}
