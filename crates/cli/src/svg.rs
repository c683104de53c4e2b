//! Log–log line plots as standalone SVG text (convergence and work–precision figures), so the
//! commands that measure also draw, with no plotting dependency.

use std::fmt::Write as _;

/// One curve: points joined by a line, each marked.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// `(x, y)`, both > 0.
    pub points: Vec<(f64, f64)>,
    /// Draw the joining line dashed (for fits and references).
    pub dashed: bool,
}

/// A log–log plot.
#[derive(Debug, Clone)]
pub struct LogLog {
    /// Title above the plot.
    pub title: String,
    /// Label of the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// The curves.
    pub series: Vec<Series>,
}

const COLORS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
];

fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    // Enough ticks to read a value off even a narrow range.
    let mantissas: &[f64] = match hi / lo {
        r if r < 20.0 => &[1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0],
        r if r < 300.0 => &[1.0, 2.0, 5.0],
        _ => &[1.0],
    };
    let mut out = Vec::new();
    for e in a..=b {
        for m in mantissas {
            let v = m * 10f64.powi(e);
            if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                out.push(v);
            }
        }
    }
    out
}

fn label(v: f64) -> String {
    if (1e-3..1e4).contains(&v) {
        format!("{}", (v * 1e6).round() / 1e6)
    } else {
        format!("{v:.0e}")
    }
}

impl LogLog {
    /// The SVG document.
    pub fn render(&self) -> String {
        let (w, h) = (770.0, 480.0);
        let (left, right, top, bottom) = (80.0, 270.0, 40.0, 60.0);
        let pts = self.series.iter().flat_map(|s| s.points.iter());
        let finite: Vec<(f64, f64)> = pts
            .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
            .copied()
            .collect();
        let (mut x0, mut x1, mut y0, mut y1) = finite.iter().fold(
            (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64),
            |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
        );
        if finite.is_empty() {
            (x0, x1, y0, y1) = (1.0, 10.0, 1.0, 10.0);
        }
        // Pad a little in log space, and to whole ticks when the range is wide.
        let pad = |a: f64, b: f64| {
            let (la, lb) = (a.log10(), b.log10());
            let p = 0.05 * (lb - la).max(0.2);
            (10f64.powf(la - p), 10f64.powf(lb + p))
        };
        (x0, x1) = pad(x0, x1);
        (y0, y1) = pad(y0, y1);
        let px = |x: f64| {
            left + (x.log10() - x0.log10()) / (x1.log10() - x0.log10()) * (w - left - right)
        };
        let py = |y: f64| {
            h - bottom - (y.log10() - y0.log10()) / (y1.log10() - y0.log10()) * (h - top - bottom)
        };

        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{}" y="22" text-anchor="middle" font-size="15">{}</text>"#,
            (left + w - right) / 2.0,
            esc(&self.title)
        );
        for t in ticks(x0, x1) {
            let x = px(t);
            let _ = writeln!(
                s,
                r##"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{:.1}" stroke="#ddd"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
                h - bottom,
                h - bottom + 16.0,
                label(t)
            );
        }
        for t in ticks(y0, y1) {
            let y = py(t);
            let _ = writeln!(
                s,
                r##"<line x1="{left}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#ddd"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"##,
                w - right,
                left - 6.0,
                y + 4.0,
                label(t)
            );
        }
        let _ = writeln!(
            s,
            r#"<rect x="{left}" y="{top}" width="{:.1}" height="{:.1}" fill="none" stroke="black"/>"#,
            w - left - right,
            h - top - bottom
        );
        let _ = writeln!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            (left + w - right) / 2.0,
            h - 18.0,
            esc(&self.x_label)
        );
        let _ = writeln!(
            s,
            r#"<text transform="translate(20,{:.1}) rotate(-90)" text-anchor="middle">{}</text>"#,
            (top + h - bottom) / 2.0,
            esc(&self.y_label)
        );
        for (k, series) in self.series.iter().enumerate() {
            let color = COLORS[k % COLORS.len()];
            let path: Vec<String> = series
                .points
                .iter()
                .filter(|(x, y)| *x > 0.0 && *y > 0.0)
                .map(|&(x, y)| format!("{:.1},{:.1}", px(x), py(y)))
                .collect();
            let dash = if series.dashed {
                r#" stroke-dasharray="6,4""#
            } else {
                ""
            };
            let _ = writeln!(
                s,
                r#"<polyline points="{}" fill="none" stroke="{color}" stroke-width="1.6"{dash}/>"#,
                path.join(" ")
            );
            if !series.dashed {
                for p in &path {
                    let (x, y) = p.split_once(',').expect("x,y");
                    let _ = writeln!(s, r#"<circle cx="{x}" cy="{y}" r="3.2" fill="{color}"/>"#);
                }
            }
            let ly = top + 14.0 + 20.0 * k as f64;
            let _ = writeln!(
                s,
                r#"<line x1="{:.1}" y1="{ly:.1}" x2="{:.1}" y2="{ly:.1}" stroke="{color}" stroke-width="2"{dash}/><text x="{:.1}" y="{:.1}">{}</text>"#,
                w - right + 10.0,
                w - right + 34.0,
                w - right + 40.0,
                ly + 4.0,
                esc(&series.name)
            );
        }
        s.push_str("</svg>\n");
        s
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// Least squares fit of `log y = a + p log x`: `(p, a, r²)`.
pub fn fit_power(points: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0)
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let syy: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
    if sxx == 0.0 {
        return None;
    }
    let p = sxy / sxx;
    let r2 = if syy == 0.0 {
        1.0
    } else {
        sxy * sxy / (sxx * syy)
    };
    Some((p, my - p * mx, r2))
}

