//! Broad phase: every pair of disks whose gap `|q_i − q_j| − r_i − r_j` is at most a margin.

use moreau_core::Parallelism;
use parry2d_f64::bounding_volume::Aabb;
use parry2d_f64::math::Vector;
use parry2d_f64::partitioning::{Bvh, BvhBuildStrategy, BvhWorkspace};

/// Finds candidate contacts. Every backend returns exactly the pairs `(i, j)`, `i < j`, with
/// `|q_i − q_j| − r_i − r_j ≤ margin`, sorted, so that backends are interchangeable.
pub trait BroadPhase: std::fmt::Debug + Send {
    /// A short name for reports.
    fn name(&self) -> &'static str;
    /// Writes the pairs into `out` (cleared first). `pos` is `[x0, y0, x1, y1, ...]`.
    fn pairs(&mut self, pos: &[f64], radius: &[f64], margin: f64, out: &mut Vec<(u32, u32)>);
}

/// The exact gap test shared by every backend (the same arithmetic, so the same answers).
#[inline]
fn close(pos: &[f64], radius: &[f64], i: usize, j: usize, margin: f64) -> bool {
    let dx = pos[2 * i] - pos[2 * j];
    let dy = pos[2 * i + 1] - pos[2 * j + 1];
    (dx * dx + dy * dy).sqrt() - radius[i] - radius[j] <= margin
}

/// All pairs, O(N²): the reference for tests.
#[derive(Debug, Clone, Copy, Default)]
pub struct BruteForce;

impl BroadPhase for BruteForce {
    fn name(&self) -> &'static str {
        "brute-force"
    }
    fn pairs(&mut self, pos: &[f64], radius: &[f64], margin: f64, out: &mut Vec<(u32, u32)>) {
        out.clear();
        let n = radius.len();
        for i in 0..n {
            for j in i + 1..n {
                if close(pos, radius, i, j, margin) {
                    out.push((i as u32, j as u32));
                }
            }
        }
    }
}

/// A uniform grid of square cells of side `2 r_max + margin`: fast when radii are similar.
/// With threads ([`CellGrid::on_threads`]) its rows of cells are swept in bands, one a thread;
/// the pairs are sorted at the end, so they are the same on any thread count.
#[derive(Debug, Clone, Default)]
pub struct CellGrid {
    threads: usize,
    helper: Option<std::sync::Arc<moreau_core::Helper>>,
    // each band's pairs, from the threads after the first
    bands: Vec<Vec<(u32, u32)>>,
    cell_start: Vec<u32>,
    fill: Vec<u32>,
    cell_of: Vec<u32>,
    // The disks in cell order: their indices, and their x, y and radius side by side (the
    // pair tests then read memory in order, not scattered by index).
    sorted: Vec<u32>,
    packed: Vec<[f64; 3]>,
    sort: PairSort,
}

/// The side of the grid's cells: `cell`, or larger where `(span₀/c + 1)(span₁/c + 1)` cells of
/// that side would exceed `budget`, then the smallest side within it (the positive root of
/// that quadratic in `1/c`, in the form that neither cancels nor overflows: a crowd spread
/// over a long thin strip, or people far apart, get at most about `budget` cells, not one
/// side's worth of them squared).
pub(crate) fn cell_within_budget(cell: f64, span: [f64; 2], budget: f64) -> f64 {
    let cells = |c: f64| (span[0] / c + 1.0) * (span[1] / c + 1.0);
    if cells(cell) <= budget {
        return cell;
    }
    // (s₀s₁) x² + (s₀ + s₁) x − (budget − 1) = 0 for x = 1/c.
    let (sum, product, room) = (span[0] + span[1], span[0] * span[1], budget - 1.0);
    let x = 2.0 * room / (sum + (sum * sum + 4.0 * product * room).sqrt());
    cell.max(1.0 / x)
}

