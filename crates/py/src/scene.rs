//! `moreau.Scene`: a validated scene (TOML file, TOML text, dict), its walkable area from a
//! shapely polygon or WKT, and its TOML and dict forms.

use moreau_crowd::Scene;
use pyo3::prelude::*;
use pyo3::types::{PyString, PyTuple};

use crate::SceneError;
use crate::value::{from_toml, to_py, to_toml};

/// A crowd scene: walkable area, exits, groups of people, time and solver settings, as the
/// TOML scene files of `data/scenes/` say them. Immutable; every constructor validates, and
/// an invalid scene raises `SceneError` naming the field and the value.
#[pyclass(name = "Scene", module = "moreau", frozen)]
#[derive(Debug, Clone)]
pub struct PyScene {
    pub scene: Scene,
}

/// The rings `(outer, holes)` of a shapely `Polygon` or of its WKT, without the closing
/// point.
type Rings = (Vec<[f64; 2]>, Vec<Vec<[f64; 2]>>);

/// A shapely geometry from a shapely geometry or a WKT string, for the argument `field`:
/// WKT that does not parse is `wkt_error`'s error, anything else a TypeError naming `field`
/// and what it takes (`expected`).
pub fn geometry<'py>(
    obj: &Bound<'py, PyAny>,
    field: &str,
    expected: &str,
    wkt_error: impl FnOnce(PyErr) -> PyErr,
) -> PyResult<Bound<'py, PyAny>> {
    let shapely = obj.py().import("shapely")?;
    if obj.is_instance_of::<PyString>() {
        shapely.call_method1("from_wkt", (obj,)).map_err(wkt_error)
    } else if obj.is_instance(&shapely.getattr("Geometry")?)? {
        Ok(obj.clone())
    } else {
        // (Anything else met an AttributeError on `geom_type`, or a numpy broadcast error.)
        Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "{field}: {expected} or its WKT, not {}",
            obj.get_type().name()?
        )))
    }
}

fn ring(coords: &Bound<'_, PyAny>) -> PyResult<Vec<[f64; 2]>> {
    let mut points: Vec<[f64; 2]> = Vec::new();
    for p in coords.getattr("coords")?.try_iter()? {
        let p = p?;
        points.push([p.get_item(0)?.extract()?, p.get_item(1)?.extract()?]);
    }
    if points.len() > 1 && points.first() == points.last() {
        points.pop();
    }
    Ok(points)
}

fn rings(obj: &Bound<'_, PyAny>) -> PyResult<Rings> {
    let geom = geometry(obj, "area", "a shapely Polygon", |e| {
        SceneError::new_err(format!("scene error at area = {obj}: {e}"))
    })?;
    let kind: String = geom.getattr("geom_type")?.extract()?;
    if kind != "Polygon" {
        let wkt: String = geom.getattr("wkt")?.extract()?;
        return Err(SceneError::new_err(format!(
            "scene error at area = {wkt}: the walkable area must be one Polygon, not a {kind}"
        )));
    }
    let outer = ring(&geom.getattr("exterior")?)?;
    let holes = geom
        .getattr("interiors")?
        .try_iter()?
        .map(|r| ring(&r?))
        .collect::<PyResult<_>>()?;
    Ok((outer, holes))
}

#[pymethods]
impl PyScene {
    /// Reads and validates a scene file (TOML).
    #[staticmethod]
    fn from_file(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Self> {
        Scene::from_file(&path)
            .map(|scene| PyScene { scene })
            .map_err(|e| to_py(py, e))
    }

    /// Parses and validates a scene from TOML text; `origin` names it in error messages.
    #[staticmethod]
    #[pyo3(signature = (text, origin = "<string>"))]
    fn from_toml(py: Python<'_>, text: &str, origin: &str) -> PyResult<Self> {
        Scene::from_toml(text, origin)
            .map(|scene| PyScene { scene })
            .map_err(|e| to_py(py, e))
    }

    /// A scene from a dict of the TOML file's structure (nested dicts, lists, numbers,
    /// strings; numpy arrays are taken as lists), validated like a file.
    #[staticmethod]
    fn from_dict(py: Python<'_>, d: &Bound<'_, PyAny>) -> PyResult<Self> {
        let value = to_toml(d, "")?;
        if !value.is_table() {
            return Err(SceneError::new_err(format!(
                "scene error at <dict> = {d}: a scene is a dict"
            )));
        }
        let text = toml::to_string(&value)
            .map_err(|e| SceneError::new_err(format!("scene <dict>: {e}")))?;
        // The dict's keys, not lines of TOML nobody wrote: the parse error's span names its
        // key (`groups[0].radius`), as a validation error names its field.
        // (`field`, `value` and `reason` as a validation error has them; a missing key's
        // field is its table, and no value.)
        if let Err(e) = toml::from_str::<Scene>(&text) {
            let reason = e.message().trim().to_string();
            // The root table's span is empty at 0: a key missing there is the scene's, not
            // the first line's (`seed` left out was blamed on `name`).
            let span = e.span().filter(|span| !span.is_empty());
            let (field, value) = match span.and_then(|span| key_at(&text, span.start)) {
                Some((path, Some(value))) if !reason.starts_with("missing field") => {
                    (Some(path), Some(value))
                }
                Some((path, _)) if !path.is_empty() => (Some(path), None),
                _ => (None, None),
            };
            let message = match (&field, &value) {
                (Some(f), Some(v)) => format!("scene error at {f} = {v}: {reason}"),
                (Some(f), None) => format!("scene error at {f}: {reason}"),
                _ => format!("scene error in <dict>: {reason}"),
            };
            let err = SceneError::new_err(message);
            let v = err.value(py);
            v.setattr("field", field)?;
            v.setattr("value", value)?;
            v.setattr("reason", reason)?;
            return Err(err);
        }
        Self::from_toml(py, &text, "<dict>")
    }

    /// This scene with another walkable area: a shapely `Polygon` (holes are obstacles) or
    /// its WKT (`"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))"`). Validated: exits, spawn areas
    /// and targets must still fit it.
    fn with_area(&self, py: Python<'_>, area: &Bound<'_, PyAny>) -> PyResult<Self> {
        let (outer, holes) = rings(area)?;
        let mut scene = self.scene.clone();
        scene.area.outer = outer;
        scene.area.holes = holes;
        scene.validate().map_err(|e| to_py(py, e))?;
        Ok(PyScene { scene })
    }

    /// The scene as TOML (it reads back to an equal scene).
    fn to_toml(&self) -> String {
        self.scene.to_toml()
    }

    /// The scene as a dict of the TOML file's structure (`Scene.from_dict` reads it back).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let value = toml::Value::try_from(&self.scene)
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
        from_toml(py, &value)
    }

