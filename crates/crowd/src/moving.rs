//! Moving geometry: walls, door panels and obstacles with a prescribed motion, their position
//! at any time, the bound `β` on how fast they move (seeds/000 (A2): `|∂ₜg| ≤ β`), and the
//! contact source of people against them.

use moreau_core::ConstraintRows;
use serde::{Deserialize, Serialize};

use crate::contacts::{ContactKind, ContactQuery, ContactSource, push_segment_rows};
use crate::geometry::{Polygon, Segment, ring_contains};
use crate::scene::{Exit, Keyframe, MovingBody, Scene};
use crate::walls::Walls;

/// One body: its segments where the scene file draws them, the pivot its rotation turns about,
/// and its keyframes (time, offset, angle in radians), piecewise linear in time.
#[derive(Debug, Clone)]
struct Body {
    segments: Vec<Segment>,
    /// The ring of a closed body (an obstacle nobody may be inside).
    ring: Option<Vec<[f64; 2]>>,
    pivot: [f64; 2],
    keys: Vec<(f64, [f64; 2], f64)>,
    /// The largest distance of a point of the body from its pivot.
    reach: f64,
}

impl Body {
    fn new(b: &MovingBody) -> Self {
        let (points, closed) = match (&b.line, &b.polygon) {
            (Some(l), _) => (l.clone(), false),
            (None, Some(p)) => (
                Polygon {
                    vertices: p.clone(),
                }
                .oriented(false)
                .vertices,
                true,
            ),
            (None, None) => (Vec::new(), false),
        };
        // The first point as the scene file writes it (a clockwise polygon's points are
        // reversed above: it turned about its last vertex, and the scene's checks about
        // another pivot than the one that ran).
        let first = b
            .line
            .as_ref()
            .or(b.polygon.as_ref())
            .and_then(|p| p.first());
        let pivot = b.pivot.unwrap_or(first.copied().unwrap_or([0.0; 2]));
        let n = points.len();
        let segments: Vec<Segment> = if closed {
            (0..n)
                .map(|i| Segment {
                    a: points[i],
                    b: points[(i + 1) % n],
                })
                .collect()
        } else {
            points
                .windows(2)
                .map(|w| Segment { a: w[0], b: w[1] })
                .collect()
        };
        let reach = points
            .iter()
            .map(|p| ((p[0] - pivot[0]).powi(2) + (p[1] - pivot[1]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        Self {
            segments,
            ring: closed.then_some(points),
            pivot,
            keys: b
                .keyframes
                .iter()
                .map(|k| (k.t, k.offset, k.angle.to_radians()))
                .collect(),
            reach,
        }
    }

    /// Offset and angle at `t`: linear between keyframes, held before the first and after the
    /// last.
    fn pose(&self, t: f64) -> ([f64; 2], f64) {
        let keys = &self.keys;
        let (first, last) = (keys[0], keys[keys.len() - 1]);
        if t <= first.0 {
            return (first.1, first.2);
        }
        if t >= last.0 {
            return (last.1, last.2);
        }
        let k = keys.partition_point(|key| key.0 <= t) - 1;
        let (a, b) = (keys[k], keys[k + 1]);
        let s = (t - a.0) / (b.0 - a.0);
        (
            [
                a.1[0] + s * (b.1[0] - a.1[0]),
                a.1[1] + s * (b.1[1] - a.1[1]),
            ],
            a.2 + s * (b.2 - a.2),
        )
    }

    /// Where the body puts the point `x` of the scene file at pose `(offset, angle)`.
    fn place(&self, (offset, angle): ([f64; 2], f64), x: [f64; 2]) -> [f64; 2] {
        let (s, c) = angle.sin_cos();
        let d = [x[0] - self.pivot[0], x[1] - self.pivot[1]];
        [
            self.pivot[0] + offset[0] + c * d[0] - s * d[1],
            self.pivot[1] + offset[1] + s * d[0] + c * d[1],
        ]
    }

    /// A bound on the speed of every point of the body over `[t0, t1]`: on each keyframe
    /// interval, translation speed plus angular speed times the reach.
    fn max_speed(&self, t0: f64, t1: f64) -> f64 {
        self.keys
            .windows(2)
            .filter(|w| w[1].0 > t0 && w[0].0 < t1)
            .map(|w| {
                let dt = w[1].0 - w[0].0;
                let dx = w[1].1[0] - w[0].1[0];
                let dy = w[1].1[1] - w[0].1[1];
                ((dx * dx + dy * dy).sqrt() + (w[1].2 - w[0].2).abs() * self.reach) / dt
            })
            .fold(0.0, f64::max)
    }
}

/// A body driven from outside (a co-simulation input) instead of by the clock: its keyframe
/// parameter goes linearly from `s0` at `t0` to `s1` at `t1`, and stays at `s1` after.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Drive {
    /// Start of the interval (s).
    pub t0: f64,
    /// Keyframe parameter at `t0`.
    pub s0: f64,
    /// End of the interval (s).
    pub t1: f64,
    /// Keyframe parameter at `t1`.
    pub s1: f64,
}

impl Drive {
    fn param(&self, t: f64) -> f64 {
        if t >= self.t1 || self.t1 <= self.t0 {
            self.s1
        } else if t <= self.t0 {
            self.s0
        } else {
            self.s0 + (self.s1 - self.s0) * (t - self.t0) / (self.t1 - self.t0)
        }
    }
}

/// The moving bodies of a scene; their segments are numbered body after body, in the order the
/// scene lists them (the `b` of a [`ContactKind::MovingWall`] key). Each follows its keyframes
/// in time, or, once [driven](Self::drive), in a parameter set from outside.
#[derive(Debug, Clone, Default)]
pub struct MovingBodies {
    bodies: Vec<Body>,
    names: Vec<String>,
    drives: Vec<Option<Drive>>,
}

impl MovingBodies {
    /// The bodies of `scene` (validated): its `[[moving]]` ones, then a panel for every exit
    /// that `closes` or `opens` (see `exit_panel`).
    pub fn new(scene: &Scene) -> Self {
        let all: Vec<MovingBody> = scene
            .moving
            .iter()
            .cloned()
            .chain({
                let walls = scene.walls();
                scene
                    .exits
                    .iter()
                    .filter_map(move |e| exit_panel(e, &walls))
                    .collect::<Vec<_>>()
            })
            .collect();
        Self {
            bodies: all.iter().map(Body::new).collect(),
            names: all.iter().map(|b| b.name.clone()).collect(),
            drives: vec![None; all.len()],
        }
    }

    /// The keyframe parameter of body `b` at time `t`: `t` itself, or its drive's.
    pub fn param(&self, b: usize, t: f64) -> f64 {
        match &self.drives[b] {
            None => t,
            Some(d) => d.param(t),
        }
    }

    /// From now on body `b` is driven: its keyframe parameter goes linearly from its value at
    /// `t0` to `s1` at `t1` (so it moves continuously), and stays there. A co-simulation sets
    /// it before every step of its own (`t1` the end of that step).
    pub fn drive(&mut self, b: usize, t0: f64, t1: f64, s1: f64) {
        let s0 = self.param(b, t0);
        self.drives[b] = Some(Drive { t0, s0, t1, s1 });
    }

    /// The drives of the bodies (`None`: following the clock), for a saved state.
    pub fn drives(&self) -> &[Option<Drive>] {
        &self.drives
    }

    /// Restores [`drives`](Self::drives).
    pub fn set_drives(&mut self, drives: &[Option<Drive>]) {
        self.drives.copy_from_slice(drives);
    }

    /// True when the scene has none.
    pub fn is_empty(&self) -> bool {
        self.bodies.is_empty()
    }

    /// Their names, in order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// How many segments in all.
    pub fn segment_count(&self) -> usize {
        self.bodies.iter().map(|b| b.segments.len()).sum()
    }

    /// The body of each segment, in segment order.
    pub fn segment_bodies(&self) -> impl Iterator<Item = u32> + '_ {
        self.bodies
            .iter()
            .enumerate()
            .flat_map(|(k, b)| std::iter::repeat_n(k as u32, b.segments.len()))
    }

    /// Each body's keyframe parameter at time `t` into `out` (cleared first).
    pub fn params_at(&self, t: f64, out: &mut Vec<f64>) {
        out.clear();
        out.extend((0..self.bodies.len()).map(|k| self.param(k, t)));
    }

    /// Every segment at time `t` into `out` (cleared first), in segment order.
    pub fn segments_at(&self, t: f64, out: &mut Vec<Segment>) {
        self.place_segments(|k| self.param(k, t), out);
    }

    /// Every segment with body `k` at keyframe parameter `params[k]` into `out`.
    pub fn segments_with(&self, params: &[f64], out: &mut Vec<Segment>) {
        self.place_segments(|k| params[k], out);
    }

    fn place_segments(&self, param: impl Fn(usize) -> f64, out: &mut Vec<Segment>) {
        out.clear();
        for (k, b) in self.bodies.iter().enumerate() {
            let pose = b.pose(param(k));
            out.extend(b.segments.iter().map(|s| Segment {
                a: b.place(pose, s.a),
                b: b.place(pose, s.b),
            }));
        }
    }

    /// True when `p` is inside a closed body at time `t`.
    pub fn inside(&self, t: f64, p: [f64; 2]) -> bool {
        self.inside_placed(|k| self.param(k, t), p)
    }

    /// True when `p` is inside a closed body, body `k` at keyframe parameter `params[k]`.
    pub fn inside_with(&self, params: &[f64], p: [f64; 2]) -> bool {
        self.inside_placed(|k| params[k], p)
    }

    fn inside_placed(&self, param: impl Fn(usize) -> f64, p: [f64; 2]) -> bool {
        self.bodies.iter().enumerate().any(|(k, b)| {
            b.ring.as_ref().is_some_and(|ring| {
                // Move the point back into the body's own frame instead of moving the ring.
                let (offset, angle) = b.pose(param(k));
                let (s, c) = angle.sin_cos();
                let d = [p[0] - b.pivot[0] - offset[0], p[1] - b.pivot[1] - offset[1]];
                let x = [
                    b.pivot[0] + c * d[0] + s * d[1],
                    b.pivot[1] - s * d[0] + c * d[1],
                ];
                ring_contains(ring, x)
            })
        })
    }

    /// `β` over `[t0, t1]`: no point of any body moves faster (m/s); 0 when none moves.
    pub fn max_speed(&self, t0: f64, t1: f64) -> f64 {
        self.bodies
            .iter()
            .enumerate()
            .map(|(k, b)| match &self.drives[k] {
                None => b.max_speed(t0, t1),
                // The parameter runs at |ds/dt| over the drive's interval, 0 outside it.
                Some(d) if d.t1 > d.t0 && t1 > d.t0 && t0 < d.t1 => {
                    let rate = (d.s1 - d.s0).abs() / (d.t1 - d.t0);
                    let (a, z) = (d.param(t0.max(d.t0)), d.param(t1.min(d.t1)));
                    rate * b.max_speed(a.min(z), a.max(z))
                }
                Some(_) => 0.0,
            })
            .fold(0.0, f64::max)
    }

    /// The times at which some body starts or stops moving or changes its motion (its keyframe
    /// times), in increasing order without repeats.
    pub fn key_times(&self) -> Vec<f64> {
        let mut t: Vec<f64> = self
            .bodies
            .iter()
            .flat_map(|b| b.keys.iter().map(|k| k.0))
            .collect();
        t.sort_by(f64::total_cmp);
        t.dedup();
        t
    }
}

/// The panel of an exit that `closes` or `opens` over an interval: a body `exit:NAME` along the
/// exit's closing line `a → b`, which is the line itself when closed and shifted by `a − b`
/// (beyond `a`, into the wall of a door) when open.
pub fn exit_panel(exit: &Exit, walls: &[Segment]) -> Option<MovingBody> {
    if exit.closes.is_none() && exit.opens.is_none() {
        return None;
    }
    let area = exit.area.as_ref().map(|a| Polygon {
        vertices: a.clone(),
    });
    let line = crate::exits::closure(
        area.as_ref(),
        exit.segment.map(|s| Segment { a: s[0], b: s[1] }),
        walls,
    );
    let open = [line.a[0] - line.b[0], line.a[1] - line.b[1]];
    let key = |t: f64, offset: [f64; 2]| Keyframe {
        t,
        offset,
        angle: 0.0,
    };
    let mut moves: Vec<(f64, f64, [f64; 2], [f64; 2])> = Vec::new();
    if let Some([t0, t1]) = exit.closes {
        moves.push((t0, t1, open, [0.0; 2]));
    }
    if let Some([t0, t1]) = exit.opens {
        moves.push((t0, t1, [0.0; 2], open));
    }
    moves.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut keyframes: Vec<Keyframe> = Vec::new();
    for (t0, t1, from, to) in moves {
        if keyframes.last().is_none_or(|k| k.t < t0) {
            keyframes.push(key(t0, from));
        }
        keyframes.push(key(t1, to));
    }
    Some(MovingBody {
        name: format!("exit:{}", exit.name),
        line: Some(vec![line.a, line.b]),
        polygon: None,
        pivot: None,
        keyframes,
    })
}

/// People against the moving bodies' segments at the query's time: `g(t, q) = dist(q_i,
/// segment(t)) − r_i` with its exact gradient at `t`. The segments are placed and indexed
/// ([`Walls`]) once per call: a few per scene, against every person.
#[derive(Debug, Default)]
pub struct PersonMovingWalls {
    at: Vec<Segment>,
    index: Walls,
    near: Vec<u32>,
}

impl ContactSource for PersonMovingWalls {
    fn name(&self) -> &'static str {
        "person-moving-wall"
    }

