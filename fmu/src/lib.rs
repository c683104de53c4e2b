//! The crowd stepper of moreau as an FMU for co-simulation, in three layers as in the
//! Modelica Reference-FMUs: the FMI glue ([`fmi2`], [`fmi3`]: C entry points that check the
//! instance state, pointers and numbers, catch panics and translate), a small runtime
//! ([`runtime`]: instance, state machine, logging, stepping to the communication point), and
//! the model ([`model`]: the scene driven by the catching-up scheme). The glue translates; it
//! does not simulate. FMU states (get, set, serialize: what co-simulation masters roll back
//! with) are [`snapshot::Snapshot`]s of an instance, built on the crowd's `SimState`.
//!
//! The model descriptions are `fmu/fmi2/modelDescription.xml` and
//! `fmu/fmi3/modelDescription.xml`; the binary embeds them, so the GUID and the instantiation
//! token it checks are the ones the XML declares. `fmu/package.py` makes the `.fmu` files.
// The FMI layers are a C ABI: raw pointers from the host, exported symbols.
#![allow(unsafe_code)]

pub mod fmi2;
pub mod fmi3;
mod glue;
pub mod model;
pub mod runtime;
pub mod snapshot;

use runtime::State;

/// The errors of the FMU; each becomes an error status and a log line.
#[derive(Debug, thiserror::Error)]
pub enum FmuError {
    /// A function called in a state that does not allow it.
    #[error(
        "{function} is not allowed in state {state:?} (only in {})",
        states(function, .allowed)
    )]
    State {
        /// The FMI function.
        function: String,
        /// The instance's state.
        state: State,
        /// The states that allow it.
        allowed: &'static [State],
    },
    /// No variable has this value reference.
    #[error("unknown value reference {0}")]
    UnknownReference(u32),
    /// The variable exists with another type.
    #[error("value reference {vr} ({name}) is of another type")]
    WrongType {
        /// The value reference.
        vr: u32,
        /// The variable's name.
        name: String,
    },
    /// A value or setting out of its domain.
    #[error("{0}")]
    Setting(String),
    /// A null pointer where a value was needed.
    #[error("{0} is a null pointer")]
    Null(&'static str),
    /// A capability this FMU does not have.
    #[error("{0} is not supported by this FMU")]
    Unsupported(&'static str),
    /// The scene or a step failed.
    #[error(transparent)]
    Crowd(#[from] moreau_crowd::CrowdError),
}

/// `A, B or C`.
/// The states in `list` as words; FMI 2 has no Configuration mode, so an `fmi2` function's
/// list leaves it out (its refusals named a state FMI 2 does not have).
fn states(function: &str, list: &[State]) -> String {
    let names: Vec<String> = list
        .iter()
        .filter(|s| !(function.starts_with("fmi2") && **s == State::Configuration))
        .map(|s| format!("{s:?}"))
        .collect();
    match names.split_last() {
        None => "no state".into(),
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
    }
}

/// The value of `attribute="…"` in an XML text (the GUID or instantiation token of a model
/// description embedded in the binary).
pub(crate) fn xml_attribute(xml: &'static str, attribute: &str) -> &'static str {
    let key = format!("{attribute}=\"");
    let start = xml.find(&key).map_or(0, |i| i + key.len());
    let end = xml[start..].find('"').map_or(start, |i| start + i);
    &xml[start..end]
}

/// A file path from FMI 2's resource location, a URI: `file:///a/b`, `file:/a/b` (or a plain
/// path, from hosts that pass one), with `%XX` escapes decoded in a URI only.
pub(crate) fn resource_path(location: &str) -> std::path::PathBuf {
    let Some(rest) = location
        .strip_prefix("file://localhost")
        .or_else(|| location.strip_prefix("file://"))
        .or_else(|| location.strip_prefix("file:"))
    else {
        return std::path::PathBuf::from(location);
    };
    let hex = |b: u8| (b as char).to_digit(16).map(|d| d as u8);
    let bytes = rest.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        // Byte by byte: a `%` before a multibyte character sliced the text inside it and
        // panicked.
        if bytes[i] == b'%'
            && i + 2 < bytes.len()
            && let (Some(h), Some(l)) = (hex(bytes[i + 1]), hex(bytes[i + 2]))
        {
            out.push(h << 4 | l);
            i += 3;
            continue;
        }
        out.push(bytes[i]);
        i += 1;
    }
    std::path::PathBuf::from(String::from_utf8_lossy(&out).into_owned())
}

/// A file path from FMI 3's `resourcePath`: an absolute path as it is, `%` and all (it was
/// decoded as a URI: an FMU unpacked under `100%25/` read its scene from `100%/`). A
/// `file:` URI, which FMI 3 does not pass, is still read as one.
pub(crate) fn resource_dir(path: &str) -> std::path::PathBuf {
    if path.starts_with("file:") {
        resource_path(path)
    } else {
        std::path::PathBuf::from(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resource_locations_become_paths() {
        assert_eq!(
            resource_path("file:///tmp/a%20b/resources"),
            std::path::PathBuf::from("/tmp/a b/resources")
        );
        assert_eq!(
            resource_path("file:/tmp/x/"),
            std::path::PathBuf::from("/tmp/x/")
        );
        assert_eq!(
            resource_path("/plain/path"),
            std::path::PathBuf::from("/plain/path")
        );
    }

    #[test]
    fn an_fmi3_resource_path_was_decoded_as_a_uri() {
        // FMI 3's resourcePath is a path: `%41` and `%25` in a directory's name are its own.
        assert_eq!(
            resource_dir("/tmp/a%41b/100%25/resources/"),
            std::path::PathBuf::from("/tmp/a%41b/100%25/resources/")
        );
        assert_eq!(
            resource_dir("file:///tmp/a%20b/resources"),
            std::path::PathBuf::from("/tmp/a b/resources")
        );
        // A `%` before a multibyte character panicked (slicing inside it).
        assert_eq!(
            resource_path("file:///tmp/x%aé/r"),
            std::path::PathBuf::from("/tmp/x%aé/r")
        );
        assert_eq!(
            resource_path("file:///tmp/%C3%A9"),
            std::path::PathBuf::from("/tmp/é")
        );
    }

    #[test]
    fn the_guids_come_from_the_model_descriptions() {
        let guid = *fmi2::GUID;
        assert!(
            guid.starts_with('{') && guid.ends_with('}') && guid.len() == 38,
            "{guid}"
        );
        assert_eq!(guid, *fmi3::TOKEN);
    }
}
