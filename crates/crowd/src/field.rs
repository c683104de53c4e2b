//! Desired velocities: geodesic distance to each goal (fast marching) and its descent direction.

use std::sync::Mutex;

use moreau_core::{Field, Parallelism};
use ndarray::Array2;

use crate::people::{PeopleView, Place};
use crate::scene::DesiredVelocityKind;
use crate::walls::Walls;

/// Why a distance field could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FieldError {
    /// The grid would have more cells than [`limits::MAX_FIELD_CELLS`](crate::limits::MAX_FIELD_CELLS)
    /// (checked before anything is allocated).
    #[error(
        "the distance grid over {} m × {} m with cells of {} m would have \
         {cells:.3e} cells, more than the limit of {limit:e}",
        moreau_core::Num(*width),
        moreau_core::Num(*height),
        moreau_core::Num(*cell)
    )]
    TooManyCells {
        /// Width of the box (m).
        width: f64,
        /// Height of the box (m).
        height: f64,
        /// The cell size (m).
        cell: f64,
        /// The cells it would take.
        cells: f64,
        /// The limit.
        limit: f64,
    },
    /// The cell size is not finite and > 0, or the box is not finite.
    #[error(
        "cell {} m over [{lo:?}, {hi:?}]: needs a finite box and a finite cell > 0",
        moreau_core::Num(*cell)
    )]
    Invalid {
        /// Lower corner.
        lo: [f64; 2],
        /// Upper corner.
        hi: [f64; 2],
        /// The cell size.
        cell: f64,
    },
    /// No walkable cell's centre is in the goal.
    #[error("no walkable cell of the distance grid lies in the goal")]
    NoGoal,
}

/// The geodesic distance to a goal around walls and obstacles, on a grid of square cells, with
/// the unit descent direction at every cell centre.
#[derive(Debug, Clone)]
pub struct DistanceField {
    origin: [f64; 2],
    cell: f64,
    nx: usize,
    ny: usize,
    dist: Vec<f64>,
    dir: Vec<[f64; 2]>,
}

