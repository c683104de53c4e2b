//! Contact generation: the sources of constraint rows (pairs of people, people and walls),
//! each behind [`ContactSource`] with its own stable key, and the crowd's constraint set for
//! one step, borrowed from the people and the walls.

use moreau_core::{ConstraintKey, ConstraintRows, ConstraintSet, Parallelism, count_outside};

use crate::broad::BroadPhase;
use crate::moving::MovingBodies;
use crate::people::PeopleView;
use crate::walls::Walls;

/// The kinds of contact, the top two bits of their keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ContactKind {
    /// Two people: `g = |q_i − q_j| − r_i − r_j`.
    PersonPerson = 0,
    /// A person and a wall segment: `g = dist(q_i, wall) − r_i`.
    PersonWall = 1,
    /// A person and a segment of a moving body: `g = dist(q_i, segment(t)) − r_i`.
    MovingWall = 2,
}

impl ContactKind {
    /// The key of a contact of this kind between `a` and `b` (both below 2³¹): stable across
    /// steps, so multipliers warm-start by it.
    pub fn key(self, a: u32, b: u32) -> ConstraintKey {
        debug_assert!(a < 1 << 31 && b < 1 << 31);
        ((self as u64) << 62) | ((a as u64) << 31) | b as u64
    }

    /// The kind and the two halves of `key`.
    pub fn of(key: ConstraintKey) -> (Option<ContactKind>, u32, u32) {
        let kind = match key >> 62 {
            0 => Some(ContactKind::PersonPerson),
            1 => Some(ContactKind::PersonWall),
            2 => Some(ContactKind::MovingWall),
            _ => None,
        };
        (
            kind,
            ((key >> 31) & 0x7fff_ffff) as u32,
            (key & 0x7fff_ffff) as u32,
        )
    }
}

/// What a source reads to list its contacts: the time, the positions, the people and the
/// walls, and the margin (every contact with `g ≤ margin` must be listed).
#[derive(Debug, Clone, Copy)]
pub struct ContactQuery<'a> {
    /// The time at which `g` and `∇g` are evaluated.
    pub t: f64,
    /// Positions `[x0, y0, …]`.
    pub q: &'a [f64],
    /// The people.
    pub people: PeopleView<'a>,
    /// The walls.
    pub walls: &'a Walls,
    /// The walls, panels and obstacles that move.
    pub moving: &'a MovingBodies,
    /// The margin (m).
    pub margin: f64,
}

/// One kind of contact: appends a row `g_i(t, q) ≥ 0` with its gradient and key for every
/// contact of its kind with `g ≤ margin`.
pub trait ContactSource: std::fmt::Debug + Send {
    /// A short name for reports.
    fn name(&self) -> &'static str;
    /// Appends the rows to `rows`.
    fn assemble(&mut self, at: &ContactQuery<'_>, rows: &mut ConstraintRows);
    /// How many people's positions each of this source's gaps depends on, each
    /// 1-Lipschitz in it at a fixed time (a gap then moves by at most that many times the
    /// farthest anyone moved), or `None` when the source cannot say: then the check after
    /// every step assembles the contacts again.
    fn people_per_gap(&self) -> Option<usize> {
        None
    }
}

/// Pairs of people found by a [`BroadPhase`].
#[derive(Debug)]
pub struct PersonPairs {
    broad: Box<dyn BroadPhase>,
    pairs: Vec<(u32, u32)>,
    bands: Bands,
}

impl PersonPairs {
    /// Pairs found by `broad`.
    pub fn new(broad: Box<dyn BroadPhase>) -> Self {
        Self {
            broad,
            pairs: Vec::new(),
            bands: Bands::default(),
        }
    }

    /// Its rows assembled on `parallelism`'s threads, in bands of pairs where there are many
    /// (the same rows as on one thread).
    pub fn on_threads(mut self, parallelism: Parallelism) -> Self {
        self.bands = Bands::new(parallelism);
        self
    }
}

/// The threads a source assembles its rows on, and the rows and scratch of the bands after the
/// first: with threads and many items (pairs, people: two bands from a thousand, one a
/// thread from ten thousand), each band by one thread into rows of its own, appended in order
/// after (the same rows as one thread's).
#[derive(Debug, Default)]
struct Bands {
    threads: usize,
    helper: Option<std::sync::Arc<moreau_core::Helper>>,
    rows: Vec<ConstraintRows>,
    near: Vec<Vec<u32>>,
}

impl Bands {
    fn new(parallelism: Parallelism) -> Self {
        Self {
            threads: parallelism.get(),
            helper: crate::bands::helper_for(parallelism),
            rows: Vec::new(),
            near: Vec::new(),
        }
    }