    /// The scene's name.
    #[getter]
    fn name(&self) -> &str {
        &self.scene.name
    }

    /// The walkable area as WKT (what PedPy's `WalkableArea` reads).
    #[getter]
    fn wkt(&self) -> String {
        self.scene.wkt()
    }

    /// The horizon (s).
    #[getter]
    fn horizon(&self) -> f64 {
        self.scene.time.horizon
    }

    /// The time between output frames (s).
    #[getter]
    fn output_interval(&self) -> f64 {
        self.scene.time.output_interval
    }

    /// The exits' names, in order (their indices are what `set_exit_open` also takes).
    #[getter]
    fn exits(&self) -> Vec<String> {
        self.scene.exits.iter().map(|e| e.name.clone()).collect()
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other
            .cast::<PyScene>()
            .is_ok_and(|o| o.get().scene.to_toml() == self.scene.to_toml())
    }

    fn __hash__(&self) -> u64 {
        moreau_crowd::SimState::hash_scene(&self.scene)
    }

    fn __repr__(&self) -> String {
        format!(
            "Scene(name={:?}, exits={}, groups={}, horizon={})",
            self.scene.name,
            self.scene.exits.len(),
            self.scene.groups.len(),
            self.scene.time.horizon
        )
    }

    /// Pickled as its TOML.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        let py = slf.py();
        let from_toml = slf.get_type().getattr("from_toml")?;
        (from_toml, (slf.get().scene.to_toml(),)).into_pyobject(py)
    }
}

/// In `text` as `toml::to_string` writes a table (headers `[a.b]` and `[[a]]`, one `key =
/// value` a line), the dotted path of what byte `at` lies in, with the indices of arrays of
/// tables (`groups[0].radius`), and the value written there: the key of its line with its
/// value, or the table of a header line (`None` for the value).
fn key_at(text: &str, at: usize) -> Option<(String, Option<String>)> {
    // Arrays of tables by their resolved path, and how many elements each had so far.
    let mut counts: Vec<(String, usize)> = Vec::new();
    // A header's path, each array of tables before its last part at its current element.
    let resolve = |name: &str, counts: &[(String, usize)]| {
        let parts: Vec<&str> = name
            .split('.')
            .map(|p| p.trim().trim_matches('"'))
            .collect();
        let mut path = String::new();
        for (k, part) in parts.iter().enumerate() {
            if k > 0 {
                path.push('.');
            }
            path.push_str(part);
            if k + 1 < parts.len()
                && let Some((_, n)) = counts.iter().find(|(p, _)| *p == path)
            {
                path = format!("{path}[{}]", n - 1);
            }
        }
        path
    };
    let (mut table, mut start) = (String::new(), 0);
    for line in text.split_inclusive('\n') {
        let end = start + line.len();
        let l = line.trim();
        let here = (start..end).contains(&at);
        if let Some(name) = l.strip_prefix("[[").and_then(|l| l.strip_suffix("]]")) {
            let base = resolve(name, &counts);
            let n = match counts.iter_mut().find(|(p, _)| *p == base) {
                Some((_, n)) => {
                    *n += 1;
                    *n
                }
                None => {
                    counts.push((base.clone(), 1));
                    1
                }
            };
            table = format!("{base}[{}]", n - 1);
        } else if let Some(name) = l.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            table = resolve(name, &counts);
        } else if here {
            let (key, value) = l.split_once('=')?;
            let key = key.trim().trim_matches('"');
            let path = match table.is_empty() {
                true => key.to_string(),
                false => format!("{table}.{key}"),
            };
            return Some((path, Some(value.trim().to_string())));
        }
        if here {
            return Some((table, None));
        }
        start = end;
    }
    None
}
