//! Convex sets with exact projections (box, half-space, ball), polyhedra as constraint rows,
//! and the separable absolute value `ψ(x) = Σ μ_i |x_i|` (dry friction).

use crate::error::CoreError;
use crate::num::Num;
use crate::rows::ConstraintRows;
use crate::traits::{ConstraintSet, ConvexPart, ConvexSet};

fn check_finite(field: &'static str, v: &[f64]) -> Result<(), CoreError> {
    match v.iter().find(|x| x.is_nan()) {
        Some(x) => Err(CoreError::InvalidParameter {
            field,
            value: Num(*x).to_string(),
            reason: "NaN",
        }),
        None => Ok(()),
    }
}

/// The box `[lo, hi]` (bounds may be infinite).
#[derive(Debug, Clone, PartialEq)]
pub struct BoxSet {
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl BoxSet {
    /// The box `lo ≤ x ≤ hi`, checked: same lengths, no NaN, `lo ≤ hi`.
    pub fn new(lo: Vec<f64>, hi: Vec<f64>) -> Result<Self, CoreError> {
        if lo.len() != hi.len() {
            return Err(CoreError::DimensionMismatch {
                what: "box upper bound",
                expected: lo.len(),
                got: hi.len(),
            });
        }
        check_finite("box lower bound", &lo)?;
        check_finite("box upper bound", &hi)?;
        if let Some(i) = (0..lo.len()).find(|&i| lo[i] > hi[i]) {
            return Err(CoreError::InvalidParameter {
                field: "box bounds",
                value: format!("lo[{i}] = {} > hi[{i}] = {}", lo[i], hi[i]),
                reason: "empty box",
            });
        }
        // A lower bound of +∞ or an upper bound of −∞ holds no real number either: the box
        // [∞, ∞] projected everything to ∞, a state the next step refused as not finite.
        if let Some(i) =
            (0..lo.len()).find(|&i| lo[i] == f64::INFINITY || hi[i] == f64::NEG_INFINITY)
        {
            return Err(CoreError::InvalidParameter {
                field: "box bounds",
                value: format!("lo[{i}] = {}, hi[{i}] = {}", lo[i], hi[i]),
                reason: "empty box (a lower bound of +∞ or an upper bound of −∞)",
            });
        }
        Ok(Self { lo, hi })
    }

    /// Lower bounds.
    pub fn lo(&self) -> &[f64] {
        &self.lo
    }

    /// Upper bounds.
    pub fn hi(&self) -> &[f64] {
        &self.hi
    }
}

impl ConvexSet for BoxSet {
    fn dim(&self) -> usize {
        self.lo.len()
    }
    fn project(&self, y: &[f64], out: &mut [f64]) {
        for i in 0..y.len() {
            out[i] = y[i].clamp(self.lo[i], self.hi[i]);
        }
    }
}

impl ConstraintSet for BoxSet {
    fn dim(&self) -> usize {
        self.lo.len()
    }
    fn assemble(&mut self, _t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows) {
        // An infinite bound is no row: with the default infinite margin `∞ ≤ ∞` pushed a row
        // of value ∞, which every solver refuses (a box on the half-line could not run).
        for i in 0..q.len() {
            let below = q[i] - self.lo[i];
            if below <= margin && self.lo[i] != f64::NEG_INFINITY {
                rows.push(2 * i as u64, below, [(i, 1.0)]);
            }
            let above = self.hi[i] - q[i];
            if above <= margin && self.hi[i] != f64::INFINITY {
                rows.push(2 * i as u64 + 1, above, [(i, -1.0)]);
            }
        }
    }
}

/// The half-space `{x : aᵀx ≤ β}`.
#[derive(Debug, Clone, PartialEq)]
pub struct HalfSpace {
    /// Outward normal (not necessarily unit).
    pub a: Vec<f64>,
    /// Offset.
    pub beta: f64,
}

impl HalfSpace {
    /// `{x : aᵀx ≤ β}`, checked: `a` finite and `≠ 0`, `β` a number and not `−∞` (the empty
    /// set, whose projection was `−∞`).
    pub fn new(a: Vec<f64>, beta: f64) -> Result<Self, CoreError> {
        check_finite("half-space normal", &a)?;
        check_finite("half-space offset", &[beta])?;
        if let Some(x) = a.iter().find(|x| x.is_infinite()) {
            return Err(CoreError::InvalidParameter {
                field: "half-space normal",
                value: Num(*x).to_string(),
                reason: "not finite",
            });
        }
        if beta == f64::NEG_INFINITY {
            return Err(CoreError::InvalidParameter {
                field: "half-space offset",
                value: Num(beta).to_string(),
                reason: "−∞: the empty set",
            });
        }
        if a.iter().all(|&x| x == 0.0) {
            return Err(CoreError::InvalidParameter {
                field: "half-space normal",
                value: "0".into(),
                reason: "zero normal",
            });
        }
        Ok(Self { a, beta })
    }

