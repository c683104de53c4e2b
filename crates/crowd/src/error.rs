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
    /// A step's projection could not be certified, and no Farkas certificate showed its
    /// constraints infeasible: the integrator's error, with how fast the crowd asked to go.
    /// The certified accuracy is absolute while rounding grows with the velocities, so a
    /// speed factor or desired speed far beyond walking shows here (10⁶ × 1.3 m/s stops at
    /// the rounding floor).
    #[error(
        "{error}; the step's desired velocities reach {} m/s (speed factor {})",
        moreau_core::Num(*fastest),
        moreau_core::Num(*speed_factor)
    )]
    NotCertified {
        /// The integrator's error ([`moreau_integrate::IntegrateError::NotCertified`]).
        error: moreau_integrate::IntegrateError,
        /// The largest desired speed of the step, the speed factor included (m/s).
        fastest: f64,
        /// The speed factor on every desired speed.
        speed_factor: f64,
    },
    /// The feasible set left no room: the constraints of a step cannot all hold (a moving wall
    /// crushing people against another, say).
    #[error("{0}")]
    Infeasible(Box<Infeasibility>),
}

/// Why a step had no feasible configuration: the constraints of a Farkas certificate (a
/// nonnegative combination of them that no velocity can meet), and who they involve.
#[derive(Debug, Clone, PartialEq)]
pub struct Infeasibility {
    /// The end of the step that failed (s).
    pub t: f64,
    /// The constraints of the certificate, heaviest first: kind, person, other person or wall
    /// or moving segment, and the certificate's weight (the largest is 1).
    pub contacts: Vec<(crate::ContactKind, u32, u32, f64)>,
    /// The people in them, by id, increasing.
    pub people: Vec<u32>,
    /// The moving bodies in them, by name.
    pub moving: Vec<String>,
}

impl std::fmt::Display for Infeasibility {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "infeasible: no room for everyone at t = {} s: {} constraints cannot all hold, \
             between people {:?}",
            moreau_core::Num(self.t),
            self.contacts.len(),
            self.people
        )?;
        if self.moving.is_empty() {
            Ok(())
        } else {
            write!(f, " and moving bodies {:?}", self.moving)
        }
    }
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
