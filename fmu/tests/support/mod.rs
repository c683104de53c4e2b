//! The FMI 2 and FMI 3 C API as a host calls it, for the FMU's tests: one instance either
//! way ([`Api`]), its callbacks, and the FMI 3 logger that keeps the log lines.
// The FMI entry points are a C ABI: raw pointers, as a host passes them.
#![allow(unsafe_code)]
// (Each test file uses what it needs.)
#![allow(dead_code)]

use std::cell::RefCell;
use std::ffi::{CStr, CString, c_char, c_int, c_void};

use moreau_fmu::model::vr;
use moreau_fmu::{fmi2, fmi3};

pub const OK: c_int = 0;
pub const WARNING: c_int = 1;
pub const DISCARD: c_int = 2;
pub const ERROR: c_int = 3;

/// The FMI 3 logger: the message into the `RefCell<Vec<String>>` behind `env`.
pub unsafe extern "C" fn log3(
    env: *mut c_void,
    _: c_int,
    _: *const c_char,
    message: *const c_char,
) {
    // SAFETY: `env` is the instance's log, alive as long as the instance; `message` a
    // NUL-terminated string of the FMU's.
    unsafe {
        let lines = &*(env as *const RefCell<Vec<String>>);
        lines
            .borrow_mut()
            .push(CStr::from_ptr(message).to_string_lossy().into_owned());
    }
}

/// `fmi2CallbackFunctions` as a host lays it out. No logger: an FMI 2 logger is variadic, which
/// stable Rust cannot define (the tests check log lines through FMI 3).
#[repr(C)]
pub struct Callbacks2 {
    logger: *const c_void,
    allocate_memory: *const c_void,
    free_memory: *const c_void,
    step_finished: *const c_void,
    component_environment: *mut c_void,
}

/// An instance's calls in FMI 2 or FMI 3 (`c` the instance), each returning the FMU's status.
///
/// # Safety (every method)
/// `c` is a live instance of this FMI version; each state a live state of it.
#[derive(Clone, Copy)]
pub struct Api {
    pub v3: bool,
    pub c: *mut c_void,
}

