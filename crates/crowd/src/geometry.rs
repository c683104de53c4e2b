//! Polygons and segments: containment, distances and closest points.

/// A segment `[a, b]` (a wall, or an exit line).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// First end.
    pub a: [f64; 2],
    /// Second end.
    pub b: [f64; 2],
}

impl Segment {
    /// The closest point of the segment to `p`.
    pub fn closest(&self, p: [f64; 2]) -> [f64; 2] {
        let d = [self.b[0] - self.a[0], self.b[1] - self.a[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        let t = if len2 > 0.0 {
            (((p[0] - self.a[0]) * d[0] + (p[1] - self.a[1]) * d[1]) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        [self.a[0] + t * d[0], self.a[1] + t * d[1]]
    }

    /// Euclidean distance from `p`.
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        let c = self.closest(p);
        ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2)).sqrt()
    }

    /// The length.
    pub fn length(&self) -> f64 {
        (self.b[0] - self.a[0]).hypot(self.b[1] - self.a[1])
    }

    /// The unit normal on the left of `a → b` (the walkable side of a wall).
    pub fn left_normal(&self) -> [f64; 2] {
        let d = [self.b[0] - self.a[0], self.b[1] - self.a[1]];
        let l = (d[0] * d[0] + d[1] * d[1]).sqrt();
        [-d[1] / l, d[0] / l]
    }
}

/// A simple polygon given by its vertices (no repeated closing vertex).
#[derive(Debug, Clone, PartialEq)]
pub struct Polygon {
    /// Vertices in order.
    pub vertices: Vec<[f64; 2]>,
}

impl Polygon {
    /// Twice the signed area (positive when counter-clockwise), by the shoelace formula about
    /// the first vertex: about the origin it cancelled every digit far from it (a door of
    /// 1 m² at (3·10⁸, 3·10⁸) m had area 0, a room of 36 m² at 10⁹ m too).
    pub fn signed_area2(&self) -> f64 {
        let v = &self.vertices;
        let Some(&o) = v.first() else {
            return 0.0;
        };
        (1..v.len().saturating_sub(1))
            .map(|i| {
                let (p, q) = (v[i], v[i + 1]);
                (p[0] - o[0]) * (q[1] - o[1]) - (q[0] - o[0]) * (p[1] - o[1])
            })
            .sum()
    }

    /// The area.
    pub fn area(&self) -> f64 {
        0.5 * self.signed_area2().abs()
    }

    /// The same polygon, counter-clockwise if `ccw`, clockwise otherwise.
    pub fn oriented(mut self, ccw: bool) -> Self {
        if (self.signed_area2() > 0.0) != ccw {
            self.vertices.reverse();
        }
        self
    }

    /// Point in polygon (even–odd rule).
    pub fn contains(&self, p: [f64; 2]) -> bool {
        ring_contains(&self.vertices, p)
    }

    /// Two edges that cross (not neighbours sharing their common vertex), if any: a polygon
    /// whose boundary crosses itself has no clear inside (`(i, j)`: edges `v_i → v_{i+1}` and
    /// `v_j → v_{j+1}`). Edges of zero length are skipped, but their neighbours are then
    /// taken as not adjacent: the scene refuses repeated vertices before asking.
    pub fn self_intersection(&self) -> Option<(usize, usize)> {
        let v = &self.vertices;
        let n = v.len();
        let orient = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
            let d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            if d > 0.0 {
                1
            } else if d < 0.0 {
                -1
            } else {
                0
            }
        };
        let on = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
            c[0] >= a[0].min(b[0])
                && c[0] <= a[0].max(b[0])
                && c[1] >= a[1].min(b[1])
                && c[1] <= a[1].max(b[1])
        };
        let cross = |p1: [f64; 2], p2: [f64; 2], q1: [f64; 2], q2: [f64; 2]| {
            let (o1, o2) = (orient(p1, p2, q1), orient(p1, p2, q2));
            let (o3, o4) = (orient(q1, q2, p1), orient(q1, q2, p2));
            (o1 != o2 && o3 != o4)
                || (o1 == 0 && on(p1, p2, q1))
                || (o2 == 0 && on(p1, p2, q2))
                || (o3 == 0 && on(q1, q2, p1))
                || (o4 == 0 && on(q1, q2, p2))
        };
        let edge = |i: usize| (v[i], v[(i + 1) % n]);
        for i in 0..n {
            let (a, b) = edge(i);
            if a == b {
                continue;
            }
            for j in i + 1..n {
                // Neighbours share a vertex: skip them (the first and the last edge too).
                if j == i + 1 || (i == 0 && j == n - 1) {
                    continue;
                }
                let (c, d) = edge(j);
                if c == d {
                    continue;
                }
                if cross(a, b, c, d) {
                    return Some((i, j));
                }
            }
        }
        None
    }
}

