//! FMI 3.0 co-simulation glue: the 75 functions of the standard, with the array outputs
//! `positions[nPeople][2]` and `radii[nPeople]`. Same rules as the FMI 2 layer: pointers and
//! states checked, panics caught, errors become `fmi3Error` and a log line.

use std::ffi::{c_char, c_void};
use std::panic::AssertUnwindSafe;
use std::sync::LazyLock;

use crate::FmuError;
use crate::glue::{
    Component, Status, c_text, deserialize_state, free_state, get_scalars, get_state, get_strings,
    refs, serialize_state, set_scalars, set_state, set_strings, state_size, text, values_mut, with,
};
use crate::model::{Kind, variable, vr as refs_of};
use crate::runtime::{Instance, Level, State};

/// The FMI 3 model description, as shipped in the FMU.
pub const MODEL_DESCRIPTION: &str = include_str!("../fmi3/modelDescription.xml");

/// The instantiation token the model description declares.
pub static TOKEN: LazyLock<&'static str> =
    LazyLock::new(|| crate::xml_attribute(MODEL_DESCRIPTION, "instantiationToken"));

type LogMessage = Option<unsafe extern "C" fn(*mut c_void, Status, *const c_char, *const c_char)>;

fn instantiate(
    name: *const c_char,
    token: *const c_char,
    resource_path: *const c_char,
    logging_on: bool,
    env: *mut c_void,
    log_message: LogMessage,
    kind: &str,
) -> *mut c_void {
    let made = crate::glue::quiet_catch(AssertUnwindSafe(|| {
        // SAFETY: the host's string (or null).
        let instance_name = unsafe { text(name, "instanceName") }
            .unwrap_or("?")
            .to_string();
        let log = move |level: Level, message: &str| {
            if let Some(log_message) = log_message {
                let (status, category) = match level {
                    Level::Info => (0, c"logAll"),
                    Level::Warning => (1, c"logStatusWarning"),
                    Level::Error => (3, c"logStatusError"),
                };
                let message = c_text(message);
                // SAFETY: the host's callback with its environment.
                unsafe { log_message(env, status, category.as_ptr(), message.as_ptr()) };
            }
        };
        let fail = |message: String| {
            log(Level::Error, &format!("fmi3Instantiate{kind}: {message}"));
            None
        };
        if kind != "CoSimulation" {
            return fail("this FMU is for co-simulation only".into());
        }
        if name.is_null() {
            return fail("instanceName is a null pointer".into());
        }
        // SAFETY: the host's string.
        let given = match unsafe { text(token, "instantiationToken") } {
            Ok(t) => t,
            Err(e) => return fail(e.to_string()),
        };
        if given != *TOKEN {
            return fail(format!(
                "wrong instantiation token {given}: this binary is {}",
                *TOKEN
            ));
        }
        let resources = if resource_path.is_null() {
            None
        } else {
            // SAFETY: the host's string.
            unsafe { text(resource_path, "resourcePath") }
                .ok()
                .map(crate::resource_dir)
        };
        let instance = Instance::new(instance_name, resources, logging_on, Box::new(log));
        instance.info("instantiated");
        Some(Box::into_raw(Box::new(Component {
            instance,
            strings: Vec::new(),
        })) as *mut c_void)
    }));
    made.ok().flatten().unwrap_or(std::ptr::null_mut())
}

/// `fmi3GetVersion`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3GetVersion() -> *const c_char {
    c"3.0".as_ptr()
}

/// `fmi3SetDebugLogging`.
///
/// # Safety
/// `categories` holds `n` NUL-terminated strings, as the standard defines them.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetDebugLogging(
    c: *mut c_void,
    logging_on: bool,
    n: usize,
    categories: *const *const c_char,
) -> Status {
    // SAFETY: the host's `n` category names.
    with(c, "fmi3SetDebugLogging", |comp| unsafe {
        crate::glue::set_debug_logging(comp, logging_on, n, categories)
    })
}

