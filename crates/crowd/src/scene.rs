//! Scene files: the whole input of a crowd run, read from TOML and validated field by field.

use std::path::Path;

use serde::{Deserialize, Serialize};

use moreau_core::{Num, StepReport};
use moreau_integrate::{AdaptiveSettings, EpsPolicy, ErrorEstimate, Stepping};
pub use moreau_solve::SolverKind;

use crate::error::CrowdError;
use crate::events::Inflow;
use crate::geometry::{Polygon, Segment, ring_contains, segments_cross};

/// The bounds a scene must keep so that building and running it cannot exhaust the machine:
/// each is checked before anything is allocated, and an error names the field, its value and
/// the limit.
pub mod limits {
    /// The largest coordinate magnitude (m): beyond it areas, distances and grids lose every
    /// digit of a person's size (and `1e308` overflows to infinity).
    pub const MAX_COORDINATE: f64 = 1e15;
    /// The most cells of one distance field (the area's bounding box in cells of
    /// `solver.grid_cell`), e.g. 200 m × 200 m at 0.1 m: some 50 bytes a cell while solving
    /// and 24 kept, about 100 MB a field.
    pub const MAX_FIELD_CELLS: f64 = 4e6;
    /// The most steps one run can be asked for (`time.horizon / time.step`).
    pub const MAX_STEPS: f64 = moreau_integrate::MAX_STEPS;
    /// The most output frames one run can be asked for (`time.horizon / time.output_interval`).
    pub const MAX_FRAMES: f64 = 1e8;
    /// The most people one scene may hold: ten times the largest crowd moreau is built for
    /// (10⁶), and some 2 GB of state.
    pub const MAX_PEOPLE: f64 = 1e7;
    /// The densest packing of equal disks in the plane, `π / (2√3)`: a spawn region holds at
    /// most this fraction of its area in disks.
    pub const PACKING: f64 = 0.906_899_682_117_108_9;
    /// Projection threads a scene may ask for on this machine: twice its cores (0 means every
    /// core). More only makes the threads wait for each other.
    pub fn max_threads() -> usize {
        2 * std::thread::available_parallelism().map_or(1, |n| n.get())
    }

    /// A stored run's thread count on this machine: at most [`max_threads`] (a run saved on
    /// a larger machine goes on here; its results do not depend on the thread count).
    pub fn threads_here(threads: usize) -> usize {
        threads.min(max_threads())
    }
}

/// Cells of the distance grid over the box `[lo, hi]` with cells of `cell`, as a float (it
/// may be far beyond `usize`).
pub(crate) fn grid_cells(lo: [f64; 2], hi: [f64; 2], cell: f64) -> f64 {
    let nx = ((hi[0] - lo[0]) / cell).ceil().max(1.0);
    let ny = ((hi[1] - lo[1]) / cell).ceil().max(1.0);
    nx * ny
}

/// A number, or a uniform distribution `{ min, max }` to draw it from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Quantity {
    /// The same value for everyone.
    Fixed(f64),
    /// Drawn uniformly in `[min, max]`.
    Uniform {
        /// Lower end.
        min: f64,
        /// Upper end.
        max: f64,
    },
}

/// Read as written: a number, or a table of `min` and `max` and no other key (an untagged
/// enum took `{ min, max, mean }` without a word and said of anything else "data did not
/// match any variant of untagged enum Quantity").
impl<'de> Deserialize<'de> for Quantity {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Written {
            Fixed(f64),
            Uniform(Range),
        }
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Range {
            min: f64,
            max: f64,
        }
        match Written::deserialize(d) {
            Ok(Written::Fixed(x)) => Ok(Quantity::Fixed(x)),
            Ok(Written::Uniform(Range { min, max })) => Ok(Quantity::Uniform { min, max }),
            // A key left out is said as such (it was "expected a number…" at the group's
            // header, the key never named).
            Err(e) if e.to_string().starts_with("missing field") => Err(e),
            Err(_) => Err(serde::de::Error::custom(
                "expected a number, or a range `{ min = …, max = … }` with no other key",
            )),
        }
    }
}

impl Quantity {
    pub(crate) fn check(&self, field: &str, positive: bool) -> Result<(), CrowdError> {
        let ok = |x: f64| x.is_finite() && if positive { x > 0.0 } else { x >= 0.0 };
        let need = if positive {
            "must be finite and > 0"
        } else {
            "must be finite and ≥ 0"
        };
        match *self {
            Quantity::Fixed(x) if !ok(x) => Err(CrowdError::invalid(field, Num(x), need)),
            Quantity::Uniform { min, .. } if !ok(min) => {
                Err(CrowdError::invalid(format!("{field}.min"), Num(min), need))
            }
            Quantity::Uniform { max, .. } if !ok(max) => {
                Err(CrowdError::invalid(format!("{field}.max"), Num(max), need))
            }
            Quantity::Uniform { min, max } if min > max => Err(CrowdError::invalid(
                format!("{field}.min"),
                min,
                format!("greater than max = {max}"),
            )),
            _ => Ok(()),
        }
    }

    /// The largest value it can take.
    pub fn max(&self) -> f64 {
        match *self {
            Quantity::Fixed(x) => x,
            Quantity::Uniform { max, .. } => max,
        }
    }

    /// The smallest value it can take.
    pub fn min(&self) -> f64 {
        match *self {
            Quantity::Fixed(x) => x,
            Quantity::Uniform { min, .. } => min,
        }
    }
}

/// The walkable area: an outer polygon with holes (obstacles); walls are their edges. A
/// scene file gives it by its rings (`[area] outer = ..., holes = ...`) or as WKT
/// (`area = "POLYGON (...)"`, `[area] wkt_file = "room.wkt"`: see `crate::wkt`); read, it is
/// its rings, and it is written back as them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Area {
    /// Outer boundary.
    pub outer: Vec<[f64; 2]>,
    /// Obstacles inside it.
    pub holes: Vec<Vec<[f64; 2]>>,
    /// The WKT the scene file gave, until [`Scene::from_toml`] reads it into the rings.
    #[serde(skip)]
    pub(crate) wkt_source: Option<crate::wkt::WktSource>,
}

/// What happens to a person who reaches an exit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExitAction {
    /// The person leaves the simulation.
    Remove,
    /// The person keeps walking to the exit's target area (the state keeps its size).
    Continue,
}