    fn excess(&self, x: &[f64]) -> f64 {
        self.a.iter().zip(x).map(|(a, x)| a * x).sum::<f64>() - self.beta
    }
}

impl ConvexSet for HalfSpace {
    fn dim(&self) -> usize {
        self.a.len()
    }
    fn project(&self, y: &[f64], out: &mut [f64]) {
        let e = self.excess(y).max(0.0) / self.a.iter().map(|a| a * a).sum::<f64>();
        for i in 0..y.len() {
            out[i] = y[i] - e * self.a[i];
        }
    }
}

/// A polyhedron `{x : a_jᵀx ≤ β_j}`: no closed-form projection, so it is a [`ConstraintSet`]
/// whose rows `g_j = β_j − a_jᵀx` the projection solvers handle.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HalfSpaces {
    faces: Vec<HalfSpace>,
}

impl HalfSpaces {
    /// The intersection of `faces`, all of the same dimension.
    pub fn new(faces: Vec<HalfSpace>) -> Result<Self, CoreError> {
        if let Some(first) = faces.first()
            && let Some(f) = faces.iter().find(|f| f.a.len() != first.a.len())
        {
            return Err(CoreError::DimensionMismatch {
                what: "half-space normal",
                expected: first.a.len(),
                got: f.a.len(),
            });
        }
        Ok(Self { faces })
    }

    /// The faces.
    pub fn faces(&self) -> &[HalfSpace] {
        &self.faces
    }
}

impl ConstraintSet for HalfSpaces {
    fn dim(&self) -> usize {
        self.faces.first().map_or(0, |f| f.a.len())
    }
    fn assemble(&mut self, _t: f64, q: &[f64], margin: f64, rows: &mut ConstraintRows) {
        for (j, f) in self.faces.iter().enumerate() {
            let g = -f.excess(q);
            // A face at β = +∞ is the whole space: no row (as a box's infinite bound), not a
            // row of value ∞ under the default infinite margin.
            if g <= margin && f.beta != f64::INFINITY {
                rows.push(
                    j as u64,
                    g,
                    f.a.iter()
                        .enumerate()
                        .filter(|(_, a)| **a != 0.0)
                        .map(|(c, &a)| (c, -a)),
                );
            }
        }
    }
}

/// The closed ball `{x : |x − c| ≤ R}`. Its constraint `R − |x − c|` is concave, so a ball
/// is used through its exact projection, not through linearized rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Ball {
    center: Vec<f64>,
    radius: f64,
}

impl Ball {
    /// The ball of `center` and `radius ≥ 0`.
    pub fn new(center: Vec<f64>, radius: f64) -> Result<Self, CoreError> {
        check_finite("ball center", &center)?;
        if !(radius >= 0.0) {
            return Err(CoreError::InvalidParameter {
                field: "ball radius",
                value: Num(radius).to_string(),
                reason: "must be ≥ 0",
            });
        }
        Ok(Self { center, radius })
    }
}

