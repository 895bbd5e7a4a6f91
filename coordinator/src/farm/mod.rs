//! Renders a frame on a set of gRPC workers: every worker gets the scene
//! bundle (all at once), then pulls strips from one queue until the frame
//! is done. A strip whose worker fails, misses its deadline or returns a
//! reply that does not fit the strip goes back on the queue for another; a
//! worker that fails three times is dropped for this frame; the frame fails
//! only when no worker is left, and then says what each worker last failed
//! with. Strips land by their columns
//! ([`Assembly`](crate::assembly::Assembly)), so the frame is the same
//! whoever rendered what.
//!
//! In parts: reaching the workers and sending them the scene ([`client`]),
//! a reply checked before use ([`reply`]), the scene prepared once and
//! shared (`prepared`), a run over frames and strips ([`run`]) and one
//! worker's pulling of strips (`pull`).

pub mod client;
mod prepared;
mod pull;
pub mod reply;
pub mod run;

pub use client::{Client, connect, upload};
pub use reply::{BadReply, decode_reply};
pub use run::{FarmJob, FarmRun, Finished, Resume, render_frame, render_frames, render_streamed};

use crate::schedule::Strip;
use serde::Serialize;
use std::sync::Arc;
use tonic::transport::ClientTlsConfig;

/// What a worker said (an error's text), as it may be shown and logged:
/// bounded, and escaped so it cannot drive a terminal or forge a log line.
fn said(text: &str) -> String {
    sylva_scene::sandbox::printable(text, 500)
}

/// Failures after which a worker is dropped for the frame.
pub const MAX_FAILURES: u32 = 3;

/// What happened, for progress bars and logs.
#[derive(Clone, Debug)]
pub enum FarmEvent {
    /// A strip of `frame` (0 unless a sequence) came back with `bytes` of
    /// pixels; `preview` is it in 8-bit sRGB, rows from the top (for a
    /// live view).
    StripDone {
        frame: usize,
        strip: Strip,
        worker: String,
        ms: f64,
        bytes: u64,
        preview: Arc<Vec<[u8; 3]>>,
    },
    /// A scene bundle of `bytes` was sent to a worker.
    BundleSent { worker: String, bytes: u64 },
    /// A strip failed on a worker and was put back on the queue.
    StripRetried { frame: usize, strip: Strip, worker: String, error: String },
    /// A worker was dropped for this frame.
    WorkerDropped { worker: String, error: String },
    /// The scene's prepared data was made or found on one worker and sent
    /// to the others.
    PreparedShared(PreparedShare),
    /// What the farm is doing now, in words: sending the scene, one worker
    /// preparing it, sharing what it prepared, tracing.
    Stage(String),
    /// The strips this run will render (fewer than planned when an earlier
    /// run left frames or strips), and those an earlier run rendered: the
    /// job's progress counts both.
    Planned { strips: usize, kept: usize },
}

/// How a job's scene was prepared once for the farm.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PreparedShare {
    /// The worker that held or made the prepared data.
    pub from: String,
    /// The workers that took it.
    pub to: Vec<String>,
    /// Bytes sent to each.
    pub bytes: u64,
    /// Time `from` spent preparing (0 when it held the data already), ms.
    pub prepare_ms: f64,
    /// Time to export it and for every other worker to take it, ms.
    pub share_ms: f64,
}

/// Per-worker figures of one frame.
#[derive(Clone, Debug, Default, Serialize)]
pub struct WorkerReport {
    /// Address.
    pub worker: String,
    /// Strips rendered.
    pub strips: u32,
    /// Milliseconds spent rendering them (as the worker measured).
    pub render_ms: f64,
    /// Milliseconds of scene preparation (first strip of a new scene).
    pub prepare_ms: f64,
    /// Strips that failed here.
    pub failures: u32,
    /// Whether the worker was dropped.
    pub dropped: bool,
    /// What it last failed with.
    pub last_error: Option<String>,
}

/// Where and how to reach the workers.
#[derive(Clone, Debug, Default)]
pub struct Workers {
    /// Addresses, `host:port`.
    pub addrs: Vec<String>,
    /// Bearer token the workers require, if any.
    pub token: Option<String>,
    /// TLS to reach them with, if they serve it.
    pub tls: Option<ClientTlsConfig>,
    /// Per worker, the key it was given at registration, sent in place of
    /// `token` (only calls with it may push prepared data into the worker).
    pub keys: std::collections::HashMap<String, String>,
    /// The job these calls serve: a worker uses prepared data imported
    /// for a job for that job's strips only.
    pub job: String,
}

impl Workers {
    /// Workers that need no token.
    pub fn open(addrs: &[String]) -> Self {
        Self { addrs: addrs.to_vec(), ..Default::default() }
    }

    /// The bearer token to call `addr` with.
    pub fn token_for(&self, addr: &str) -> Option<String> {
        self.keys.get(addr).cloned().or_else(|| self.token.clone())
    }
}