/// `fmi3InstantiateModelExchange`: not provided (null and a log line).
#[unsafe(no_mangle)]
pub extern "C" fn fmi3InstantiateModelExchange(
    name: *const c_char,
    token: *const c_char,
    resource_path: *const c_char,
    _visible: bool,
    logging_on: bool,
    env: *mut c_void,
    log_message: LogMessage,
) -> *mut c_void {
    instantiate(
        name,
        token,
        resource_path,
        logging_on,
        env,
        log_message,
        "ModelExchange",
    )
}

/// `fmi3InstantiateCoSimulation`: null (and a log line) for a wrong instantiation token.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3InstantiateCoSimulation(
    name: *const c_char,
    token: *const c_char,
    resource_path: *const c_char,
    _visible: bool,
    logging_on: bool,
    _event_mode_used: bool,
    _early_return_allowed: bool,
    _required_intermediate: *const u32,
    _n_required_intermediate: usize,
    env: *mut c_void,
    log_message: LogMessage,
    _intermediate_update: *const c_void,
) -> *mut c_void {
    instantiate(
        name,
        token,
        resource_path,
        logging_on,
        env,
        log_message,
        "CoSimulation",
    )
}

/// `fmi3InstantiateScheduledExecution`: not provided (null and a log line).
#[unsafe(no_mangle)]
pub extern "C" fn fmi3InstantiateScheduledExecution(
    name: *const c_char,
    token: *const c_char,
    resource_path: *const c_char,
    _visible: bool,
    logging_on: bool,
    env: *mut c_void,
    log_message: LogMessage,
    _clock_update: *const c_void,
    _lock: *const c_void,
    _unlock: *const c_void,
) -> *mut c_void {
    instantiate(
        name,
        token,
        resource_path,
        logging_on,
        env,
        log_message,
        "ScheduledExecution",
    )
}

/// `fmi3FreeInstance`.
///
/// # Safety
/// `c` is null or an instance from `fmi3Instantiate…`, not freed yet.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3FreeInstance(c: *mut c_void) {
    if c.is_null() {
        return;
    }
    let _ = crate::glue::quiet_catch(AssertUnwindSafe(|| {
        // SAFETY: see above.
        drop(unsafe { Box::from_raw(c as *mut Component) });
    }));
}

/// `fmi3EnterInitializationMode`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3EnterInitializationMode(
    c: *mut c_void,
    _tolerance_defined: bool,
    _tolerance: f64,
    start_time: f64,
    stop_time_defined: bool,
    stop_time: f64,
) -> Status {
    with(c, "fmi3EnterInitializationMode", |comp| {
        if !start_time.is_finite() {
            return Err(FmuError::Setting(format!(
                "startTime = {start_time}: not a finite number"
            )));
        }
        comp.instance
            .expect("fmi3EnterInitializationMode", &[State::Instantiated])?;
        comp.instance.set_start_time(start_time);
        comp.instance
            .set_stop_time(stop_time_defined.then_some(stop_time))?;
        comp.instance.enter_initialization()
    })
}

/// `fmi3ExitInitializationMode`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3ExitInitializationMode(c: *mut c_void) -> Status {
    with(c, "fmi3ExitInitializationMode", |comp| {
        comp.instance.exit_initialization()
    })
}

/// `fmi3Terminate`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3Terminate(c: *mut c_void) -> Status {
    with(c, "fmi3Terminate", |comp| comp.instance.terminate())
}

/// `fmi3Reset`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3Reset(c: *mut c_void) -> Status {
    with(c, "fmi3Reset", |comp| {
        comp.instance.reset();
        Ok(())
    })
}

/// `fmi3GetFloat64`: scalars one value each, arrays their whole length, in order.
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3GetFloat64(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *mut f64,
    n_values: usize,
) -> Status {
    with(c, "fmi3GetFloat64", |comp| {
        // SAFETY: the host's arrays.
        let (refs, out) = unsafe { (refs(vr, nvr)?, values_mut(value, n_values)?) };
        let inst = &mut comp.instance;
        let mut at = 0;
        for &r in refs {
            let len = match variable(r).map(|v| v.kind) {
                Some(Kind::RealArray) => inst.array_len(r)?,
                _ => 1,
            };
            let slot = out.get_mut(at..at + len).ok_or_else(|| {
                FmuError::Setting(format!(
                    "nValues = {n_values} is too small for the references given"
                ))
            })?;
            match (r, variable(r).map(|v| v.kind)) {
                (_, Some(Kind::RealArray)) => inst.get_array(r, slot)?,
                _ => slot[0] = inst.get_real(r)?,
            }
            at += len;
        }
        if at != n_values {
            let arrays = refs
                .iter()
                .any(|&r| matches!(variable(r).map(|v| v.kind), Some(Kind::RealArray)));
            let sizes = if arrays {
                format!(
                    " (positions holds 2 × n_people values, radii n_people; n_people = {} for \
                     this scene)",
                    inst.get_uint64(refs_of::N_PEOPLE)?
                )
            } else {
                String::new()
            };
            return Err(FmuError::Setting(format!(
                "nValues = {n_values}, the references hold {at}{sizes}"
            )));
        }
        Ok(())
    })
}