impl ConvexSet for Ball {
    fn dim(&self) -> usize {
        self.center.len()
    }
    fn project(&self, y: &[f64], out: &mut [f64]) {
        let d = y
            .iter()
            .zip(&self.center)
            .map(|(y, c)| (y - c) * (y - c))
            .sum::<f64>()
            .sqrt();
        let s = if d > self.radius {
            self.radius / d
        } else {
            1.0
        };
        for i in 0..y.len() {
            out[i] = self.center[i] + s * (y[i] - self.center[i]);
        }
    }
}

/// `ψ(x) = Σ μ_i |x_i|` with `μ_i ≥ 0`: componentwise dry (Coulomb) friction.
#[derive(Debug, Clone, PartialEq)]
pub struct SeparableAbs {
    weights: Vec<f64>,
}

impl SeparableAbs {
    /// Friction levels `μ_i ≥ 0`.
    pub fn new(weights: Vec<f64>) -> Result<Self, CoreError> {
        if let Some(w) = weights.iter().find(|w| !(**w >= 0.0) || !w.is_finite()) {
            return Err(CoreError::InvalidParameter {
                field: "friction level",
                value: Num(*w).to_string(),
                reason: "must be finite and ≥ 0",
            });
        }
        Ok(Self { weights })
    }

    /// The levels `μ_i`.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }
}

