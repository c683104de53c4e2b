//! A crowd run: people placed from the scene, stepped by the catching-up scheme, exits applied.

use std::collections::HashMap;

use moreau_core::Parallelism;
use moreau_core::StepReport;
use moreau_integrate::{
    AdaptiveStep, EpsPolicy, LinearizedProjection, LinearizedSettings, Scheme, StepController,
};
use moreau_solve::{
    Apgd, ApgdSettings, AutoSettings, AutoSolver, ClarabelReference, ClarabelSettings,
    InteriorPoint, InteriorPointSettings, ProjectionSolver,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::broad::{BroadPhaseKind, choose_broad_phase};
use crate::constraints::CrowdConstraints;
use crate::error::CrowdError;
use crate::field::{DesiredVelocity, DistanceField};
use crate::geometry::{Polygon, Segment};
use crate::scene::{BroadPhaseChoice, ExitAction, Quantity, Scene, SolverKind};

/// Where a person is headed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Walking to exit `e`.
    ToExit(usize),
    /// Passed exit `e`, walking to its target area.
    ToTarget(usize),
    /// Inside the target area of exit `e`: standing.
    Arrived(usize),
}

/// An exit as the run uses it.
#[derive(Debug, Clone)]
struct ExitRuntime {
    area: Option<Polygon>,
    segment: Option<Segment>,
    action: ExitAction,
    field: usize,
    target: Option<(Polygon, usize)>,
    open: bool,
}

impl ExitRuntime {
    /// The wall that closes the exit.
    fn closure(&self) -> Segment {
        if let Some(s) = self.segment {
            return s;
        }
        let (lo, hi) = self.area.as_ref().expect("an area or a segment").bounds();
        if hi[1] - lo[1] >= hi[0] - lo[0] {
            let x = 0.5 * (lo[0] + hi[0]);
            Segment {
                a: [x, lo[1]],
                b: [x, hi[1]],
            }
        } else {
            let y = 0.5 * (lo[1] + hi[1]);
            Segment {
                a: [lo[0], y],
                b: [hi[0], y],
            }
        }
    }

    fn reached(&self, p: [f64; 2], r: f64) -> bool {
        if !self.open {
            return false;
        }
        match (&self.area, &self.segment) {
            (Some(a), _) => a.contains(p),
            (None, Some(s)) => s.distance(p) <= r,
            _ => false,
        }
    }
}

/// One recorded configuration.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    /// Time.
    pub t: f64,
    /// Ids of the people present.
    pub ids: &'a [u32],
    /// Their positions `[x0, y0, x1, y1, ...]`.
    pub positions: &'a [f64],
    /// Their radii.
    pub radii: &'a [f64],
}

type CrowdScheme =
    Scheme<DesiredVelocity, LinearizedProjection<CrowdConstraints, Box<dyn ProjectionSolver>>>;

/// A crowd run built from a [`Scene`].
pub struct Simulation {
    scene: Scene,
    exits: Vec<ExitRuntime>,
    scheme: CrowdScheme,
    q: Vec<f64>,
    stage: Vec<Stage>,
    t: f64,
    steps: usize,
    exit_times: Vec<(u32, f64)>,
    total: usize,
    broad: BroadPhaseKind,
    solver: SolverKind,
    /// The walls of the scene, before closed exits add theirs.
    scene_walls: usize,
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("t", &self.t)
            .field("people", &self.stage.len())
            .finish_non_exhaustive()
    }
}

fn draw(q: &Quantity, rng: &mut ChaCha8Rng) -> f64 {
    match *q {
        Quantity::Fixed(x) => x,
        Quantity::Uniform { min, max } => {
            if max > min {
                rng.random_range(min..=max)
            } else {
                min
            }
        }
    }
}

/// Overlap test against people already placed, through a hash of cells of side `2 r_max`.
struct Placed {
    cell: f64,
    cells: HashMap<(i64, i64), Vec<usize>>,
    pos: Vec<[f64; 2]>,
    radius: Vec<f64>,
}