/// `fmi3SetFloat64` (scalars: no Float64 array is settable).
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetFloat64(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *const f64,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SetFloat64", |comp| unsafe {
        set_scalars(comp, vr, nvr, value, n_values, Instance::set_real)
    })
}

/// `fmi3GetInt32`.
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3GetInt32(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *mut i32,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3GetInt32", |comp| unsafe {
        get_scalars(comp, vr, nvr, value, n_values, Instance::get_integer)
    })
}

/// `fmi3SetInt32`.
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetInt32(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *const i32,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SetInt32", |comp| unsafe {
        set_scalars(comp, vr, nvr, value, n_values, Instance::set_integer)
    })
}

/// `fmi3GetBoolean`.
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3GetBoolean(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *mut bool,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3GetBoolean", |comp| unsafe {
        get_scalars(comp, vr, nvr, value, n_values, Instance::get_boolean)
    })
}

/// `fmi3SetBoolean`: the bytes are read as `u8`, so a host's value other than 0/1 is no UB.
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetBoolean(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *const bool,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SetBoolean", |comp| unsafe {
        set_scalars(comp, vr, nvr, value as *const u8, n_values, |inst, r, v| {
            inst.set_boolean(r, v != 0)
        })
    })
}

/// `fmi3GetString`: the strings stay valid until the next call on this instance.
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3GetString(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *mut *const c_char,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3GetString", |comp| unsafe {
        get_strings(comp, vr, nvr, value, n_values)
    })
}

/// `fmi3SetString`.
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetString(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *const *const c_char,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SetString", |comp| unsafe {
        set_strings(comp, vr, nvr, value, n_values)
    })
}

/// `fmi3DoStep`: steps the model to `t + h` with its internal steps; never asks for events,
/// never terminates, never returns early.
///
/// # Safety
/// The four out-pointers are null or point to one value each.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3DoStep(
    c: *mut c_void,
    t: f64,
    h: f64,
    _no_set_prior: bool,
    event_handling_needed: *mut bool,
    terminate_simulation: *mut bool,
    early_return: *mut bool,
    last_successful_time: *mut f64,
) -> Status {
    with(c, "fmi3DoStep", |comp| {
        let outcome = comp.instance.do_step(t, h);
        // SAFETY: null or one value each.
        unsafe {
            for flag in [event_handling_needed, terminate_simulation, early_return] {
                if !flag.is_null() {
                    *flag = false;
                }
            }
            if !last_successful_time.is_null() {
                *last_successful_time = comp.instance.time().unwrap_or(t);
            }
        }
        outcome
    })
}

/// `fmi3GetUInt64` (`n_people`, the scene's count).
///
/// # Safety
/// `vr` holds `nvr` references and `value` room for `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3GetUInt64(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *mut u64,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3GetUInt64", |comp| unsafe {
        get_scalars(comp, vr, nvr, value, n_values, Instance::get_uint64)
    })
}

/// `fmi3SetUInt64` (`n_people`: must be the scene's count, checked when the model is built).
///
/// # Safety
/// `vr` holds `nvr` references and `value` `n_values` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetUInt64(
    c: *mut c_void,
    vr: *const u32,
    nvr: usize,
    value: *const u64,
    n_values: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SetUInt64", |comp| unsafe {
        set_scalars(comp, vr, nvr, value, n_values, Instance::set_uint64)
    })
}

