//! What a finished job reports about itself (`JobEvent.stats_json`, the
//! `.stats.json` beside an image): typed here, serialized once.

use crate::executor::RenderedFrame;
use crate::farm::{PreparedShare, WorkerReport};
use crate::schedule::ScheduleKind;
use serde::Serialize;
use sylva_scene::film::ToneMapStats;

/// A finished job's figures.
#[derive(Clone, Debug, Serialize)]
pub struct JobStats {
    /// The strip schedule.
    pub schedule: ScheduleKind,
    /// Where the strips' cost came from: uniform, or measured on a frame before.
    pub strip_cost: &'static str,
    /// The whole job's render time (all frames), ms.
    pub frame_ms: f64,
    /// Time to get the scene to the workers, ms.
    pub upload_ms: f64,
    /// Where the job's time went on the coordinator.
    pub phases: JobPhases,
    /// How the scene was prepared once and shared, when it was.
    pub prepared_once: Option<PreparedShare>,
    /// Per worker.
    pub workers: Vec<WorkerReport>,
    /// One frame's figures ([`FrameStats`], as stored with the frame),
    /// beside the job's (a single frame).
    #[serde(flatten)]
    pub frame: Option<serde_json::Value>,
    /// A sequence's figures.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sequence: Option<SequenceStats>,
}

/// Where a job's time went on the coordinator, ms (`sylva bench farm`
/// tables them against the client's and the workers' times).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct JobPhases {
    /// From the farm's start (the bundle read and the strips planned)
    /// until it handed over its last frame: the scene's upload, the strips
    /// rendered and sent back, the frames assembled.
    pub farm_ms: f64,
    /// Encoding, hashing and writing the frames' EXRs and recording them,
    /// summed: beside the farm for a sequence's earlier frames, after it
    /// for the last (a single frame's all after it).
    pub store_ms: f64,
    /// From the farm's start until the last frame was stored.
    pub stored_ms: f64,
    /// After the farm: the frames tone mapped and their PNGs written.
    pub tone_map_ms: f64,
}

/// One frame's figures.
#[derive(Clone, Debug, Serialize)]
pub struct FrameStats {
    /// Every strip, left to right.
    pub strips: Vec<StripStats>,
    /// Rays traced.
    pub rays: RayStats,
    /// Mean fraction of samples that hit a model.
    pub coverage: f64,
    /// What the tone mapper measured.
    pub tone_map: ToneMapStats,
    /// What the workers' lighting found about the scene that its user
    /// should hear ("model: finding"), each once.
    pub warnings: Vec<String>,
}

/// One strip's times.
#[derive(Clone, Debug, Serialize)]
pub struct StripStats {
    /// Columns `[x0, x1)`.
    pub x0: u32,
    /// End column.
    pub x1: u32,
    /// Render time on the worker, ms.
    pub render_ms: f64,
    /// The whole call (render plus transfer), ms.
    pub rpc_ms: f64,
}

/// Rays traced for a frame.
#[derive(Clone, Debug, Serialize)]
pub struct RayStats {
    /// Camera rays.
    pub primary: u64,
    /// Rays towards the sun.
    pub shadow: u64,
    /// Transparent texels a ray passed through and went on.
    pub transparent_passed: u64,
    /// Primary and shadow rays per second of the frame's time, millions.
    pub mrays_per_second: f64,
}

/// A sequence's figures.
#[derive(Clone, Debug, Serialize)]
pub struct SequenceStats {
    /// Frames rendered.
    pub frames: usize,
    /// The job's time over its frames, ms.
    pub ms_per_frame: f64,
    /// Whether whole frames went to workers side by side (no strips cut).
    pub whole_frames_in_parallel: bool,
    /// Each frame's figures ([`FrameStats`], as stored with the frame).
    pub per_frame: Vec<serde_json::Value>,
}

impl FrameStats {
    /// The figures of `f`, tone mapped as `tone`, rendered in `ms`.
    pub fn of(f: &RenderedFrame, tone: &ToneMapStats, ms: f64) -> Self {
        let strips = f
            .strip_times
            .iter()
            .map(|t| StripStats {
                x0: t.strip.0,
                x1: t.strip.1,
                render_ms: t.render_ms,
                rpc_ms: t.call_ms,
            })
            .collect();
        let rays = RayStats {
            primary: f.rays.primary,
            shadow: f.rays.shadow,
            transparent_passed: f.rays.transparent,
            mrays_per_second: f.rays.traced() as f64 / (ms / 1e3) / 1e6,
        };
        let coverage =
            f.coverage.iter().map(|&c| c as f64).sum::<f64>() / f.coverage.len().max(1) as f64;
        FrameStats { strips, rays, coverage, tone_map: *tone, warnings: f.warnings.clone() }
    }
}