impl DistanceField {
    /// Solves the eikonal equation `|∇D| = 1` on the cells of `[lo, hi]` whose centres are
    /// `walkable`, with `D = 0` on the walkable cells whose centres satisfy `goal`.
    /// Fails, before allocating anything, when the grid would have more than
    /// [`limits::MAX_FIELD_CELLS`](crate::limits::MAX_FIELD_CELLS) cells; and when no walkable
    /// cell is in the goal.
    pub fn build(
        lo: [f64; 2],
        hi: [f64; 2],
        cell: f64,
        walkable: impl Fn([f64; 2]) -> bool,
        goal: impl Fn([f64; 2]) -> bool,
    ) -> Result<Self, FieldError> {
        let finite = lo.iter().chain(&hi).all(|x| x.is_finite());
        if !(finite && cell > 0.0 && cell.is_finite() && hi[0] >= lo[0] && hi[1] >= lo[1]) {
            return Err(FieldError::Invalid { lo, hi, cell });
        }
        let cells = crate::scene::grid_cells(lo, hi, cell);
        let limit = crate::limits::MAX_FIELD_CELLS;
        if !(cells <= limit) {
            return Err(FieldError::TooManyCells {
                width: hi[0] - lo[0],
                height: hi[1] - lo[1],
                cell,
                cells,
                limit,
            });
        }
        let nx = ((hi[0] - lo[0]) / cell).ceil().max(1.0) as usize;
        let ny = ((hi[1] - lo[1]) / cell).ceil().max(1.0) as usize;
        let center = |ix: usize, iy: usize| {
            [
                lo[0] + (ix as f64 + 0.5) * cell,
                lo[1] + (iy as f64 + 0.5) * cell,
            ]
        };
        let mut blocked = Array2::from_elem((ny, nx), true);
        let mut sources = Vec::new();
        for iy in 0..ny {
            for ix in 0..nx {
                let c = center(ix, iy);
                if walkable(c) {
                    blocked[[iy, ix]] = false;
                    if goal(c) {
                        sources.push((iy, ix));
                    }
                }
            }
        }
        if sources.is_empty() {
            return Err(FieldError::NoGoal);
        }
        let cost = eikonal::CostField::with_obstacles(&blocked);
        let solved = eikonal::solve_multi(&cost, &sources).map_err(|_| FieldError::NoGoal)?;
        let d = solved.distance();
        let dist: Vec<f64> = (0..ny * nx).map(|k| d[[k / nx, k % nx]] * cell).collect();
        let at = |ix: i64, iy: i64| -> f64 {
            if ix < 0 || iy < 0 || ix >= nx as i64 || iy >= ny as i64 {
                f64::INFINITY
            } else {
                dist[iy as usize * nx + ix as usize]
            }
        };
        // Descent direction: central differences where both neighbours are walkable,
        // one-sided towards the walkable one otherwise (so it never points into a wall cell).
        let slope = |here: f64, minus: f64, plus: f64| -> f64 {
            match (minus.is_finite(), plus.is_finite()) {
                (true, true) => (plus - minus) / (2.0 * cell),
                (true, false) => (here - minus) / cell,
                (false, true) => (plus - here) / cell,
                (false, false) => 0.0,
            }
        };
        let mut dir = vec![[0.0; 2]; nx * ny];
        for iy in 0..ny as i64 {
            for ix in 0..nx as i64 {
                let here = at(ix, iy);
                if !here.is_finite() {
                    continue;
                }
                let gx = slope(here, at(ix - 1, iy), at(ix + 1, iy));
                let gy = slope(here, at(ix, iy - 1), at(ix, iy + 1));
                let norm = (gx * gx + gy * gy).sqrt();
                if norm > 0.0 {
                    dir[iy as usize * nx + ix as usize] = [-gx / norm, -gy / norm];
                }
            }
        }
        Ok(Self {
            origin: lo,
            cell,
            nx,
            ny,
            dist,
            dir,
        })
    }

    /// A field over the same grid with no way to the goal: infinite distance and no direction
    /// everywhere (people heading there stand, and can be pushed).
    pub fn unreachable(&self) -> Self {
        Self {
            origin: self.origin,
            cell: self.cell,
            nx: self.nx,
            ny: self.ny,
            dist: vec![f64::INFINITY; self.dist.len()],
            dir: vec![[0.0; 2]; self.dir.len()],
        }
    }

    fn cell_of(&self, p: [f64; 2]) -> Option<(usize, usize)> {
        let fx = (p[0] - self.origin[0]) / self.cell;
        let fy = (p[1] - self.origin[1]) / self.cell;
        // Truncation is the floor where it is taken (f ≥ 0).
        if fx >= 0.0 && fy >= 0.0 && fx < self.nx as f64 && fy < self.ny as f64 {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }

    /// The distance at the cell containing `p` (∞ outside the walkable cells).
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        self.cell_of(p)
            .map_or(f64::INFINITY, |(ix, iy)| self.dist[iy * self.nx + ix])
    }

    /// The distance at `p` blended bilinearly from the four nearest cell centres, walkable
    /// cells only (their weights renormalized): Lipschitz in `p` where a walkable cell is
    /// near, unlike [`Self::distance`], which is constant on each cell and jumps between
    /// them. ∞ where no walkable cell is near.
    pub fn interpolated_distance(&self, p: [f64; 2]) -> f64 {
        let (mut acc, mut weight) = (0.0, 0.0);
        for (cell, w) in self.corners(p) {
            let Some(k) = cell else { continue };
            let d = self.dist[k];
            if d.is_finite() && w > 0.0 {
                acc += w * d;
                weight += w;
            }
        }
        if weight > 0.0 {
            acc / weight
        } else {
            f64::INFINITY
        }
    }

