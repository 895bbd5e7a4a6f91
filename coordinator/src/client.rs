//! A client of the coordinator: submit a job, follow it with a progress
//! bar, fetch its image.

use crate::job_state::{JobState, wire_ended, wire_name};
use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use std::time::Duration;
use sylva_proto::pb;
use sylva_proto::pb::coordinator_client::CoordinatorClient;
use tokio_stream::StreamExt;
use tonic::service::interceptor::InterceptedService;

/// A finished job, fetched.
pub struct FinishedJob {
    /// Its id.
    pub id: String,
    /// The tone-mapped image of each frame (one unless a sequence).
    pub pngs: Vec<Vec<u8>>,
    /// The linear HDR frames, when asked for.
    pub exrs: Option<Vec<Vec<u8>>>,
    /// The coordinator's stats of the frame.
    pub stats: serde_json::Value,
    /// Where the client's time went.
    pub times: ClientTimes,
}

/// Where a submission's time went on the client, ms.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct ClientTimes {
    /// Connecting and sending the spec and the bundle, until the job's id.
    pub submit_ms: f64,
    /// Watching the job until its end event.
    pub wait_ms: f64,
    /// Fetching the results.
    pub fetch_ms: f64,
}

/// A client of the coordinator at `addr`, carrying `token`.
pub type Client =
    CoordinatorClient<InterceptedService<tonic::transport::Channel, sylva_proto::auth::Attach>>;

/// Connects to the coordinator at `addr` (within 10 s), with `token` on every call.
pub async fn connect(
    addr: &str,
    token: Option<String>,
    tls: Option<&tonic::transport::ClientTlsConfig>,
) -> anyhow::Result<Client> {
    let ch = sylva_proto::tls::connect(addr, tls, Duration::from_secs(10))
        .await
        .with_context(|| format!("cannot reach the coordinator at {addr}"))?;
    Ok(CoordinatorClient::with_interceptor(ch, sylva_proto::auth::attach(token))
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(1 << 30))
}

/// A call's error as a person reads it: the code and the server's message.
pub fn status_error(s: tonic::Status) -> anyhow::Error {
    if connection_lost(&s) {
        return anyhow::anyhow!(
            "the connection to the coordinator was lost (it stopped, or the network failed)"
        );
    }
    anyhow::anyhow!("{:?}: {}", s.code(), s.message())
}

/// Whether a call failed because the connection under it broke (the
/// coordinator died mid-call), not because the coordinator answered no:
/// the transport's own words ("h2 protocol error", "broken pipe") mean
/// nothing to a user.
fn connection_lost(s: &tonic::Status) -> bool {
    use tonic::Code;
    let m = s.message().to_ascii_lowercase();
    matches!(s.code(), Code::Unknown | Code::Unavailable | Code::Internal | Code::Cancelled)
        && [
            "h2 protocol error",
            "transport error",
            "broken pipe",
            "connection reset",
            "stream closed",
            "error reading a body",
        ]
        .iter()
        .any(|w| m.contains(w))
}

/// Sends a job to the coordinator at `addr`, follows it with a progress
/// bar and fetches its image.
pub async fn submit_and_follow(
    addr: &str,
    token: Option<String>,
    tls: Option<&tonic::transport::ClientTlsConfig>,
    spec: pb::JobSpec,
    bundle: &sylva_scene::bundle::SceneBundle,
    exr: bool,
) -> anyhow::Result<FinishedJob> {
    let views = spec.views.len();
    let t = std::time::Instant::now();
    let ms = |t: std::time::Instant| t.elapsed().as_secs_f64() * 1e3;
    let mut c = connect(addr, token, tls).await?;
    let mut chunks = vec![pb::SubmitChunk {
        spec: Some(spec),
        hash: bundle.hash.clone(),
        total_size: bundle.bytes.len() as u64,
        data: vec![],
    }];
    chunks.extend(
        bundle
            .bytes
            .chunks(1 << 20)
            .map(|d| pb::SubmitChunk { data: d.to_vec(), ..Default::default() }),
    );
    let id = c.submit_job(tokio_stream::iter(chunks)).await.map_err(status_error)?.into_inner().id;
    let mut times = ClientTimes { submit_ms: ms(t), ..Default::default() };
    let t = std::time::Instant::now();
    let mut progress = JobProgress::new(&id, views);
    let lost = |e: anyhow::Error| {
        e.context(format!(
            "job {id} was accepted, and is kept if the coordinator keeps a state folder: \
             `sylva jobs` and `sylva fetch {id}` once it is back"
        ))
    };
    let mut events = c
        .watch_job(pb::JobId { id: id.clone() })
        .await
        .map_err(status_error)
        .map_err(lost)?
        .into_inner();
    let mut end = None;
    while let Some(ev) = events.next().await {
        let ev = ev.map_err(status_error).map_err(lost)?;
        progress.update(&ev);
        if !ev.message.is_empty() && !wire_ended(ev.state) {
            tracing::warn!("{}", ev.message);
        }
        if wire_ended(ev.state) {
            end = Some(ev);
            break;
        }
    }
    progress.finish();
    let end = end.context("the coordinator closed the job's event stream early")?;
    if JobState::from_wire(end.state) != Some(JobState::Done) {
        // A cancel carries no reason: no empty one is printed after a colon.
        let why = if end.message.is_empty() { String::new() } else { format!(": {}", end.message) };
        bail!("job {id} {}{why}", wire_name(end.state));
    }
    times.wait_ms = ms(t);
    let t = std::time::Instant::now();
    let frames = views.max(1) as u32;
    let mut fetch = async |format: &str| -> anyhow::Result<Vec<Vec<u8>>> {
        let mut out = Vec::new();
        for frame in 0..frames {
            out.push(
                c.fetch_result(pb::FetchRequest { id: id.clone(), format: format.into(), frame })
                    .await
                    .map_err(status_error)?
                    .into_inner()
                    .data,
            );
        }
        Ok(out)
    };
    let pngs = fetch("png").await?;
    let exrs = if exr { Some(fetch("exr").await?) } else { None };
    times.fetch_ms = ms(t);
    let stats = serde_json::from_str(&end.stats_json).unwrap_or(serde_json::Value::Null);
    Ok(FinishedJob { id, pngs, exrs, stats, times })
}