impl BroadPhase for CellGrid {
    fn name(&self) -> &'static str {
        "grid"
    }
    fn pairs(&mut self, pos: &[f64], radius: &[f64], margin: f64, out: &mut Vec<(u32, u32)>) {
        out.clear();
        let n = radius.len();
        if n < 2 {
            return;
        }
        let rmax = radius.iter().cloned().fold(0.0, f64::max);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for i in 0..n {
            for k in 0..2 {
                lo[k] = lo[k].min(pos[2 * i + k]);
                hi[k] = hi[k].max(pos[2 * i + k]);
            }
        }
        // Pairs within the margin are at most one cell apart; cap the cell count at ~4N.
        let span = [(hi[0] - lo[0]).max(0.0), (hi[1] - lo[1]).max(0.0)];
        let cell = cell_within_budget(
            (2.0 * rmax + margin.max(0.0)).max(1e-12),
            span,
            (4 * n + 16) as f64,
        );
        let nx = (span[0] / cell) as usize + 1;
        let ny = (span[1] / cell) as usize + 1;
        // Counting sort of the disks by cell.
        self.cell_start.clear();
        self.cell_start.resize(nx * ny + 1, 0);
        self.cell_of.clear();
        for i in 0..n {
            let cx = (((pos[2 * i] - lo[0]) / cell) as usize).min(nx - 1);
            let cy = (((pos[2 * i + 1] - lo[1]) / cell) as usize).min(ny - 1);
            let c = (cy * nx + cx) as u32;
            self.cell_of.push(c);
            self.cell_start[c as usize + 1] += 1;
        }
        for c in 0..nx * ny {
            self.cell_start[c + 1] += self.cell_start[c];
        }
        self.sorted.clear();
        self.sorted.resize(n, 0);
        self.packed.clear();
        self.packed.resize(n, [0.0; 3]);
        self.fill.clear();
        self.fill.extend_from_slice(&self.cell_start);
        for i in 0..n {
            let c = self.cell_of[i] as usize;
            let at = self.fill[c] as usize;
            self.sorted[at] = i as u32;
            self.packed[at] = [pos[2 * i], pos[2 * i + 1], radius[i]];
            self.fill[c] += 1;
        }
        // The gap test of `close`, on the packed copies, with the lower index first (the
        // same arithmetic as every backend, so the same answers). Pairs farther apart than
        // `reach` (the largest sum of radii and the margin, grown well beyond rounding) fail
        // it for certain and are dropped without the square root.
        let reach = 2.0 * rmax + margin;
        let reach2 = if reach > 0.0 {
            let reach = reach + 1e-9 * (4.0 * rmax + margin.abs());
            reach * reach
        } else {
            f64::INFINITY
        };
        let grid = Grid {
            sorted: &self.sorted,
            packed: &self.packed,
            cell_start: &self.cell_start,
            nx,
            ny,
            reach2,
            margin,
        };
        let threads = crate::bands::count(self.threads, n).min(ny);
        if threads <= 1 {
            grid.sweep(0..ny, out);
        } else {
            // Bands of rows of cells, the first on the caller.
            self.bands.resize_with(threads - 1, Vec::new);
            let band = |k: usize| k * ny / threads..(k + 1) * ny / threads;
            let grid = &grid;
            crate::bands::run(
                self.helper.as_deref(),
                || grid.sweep(band(0), out),
                self.bands.iter_mut().enumerate().map(|(k, pairs)| {
                    move || {
                        pairs.clear();
                        grid.sweep(band(k + 1), pairs);
                    }
                }),
            );
            for pairs in &self.bands {
                out.extend_from_slice(pairs);
            }
        }
        self.sort.sort(n, out);
    }
}

impl CellGrid {
    /// A grid that sweeps its cells on `parallelism`'s threads when there are many disks.
    pub fn on_threads(parallelism: Parallelism) -> Self {
        Self {
            threads: parallelism.get(),
            helper: crate::bands::helper_for(parallelism),
            ..Self::default()
        }
    }
}

/// One call's grid, shared by the threads that sweep it: the disks in cell order, packed,
/// and the cells.
struct Grid<'a> {
    sorted: &'a [u32],
    packed: &'a [[f64; 3]],
    cell_start: &'a [u32],
    nx: usize,
    ny: usize,
    reach2: f64,
    margin: f64,
}