    /// The four cells whose centres surround `p`, each with its bilinear weight, in a fixed
    /// order; `None` for one off the grid.
    #[inline]
    fn corners(&self, p: [f64; 2]) -> [(Option<usize>, f64); 4] {
        let fx = (p[0] - self.origin[0]) / self.cell - 0.5;
        let fy = (p[1] - self.origin[1]) / self.cell - 0.5;
        let (x0, y0) = (floor(fx), floor(fy));
        let (tx, ty) = (fx - x0, fy - y0);
        let at = |dx: i64, dy: i64| {
            let (ix, iy) = (x0 as i64 + dx, y0 as i64 + dy);
            (ix >= 0 && iy >= 0 && ix < self.nx as i64 && iy < self.ny as i64)
                .then(|| iy as usize * self.nx + ix as usize)
        };
        [
            (at(0, 0), (1.0 - tx) * (1.0 - ty)),
            (at(1, 0), tx * (1.0 - ty)),
            (at(0, 1), (1.0 - tx) * ty),
            (at(1, 1), tx * ty),
        ]
    }

    /// Asks the processor to bring the cells [`Self::direction`]`(p)` reads into its cache;
    /// changes no result.
    #[inline]
    pub fn prefetch(&self, p: [f64; 2]) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let fx = (p[0] - self.origin[0]) / self.cell - 0.5;
            let fy = (p[1] - self.origin[1]) / self.cell - 0.5;
            let (x0, y0) = (floor(fx), floor(fy));
            if !(x0 >= 0.0 && y0 >= 0.0 && x0 < self.nx as f64 && y0 < self.ny as f64) {
                return;
            }
            let (ix, iy) = (x0 as usize, y0 as usize);
            for row in [iy, (iy + 1).min(self.ny - 1)] {
                let cell = &self.dir[row * self.nx + ix];
                // SAFETY: a prefetch only hints the cache: it reads nothing the program sees
                // and cannot fault (the address is a cell of the grid besides).
                #[allow(unsafe_code)]
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>((cell as *const [f64; 2]).cast::<i8>());
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = p;
    }

    /// The descent direction at `p`: bilinear blend of the four nearest cell directions
    /// (walkable cells only), normalized; zero where no walkable cell is near.
    pub fn direction(&self, p: [f64; 2]) -> [f64; 2] {
        let mut acc = [0.0; 2];
        for (cell, w) in self.corners(p) {
            let Some(k) = cell else { continue };
            let d = self.dir[k];
            acc[0] += w * d[0];
            acc[1] += w * d[1];
        }
        let n = (acc[0] * acc[0] + acc[1] * acc[1]).sqrt();
        if n > 1e-12 {
            [acc[0] / n, acc[1] / n]
        } else {
            [0.0, 0.0]
        }
    }
}

/// People whose cells of the distance field [`DesiredVelocity::eval`] asks the processor to
/// fetch ahead of their turn: the field's cells (2 MB on cromosim's scene) are read at random
/// and had left the cache since the last step, each read a wait of ~100 ns.
const PREFETCH_AHEAD: usize = 8;

/// `x.floor()` inlined (x86-64 has no floor instruction before SSE4.1, and the call into libm
/// was 3 % of a step at a million people); exact for |x| < 2⁶³.
#[inline]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// The distance fields a person's place leads to: exit `e`'s own, and its target area's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExitGoal {
    /// Index of the field of the distance to the exit.
    pub exit: usize,
    /// Index of the field of the distance to the exit's target area, if it has one.
    pub target: Option<usize>,
}