/// The half-width of the 95 % confidence interval of the order fitted by [`fit_power`]
/// (least squares on `ln y = p ln x + c`: standard error of the slope times Student's t with
/// `n − 2` degrees of freedom); `None` with fewer than 3 points.
pub fn order_interval(points: &[(f64, f64)]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0)
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = pts.len();
    if n < 3 {
        return None;
    }
    let nf = n as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / nf;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / nf;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let syy: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
    if sxx == 0.0 {
        return None;
    }
    let sse = (syy - sxy * sxy / sxx).max(0.0);
    let se = (sse / (nf - 2.0) / sxx).sqrt();
    // Student's t, 97.5 % quantile, 1..=30 degrees of freedom; 1.96 beyond.
    const T975: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    let t = T975.get(n - 3).copied().unwrap_or(1.96);
    Some(t * se)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_order_interval_is_zero_on_a_power_law_and_covers_noise() {
        let exact: Vec<(f64, f64)> = [0.1, 0.2, 0.5, 1.0]
            .iter()
            .map(|&h: &f64| (h, 3.0 * h.powf(0.5)))
            .collect();
        assert!(order_interval(&exact).unwrap() < 1e-12);
        // ln y = 0.5 ln h ± 0.1: slope 0.5 within the interval, which is not zero.
        let noisy: Vec<(f64, f64)> = [0.1, 0.2, 0.5, 1.0, 2.0]
            .iter()
            .zip([0.1, -0.1, 0.1, -0.1, 0.1])
            .map(|(&h, e): (&f64, f64)| (h, (0.5 * h.ln() + e).exp()))
            .collect();
        let (p, _, _) = fit_power(&noisy).unwrap();
        let w = order_interval(&noisy).unwrap();
        assert!(w > 0.01 && (p - 0.5).abs() <= w, "order {p} ± {w}");
        assert!(order_interval(&exact[..2]).is_none());
    }

    #[test]
    fn a_power_law_is_fitted_exactly() {
        let pts: Vec<(f64, f64)> = [0.1, 0.2, 0.5, 1.0]
            .iter()
            .map(|&h: &f64| (h, 3.0 * h.powf(0.5)))
            .collect();
        let (p, a, r2) = fit_power(&pts).unwrap();
        assert!(
            (p - 0.5).abs() < 1e-12 && (a - 3f64.ln()).abs() < 1e-12 && (r2 - 1.0).abs() < 1e-12
        );
    }

    #[test]
    fn a_plot_is_an_svg_document_with_every_series() {
        let plot = LogLog {
            title: "t <1>".into(),
            x_label: "h".into(),
            y_label: "e".into(),
            series: vec![
                Series {
                    name: "a".into(),
                    points: vec![(0.1, 1.0), (1.0, 3.0)],
                    dashed: false,
                },
                Series {
                    name: "b".into(),
                    points: vec![(0.1, 2.0), (1.0, 4.0)],
                    dashed: true,
                },
            ],
        };
        let svg = plot.render();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<polyline").count(), 2);
        assert!(svg.contains("t &lt;1&gt;"));
    }
}
