//! Exits as a run uses them: where they are, what passing one does, whether they are open,
//! and the distance fields that lead to them; built once from the scene.

use crate::error::CrowdError;
use crate::field::{DistanceField, ExitGoal, FieldError};
use crate::geometry::{Polygon, Segment};
use crate::scene::{ExitAction, Scene};

/// One exit.
#[derive(Debug, Clone)]
pub(crate) struct ExitRuntime {
    pub area: Option<Polygon>,
    pub segment: Option<Segment>,
    pub action: ExitAction,
    pub target: Option<Polygon>,
    pub open: bool,
    /// The wall that closes it ([`closure`]).
    pub line: Segment,
    /// The segment (in `MovingBodies` order) of the panel that closes the exit on schedule.
    pub panel: Option<usize>,
    /// How much of the exit its panel leaves open.
    pub passage: Passage,
}

/// How much of an exit with a panel is open: an exit line counts people only along the part
/// the panel leaves uncovered; an exit area only while the panel is fully out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Passage {
    /// No panel, or fully out.
    Whole,
    /// The uncovered part of the exit line.
    Part(Segment),
    /// Covered.
    Shut,
}

impl ExitRuntime {
    /// The wall that closes the exit ([`closure`]).
    pub fn closure(&self) -> Segment {
        self.line
    }

    /// How near a person's edge must come to an exit line to pass it (m): the wall slide's
    /// range and 1 cm. A person walking to an exit line on a wall stops being pushed into the
    /// wall [`WALL_RANGE`](crate::DesiredVelocity::WALL_RANGE) short of it, and one pressed
    /// against it keeps the positive gap the projection leaves (up to its certified accuracy
    /// `√ε`, millimetres): with a reach of one radius, neither ever passed.
    pub const LINE_REACH: f64 = crate::DesiredVelocity::WALL_RANGE + 0.01;

    /// Whether a person of radius `r` at `p` has passed the (open) exit: its centre inside the
    /// exit area, or its edge within [`LINE_REACH`](Self::LINE_REACH) of the exit line.
    pub fn reached(&self, p: [f64; 2], r: f64) -> bool {
        if !self.open {
            return false;
        }
        match self.passage {
            Passage::Shut => false,
            Passage::Whole => self.covers(p, r),
            // Through a gap narrower than the person nobody passes (a panel leaving 2.5 cm
            // of a door let people of 0.4 m out). Only exit lines are ever partly open.
            Passage::Part(s) => {
                self.area.is_none()
                    && s.length() >= 2.0 * r
                    && s.distance(p) <= r + Self::LINE_REACH
            }
        }
    }

    /// Whether a person of radius `r` at `p` stands where the exit counts people out once it
    /// is open: [`reached`](Self::reached) whatever the exit's state. Where people start or
    /// enter is checked with it: a group or a source inside an exit that opens later was
    /// taken, and everyone there was counted out at the opening without walking.
    pub fn covers(&self, p: [f64; 2], r: f64) -> bool {
        match (&self.area, &self.segment) {
            (Some(a), _) => a.contains(p),
            (None, Some(s)) => s.distance(p) <= r + Self::LINE_REACH,
            _ => false,
        }
    }

    /// Reads the panel's position from the moving segments where they are now: the panel is
    /// the closing line `a → b` shifted by `s (a − b)`, fully out at `s = 1`, across at `s = 0`;
    /// its tip `b + s (a − b)` leaves `[tip, b]` open.
    pub fn update_passage(&mut self, segments: &[Segment]) {
        let Some(k) = self.panel else {
            return;
        };
        let (line, tip) = (self.closure(), segments[k].b);
        let d = [line.a[0] - line.b[0], line.a[1] - line.b[1]];
        let out = ((tip[0] - line.b[0]) * d[0] + (tip[1] - line.b[1]) * d[1])
            / (d[0] * d[0] + d[1] * d[1]);
        self.passage = if out >= 1.0 - 1e-9 {
            Passage::Whole
        } else if out <= 1e-9 || self.segment.is_none() {
            Passage::Shut
        } else {
            Passage::Part(Segment { a: tip, b: line.b })
        };
    }
}

/// The wall that closes an exit: its segment; for an area, the mid-line of its bounding box
/// across the doorway it fills: of the two mid-lines, the one whose ends lie nearer the
/// scene's `walls` (the door's jambs), the one along the longer side when that does not tell.
/// (Until session 38 always the one along the longer side: the panel of a door 1 m deep and
/// 0.9 m wide ran along the passage, and people walked through the closed door beside it.)
pub(crate) fn closure(
    area: Option<&Polygon>,
    segment: Option<Segment>,
    walls: &[Segment],
) -> Segment {
    if let Some(s) = segment {
        return s;
    }
    let (lo, hi) = area.expect("an area or a segment").bounds();
    let (x, y) = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]));
    let across_x = Segment {
        a: [x, lo[1]],
        b: [x, hi[1]],
    };
    let across_y = Segment {
        a: [lo[0], y],
        b: [hi[0], y],
    };
    let (off_x, off_y) = (
        ends_off_walls(&across_x, walls),
        ends_off_walls(&across_y, walls),
    );
    if off_x < off_y || (off_x == off_y && hi[1] - lo[1] >= hi[0] - lo[0]) {
        across_x
    } else {
        across_y
    }
}