/// The desired velocity `U(q)` of every person: speed × descent direction of the distance to
/// the person's current goal, slid along any wall the person is touching so that it never
/// points into a wall. Persons without a goal stand still, and so do the people of a group not
/// yet released (at `t` before its release time). Borrowed for a step from the people, the
/// walls, the distance fields and the release times.
#[derive(Debug)]
pub struct DesiredVelocity<'a> {
    /// The distance fields.
    pub fields: &'a [DistanceField],
    /// Per exit, its fields.
    pub goals: &'a [ExitGoal],
    /// The walls.
    pub walls: &'a Walls,
    /// The people.
    pub people: PeopleView<'a>,
    /// Per group index (`PeopleView::group`): its people stand at times before it (s; the
    /// group's release).
    pub stand_until: &'a [f64],
    /// Multiplies every desired speed (an input of co-simulation).
    pub speed_factor: f64,
    /// Classic (jumps at the wall slide and on arrival) or Lipschitz.
    pub kind: DesiredVelocityKind,
    /// Scratch for the walls near a person: the caller's thread's first, then one for each
    /// other band (grown to the bands' count, kept from step to step).
    pub near: &'a Mutex<Vec<Vec<u32>>>,
    /// Threads: from a thousand people on, two bands of them, the second on `helper`; from
    /// ten thousand on, one band a thread (each with scratch of its own); every person's
    /// velocity is the same whoever computes it.
    pub parallelism: Parallelism,
    /// The helper thread for the second band (without one, a thread of its own).
    pub helper: Option<&'a moreau_core::Helper>,
}

impl DesiredVelocity<'_> {
    /// How close to a wall (beyond the radius) the sliding starts.
    pub const WALL_RANGE: f64 = 0.05;
    /// Over how much distance to its target area a person slows down (Lipschitz kind).
    pub const ARRIVAL_RANGE: f64 = 1.0;

    /// The distance field person `i` descends, if any.
    pub fn goal(&self, i: usize) -> Option<usize> {
        match self.people.place[i] {
            Place::ToExit(e) => Some(self.goals[e as usize].exit),
            Place::ToTarget(e) => self.goals[e as usize].target,
            Place::Arrived(_) => None,
        }
    }

    /// The desired velocity of person `i` at `p`.
    pub fn velocity(&self, i: usize, p: [f64; 2], near: &mut Vec<u32>) -> [f64; 2] {
        let Some(g) = self.goal(i) else {
            return [0.0, 0.0];
        };
        let lipschitz = self.kind == DesiredVelocityKind::Lipschitz;
        let mut d = self.fields[g].direction(p);
        let mut slow = 1.0;
        if lipschitz && matches!(self.people.place[i], Place::ToTarget(_)) {
            // (Interpolated: the cell's own distance made the slowing a staircase of
            // 0.1 m/s steps, not Lipschitz.)
            slow = (self.fields[g].interpolated_distance(p) / Self::ARRIVAL_RANGE).clamp(0.0, 1.0);
        }
        let r = self.people.radius[i];
        self.walls.near(p, r + Self::WALL_RANGE, near);
        let segments = self.walls.segments();
        for &w in near.iter() {
            let c = segments[w as usize].closest(p);
            let (ex, ey) = (p[0] - c[0], p[1] - c[1]);
            let dist = (ex * ex + ey * ey).sqrt();
            if dist > r + Self::WALL_RANGE || dist == 0.0 {
                continue;
            }
            let n = [ex / dist, ey / dist];
            let into = d[0] * n[0] + d[1] * n[1];
            if into < 0.0 {
                // Classic: all of it at once; Lipschitz: fading in from r + WALL_RANGE to r.
                let share = if lipschitz {
                    ((r + Self::WALL_RANGE - dist) / Self::WALL_RANGE).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                d = [d[0] - share * into * n[0], d[1] - share * into * n[1]];
            }
        }
        let s = self.people.speed[i] * self.speed_factor * slow;
        [s * d[0], s * d[1]]
    }
}