/// `fmi3EnterConfigurationMode`: from Instantiated, to set the structural parameter.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3EnterConfigurationMode(c: *mut c_void) -> Status {
    with(c, "fmi3EnterConfigurationMode", |comp| {
        comp.instance.enter_configuration()
    })
}

/// `fmi3ExitConfigurationMode`: back to Instantiated.
#[unsafe(no_mangle)]
pub extern "C" fn fmi3ExitConfigurationMode(c: *mut c_void) -> Status {
    with(c, "fmi3ExitConfigurationMode", |comp| {
        comp.instance.exit_configuration()
    })
}

// ---- FMU states (canGetAndSetFMUState, canSerializeFMUState) ------------------------------

/// `fmi3GetFMUState`: a new state in `*state` when it is null, else overwrites that state.
///
/// # Safety
/// `state` points to the host's `fmi3FMUState` (null or a state of this FMU).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3GetFMUState(c: *mut c_void, state: *mut *mut c_void) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3GetFMUState", |comp| unsafe {
        get_state(comp, state)
    })
}

/// `fmi3SetFMUState`: refused (error, log line, nothing changes) for a state of another scene.
///
/// # Safety
/// `state` is a state of this FMU, not freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SetFMUState(c: *mut c_void, state: *mut c_void) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SetFMUState", |comp| unsafe {
        set_state(comp, state)
    })
}

/// `fmi3FreeFMUState`: frees `*state` and sets it to null.
///
/// # Safety
/// `state` points to the host's `fmi3FMUState` (null or a state of this FMU).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3FreeFMUState(c: *mut c_void, state: *mut *mut c_void) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3FreeFMUState", |_| unsafe { free_state(state) })
}

/// `fmi3SerializedFMUStateSize`.
///
/// # Safety
/// `state` is a state of this FMU; `size` points to one `size_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SerializedFMUStateSize(
    c: *mut c_void,
    state: *mut c_void,
    size: *mut usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SerializedFMUStateSize", |_| unsafe {
        state_size(state, size)
    })
}

/// `fmi3SerializeFMUState`: `size` is what `fmi3SerializedFMUStateSize` said.
///
/// # Safety
/// `state` is a state of this FMU; `bytes` has room for `size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3SerializeFMUState(
    c: *mut c_void,
    state: *mut c_void,
    bytes: *mut u8,
    size: usize,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3SerializeFMUState", |_| unsafe {
        serialize_state(state, bytes, size)
    })
}

/// `fmi3DeserializeFMUState`: checks that the bytes are a state of this FMU and format; the
/// scene is checked by `fmi3SetFMUState`.
///
/// # Safety
/// `bytes` holds `size` bytes; `state` points to the host's `fmi3FMUState`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi3DeserializeFMUState(
    c: *mut c_void,
    bytes: *const u8,
    size: usize,
    state: *mut *mut c_void,
) -> Status {
    // SAFETY: passed on.
    with(c, "fmi3DeserializeFMUState", |_| unsafe {
        deserialize_state(bytes, size, state)
    })
}

// ---- What this FMU does not provide ----------------------------------------------------

macro_rules! unsupported {
    ($($name:ident ($($arg:ident: $ty:ty),*);)*) => {$(
        #[doc = concat!("`", stringify!($name), "`: not supported (an error and a log line).")]
        #[unsafe(no_mangle)]
        pub extern "C" fn $name(c: *mut c_void, $($arg: $ty),*) -> Status {
            $(let _ = $arg;)*
            with(c, stringify!($name), |_| Err(FmuError::Unsupported(stringify!($name))))
        }
    )*};
}

