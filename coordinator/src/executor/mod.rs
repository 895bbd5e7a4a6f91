//! Where a frame's strips are rendered: one interface, two back-ends —
//! this process's GPU (`InProcess`, in the `sylva` binary, which links the
//! worker) and gRPC workers ([`Farm`]) — and one
//! assembly ([`crate::assembly::Assembly`]) behind both, so a frame is put
//! together and checked the same way whoever rendered it.

mod grpc;

pub use grpc::Farm;

use crate::farm::WorkerReport;
use crate::schedule::Strip;
use sylva_scene::film::HdrImage;
use sylva_scene::frame::Denoise;

/// A rendered, assembled frame.
#[derive(Clone, Debug)]
pub struct RenderedFrame {
    /// Linear HDR.
    pub image: HdrImage,
    /// Per pixel, the fraction of samples that hit a model.
    pub coverage: Vec<f32>,
    /// Rays traced.
    pub rays: sylva_scene::film::RayCounts,
    /// Per worker (empty in this process).
    pub workers: Vec<WorkerReport>,
    /// Every strip: its render time and the whole call's time as the
    /// executor saw it (render plus transfer), by strip.
    pub strip_times: Vec<crate::schedule::StripTime>,
    /// Time to get the scene to the workers (0 in this process).
    pub upload_ms: f64,
    /// How the scene was prepared once for the farm, when it was.
    pub prepared: Option<crate::farm::PreparedShare>,
    /// The passes beside the image, when the frame asks for any.
    pub passes: Option<sylva_scene::passes::PassImage>,
    /// What the workers' lighting found about the scene, each once.
    pub warnings: Vec<String>,
    /// The image before [`RenderedFrame::denoise`], when it was denoised.
    pub noisy: Option<HdrImage>,
}

/// Denoises `image` in place as `what` says (docs/denoising.md), with the
/// `passes` rendered beside it: the guides, and for the indirect light
/// alone the light split. The noisy image it was; `None` for
/// [`Denoise::Off`].
pub fn denoise(
    image: &mut HdrImage,
    passes: Option<&sylva_scene::passes::PassImage>,
    what: Denoise,
) -> anyhow::Result<Option<HdrImage>> {
    Ok(match what {
        Denoise::Off => None,
        Denoise::Frame => Some(denoise_image(image, passes)?),
        Denoise::Indirect => {
            let p = passes.ok_or_else(|| anyhow::anyhow!("denoise: the frame has no passes"))?;
            Some(denoise_indirect(image, p)?)
        }
    })
}

/// Denoises `image` in place, guided by the albedo and normal of
/// `passes`; the noisy image it was.
fn denoise_image(
    image: &mut HdrImage,
    passes: Option<&sylva_scene::passes::PassImage>,
) -> anyhow::Result<HdrImage> {
    use sylva_scene::passes::Pass;
    let guide = |p: Pass| {
        passes
            .and_then(|s| s.plane(p))
            .ok_or_else(|| anyhow::anyhow!("denoise: the frame has no {p} pass, one of its guides"))
    };
    let (albedo, normal) = (guide(Pass::Albedo)?, guide(Pass::Normal)?);
    let (width, height) = (image.width, image.height);
    let noisy = sylva_denoise::Noisy {
        width,
        height,
        color: &image.pixels,
        albedo: Some(albedo),
        normal: Some(normal),
    };
    let clean = sylva_denoise::denoise(&noisy)?;
    let pixels = std::mem::replace(&mut image.pixels, clean);
    Ok(HdrImage { width, height, pixels })
}

/// Denoises the indirect light of `image` alone (the `indirect` pass of
/// `passes`, which splits the image into direct + indirect + sky), guided
/// by its albedo and normal; the direct light and the sky stay as traced.
/// The noisy image it was.
fn denoise_indirect(
    image: &mut HdrImage,
    passes: &sylva_scene::passes::PassImage,
) -> anyhow::Result<HdrImage> {
    use sylva_scene::passes::Pass;
    let noisy = passes
        .plane(Pass::Indirect)
        .ok_or_else(|| anyhow::anyhow!("denoise: the frame has no indirect pass"))?;
    let mut indirect = HdrImage {
        width: image.width,
        height: image.height,
        pixels: noisy.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    };
    denoise_image(&mut indirect, Some(passes))?;
    let before = image.clone();
    for ((p, n), d) in image.pixels.iter_mut().zip(noisy.chunks_exact(3)).zip(&indirect.pixels) {
        for c in 0..3 {
            p[c] += d[c] - n[c];
        }
    }
    Ok(before)
}

impl RenderedFrame {
    /// Denoises the assembled frame as `what` says (the whole of it, so
    /// no seams where strips meet), guided by its albedo and normal
    /// passes, and keeps the noisy image beside it for the EXR
    /// (docs/denoising.md). Its time, ms.
    pub fn denoise(&mut self, what: Denoise) -> anyhow::Result<f64> {
        let t = std::time::Instant::now();
        self.noisy = denoise(&mut self.image, self.passes.as_ref(), what)?;
        Ok(t.elapsed().as_secs_f64() * 1e3)
    }

    /// The frame as the OpenEXR results are kept in: one multi-layer file
    /// with its passes and, denoised, the noisy image; else plain RGB.
    pub fn exr(&self) -> anyhow::Result<Vec<u8>> {
        Ok(match &self.passes {
            Some(p) => sylva_scene::passes::encode_layers(&self.image, p, self.noisy.as_ref())?,
            None => crate::results::encode_exr(&self.image)?,
        })
    }
}

/// Renders the strips of a plan and assembles them into a frame.
pub trait StripExecutor {
    /// Renders every strip of `plan` (columns covering the frame exactly);
    /// `on_strip` hears of each as it is done.
    fn render(
        &mut self,
        plan: &[Strip],
        on_strip: &(dyn Fn(Strip) + Send + Sync),
    ) -> anyhow::Result<RenderedFrame>;
}

/// `n` strips of at most `width` columns each, left to right, covering
/// `[0, frame_width)`.
pub fn even_strips(frame_width: u32, width: u32) -> Vec<Strip> {
    (0..frame_width.div_ceil(width.max(1)))
        .map(|i| (i * width, ((i + 1) * width).min(frame_width)))
        .collect()
}
