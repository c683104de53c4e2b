//! `Walls`: the wall segments of a scene and a grid index over them, built once, that finds
//! the walls within reach of a point without looking at the others (and, from a cell's
//! clearance, answers "none" for most points in one look).

use crate::geometry::Segment;

/// Wall segments (the walkable side on each one's left) and a uniform grid of square cells,
/// each listing the walls that pass through it.
#[derive(Debug, Clone, Default)]
pub struct Walls {
    segments: Vec<Segment>,
    origin: [f64; 2],
    cell: f64,
    nx: usize,
    ny: usize,
    cell_start: Vec<u32>,
    entries: Vec<u32>,
    /// Per cell, how many rings of cells around it list no wall (at most `u8::MAX`): every
    /// wall is then at least that many cell sides away from any point of the cell.
    clear_rings: Vec<u8>,
}

impl Walls {
    /// The side (m) of the cells when four per wall would be larger: a person's query then
    /// looks at the walls within a few metres, not at those of a tenth of a large hall
    /// (at a million people the walls' queries were 4–6 % of a step with the coarse cells).
    pub const FINE_CELL: f64 = 2.0;
    /// The most cells [`FINE_CELL`](Self::FINE_CELL) makes.
    pub const MAX_CELLS: f64 = (1 << 18) as f64;

