//! The figures `compare` draws: the side-by-side grid with heat maps of
//! each method's error, and the parameter sweeps.

use super::*;

/// Figure 2 of the forest paper as an SVG of PNG tiles: full (LB), local,
/// ambient matched, LB visualization, reference, and error heat maps.
pub(super) fn write_figure(
    path: &Path,
    a: &CompareArgs,
    rendered: &[Rendered],
    reference: &HdrImage,
) -> anyhow::Result<()> {
    let find = |pred: &dyn Fn(&MethodReport) -> bool| rendered.iter().find(|m| pred(&m.report));
    let lb = find(&|m| m.name == "lb auto").or_else(|| find(&|m| m.lighting == LightingMode::Lb));
    let mut tiles: Vec<(String, PathBuf)> = Vec::new();
    let dir = path.parent().unwrap_or(Path::new("."));
    let name_of = |p: &str| {
        PathBuf::from(p).file_name().map(|f| f.to_string_lossy().to_string()).unwrap_or_default()
    };
    if let Some(m) = lb {
        tiles.push((format!("(a) full: {}", m.report.name), name_of(&m.report.image).into()));
    }
    for (label, l) in
        [("(b) local", LightingMode::Local), ("(c) ambient matched", LightingMode::Ambient)]
    {
        if let Some(m) = find(&|m| m.lighting == l) {
            tiles.push((label.into(), name_of(&m.report.image).into()));
        }
    }
    // The LB light alone is a separate render of the auto scene's grids: the
    // (a) − (b) difference shows it without another LB solve.
    if let (Some(m), Some(l)) = (lb, find(&|m| m.lighting == LightingMode::Local)) {
        let diff = HdrImage {
            width: a.width,
            height: a.height,
            pixels: m
                .image
                .pixels
                .iter()
                .zip(&l.image.pixels)
                .map(|(p, q)| std::array::from_fn(|c| (p[c] - q[c]).max(0.0)))
                .collect(),
        };
        let (ldr, _) = reinhard(&diff, 0.18);
        write_png(&dir.join("lb-visualize.png"), a.width, a.height, &ldr)?;
        tiles.push(("(d) LB light alone".into(), "lb-visualize.png".into()));
    }
    tiles.push(("(e) reference (path traced)".into(), "reference.png".into()));
    if let Some(m) = find(&|m| m.lighting == LightingMode::Boulanger) {
        tiles.push(("(f) Boulanger et al.".into(), name_of(&m.report.image).into()));
    }
    for (label, m) in [
        ("error: full", lb),
        ("error: ambient", find(&|m| m.lighting == LightingMode::Ambient)),
        ("error: Boulanger", find(&|m| m.lighting == LightingMode::Boulanger)),
    ] {
        if let Some(m) = m {
            let file = format!("error-{}.png", m.report.name.replace(['³', ' ', '+'], ""));
            write_png(&dir.join(&file), a.width, a.height, &heat_map(&m.image, reference))?;
            tiles.push((format!("{label} (black 0, red 50 %, yellow ≥ 100 %)"), file.into()));
        }
    }
    let (tw, th) = (a.width as f64, a.height as f64 + 22.0);
    let cols = 3usize;
    let rows = tiles.len().div_ceil(cols);
    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" width="{}" height="{}" font-family="sans-serif" font-size="13"><rect width="100%" height="100%" fill="white"/>"#,
        tw * cols as f64,
        th * rows as f64
    );
    for (i, (label, file)) in tiles.iter().enumerate() {
        let (x, y) = ((i % cols) as f64 * tw, (i / cols) as f64 * th);
        // `href` for SVG 2 readers, `xlink:href` for older ones: both the file.
        s += &format!(
            r#"<text x="{}" y="{}">{}</text><image x="{x}" y="{}" width="{}" height="{}" href="{file}" xlink:href="{file}"/>"#,
            x + 4.0,
            y + 15.0,
            label,
            y + 20.0,
            a.width,
            a.height,
            file = file.display()
        );
    }
    s += "</svg>\n";
    std::fs::write(path, s).with_context(|| format!("{}: cannot write", path.display()))
}

/// Per-pixel relative luminance error as colour: black 0, red 0.5, yellow ≥ 1.
pub(super) fn heat_map(m: &HdrImage, r: &HdrImage) -> Vec<[u8; 3]> {
    m.pixels
        .iter()
        .zip(&r.pixels)
        .map(|(&p, &q)| {
            let lr = luminance(q).max(1e-4);
            let e = ((luminance(p) - lr).abs() / lr).clamp(0.0, 1.0);
            let red = (2.0 * e).min(1.0);
            let green = (2.0 * e - 1.0).max(0.0);
            [(red * 255.0) as u8, (green * 255.0) as u8, 0]
        })
        .collect()
}

/// Runs the LB failure-mode sweeps and charts each: LB's error against
/// the Monte Carlo reference beside the best constant's.
pub(super) fn write_sweeps(out: &Path) -> anyhow::Result<serde_json::Value> {
    let mut all = Vec::new();
    for sweep in sylva_light::studies::limits::failure_sweeps(true) {
        let lb: Vec<(f64, f64)> = sweep.points.iter().map(|p| (p.x, 100.0 * p.lb_error)).collect();
        let amb: Vec<(f64, f64)> =
            sweep.points.iter().map(|p| (p.x, 100.0 * p.ambient_error)).collect();
        let warned: Vec<(f64, f64)> =
            sweep.points.iter().filter(|p| p.warned).map(|p| (p.x, 100.0 * p.lb_error)).collect();
        let mut xs: Vec<f64> = sweep.points.iter().map(|p| p.x).collect();
        xs.sort_by(f64::total_cmp);
        let series = [
            Series { name: "LB".into(), color: "#2ca02c", dashed: false, points: sorted(lb) },
            Series {
                name: "constant ambient".into(),
                color: "#999999",
                dashed: true,
                points: sorted(amb),
            },
            Series {
                name: "LB, warned".into(),
                color: "#d62728",
                dashed: false,
                points: sorted(warned),
            },
        ];
        let file = out.join(format!("failure-{}.svg", sweep.name.replace(' ', "-")));
        std::fs::write(
            &file,
            line_chart(
                &format!("LB against Monte Carlo: {}", sweep.name),
                sweep.x_label,
                "relative RMS error of fluence, %",
                &xs,
                &series,
            ),
        )?;
        all.push(json!({ "name": sweep.name, "x_label": sweep.x_label, "chart": file, "points": sweep.points.iter().map(|p| json!({ "x": p.x, "lb_error": p.lb_error, "ambient_error": p.ambient_error, "warned": p.warned, "lb_ms": p.lb_ms, "mc_ms": p.mc_ms })).collect::<Vec<_>>() }));
    }
    Ok(serde_json::Value::Array(all))
}

pub(super) fn sorted(mut v: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}
