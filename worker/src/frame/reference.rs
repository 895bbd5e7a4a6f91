//! The reference converged: the path tracer (or a gather's paths) run in
//! batches with different seeds until the image's own error estimate is
//! small enough. Each batch's mean is one independent sample of every
//! pixel, so the spread of the batch means gives a per-pixel standard
//! error: a reference states how far it may still be from the truth.

use crate::gpu::GpuContext;
use crate::lighting::{self, Kernel};
use crate::trace::{RenderSettings, StripRenderer};
use serde::{Deserialize, Serialize};
use std::time::Instant;
use sylva_scene::LightingMode;
use sylva_scene::color::luminance;
use sylva_scene::film::HdrImage;
use sylva_scene::passes::PassImage;

/// The smallest batch worth a dispatch (see `ReferenceOptions::batch_spp`).
pub const MIN_BATCH_SPP: u32 = 16;

/// When a progressive reference stops.
#[derive(Clone, Copy, Debug)]
pub struct ReferenceOptions {
    /// Samples per pixel in one batch (one dispatch, one path per
    /// invocation, at most what the adapter can bind for the frame).
    /// Larger batches stratify the pixel more finely (4 × 4 cells at 16).
    pub batch_spp: u32,
    /// Batches always rendered (the error estimate needs a few).
    pub min_batches: u32,
    /// Batches at most.
    pub max_batches: u32,
    /// Stop once the relative standard error of the frame is below this.
    pub target_error: f64,
    /// Stop after this many seconds, converged or not.
    pub max_seconds: f64,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        Self {
            batch_spp: MIN_BATCH_SPP,
            min_batches: 4,
            max_batches: 1024,
            target_error: 0.01,
            max_seconds: 600.0,
        }
    }
}

/// A reference image and its own error estimate.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReferenceImage {
    /// The mean of all samples, linear HDR.
    pub image: HdrImage,
    /// Per pixel, the fraction of camera rays whose first hit is a model.
    pub coverage: Vec<f32>,
    /// What `local` shows along the same camera samples: `image − local`
    /// is the reference's indirect light, free of the edge aliasing a
    /// differently sampled `local` image would add.
    pub local: HdrImage,
    /// Per pixel, the standard error of the mean's luminance.
    pub std_error: Vec<f32>,
    /// Per pixel and channel, the variance of the mean of the indirect
    /// light (`image − local`): what the reference's own noise adds, in
    /// expectation, to a squared error measured against it.
    pub indirect_variance: Vec<[f32; 3]>,
    /// What was rendered and how close it is.
    pub stats: ReferenceStats,
    /// The passes the frame asked for: the light split as the mean of
    /// every batch's, the guides from the first batch.
    #[serde(skip)]
    pub passes: Option<PassImage>,
}

/// How a reference was made.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct ReferenceStats {
    /// Samples per pixel in all.
    pub spp: u32,
    /// Batches.
    pub batches: u32,
    /// √(Σ σ²) / √(Σ μ²) over the frame's luminance: the relative RMS
    /// standard error of the image.
    pub relative_error: f64,
    /// Whether `relative_error` reached the target.
    pub converged: bool,
    /// Wall time.
    pub ms: f64,
}

/// Renders `f` progressively: with the reference's paths, or with the
/// paths of another method its kernel draws (a gather: so `compare` has
/// a converged one-bounce image to hold Boulanger et al.'s terms against,
/// the form of their paper's comparison). Other lightings get the reference's.
pub fn render_reference(
    ctx: &GpuContext,
    renderer: &StripRenderer,
    f: &RenderSettings,
    opts: &ReferenceOptions,
    progress: &dyn Fn(&ReferenceStats),
) -> anyhow::Result<ReferenceImage> {
    render_reference_columns(ctx, renderer, f, &[(0, f.width)], opts, progress)
}