/// How far the farther end of `line` lies from the nearest of `walls`.
pub(crate) fn ends_off_walls(line: &Segment, walls: &[Segment]) -> f64 {
    [line.a, line.b]
        .iter()
        .map(|&p| {
            walls
                .iter()
                .map(|w| w.distance(p))
                .fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max)
}

/// Whether the grid cell centred at `p` is a goal cell of the exit with `area` or `segment`:
/// inside the area, or within ¾ of a cell of the line.
fn is_goal(area: &Option<Polygon>, segment: &Option<Segment>, cell: f64, p: [f64; 2]) -> bool {
    match (area, segment) {
        (Some(a), _) => a.contains(p),
        (None, Some(s)) => s.distance(p) <= 0.75 * cell,
        _ => false,
    }
}

/// The exits of a scene with their distance fields: one per exit, one per target area.
///
/// With moving bodies and `model.field_update`, the fields are rebuilt as the walkable area
/// changes ([`Exits::rebuild_fields`]); a goal that the geometry cuts off gets an
/// [unreachable](DistanceField::unreachable) field until it opens again.
#[derive(Debug, Clone)]
pub(crate) struct Exits {
    pub exits: Vec<ExitRuntime>,
    pub goals: Vec<ExitGoal>,
    pub fields: Vec<DistanceField>,
}

impl Exits {
    /// Solves the distance fields again over the cells whose centres are `walkable` (the
    /// scene's exits and targets as goals); a goal with no walkable cell left, or none a
    /// path reaches, gets an unreachable field.
    pub fn rebuild_fields(&mut self, scene: &Scene, walkable: &dyn Fn([f64; 2]) -> bool) {
        let (lo, hi) = Polygon {
            vertices: scene.area.outer.clone(),
        }
        .bounds();
        let cell = scene.solver.grid_cell;
        for (e, exit) in self.exits.iter().enumerate() {
            let goal = |p: [f64; 2]| is_goal(&exit.area, &exit.segment, cell, p);
            let k = self.goals[e].exit;
            self.fields[k] = DistanceField::build(lo, hi, cell, walkable, goal)
                .unwrap_or_else(|_| self.fields[k].unreachable());
            if let (Some(t), Some(k)) = (&exit.target, self.goals[e].target) {
                self.fields[k] = DistanceField::build(lo, hi, cell, walkable, |p| t.contains(p))
                    .unwrap_or_else(|_| self.fields[k].unreachable());
            }
        }
    }

    /// Builds the exits and solves their distance fields on the scene's grid, over the cells
    /// whose centres are `walkable`.
    pub fn build(scene: &Scene, walkable: &dyn Fn([f64; 2]) -> bool) -> Result<Self, CrowdError> {
        let outer = Polygon {
            vertices: scene.area.outer.clone(),
        };
        let (lo, hi) = outer.bounds();
        let cell = scene.solver.grid_cell;
        let grid_error = |e: FieldError, field: String, value: String, what: &str| match e {
            FieldError::NoGoal => CrowdError::invalid(
                field,
                value,
                format!(
                    "no walkable cell of the distance grid lies in the {what}: make the {what} \
                     wider than a cell or solver.grid_cell (now {}) smaller",
                    moreau_core::Num(cell)
                ),
            ),
            other => CrowdError::invalid(
                "solver.grid_cell",
                moreau_core::Num(cell),
                other.to_string(),
            ),
        };
        let mut out = Self {
            exits: Vec::new(),
            goals: Vec::new(),
            fields: Vec::new(),
        };
        let walls = scene.walls();
        for (e, exit) in scene.exits.iter().enumerate() {
            let area = exit.area.as_ref().map(|a| Polygon {
                vertices: a.clone(),
            });
            let segment = exit.segment.map(|s| Segment { a: s[0], b: s[1] });
            let goal = |p: [f64; 2]| is_goal(&area, &segment, cell, p);
            let f = DistanceField::build(lo, hi, cell, walkable, goal)
                .map_err(|x| grid_error(x, format!("exits[{e}]"), exit.name.clone(), "exit"))?;
            out.fields.push(f);
            let field = out.fields.len() - 1;
            let target = match &exit.target {
                Some(t) => {
                    let poly = Polygon {
                        vertices: t.clone(),
                    };
                    let f = DistanceField::build(lo, hi, cell, walkable, |p| poly.contains(p))
                        .map_err(|x| {
                            grid_error(x, format!("exits[{e}].target"), format!("{t:?}"), "target")
                        })?;
                    out.fields.push(f);
                    Some((poly, out.fields.len() - 1))
                }
                None => None,
            };
            out.goals.push(ExitGoal {
                exit: field,
                target: target.as_ref().map(|t| t.1),
            });
            let line = closure(area.as_ref(), segment, &walls);
            out.exits.push(ExitRuntime {
                area,
                segment,
                line,
                action: exit.action,
                target: target.map(|t| t.0),
                open: true,
                panel: None,
                passage: Passage::Whole,
            });
        }
        Ok(out)
    }
}
