//! Scheduled events of a scene: groups released at a time (`[[groups]] release`) and inflow
//! sources (`[[sources]]`) that bring people in while the run goes. This module owns their
//! scene keys' validation, who is due when, where a newcomer fits, and the sources' state
//! (in [`SimState`](crate::SimState)); the people themselves stay in [`People`].

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use moreau_core::Num;

use crate::error::CrowdError;
use crate::exits::Exits;
use crate::geometry::Polygon;
use crate::people::{People, Place};
use crate::scene::{Quantity, Scene, check_polygon, limits, no_such_exit};
use crate::spawn::draw;
use crate::walls::Walls;

/// An inflow source (`[[sources]]`): people enter its `area` at `rate` a second, person `k`
/// (from 1) due at `start + k / rate`, until `stop` or the horizon (whichever comes first) and
/// at most `count` in all. After every accepted step each person due is placed at a uniformly
/// random point of the area where their disk overlaps nobody and no wall (at most
/// [`Inflow::TRIES`] tries a person a step); when there is no room, they wait in a queue, in
/// order, and enter at later steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Inflow {
    /// Its name.
    pub name: String,
    /// Where people appear (their centres): a polygon inside the walkable area.
    pub area: Vec<[f64; 2]>,
    /// People per second.
    pub rate: f64,
    /// When the inflow starts (s; absent: 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<f64>,
    /// When it stops (s; absent: the horizon).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stop: Option<f64>,
    /// At most this many people in all (absent: no limit but the rate).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// Radius in metres.
    pub radius: Quantity,
    /// Desired speed in m/s.
    pub speed: Quantity,
    /// The name of the exit they walk to.
    pub destination: String,
}

impl Inflow {
    /// Random points tried for one person in one step before they wait for the next step.
    pub const TRIES: usize = 100;

    fn start_time(&self) -> f64 {
        self.start.unwrap_or(0.0)
    }

    /// The time after which nobody more is due: `stop`, or the horizon if earlier.
    fn end_time(&self, horizon: f64) -> f64 {
        self.stop.unwrap_or(horizon).min(horizon)
    }

    /// An upper bound of the people it brings in a run to `horizon` (`rate × (stop − start)`,
    /// one more for rounding, or `count`).
    pub fn most_people(&self, horizon: f64) -> f64 {
        let span = (self.end_time(horizon) - self.start_time()).max(0.0);
        let by_rate = (self.rate * span).floor() + 1.0;
        self.count.map_or(by_rate, |c| by_rate.min(c as f64))
    }
}

/// A person entering the scene from an inflow source.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EntryRecord {
    /// The new person's id (above every id so far).
    pub id: u32,
    /// The source (its index in the scene's `sources`).
    pub source: u32,
    /// When (s): the end of the step after which they were placed.
    pub t: f64,
    /// Their radius (m).
    pub radius: f64,
    /// Their group: the scene's groups by index, then one per source (this one's).
    pub group: u32,
}

/// How far a source kept to its schedule: the people due by now and those who entered. A
/// source whose area has no room (people standing in it, a moving body over it) keeps the
/// rest waiting, in order, so `due − entered` is its queue.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SourceTally {
    /// The source's name.
    pub name: String,
    /// People due by the time reached (at most `count`, none after `stop`).
    pub due: u64,
    /// People who entered.
    pub entered: u64,
}

impl SourceTally {
    /// People due who have not entered: they wait for room in the source's area.
    pub fn waiting(&self) -> u64 {
        self.due - self.entered
    }
}

/// What an inflow source's next steps depend on, in [`SimState`](crate::SimState).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InflowState {
    /// People placed so far.
    pub emitted: u64,
    /// The radius already drawn for the first person waiting, if any.
    pub waiting_radius: Option<f64>,
    /// The position of the source's random stream (`ChaCha8Rng::get_word_pos`; the seed and
    /// stream come from the scene).
    pub rng_word: u128,
}

