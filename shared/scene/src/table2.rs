//! The forest of Geist & Steele's Table 2: five species, 962 instances and
//! 273,376,528 triangles at scale 1, on a ground plane, seen as in their
//! Figure 3.

use crate::format::*;
use crate::rng::SplitMix64;
use crate::trees::{Species, TreeParams};
use std::collections::BTreeMap;

/// Metres between neighbouring trees, on average.
pub const SPACING: f32 = 8.0;

/// What to build.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForestOptions {
    /// Multiplies every species' instance count (at least one each).
    pub scale: f64,
    /// Multiplies every tree's triangle count (1 is the paper's).
    pub triangle_scale: f64,
    /// Placement and shape seed.
    pub seed: u64,
}

impl Default for ForestOptions {
    fn default() -> Self {
        Self { scale: 1.0, triangle_scale: 1.0, seed: 1 }
    }
}

/// Instances of `species` at `scale`.
pub fn instances_at(species: Species, scale: f64) -> u32 {
    ((species.shape().paper_instances as f64 * scale).round() as u32).max(1)
}

/// The forest as a scene file.
pub fn forest(o: &ForestOptions) -> crate::Result<SceneFile> {
    if !(o.scale.is_finite() && o.scale > 0.0 && o.scale <= 100.0) {
        return Err(crate::Error::Invalid(format!("--scale {}: valid range (0, 100]", o.scale)));
    }
    if !(o.triangle_scale.is_finite() && o.triangle_scale > 0.0 && o.triangle_scale <= 10.0) {
        return Err(crate::Error::Invalid(format!(
            "--triangle-scale {}: valid range (0, 10]",
            o.triangle_scale
        )));
    }
    let mut models = BTreeMap::new();
    let mut kinds = Vec::new();
    for (k, sp) in Species::ALL.into_iter().enumerate() {
        let tris =
            ((sp.shape().paper_triangles as f64 * o.triangle_scale).round() as u32).max(1000);
        models.insert(
            sp.name().to_string(),
            ModelSpec {
                gltf: None,
                mesh: None,
                tree: Some(TreeParams {
                    species: sp,
                    triangles: Some(tris),
                    seed: o.seed + k as u64,
                }),
                lb: None,
            },
        );
        kinds.extend(std::iter::repeat_n(sp, instances_at(sp, o.scale) as usize));
    }
    let mut rng = SplitMix64::new(o.seed);
    // Shuffle so the species mix across the stand.
    for i in (1..kinds.len()).rev() {
        kinds.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
    }
    let n = kinds.len();
    let side = (n as f32).sqrt() * SPACING;
    let positions = scatter(n, side, 0.6 * SPACING, &mut rng);
    let instances = kinds
        .iter()
        .zip(&positions)
        .map(|(sp, p)| InstanceSpec {
            model: sp.name().to_string(),
            position: [p[0], 0.0, p[1]],
            rotate_y_deg: rng.range(0.0, 360.0),
            scale: rng.range(0.85, 1.15),
            matrix: None,
        })
        .collect();
    Ok(SceneFile {
        models,
        instances,
        // From the southern edge, above the understorey, looking into the stand.
        camera: CameraSpec {
            position: [0.0, 14.0, -side / 2.0 - 12.0],
            look_at: [0.0, 7.0, 0.0],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 35.0,
        },
        sun: SunSpec {
            elevation_deg: Some(45.0),
            azimuth_deg: Some(60.0),
            direction: None,
            temperature_k: 6500.0,
            intensity: 3.0,
        },
        sky: SkySpec::default(),
        ground: Some(GroundSpec { color: [0.1, 0.08, 0.05] }),
        lighting: LightingMode::Lb,
        lb: LbSpec::default(),
        lb_model: Default::default(),
        forest_grid: ForestGridSpec::default(),
        clouds: Vec::new(),
        leaf_optics: Default::default(),
        sequence: None,
    })
}

/// `n` points in a `side`-wide square centred on the origin, kept at least
/// `min_gap` apart where darts allow.
fn scatter(n: usize, side: f32, min_gap: f32, rng: &mut SplitMix64) -> Vec<[f32; 2]> {
    let mut pts: Vec<[f32; 2]> = Vec::with_capacity(n);
    let cell = min_gap.max(1e-3);
    let cells = (side / cell).ceil() as usize + 1;
    let mut grid: Vec<Vec<usize>> = vec![Vec::new(); cells * cells];
    let at = |p: [f32; 2]| {
        (((p[0] + side / 2.0) / cell) as usize).min(cells - 1)
            + cells * (((p[1] + side / 2.0) / cell) as usize).min(cells - 1)
    };
    while pts.len() < n {
        let mut best = [rng.range(-side / 2.0, side / 2.0), rng.range(-side / 2.0, side / 2.0)];
        for _ in 0..30 {
            let p = [rng.range(-side / 2.0, side / 2.0), rng.range(-side / 2.0, side / 2.0)];
            let c = at(p);
            let (cx, cy) = (c % cells, c / cells);
            let clear = (cy.saturating_sub(1)..(cy + 2).min(cells)).all(|y| {
                (cx.saturating_sub(1)..(cx + 2).min(cells)).all(|x| {
                    grid[x + cells * y].iter().all(|&j| {
                        let q = pts[j];
                        (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) >= min_gap * min_gap
                    })
                })
            });
            if clear {
                best = p;
                break;
            }
        }
        grid[at(best)].push(pts.len());
        pts.push(best);
    }
    pts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_one_is_the_papers_table_2() {
        let f = forest(&ForestOptions::default()).unwrap();
        assert_eq!(f.instances.len(), 962);
        let tris: u64 = f
            .instances
            .iter()
            .map(|i| f.models[&i.model].tree.unwrap().triangles.unwrap() as u64)
            .sum();
        assert_eq!(tris, 273_376_528);
        for sp in Species::ALL {
            let count = f.instances.iter().filter(|i| i.model == sp.name()).count() as u32;
            assert_eq!(count, sp.shape().paper_instances);
        }
    }

    #[test]
    fn small_scales_keep_every_species() {
        let f = forest(&ForestOptions { scale: 0.01, ..Default::default() }).unwrap();
        // 0.12 → 1 (every species keeps one), 2.85 → 3, 2.91 → 3, 2.06 → 2, 1.68 → 2.
        assert_eq!(f.instances.len(), 11);
        assert!(forest(&ForestOptions { scale: 0.0, ..Default::default() }).is_err());
        assert!(forest(&ForestOptions { scale: f64::NAN, ..Default::default() }).is_err());
    }
}
