//! A job's frame as the dashboard shows it while (and after) it renders.

use crate::schedule::Strip;

/// A frame as the dashboard shows it while (and after) it renders.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LiveFrame {
    /// Image size.
    pub width: u32,
    pub height: u32,
    /// The newest frame (of a sequence) a strip came back for: the preview
    /// shows its strips over the frames before it.
    pub frame: usize,
    /// Strips in the order they came back or failed.
    pub strips: Vec<LiveStrip>,
    /// 8-bit sRGB, `width × height × 3`, black where no strip is yet;
    /// dropped when the job ends (its result is the image then).
    #[serde(skip)]
    pub preview: Vec<u8>,
}

/// One strip's outcome on one worker.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LiveStrip {
    /// The frame of a sequence (0 for one frame).
    pub frame: usize,
    /// Columns [x0, x1).
    pub x0: u32,
    pub x1: u32,
    /// The worker that rendered (or failed) it.
    pub worker: String,
    /// Render time on the worker, ms (0 when it failed).
    pub ms: f64,
    /// Why it failed; empty when it came back.
    pub error: String,
}

impl LiveFrame {
    pub(super) fn paint(&mut self, strip: Strip, px: &[[u8; 3]]) {
        let (x0, x1) = strip;
        let w = (x1 - x0) as usize;
        if self.preview.len() != self.width as usize * self.height as usize * 3
            || px.len() != w * self.height as usize
            || x1 > self.width
        {
            return;
        }
        for (y, row) in px.chunks_exact(w).enumerate() {
            let at = 3 * (y * self.width as usize + x0 as usize);
            self.preview[at..at + 3 * w].copy_from_slice(row.as_flattened());
        }
    }
}