    /// `assemble(items, rows, near)` for the items `0..count` in order, appending to `rows`:
    /// in bands on threads when there are many (the caller's band with `near`, the others
    /// with scratch of their own, kept from call to call).
    fn assemble(
        &mut self,
        count: usize,
        rows: &mut ConstraintRows,
        near: &mut Vec<u32>,
        assemble: impl Fn(std::ops::Range<usize>, &mut ConstraintRows, &mut Vec<u32>) + Sync,
    ) {
        let threads = crate::bands::count(self.threads, count);
        if threads <= 1 {
            assemble(0..count, rows, near);
            return;
        }
        let band = |k: usize| k * count / threads..(k + 1) * count / threads;
        let dim = rows.dim();
        self.rows.resize_with(threads - 1, ConstraintRows::default);
        self.near.resize_with(threads - 1, Vec::new);
        let assemble = &assemble;
        crate::bands::run(
            self.helper.as_deref(),
            || assemble(band(0), rows, near),
            (self.rows.iter_mut().zip(&mut self.near))
                .enumerate()
                .map(|(k, (own, near))| {
                    move || {
                        own.clear(dim);
                        assemble(band(k + 1), own, near);
                    }
                }),
        );
        for own in &self.rows {
            rows.append(own);
        }
    }
}

impl ContactSource for PersonPairs {
    fn name(&self) -> &'static str {
        "person-person"
    }

    fn assemble(&mut self, at: &ContactQuery<'_>, rows: &mut ConstraintRows) {
        let (q, radius) = (at.q, at.people.radius);
        self.broad.pairs(q, radius, at.margin, &mut self.pairs);
        let pairs = &self.pairs;
        self.bands
            // (Pairs need no scratch: an empty vector, never filled.)
            .assemble(pairs.len(), rows, &mut Vec::new(), |band, rows, _| {
                push_pair_rows(at, &pairs[band], rows);
            });
    }

    /// `|q_i − q_j| − r_i − r_j`.
    fn people_per_gap(&self) -> Option<usize> {
        Some(2)
    }
}

/// Appends the row of each pair of people in `pairs`, `g = |q_i − q_j| − r_i − r_j`.
fn push_pair_rows(at: &ContactQuery<'_>, pairs: &[(u32, u32)], rows: &mut ConstraintRows) {
    let (q, radius, id) = (at.q, at.people.radius, at.people.id);
    for &(i, j) in pairs {
        let (i, j) = (i as usize, j as usize);
        let (dx, dy) = (q[2 * i] - q[2 * j], q[2 * i + 1] - q[2 * j + 1]);
        let d = (dx * dx + dy * dy).sqrt();
        // Coincident centres: any unit direction is a subgradient.
        let e = if d > 0.0 {
            [dx / d, dy / d]
        } else {
            [1.0, 0.0]
        };
        let g = d - radius[i] - radius[j];
        let (a, b) = (id[i].min(id[j]), id[i].max(id[j]));
        rows.push(
            ContactKind::PersonPerson.key(a, b),
            g,
            [
                (2 * i, e[0]),
                (2 * i + 1, e[1]),
                (2 * j, -e[0]),
                (2 * j + 1, -e[1]),
            ],
        );
    }
}

/// People against wall segments, through the walls' grid index: the cost follows the walls
/// near each person, not all of them.
#[derive(Debug, Default)]
pub struct PersonWalls {
    near: Vec<u32>,
    bands: Bands,
}

impl PersonWalls {
    /// Its rows assembled on `parallelism`'s threads, in bands of people where there are many
    /// (the same rows as on one thread).
    pub fn on_threads(parallelism: Parallelism) -> Self {
        Self {
            near: Vec::new(),
            bands: Bands::new(parallelism),
        }
    }
}

impl ContactSource for PersonWalls {
    fn name(&self) -> &'static str {
        "person-wall"
    }

    fn assemble(&mut self, at: &ContactQuery<'_>, rows: &mut ConstraintRows) {
        let people = at.people.radius.len();
        self.bands
            .assemble(people, rows, &mut self.near, |band, rows, near| {
                push_segment_rows_of(ContactKind::PersonWall, at, at.walls, band, near, rows);
            });
    }

    /// `dist(q_i, wall) − r_i`.
    fn people_per_gap(&self) -> Option<usize> {
        Some(1)
    }
}