/// An exit: an area (polygon) or a line (segment) and what happens there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Exit {
    /// Its name, used by groups as their destination.
    pub name: String,
    /// The exit area: reaching it (center inside) counts as passing the exit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub area: Option<Vec<[f64; 2]>>,
    /// Or the exit line: a person whose edge comes within 6 cm of it has passed (the wall
    /// slide's 5 cm and 1 cm: so a line on a wall is reached by people walking to it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segment: Option<[[f64; 2]; 2]>,
    /// What happens there.
    pub action: ExitAction,
    /// For `continue`: the area to walk to afterwards (people stop inside it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<Vec<[f64; 2]>>,
    /// `[t0, t1]`: a panel slides across the exit between these times and stays (a moving
    /// body named `exit:NAME` along the exit's line, or the mid-line of its area).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closes: Option<[f64; 2]>,
    /// `[t0, t1]`: the panel slides back out between these times (an exit that only opens
    /// starts closed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub opens: Option<[f64; 2]>,
}

/// A group of people.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Group {
    /// Its name.
    pub name: String,
    /// How many, placed at random without overlap in `spawn` (or give `positions`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// The spawn region.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spawn: Option<Vec<[f64; 2]>>,
    /// Fixed initial positions instead of `count` and `spawn`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub positions: Option<Vec<[f64; 2]>>,
    /// Radius in metres.
    pub radius: Quantity,
    /// Desired speed in m/s.
    pub speed: Quantity,
    /// The name of the exit they walk to.
    pub destination: String,
    /// When they start walking (s; absent: at once): before it they stand, and can be pushed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub release: Option<f64>,
}

/// One pose of a moving body: at time `t` its points are turned by `angle` about its pivot,
/// then shifted by `offset`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    /// Time (s).
    pub t: f64,
    /// Translation from where the scene draws the body (m).
    #[serde(default)]
    pub offset: [f64; 2],
    /// Rotation about the pivot, counter-clockwise (degrees).
    #[serde(default)]
    pub angle: f64,
}

/// A wall, door panel or obstacle with a prescribed motion: the feasible set moves with it (a
/// sweeping process, seeds/000). Its pose is linear in time between keyframes and held before
/// the first and after the last, so it moves continuously.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MovingBody {
    /// Its name (in reports and the run file).
    pub name: String,
    /// An open polyline (a wall or a panel: people keep off both sides)…
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub line: Option<Vec<[f64; 2]>>,
    /// …or a closed polygon (an obstacle: nobody inside).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polygon: Option<Vec<[f64; 2]>>,
    /// The point rotations turn about (default: the first vertex).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pivot: Option<[f64; 2]>,
    /// Poses at increasing times.
    pub keyframes: Vec<Keyframe>,
}

/// Time stepping.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Time {
    /// End time (s).
    pub horizon: f64,
    /// Step `μ` (s); with `tol`, the first step tried.
    pub step: f64,
    /// Interval between recorded frames (s).
    pub output_interval: f64,
    /// Adaptive steps: the local error allowed per step (m). It sets the step sizes (between
    /// 1e-6 s and min(0.5 s, output interval, horizon), starting from `step`) and the
    /// projection accuracy `ε_k = (θ·tol)² (μ_k/μ_max)³` with θ = 0.1. Absent: fixed steps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tol: Option<f64>,
    /// The error estimate of adaptive steps (`velocity-change`, the default, or
    /// `step-doubling`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub estimate: Option<ErrorEstimate>,
}

impl Time {
    /// How the run chooses its steps: fixed steps of `step`, or with `tol` adaptive steps
    /// whose largest is the output interval (frames land on output times), asking `solver`'s
    /// projections no more than it certifies ([`SolverKind::certified_floor`]).
    pub fn stepping(&self, solver: SolverKind) -> Result<Stepping, CrowdError> {
        let Some(tol) = self.tol else {
            // Steps end at every frame, so none is longer than the output interval or the
            // horizon; a longer `step` is taken as that (`fixed_step` takes what is left below
            // a billionth of the step for rounding: `step = 1e300` was a run of no step).
            return Ok(Stepping::fixed(
                self.step.min(self.output_interval).min(self.horizon),
            )?);
        };
        let mut settings = AdaptiveSettings::new(tol);
        settings.mu_max = settings.mu_max.min(self.output_interval).min(self.horizon);
        settings.mu_first = self.step.min(settings.mu_max);
        settings.mu_min = settings.mu_min.min(settings.mu_first);
        settings.estimate = self.estimate.unwrap_or(ErrorEstimate::VelocityChange);
        if let Some(floor) = solver.certified_floor() {
            settings.eps_floor = settings.eps_floor.max(floor);
        }
        Stepping::adaptive(settings)
            .map_err(|e| CrowdError::invalid("time.tol", Num(tol), e.to_string()))
    }
}

/// What to tell the user, once, when an adaptive step is accepted above `time.tol`: only a
/// step at the controller's smallest is (whatever its error), so a tolerance this small keeps
/// the run at that step, hours for a long horizon. Fixed steps never say it. `moreau run` and
/// `moreau tradeoff` print it once a run, the FMU logs it once an instance, the Python module
/// warns once a simulation.
#[derive(Debug, Clone, Copy)]
pub struct ToleranceWarning {
    tol: Option<f64>,
    said: bool,
}

impl ToleranceWarning {
    /// Watching the steps of a run with `time`.
    pub fn new(time: &Time) -> Self {
        Self {
            tol: time.tol,
            said: false,
        }
    }

    /// The message of the first step above the tolerance; `None` for every other step.
    pub fn first(&mut self, report: &StepReport) -> Option<String> {
        let tol = self.tol.filter(|_| !self.said)?;
        let error = report.local_error.filter(|&e| e > tol)?;
        self.said = true;
        Some(format!(
            "at t = {} s the smallest step, {} s, erred by {} m, more than time.tol = {} m: \
             the run goes on at that step where the tolerance cannot be met (a larger tol runs \
             faster)",
            Num(report.t),
            Num(report.mu),
            Num(error),
            Num(tol)
        ))
    }
}

/// Which broad phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum BroadPhaseChoice {
    /// Chosen from the spread of radii.
    #[default]
    Auto,
    /// The uniform cell grid.
    Grid,
    /// parry's bounding-volume hierarchy.
    Bvh,
}