    /// The index over `segments`: about four cells per wall (at most `4 walls + 16`), or
    /// cells of [`FINE_CELL`](Self::FINE_CELL) where that makes more (at most
    /// [`MAX_CELLS`](Self::MAX_CELLS)), each listing every wall that passes within its
    /// circumscribed circle (a superset of the walls that cross it).
    pub fn new(segments: Vec<Segment>) -> Self {
        let mut walls = Self {
            segments,
            ..Self::default()
        };
        if walls.segments.is_empty() {
            return walls;
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for s in &walls.segments {
            for p in [s.a, s.b] {
                for k in 0..2 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
        let span = [(hi[0] - lo[0]).max(1e-9), (hi[1] - lo[1]).max(1e-9)];
        let fine = (span[0] * span[1] / (Self::FINE_CELL * Self::FINE_CELL)).min(Self::MAX_CELLS);
        let budget = ((4 * walls.segments.len() + 16) as f64).max(fine);
        let mut cell = (span[0] * span[1] / budget).sqrt().max(1e-9);
        // Rounding up each side can exceed the budget on thin boxes: grow the cells until not.
        while (span[0] / cell).ceil() * (span[1] / cell).ceil() > budget {
            cell *= 1.25;
        }
        let nx = ((span[0] / cell).ceil() as usize).max(1);
        let ny = ((span[1] / cell).ceil() as usize).max(1);
        walls.origin = lo;
        walls.cell = cell;
        walls.nx = nx;
        walls.ny = ny;
        let reach = 0.5 * std::f64::consts::SQRT_2 * cell * (1.0 + 1e-9);
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
        for (w, s) in walls.segments.iter().enumerate() {
            let (x0, x1) = walls.cell_range(s.a[0].min(s.b[0]), s.a[0].max(s.b[0]), 0);
            let (y0, y1) = walls.cell_range(s.a[1].min(s.b[1]), s.a[1].max(s.b[1]), 1);
            for iy in y0..=y1 {
                for ix in x0..=x1 {
                    let c = [
                        lo[0] + (ix as f64 + 0.5) * cell,
                        lo[1] + (iy as f64 + 0.5) * cell,
                    ];
                    if s.distance(c) <= reach {
                        lists[iy * nx + ix].push(w as u32);
                    }
                }
            }
        }
        walls.cell_start.push(0);
        for l in &lists {
            walls.entries.extend_from_slice(l);
            walls.cell_start.push(walls.entries.len() as u32);
        }
        walls.clear_rings = clear_rings(nx, ny, |c| !lists[c].is_empty());
        walls
    }

    /// The cells `[first, last]` along axis `k` that `[a, b]` overlaps, clamped to the grid.
    fn cell_range(&self, a: f64, b: f64, k: usize) -> (usize, usize) {
        let n = if k == 0 { self.nx } else { self.ny };
        // Truncation is the floor here (f ≥ 0), without a call into libm (x86-64 has no
        // floor instruction before SSE4.1; with the distance fields' floors, 2.7 % of a step
        // at a million people).
        let to_cell = |x: f64| -> usize {
            let f = (x - self.origin[k]) / self.cell;
            if f >= 0.0 { (f as usize).min(n - 1) } else { 0 }
        };
        (to_cell(a), to_cell(b))
    }

    /// The segments.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// Hands the segments back (the index is left empty), to reuse their memory.
    pub fn take_segments(&mut self) -> Vec<Segment> {
        let segments = std::mem::take(&mut self.segments);
        *self = Self::default();
        segments
    }

    /// How many walls.
    pub fn len(&self) -> usize {
        self.segments.len()
    }

    /// True without walls.
    pub fn is_empty(&self) -> bool {
        self.segments.is_empty()
    }

    /// Writes into `out` (cleared first), in increasing order, the index of every wall that
    /// may lie within `reach` of `p`: a superset of those that do, found from the cells the
    /// square `p ± reach` overlaps.
    pub fn near(&self, p: [f64; 2], reach: f64, out: &mut Vec<u32>) {
        out.clear();
        if self.segments.is_empty() || !(reach >= 0.0) {
            return;
        }
        if !reach.is_finite() {
            out.extend(0..self.segments.len() as u32);
            return;
        }
        let (lo, hi) = ([p[0] - reach, p[1] - reach], [p[0] + reach, p[1] + reach]);
        // Far from every wall (most people in a room): the cell of `p` says so. A point
        // outside the grid is taken by its nearest cell, which is no farther from the walls.
        let (cx, _) = self.cell_range(p[0], p[0], 0);
        let (cy, _) = self.cell_range(p[1], p[1], 1);
        if f64::from(self.clear_rings[cy * self.nx + cx]) * self.cell > reach {
            return;
        }
        let top = [
            self.origin[0] + self.nx as f64 * self.cell,
            self.origin[1] + self.ny as f64 * self.cell,
        ];
        // Entirely outside the grid: no wall is within reach (every wall lies in the grid).
        if hi[0] < self.origin[0] || hi[1] < self.origin[1] || lo[0] > top[0] || lo[1] > top[1] {
            return;
        }
        let (x0, x1) = self.cell_range(lo[0], hi[0], 0);
        let (y0, y1) = self.cell_range(lo[1], hi[1], 1);
        let cell =
            |c: usize| &self.entries[self.cell_start[c] as usize..self.cell_start[c + 1] as usize];
        if x0 == x1 && y0 == y1 {
            // One cell: its list is already sorted and without repeats.
            out.extend_from_slice(cell(y0 * self.nx + x0));
            return;
        }
        for iy in y0..=y1 {
            for ix in x0..=x1 {
                out.extend_from_slice(cell(iy * self.nx + ix));
            }
        }
        out.sort_unstable();
        out.dedup();
    }
}

/// For each cell of an `nx × ny` grid, the number of rings of cells around it in which no
/// cell is `listed` (Chebyshev distance to the nearest listed cell, minus one; cells past
/// the grid's edge list nothing), at most `u8::MAX`: two sweeps of the chessboard distance
/// transform.
fn clear_rings(nx: usize, ny: usize, listed: impl Fn(usize) -> bool) -> Vec<u8> {
    const FAR: u32 = u8::MAX as u32 + 1;
    let mut d: Vec<u32> = (0..nx * ny)
        .map(|c| if listed(c) { 0 } else { FAR })
        .collect();
    for iy in 0..ny {
        for ix in 0..nx {
            let mut best = d[iy * nx + ix];
            if ix > 0 {
                best = best.min(d[iy * nx + ix - 1] + 1);
            }
            if iy > 0 {
                for jx in ix.saturating_sub(1)..=(ix + 1).min(nx - 1) {
                    best = best.min(d[(iy - 1) * nx + jx] + 1);
                }
            }
            d[iy * nx + ix] = best;
        }
    }
    for iy in (0..ny).rev() {
        for ix in (0..nx).rev() {
            let mut best = d[iy * nx + ix];
            if ix + 1 < nx {
                best = best.min(d[iy * nx + ix + 1] + 1);
            }
            if iy + 1 < ny {
                for jx in ix.saturating_sub(1)..=(ix + 1).min(nx - 1) {
                    best = best.min(d[(iy + 1) * nx + jx] + 1);
                }
            }
            d[iy * nx + ix] = best;
        }
    }
    // A cell at distance k has k − 1 clear rings around it; none listed at all: as far as
    // can be told.
    d.iter()
        .map(|&k| (k.saturating_sub(1)).min(u8::MAX as u32) as u8)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Every wall within reach of a point is listed (and no wall twice), on many walls in a
    /// small area and on a few long ones, diagonals among them, around a large hall (cells
    /// of about `FINE_CELL`).
    #[test]
    fn near_finds_every_wall_within_reach() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let many: Vec<Segment> = (0..300)
            .map(|_| {
                let a = [rng.random_range(0.0..50.0), rng.random_range(0.0..20.0)];
                let len = if rng.random_bool(0.1) { 30.0 } else { 1.0 };
                let b = [
                    a[0] + rng.random_range(-len..len),
                    a[1] + rng.random_range(-len..len),
                ];
                Segment { a, b }
            })
            .collect();
        let hall: Vec<Segment> = [
            ([0.0, 0.0], [600.0, 0.0]),
            ([600.0, 0.0], [600.0, 400.0]),
            ([600.0, 400.0], [0.0, 400.0]),
            ([0.0, 400.0], [0.0, 0.0]),
            ([100.0, 100.0], [350.0, 310.0]),
            ([500.0, 20.0], [480.0, 390.0]),
        ]
        .into_iter()
        .map(|(a, b)| Segment { a, b })
        .collect();
        let coarse = Walls::new(many.clone());
        check_near(&coarse, &many, [-10.0, 60.0], [-10.0, 30.0], &mut rng);
        let fine = Walls::new(hall.clone());
        assert!(
            fine.cell <= 2.0 * Walls::FINE_CELL,
            "cells of {} m",
            fine.cell
        );
        check_near(&fine, &hall, [-10.0, 610.0], [-10.0, 410.0], &mut rng);
    }

    /// The rings are the chessboard distance to the nearest listed cell less one, as counted
    /// cell by cell, on random grids (sparse and dense lists, one row, one column).
    #[test]
    fn clear_rings_count_the_empty_rings_around_each_cell() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (nx, ny, share) in [
            (17, 11, 0.05),
            (9, 23, 0.3),
            (1, 30, 0.1),
            (40, 1, 0.1),
            (5, 5, 0.0),
        ] {
            let listed: Vec<bool> = (0..nx * ny).map(|_| rng.random_bool(share)).collect();
            let rings = clear_rings(nx, ny, |c| listed[c]);
            for c in 0..nx * ny {
                let (x, y) = ((c % nx) as i64, (c / nx) as i64);
                let nearest = (0..nx * ny)
                    .filter(|&o| listed[o])
                    .map(|o| ((o % nx) as i64 - x).abs().max(((o / nx) as i64 - y).abs()))
                    .min();
                let expected = nearest.map_or(u8::MAX, |k| (k.max(1) - 1).min(255) as u8);
                assert_eq!(rings[c], expected, "{nx}×{ny}, cell {c}");
            }
        }
    }

    fn check_near(
        walls: &Walls,
        segments: &[Segment],
        x: [f64; 2],
        y: [f64; 2],
        rng: &mut ChaCha8Rng,
    ) {
        let mut near = Vec::new();
        for k in 0..20_000 {
            let mut p = [rng.random_range(x[0]..x[1]), rng.random_range(y[0]..y[1])];
            if k % 2 == 0 {
                // Near a wall.
                let s = &segments[k % segments.len()];
                let t = rng.random_range(0.0..1.0);
                p = [
                    s.a[0] + t * (s.b[0] - s.a[0]) + rng.random_range(-3.0..3.0),
                    s.a[1] + t * (s.b[1] - s.a[1]) + rng.random_range(-3.0..3.0),
                ];
            }
            let reach = rng.random_range(0.0..3.0);
            walls.near(p, reach, &mut near);
            assert!(near.windows(2).all(|w| w[0] < w[1]));
            for (w, s) in segments.iter().enumerate() {
                if s.distance(p) <= reach {
                    assert!(
                        near.contains(&(w as u32)),
                        "wall {w} at {} missed from {p:?}",
                        s.distance(p)
                    );
                }
            }
        }
    }
}