/// Checks the scheduled events of `scene` (called last by [`Scene::validate`]): release times,
/// every source's fields, and the people the scene can ever hold with its sources.
pub(crate) fn validate(scene: &Scene) -> Result<(), CrowdError> {
    for (g, group) in scene.groups.iter().enumerate() {
        if let Some(t) = group.release
            && !(t.is_finite() && t >= 0.0)
        {
            return Err(CrowdError::invalid(
                format!("groups[{g}].release"),
                Num(t),
                "must be finite and ≥ 0 (s)",
            ));
        }
    }
    let walls = scene.walls();
    let on_wall = |p: [f64; 2]| {
        let tol = 1e-9 * p[0].abs().max(p[1].abs()).max(1.0);
        walls.iter().any(|w| w.distance(p) <= tol)
    };
    let corners: Vec<[f64; 2]> = std::iter::once(&scene.area.outer)
        .chain(&scene.area.holes)
        .flatten()
        .copied()
        .collect();
    let horizon = scene.time.horizon;
    let mut people: f64 = scene
        .groups
        .iter()
        .map(|g| match (&g.positions, g.count) {
            (Some(p), _) => p.len() as f64,
            (None, Some(n)) => n as f64,
            _ => 0.0,
        })
        .sum();
    for (s, source) in scene.sources.iter().enumerate() {
        let f = format!("sources[{s}]");
        if scene.sources[..s].iter().any(|x| x.name == source.name) {
            return Err(CrowdError::invalid(
                format!("{f}.name"),
                &source.name,
                "duplicate source name",
            ));
        }
        if scene.groups.iter().any(|g| g.name == source.name) {
            return Err(CrowdError::invalid(
                format!("{f}.name"),
                &source.name,
                "a group has this name (the run file's /people/group tells groups and \
                 sources apart by name)",
            ));
        }
        let area = check_polygon(&format!("{f}.area"), &source.area)?;
        if let Some(p) = area
            .vertices
            .iter()
            .find(|p| !scene.walkable(**p) && !on_wall(**p))
        {
            return Err(CrowdError::invalid(
                format!("{f}.area"),
                format!("{p:?}"),
                "vertex outside the walkable area (a source's area lies inside it)",
            ));
        }
        if let Some(c) = corners
            .iter()
            .find(|c| area.contains(**c) && area.boundary_distance(**c) > 1e-9)
        {
            return Err(CrowdError::invalid(
                format!("{f}.area"),
                format!("{:?}", source.area),
                format!(
                    "a corner of the walkable area's boundary, {c:?}, lies inside it (a \
                     source's area lies inside the walkable area)"
                ),
            ));
        }
        if !(source.rate.is_finite() && source.rate > 0.0) {
            return Err(CrowdError::invalid(
                format!("{f}.rate"),
                Num(source.rate),
                "must be finite and > 0 (people per second)",
            ));
        }
        let start = source.start_time();
        if !(start.is_finite() && start >= 0.0) {
            return Err(CrowdError::invalid(
                format!("{f}.start"),
                Num(start),
                "must be finite and ≥ 0 (s)",
            ));
        }
        if let Some(stop) = source.stop
            && !(stop.is_finite() && stop > start)
        {
            return Err(CrowdError::invalid(
                format!("{f}.stop"),
                Num(stop),
                format!("must be finite and > start = {}", Num(start)),
            ));
        }
        if source.count == Some(0) {
            return Err(CrowdError::invalid(
                format!("{f}.count"),
                0,
                "a source brings at least one person (leave count out for no limit)",
            ));
        }
        source.radius.check(&format!("{f}.radius"), true)?;
        source.speed.check(&format!("{f}.speed"), false)?;
        if !scene.exits.iter().any(|e| e.name == source.destination) {
            return Err(no_such_exit(
                format!("{f}.destination"),
                &source.destination,
                &scene.exits,
            ));
        }
        people += source.most_people(horizon);
        if people > limits::MAX_PEOPLE {
            let (field, value) = match source.count {
                Some(n) => (format!("{f}.count"), n.to_string()),
                None => (format!("{f}.rate"), Num(source.rate).to_string()),
            };
            return Err(CrowdError::invalid(
                field,
                value,
                format!(
                    "the scene could hold {people:.3e} people (its groups, and each source's \
                     rate × (stop − start) or count), more than the limit of {:e}",
                    limits::MAX_PEOPLE
                ),
            ));
        }
    }
    Ok(())
}

/// One source as a run uses it.
#[derive(Debug, Clone)]
struct SourceRuntime {
    area: Polygon,
    lo: [f64; 2],
    hi: [f64; 2],
    rate: f64,
    start: f64,
    end: f64,
    count: u64,
    radius: Quantity,
    speed: Quantity,
    exit: u32,
    group: u32,
    rng: ChaCha8Rng,
    emitted: u64,
    waiting_radius: Option<f64>,
}

impl SourceRuntime {
    fn due_at(&self, k: u64) -> f64 {
        self.start + k as f64 / self.rate
    }

