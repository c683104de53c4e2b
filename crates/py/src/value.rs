//! Python values to TOML values and back (scenes as dicts), and crowd errors to Python
//! exceptions.

use moreau_crowd::CrowdError;
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use crate::SceneError;

/// A crowd error as a Python exception: scene errors as `SceneError` (with `field`, `value`
/// and `reason` when a value is at fault; only `reason`, the parser's message, when the text
/// is no scene), an unreadable file as `OSError`, the rest (a step
/// that failed, an observer that stopped the run) as `RuntimeError`.
pub fn to_py(py: Python<'_>, e: CrowdError) -> PyErr {
    let message = e.to_string();
    match e {
        CrowdError::Invalid {
            field,
            value,
            reason,
        } => {
            let err = SceneError::new_err(message);
            let v = err.value(py);
            let _ = v.setattr("field", field);
            let _ = v.setattr("value", value);
            let _ = v.setattr("reason", reason);
            err
        }
        CrowdError::Parse {
            message: reason, ..
        } => {
            // No value at fault (`field` and `value` stay the class's `None`); the parser's
            // message, which names the key and line, is the reason.
            let err = SceneError::new_err(message);
            let _ = err.value(py).setattr("reason", reason);
            err
        }
        CrowdError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(message)
        }
        CrowdError::Io { .. } => PyOSError::new_err(message),
        CrowdError::Observer(_)
        | CrowdError::Integrate(_)
        | CrowdError::NotCertified { .. }
        | CrowdError::Infeasible(_) => PyRuntimeError::new_err(message),
    }
}

/// `obj` (dicts, lists, tuples, str, bool, int, float, and anything with `tolist()` such as
/// numpy arrays and scalars) as a TOML value; `path` names it in errors.
pub fn to_toml(obj: &Bound<'_, PyAny>, path: &str) -> PyResult<toml::Value> {
    if obj.hasattr("tolist")? && !obj.is_instance_of::<PyString>() {
        return to_toml(&obj.call_method0("tolist")?, path);
    }
    if obj.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(obj.extract()?));
    }
    if obj.is_instance_of::<PyInt>() {
        return Ok(toml::Value::Integer(obj.extract().map_err(|_| {
            SceneError::new_err(format!(
                "scene error at {path} = {obj}: not a 64-bit integer"
            ))
        })?));
    }
    if obj.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(obj.extract()?));
    }
    if let Ok(s) = obj.cast::<PyString>() {
        return Ok(toml::Value::String(s.to_str()?.to_owned()));
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in d.iter() {
            let key: String = k.extract().map_err(|_| {
                SceneError::new_err(format!("scene error at {path} = {k}: keys must be strings"))
            })?;
            let sub = if path.is_empty() {
                key.clone()
            } else {
                format!("{path}.{key}")
            };
            table.insert(key, to_toml(&v, &sub)?);
        }
        return Ok(toml::Value::Table(table));
    }
    if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
        let items = obj
            .try_iter()?
            .enumerate()
            .map(|(i, v)| to_toml(&v?, &format!("{path}[{i}]")))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(items));
    }
    let what = obj.get_type().name()?;
    Err(SceneError::new_err(format!(
        "scene error at {path} = {obj}: a {what} has no TOML form (use dict, list, str, bool, int or float)"
    )))
}

/// A TOML value as plain Python objects (tables as dicts, arrays as lists).
pub fn from_toml<'py>(py: Python<'py>, value: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match value {
        toml::Value::String(s) => s.into_pyobject(py)?.into_any(),
        toml::Value::Integer(i) => i.into_pyobject(py)?.into_any(),
        toml::Value::Float(f) => f.into_pyobject(py)?.into_any(),
        toml::Value::Boolean(b) => b.into_pyobject(py)?.to_owned().into_any(),
        toml::Value::Datetime(d) => d.to_string().into_pyobject(py)?.into_any(),
        toml::Value::Array(items) => {
            let list = PyList::empty(py);
            for v in items {
                list.append(from_toml(py, v)?)?;
            }
            list.into_any()
        }
        toml::Value::Table(table) => {
            let dict = PyDict::new(py);
            for (k, v) in table {
                dict.set_item(k, from_toml(py, v)?)?;
            }
            dict.into_any()
        }
    })
}