unsupported! {
    fmi3EnterEventMode();
    fmi3GetFloat32(vr: *const u32, nvr: usize, value: *mut f32, n: usize);
    fmi3GetInt8(vr: *const u32, nvr: usize, value: *mut i8, n: usize);
    fmi3GetUInt8(vr: *const u32, nvr: usize, value: *mut u8, n: usize);
    fmi3GetInt16(vr: *const u32, nvr: usize, value: *mut i16, n: usize);
    fmi3GetUInt16(vr: *const u32, nvr: usize, value: *mut u16, n: usize);
    fmi3GetUInt32(vr: *const u32, nvr: usize, value: *mut u32, n: usize);
    fmi3GetInt64(vr: *const u32, nvr: usize, value: *mut i64, n: usize);
    fmi3GetBinary(vr: *const u32, nvr: usize, sizes: *mut usize, value: *mut *const u8, n: usize);
    fmi3GetClock(vr: *const u32, nvr: usize, value: *mut bool);
    fmi3SetFloat32(vr: *const u32, nvr: usize, value: *const f32, n: usize);
    fmi3SetInt8(vr: *const u32, nvr: usize, value: *const i8, n: usize);
    fmi3SetUInt8(vr: *const u32, nvr: usize, value: *const u8, n: usize);
    fmi3SetInt16(vr: *const u32, nvr: usize, value: *const i16, n: usize);
    fmi3SetUInt16(vr: *const u32, nvr: usize, value: *const u16, n: usize);
    fmi3SetUInt32(vr: *const u32, nvr: usize, value: *const u32, n: usize);
    fmi3SetInt64(vr: *const u32, nvr: usize, value: *const i64, n: usize);
    fmi3SetBinary(vr: *const u32, nvr: usize, sizes: *const usize, value: *const *const u8, n: usize);
    fmi3SetClock(vr: *const u32, nvr: usize, value: *const bool);
    fmi3GetNumberOfVariableDependencies(vr: u32, n: *mut usize);
    fmi3GetVariableDependencies(dependent: u32, element_dependent: *mut usize, independents: *mut u32, element_independents: *mut usize, kinds: *mut i32, n: usize);
    fmi3GetDirectionalDerivative(unknowns: *const u32, n_unknowns: usize, knowns: *const u32, n_knowns: usize, seed: *const f64, n_seed: usize, sensitivity: *mut f64, n_sensitivity: usize);
    fmi3GetAdjointDerivative(unknowns: *const u32, n_unknowns: usize, knowns: *const u32, n_knowns: usize, seed: *const f64, n_seed: usize, sensitivity: *mut f64, n_sensitivity: usize);
    fmi3GetIntervalDecimal(vr: *const u32, nvr: usize, intervals: *mut f64, qualifiers: *mut i32);
    fmi3GetIntervalFraction(vr: *const u32, nvr: usize, counters: *mut u64, resolutions: *mut u64, qualifiers: *mut i32);
    fmi3GetShiftDecimal(vr: *const u32, nvr: usize, shifts: *mut f64);
    fmi3GetShiftFraction(vr: *const u32, nvr: usize, counters: *mut u64, resolutions: *mut u64);
    fmi3SetIntervalDecimal(vr: *const u32, nvr: usize, intervals: *const f64);
    fmi3SetIntervalFraction(vr: *const u32, nvr: usize, counters: *const u64, resolutions: *const u64);
    fmi3SetShiftDecimal(vr: *const u32, nvr: usize, shifts: *const f64);
    fmi3SetShiftFraction(vr: *const u32, nvr: usize, counters: *const u64, resolutions: *const u64);
    fmi3EvaluateDiscreteStates();
    fmi3UpdateDiscreteStates(needs_update: *mut bool, terminate: *mut bool, nominals_changed: *mut bool, values_changed: *mut bool, next_defined: *mut bool, next_time: *mut f64);
    fmi3EnterContinuousTimeMode();
    fmi3CompletedIntegratorStep(no_set_prior: bool, enter_event_mode: *mut bool, terminate: *mut bool);
    fmi3SetTime(time: f64);
    fmi3SetContinuousStates(x: *const f64, n: usize);
    fmi3GetContinuousStateDerivatives(dx: *mut f64, n: usize);
    fmi3GetEventIndicators(z: *mut f64, n: usize);
    fmi3GetContinuousStates(x: *mut f64, n: usize);
    fmi3GetNominalsOfContinuousStates(nominals: *mut f64, n: usize);
    fmi3GetNumberOfEventIndicators(n: *mut usize);
    fmi3GetNumberOfContinuousStates(n: *mut usize);
    fmi3EnterStepMode();
    fmi3GetOutputDerivatives(vr: *const u32, nvr: usize, orders: *const i32, value: *mut f64, n: usize);
    fmi3ActivateModelPartition(clock: u32, time: f64);
}