impl Api {
    pub unsafe fn set_scene(self, text: &CStr) -> c_int {
        let p = text.as_ptr();
        unsafe {
            if self.v3 {
                fmi3::fmi3SetString(self.c, &vr::SCENE, 1, &p, 1)
            } else {
                fmi2::fmi2SetString(self.c, &vr::SCENE, 1, &p)
            }
        }
    }
    pub fn enter_initialization(self, tol: Option<f64>, start: f64, stop: Option<f64>) -> c_int {
        let (tol_defined, tol) = (tol.is_some(), tol.unwrap_or(0.0));
        let (stop_defined, stop) = (stop.is_some(), stop.unwrap_or(0.0));
        if self.v3 {
            fmi3::fmi3EnterInitializationMode(self.c, tol_defined, tol, start, stop_defined, stop)
        } else {
            let status = fmi2::fmi2SetupExperiment(
                self.c,
                c_int::from(tol_defined),
                tol,
                start,
                c_int::from(stop_defined),
                stop,
            );
            if status != OK {
                return status;
            }
            fmi2::fmi2EnterInitializationMode(self.c)
        }
    }
    pub fn exit_initialization(self) -> c_int {
        if self.v3 {
            fmi3::fmi3ExitInitializationMode(self.c)
        } else {
            fmi2::fmi2ExitInitializationMode(self.c)
        }
    }
    pub unsafe fn do_step(self, t: f64, h: f64) -> c_int {
        if self.v3 {
            let (mut event, mut terminate, mut early, mut last) = (false, false, false, 0.0);
            unsafe {
                fmi3::fmi3DoStep(
                    self.c,
                    t,
                    h,
                    true,
                    &mut event,
                    &mut terminate,
                    &mut early,
                    &mut last,
                )
            }
        } else {
            fmi2::fmi2DoStep(self.c, t, h, 1)
        }
    }
    /// `values` to reference `r` (FMI 3: one reference and all the values; FMI 2: the
    /// reference once for each value).
    pub unsafe fn set_real(self, r: u32, values: &[f64]) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3SetFloat64(self.c, &r, 1, values.as_ptr(), values.len())
            } else {
                let refs = vec![r; values.len()];
                fmi2::fmi2SetReal(self.c, refs.as_ptr(), refs.len(), values.as_ptr())
            }
        }
    }
    /// FMI 3: `out` of any length; FMI 2: one value a reference.
    pub unsafe fn get_real(self, refs: &[u32], out: &mut Vec<f64>) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3GetFloat64(
                    self.c,
                    refs.as_ptr(),
                    refs.len(),
                    out.as_mut_ptr(),
                    out.len(),
                )
            } else {
                out.resize(refs.len(), 0.0);
                fmi2::fmi2GetReal(self.c, refs.as_ptr(), refs.len(), out.as_mut_ptr())
            }
        }
    }
    pub unsafe fn get_integer(self, refs: &[u32], out: &mut Vec<i32>) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3GetInt32(
                    self.c,
                    refs.as_ptr(),
                    refs.len(),
                    out.as_mut_ptr(),
                    out.len(),
                )
            } else {
                out.resize(refs.len(), 0);
                fmi2::fmi2GetInteger(self.c, refs.as_ptr(), refs.len(), out.as_mut_ptr())
            }
        }
    }
    /// `values` to reference `r` (FMI 3: one reference and all the values; FMI 2: the
    /// reference once for each value, any integer as the Boolean).
    pub unsafe fn set_boolean(self, r: u32, values: &[c_int]) -> c_int {
        unsafe {
            if self.v3 {
                let bytes: Vec<bool> = values.iter().map(|&v| v != 0).collect();
                fmi3::fmi3SetBoolean(self.c, &r, 1, bytes.as_ptr(), bytes.len())
            } else {
                let refs = vec![r; values.len()];
                fmi2::fmi2SetBoolean(self.c, refs.as_ptr(), refs.len(), values.as_ptr())
            }
        }
    }
    /// FMI 3: `out` of any length; FMI 2: one value a reference.
    pub unsafe fn get_boolean(self, refs: &[u32], out: &mut Vec<c_int>) -> c_int {
        unsafe {
            if self.v3 {
                let mut bytes = vec![false; out.len()];
                let status = fmi3::fmi3GetBoolean(
                    self.c,
                    refs.as_ptr(),
                    refs.len(),
                    bytes.as_mut_ptr(),
                    bytes.len(),
                );
                out.iter_mut().zip(&bytes).for_each(|(o, &b)| *o = b.into());
                status
            } else {
                out.resize(refs.len(), 0);
                fmi2::fmi2GetBoolean(self.c, refs.as_ptr(), refs.len(), out.as_mut_ptr())
            }
        }
    }
    pub unsafe fn get_state(self, state: &mut *mut c_void) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3GetFMUState(self.c, state)
            } else {
                fmi2::fmi2GetFMUstate(self.c, state)
            }
        }
    }
    pub unsafe fn set_state(self, state: *mut c_void) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3SetFMUState(self.c, state)
            } else {
                fmi2::fmi2SetFMUstate(self.c, state)
            }
        }
    }
    pub unsafe fn free_state(self, state: &mut *mut c_void) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3FreeFMUState(self.c, state)
            } else {
                fmi2::fmi2FreeFMUstate(self.c, state)
            }
        }
    }
    /// The state's bytes, or the status that refused them.
    pub unsafe fn serialize(self, state: *mut c_void) -> Result<Vec<u8>, c_int> {
        let mut size = 0;
        unsafe {
            let status = if self.v3 {
                fmi3::fmi3SerializedFMUStateSize(self.c, state, &mut size)
            } else {
                fmi2::fmi2SerializedFMUstateSize(self.c, state, &mut size)
            };
            if status != OK {
                return Err(status);
            }
            let mut bytes = vec![0u8; size];
            let status = if self.v3 {
                fmi3::fmi3SerializeFMUState(self.c, state, bytes.as_mut_ptr(), size)
            } else {
                fmi2::fmi2SerializeFMUstate(self.c, state, bytes.as_mut_ptr() as *mut c_char, size)
            };
            if status == OK { Ok(bytes) } else { Err(status) }
        }
    }
    pub unsafe fn deserialize(self, bytes: &[u8], state: &mut *mut c_void) -> c_int {
        unsafe {
            if self.v3 {
                fmi3::fmi3DeserializeFMUState(self.c, bytes.as_ptr(), bytes.len(), state)
            } else {
                fmi2::fmi2DeSerializeFMUstate(
                    self.c,
                    bytes.as_ptr() as *const c_char,
                    bytes.len(),
                    state,
                )
            }
        }
    }
    pub fn reset(self) -> c_int {
        if self.v3 {
            fmi3::fmi3Reset(self.c)
        } else {
            fmi2::fmi2Reset(self.c)
        }
    }
    pub fn terminate(self) -> c_int {
        if self.v3 {
            fmi3::fmi3Terminate(self.c)
        } else {
            fmi2::fmi2Terminate(self.c)
        }
    }
    /// FMI 3: enter configuration mode; FMI 2: ask for the last successful time.
    pub unsafe fn other(self) -> c_int {
        if self.v3 {
            fmi3::fmi3EnterConfigurationMode(self.c)
        } else {
            let mut last = 0.0;
            // (fmi2LastSuccessfulTime = 2)
            unsafe { fmi2::fmi2GetRealStatus(self.c, 2, &mut last) }
        }
    }
    pub fn free(self) {
        // SAFETY: see the type; freed once, by the caller's last use.
        unsafe {
            if self.v3 {
                fmi3::fmi3FreeInstance(self.c)
            } else {
                fmi2::fmi2FreeInstance(self.c)
            }
        }
    }
}