impl Placed {
    fn key(&self, p: [f64; 2]) -> (i64, i64) {
        (
            (p[0] / self.cell).floor() as i64,
            (p[1] / self.cell).floor() as i64,
        )
    }
    fn overlaps(&self, p: [f64; 2], r: f64) -> Option<usize> {
        let (cx, cy) = self.key(p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &j in self
                    .cells
                    .get(&(cx + dx, cy + dy))
                    .map_or(&[][..], |v| v.as_slice())
                {
                    let q = self.pos[j];
                    if ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt() < r + self.radius[j] {
                        return Some(j);
                    }
                }
            }
        }
        None
    }
    fn insert(&mut self, p: [f64; 2], r: f64) {
        let k = self.key(p);
        self.cells.entry(k).or_default().push(self.pos.len());
        self.pos.push(p);
        self.radius.push(r);
    }
}

impl Simulation {
    /// Builds the run: distance fields, initial positions, solver. Every failure names the
    /// scene field at fault.
    pub fn new(scene: Scene) -> Result<Self, CrowdError> {
        scene.validate()?;
        let walls = scene.walls();
        let outer = Polygon {
            vertices: scene.area.outer.clone(),
        };
        let (lo, hi) = outer.bounds();
        let cell = scene.solver.grid_cell;
        let walkable = |p: [f64; 2]| scene.walkable(p);

        // One distance field per exit, one per target area.
        let mut fields = Vec::new();
        let mut exits = Vec::new();
        for (e, exit) in scene.exits.iter().enumerate() {
            let area = exit.area.as_ref().map(|a| Polygon {
                vertices: a.clone(),
            });
            let segment = exit.segment.map(|s| Segment { a: s[0], b: s[1] });
            let goal = |p: [f64; 2]| match (&area, &segment) {
                (Some(a), _) => a.contains(p),
                (None, Some(s)) => s.distance(p) <= 0.75 * cell,
                _ => false,
            };
            let f = DistanceField::build(lo, hi, cell, walkable, goal).ok_or_else(|| {
                CrowdError::invalid(
                    format!("exits[{e}]"),
                    &exit.name,
                    "no walkable cell of the distance grid lies in the exit",
                )
            })?;
            fields.push(f);
            let field = fields.len() - 1;
            let target = match &exit.target {
                Some(t) => {
                    let poly = Polygon {
                        vertices: t.clone(),
                    };
                    let f = DistanceField::build(lo, hi, cell, walkable, |p| poly.contains(p))
                        .ok_or_else(|| {
                            CrowdError::invalid(
                                format!("exits[{e}].target"),
                                format!("{t:?}"),
                                "no walkable cell of the distance grid lies in the target",
                            )
                        })?;
                    fields.push(f);
                    Some((poly, fields.len() - 1))
                }
                None => None,
            };
            exits.push(ExitRuntime {
                area,
                segment,
                action: exit.action,
                field,
                target,
                open: true,
            });
        }

        // People.
        let mut rng = ChaCha8Rng::seed_from_u64(scene.seed);
        let mut placed = Placed {
            cell: (2.0 * scene.max_radius()).max(1e-9),
            cells: HashMap::new(),
            pos: Vec::new(),
            radius: Vec::new(),
        };
        let (mut speed, mut stage) = (Vec::new(), Vec::new());
        let clear_of_walls = |p: [f64; 2], r: f64| walls.iter().all(|w| w.distance(p) >= r);
        for (g, group) in scene.groups.iter().enumerate() {
            let exit = scene
                .exits
                .iter()
                .position(|e| e.name == group.destination)
                .expect("validated");
            let first = placed.pos.len();
            match (&group.positions, group.count, &group.spawn) {
                (Some(list), _, _) => {
                    for (k, &p) in list.iter().enumerate() {
                        let r = draw(&group.radius, &mut rng);
                        let field = format!("groups[{g}].positions[{k}]");
                        if !scene.walkable(p) || !clear_of_walls(p, r) {
                            return Err(CrowdError::invalid(
                                field,
                                format!("{p:?}"),
                                format!(
                                    "a disk of radius {r} there is not inside the walkable area"
                                ),
                            ));
                        }
                        if let Some(j) = placed.overlaps(p, r) {
                            return Err(CrowdError::invalid(
                                field,
                                format!("{p:?}"),
                                format!("overlaps the person at {:?}", placed.pos[j]),
                            ));
                        }
                        placed.insert(p, r);
                    }
                }
                (None, Some(n), Some(region)) => {
                    let region = Polygon {
                        vertices: region.clone(),
                    };
                    let (rlo, rhi) = region.bounds();
                    let budget = 2000 * n + 10_000;
                    let (mut made, mut tries) = (0, 0);
                    let mut r = draw(&group.radius, &mut rng);
                    while made < n && tries < budget {
                        tries += 1;
                        let p = [
                            rng.random_range(rlo[0]..=rhi[0]),
                            rng.random_range(rlo[1]..=rhi[1]),
                        ];
                        if region.contains(p)
                            && scene.walkable(p)
                            && clear_of_walls(p, r)
                            && placed.overlaps(p, r).is_none()
                        {
                            placed.insert(p, r);
                            made += 1;
                            r = draw(&group.radius, &mut rng);
                        }
                    }
                    if made < n {
                        return Err(CrowdError::invalid(
                            format!("groups[{g}].count"),
                            n,
                            format!(
                                "only {made} people fit in the spawn region ({:.2} m²) after {tries} random tries",
                                region.area()
                            ),
                        ));
                    }
                }
                _ => unreachable!("validated"),
            }
            for k in first..placed.pos.len() {
                let p = placed.pos[k];
                if !fields[exits[exit].field].distance(p).is_finite() {
                    return Err(CrowdError::invalid(
                        format!("groups[{g}].destination"),
                        &group.destination,
                        format!("unreachable from {p:?} (no walkable path on the distance grid)"),
                    ));
                }
                speed.push(draw(&group.speed, &mut rng));
                stage.push(Stage::ToExit(exit));
            }
        }
        let n = placed.pos.len();
        if n >= (1 << 31) {
            return Err(CrowdError::invalid("groups", n, "at most 2³¹ − 1 people"));
        }
        // People are numbered along a Z-order curve over cells of two radii of their starting
        // positions, so that people who touch sit close in every per-person array and the
        // solver's products read memory nearly in order (1.3× faster at 100,000 people).
        let order = spatial_order(&placed.pos, placed.cell);
        let q: Vec<f64> = order.iter().flat_map(|&k| placed.pos[k]).collect();
        let ids: Vec<u32> = (0..n as u32).collect();
        let radius: Vec<f64> = order.iter().map(|&k| placed.radius[k]).collect();
        let speed: Vec<f64> = order.iter().map(|&k| speed[k]).collect();
        let stage: Vec<Stage> = order.iter().map(|&k| stage[k]).collect();

        let broad = match scene.solver.broad_phase {
            BroadPhaseChoice::Grid => BroadPhaseKind::Grid,
            BroadPhaseChoice::Bvh => BroadPhaseKind::Bvh,
            BroadPhaseChoice::Auto => choose_broad_phase(scene.min_radius(), scene.max_radius()),
        };
        let goal = stage.iter().map(|s| match *s {
            Stage::ToExit(e) => Some(exits[e].field),
            _ => None,
        });
        let field = DesiredVelocity {
            fields,
            walls: walls.clone(),
            speed,
            radius: radius.clone(),
            goal: goal.collect(),
            speed_factor: 1.0,
        };
        let scene_walls = walls.len();
        let constraints = CrowdConstraints::new(walls, radius, ids, broad.build());
        let settings = LinearizedSettings {
            max_violation: scene.solver.max_violation,
            max_redo: 8,
        };
        let kind = scene.solver.kind;
        let apgd = || -> Result<Box<dyn ProjectionSolver>, CrowdError> {
            Ok(Box::new(
                Apgd::new(
                    ApgdSettings::builder()
                        .parallelism(Parallelism::threads(scene.solver.threads))
                        .build()
                        .map_err(moreau_integrate::IntegrateError::from)?,
                )
                .map_err(moreau_integrate::IntegrateError::from)?,
            ))
        };
        let clarabel = || -> Box<dyn ProjectionSolver> {
            Box::new(ClarabelReference::new(ClarabelSettings::default()))
        };
        let solver: Box<dyn ProjectionSolver> = match kind {
            SolverKind::Apgd => apgd()?,
            SolverKind::Auto => Box::new(
                AutoSolver::new(AutoSettings {
                    parallelism: Parallelism::threads(scene.solver.threads),
                    ..AutoSettings::default()
                })
                .map_err(moreau_integrate::IntegrateError::from)?,
            ),
            SolverKind::Interior => Box::new(
                InteriorPoint::new(
                    InteriorPointSettings::builder()
                        .parallelism(Parallelism::threads(scene.solver.threads))
                        .build()
                        .map_err(moreau_integrate::IntegrateError::from)?,
                )
                .map_err(moreau_integrate::IntegrateError::from)?,
            ),
            SolverKind::Clarabel => clarabel(),
        };
        // The fallback answers when the main solver misses its target: Clarabel while its
        // memory is small, APGD (no factorization) for the largest crowds.
        let fallback = match kind {
            SolverKind::Clarabel => None,
            SolverKind::Apgd => Some(clarabel()),
            _ if n <= SolverKind::CLARABEL_FALLBACK_MAX_PEOPLE => Some(clarabel()),
            _ => Some(apgd()?),
        };
        let mut correction = LinearizedProjection::new(constraints, solver, settings)?;
        if let Some(fallback) = fallback {
            correction = correction.with_fallback(fallback);
        }
        let eps = EpsPolicy::new(scene.solver.eps_kappa, 3.0)?;
        let scheme = Scheme::new(field, correction, eps);
        Ok(Self {
            scene,
            exits,
            scheme,
            q,
            stage,
            t: 0.0,
            steps: 0,
            exit_times: Vec::new(),
            total: n,
            broad,
            solver: kind,
            scene_walls,
        })
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Current time.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Steps taken.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// People at the start.
    pub fn total_people(&self) -> usize {
        self.total
    }

    /// The current configuration.
    pub fn frame(&self) -> Frame<'_> {
        let c = self.scheme.correction().constraints();
        Frame {
            t: self.t,
            ids: &c.ids,
            positions: &self.q,
            radii: &c.radius,
        }
    }

