//! Test helpers written independently of the library: an exact QP by active-set enumeration,
//! a dense solve, and the least-squares fit of an observed order.
#![allow(dead_code)]

/// Solves the square system `a x = y` by Gaussian elimination; `None` when singular.
pub fn solve_dense(mut a: Vec<Vec<f64>>, mut y: Vec<f64>) -> Option<Vec<f64>> {
    let k = y.len();
    for col in 0..k {
        let piv = (col..k).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs() < 1e-10 {
            return None;
        }
        a.swap(col, piv);
        y.swap(col, piv);
        for r in col + 1..k {
            let f = a[r][col] / a[col][col];
            for c in col..k {
                a[r][c] -= f * a[col][c];
            }
            y[r] -= f * y[col];
        }
    }
    let mut x = vec![0.0; k];
    for r in (0..k).rev() {
        let s: f64 = (r + 1..k).map(|c| a[r][c] * x[c]).sum();
        x[r] = (y[r] - s) / a[r][r];
    }
    Some(x)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `min ½|v − w|² s.t. b + J v ≥ 0` exactly, by enumerating active sets (small problems):
/// returns `(v*, λ*)` with `v* = w + Jᵀλ*` of least objective among all KKT points whose
/// active Gram matrix is nonsingular. `j` is dense, one row per constraint.
pub fn exact_qp(w: &[f64], j: &[Vec<f64>], b: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let (n, m) = (w.len(), b.len());
    let mut best: Option<(f64, Vec<f64>, Vec<f64>)> = None;
    for mask in 0u32..(1 << m) {
        let act: Vec<usize> = (0..m).filter(|i| mask >> i & 1 == 1).collect();
        if act.len() > n {
            continue;
        }
        let gram: Vec<Vec<f64>> = act
            .iter()
            .map(|&a| act.iter().map(|&c| dot(&j[a], &j[c])).collect())
            .collect();
        let rhs: Vec<f64> = act.iter().map(|&a| -b[a] - dot(&j[a], w)).collect();
        let Some(la) = solve_dense(gram, rhs) else {
            continue;
        };
        if la.iter().any(|&l| l < -1e-10) {
            continue;
        }
        let mut v = w.to_vec();
        for (k, &a) in act.iter().enumerate() {
            for c in 0..n {
                v[c] += j[a][c] * la[k];
            }
        }
        if (0..m).any(|i| b[i] + dot(&j[i], &v) < -1e-10) {
            continue;
        }
        let obj = 0.5 * v.iter().zip(w).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
        if best.as_ref().is_none_or(|(o, _, _)| obj < *o - 1e-14) {
            let mut lam = vec![0.0; m];
            for (k, &a) in act.iter().enumerate() {
                lam[a] = la[k].max(0.0);
            }
            best = Some((obj, v, lam));
        }
    }
    let (_, v, l) = best.expect("a feasible strictly convex QP has a KKT point");
    (v, l)
}

/// Least-squares slope of `log e` against `log h`, and the coefficient of determination R².
pub fn fit_order(h: &[f64], e: &[f64]) -> (f64, f64) {
    let x: Vec<f64> = h.iter().map(|v| v.ln()).collect();
    let y: Vec<f64> = e.iter().map(|v| v.ln()).collect();
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(&y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    let syy: f64 = y.iter().map(|b| (b - my) * (b - my)).sum();
    let slope = sxy / sxx;
    (slope, sxy * sxy / (sxx * syy))
}
