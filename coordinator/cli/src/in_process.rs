//! Strips rendered on this process's GPU, one after another.

use std::time::Instant;
use sylva_coordinator::assembly::{Assembly, StripPixels};
use sylva_coordinator::executor::{RenderedFrame, StripExecutor};
use sylva_coordinator::schedule::{Strip, StripTime};
use sylva_worker::GpuContext;
use sylva_worker::trace::{RenderSettings, StripRenderer};

/// This process's GPU and a prepared scene.
pub struct InProcess<'a> {
    ctx: &'a GpuContext,
    renderer: &'a StripRenderer,
    settings: RenderSettings,
}

impl<'a> InProcess<'a> {
    /// Renders with `renderer` on `ctx` what `settings` asks for.
    pub fn new(ctx: &'a GpuContext, renderer: &'a StripRenderer, settings: RenderSettings) -> Self {
        Self { ctx, renderer, settings }
    }
}

impl StripExecutor for InProcess<'_> {
    fn render(
        &mut self,
        plan: &[Strip],
        on_strip: &(dyn Fn(Strip) + Send + Sync),
    ) -> anyhow::Result<RenderedFrame> {
        let f = &self.settings;
        let mut frame = Assembly::new(f.width, f.height, f.passes);
        let mut strip_times = Vec::with_capacity(plan.len());
        for &(x0, x1) in plan {
            let t = Instant::now();
            let s = self.renderer.render_strip(self.ctx, f, x0, x1)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let px = StripPixels {
                strip: (x0, x1),
                rgb: s.pixels,
                coverage: s.coverage,
                rays: s.rays,
                passes: s.passes,
            };
            frame.add(&px).map_err(|e| {
                anyhow::anyhow!("the renderer returned a strip that does not fit: {e}")
            })?;
            strip_times.push(StripTime { strip: (x0, x1), render_ms: ms, call_ms: ms });
            on_strip((x0, x1));
        }
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
        })
    }
}