fn default_kappa() -> f64 {
    1e-2
}
fn default_violation() -> f64 {
    1e-6
}
pub(crate) fn default_threads() -> usize {
    1
}
fn default_cell() -> f64 {
    0.1
}

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSettings {
    /// The projection solver.
    #[serde(default)]
    pub kind: SolverKind,
    /// `κ` in `ε_k = κ μ_k³` (m²/s³).
    #[serde(default = "default_kappa")]
    pub eps_kappa: f64,
    /// Largest accepted overlap of the linearized constraints (m): below the smallest radius.
    #[serde(default = "default_violation")]
    pub max_violation: f64,
    /// Cell size of the geodesic-distance grid (m).
    #[serde(default = "default_cell")]
    pub grid_cell: f64,
    /// The broad phase.
    #[serde(default)]
    pub broad_phase: BroadPhaseChoice,
    /// Threads for the projection (0: every core). Results do not depend on it beyond the
    /// certified tolerance.
    #[serde(default = "default_threads")]
    pub threads: usize,
    /// Our interior point's settings (`[solver.interior]`: `kind = "interior"`, and inside
    /// `auto`; absent: the defaults, and then not written out). Threads: `threads`.
    #[serde(default, skip_serializing_if = "is_default")]
    pub interior: moreau_solve::InteriorPointSettings,
    /// The semismooth Newton method's (`[solver.newton]`, `kind = "newton"`).
    #[serde(default, skip_serializing_if = "is_default")]
    pub newton: moreau_solve::NewtonSettings,
    /// Projected Gauss–Seidel's (`[solver.gauss_seidel]`: `kind = "gauss-seidel"`, and inside
    /// `auto`, whose own `first_order_passes` is its budget there).
    #[serde(default, skip_serializing_if = "is_default")]
    pub gauss_seidel: moreau_solve::GaussSeidelSettings,
    /// APGD's (`[solver.apgd]`: `kind = "apgd"`, and the fallback of large problems).
    #[serde(default, skip_serializing_if = "is_default")]
    pub apgd: moreau_solve::ApgdSettings,
    /// `auto`'s own (`[solver.auto]`).
    #[serde(default, skip_serializing_if = "is_default")]
    pub auto: moreau_solve::AutoSettings,
}

fn is_default<T: Default + PartialEq>(x: &T) -> bool {
    *x == T::default()
}

impl SolverSettings {
    /// Every solver's settings, for [`SolverKind::build_with`].
    pub fn tuning(&self) -> moreau_solve::SolverTuning {
        moreau_solve::SolverTuning {
            interior: self.interior,
            newton: self.newton,
            gauss_seidel: self.gauss_seidel,
            apgd: self.apgd,
            auto: self.auto,
        }
    }
}

impl Default for SolverSettings {
    fn default() -> Self {
        Self {
            kind: SolverKind::Auto,
            eps_kappa: default_kappa(),
            max_violation: default_violation(),
            grid_cell: default_cell(),
            broad_phase: BroadPhaseChoice::Auto,
            threads: default_threads(),
            interior: Default::default(),
            newton: Default::default(),
            gauss_seidel: Default::default(),
            apgd: Default::default(),
            auto: Default::default(),
        }
    }
}

/// Which desired velocity people follow (the default: [`Lipschitz`](Self::Lipschitz); it was
/// [`Classic`](Self::Classic) before, which is how [`Scene::from_run_file`] reads run files
/// of that time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DesiredVelocityKind {
    /// Speed × the descent direction of the distance to the goal, projected off any wall
    /// within 5 cm beyond the radius, zero once arrived: it jumps where the wall slide starts
    /// and on arrival (not Lipschitz). `[model] desired_velocity = "classic"`.
    Classic,
    /// Lipschitz in the positions (the assumption of seeds/000 (8)) wherever the distance
    /// field's direction is: the wall slide fades in linearly over the 5 cm beyond the radius,
    /// and people heading to a target area slow down linearly over its last metre and stop
    /// on its boundary. The default.
    #[default]
    Lipschitz,
}

/// The model's choices that the papers leave open. A scene always serializes it whole with
/// its desired velocity (a scene written out, into a run file say, says which one it ran with
/// whatever the default is when it is read back).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    /// The desired velocity (`lipschitz`, the default, or `classic`).
    #[serde(default)]
    pub desired_velocity: DesiredVelocityKind,
    /// With moving bodies: every this many seconds (at the first step from then on), the
    /// distance fields are solved again around the bodies where they are, if any moved since
    /// (the cost is the step report's `field` time). Absent: the fields see the fixed walls
    /// only, and people walk into a closed door as if it were open.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_update: Option<f64>,
}

/// What a run records beyond positions, exits and step reports: only what the scene asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Output {
    /// Contact forces: per output frame, the contacts of the last step with `λ > 10⁻⁶ m/s` and each
    /// person's pressure `Σ λ` (m/s).
    #[serde(default)]
    pub contacts: bool,
}

impl Output {
    fn is_default(&self) -> bool {
        *self == Output::default()
    }
}

/// Every array of numbers in a scene is a pair (a point `[x, y]`, `[t0, t1]`, an offset) and
/// every `segment` is two points: toml hands serde the first two elements of a longer array
/// and drops the rest without a word (a position `[1, 1, 5]` was read as `[1, 1]`, a segment
/// of three points as its first two). The first that is not, named with its value.
fn check_pairs(path: &str, value: &toml::Value) -> Result<(), CrowdError> {
    let toml::Value::Array(items) = value else {
        if let toml::Value::Table(t) = value {
            for (key, v) in t {
                check_pairs(&format!("{path}.{key}"), v)?;
            }
        }
        return Ok(());
    };
    let numbers = !items.is_empty()
        && items
            .iter()
            .all(|v| matches!(v, toml::Value::Integer(_) | toml::Value::Float(_)));
    let segment = path.ends_with(".segment");
    if (numbers || segment) && items.len() != 2 {
        let what = match segment {
            true => "a segment is two points [[x, y], [x, y]]",
            false => "a pair of numbers ([x, y], [t0, t1], [dx, dy])",
        };
        return Err(CrowdError::invalid(
            path,
            value.to_string(),
            format!("{} elements given: {what}", items.len()),
        ));
    }
    for (i, v) in items.iter().enumerate() {
        check_pairs(&format!("{path}[{i}]"), v)?;
    }
    Ok(())
}

/// A whole scene, as read from TOML; [`Scene::validate`] checks it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// A name for reports.
    #[serde(default)]
    pub name: String,
    /// The random seed (initial positions, distributions).
    pub seed: u64,
    /// The walkable area.
    pub area: Area,
    /// The exits.
    pub exits: Vec<Exit>,
    /// The groups of people (absent: none, for a scene whose people all come from sources).
    #[serde(default)]
    pub groups: Vec<Group>,
    /// People entering while the run goes ([`Inflow`]; absent: none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sources: Vec<Inflow>,
    /// Time stepping.
    pub time: Time,
    /// Solver settings.
    #[serde(default)]
    pub solver: SolverSettings,
    /// The model's open choices (absent: the Lipschitz desired velocity). Always written.
    #[serde(default)]
    pub model: Model,
    /// What a run records (absent: positions, exits and steps only).
    #[serde(default, skip_serializing_if = "Output::is_default")]
    pub output: Output,
    /// Walls, panels and obstacles that move (absent: the geometry is fixed).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub moving: Vec<MovingBody>,
}

