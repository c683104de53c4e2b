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
}

impl ExitRuntime {
    /// The wall that closes the exit: its segment, or for an area the mid-line of the area's
    /// bounding box along its longer side.
    pub fn closure(&self) -> Segment {
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
        match (&self.area, &self.segment) {
            (Some(a), _) => a.contains(p),
            (None, Some(s)) => s.distance(p) <= r + Self::LINE_REACH,
            _ => false,
        }
    }
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
                format!("no walkable cell of the distance grid lies in the {what}"),
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
            out.exits.push(ExitRuntime {
                area,
                segment,
                action: exit.action,
                target: target.map(|t| t.0),
                open: true,
            });
        }
        Ok(out)
    }
}
