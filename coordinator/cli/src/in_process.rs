//! Strips rendered on this process's GPU, one after another.

use sylva_coordinator::assembly::{Assembly, StripPixels};
use sylva_coordinator::executor::{RenderedFrame, StripExecutor};
use sylva_coordinator::schedule::{Strip, StripTime};
use sylva_worker::frame::Frame;

/// A frame composed on this process's GPU, its strips assembled as a
/// farm's are.
pub struct InProcess<'a> {
    frame: &'a Frame,
}

impl<'a> InProcess<'a> {
    /// Renders `frame`'s strips.
    pub fn new(frame: &'a Frame) -> Self {
        Self { frame }
    }
}

impl StripExecutor for InProcess<'_> {
    fn render(
        &mut self,
        plan: &[Strip],
        on_strip: &(dyn Fn(Strip) + Send + Sync),
    ) -> anyhow::Result<RenderedFrame> {
        let f = &self.frame.settings;
        let mut frame = Assembly::new(f.width, f.height, f.passes);
        let mut strip_times = Vec::with_capacity(plan.len());
        self.frame.strips(plan, &mut |s, ms| {
            let (x0, x1) = (s.x0, s.x0 + s.width);
            let px = StripPixels {
                strip: (x0, x1),
                rgb: s.pixels,
                coverage: s.coverage,
                rays: s.rays,
                passes: s.passes,
                warnings: self.frame.warnings(),
            };
            frame.add(&px).map_err(|e| {
                anyhow::anyhow!("the renderer returned a strip that does not fit: {e}")
            })?;
            strip_times.push(StripTime { strip: (x0, x1), render_ms: ms, call_ms: ms });
            on_strip((x0, x1));
            Ok(())
        })?;
        anyhow::ensure!(frame.complete(), "the plan does not cover the frame");
        Ok(RenderedFrame {
            image: frame.image,
            coverage: frame.coverage,
            rays: frame.rays,
            workers: Vec::new(),
            strip_times,
            upload_ms: 0.0,
            prepared: None,
            passes: frame.passes,
            warnings: frame.warnings,
            noisy: None,
        })
    }
}