impl Grid<'_> {
    /// The pairs of the disks in the rows of cells `rows` with their own cell and four forward
    /// neighbours, appended to `out` (not sorted).
    fn sweep(&self, rows: std::ops::Range<usize>, out: &mut Vec<(u32, u32)>) {
        let (sorted, packed, margin, reach2) = (self.sorted, self.packed, self.margin, self.reach2);
        let (nx, ny) = (self.nx, self.ny);
        let mut test = |a: usize, b: usize| {
            let (dx, dy) = (packed[a][0] - packed[b][0], packed[a][1] - packed[b][1]);
            if dx * dx + dy * dy > reach2 {
                return;
            }
            let (i, j) = (sorted[a], sorted[b]);
            let (p, q) = if i < j {
                (&packed[a], &packed[b])
            } else {
                (&packed[b], &packed[a])
            };
            let (dx, dy) = (p[0] - q[0], p[1] - q[1]);
            if (dx * dx + dy * dy).sqrt() - p[2] - q[2] <= margin {
                out.push((i.min(j), i.max(j)));
            }
        };
        // Each disk against its own cell (later entries) and four forward neighbours.
        let range = |c: usize| self.cell_start[c] as usize..self.cell_start[c + 1] as usize;
        for cy in rows {
            for cx in 0..nx {
                let own = range(cy * nx + cx);
                if own.is_empty() {
                    continue;
                }
                for a in own.clone() {
                    for b in a + 1..own.end {
                        test(a, b);
                    }
                }
                for (dx, dy) in [(1i64, 0i64), (-1, 1), (0, 1), (1, 1)] {
                    let (ox, oy) = (cx as i64 + dx, cy as i64 + dy);
                    if ox < 0 || oy < 0 || ox >= nx as i64 || oy >= ny as i64 {
                        continue;
                    }
                    let other = range(oy as usize * nx + ox as usize);
                    for a in own.clone() {
                        for b in other.clone() {
                            test(a, b);
                        }
                    }
                }
            }
        }
    }
}

/// Sorts pairs `(i, j)` of `i < n` in linear time: a counting sort on `i`, then each `i`'s
/// few partners. Keeps its buffers from call to call.
#[derive(Debug, Clone, Default)]
struct PairSort {
    end: Vec<u32>,
    scratch: Vec<(u32, u32)>,
}

impl PairSort {
    fn sort(&mut self, n: usize, pairs: &mut Vec<(u32, u32)>) {
        // end[i + 1] counts i's pairs, then (prefix sums) is where i's pairs begin.
        self.end.clear();
        self.end.resize(n + 1, 0);
        for &(i, _) in pairs.iter() {
            self.end[i as usize + 1] += 1;
        }
        for i in 0..n {
            self.end[i + 1] += self.end[i];
        }
        self.scratch.clear();
        self.scratch.resize(pairs.len(), (0, 0));
        // Placing i's pairs moves end[i] from where they begin to where they end.
        for &(i, j) in pairs.iter() {
            let at = &mut self.end[i as usize];
            self.scratch[*at as usize] = (i, j);
            *at += 1;
        }
        let mut begin = 0;
        for &end in &self.end[..n] {
            let end = end as usize;
            if end - begin > 1 {
                self.scratch[begin..end].sort_unstable();
            }
            begin = end;
        }
        std::mem::swap(pairs, &mut self.scratch);
    }
}

/// parry's bounding-volume hierarchy over the disks' boxes: robust when radii differ a lot.
#[derive(Default)]
pub struct TreeBroadPhase {
    leaves: Vec<Aabb>,
    workspace: BvhWorkspace,
}

impl std::fmt::Debug for TreeBroadPhase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TreeBroadPhase")
            .field("leaves", &self.leaves.len())
            .finish_non_exhaustive()
    }
}