    /// How many people are due by `t` (a time within `tolerance` of `t` counts as reached), at
    /// most by `end` and at most `count`.
    fn due(&self, t: f64, tolerance: f64) -> u64 {
        let reached = |time: f64, target: f64| target - time <= tolerance;
        let by = |time: f64| {
            let mut k = (self.rate * (time - self.start)).floor().max(0.0) as u64;
            while k > 0 && !reached(time, self.due_at(k)) {
                k -= 1;
            }
            while k < self.count && reached(time, self.due_at(k + 1)) {
                k += 1;
            }
            k
        };
        by(t).min(by(self.end)).min(self.count)
    }
}

/// The scheduled events of a run: release times by group, the sources with their state, and
/// who entered in the last step.
///
/// Times add up steps with rounding (200 steps of 0.05 s end at 10.000000000000007 s, 100 at
/// 4.99999999999999 s), so a time within a billionth of a step of an event's time counts as
/// reached, as the run's stepping counts its stops (`Stepping::reached`).
#[derive(Debug, Clone)]
pub(crate) struct Events {
    /// Per group index (the scene's groups, then one per source): its people stand at times
    /// before it (the group's release less the tolerance on times).
    pub stand_until: Vec<f64>,
    /// Times within this of an event's time count as reached (s): a billionth of a step.
    tolerance: f64,
    sources: Vec<SourceRuntime>,
    /// The people at the start: the first id a source gives.
    first_id: u32,
    /// The largest radius of the scene (how far a newcomer's neighbours can be).
    max_radius: f64,
    /// Who entered after the last accepted step.
    entered: Vec<EntryRecord>,
    // scratch
    near_people: Vec<usize>,
    near_walls: Vec<u32>,
}

impl Events {
    /// The events of `scene`, whose `people` were placed among `walls` at the start. Fails,
    /// naming the field, when a source's area has no room for anybody or no way to its exit.
    pub fn build(
        scene: &Scene,
        walls: &Walls,
        exits: &Exits,
        people: &People,
    ) -> Result<Self, CrowdError> {
        // A billionth of the longest step a run takes (`time.step` may be far longer than the
        // horizon: a tolerance of 2e292 s counted people due forever, found by the fuzzer).
        let t = &scene.time;
        let tolerance = 1e-9 * t.step.min(t.output_interval).min(t.horizon);
        let mut stand_until: Vec<f64> = scene
            .groups
            .iter()
            .map(|g| g.release.unwrap_or(0.0) - tolerance)
            .collect();
        // A source's people walk as soon as they enter.
        stand_until.extend(scene.sources.iter().map(|_| f64::NEG_INFINITY));
        let first_id = u32::try_from(people.len()).expect("at most 2³¹ − 1 people");
        let mut out = Self {
            stand_until,
            tolerance,
            sources: Vec::new(),
            first_id,
            max_radius: scene.max_radius(),
            entered: Vec::new(),
            near_people: Vec::new(),
            near_walls: Vec::new(),
        };
        for (s, source) in scene.sources.iter().enumerate() {
            let exit = scene
                .exits
                .iter()
                .position(|e| e.name == source.destination)
                .expect("validated");
            let area = Polygon {
                vertices: source.area.clone(),
            };
            let (lo, hi) = area.bounds();
            let mut rng = ChaCha8Rng::seed_from_u64(scene.seed);
            rng.set_stream(1 + s as u64);
            let mut runtime = SourceRuntime {
                area,
                lo,
                hi,
                rate: source.rate,
                start: source.start_time(),
                end: source.end_time(scene.time.horizon),
                count: source.count.map_or(u64::MAX, |c| c as u64),
                radius: source.radius,
                speed: source.speed,
                exit: exit as u32,
                group: (scene.groups.len() + s) as u32,
                rng,
                emitted: 0,
                waiting_radius: None,
            };
            out.check_room(scene, walls, exits, s, &runtime)?;
            // The bound of the scene's people is `most_people`: keep to it whatever happens.
            runtime.count = runtime
                .count
                .min(source.most_people(scene.time.horizon) as u64);
            out.sources.push(runtime);
        }
        Ok(out)
    }

