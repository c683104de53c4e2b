//! The crowd's constraint set: disk–disk and disk–wall gaps near a configuration, as rows.

use moreau_core::{ConstraintRows, ConstraintSet};

use crate::broad::BroadPhase;
use crate::geometry::Segment;

/// Marks a wall constraint's key (people ids stay below 2³¹).
const WALL_BIT: u64 = 1 << 31;

/// `g_ij = |q_i − q_j| − r_i − r_j` and `g_iw = dist(q_i, wall w) − r_i`, both convex in `q`,
/// so the linearized set lies inside the feasible set. Keys are built from the persons' stable
/// ids, so multipliers warm-start across steps and removals.
#[derive(Debug)]
pub struct CrowdConstraints {
    pub(crate) walls: Vec<Segment>,
    pub(crate) radius: Vec<f64>,
    pub(crate) ids: Vec<u32>,
    broad: Box<dyn BroadPhase>,
    pairs: Vec<(u32, u32)>,
    // The post-step check's rows and keys, reused from step to step.
    check: ConstraintRows,
    crossed: Vec<u64>,
}

impl CrowdConstraints {
    /// Constraints for disks of `radius` (with stable `ids`) among `walls`.
    pub fn new(
        walls: Vec<Segment>,
        radius: Vec<f64>,
        ids: Vec<u32>,
        broad: Box<dyn BroadPhase>,
    ) -> Self {
        assert_eq!(radius.len(), ids.len());
        Self {
            walls,
            radius,
            ids,
            broad,
            pairs: Vec::new(),
            check: ConstraintRows::default(),
            crossed: Vec::new(),
        }
    }

    /// The broad phase's name.
    pub fn broad_phase(&self) -> &'static str {
        self.broad.name()
    }

    /// The key of the pair of persons with ids `a`, `b`.
    pub fn pair_key(a: u32, b: u32) -> u64 {
        ((a.min(b) as u64) << 32) | a.max(b) as u64
    }

    /// The key of person `id` against wall `w`.
    pub fn wall_key(id: u32, w: usize) -> u64 {
        ((id as u64) << 32) | WALL_BIT | w as u64
    }
}

impl ConstraintSet for CrowdConstraints {
    fn dim(&self) -> usize {
        2 * self.radius.len()
    }

    /// As the default, with the rows kept from step to step, and the assembled keys searched
    /// only for the (usually no) rows violated beyond `tol`.
    fn crossed_outside(
        &mut self,
        t: f64,
        q: &[f64],
        assembled: &ConstraintRows,
        tol: f64,
    ) -> usize {
        let mut check = std::mem::take(&mut self.check);
        check.clear(self.dim());
        self.assemble(t, q, -tol, &mut check);
        self.crossed.clear();
        self.crossed.extend(
            check
                .keys()
                .iter()
                .zip(check.values())
                .filter(|&(_, &g)| g < -tol)
                .map(|(&k, _)| k),
        );
        self.check = check;
        if self.crossed.is_empty() {
            return 0;
        }
        self.crossed.sort_unstable();
        let known = assembled
            .keys()
            .iter()
            .filter(|k| self.crossed.binary_search(k).is_ok())
            .count();
        self.crossed.len() - known
    }

    fn assemble(&mut self, _t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows) {
        self.broad.pairs(q, &self.radius, margin, &mut self.pairs);
        for &(i, j) in &self.pairs {
            let (i, j) = (i as usize, j as usize);
            let (dx, dy) = (q[2 * i] - q[2 * j], q[2 * i + 1] - q[2 * j + 1]);
            let d = (dx * dx + dy * dy).sqrt();
            // Coincident centres: any unit direction is a subgradient.
            let e = if d > 0.0 {
                [dx / d, dy / d]
            } else {
                [1.0, 0.0]
            };
            let g = d - self.radius[i] - self.radius[j];
            rows.push(
                Self::pair_key(self.ids[i], self.ids[j]),
                g,
                [
                    (2 * i, e[0]),
                    (2 * i + 1, e[1]),
                    (2 * j, -e[0]),
                    (2 * j + 1, -e[1]),
                ],
            );
        }
        for i in 0..self.radius.len() {
            let p = [q[2 * i], q[2 * i + 1]];
            for (w, wall) in self.walls.iter().enumerate() {
                let c = wall.closest(p);
                let (ex, ey) = (p[0] - c[0], p[1] - c[1]);
                let d = (ex * ex + ey * ey).sqrt();
                let g = d - self.radius[i];
                if g > margin {
                    continue;
                }
                // On the wall itself: the walkable side is the wall's left.
                let n = if d > 0.0 {
                    [ex / d, ey / d]
                } else {
                    wall.left_normal()
                };
                rows.push(
                    Self::wall_key(self.ids[i], w),
                    g,
                    [(2 * i, n[0]), (2 * i + 1, n[1])],
                );
            }
        }
    }

    /// Two disks close by at most `|v_i| + |v_j|` per unit time and a disk closes on a wall at
    /// `|v_i|`; `v` can exceed the desired `w` when pushed, hence the factor, and the check
    /// after the step catches the rest.
    fn margin(&self, _q: &[f64], w: &[f64], mu: f64) -> f64 {
        let vmax = w
            .chunks_exact(2)
            .map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt())
            .fold(0.0, f64::max);
        let rmin = self.radius.iter().cloned().fold(f64::INFINITY, f64::min);
        3.0 * mu * vmax + 0.05 * rmin
    }
}