/// Appends a row `g = dist(q_i, segment) − r_i` with `g ≤ margin`, keyed `kind(id, segment)`,
/// for every person and every segment of `walls` near them (the segments' grid index); on a
/// segment itself the normal is its left side.
pub(crate) fn push_segment_rows(
    kind: ContactKind,
    at: &ContactQuery<'_>,
    walls: &Walls,
    near: &mut Vec<u32>,
    rows: &mut ConstraintRows,
) {
    let people = 0..at.people.radius.len();
    push_segment_rows_of(kind, at, walls, people, near, rows);
}

/// [`push_segment_rows`] for the people `people` only.
fn push_segment_rows_of(
    kind: ContactKind,
    at: &ContactQuery<'_>,
    walls: &Walls,
    people: std::ops::Range<usize>,
    near: &mut Vec<u32>,
    rows: &mut ConstraintRows,
) {
    let (q, radius, id) = (at.q, at.people.radius, at.people.id);
    let segments = walls.segments();
    for i in people {
        let p = [q[2 * i], q[2 * i + 1]];
        walls.near(p, radius[i] + at.margin.max(0.0), near);
        for &w in near.iter() {
            let wall = &segments[w as usize];
            let c = wall.closest(p);
            let (ex, ey) = (p[0] - c[0], p[1] - c[1]);
            let d = (ex * ex + ey * ey).sqrt();
            let g = d - radius[i];
            if g > at.margin {
                continue;
            }
            let n = if d > 0.0 {
                [ex / d, ey / d]
            } else {
                wall.left_normal()
            };
            rows.push(kind.key(id[i], w), g, [(2 * i, n[0]), (2 * i + 1, n[1])]);
        }
    }
}

/// The contact sources of a run and the scratch of the check after each step; owned by the
/// simulation, lent to [`CrowdContacts`] at every step.
#[derive(Debug)]
pub struct ContactSources {
    sources: Vec<Box<dyn ContactSource>>,
    check: ConstraintRows,
    crossed: Vec<ConstraintKey>,
    near: Vec<u32>,
}

impl ContactSources {
    /// The sources, in the order their rows are assembled.
    pub fn new(sources: Vec<Box<dyn ContactSource>>) -> Self {
        Self {
            sources,
            check: ConstraintRows::default(),
            crossed: Vec::new(),
            near: Vec::new(),
        }
    }

    /// The most people's positions any source's gap depends on, or `None` if a source
    /// cannot say ([`ContactSource::people_per_gap`]).
    pub fn people_per_gap(&self) -> Option<usize> {
        self.sources
            .iter()
            .try_fold(0, |most, s| Some(most.max(s.people_per_gap()?)))
    }

    /// Appends every source's rows with `g ≤ margin` at `(t, q)`.
    pub fn assemble(
        &mut self,
        t: f64,
        q: &[f64],
        people: PeopleView<'_>,
        walls: &Walls,
        moving: &MovingBodies,
        margin: f64,
        rows: &mut ConstraintRows,
    ) {
        let at = ContactQuery {
            t,
            q,
            people,
            walls,
            moving,
            margin,
        };
        for s in &mut self.sources {
            s.assemble(&at, rows);
        }
    }
}

/// The crowd's feasible set for one step: `g ≥ 0` for every contact of every source, convex
/// in `q`, so the linearized set lies inside it. Borrowed from the people and the walls.
#[derive(Debug)]
pub struct CrowdContacts<'a> {
    /// The people.
    pub people: PeopleView<'a>,
    /// The walls.
    pub walls: &'a Walls,
    /// The walls, panels and obstacles that move.
    pub moving: &'a MovingBodies,
    /// The sources and their scratch.
    pub sources: &'a mut ContactSources,
}

