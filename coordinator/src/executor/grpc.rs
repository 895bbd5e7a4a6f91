//! Strips rendered by gRPC workers ([`crate::farm`]), from synchronous code.

use super::{RenderedFrame, StripExecutor};
use crate::farm::{FarmEvent, Workers, render_frame};
use crate::schedule::Strip;
use std::sync::Arc;
use std::time::Duration;
use sylva_proto::sync::lock;
use sylva_scene::bundle::SceneBundle;
use sylva_scene::frame::FrameSettings;

/// Workers, the scene they are sent and the frame they render.
pub struct Farm<'a> {
    rt: &'a tokio::runtime::Runtime,
    workers: Workers,
    bundle: &'a SceneBundle,
    frame: FrameSettings,
    deadline: Duration,
}

impl<'a> Farm<'a> {
    /// Renders `frame` of `bundle` on `workers`, each strip within `deadline`,
    /// driving the calls on `rt`.
    pub fn new(
        rt: &'a tokio::runtime::Runtime,
        workers: Workers,
        bundle: &'a SceneBundle,
        frame: FrameSettings,
        deadline: Duration,
    ) -> Self {
        Self { rt, workers, bundle, frame, deadline }
    }
}

impl StripExecutor for Farm<'_> {
    fn render(
        &mut self,
        plan: &[Strip],
        on_strip: &(dyn Fn(Strip) + Send + Sync),
    ) -> anyhow::Result<RenderedFrame> {
        // The farm calls back from its own tasks: hand the strips over.
        let (tx, rx) = std::sync::mpsc::channel();
        let tx = Arc::new(std::sync::Mutex::new(tx));
        let events = move |e: FarmEvent| {
            if let FarmEvent::StripDone { strip, .. } = e {
                let _ = lock(&tx).send(strip);
            }
        };
        let frame = self.rt.block_on(render_frame(
            &self.workers,
            self.bundle,
            self.frame,
            plan.to_vec(),
            self.deadline,
            events,
        ));
        for s in rx.try_iter() {
            on_strip(s);
        }
        frame
    }
}
