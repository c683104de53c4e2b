//! The one error type of the crowd crate.

/// Errors of scenes and crowd runs.
#[derive(Debug, thiserror::Error)]
pub enum CrowdError {
    /// The scene file could not be read.
    #[error("cannot read scene {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The scene is not valid TOML for a scene (syntax, unknown key, wrong type).
    #[error("scene {path}: {message}")]
    Parse {
        /// The file (or `<string>`).
        path: String,
        /// The parser's message, which names the key and line.
        message: String,
    },
    /// A scene value is out of its domain.
    #[error("scene error at {field} = {value}: {reason}")]
    Invalid {
        /// Where in the scene (`groups[0].radius`).
        field: String,
        /// The value, printed.
        value: String,
        /// Why it is rejected.
        reason: String,
    },
    /// An observer stopped the run.
    #[error("{0}")]
    Observer(#[source] Box<dyn std::error::Error + Send + Sync>),
    /// The time stepping failed.
    #[error(transparent)]
    Integrate(#[from] moreau_integrate::IntegrateError),
}

impl CrowdError {
    pub(crate) fn invalid(
        field: impl Into<String>,
        value: impl std::fmt::Display,
        reason: impl Into<String>,
    ) -> Self {
        CrowdError::Invalid {
            field: field.into(),
            value: value.to_string(),
            reason: reason.into(),
        }
    }
}
