//! The filter over the gathers' indirect light (docs/lighting.md,
//! "Filtering the gather"): per pixel, the mean of its neighbours'
//! estimates of the same light. The strip renderer runs it over the
//! per-sample kernel's means before cropping a strip to its columns.

/// Per pixel, the means over its samples of the per-sample kernel's four
/// images (`reference.wgsl`'s `reference_sample`).
pub struct SampleMeans {
    /// The paths' radiance, and the fraction of samples that hit a model.
    pub paths: Vec<[f32; 4]>,
    /// What `local` shows along the same camera rays, and the first
    /// surface's distance (0 for samples that see the sky).
    pub first: Vec<[f32; 4]>,
    /// The albedo a diffuse field sees at the first surface, and the
    /// fraction of samples that hit a surface (model or ground).
    pub guide: Vec<[f32; 4]>,
    /// The indirect light of the samples whose first event is a surface
    /// (0 for the rest: the sky's, or a cloud's light before any surface):
    /// `paths − first` without what clouds add in front of or behind the
    /// surfaces. The fourth value is unused.
    pub surface_indirect: Vec<[f32; 4]>,
    /// Per channel, the variance of the mean of `surface_indirect` from
    /// its samples' spread; 0 with one sample.
    pub indirect_variance: Vec<[f32; 3]>,
    /// With passes (empty otherwise): the sun's light off the first
    /// surface, and the sky seen directly (docs/passes.md).
    pub direct: Vec<[f32; 3]>,
    /// ... and the sky seen directly.
    pub sky: Vec<[f32; 3]>,
}

/// The depth range, in metres, within which two pixels' first surfaces
/// may belong to one crown: the smallest instance's horizontal half-extent
/// (its crown's radius). A neighbour farther in depth than that lies on
/// another crown or on the ground behind, whose indirect light the filter
/// must not mix in (docs/lighting.md, "Filtering the gather").
pub fn crown_depth(scene: &sylva_scene::Scene) -> f32 {
    // Each model's bounds once: a forest's instances share a few models,
    // and walking a model's vertices per instance cost the full forest's
    // first frame 2.3 s (benchmarks/results/issue-28).
    let bounds: Vec<_> = scene.models.iter().map(|m| m.model.bounds()).collect();
    scene
        .instances
        .iter()
        .filter_map(|i| {
            let (lo, hi) = bounds[i.model as usize]?;
            let size = i.to_world.matrix3 * (hi - lo);
            let half = 0.5 * glam::Vec2::new(size.x.abs(), size.z.abs()).min_element();
            (half > 0.0).then_some(half)
        })
        .fold(f32::INFINITY, f32::min)
}