pub(crate) fn check_polygon(field: &str, v: &[[f64; 2]]) -> Result<Polygon, CrowdError> {
    if v.len() < 3 {
        return Err(CrowdError::invalid(
            field,
            format!("{} vertices", v.len()),
            "a polygon needs at least 3 vertices",
        ));
    }
    for (i, p) in v.iter().enumerate() {
        check_point(&format!("{field}[{i}]"), *p)?;
    }
    // A repeated vertex is an edge of zero length, which the walls and the crossing check
    // cannot use (it was refused as "the boundary crosses itself").
    let n = v.len();
    if let Some(i) = (1..=n).find(|&i| v[i - 1] == v[i % n]) {
        let (at, why) = if i == n {
            (
                n - 1,
                "repeats the first vertex: a ring closes by itself (leave the closing vertex out)",
            )
        } else {
            (i, "repeats the vertex before it (list each vertex once)")
        };
        return Err(CrowdError::invalid(
            format!("{field}[{at}]"),
            format!("{:?}", v[at]),
            why,
        ));
    }
    let poly = Polygon {
        vertices: v.to_vec(),
    };
    if poly.area() <= 0.0 {
        return Err(CrowdError::invalid(
            field,
            format!("{v:?}"),
            "polygon has zero area",
        ));
    }
    if let Some((i, j)) = poly.self_intersection() {
        let n = v.len();
        return Err(CrowdError::invalid(
            field,
            format!("{v:?}"),
            format!(
                "the boundary crosses itself: edge {:?} → {:?} meets edge {:?} → {:?} \
                 (a polygon must be simple: list its vertices in order around it)",
                v[i],
                v[(i + 1) % n],
                v[j],
                v[(j + 1) % n]
            ),
        ));
    }
    Ok(poly)
}

/// The error of a `destination` (at `field`) that no exit has: it names the exits there are.
pub(crate) fn no_such_exit(field: String, destination: &str, exits: &[Exit]) -> CrowdError {
    let names: Vec<&str> = exits.iter().map(|e| e.name.as_str()).collect();
    CrowdError::invalid(
        field,
        destination,
        format!("no exit has this name (the exits: {})", names.join(", ")),
    )
}

/// A point: finite, and within [`limits::MAX_COORDINATE`] of the origin on both axes.
pub(crate) fn check_point(field: &str, p: [f64; 2]) -> Result<(), CrowdError> {
    if !p[0].is_finite() || !p[1].is_finite() {
        return Err(CrowdError::invalid(
            field,
            format!("{p:?}"),
            "coordinates must be finite",
        ));
    }
    if p[0].abs() > limits::MAX_COORDINATE || p[1].abs() > limits::MAX_COORDINATE {
        return Err(CrowdError::invalid(
            field,
            format!("{p:?}"),
            format!(
                "coordinates must be within ±{:e} m (the limit of a scene)",
                limits::MAX_COORDINATE
            ),
        ));
    }
    Ok(())
}