impl ConvexPart for SeparableAbs {
    fn min_norm_selection(&self, x: &[f64], f: &[f64], out: &mut [f64]) {
        for i in 0..x.len() {
            let m = self.weights[i];
            out[i] = if x[i] > 0.0 {
                f[i] - m
            } else if x[i] < 0.0 {
                f[i] + m
            } else {
                // ∂|0| = [−1, 1]: f − μ s of least modulus is the soft threshold of f.
                f[i] - f[i].clamp(-m, m)
            };
        }
    }
    fn prox(&self, tau: f64, x: &[f64], out: &mut [f64]) {
        for i in 0..x.len() {
            let m = tau * self.weights[i];
            out[i] = x[i] - x[i].clamp(-m, m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The projection onto a convex set is characterized by `⟨y − p, z − p⟩ ≤ 0` for all z in
    /// the set; checked on sample points of the set.
    fn check_projection<S: ConvexSet>(set: &S, y: &[f64], samples: &[Vec<f64>]) {
        let mut p = vec![0.0; y.len()];
        set.project(y, &mut p);
        for z in samples {
            let ip: f64 = (0..y.len()).map(|i| (y[i] - p[i]) * (z[i] - p[i])).sum();
            assert!(ip <= 1e-12, "variational inequality fails: {ip}");
        }
    }

    #[test]
    fn exact_projections_satisfy_the_variational_inequality() {
        let b = BoxSet::new(vec![-1.0, 0.0], vec![1.0, 2.0]).unwrap();
        let corners = vec![
            vec![-1.0, 0.0],
            vec![1.0, 0.0],
            vec![-1.0, 2.0],
            vec![1.0, 2.0],
            vec![0.2, 1.3],
        ];
        for y in [[3.0, -1.0], [0.5, 0.5], [-4.0, 7.0]] {
            check_projection(&b, &y, &corners);
        }
        let h = HalfSpace::new(vec![1.0, 2.0], 1.0).unwrap();
        let pts = vec![vec![1.0, 0.0], vec![-3.0, 2.0], vec![0.0, -5.0]];
        check_projection(&h, &[2.0, 2.0], &pts);
        let ball = Ball::new(vec![1.0, 1.0], 2.0).unwrap();
        let on: Vec<Vec<f64>> = (0..12)
            .map(|k| {
                let a = k as f64 * 0.5;
                vec![1.0 + 2.0 * a.cos(), 1.0 + 2.0 * a.sin()]
            })
            .collect();
        check_projection(&ball, &[5.0, -3.0], &on);
        assert!((ball.distance(&[5.0, 1.0]) - 2.0).abs() < 1e-14);
    }

    #[test]
    fn bad_sets_are_rejected_with_the_field_named() {
        let e = BoxSet::new(vec![1.0], vec![0.0]).unwrap_err();
        assert!(e.to_string().contains("lo[0] = 1 > hi[0] = 0"), "{e}");
        assert!(
            Ball::new(vec![0.0], -1.0)
                .unwrap_err()
                .to_string()
                .contains("ball radius")
        );
        assert!(HalfSpace::new(vec![0.0, 0.0], 1.0).is_err());
        assert!(SeparableAbs::new(vec![f64::NAN]).is_err());
    }

    #[test]
    fn empty_sets_of_infinite_bounds_were_taken_and_projected_to_infinity() {
        // `aᵀx ≤ −∞` and the box `[∞, ∞]` hold no point: taken, they projected every state to
        // ±∞, which the next step refused as a non-finite state.
        let e = HalfSpace::new(vec![1.0], f64::NEG_INFINITY).unwrap_err();
        assert!(e.to_string().contains("half-space offset"), "{e}");
        assert!(HalfSpace::new(vec![f64::INFINITY], 1.0).is_err());
        let e = BoxSet::new(vec![f64::INFINITY], vec![f64::INFINITY]).unwrap_err();
        assert!(e.to_string().contains("empty box"), "{e}");
        assert!(BoxSet::new(vec![f64::NEG_INFINITY], vec![f64::NEG_INFINITY]).is_err());
        // Infinite bounds on the right side are fine: a half-line, the whole space.
        BoxSet::new(vec![0.0, f64::NEG_INFINITY], vec![f64::INFINITY, 1.0]).unwrap();
        let whole = HalfSpace::new(vec![1.0], f64::INFINITY).unwrap();
        let mut faces = HalfSpaces::new(vec![whole]).unwrap();
        let mut rows = ConstraintRows::new(1);
        faces.assemble(0.0, &[3.0], f64::INFINITY, &mut rows);
        assert_eq!(rows.len(), 0, "the whole space is no row");
    }

    #[test]
    fn friction_selection_is_minimal_norm_and_prox_is_soft_threshold() {
        let psi = SeparableAbs::new(vec![1.0, 1.0, 1.0, 2.0]).unwrap();
        let x = [0.0, 0.0, 1.0, -1.0];
        let f = [0.5, -3.0, 0.0, 0.0];
        let mut w = [0.0; 4];
        psi.min_norm_selection(&x, &f, &mut w);
        assert_eq!(w, [0.0, -2.0, -1.0, 2.0]);
        let mut p = [0.0; 4];
        psi.prox(0.5, &[0.2, -3.0, 0.6, -0.9], &mut p);
        let expect = [0.0, -2.5, 0.1, 0.0];
        for i in 0..4 {
            assert!((p[i] - expect[i]).abs() < 1e-15);
        }
    }

    #[test]
    fn polyhedron_rows_are_the_faces() {
        let mut poly = HalfSpaces::new(vec![
            HalfSpace::new(vec![1.0, 0.0], 1.0).unwrap(),
            HalfSpace::new(vec![0.0, 1.0], 5.0).unwrap(),
        ])
        .unwrap();
        let mut rows = ConstraintRows::new(2);
        poly.assemble(0.0, &[0.5, 0.0], 1.0, &mut rows);
        assert_eq!(rows.len(), 1);
        assert_eq!(rows.values(), &[0.5]);
        assert_eq!(rows.row(0), (&[0usize][..], &[-1.0][..]));
        // Only the face that is violated and not assembled counts as crossed.
        let none = ConstraintRows::new(2);
        assert_eq!(poly.crossed_outside(0.0, &[2.0, 6.0], &rows, 1e-12), 1);
        assert_eq!(poly.crossed_outside(0.0, &[2.0, 6.0], &none, 1e-12), 2);
    }
}