impl BroadPhase for TreeBroadPhase {
    fn name(&self) -> &'static str {
        "bvh"
    }
    fn pairs(&mut self, pos: &[f64], radius: &[f64], margin: f64, out: &mut Vec<(u32, u32)>) {
        out.clear();
        let n = radius.len();
        if n < 2 {
            return;
        }
        // Boxes grown by half the margin each: overlapping boxes ⇐ gap ≤ margin.
        let grow = 0.5 * margin.max(0.0);
        self.leaves.clear();
        self.leaves.extend((0..n).map(|i| {
            let e = radius[i] + grow;
            Aabb::new(
                Vector::new(pos[2 * i] - e, pos[2 * i + 1] - e),
                Vector::new(pos[2 * i] + e, pos[2 * i + 1] + e),
            )
        }));
        let bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &self.leaves);
        bvh.traverse_bvtt_single_tree::<false>(&mut self.workspace, &mut |a, b| {
            let (i, j) = (a.min(b), a.max(b));
            if i != j && close(pos, radius, i as usize, j as usize, margin) {
                out.push((i, j));
            }
        });
        out.sort_unstable();
        out.dedup();
    }
}

/// A Verlet list over a backend: the backend's pairs at a wider margin (the skin), kept from
/// call to call and filtered by the exact gap test while nobody has moved far enough to close
/// the skin. A gap moves by at most the two people's displacements, so a pair within `margin`
/// now was within `margin + 2 × the farthest anyone moved` when the list was built; while that
/// stays inside the built margin the list holds every pair, and the exact test on it gives
/// the very pairs (and order) of the backend alone.
///
/// The skin is sized for a list to serve [`VerletList::CALLS`] calls at the speed measured
/// (the farthest anyone moved over the calls since the positions were kept: the first call
/// only keeps them). Where that skin would be wider than the largest radius, or the people
/// changed within a call or two (a hall's people leave at every step, shifting indices, and
/// a list is for the same people), a list does not pay: the next [`VerletList::PAUSE`] calls
/// go straight to the backend, keeping nothing, then the speed is measured again. Halls at
/// 0.05 s steps take the backend (people leave every step, the farthest walker goes 0.1 m a
/// step); cromosim's scene at 0.01 s keeps its lists 4–6 calls.
#[derive(Debug)]
pub struct VerletList {
    inner: Box<dyn BroadPhase>,
    candidates: Vec<(u32, u32)>,
    built_pos: Vec<f64>,
    built_radius: Vec<f64>,
    /// The margin the candidates hold; NaN without a list.
    built_margin: f64,
    /// Calls since the positions were kept.
    served: usize,
    /// Calls left to go straight to the backend.
    paused: usize,
    /// The farthest anyone moved in a call, as last measured (NaN before).
    speed: f64,
    builds: usize,
}

impl VerletList {
    /// Calls a list is sized to serve.
    pub const CALLS: usize = 4;
    /// Calls that go straight to the backend when a list would not pay.
    pub const PAUSE: usize = 16;

    /// A list kept over `inner`'s pairs.
    pub fn new(inner: Box<dyn BroadPhase>) -> Self {
        Self {
            inner,
            candidates: Vec::new(),
            built_pos: Vec::new(),
            built_radius: Vec::new(),
            built_margin: f64::NAN,
            served: 0,
            paused: 0,
            speed: f64::NAN,
            builds: 0,
        }
    }

    /// How many times the backend was asked for pairs.
    pub fn builds(&self) -> usize {
        self.builds
    }

    /// The farthest anyone moved since the positions were kept, if the people are the same
    /// (radii, bit for bit), and the largest coordinate.
    fn moved(&self, pos: &[f64], radius: &[f64]) -> Option<(f64, f64)> {
        if pos.len() != self.built_pos.len()
            || radius.len() != self.built_radius.len()
            || radius
                .iter()
                .zip(&self.built_radius)
                .any(|(a, b)| a.to_bits() != b.to_bits())
        {
            return None;
        }
        let (mut moved2, mut scale) = (0.0f64, 0.0f64);
        for (a, b) in pos.chunks_exact(2).zip(self.built_pos.chunks_exact(2)) {
            let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
            let d2 = dx * dx + dy * dy;
            // NaN propagates (and makes the list fail to hold).
            if !(d2 <= moved2) {
                moved2 = d2;
            }
            scale = scale.max(a[0].abs()).max(a[1].abs());
        }
        Some((moved2.sqrt(), scale))
    }