/// An instance of the FMU in FMI 3 (logging into `log`) or FMI 2 (no logger), state
/// Instantiated, given no resource location.
pub fn instantiate(v3: bool, log: &RefCell<Vec<String>>, logging_on: bool) -> Api {
    instantiate_in(v3, log, logging_on, None)
}

/// [`instantiate`] with the FMU's resources in the directory `resources` (passed as FMI 3's
/// path or FMI 2's `file://` URI).
pub fn instantiate_in(
    v3: bool,
    log: &RefCell<Vec<String>>,
    logging_on: bool,
    resources: Option<&std::path::Path>,
) -> Api {
    let location = resources.map(|dir| {
        CString::new(if v3 {
            format!("{}/", dir.display())
        } else {
            format!("file://{}", dir.display())
        })
        .unwrap()
    });
    let location = location.as_ref().map_or(std::ptr::null(), |l| l.as_ptr());
    let c = if v3 {
        let token = CString::new(*fmi3::TOKEN).unwrap();
        fmi3::fmi3InstantiateCoSimulation(
            c"test".as_ptr(),
            token.as_ptr(),
            location,
            false,
            logging_on,
            false,
            false,
            std::ptr::null(),
            0,
            log as *const RefCell<Vec<String>> as *mut c_void,
            Some(log3),
            std::ptr::null(),
        )
    } else {
        let guid = CString::new(*fmi2::GUID).unwrap();
        let callbacks = Callbacks2 {
            logger: std::ptr::null(),
            allocate_memory: std::ptr::null(),
            free_memory: std::ptr::null(),
            step_finished: std::ptr::null(),
            component_environment: std::ptr::null_mut(),
        };
        // SAFETY: the strings and the callbacks (laid out as fmi2CallbackFunctions) live
        // through the call.
        unsafe {
            fmi2::fmi2Instantiate(
                c"test".as_ptr(),
                1,
                guid.as_ptr(),
                location,
                &callbacks as *const Callbacks2 as *const fmi2::CallbackFunctions,
                0,
                c_int::from(logging_on),
            )
        }
    };
    assert!(!c.is_null(), "not instantiated");
    Api { v3, c }
}
