//! Per-crown diagnosis for `compare`: which instance each pixel shows, and
//! each instance's mean indirect light for the reference and every method,
//! so a method's error can be placed: a wrong environment (every crown of
//! a stand off together, contrast between crowns lost) or a wrong species
//! field (one model's crowns off wherever they stand).

use glam::Vec3;
use serde::Serialize;
use std::path::Path;
use sylva_accel::{Ray, SceneAccel};
use sylva_scene::Scene;
use sylva_scene::color::luminance;
use sylva_scene::film::write_png;

/// A method's indirect light at a pixel, by the pixel's index.
pub type PixelLight<'a> = Box<dyn Fn(usize) -> [f32; 3] + 'a>;

/// Crowns with fewer pixels than this are left out of the table: their
/// means are edge pixels and noise.
pub const MIN_PIXELS: usize = 20;

/// The camera ray through point (`x`, `y`) of the film, in pixels from its
/// top-left corner: the same pinhole as the render kernel's `camera_ray`.
fn camera_ray(scene: &Scene, width: u32, height: u32, x: f32, y: f32) -> Ray {
    let c = &scene.camera;
    let aspect = width as f32 / height as f32;
    let sx = (2.0 * x / width as f32 - 1.0) * c.tan_half_fov_y * aspect;
    let sy = (1.0 - 2.0 * y / height as f32) * c.tan_half_fov_y;
    Ray::new(c.position, (c.forward + c.right * sx + c.up * sy).normalize())
}

/// Distance along `ray` to the ground plane in front, if the scene has one.
fn ground_distance(scene: &Scene, ray: &Ray) -> f32 {
    match scene.ground {
        Some(_) if ray.dir.y < 0.0 => -ray.origin.y / ray.dir.y,
        _ => f32::INFINITY,
    }
}

/// Per pixel, the instance its centre's camera ray meets first (alpha
/// test included; `accel`: the scene's structures on the CPU), or `None`
/// for the sky or the ground in front.
pub fn instance_ids(
    scene: &Scene,
    accel: &SceneAccel,
    width: u32,
    height: u32,
) -> Vec<Option<u32>> {
    let mut ids = Vec::with_capacity((width * height) as usize);
    for y in 0..height {
        for x in 0..width {
            let ray = camera_ray(scene, width, height, x as f32 + 0.5, y as f32 + 0.5);
            let hit = accel.closest(scene, &ray, 0.0, ground_distance(scene, &ray));
            ids.push(hit.map(|h| h.instance));
        }
    }
    ids
}

/// Camera rays per pixel side that [`cloud_pixels`] casts.
pub const CLOUD_RAYS_PER_SIDE: u32 = 4;

/// Per pixel, whether any of its camera rays (a 4 × 4 grid over the
/// pixel) crosses a cloud's box before its first surface: where a method
/// that draws no clouds (`local`, `boulanger`) misses the cloud itself,
/// in front of a crown or behind its gaps. Such pixels' error is the
/// cloud's, not the leaves' light, and `compare` reports them apart. The
/// box bounds the cloud's density, so the mask is conservative: it can
/// flag a pixel whose rays cross only the box's empty corners.
pub fn cloud_pixels(scene: &Scene, accel: &SceneAccel, width: u32, height: u32) -> Vec<bool> {
    if scene.clouds.is_empty() {
        return vec![false; (width * height) as usize];
    }
    let boxes: Vec<(Vec3, Vec3)> = scene
        .clouds
        .iter()
        .map(|c| {
            let (centre, half) = (Vec3::from(c.center), Vec3::splat(c.size / 2.0));
            (centre - half, centre + half)
        })
        .collect();
    let k = CLOUD_RAYS_PER_SIDE;
    let mut mask = Vec::with_capacity((width * height) as usize);
    for y in 0..height {
        for x in 0..width {
            let sees = (0..k * k).any(|s| {
                let (u, v) = ((s % k) as f32 + 0.5, (s / k) as f32 + 0.5);
                let ray = camera_ray(
                    scene,
                    width,
                    height,
                    x as f32 + u / k as f32,
                    y as f32 + v / k as f32,
                );
                let far = ground_distance(scene, &ray);
                let far = accel.closest(scene, &ray, 0.0, far).map_or(far, |h| h.t);
                boxes.iter().any(|&(lo, hi)| crosses_box(&ray, lo, hi, far))
            });
            mask.push(sees);
        }
    }
    mask
}