    /// Keeps the positions and radii (of a new list, or to measure the speed).
    fn keep(&mut self, pos: &[f64], radius: &[f64]) {
        self.built_pos.clear();
        self.built_pos.extend_from_slice(pos);
        self.built_radius.clear();
        self.built_radius.extend_from_slice(radius);
    }

    /// Goes straight to the backend for the next [`Self::PAUSE`] calls, keeping nothing.
    fn pause(&mut self) {
        self.paused = Self::PAUSE;
        self.candidates = Vec::new();
        self.built_pos = Vec::new();
        self.built_radius = Vec::new();
        self.built_margin = f64::NAN;
        self.served = 0;
    }
}

impl BroadPhase for VerletList {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn pairs(&mut self, pos: &[f64], radius: &[f64], margin: f64, out: &mut Vec<(u32, u32)>) {
        if self.paused > 0 {
            self.paused -= 1;
            self.builds += 1;
            return self.inner.pairs(pos, radius, margin, out);
        }
        let rmax = radius.iter().fold(0.0f64, |m, &r| m.max(r));
        let moved = self.moved(pos, radius);
        if let Some((moved, _)) = moved.filter(|_| self.served > 0) {
            self.speed = moved / self.served as f64;
        }
        let listed = !self.built_margin.is_nan();
        // The list holds every pair within `margin` when `margin + 2 × moved` (with room for
        // rounding) stays inside the built margin.
        let holds = listed
            && moved.is_some_and(|(moved, scale)| {
                let rounding = 1e-12 * (1.0 + scale + rmax);
                margin + 2.0 * moved * (1.0 + 1e-9) + rounding <= self.built_margin
            });
        if !holds {
            if !listed && self.served == 0 {
                // Nothing kept yet (or since a pause): this call keeps the positions, the
                // next one measures how far people go in a call.
                self.keep(pos, radius);
                self.served = 1;
                self.builds += 1;
                return self.inner.pairs(pos, radius, margin, out);
            }
            // CALLS calls at the speed measured, both people of a pair moving.
            let skin = 2.0 * Self::CALLS as f64 * self.speed;
            if (moved.is_none() && self.served < 2) || !(skin <= rmax) {
                self.pause();
                self.builds += 1;
                return self.inner.pairs(pos, radius, margin, out);
            }
            self.built_margin = margin.max(0.0) + skin;
            self.inner
                .pairs(pos, radius, self.built_margin, &mut self.candidates);
            self.keep(pos, radius);
            self.served = 0;
            self.builds += 1;
        }
        self.served += 1;
        out.clear();
        out.extend(
            self.candidates
                .iter()
                .filter(|&&(i, j)| close(pos, radius, i as usize, j as usize, margin)),
        );
    }
}

/// Which backend a scene gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BroadPhaseKind {
    /// [`CellGrid`].
    Grid,
    /// [`TreeBroadPhase`].
    Bvh,
}

/// The grid when radii are within a factor 4 of each other, the tree otherwise: a grid cell
/// sized for the largest disk holds many small ones.
pub fn choose_broad_phase(min_radius: f64, max_radius: f64) -> BroadPhaseKind {
    if max_radius <= 4.0 * min_radius {
        BroadPhaseKind::Grid
    } else {
        BroadPhaseKind::Bvh
    }
}

impl BroadPhaseKind {
    /// A fresh backend of this kind, under a [`VerletList`].
    pub fn build(self) -> Box<dyn BroadPhase> {
        self.build_on(Parallelism::SEQUENTIAL)
    }

    /// [`build`](Self::build), sweeping on `parallelism`'s threads where the backend can (the
    /// grid).
    pub fn build_on(self, parallelism: Parallelism) -> Box<dyn BroadPhase> {
        let inner: Box<dyn BroadPhase> = match self {
            BroadPhaseKind::Grid => Box::new(CellGrid::on_threads(parallelism)),
            BroadPhaseKind::Bvh => Box::new(TreeBroadPhase::default()),
        };
        Box::new(VerletList::new(inner))
    }
}