    fn assemble(&mut self, at: &ContactQuery<'_>, rows: &mut ConstraintRows) {
        if at.moving.is_empty() {
            return;
        }
        let mut segments = std::mem::take(&mut self.at);
        at.moving.segments_at(at.t, &mut segments);
        self.index = Walls::new(segments);
        push_segment_rows(
            ContactKind::MovingWall,
            at,
            &self.index,
            &mut self.near,
            rows,
        );
        self.at = self.index.take_segments();
    }

    /// `dist(q_i, segment(t)) − r_i`, at a fixed time.
    fn people_per_gap(&self) -> Option<usize> {
        Some(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Keyframe;

    fn body(keys: &[(f64, [f64; 2], f64)]) -> MovingBody {
        MovingBody {
            name: "b".into(),
            line: Some(vec![[1.0, 0.0], [2.0, 0.0]]),
            polygon: None,
            pivot: Some([0.0, 0.0]),
            keyframes: keys
                .iter()
                .map(|&(t, offset, angle)| Keyframe { t, offset, angle })
                .collect(),
        }
    }

    #[test]
    fn poses_are_linear_between_keyframes_and_held_outside() {
        let b = Body::new(&body(&[(1.0, [0.0, 0.0], 0.0), (3.0, [2.0, 0.0], 90.0)]));
        let p = |t| b.place(b.pose(t), [1.0, 0.0]);
        assert_eq!(p(0.0), [1.0, 0.0]);
        assert_eq!(p(1.0), [1.0, 0.0]);
        let mid = p(2.0);
        let s = std::f64::consts::FRAC_1_SQRT_2;
        assert!((mid[0] - (1.0 + s)).abs() < 1e-15 && (mid[1] - s).abs() < 1e-15);
        let end = p(5.0);
        assert!((end[0] - 2.0).abs() < 1e-15 && (end[1] - 1.0).abs() < 1e-15);
        // 1 m/s translation + (π/2)/2 rad/s × reach 2 m.
        let beta = b.max_speed(0.0, 10.0);
        assert!((beta - (1.0 + std::f64::consts::PI / 2.0)).abs() < 1e-12);
        assert_eq!(b.max_speed(3.0, 10.0), 0.0);
        assert_eq!(b.max_speed(0.0, 1.0), 0.0);
    }

    #[test]
    fn a_counter_clockwise_polygon_turned_about_its_last_vertex() {
        // No pivot: the first point as written, (10, 5). The points are stored clockwise, so
        // a counter-clockwise polygon's were reversed, and it turned about (10, 6).
        let b = Body::new(&MovingBody {
            name: "b".into(),
            line: None,
            polygon: Some(vec![[10.0, 5.0], [12.0, 5.0], [12.0, 6.0], [10.0, 6.0]]),
            pivot: None,
            keyframes: vec![
                Keyframe {
                    t: 0.0,
                    offset: [0.0, 0.0],
                    angle: 0.0,
                },
                Keyframe {
                    t: 1.0,
                    offset: [0.0, 0.0],
                    angle: 90.0,
                },
            ],
        });
        assert_eq!(b.pivot, [10.0, 5.0]);
        assert_eq!(b.place(b.pose(1.0), [10.0, 5.0]), [10.0, 5.0]);
        let far = b.place(b.pose(1.0), [12.0, 6.0]);
        assert!(
            (far[0] - 9.0).abs() < 1e-12 && (far[1] - 7.0).abs() < 1e-12,
            "{far:?}"
        );
    }

    #[test]
    fn the_speed_bound_holds_on_every_point() {
        let b = Body::new(&body(&[
            (0.0, [0.0, 0.0], 0.0),
            (0.5, [0.3, -0.2], 40.0),
            (2.0, [1.0, 1.0], -30.0),
        ]));
        let beta = b.max_speed(0.0, 2.0);
        let h = 1e-4;
        let mut fastest: f64 = 0.0;
        for k in 0..20000 {
            let t = k as f64 * h;
            for x in [[1.0, 0.0], [1.5, 0.0], [2.0, 0.0]] {
                let (p0, p1) = (b.place(b.pose(t), x), b.place(b.pose(t + h), x));
                fastest =
                    fastest.max(((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2)).sqrt() / h);
            }
        }
        assert!(fastest <= beta * (1.0 + 1e-9), "{fastest} > β = {beta}");
        assert!(
            fastest >= 0.5 * beta,
            "β = {beta} is far from the fastest {fastest}"
        );
    }
}