    /// `(id, time)` of everyone who passed an exit so far.
    pub fn exit_times(&self) -> &[(u32, f64)] {
        &self.exit_times
    }

    /// The projection solver in use. `Apgd` has Clarabel as fallback; `Interior` and `Auto`
    /// have Clarabel up to [`SolverKind::CLARABEL_FALLBACK_MAX_PEOPLE`] people, APGD above.
    /// With `Auto` each step report names the solver that answered.
    pub fn solver_kind(&self) -> SolverKind {
        self.solver
    }

    /// The broad phase in use.
    pub fn broad_phase(&self) -> BroadPhaseKind {
        self.broad
    }

    /// The scheme (its correction holds the last step's rows and multipliers, its field the
    /// desired velocities).
    pub fn scheme(&self) -> &CrowdScheme {
        &self.scheme
    }

    /// The scheme, mutably: for benchmarks and tools that time or drive its stages (field,
    /// constraint assembly, the post-step check) one by one between steps.
    pub fn scheme_mut(&mut self) -> &mut CrowdScheme {
        &mut self.scheme
    }

    /// The projection problem of the last step (rows, offsets, prediction), to re-solve it.
    pub fn last_projection(&self) -> moreau_solve::ProjectionProblem<'_> {
        self.scheme
            .correction()
            .last_problem(self.scheme.prediction())
    }

    /// The factor on every desired speed.
    pub fn set_speed_factor(&mut self, factor: f64) {
        self.scheme.field_mut().speed_factor = factor;
    }

    /// One step of size `mu`; then applies exits.
    pub fn step(&mut self, mu: f64) -> Result<StepReport, CrowdError> {
        let report = self.scheme.step(self.steps, self.t, &mut self.q, mu)?;
        self.t = report.t;
        self.steps += 1;
        self.apply_exits();
        Ok(report)
    }

    /// Whether exit `e` is open.
    pub fn exit_open(&self, e: usize) -> Option<bool> {
        self.exits.get(e).map(|x| x.open)
    }

    /// Opens or closes exit `e` (a scene change, from the next step on). A closed exit is a
    /// wall: its segment, or for an area the mid-line of the area's bounding box along its
    /// longer side; nobody passes it, and people standing in it are pushed out to the side
    /// their centre is on. Reopening removes the wall.
    pub fn set_exit_open(&mut self, e: usize, open: bool) -> Result<(), CrowdError> {
        let Some(exit) = self.exits.get_mut(e) else {
            return Err(CrowdError::invalid(
                "exit",
                e,
                format!("the scene has {} exits", self.exits.len()),
            ));
        };
        if exit.open == open {
            return Ok(());
        }
        exit.open = open;
        let mut walls: Vec<Segment> =
            self.scheme.correction().constraints().walls[..self.scene_walls].to_vec();
        for x in self.exits.iter().filter(|x| !x.open) {
            walls.push(x.closure());
        }
        self.scheme.field_mut().walls = walls.clone();
        self.scheme.correction_mut().constraints_mut().walls = walls;
        Ok(())
    }

    /// The smallest gap between two people present, or between a person and a wall (closed
    /// exits included), at the current configuration (m); `+∞` when there is nothing to
    /// touch within `reach` (m).
    pub fn min_gap(&self, reach: f64) -> f64 {
        let c = self.scheme.correction().constraints();
        let mut rows = moreau_core::ConstraintRows::new(self.q.len());
        // Assembling with a margin lists every pair and wall closer than it.
        let mut scratch = CrowdConstraints::new(
            c.walls.clone(),
            c.radius.clone(),
            c.ids.clone(),
            self.broad.build(),
        );
        moreau_core::ConstraintSet::assemble(&mut scratch, self.t, &self.q, reach, &mut rows);
        rows.values().iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// One adaptive step chosen by `controller`, ending at or before `t_end`; then applies
    /// exits (and makes the controller forget velocities when people left).
    pub fn step_adaptive(
        &mut self,
        controller: &mut StepController,
        t_end: f64,
    ) -> Result<AdaptiveStep, CrowdError> {
        let people = self.q.len();
        let step = controller.step(&mut self.scheme, self.steps, self.t, &mut self.q, t_end)?;
        self.t = step.report.t;
        self.steps += 1;
        self.apply_exits();
        if self.q.len() != people {
            controller.reset_history();
        }
        Ok(step)
    }

    /// The steps [`run`](Self::run) takes: `(μ_k, frame after it?)`, the scene's step with the
    /// last one shortened to land on the horizon, and a frame every output interval and at
    /// the end.
    pub fn schedule(&self) -> Vec<(f64, bool)> {
        let time = self.scene.time;
        let n_steps = (time.horizon / time.step - 1e-9).ceil() as usize;
        let every = ((time.output_interval / time.step).round() as usize).max(1);
        (0..n_steps)
            .map(|k| {
                let mu = if k + 1 < n_steps {
                    time.step
                } else {
                    time.horizon - time.step * (n_steps - 1) as f64
                };
                (mu, (k + 1) % every == 0 || k + 1 == n_steps)
            })
            .collect()
    }

    /// Runs to the scene's horizon along [`schedule`](Self::schedule), calling `on_frame` at
    /// the start and at every output frame, and `on_step` after every step. The first error,
    /// of a step or of a callback, ends the run and is returned.
    pub fn run<E: From<CrowdError>>(
        &mut self,
        mut on_step: impl FnMut(&Self, &StepReport) -> Result<(), E>,
        mut on_frame: impl FnMut(Frame<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        on_frame(self.frame())?;
        for (mu, frame) in self.schedule() {
            let report = self.step(mu)?;
            on_step(self, &report)?;
            if frame {
                on_frame(self.frame())?;
            }
        }
        Ok(())
    }

    fn apply_exits(&mut self) {
        let mut keep = Vec::with_capacity(self.stage.len());
        let mut changed = false;
        for i in 0..self.stage.len() {
            let p = [self.q[2 * i], self.q[2 * i + 1]];
            let r = self.scheme.correction().constraints().radius[i];
            let id = self.scheme.correction().constraints().ids[i];
            let mut stays = true;
            match self.stage[i] {
                Stage::ToExit(e) if self.exits[e].reached(p, r) => {
                    self.exit_times.push((id, self.t));
                    changed = true;
                    match (&self.exits[e].action, &self.exits[e].target) {
                        (ExitAction::Continue, Some(_)) => self.stage[i] = Stage::ToTarget(e),
                        _ => stays = false,
                    }
                }
                Stage::ToTarget(e)
                    if self.exits[e]
                        .target
                        .as_ref()
                        .is_some_and(|(t, _)| t.contains(p)) =>
                {
                    self.stage[i] = Stage::Arrived(e);
                    changed = true;
                }
                _ => {}
            }
            keep.push(stays);
        }
        if !changed {
            return;
        }
        let exits = &self.exits;
        let goal: Vec<Option<usize>> = self
            .stage
            .iter()
            .map(|s| match *s {
                Stage::ToExit(e) => Some(exits[e].field),
                Stage::ToTarget(e) => exits[e].target.as_ref().map(|t| t.1),
                Stage::Arrived(_) => None,
            })
            .collect();
        let field = self.scheme.field_mut();
        field.goal = goal;
        if keep.iter().all(|&k| k) {
            return;
        }
        fn retain<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut k = keep.iter();
            v.retain(|_| *k.next().unwrap());
        }
        retain(&mut field.speed, &keep);
        retain(&mut field.radius, &keep);
        retain(&mut field.goal, &keep);
        retain(&mut self.stage, &keep);
        let c = self.scheme.correction_mut().constraints_mut();
        retain(&mut c.radius, &keep);
        retain(&mut c.ids, &keep);
        let mut k = keep.iter().flat_map(|&b| [b, b]);
        self.q.retain(|_| k.next().unwrap());
    }
}

/// The indices of `pos` sorted along a Z-order (Morton) curve over square cells of side
/// `cell`; ties keep their order.
fn spatial_order(pos: &[[f64; 2]], cell: f64) -> Vec<usize> {
    fn spread(mut x: u64) -> u64 {
        x &= 0xffff_ffff;
        x = (x | (x << 16)) & 0x0000_ffff_0000_ffff;
        x = (x | (x << 8)) & 0x00ff_00ff_00ff_00ff;
        x = (x | (x << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
        x = (x | (x << 2)) & 0x3333_3333_3333_3333;
        (x | (x << 1)) & 0x5555_5555_5555_5555
    }
    let lo = pos
        .iter()
        .fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
    let key = |p: &[f64; 2]| {
        let ix = ((p[0] - lo[0]) / cell) as u64;
        let iy = ((p[1] - lo[1]) / cell) as u64;
        spread(ix) | (spread(iy) << 1)
    };
    let mut order: Vec<usize> = (0..pos.len()).collect();
    order.sort_by_key(|&k| key(&pos[k]));
    order
}