/// Whether segments `p1 → p2` and `q1 → q2` cross at one point inside both (each one's ends
/// strictly on either side of the other's line): touching at an end or running along each
/// other is not crossing.
pub fn segments_cross(p1: [f64; 2], p2: [f64; 2], q1: [f64; 2], q2: [f64; 2]) -> bool {
    // Which side of `a → b` the point `c` is on: 1, −1, or 0 on the line (`signum` gives 1
    // for 0).
    let side = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        let d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        (d > 0.0) as i8 - (d < 0.0) as i8
    };
    let strictly = |x: i8, y: i8| x * y == -1;
    strictly(side(p1, p2, q1), side(p1, p2, q2)) && strictly(side(q1, q2, p1), side(q1, q2, p2))
}

/// Point in the polygon with vertices `v` (even–odd rule), without building a [`Polygon`].
pub fn ring_contains(v: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut inside = false;
    let mut j = v.len() - 1;
    for i in 0..v.len() {
        let (a, b) = (v[i], v[j]);
        if (a[1] > p[1]) != (b[1] > p[1])
            && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0]
        {
            inside = !inside;
        }
        j = i;
    }
    inside
}

impl Polygon {
    /// The edges `v_i → v_{i+1}`.
    pub fn edges(&self) -> impl Iterator<Item = Segment> + '_ {
        let v = &self.vertices;
        (0..v.len()).map(move |i| Segment {
            a: v[i],
            b: v[(i + 1) % v.len()],
        })
    }

    /// Bounding box `(min, max)`.
    pub fn bounds(&self) -> ([f64; 2], [f64; 2]) {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in &self.vertices {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }

    /// Distance from `p` to the boundary.
    pub fn boundary_distance(&self, p: [f64; 2]) -> f64 {
        self.edges()
            .map(|e| e.distance(p))
            .fold(f64::INFINITY, f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_door_far_from_the_origin_kept_its_area() {
        // About the origin, the shoelace formula gave this 1 m² door at (3·10⁸, 3·10⁸) m
        // twice an area of 0.
        let x = 3e8;
        let door = Polygon {
            vertices: vec![
                [x + 9.5, x + 4.0],
                [x + 10.0, x + 4.0],
                [x + 10.0, x + 6.0],
                [x + 9.5, x + 6.0],
            ],
        };
        assert_eq!(door.signed_area2(), 2.0);
        assert_eq!(door.clone().oriented(false).signed_area2(), -2.0);
    }

    #[test]
    fn segments_cross_only_through_both_interiors() {
        assert!(segments_cross(
            [0.0, 0.0],
            [2.0, 2.0],
            [0.0, 2.0],
            [2.0, 0.0]
        ));
        // Touching at an end, a T, and running along each other are not crossing.
        assert!(!segments_cross(
            [0.0, 0.0],
            [1.0, 1.0],
            [1.0, 1.0],
            [2.0, 0.0]
        ));
        assert!(!segments_cross(
            [0.0, 0.0],
            [2.0, 0.0],
            [1.0, 0.0],
            [1.0, 1.0]
        ));
        assert!(!segments_cross(
            [0.0, 0.0],
            [2.0, 0.0],
            [1.0, 0.0],
            [3.0, 0.0]
        ));
        assert!(!segments_cross(
            [0.0, 0.0],
            [1.0, 0.0],
            [2.0, -1.0],
            [2.0, 1.0]
        ));
    }

    #[test]
    fn square_containment_distance_and_orientation() {
        let sq = Polygon {
            vertices: vec![[0.0, 0.0], [0.0, 2.0], [2.0, 2.0], [2.0, 0.0]],
        };
        assert!(sq.signed_area2() < 0.0);
        let sq = sq.oriented(true);
        assert!(sq.signed_area2() > 0.0 && (sq.area() - 4.0).abs() < 1e-15);
        assert!(sq.contains([1.0, 1.0]) && !sq.contains([3.0, 1.0]));
        assert!((sq.boundary_distance([0.5, 1.0]) - 0.5).abs() < 1e-15);
        // CCW: the left normal of every edge points inside.
        for e in sq.edges() {
            let m = [(e.a[0] + e.b[0]) / 2.0, (e.a[1] + e.b[1]) / 2.0];
            let n = e.left_normal();
            assert!(sq.contains([m[0] + 0.1 * n[0], m[1] + 0.1 * n[1]]));
        }
        let s = Segment {
            a: [0.0, 0.0],
            b: [1.0, 0.0],
        };
        assert_eq!(s.closest([2.0, 1.0]), [1.0, 0.0]);
        assert!((s.distance([0.5, -2.0]) - 2.0).abs() < 1e-15);
    }
}
