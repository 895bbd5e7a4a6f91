//! Small SVG line charts for benchmark results.

use std::fmt::Write;

/// One line of a chart.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// CSS colour.
    pub color: &'static str,
    /// Dashed (for reference lines).
    pub dashed: bool,
    /// Points.
    pub points: Vec<(f64, f64)>,
}

/// A line chart with linear axes from 0 (x from below 0 when the data
/// are), ticks at the x values given.
pub fn line_chart(
    title: &str,
    x_label: &str,
    y_label: &str,
    x_ticks: &[f64],
    series: &[Series],
) -> String {
    let (w, h, left, right, top, bottom) = (640.0, 420.0, 64.0, 170.0, 40.0, 56.0);
    let x_max = series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).fold(1.0f64, f64::max);
    let y_max =
        series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).fold(1.0f64, f64::max) * 1.05;
    let x_min = series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).fold(0.0f64, f64::min);
    let px = |x: f64| left + (w - left - right) * (x - x_min) / (x_max - x_min);
    let py = |y: f64| h - bottom - (h - top - bottom) * y / y_max;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = write!(
        s,
        r#"<rect width="{w}" height="{h}" fill="white"/><text x="{}" y="22" font-size="15" text-anchor="middle">{title}</text>"#,
        (w - right + left) / 2.0
    );
    let (x0, y0, x1, y1) = (px(x_min), py(0.0), px(x_max), py(y_max));
    let _ = write!(s, r#"<path d="M{x0},{y1} L{x0},{y0} L{x1},{y0}" stroke="black" fill="none"/>"#);
    for &t in x_ticks {
        let _ = write!(
            s,
            r#"<line x1="{0}" y1="{y0}" x2="{0}" y2="{1}" stroke="black"/><text x="{0}" y="{2}" text-anchor="middle">{t}</text>"#,
            px(t),
            y0 + 5.0,
            y0 + 18.0
        );
    }
    let step = nice_step(y_max);
    let mut t = 0.0;
    while t <= y_max {
        let _ = write!(
            s,
            r##"<line x1="{x0}" y1="{0}" x2="{x1}" y2="{0}" stroke="#ddd"/><text x="{1}" y="{2}" text-anchor="end">{t}</text>"##,
            py(t),
            x0 - 6.0,
            py(t) + 4.0
        );
        t += step;
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{x_label}</text>"#,
        (x0 + x1) / 2.0,
        h - 14.0
    );
    let _ = write!(
        s,
        r#"<text x="16" y="{0}" text-anchor="middle" transform="rotate(-90 16 {0})">{y_label}</text>"#,
        (y0 + y1) / 2.0
    );
    for (i, ser) in series.iter().enumerate() {
        let d: Vec<String> = ser
            .points
            .iter()
            .enumerate()
            .map(|(k, p)| {
                format!("{}{:.1},{:.1}", if k == 0 { "M" } else { "L" }, px(p.0), py(p.1))
            })
            .collect();
        let dash = if ser.dashed { r#" stroke-dasharray="6 4""# } else { "" };
        let _ = write!(
            s,
            r#"<path d="{}" stroke="{}" stroke-width="2" fill="none"{dash}/>"#,
            d.join(" "),
            ser.color
        );
        for p in &ser.points {
            let _ = write!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{}"/>"#,
                px(p.0),
                py(p.1),
                ser.color
            );
        }
        let ly = top + 20.0 + 20.0 * i as f64;
        let _ = write!(
            s,
            r#"<line x1="{0}" y1="{ly}" x2="{1}" y2="{ly}" stroke="{2}" stroke-width="2"{dash}/><text x="{3}" y="{4}">{5}</text>"#,
            w - right + 12.0,
            w - right + 36.0,
            ser.color,
            w - right + 42.0,
            ly + 4.0,
            ser.name
        );
    }
    s.push_str("</svg>\n");
    s
}

fn nice_step(max: f64) -> f64 {
    let raw = max / 6.0;
    let mag = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(mag * 10.0)
}
