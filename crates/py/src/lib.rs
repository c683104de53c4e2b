//! The Python extension module `moreau._moreau`: `Scene`, `Simulation`, `SceneError` and the
//! run-file writer, a thin adapter over `moreau_crowd::Simulation` (the Python package
//! `moreau` re-exports them and adds `run` and `to_pedpy`).

mod scene;
mod sim;
mod value;

use pyo3::prelude::*;

pyo3::create_exception!(
    moreau,
    SceneError,
    pyo3::exceptions::PyValueError,
    "A scene that cannot be read or is invalid; the message names the field and the value \
     (as `moreau run` says it). Attributes `field`, `value`, `reason`: the field and value at \
     fault and why, `None` where there is none (a text that is no scene has only a `reason`)."
);

/// The extension module.
#[pymodule]
fn _moreau(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let scene_error = m.py().get_type::<SceneError>();
    // Every instance has the three attributes; those raised where no field is at fault
    // (a text that does not parse, a state of another scene) read them as `None`.
    for attribute in ["field", "value", "reason"] {
        scene_error.setattr(attribute, m.py().None())?;
    }
    m.add("SceneError", scene_error)?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<sim::PySimulation>()?;
    m.add_function(wrap_pyfunction!(sim::run_to_file, m)?)?;
    m.add("__version__", moreau_record::VERSION)?;
    Ok(())
}