impl Scene {
    /// Reads and validates a scene file.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, CrowdError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| CrowdError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let dir = path.parent().unwrap_or(Path::new(""));
        Self::from_toml_in(&text, &path.display().to_string(), dir)
    }

    /// Parses and validates a scene from TOML text; `origin` names it in errors. An
    /// `[area] wkt_file` is read relative to the current directory.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, CrowdError> {
        Self::from_toml_in(text, origin, Path::new(""))
    }

    /// [`Scene::from_toml`], with an `[area] wkt_file` read relative to `dir` (what
    /// [`Scene::from_file`] gives: the scene file's directory).
    pub fn from_toml_in(text: &str, origin: &str, dir: &Path) -> Result<Self, CrowdError> {
        let parse_error = |e: toml::de::Error| CrowdError::Parse {
            path: origin.to_string(),
            message: e.to_string(),
        };
        let mut scene: Scene = toml::from_str(text).map_err(parse_error)?;
        let table: toml::Table = toml::from_str(text).map_err(parse_error)?;
        for (key, value) in &table {
            check_pairs(key, value)?;
        }
        scene.area.read_wkt(dir)?;
        scene.validate()?;
        Ok(scene)
    }

    /// A scene stored in a run file (its attribute `scene`), `origin` naming it in errors. A
    /// scene serialized since the desired velocity's default became `lipschitz` always names
    /// its kind ([`Model`] is always written); one that does not was stored before, when an
    /// absent kind meant `classic`, and it is read as `classic`, so that `moreau run --from`
    /// reproduces what ran. Scene files are read with [`Scene::from_file`]: there an absent kind
    /// is the default.
    pub fn from_run_file(text: &str, origin: &str) -> Result<Self, CrowdError> {
        let mut scene = Self::from_toml(text, origin)?;
        let table: toml::Table = toml::from_str(text).map_err(|e| CrowdError::Parse {
            path: origin.to_string(),
            message: e.to_string(),
        })?;
        let named = table
            .get("model")
            .and_then(|m| m.get("desired_velocity"))
            .is_some();
        if !named {
            scene.model.desired_velocity = DesiredVelocityKind::Classic;
        }
        Ok(scene)
    }

    /// The scene as TOML (it round-trips through [`Scene::from_toml`]; `[model]` always
    /// written).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a scene serializes")
    }

    /// The walkable area's outer ring, checked with the holes: its rings simple, each hole
    /// inside the outer ring (on it is fine: an obstacle against a wall) and clear of the
    /// other holes but for touching, as PedPy and shapely need it (until session 38 a hole's
    /// vertex on the outer ring's right or top edge was refused, and holes that overlapped,
    /// lay in each other or crossed the outer ring between their vertices were taken, and the
    /// run file's area then failed in PedPy).
    fn check_area(&self) -> Result<Polygon, CrowdError> {
        let outer = check_polygon("area.outer", &self.area.outer)?;
        let on = |ring: &Polygon, p: [f64; 2]| {
            ring.boundary_distance(p) <= 1e-9 * p[0].abs().max(p[1].abs()).max(1.0)
        };
        let inside = |ring: &Polygon, p: [f64; 2]| ring.contains(p) && !on(ring, p);
        let on_segment =
            |e: Segment, p: [f64; 2]| e.distance(p) <= 1e-9 * p[0].abs().max(p[1].abs()).max(1.0);
        let crossing = |a: &Polygon, b: &Polygon| {
            a.edges().find_map(|e| {
                b.edges()
                    .find(|f| segments_cross(e.a, e.b, f.a, f.b))
                    .map(|f| (e, f))
            })
        };
        // A ring's vertices and the midpoints of its edges' pieces between the points where
        // `other`'s vertices touch them: where two rings meet without an edge crossing, one
        // of these lies strictly on the wrong side of the other ring whenever the rings
        // overlap (one inside the other, or an edge running outside between two vertices on
        // the other ring, or through one of its vertices).
        let points = |ring: &Polygon, other: &Polygon| -> Vec<[f64; 2]> {
            let mut out = ring.vertices.clone();
            let mut cuts = Vec::new();
            for e in ring.edges() {
                let d = [e.b[0] - e.a[0], e.b[1] - e.a[1]];
                let len2 = d[0] * d[0] + d[1] * d[1];
                cuts.clear();
                cuts.extend([0.0, 1.0]);
                for &q in other.vertices.iter().filter(|&&q| on_segment(e, q)) {
                    let t = ((q[0] - e.a[0]) * d[0] + (q[1] - e.a[1]) * d[1]) / len2;
                    cuts.push(t.clamp(0.0, 1.0));
                }
                cuts.sort_by(f64::total_cmp);
                out.extend(cuts.windows(2).filter(|w| w[1] > w[0]).map(|w| {
                    let t = 0.5 * (w[0] + w[1]);
                    [e.a[0] + t * d[0], e.a[1] + t * d[1]]
                }));
            }
            out
        };
        let mut holes: Vec<(Polygon, [f64; 2], [f64; 2])> = Vec::new();
        for (h, hole) in self.area.holes.iter().enumerate() {
            let f = format!("area.holes[{h}]");
            let poly = check_polygon(&f, hole)?;
            if let Some(p) = poly
                .vertices
                .iter()
                .find(|p| !outer.contains(**p) && !on(&outer, **p))
            {
                return Err(CrowdError::invalid(
                    f,
                    format!("{p:?}"),
                    "hole vertex outside the outer polygon",
                ));
            }
            if let Some((e, o)) = crossing(&poly, &outer) {
                return Err(CrowdError::invalid(
                    f,
                    format!("{hole:?}"),
                    format!(
                        "its edge {:?} → {:?} crosses the outer boundary's edge {:?} → {:?} \
                         (a hole lies inside the outer polygon)",
                        e.a, e.b, o.a, o.b
                    ),
                ));
            }
            // Between vertices on the outer ring an edge can still run outside it (along a
            // notch of the outer ring, the gap of a door): the run file's area was then
            // invalid, and PedPy's Voronoi cells raised a TopologyException.
            if let Some(p) = points(&poly, &outer)
                .into_iter()
                .find(|&p| !outer.contains(p) && !on(&outer, p))
            {
                return Err(CrowdError::invalid(
                    f,
                    format!("{hole:?}"),
                    format!(
                        "its boundary runs outside the outer polygon (through {p:?}): a hole \
                         lies inside the outer polygon"
                    ),
                ));
            }
            let (lo, hi) = poly.bounds();
            for (g, (other, olo, ohi)) in holes.iter().enumerate() {
                if lo[0] > ohi[0] || lo[1] > ohi[1] || olo[0] > hi[0] || olo[1] > hi[1] {
                    continue;
                }
                let overlap = crossing(&poly, other)
                    .map(|(e, o)| {
                        format!(
                            "its edge {:?} → {:?} crosses area.holes[{g}]'s edge {:?} → {:?}",
                            e.a, e.b, o.a, o.b
                        )
                    })
                    .or_else(|| {
                        points(&poly, other)
                            .into_iter()
                            .any(|p| inside(other, p))
                            .then(|| format!("it lies in area.holes[{g}]"))
                    })
                    .or_else(|| {
                        points(other, &poly)
                            .into_iter()
                            .any(|p| inside(&poly, p))
                            .then(|| format!("area.holes[{g}] lies in it"))
                    })
                    // The same ring twice (either way round): every point on the other's
                    // boundary, none strictly inside, and the file's area was invalid.
                    .or_else(|| {
                        points(&poly, other)
                            .into_iter()
                            .all(|p| on(other, p))
                            .then(|| format!("it is area.holes[{g}] again"))
                    });
                if let Some(why) = overlap {
                    return Err(CrowdError::invalid(
                        f,
                        format!("{hole:?}"),
                        format!(
                            "{why}: holes may touch but not overlap (obstacles that overlap \
                             are one hole: merge them)"
                        ),
                    ));
                }
            }
            holes.push((poly, lo, hi));
        }
        Ok(outer)
    }

    /// Checks every value that can be checked without building the scene.
    pub fn validate(&self) -> Result<(), CrowdError> {
        self.area.check_read()?;
        let outer = self.check_area()?;
        let t = &self.time;
        for (f, v) in [
            ("time.horizon", t.horizon),
            ("time.step", t.step),
            ("time.output_interval", t.output_interval),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(CrowdError::invalid(f, Num(v), "must be finite and > 0"));
            }
        }
        if let Some(tol) = t.tol
            && !(tol > 0.0 && tol.is_finite())
        {
            return Err(CrowdError::invalid(
                "time.tol",
                Num(tol),
                "must be finite and > 0",
            ));
        }
        // An estimate with fixed steps was taken and ignored (`--estimate` without `--tol`
        // is refused on the command line).
        if let (Some(estimate), None) = (t.estimate, t.tol) {
            return Err(CrowdError::invalid(
                "time.estimate",
                match estimate {
                    ErrorEstimate::StepDoubling => "step-doubling",
                    ErrorEstimate::VelocityChange => "velocity-change",
                },
                "chooses the error estimate of adaptive steps: give time.tol too, or drop it",
            ));
        }
        // Fixed steps take horizon / step steps; adaptive ones at least horizon / their
        // largest step (0.5 s, the output interval, the horizon).
        let (steps, field, value) = match t.tol {
            None => (t.horizon / t.step, "time.step", Num(t.step)),
            Some(_) => (
                t.horizon / t.output_interval.min(0.5).min(t.horizon),
                "time.horizon",
                Num(t.horizon),
            ),
        };
        if !(steps <= limits::MAX_STEPS) {
            return Err(CrowdError::invalid(
                field,
                value,
                format!(
                    "the run would take {steps:.3e} steps (time.horizon = {}, time.step = {}), \
                     more than the limit of {:e} steps a run",
                    Num(t.horizon),
                    Num(t.step),
                    limits::MAX_STEPS
                ),
            ));
        }
        let frames = t.horizon / t.output_interval;
        if !(frames <= limits::MAX_FRAMES) {
            return Err(CrowdError::invalid(
                "time.output_interval",
                Num(t.output_interval),
                format!(
                    "time.horizon / time.output_interval = {frames:.3e} frames, more than the \
                     limit of {:e} frames a run (time.horizon = {})",
                    limits::MAX_FRAMES,
                    Num(t.horizon)
                ),
            ));
        }
        let s = &self.solver;
        for (f, v) in [
            ("solver.eps_kappa", s.eps_kappa),
            ("solver.max_violation", s.max_violation),
            ("solver.grid_cell", s.grid_cell),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(CrowdError::invalid(f, Num(v), "must be finite and > 0"));
            }
        }
        // The certified accuracy of the shortest step must be a number: an `ε` below the
        // smallest normal double is rounded away (to 0), which no projection certifies (a
        // horizon of 1e-300 s failed its first step as "not certified, ε = 0e0 for target
        // 0e0").
        let stepping = t.stepping(s.kind)?;
        let policy = self.eps_policy(&stepping)?;
        let (shortest, field) = [
            (t.step, "time.step"),
            (t.output_interval, "time.output_interval"),
            (t.horizon, "time.horizon"),
        ]
        .into_iter()
        .fold((f64::INFINITY, ""), |a, b| if b.0 < a.0 { b } else { a });
        let eps = policy.eps(shortest);
        if !(eps >= f64::MIN_POSITIVE) {
            return Err(CrowdError::invalid(
                field,
                Num(shortest),
                format!(
                    "a step of {} s would be certified to ε = {}, below the smallest normal \
                     double ({:e}): no step may be shorter than {:.3e} s here{}",
                    Num(shortest),
                    Num(eps),
                    f64::MIN_POSITIVE,
                    policy.shortest_certifiable(),
                    match stepping {
                        Stepping::Fixed { .. } => format!(
                            " (ε = solver.eps_kappa·μ³, solver.eps_kappa = {})",
                            Num(s.eps_kappa)
                        ),
                        Stepping::Adaptive(_) => String::new(),
                    }
                ),
            ));
        }
        if s.threads > 1024 {
            return Err(CrowdError::invalid(
                "solver.threads",
                s.threads,
                "at most 1024 (0: every core)",
            ));
        }
        if let Err((table, e)) = s.tuning().validate() {
            return Err(match e {
                moreau_solve::SolveError::InvalidSetting {
                    field,
                    value,
                    reason,
                } => CrowdError::invalid(format!("solver.{table}.{field}"), value, reason),
                other => CrowdError::invalid(format!("solver.{table}"), "", other.to_string()),
            });
        }
        let (lo, hi) = outer.bounds();
        let cells = grid_cells(lo, hi, s.grid_cell);
        if !(cells <= limits::MAX_FIELD_CELLS) {
            return Err(CrowdError::invalid(
                "solver.grid_cell",
                Num(s.grid_cell),
                format!(
                    "the distance grid over the area's {} m × {} m bounding box would have \
                     {cells:.3e} cells, more than the limit of {:e}: use a grid_cell of at \
                     least {:.3e} m",
                    Num(hi[0] - lo[0]),
                    Num(hi[1] - lo[1]),
                    limits::MAX_FIELD_CELLS,
                    ((hi[0] - lo[0]) * (hi[1] - lo[1]) / limits::MAX_FIELD_CELLS).sqrt() * 1.01
                ),
            ));
        }
        if self.exits.is_empty() {
            return Err(CrowdError::invalid(
                "exits",
                "[]",
                "a scene needs at least one exit",
            ));
        }
        for (e, exit) in self.exits.iter().enumerate() {
            let f = format!("exits[{e}]");
            if self.exits[..e].iter().any(|x| x.name == exit.name) {
                return Err(CrowdError::invalid(
                    format!("{f}.name"),
                    &exit.name,
                    "duplicate exit name",
                ));
            }
            if exit.name.trim().is_empty() {
                return Err(CrowdError::invalid(
                    format!("{f}.name"),
                    format!("{:?}", exit.name),
                    "an exit needs a name (destinations, the run file and the FMU name it)",
                ));
            }
            match (&exit.area, &exit.segment) {
                (Some(a), None) => {
                    check_polygon(&format!("{f}.area"), a)?;
                }
                (None, Some(s)) => {
                    for (k, p) in s.iter().enumerate() {
                        check_point(&format!("{f}.segment[{k}]"), *p)?;
                    }
                    if s[0] == s[1] {
                        return Err(CrowdError::invalid(
                            format!("{f}.segment"),
                            format!("{s:?}"),
                            "needs two distinct finite points",
                        ));
                    }
                }
                _ => {
                    return Err(CrowdError::invalid(
                        &f,
                        &exit.name,
                        "give exactly one of `area` and `segment`",
                    ));
                }
            }
            for (name, interval) in [("closes", exit.closes), ("opens", exit.opens)] {
                if let Some([t0, t1]) = interval
                    && !(t0 >= 0.0 && t0.is_finite() && t1 > t0 && t1.is_finite())
                {
                    return Err(CrowdError::invalid(
                        format!("{f}.{name}"),
                        format!("[{}, {}]", Num(t0), Num(t1)),
                        "give [t0, t1] with 0 ≤ t0 < t1, finite (seconds)",
                    ));
                }
            }
            if let (Some(c), Some(o)) = (exit.closes, exit.opens)
                && c[0] < o[1]
                && o[0] < c[1]
            {
                return Err(CrowdError::invalid(
                    format!("{f}.opens"),
                    format!("{o:?}"),
                    format!("overlaps closes = {c:?}: the panel cannot move both ways at once"),
                ));
            }
            // A panel parks beside the door, beyond an end of the line across it: an area
            // with no walls at the ends of that line is not in a doorway, and its panel
            // would stand in the room while the exit is open (an invisible wall).
            // The same for a segment exit, whose panel runs along the segment (one from the
            // middle of a corridor to its wall parked its panel in the corridor).
            if let Some((name, Some(interval))) = [("closes", exit.closes), ("opens", exit.opens)]
                .into_iter()
                .find(|(_, i)| i.is_some())
            {
                let walls = self.walls();
                let poly = exit.area.as_ref().map(|a| Polygon {
                    vertices: a.clone(),
                });
                let segment = exit.segment.map(|s| Segment { a: s[0], b: s[1] });
                let line = crate::exits::closure(poly.as_ref(), segment, &walls);
                let off = crate::exits::ends_off_walls(&line, &walls);
                if !(off <= 0.05 * line.length()) {
                    let what = match segment {
                        Some(_) => "segment",
                        None => "area: the line across it,",
                    };
                    return Err(CrowdError::invalid(
                        format!("{f}.{name}"),
                        format!("{interval:?}"),
                        format!(
                            "the exit's {what} {:?} → {:?}, is not in a doorway: it ends {} m \
                             from the nearest wall, so its panel would stand in the room while \
                             open (give the exit an area between the door's jambs, or a \
                             segment across the door from jamb to jamb)",
                            line.a,
                            line.b,
                            Num(off)
                        ),
                    ));
                }
            }
            match (exit.action, &exit.target) {
                (ExitAction::Continue, Some(t)) => {
                    check_polygon(&format!("{f}.target"), t)?;
                }
                (ExitAction::Continue, None) => {
                    return Err(CrowdError::invalid(
                        format!("{f}.target"),
                        "missing",
                        "action = \"continue\" needs a target area",
                    ));
                }
                (ExitAction::Remove, Some(_)) => {
                    return Err(CrowdError::invalid(
                        format!("{f}.target"),
                        "given",
                        "only action = \"continue\" has a target",
                    ));
                }
                _ => {}
            }
        }
        self.validate_moving()?;
        if let Some(dt) = self.model.field_update
            && !(dt > 0.0 && dt.is_finite())
        {
            return Err(CrowdError::invalid(
                "model.field_update",
                Num(dt),
                "must be finite and > 0 (seconds between rebuilds of the distance fields)",
            ));
        }
        if self.groups.is_empty() && self.sources.is_empty() {
            return Err(CrowdError::invalid(
                "groups",
                "[]",
                "the scene has no people (give groups, or sources)",
            ));
        }
        let mut people = 0.0;
        for (g, group) in self.groups.iter().enumerate() {
            people += match (&group.positions, group.count) {
                (Some(p), _) => p.len() as f64,
                (None, Some(n)) => n as f64,
                _ => 0.0,
            };
            if people > limits::MAX_PEOPLE {
                return Err(CrowdError::invalid(
                    format!("groups[{g}].count"),
                    group.count.unwrap_or(0),
                    format!(
                        "the scene would hold {people:.3e} people, more than the limit of {:e}",
                        limits::MAX_PEOPLE
                    ),
                ));
            }
        }
        for (g, group) in self.groups.iter().enumerate() {
            let f = format!("groups[{g}]");
            // The run file's `/people/group` and `moreau_run.Run.group_name` name each group
            // by index; two of one name could not be told apart by name in an analysis.
            if self.groups[..g].iter().any(|x| x.name == group.name) {
                return Err(CrowdError::invalid(
                    format!("{f}.name"),
                    &group.name,
                    "duplicate group name",
                ));
            }
            group.radius.check(&format!("{f}.radius"), true)?;
            group.speed.check(&format!("{f}.speed"), false)?;
            if !self.exits.iter().any(|e| e.name == group.destination) {
                return Err(no_such_exit(
                    format!("{f}.destination"),
                    &group.destination,
                    &self.exits,
                ));
            }
            match (&group.positions, group.count, &group.spawn) {
                (Some(p), None, None) => {
                    if p.is_empty() {
                        return Err(CrowdError::invalid(
                            format!("{f}.positions"),
                            "[]",
                            "a group needs at least one person",
                        ));
                    }
                    for (i, q) in p.iter().enumerate() {
                        check_point(&format!("{f}.positions[{i}]"), *q)?;
                    }
                }
                (None, Some(n), Some(region)) => {
                    if n == 0 {
                        return Err(CrowdError::invalid(
                            format!("{f}.count"),
                            0,
                            "a group needs at least one person",
                        ));
                    }
                    check_polygon(&format!("{f}.spawn"), region)?;
                }
                _ => {
                    return Err(CrowdError::invalid(
                        &f,
                        &group.name,
                        "give either `positions`, or `count` and `spawn`",
                    ));
                }
            }
        }
        crate::events::validate(self)?;
        self.check_violation_bound()
    }

    /// The projections' `ε_k` with `stepping`: `solver.eps_kappa · μ³` for fixed steps, the
    /// adaptive controller's, tied to its tolerance, for adaptive ones.
    pub(crate) fn eps_policy(&self, stepping: &Stepping) -> Result<EpsPolicy, CrowdError> {
        match stepping {
            Stepping::Fixed { .. } => EpsPolicy::new(self.solver.eps_kappa, 3.0).map_err(|e| {
                CrowdError::invalid(
                    "solver.eps_kappa",
                    Num(self.solver.eps_kappa),
                    e.to_string(),
                )
            }),
            Stepping::Adaptive(c) => Ok(c.settings().eps_policy()),
        }
    }

    /// `solver.max_violation` is a tolerance on overlaps: one as large as the smallest person's
    /// radius lets two people overlap by a whole radius and still count as certified (1e300
    /// gave overlaps of 0.4 m on room-60, every step "within the bound").
    fn check_violation_bound(&self) -> Result<(), CrowdError> {
        let radii = self
            .groups
            .iter()
            .enumerate()
            .map(|(g, group)| (group.radius.min(), format!("groups[{g}].radius")))
            .chain(
                self.sources
                    .iter()
                    .enumerate()
                    .map(|(k, source)| (source.radius.min(), format!("sources[{k}].radius"))),
            );
        let Some((smallest, field)) = radii.min_by(|a, b| a.0.total_cmp(&b.0)) else {
            return Ok(());
        };
        let bound = self.solver.max_violation;
        if bound >= smallest {
            return Err(CrowdError::invalid(
                "solver.max_violation",
                Num(bound),
                format!(
                    "the overlap allowed must be below the smallest radius, {} m ({field}): \
                     people could overlap by a whole radius and still count as certified \
                     (the default is 1e-6 m)",
                    Num(smallest)
                ),
            ));
        }
        Ok(())
    }

    fn validate_moving(&self) -> Result<(), CrowdError> {
        for (b, body) in self.moving.iter().enumerate() {
            let f = format!("moving[{b}]");
            if self.moving[..b].iter().any(|x| x.name == body.name) {
                return Err(CrowdError::invalid(
                    format!("{f}.name"),
                    &body.name,
                    "duplicate moving body name",
                ));
            }
            // The panels of exits that open or close are the bodies `exit:NAME`: a body of that
            // name made two of them in the run file and in infeasibility reports.
            if body.name.starts_with("exit:") {
                return Err(CrowdError::invalid(
                    format!("{f}.name"),
                    &body.name,
                    "names starting with \"exit:\" are the panels of exits that open or close",
                ));
            }
            match (&body.line, &body.polygon) {
                (Some(line), None) => {
                    if line.len() < 2 {
                        return Err(CrowdError::invalid(
                            format!("{f}.line"),
                            format!("{line:?}"),
                            "a line needs at least 2 points",
                        ));
                    }
                    for (i, p) in line.iter().enumerate() {
                        check_point(&format!("{f}.line[{i}]"), *p)?;
                    }
                    if let Some(i) = (1..line.len()).find(|&i| line[i] == line[i - 1]) {
                        return Err(CrowdError::invalid(
                            format!("{f}.line[{i}]"),
                            format!("{:?}", line[i]),
                            "repeats the point before it (a segment of zero length)",
                        ));
                    }
                }
                (None, Some(polygon)) => {
                    check_polygon(&format!("{f}.polygon"), polygon)?;
                }
                _ => {
                    return Err(CrowdError::invalid(
                        &f,
                        &body.name,
                        "give exactly one of `line` and `polygon`",
                    ));
                }
            }
            if let Some(p) = body.pivot {
                check_point(&format!("{f}.pivot"), p)?;
            }
            if body.keyframes.is_empty() {
                return Err(CrowdError::invalid(
                    format!("{f}.keyframes"),
                    "[]",
                    "a moving body needs at least one keyframe",
                ));
            }
            for (k, key) in body.keyframes.iter().enumerate() {
                let kf = format!("{f}.keyframes[{k}]");
                if !(key.t >= 0.0 && key.t.is_finite()) {
                    return Err(CrowdError::invalid(
                        format!("{kf}.t"),
                        Num(key.t),
                        "must be finite and ≥ 0",
                    ));
                }
                if k > 0 && !(key.t > body.keyframes[k - 1].t) {
                    return Err(CrowdError::invalid(
                        format!("{kf}.t"),
                        Num(key.t),
                        format!(
                            "keyframe times must increase (the one before is at {})",
                            Num(body.keyframes[k - 1].t)
                        ),
                    ));
                }
                check_point(&format!("{kf}.offset"), key.offset)?;
                if !(key.angle.is_finite() && key.angle.abs() <= 1e6) {
                    return Err(CrowdError::invalid(
                        format!("{kf}.angle"),
                        Num(key.angle),
                        "must be finite, within ±1e6 degrees",
                    ));
                }
                if k > 0 {
                    // The speed bound β of this interval must be a number.
                    let before = &body.keyframes[k - 1];
                    let points = body.line.iter().chain(&body.polygon).flatten();
                    let pivot = body
                        .pivot
                        .or(body
                            .line
                            .iter()
                            .chain(&body.polygon)
                            .flatten()
                            .next()
                            .copied())
                        .unwrap_or([0.0; 2]);
                    let reach = points
                        .map(|p| (p[0] - pivot[0]).hypot(p[1] - pivot[1]))
                        .fold(0.0, f64::max);
                    let dt = key.t - before.t;
                    let beta = ((key.offset[0] - before.offset[0])
                        .hypot(key.offset[1] - before.offset[1])
                        + (key.angle - before.angle).to_radians().abs() * reach)
                        / dt;
                    if !beta.is_finite() {
                        return Err(CrowdError::invalid(
                            format!("{kf}.t"),
                            Num(key.t),
                            format!(
                                "the body would move at {beta} m/s between t = {} and {}",
                                Num(before.t),
                                Num(key.t)
                            ),
                        ));
                    }
                    // Steps are cut so that no body moves more than half the smallest radius
                    // in one; a body too fast for the shortest step failed the run when it got
                    // there (`Simulation::moving_stop`), after every step before it.
                    let r_min = self.min_radius();
                    let largest = 0.5 * r_min / beta;
                    if !(largest >= crate::sim::MIN_MOVING_STEP) {
                        return Err(CrowdError::invalid(
                            format!("{kf}.t"),
                            Num(key.t),
                            format!(
                                "the body would move at {} m/s between t = {} and {}, which \
                                 needs steps of {largest:.3e} s (half the smallest radius, {} \
                                 m, per step), below the {:e} s a run allows",
                                Num(beta),
                                Num(before.t),
                                Num(key.t),
                                Num(r_min),
                                crate::sim::MIN_MOVING_STEP
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// The walls: edges of the outer polygon (counter-clockwise) and of the holes (clockwise),
    /// so that the walkable side is on the left of every wall.
    pub fn walls(&self) -> Vec<Segment> {
        let outer = Polygon {
            vertices: self.area.outer.clone(),
        }
        .oriented(true);
        let mut walls: Vec<Segment> = outer.edges().collect();
        for h in &self.area.holes {
            walls.extend(
                Polygon {
                    vertices: h.clone(),
                }
                .oriented(false)
                .edges(),
            );
        }
        walls
    }

    /// The walkable area as WKT (`POLYGON ((outer), (hole), ...)`), the form the Pedestrian
    /// Dynamics Data Archive and PedPy's `WalkableArea` read. Rings are closed; `{}` prints
    /// the shortest text that reads back to the same `f64`.
    pub fn wkt(&self) -> String {
        fn ring(points: &[[f64; 2]]) -> String {
            let mut out: Vec<String> = points
                .iter()
                .map(|p| format!("{} {}", p[0], p[1]))
                .collect();
            if let (Some(a), Some(b)) = (points.first(), points.last())
                && a != b
            {
                out.push(format!("{} {}", a[0], a[1]));
            }
            format!("({})", out.join(", "))
        }
        let rings: Vec<String> = std::iter::once(ring(&self.area.outer))
            .chain(self.area.holes.iter().map(|h| ring(h)))
            .collect();
        format!("POLYGON ({})", rings.join(", "))
    }

    /// True when `p` is inside the walkable area.
    pub fn walkable(&self, p: [f64; 2]) -> bool {
        ring_contains(&self.area.outer, p) && !self.area.holes.iter().any(|h| ring_contains(h, p))
    }

    /// The radii of the groups' and the sources' people.
    fn radii(&self) -> impl Iterator<Item = &Quantity> {
        let sources = self.sources.iter().map(|s| &s.radius);
        self.groups.iter().map(|g| &g.radius).chain(sources)
    }

    /// The smallest radius any person can have.
    pub fn min_radius(&self) -> f64 {
        self.radii()
            .map(Quantity::min)
            .fold(f64::INFINITY, f64::min)
    }

    /// The largest radius any person can have.
    pub fn max_radius(&self) -> f64 {
        self.radii().map(Quantity::max).fold(0.0, f64::max)
    }
}