/// Filters the gathered indirect light (of the samples whose first event
/// is a surface: `SampleMeans::surface_indirect`) of a strip `width`
/// pixels wide, where its noise and not the light itself varies from
/// pixel to pixel. Per pixel and channel, in irradiance (indirect light
/// over the albedo its first surface shows a diffuse field, so leaf and
/// texture colour stay per pixel), the pixel's value becomes the mean of
/// the values in its (2 radius + 1)² window that are estimates of the
/// same light: the first surface within `crown_depth` of its own, and a
/// value within two standard deviations of the difference of the two
/// estimates (each pixel's variance from its own samples' spread):
/// (y_q − y_p)² ≤ 4 (σ_p² + σ_q²). Two estimates of one light fail that
/// test 5 % of the time; light that differs by more than the noise is
/// kept, and as the rays per pixel grow the filter averages less
/// (docs/lighting.md, "Filtering the gather"). With one sample per pixel
/// there is no σ², and nothing changes. Pixels that see no surface are
/// left as they are.
pub fn filter_indirect(m: &mut SampleMeans, width: usize, radius: usize, crown_depth: f32) {
    let n = m.paths.len();
    if width == 0 || n == 0 || radius == 0 {
        return;
    }
    let height = n / width;
    // Per pixel: mean distance of the samples that hit a surface.
    let depth: Vec<f32> = (0..n)
        .map(|i| if m.guide[i][3] > 0.0 { m.first[i][3] / m.guide[i][3] } else { f32::NAN })
        .collect();
    // Per pixel and channel: irradiance and its variance (None without a surface).
    let irr: Vec<[Option<(f64, f64)>; 3]> = (0..n)
        .map(|i| {
            std::array::from_fn(|c| {
                let a = m.guide[i][c] as f64;
                (m.guide[i][3] > 0.0 && a > 1e-6).then(|| {
                    // Indirect light is never negative: a mean below zero
                    // is rounding, which the division by a small albedo
                    // (a leaf's edge, one sample of a dark channel) would
                    // make large.
                    let y = (m.surface_indirect[i][c] as f64 / a).max(0.0);
                    (y, m.indirect_variance[i][c] as f64 / (a * a))
                })
            })
        })
        .collect();
    let r = radius as isize;
    let mut out = m.paths.clone();
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            if depth[p].is_nan() {
                continue;
            }
            for c in 0..3 {
                let Some((vp, sp)) = irr[p][c] else { continue };
                let (mut sum, mut count) = (0.0f64, 0u32);
                for dy in -r..=r {
                    let qy = y as isize + dy;
                    if qy < 0 || qy >= height as isize {
                        continue;
                    }
                    for dx in -r..=r {
                        let qx = x as isize + dx;
                        if qx < 0 || qx >= width as isize {
                            continue;
                        }
                        let q = qy as usize * width + qx as usize;
                        // No surface (NaN) is never within a crown's depth.
                        let near = (depth[q] - depth[p]).abs() <= crown_depth;
                        if !near {
                            continue;
                        }
                        if let Some((vq, sq)) = irr[q][c]
                            && (vq - vp).powi(2) <= 4.0 * (sp + sq)
                        {
                            sum += vq;
                            count += 1;
                        }
                    }
                }
                if count > 0 {
                    // Only the surfaces' indirect light is replaced: the
                    // sky's and a cloud's samples keep theirs.
                    out[p][c] = m.paths[p][c] - m.surface_indirect[p][c]
                        + m.guide[p][c] * (sum / count as f64) as f32;
                }
            }
        }
    }
    m.paths = out;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strip of pixels in a row: indirect `ind`, albedo `alb`, depth
    /// `d`, and the variance of each pixel's irradiance `noise`.
    fn strip(ind: &[f32], alb: &[f32], d: &[f32], noise: f32) -> SampleMeans {
        SampleMeans {
            paths: ind.iter().map(|&v| [0.1 + v; 4]).collect(),
            first: d.iter().map(|&d| [0.1, 0.1, 0.1, d]).collect(),
            surface_indirect: ind.iter().map(|&v| [v, v, v, 0.0]).collect(),
            guide: alb.iter().map(|&a| [a, a, a, if a > 0.0 { 1.0 } else { 0.0 }]).collect(),
            indirect_variance: alb.iter().map(|&a| [noise * a * a; 3]).collect(),
            direct: Vec::new(),
            sky: Vec::new(),
        }
    }

    // Five pixels of one crown at 10 m (albedo 0.5, 0.25, …): irradiance
    // 0.3, 0.1, 0.2, 0.25, 0.1 (mean 0.19, spread 0.0064); then a crown at
    // 30 m with irradiance 1; then sky.
    const IND: [f32; 8] = [0.15, 0.025, 0.05, 0.0625, 0.05, 0.5, 0.5, 0.0];
    const ALB: [f32; 8] = [0.5, 0.25, 0.25, 0.25, 0.5, 0.5, 0.5, 0.0];
    const DEPTH: [f32; 8] = [10.0, 10.5, 9.5, 10.0, 10.2, 30.0, 30.0, 0.0];

    #[test]
    fn estimates_of_one_light_within_their_noise_are_averaged_in_each_pixels_colour() {
        // σ² 0.01 per pixel: every pair within 2σ of their difference (0.2 ≤ 2·√0.02).
        let mut m = strip(&IND, &ALB, &DEPTH, 0.01);
        filter_indirect(&mut m, 8, 16, 2.0);
        for (i, a) in ALB.iter().enumerate().take(5) {
            assert!((m.paths[i][0] - (0.1 + a * 0.19)).abs() < 1e-6, "{i}: {:?}", m.paths[i]);
        }
        // The crown behind keeps its own light; the sky is untouched.
        assert!((m.paths[5][0] - 0.6).abs() < 1e-6 && (m.paths[6][0] - 0.6).abs() < 1e-6);
        assert_eq!(m.paths[7][0], 0.1);
    }

    #[test]
    fn light_that_differs_by_more_than_the_noise_is_kept() {
        let mut m = strip(&IND, &ALB, &DEPTH, 0.0);
        filter_indirect(&mut m, 8, 16, 2.0);
        for (i, ind) in IND.iter().enumerate() {
            assert!((m.paths[i][0] - (0.1 + ind)).abs() < 1e-6, "{i}: {:?}", m.paths[i]);
        }
        // σ² 0.001: 2√0.002 ≈ 0.089, so pixel 0 (0.3) and pixel 2 (0.2)
        // each average with 0.25 only, and pixel 1 (0.1) with pixel 4 (0.1).
        let mut m = strip(&IND, &ALB, &DEPTH, 0.001);
        filter_indirect(&mut m, 8, 16, 2.0);
        assert!((m.paths[0][0] - (0.1 + 0.5 * 0.275)).abs() < 1e-6, "{:?}", m.paths[0]);
        assert!((m.paths[1][0] - (0.1 + 0.025)).abs() < 1e-6, "{:?}", m.paths[1]);
        let want = (0.2 + 0.25) / 2.0;
        assert!((m.paths[2][0] - (0.1 + 0.25 * want)).abs() < 1e-6, "{:?}", m.paths[2]);
    }

    #[test]
    fn rounding_below_zero_under_a_small_albedo_never_makes_light_negative() {
        // Pixel 1: its path mean 1e-6 under its first light, albedo 1e-4
        // (one dark sample among many): −0.01 irradiance without the floor.
        let mut m = strip(&[0.0, 0.0, 0.0], &[0.5, 1e-4, 0.5], &[10.0; 3], 0.01);
        m.paths[1] = [0.1 - 1e-6; 4];
        m.surface_indirect[1] = [-1e-6; 4];
        filter_indirect(&mut m, 3, 1, 2.0);
        for p in &m.paths {
            assert!(p[..3].iter().all(|&v| v >= 0.1 - 1e-6), "{:?}", m.paths);
        }
        for p in [0, 2] {
            assert!(m.paths[p][0] >= 0.1, "{:?}", m.paths);
        }
    }

    #[test]
    fn a_clouds_light_is_not_spread_as_a_leafs() {
        // Pixel 1 sees a leaf at 10 m in half its samples and a bright
        // cloud in the rest: its path mean holds the cloud's 2.0 beyond its
        // first light, none of which is the leaf's indirect light. The
        // noise is large enough that all three pixels' leaf light averages.
        let mut m = strip(&[0.05, 0.05, 0.05], &[0.5, 0.25, 0.5], &[10.0; 3], 10.0);
        m.paths[1] = [0.1 + 0.05 + 2.0; 4];
        (m.guide[1][3], m.first[1][3]) = (0.5, 5.0);
        filter_indirect(&mut m, 3, 1, 2.0);
        // Irradiance 0.1, 0.2, 0.1 (the cloud's counted, 8.2 at pixel 1):
        // the ends take the mean of two, 0.15; the middle of three.
        for i in [0, 2] {
            assert!((m.paths[i][0] - (0.1 + 0.5 * 0.15)).abs() < 1e-6, "{i}: {:?}", m.paths);
        }
        let middle = 0.1 + 2.0 + 0.25 * (0.4 / 3.0);
        assert!((m.paths[1][0] - middle).abs() < 1e-6, "{:?}", m.paths);
    }
}