    /// Fails unless some point of the source's area (sampled on the distance grid, at least
    /// 8 × 8 points) takes a person of the smallest radius clear of the walls, on a walkable
    /// path to the exit and not already through it.
    fn check_room(
        &mut self,
        scene: &Scene,
        walls: &Walls,
        exits: &Exits,
        s: usize,
        source: &SourceRuntime,
    ) -> Result<(), CrowdError> {
        let r = scene.sources[s].radius.min();
        let cell = scene.solver.grid_cell;
        let (lo, hi) = (source.lo, source.hi);
        let n = |k: usize| (((hi[k] - lo[k]) / cell).ceil() as usize).max(8);
        let (nx, ny) = (n(0), n(1));
        let (mut roomy, mut reachable) = (false, false);
        let exit = &exits.exits[source.exit as usize];
        let field = &exits.fields[exits.goals[source.exit as usize].exit];
        for iy in 0..ny {
            for ix in 0..nx {
                let p = [
                    lo[0] + (ix as f64 + 0.5) / nx as f64 * (hi[0] - lo[0]),
                    lo[1] + (iy as f64 + 0.5) / ny as f64 * (hi[1] - lo[1]),
                ];
                if !(source.area.contains(p) && scene.walkable(p) && self.clear(walls, p, r)) {
                    continue;
                }
                roomy = true;
                if field.distance(p).is_finite() {
                    reachable = true;
                    if !exit.covers(p, r) {
                        return Ok(());
                    }
                }
            }
        }
        let f = format!("sources[{s}]");
        let area = format!("{:?}", scene.sources[s].area);
        Err(if !roomy {
            CrowdError::invalid(
                format!("{f}.area"),
                area,
                format!(
                    "no point of it takes a person of radius {} m clear of the walls",
                    Num(r)
                ),
            )
        } else if !reachable {
            CrowdError::invalid(
                format!("{f}.destination"),
                &scene.sources[s].destination,
                "unreachable from the source's area (no walkable path on the distance grid)",
            )
        } else {
            CrowdError::invalid(
                format!("{f}.area"),
                area,
                format!(
                    "the exit '{}' already counts people out wherever they would enter",
                    scene.sources[s].destination
                ),
            )
        })
    }

    /// Whether a disk of radius `r` at `p` keeps clear of every wall.
    fn clear(&mut self, walls: &Walls, p: [f64; 2], r: f64) -> bool {
        walls.near(p, r, &mut self.near_walls);
        let segments = walls.segments();
        self.near_walls
            .iter()
            .all(|&w| segments[w as usize].distance(p) >= r)
    }

    /// Everyone sources brought in so far.
    pub fn emitted(&self) -> usize {
        self.sources.iter().map(|s| s.emitted as usize).sum()
    }

    /// Each source's people due by `t` and entered (in the scene's order).
    pub fn tallies(&self, t: f64, scene: &Scene) -> Vec<SourceTally> {
        self.sources
            .iter()
            .zip(&scene.sources)
            .map(|(s, source)| SourceTally {
                name: source.name.clone(),
                due: s.due(t, self.tolerance).max(s.emitted),
                entered: s.emitted,
            })
            .collect()
    }

    /// An upper bound of the people the sources can bring in.
    pub fn capacity(&self) -> usize {
        self.sources.iter().map(|s| s.count as usize).sum()
    }

    /// Who entered after the last accepted step.
    pub fn entered(&self) -> &[EntryRecord] {
        &self.entered
    }

    /// After the step that ended at `t`: places the people due by then who fit (in each
    /// source's order, the sources in turn; `blocked(p, r)` says a disk there touches a moving
    /// body), at the end of `people` with the next ids, and returns how many entered.
    pub fn after_step(
        &mut self,
        t: f64,
        people: &mut People,
        scene: &Scene,
        walls: &Walls,
        exits: &Exits,
        blocked: &dyn Fn([f64; 2], f64) -> bool,
    ) -> usize {
        self.entered.clear();
        for s in 0..self.sources.len() {
            let due = self.sources[s].due(t, self.tolerance);
            if self.sources[s].emitted >= due {
                continue;
            }
            // Who could touch a newcomer: the people near the area's bounding box.
            let source = &self.sources[s];
            let reach = source.radius.max() + self.max_radius;
            let (lo, hi) = (source.lo, source.hi);
            self.near_people.clear();
            for i in 0..people.len() {
                let p = people.position(i);
                if p[0] >= lo[0] - reach
                    && p[0] <= hi[0] + reach
                    && p[1] >= lo[1] - reach
                    && p[1] <= hi[1] + reach
                {
                    self.near_people.push(i);
                }
            }
            while self.sources[s].emitted < due {
                let Some((p, r)) = self.find_room(s, people, scene, walls, exits, blocked) else {
                    break;
                };
                let id = self.first_id + self.emitted() as u32;
                let source = &mut self.sources[s];
                let speed = draw(&source.speed, &mut source.rng);
                people.push(id, p, r, speed, source.group, Place::ToExit(source.exit));
                source.emitted += 1;
                source.waiting_radius = None;
                self.near_people.push(people.len() - 1);
                self.entered.push(EntryRecord {
                    id,
                    source: s as u32,
                    t,
                    radius: r,
                    group: self.sources[s].group,
                });
            }
        }
        self.entered.len()
    }