/// Whether `ray` passes through the box [`lo`, `hi`] between 0 and `far`
/// (the slab test; a ray parallel to a slab outside it misses).
fn crosses_box(ray: &Ray, lo: Vec3, hi: Vec3, far: f32) -> bool {
    let (mut near, mut far) = (0.0f32, far);
    for a in 0..3 {
        let (o, d) = (ray.origin[a], ray.dir[a]);
        if d == 0.0 {
            if o < lo[a] || o > hi[a] {
                return false;
            }
            continue;
        }
        let (t0, t1) = ((lo[a] - o) / d, (hi[a] - o) / d);
        near = near.max(t0.min(t1));
        far = far.min(t0.max(t1));
    }
    near <= far
}

/// One crown's mean indirect light (linear RGB) for the reference and each method.
#[derive(Clone, Debug, Serialize)]
pub struct CrownRow {
    /// Instance index in the scene.
    pub instance: u32,
    /// Its model's name.
    pub model: String,
    /// Lit pixels that show it.
    pub pixels: usize,
    /// The reference's mean indirect light there.
    pub reference: [f64; 3],
    /// Each method's, in the order of [`CrownTable::methods`].
    pub methods: Vec<[f64; 3]>,
}

/// How well one method follows the reference from crown to crown.
#[derive(Clone, Debug, Serialize)]
pub struct CrownSummary {
    /// The method.
    pub method: String,
    /// Pixel-weighted RMS over crowns of the relative error of each crown's
    /// mean indirect luminance.
    pub crown_error: f64,
    /// Pixel-weighted mean of method / reference over crowns (luminance).
    pub mean_ratio: f64,
    /// The spread of log10 of the crowns' indirect luminance, method over
    /// reference's: 1 keeps the contrast between crowns, below 1 flattens it.
    pub contrast: f64,
    /// Correlation of log luminance across crowns with the reference's.
    pub correlation: f64,
    /// The crowns it gets most wrong, worst first: (instance, method / reference).
    pub worst: Vec<(u32, f64)>,
}

/// The per-crown table of one comparison.
#[derive(Clone, Debug, Serialize)]
pub struct CrownTable {
    /// Method names, the columns of each row's `methods`.
    pub methods: Vec<String>,
    /// One row per crown with at least [`MIN_PIXELS`] lit pixels, most pixels first.
    pub rows: Vec<CrownRow>,
    /// One summary per method.
    pub summary: Vec<CrownSummary>,
}

