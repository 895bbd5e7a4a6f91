//! The `ambient` methods' constant, matched to the LB light: the LB light
//! alone rendered small and averaged over the pixels that see a model
//! (the forest paper's Figure 2c).

use crate::gpu::GpuContext;
use crate::trace::{RenderSettings, StripRenderer};
use sylva_scene::LightingMode;

/// The constant ambient light whose mean over the models' pixels equals
/// the LB light's: the LB light alone, rendered at a quarter of `f`'s
/// resolution, averaged over the pixels that see a model. Deterministic,
/// so every worker of a frame finds the same.
pub fn matched(
    renderer: &StripRenderer,
    ctx: &GpuContext,
    f: &RenderSettings,
) -> anyhow::Result<[f32; 3]> {
    let small = RenderSettings {
        width: (f.width / 4).max(16),
        height: (f.height / 4).max(8),
        spp: 1,
        lighting: LightingMode::LbVisualize,
        passes: Default::default(),
        ..*f
    };
    let s = renderer.render_strip(ctx, &small, 0, small.width)?;
    Ok(coverage_weighted_mean(&s.pixels, &s.coverage))
}

/// The mean of `pixels` weighted by how much of each shows a model.
pub fn coverage_weighted_mean(pixels: &[[f32; 3]], coverage: &[f32]) -> [f32; 3] {
    let mut sum = [0.0f64; 3];
    let mut weight = 0.0f64;
    for (p, &c) in pixels.iter().zip(coverage) {
        for k in 0..3 {
            sum[k] += p[k] as f64 * c as f64;
        }
        weight += c as f64;
    }
    if weight == 0.0 {
        return [0.0; 3];
    }
    sum.map(|v| (v / weight) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mean_counts_each_pixel_by_how_much_model_it_shows() {
        let m = coverage_weighted_mean(
            &[[1.0, 2.0, 3.0], [5.0, 6.0, 7.0], [100.0; 3]],
            &[1.0, 0.5, 0.0],
        );
        assert_eq!(m.map(|v| (v * 3.0).round()), [7.0, 10.0, 13.0]);
        assert_eq!(coverage_weighted_mean(&[[1.0; 3]], &[0.0]), [0.0; 3]);
    }
}