    /// A place for the first person waiting at source `s` (drawing their radius if not yet
    /// drawn): at most [`Inflow::TRIES`] uniform points of the area's bounding box, the first
    /// inside the area and the walkable area where the disk touches no wall and nobody near,
    /// with a walkable path to the exit and not already through it.
    fn find_room(
        &mut self,
        s: usize,
        people: &People,
        scene: &Scene,
        walls: &Walls,
        exits: &Exits,
        blocked: &dyn Fn([f64; 2], f64) -> bool,
    ) -> Option<([f64; 2], f64)> {
        let source = &mut self.sources[s];
        let r = match source.waiting_radius {
            Some(r) => r,
            None => *source
                .waiting_radius
                .insert(draw(&source.radius, &mut source.rng)),
        };
        let exit = &exits.exits[source.exit as usize];
        let field = &exits.fields[exits.goals[source.exit as usize].exit];
        let (positions, radii) = (people.positions(), people.radii());
        for _ in 0..Inflow::TRIES {
            let source = &mut self.sources[s];
            let p = [
                source.rng.random_range(source.lo[0]..=source.hi[0]),
                source.rng.random_range(source.lo[1]..=source.hi[1]),
            ];
            if !(source.area.contains(p) && scene.walkable(p)) {
                continue;
            }
            let overlaps = self.near_people.iter().any(|&j| {
                let (dx, dy) = (p[0] - positions[2 * j], p[1] - positions[2 * j + 1]);
                (dx * dx + dy * dy).sqrt() - r - radii[j] < 0.0
            });
            if overlaps
                || !self.clear(walls, p, r)
                || blocked(p, r)
                || !field.distance(p).is_finite()
                || exit.covers(p, r)
            {
                continue;
            }
            return Some((p, r));
        }
        None
    }

    /// The sources' state.
    pub fn state(&self) -> Vec<InflowState> {
        self.sources
            .iter()
            .map(|s| InflowState {
                emitted: s.emitted,
                waiting_radius: s.waiting_radius,
                rng_word: s.rng.get_word_pos(),
            })
            .collect()
    }

    /// Checks that `state` and `people` (a saved state's) fit these events: one state a
    /// source, no more people than each can bring, every id below the next one to give and
    /// every group one of the scene's; names the first misfit as `(field, value, reason)`.
    pub fn check(
        &self,
        state: &[InflowState],
        people: &People,
    ) -> Result<(), (&'static str, String, String)> {
        if state.len() != self.sources.len() {
            return Err((
                "inflow",
                format!("{} sources", state.len()),
                format!("the scene has {} sources", self.sources.len()),
            ));
        }
        for (s, (x, source)) in state.iter().zip(&self.sources).enumerate() {
            if x.emitted > source.count {
                return Err((
                    "inflow",
                    format!("{} people from source {s}", x.emitted),
                    format!("it brings at most {}", source.count),
                ));
            }
            if x.waiting_radius
                .is_some_and(|r| !(r.is_finite() && r > 0.0))
            {
                return Err((
                    "inflow",
                    format!("{:?}", x.waiting_radius),
                    "a radius is finite and > 0".into(),
                ));
            }
        }
        let next = u64::from(self.first_id) + state.iter().map(|x| x.emitted).sum::<u64>();
        if let Some(&id) = people.ids().last()
            && u64::from(id) >= next
        {
            return Err((
                "people",
                format!("id {id}"),
                format!("the run so far gave ids below {next}"),
            ));
        }
        if let Some(&g) = people
            .groups()
            .iter()
            .find(|&&g| g as usize >= self.stand_until.len())
        {
            return Err((
                "people",
                format!("group {g}"),
                format!(
                    "the scene has {} groups and sources",
                    self.stand_until.len()
                ),
            ));
        }
        Ok(())
    }

    /// Takes up `state` (checked by [`check`](Self::check)).
    pub fn restore(&mut self, state: &[InflowState]) {
        for (source, x) in self.sources.iter_mut().zip(state) {
            source.emitted = x.emitted;
            source.waiting_radius = x.waiting_radius;
            source.rng.set_word_pos(x.rng_word);
        }
        self.entered.clear();
    }
}