/// [`render_reference`] of some of the frame's columns only: the ranges
/// `[x0, x1)` side by side, as one image as wide as they are together
/// (what `render --lighting auto`'s pilot measures against).
pub fn render_reference_columns(
    ctx: &GpuContext,
    renderer: &StripRenderer,
    f: &RenderSettings,
    ranges: &[(u32, u32)],
    opts: &ReferenceOptions,
    progress: &dyn Fn(&ReferenceStats),
) -> anyhow::Result<ReferenceImage> {
    anyhow::ensure!(
        opts.batch_spp > 0 && opts.max_batches >= opts.min_batches.max(2),
        "reference batches: need batch_spp ≥ 1 and max_batches ≥ 2"
    );
    anyhow::ensure!(
        !ranges.is_empty() && ranges.iter().all(|&(x0, x1)| x0 < x1 && x1 <= f.width),
        "reference columns: need ranges inside the frame"
    );
    let t = Instant::now();
    let width: u32 = ranges.iter().map(|(x0, x1)| x1 - x0).sum();
    let n = (width * f.height) as usize;
    let mut sum = vec![[0.0f64; 3]; n];
    let mut lum_sq = vec![0.0f64; n];
    // Per batch, the batch mean's indirect light squared: its spread
    // gives the indirect part's own standard error.
    let mut ind_sq = vec![[0.0f64; 3]; n];
    let mut coverage = vec![0.0f64; n];
    let mut local = vec![[0.0f64; 3]; n];
    let mut passes = (!f.passes.is_empty()).then(|| PassImage::new(width, f.height, f.passes));
    let mut stats = ReferenceStats {
        spp: 0,
        batches: 0,
        relative_error: f64::INFINITY,
        converged: false,
        ms: 0.0,
    };
    // Each sample of a batch has its own output slot: as many samples and
    // columns per dispatch as the adapter binds, with a margin.
    let budget = (ctx.limits.max_storage_buffer_binding_size / 2).max(1 << 20);
    // Sized as without passes (their two more images and one per dispatch
    // fit the margin's half), so the batches, their seeds and so the image
    // are the same with passes.
    let per_sample_column = crate::trace::render::sample_bytes_per_pixel(false) * f.height as u64;
    let batch_spp =
        (opts.batch_spp as u64).min((budget / (per_sample_column * width as u64)).max(1)) as u32;
    let columns = ((budget / (per_sample_column * batch_spp as u64)).max(1) as u32).min(f.width);
    // Each range cut into dispatches of at most `columns`, each with the
    // output column its first goes to.
    let mut chunks = Vec::new();
    let mut out_x = 0;
    for &(x0, x1) in ranges {
        for c0 in (x0..x1).step_by(columns as usize) {
            chunks.push((c0, (c0 + columns).min(x1), out_x + c0 - x0));
        }
        out_x += x1 - x0;
    }
    let mut batch = 0u32;
    loop {
        // Seeds far apart, so no batch repeats another's samples.
        let settings = RenderSettings {
            spp: batch_spp,
            seed: f.seed.wrapping_add(batch.wrapping_mul(0x9E37_79B9)),
            lighting: if lighting::method(f.lighting).kernel == Kernel::Reference {
                f.lighting
            } else {
                LightingMode::Reference
            },
            // The guides once, from the first batch.
            passes: if batch == 0 { f.passes } else { f.passes.split_only() },
            ..*f
        };
        for &(x0, x1, out) in &chunks {
            let s = renderer.render_strip(ctx, &settings, x0, x1)?;
            if let (Some(acc), Some(p)) = (&mut passes, &s.passes) {
                // Summed now, divided by the batches at the end.
                acc.add_strip(out, p, 1.0).map_err(anyhow::Error::msg)?;
            }
            for (k, p) in s.pixels.iter().enumerate() {
                let i = (k as u32 / s.width * width + out + k as u32 % s.width) as usize;
                for c in 0..3 {
                    sum[i][c] += p[c] as f64;
                    local[i][c] += s.first_light[k][c] as f64;
                    ind_sq[i][c] += ((p[c] - s.first_light[k][c]) as f64).powi(2);
                }
                let l = luminance(*p) as f64;
                lum_sq[i] += l * l;
                coverage[i] += s.coverage[k] as f64;
            }
        }
        batch += 1;
        let b = batch as f64;
        let (mut var_sum, mut mean_sq_sum) = (0.0, 0.0);
        for i in 0..n {
            let mean_l = luminance(sum[i].map(|v| (v / b) as f32)) as f64;
            let var_batch = ((lum_sq[i] / b) - mean_l * mean_l).max(0.0) * b / (b - 1.0).max(1.0);
            var_sum += var_batch / b;
            mean_sq_sum += mean_l * mean_l;
        }
        stats.batches = batch;
        stats.spp = batch * batch_spp;
        stats.relative_error = if mean_sq_sum > 0.0 { (var_sum / mean_sq_sum).sqrt() } else { 0.0 };
        stats.ms = t.elapsed().as_secs_f64() * 1e3;
        stats.converged = batch >= 2 && stats.relative_error <= opts.target_error;
        progress(&stats);
        if batch >= opts.min_batches.max(2)
            && (stats.converged || batch >= opts.max_batches || stats.ms / 1e3 >= opts.max_seconds)
        {
            break;
        }
    }
    let b = batch as f64;
    if let Some(acc) = &mut passes {
        for (p, plane) in acc.set.extra().zip(&mut acc.planes) {
            if f.passes.split_only().contains(p) {
                plane.iter_mut().for_each(|v| *v /= b as f32);
            }
        }
    }
    let image = HdrImage {
        width,
        height: f.height,
        pixels: sum.iter().map(|s| s.map(|v| (v / b) as f32)).collect(),
    };
    let std_error = (0..n)
        .map(|i| {
            let mean_l = luminance(image.pixels[i]) as f64;
            ((((lum_sq[i] / b) - mean_l * mean_l).max(0.0) / (b - 1.0).max(1.0)).sqrt()) as f32
        })
        .collect();
    let indirect_variance = (0..n)
        .map(|i| {
            std::array::from_fn(|c| {
                let mean = (sum[i][c] - local[i][c]) / b;
                (((ind_sq[i][c] / b) - mean * mean).max(0.0) / (b - 1.0).max(1.0)) as f32
            })
        })
        .collect();
    let local = HdrImage {
        width,
        height: f.height,
        pixels: local.iter().map(|s| s.map(|v| (v / b) as f32)).collect(),
    };
    Ok(ReferenceImage {
        image,
        coverage: coverage.iter().map(|c| (c / b) as f32).collect(),
        local,
        std_error,
        indirect_variance,
        stats,
        passes,
    })
}