/// The warnings a finished job's figures carry (a frame's, or every
/// frame's of a sequence), each once, in the order first found.
pub fn warnings_of(stats: &serde_json::Value) -> Vec<String> {
    let frames =
        stats["sequence"]["per_frame"].as_array().map_or(vec![stats], |f| f.iter().collect());
    let mut out: Vec<String> = Vec::new();
    for w in frames.iter().filter_map(|f| f["warnings"].as_array()).flatten() {
        if let Some(w) = w.as_str().map(printable)
            && !out.contains(&w)
        {
            out.push(w);
        }
    }
    out
}

/// What a person sees of a job while it runs: on a terminal, a bar of the
/// strips whose message names the stage (queued; the workers preparing the
/// scene: structures, voxels, LB light, upload; tracing) and, once strips
/// return, the time left, cut to the terminal's width; elsewhere (a log, a
/// pipe), one line per stage and per quarter of the strips.
struct JobProgress {
    id: String,
    bar: ProgressBar,
    stage: String,
    farm_stage: String,
    quarter: u32,
}

impl JobProgress {
    fn new(id: &str, views: usize) -> Self {
        let bar = ProgressBar::new_spinner();
        let unit = if views > 1 { format!(" ({views} frames)") } else { String::new() };
        // The stage last and cut (`wide_msg`): the line never wraps.
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{{prefix}} [{{bar:20}}] {{pos}}/{{len}}{unit} {{elapsed}} {{wide_msg}}"
            ))
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar.set_prefix(printable(id));
        bar.enable_steady_tick(Duration::from_millis(200));
        Self { id: printable(id), bar, stage: String::new(), farm_stage: String::new(), quarter: 0 }
    }

    fn update(&mut self, ev: &pb::JobEvent) {
        let state = JobState::from_wire(ev.state);
        if !ev.stage.is_empty() {
            self.farm_stage.clone_from(&ev.stage);
        }
        // Until the first strip is back, the farm's own word for its stage.
        let stage = match state {
            Some(JobState::Queued) => "queued".to_string(),
            Some(JobState::Running) if ev.strips_done == 0 && self.farm_stage.is_empty() => {
                "starting on the workers".to_string()
            }
            Some(JobState::Running) if ev.strips_done == 0 => printable(&self.farm_stage),
            Some(JobState::Running) => "tracing".to_string(),
            _ => self.stage.clone(),
        };
        if ev.strips_total > 0 {
            self.bar.set_length(ev.strips_total as u64);
            self.bar.set_position(ev.strips_done as u64);
        }
        let hidden = self.bar.is_hidden();
        let left = if ev.eta_ms > 0 { format!(", {} left", eta(ev.eta_ms)) } else { "".into() };
        if !hidden {
            self.bar.set_message(format!("{stage}{left}"));
        }
        if stage != self.stage {
            if hidden {
                eprintln!("{}: {stage}", self.id);
            }
            self.stage = stage;
        }
        let quarter = (4 * u64::from(ev.strips_done) / u64::from(ev.strips_total.max(1))) as u32;
        if hidden && quarter > self.quarter && ev.strips_done < ev.strips_total {
            eprintln!("{}: {}/{} strips{left}", self.id, ev.strips_done, ev.strips_total);
        }
        self.quarter = self.quarter.max(quarter);
    }

    fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// A time left as a person reads it: `~12 s`, `~3 min`.
fn eta(ms: u64) -> String {
    let s = ms.div_ceil(1000);
    if s < 120 { format!("~{s} s") } else { format!("~{} min", s.div_ceil(60)) }
}

/// `s` from the wire as it may reach a terminal: control characters (escape
/// sequences, carriage returns) written as escapes, not obeyed.
fn printable(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::printable;

    #[test]
    fn text_from_the_wire_cannot_drive_the_terminal() {
        let hostile = "w\u{1b}]0;TITLE\u{7}\u{1b}[2J\rforged:1 preparing";
        let shown = printable(hostile);
        assert!(!shown.chars().any(char::is_control), "{shown:?}");
        assert_eq!(shown, "w\\u{1b}]0;TITLE\\u{7}\\u{1b}[2J\\rforged:1 preparing");
        assert_eq!(printable("127.0.0.1:5 préparant"), "127.0.0.1:5 préparant");
    }
}