impl Field for DesiredVelocity<'_> {
    fn dim(&self) -> usize {
        2 * self.people.id.len()
    }
    /// The desired velocities of the step that starts at `t`: zero for the people whose
    /// group is released after `t`.
    fn eval(&self, t: f64, q: &[f64], out: &mut [f64]) {
        let n = self.people.id.len();
        let out = &mut out[..2 * n];
        let threads = crate::bands::count(self.parallelism.get(), n);
        let mut near = self.near.lock().unwrap_or_else(|e| e.into_inner());
        if near.len() < threads.max(1) {
            near.resize_with(threads.max(1), Vec::new);
        }
        let (mine, theirs) = near.split_first_mut().expect("one scratch at least");
        if threads <= 1 {
            self.eval_people(t, q, 0, out, mine);
            return;
        }
        // Bands of people, the first on the caller; the others with scratch of their own.
        let per = n.div_ceil(threads);
        let (first, others) = out.split_at_mut((2 * per).min(out.len()));
        crate::bands::run(
            self.helper,
            || self.eval_people(t, q, 0, first, mine),
            (others.chunks_mut(2 * per).zip(theirs))
                .enumerate()
                .map(|(k, (band, near))| move || self.eval_people(t, q, (k + 1) * per, band, near)),
        );
    }
}

impl DesiredVelocity<'_> {
    /// [`Field::eval`] for the people from `start` on, as many as `out` holds pairs.
    fn eval_people(&self, t: f64, q: &[f64], start: usize, out: &mut [f64], near: &mut Vec<u32>) {
        let n = self.people.id.len();
        for (k, out) in out.chunks_exact_mut(2).enumerate() {
            let i = start + k;
            let ahead = i + PREFETCH_AHEAD;
            if ahead < n
                && let Some(g) = self.goal(ahead)
            {
                self.fields[g].prefetch([q[2 * ahead], q[2 * ahead + 1]]);
            }
            let v = if t < self.stand_until[self.people.group[i] as usize] {
                [0.0, 0.0]
            } else {
                self.velocity(i, [q[2 * i], q[2 * i + 1]], near)
            };
            out[0] = v[0];
            out[1] = v[1];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_goes_around_an_obstacle_and_direction_descends() {
        // A 10 × 10 room, goal on the right edge, a wall from y = 0 to y = 8 at x = 5.
        let wall = |p: [f64; 2]| (4.8..=5.2).contains(&p[0]) && p[1] < 8.0;
        let f = DistanceField::build([0.0, 0.0], [10.0, 10.0], 0.1, |p| !wall(p), |p| p[0] > 9.9)
            .unwrap();
        // Straight to the goal from (1, 1) is 8.9; the shortest path rounds the wall's end
        // (4.8..5.2, 8) and then goes straight right to x = 9.9.
        let around = (3.8f64.powi(2) + 7.0f64.powi(2)).sqrt() + 0.4 + (9.9 - 5.2);
        let d = f.distance([1.0, 1.0]);
        assert!(
            (d - around).abs() < 0.03 * around,
            "d = {d}, around = {around}"
        );
        // From below the wall's end the direction points up (towards the gap), not into it.
        let dir = f.direction([4.0, 4.0]);
        assert!(dir[1] > 0.5, "{dir:?}");
        // Directions are unit vectors and descend the distance.
        let p = [2.0, 9.0];
        let dir = f.direction(p);
        assert!(((dir[0] * dir[0] + dir[1] * dir[1]).sqrt() - 1.0).abs() < 1e-12);
        let q2 = [p[0] + 0.3 * dir[0], p[1] + 0.3 * dir[1]];
        assert!(
            f.distance(q2) < f.distance(p) - 0.15, // 0.3 along the descent, up to one cell of sampling
            "{} vs {}",
            f.distance(q2),
            f.distance(p)
        );
    }

    #[test]
    fn the_inlined_floor_is_the_floor() {
        let mut x = -7.0f64;
        while x <= 7.0 {
            for v in [x, x.next_up(), x.next_down()] {
                assert_eq!(floor(v), v.floor(), "{v}");
            }
            x += 0.125;
        }
        for v in [
            1e15 + 0.5,
            -1e15 - 0.5,
            4503599627370497.0,
            -4503599627370497.0,
        ] {
            assert_eq!(floor(v), v.floor(), "{v}");
        }
    }
}