impl ConstraintSet for CrowdContacts<'_> {
    fn dim(&self) -> usize {
        2 * self.people.id.len()
    }

    fn assemble(&mut self, t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows) {
        self.sources
            .assemble(t, q, self.people, self.walls, self.moving, margin, rows);
    }

    /// Two disks close by at most `|v_i| + |v_j|` per unit time and a disk closes on a wall at
    /// `|v_i|`; `v` can exceed the desired `w` when pushed, hence the factor, and the check
    /// after the step catches the rest.
    fn margin(&self, _q: &[f64], w: &[f64], mu: f64) -> f64 {
        let vmax = w
            .chunks_exact(2)
            .map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt())
            .fold(0.0, f64::max);
        let rmin = self
            .people
            .radius
            .iter()
            .cloned()
            .fold(f64::INFINITY, f64::min);
        3.0 * mu * vmax + 0.05 * rmin
    }

    /// The walls whose segment a person's centre crossed on the straight way from `q` to
    /// `q_next`, their rows not assembled. Found by a bug hunt: a person squeezed along the
    /// floor by a tilted barrier moved 0.86 m in one step, straight through a partition
    /// 0.13 m away (beyond the margin, so never assembled), and landed on its free side:
    /// every frame valid, the step certified. Moving bodies are not checked here.
    fn passed_through(
        &mut self,
        _t: f64,
        q: &[f64],
        q_next: &[f64],
        assembled: &ConstraintRows,
    ) -> usize {
        let segments = self.walls.segments();
        let (id, near, crossed) = (
            self.people.id,
            &mut self.sources.near,
            &mut self.sources.crossed,
        );
        crossed.clear();
        for (i, (a, b)) in q.chunks_exact(2).zip(q_next.chunks_exact(2)).enumerate() {
            let (a, b) = ([a[0], a[1]], [b[0], b[1]]);
            let half = 0.5 * (b[0] - a[0]).hypot(b[1] - a[1]);
            if !(half > 0.0) {
                continue;
            }
            let mid = [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
            self.walls.near(mid, half, near);
            for &w in near.iter() {
                let wall = &segments[w as usize];
                if crate::geometry::segments_cross(a, b, wall.a, wall.b) {
                    crossed.push(ContactKind::PersonWall.key(id[i], w));
                }
            }
        }
        if crossed.is_empty() {
            return 0;
        }
        crossed.sort_unstable();
        crossed.dedup();
        let seen = assembled
            .keys()
            .iter()
            .filter(|k| crossed.binary_search(k).is_ok())
            .count();
        crossed.len() - seen
    }

    /// As the default, with the rows kept from step to step (no allocation per step).
    fn crossed_outside(
        &mut self,
        t: f64,
        q: &[f64],
        assembled: &ConstraintRows,
        tol: f64,
    ) -> usize {
        let mut check = std::mem::take(&mut self.sources.check);
        check.clear(self.dim());
        self.assemble(t, q, -tol, &mut check);
        let crossed = count_outside(&check, assembled, tol, &mut self.sources.crossed);
        self.sources.check = check;
        crossed
    }

    /// True when the farthest anyone moved from `q` to `q_next`, times the most people a
    /// gap depends on, stays below `margin + tol` (with room for rounding): a gap left out
    /// was above `margin` at `q`, and moves by at most that much.
    fn left_out_stay_feasible(
        &self,
        _t: f64,
        q: &[f64],
        q_next: &[f64],
        margin: f64,
        tol: f64,
    ) -> bool {
        let Some(people) = self.sources.people_per_gap() else {
            return false;
        };
        if q.len() != q_next.len() {
            return false;
        }
        let (mut moved2, mut scale) = (0.0f64, 0.0f64);
        for (a, b) in q.chunks_exact(2).zip(q_next.chunks_exact(2)) {
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let d2 = dx * dx + dy * dy;
            // NaN makes the answer false.
            if !(d2 <= moved2) {
                moved2 = d2;
            }
            scale = scale.max(a[0].abs()).max(a[1].abs());
        }
        let rounding =
            1e-12 * (1.0 + scale + self.people.radius.iter().fold(0.0, |m, &r| r.max(m)));
        people as f64 * moved2.sqrt() * (1.0 + 1e-9) + rounding <= margin + tol
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_of_different_kinds_never_collide_and_read_back() {
        let max = (1u32 << 31) - 1;
        for (a, b) in [(0, 0), (1, 2), (max, max), (max, 0)] {
            let pp = ContactKind::PersonPerson.key(a, b);
            let pw = ContactKind::PersonWall.key(a, b);
            let mw = ContactKind::MovingWall.key(a, b);
            assert!(pp != pw && pw != mw && mw != pp);
            assert_eq!(ContactKind::of(mw), (Some(ContactKind::MovingWall), a, b));
            assert_eq!(ContactKind::of(pp), (Some(ContactKind::PersonPerson), a, b));
            assert_eq!(ContactKind::of(pw), (Some(ContactKind::PersonWall), a, b));
        }
    }
}
