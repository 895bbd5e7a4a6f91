//! Pictures of an LB solution: three orthogonal slices through the middle
//! of the grid and a projection, side by side, in the solution's colours.

use crate::lb::{GridDims, Solution};
use image::{Rgb, RgbImage};
use std::path::Path;

/// Pixels along a panel's longer side.
const PANEL: u32 = 256;

/// Writes `solution` as a PNG: side slice (x–y at mid z), front slice (z–y
/// at mid x), top slice (x–z at mid y) and the side view's mean along z.
/// Values are scaled so the 99.5th percentile is white, with gamma 2.2.
pub fn write_solution_png(path: &Path, solution: &Solution) -> crate::Result<()> {
    let d = solution.dims;
    let ch: Vec<&[f32]> = solution.channels.iter().map(|c| c.total.as_slice()).collect();
    let scale = 1.0 / percentile(&ch, 0.995).max(1e-12);
    let (cx, cy, cz) = (d.nx / 2, d.ny / 2, d.nz / 2);
    let value = |x: usize, y: usize, z: usize| -> [f32; 3] {
        let i = d.index(x, y, z);
        [ch[0][i], ch[1][i], ch[2][i]]
    };
    let mean_z = |x: usize, y: usize| -> [f32; 3] {
        let mut s = [0.0; 3];
        for z in 0..d.nz {
            let v = value(x, y, z);
            (0..3).for_each(|c| s[c] += v[c] / d.nz as f32);
        }
        s
    };
    let panels: Vec<RgbImage> = vec![
        panel(d.nx, d.ny, |u, v| value(u, v, cz), scale),
        panel(d.nz, d.ny, |u, v| value(cx, v, u), scale),
        panel(d.nx, d.nz, |u, v| value(u, cy, v), scale),
        panel(d.nx, d.ny, mean_z, scale),
    ];
    let gap = 8;
    let width = panels.iter().map(|p| p.width()).sum::<u32>() + gap * (panels.len() as u32 - 1);
    let height = panels.iter().map(|p| p.height()).max().unwrap_or(1);
    let mut out = RgbImage::from_pixel(width, height, Rgb([40, 40, 48]));
    let mut x0 = 0;
    for p in &panels {
        image::imageops::overlay(&mut out, p, x0 as i64, 0);
        x0 += p.width() + gap;
    }
    out.save(path).map_err(|error| crate::Error::Image { path: path.to_path_buf(), error })
}

/// The grid of `dims` drawn up to [`PANEL`] pixels, `v` (second axis) up.
fn panel(nu: usize, nv: usize, f: impl Fn(usize, usize) -> [f32; 3], scale: f32) -> RgbImage {
    let zoom = (PANEL / nu.max(nv) as u32).max(1);
    let (w, h) = (nu as u32 * zoom, nv as u32 * zoom);
    RgbImage::from_fn(w, h, |px, py| {
        let (u, v) = ((px / zoom) as usize, nv - 1 - (py / zoom) as usize);
        let c = f(u, v);
        Rgb(c.map(|x| ((x * scale).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8))
    })
}

fn percentile(channels: &[&[f32]], q: f64) -> f32 {
    let mut all: Vec<f32> =
        channels.iter().flat_map(|c| c.iter().copied()).filter(|v| v.is_finite()).collect();
    if all.is_empty() {
        return 1.0;
    }
    let k = ((all.len() - 1) as f64 * q) as usize;
    let (_, v, _) = all.select_nth_unstable_by(k, f32::total_cmp);
    *v
}

/// The grid dimensions' shape in `.npy` order for a per-channel result.
pub fn solution_shape(d: GridDims) -> [u64; 4] {
    [3, d.nz as u64, d.ny as u64, d.nx as u64]
}