/// Averages each method's indirect light (`indirect[m](pixel)`) and the
/// reference's over the lit pixels of each crown.
pub fn table(
    scene: &Scene,
    ids: &[Option<u32>],
    lit: &[bool],
    reference: &dyn Fn(usize) -> [f32; 3],
    methods: &[(String, PixelLight<'_>)],
) -> CrownTable {
    let n = scene.instances.len();
    let mut sums = vec![(0usize, [0.0f64; 3], vec![[0.0f64; 3]; methods.len()]); n];
    for (i, id) in ids.iter().enumerate() {
        let Some(id) = *id else { continue };
        if !lit[i] {
            continue;
        }
        let s = &mut sums[id as usize];
        s.0 += 1;
        for (acc, v) in s.1.iter_mut().zip(reference(i)) {
            *acc += v as f64;
        }
        for (k, (_, f)) in methods.iter().enumerate() {
            for (acc, v) in s.2[k].iter_mut().zip(f(i)) {
                *acc += v as f64;
            }
        }
    }
    let mut rows: Vec<CrownRow> = sums
        .into_iter()
        .enumerate()
        .filter(|(_, s)| s.0 >= MIN_PIXELS)
        .map(|(inst, (pixels, r, m))| {
            let mean = |v: [f64; 3]| v.map(|x| x / pixels as f64);
            CrownRow {
                instance: inst as u32,
                model: scene.models[scene.instances[inst].model as usize].name.clone(),
                pixels,
                reference: mean(r),
                methods: m.into_iter().map(mean).collect(),
            }
        })
        .collect();
    rows.sort_by_key(|r| std::cmp::Reverse(r.pixels));
    let summary =
        methods.iter().enumerate().map(|(k, (name, _))| summarize(name, k, &rows)).collect();
    CrownTable { methods: methods.iter().map(|(n, _)| n.clone()).collect(), rows, summary }
}

fn lum(v: [f64; 3]) -> f64 {
    luminance(v.map(|x| x as f32)) as f64
}

fn summarize(name: &str, k: usize, rows: &[CrownRow]) -> CrownSummary {
    // Crowns whose reference indirect light is not positive cannot give a ratio.
    let pairs: Vec<(f64, f64, f64, u32)> = rows
        .iter()
        .map(|r| (lum(r.reference), lum(r.methods[k]), r.pixels as f64, r.instance))
        .filter(|p| p.0 > 0.0)
        .collect();
    let w: f64 = pairs.iter().map(|p| p.2).sum::<f64>().max(1.0);
    let crown_error =
        (pairs.iter().map(|p| p.2 * ((p.1 - p.0) / p.0).powi(2)).sum::<f64>() / w).sqrt();
    let mean_ratio = pairs.iter().map(|p| p.2 * p.1 / p.0).sum::<f64>() / w;
    let logs: Vec<(f64, f64)> =
        pairs.iter().filter(|p| p.1 > 0.0).map(|p| (p.0.log10(), p.1.log10())).collect();
    let (contrast, correlation) = spread_and_correlation(&logs);
    let mut worst: Vec<(u32, f64)> = pairs.iter().map(|p| (p.3, p.1 / p.0)).collect();
    worst.sort_by(|a, b| a.1.ln().abs().total_cmp(&b.1.ln().abs()).reverse());
    worst.truncate(5);
    CrownSummary { method: name.into(), crown_error, mean_ratio, contrast, correlation, worst }
}

/// (σ(b) / σ(a), correlation of a and b) over pairs (a, b).
fn spread_and_correlation(v: &[(f64, f64)]) -> (f64, f64) {
    if v.len() < 2 {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let (ma, mb) = (v.iter().map(|p| p.0).sum::<f64>() / n, v.iter().map(|p| p.1).sum::<f64>() / n);
    let (mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0);
    for &(a, b) in v {
        saa += (a - ma).powi(2);
        sbb += (b - mb).powi(2);
        sab += (a - ma) * (b - mb);
    }
    ((sbb / saa).sqrt(), sab / (saa * sbb).sqrt())
}

/// The instance-id image: each crown a colour of its own (hashed from its
/// index), the sky and ground black.
pub fn write_id_image(
    path: &Path,
    width: u32,
    height: u32,
    ids: &[Option<u32>],
) -> anyhow::Result<()> {
    let px: Vec<[u8; 3]> = ids
        .iter()
        .map(|id| match id {
            None => [0, 0, 0],
            Some(i) => {
                let h = (i.wrapping_add(1)).wrapping_mul(0x9E37_79B9);
                [(h >> 24) as u8 | 0x40, (h >> 16) as u8 | 0x40, (h >> 8) as u8 | 0x40]
            }
        })
        .collect();
    Ok(write_png(path, width, height, &px)?)
}

/// The table as Markdown: a row per crown, the reference's and each
/// method's mean indirect luminance (method as a ratio to the reference),
/// then the summary.
pub fn markdown(t: &CrownTable) -> String {
    let mut s = String::from("| instance | model | pixels | reference |");
    for m in &t.methods {
        s += &format!(" {m} |");
    }
    s += "\n|---|---|---|---|";
    s += &"---|".repeat(t.methods.len());
    s += "\n";
    for r in &t.rows {
        // A model's name comes from the scene file: a `|` in it would cut the row.
        let model = r.model.replace('|', "\\|");
        s += &format!("| {} | {model} | {} | {:.4} |", r.instance, r.pixels, lum(r.reference));
        for m in &r.methods {
            s += &format!(" {:.2} |", lum(*m) / lum(r.reference));
        }
        s += "\n";
    }
    s += "\n| method | crown error | mean ratio | contrast | correlation | worst crowns (ratio) |\n|---|---|---|---|---|---|\n";
    for m in &t.summary {
        let worst: Vec<String> = m.worst.iter().map(|(i, r)| format!("{i} ({r:.2})")).collect();
        s += &format!(
            "| {} | {:.1} % | {:.2} | {:.2} | {:.2} | {} |\n",
            m.method,
            100.0 * m.crown_error,
            m.mean_ratio,
            m.contrast,
            m.correlation,
            worst.join(", ")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_accel::AccelKind;

    #[test]
    fn a_ray_crosses_a_box_only_in_front_of_its_first_surface() {
        let ray = Ray::new(Vec3::ZERO, Vec3::Z);
        let (lo, hi) = (Vec3::new(-1.0, -1.0, 5.0), Vec3::new(1.0, 1.0, 7.0));
        assert!(crosses_box(&ray, lo, hi, f32::INFINITY));
        assert!(
            crosses_box(&ray, lo, hi, 5.5),
            "a surface inside the box: the box is in front of it"
        );
        assert!(!crosses_box(&ray, lo, hi, 4.0), "a surface in front of the box hides it");
        let beside = Ray::new(Vec3::new(2.0, 0.0, 0.0), Vec3::Z);
        assert!(!crosses_box(&beside, lo, hi, f32::INFINITY), "parallel to a slab, outside it");
        let behind = Ray::new(Vec3::ZERO, -Vec3::Z);
        assert!(!crosses_box(&behind, lo, hi, f32::INFINITY), "the box behind the camera");
    }

    /// A 32 × 16 view of one small tree, level, with a cloud where `cloud` says.
    fn view_with_cloud(cloud: &str) -> Scene {
        let text = format!(
            r#"{{
            "models": {{ "maple": {{ "tree": {{ "species": "red_maple", "triangles": 800, "seed": 3 }} }} }},
            "instances": [ {{ "model": "maple", "position": [0, 0, 0] }} ],
            "camera": {{ "position": [0, 4, -14], "look_at": [0, 4, 0], "fov_y_deg": 60 }},
            "sun": {{ "elevation_deg": 45, "azimuth_deg": 120 }},
            "ground": {{ "color": [0.1, 0.08, 0.05] }},
            "clouds": [ {cloud} ]
        }}"#
        );
        let file = sylva_scene::parse(&text, "test").unwrap();
        Scene::build(file, Path::new("."), "test").unwrap()
    }

    #[test]
    fn cloud_pixels_are_those_whose_rays_meet_the_box_before_a_surface() {
        let (w, h) = (32, 16);
        let row = |mask: &[bool], y: usize| mask[y * w..(y + 1) * w].iter().filter(|&&c| c).count();
        let cloud_pixels = |scene: &Scene, w, h| {
            cloud_pixels(scene, &SceneAccel::build(scene, AccelKind::Bvh), w, h)
        };
        // High in the sky behind the tree: the top rows see it, the ground
        // rows (below the horizon, the ground hides what is behind) do not.
        let sky =
            cloud_pixels(&view_with_cloud(r#"{ "center": [0, 16, 30], "size": 30 }"#), 32, 16);
        assert!(row(&sky, 0) > 0, "the top row looks into the cloud");
        assert_eq!(row(&sky, h - 1), 0, "the bottom row sees the ground in front of it");
        // Around the camera: every ray starts in it.
        let around =
            cloud_pixels(&view_with_cloud(r#"{ "center": [0, 4, -14], "size": 2 }"#), 32, 16);
        assert!(around.iter().all(|&c| c));
        // Behind the camera: no ray meets it.
        let behind =
            cloud_pixels(&view_with_cloud(r#"{ "center": [0, 4, -30], "size": 4 }"#), 32, 16);
        assert!(behind.iter().all(|&c| !c));
        // Under the ground, straight ahead: hidden by it.
        let buried =
            cloud_pixels(&view_with_cloud(r#"{ "center": [0, -10, 30], "size": 8 }"#), 32, 16);
        assert!(buried.iter().all(|&c| !c));
    }

    #[test]
    fn a_method_that_flattens_the_crowns_scores_low_contrast_and_a_scaled_one_full_correlation() {
        // Reference ×10 between crowns; one method constant, one half of it.
        let flat = spread_and_correlation(&[(0.0, 0.5), (1.0, 0.5001), (0.5, 0.4999)]);
        assert!(flat.0 < 0.01, "{flat:?}");
        let half = spread_and_correlation(&[(0.0, -0.3), (1.0, 0.7), (0.5, 0.2)]);
        assert!((half.0 - 1.0).abs() < 1e-9 && (half.1 - 1.0).abs() < 1e-9, "{half:?}");
    }
}
