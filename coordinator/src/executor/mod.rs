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
