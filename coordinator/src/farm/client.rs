//! Reaching a worker and sending it the scene.

use super::{FarmEvent, WorkerReport, Workers, said};
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::pb::worker_client::WorkerClient;
use sylva_scene::bundle::SceneBundle;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, ClientTlsConfig};

/// Bytes per upload chunk.
const CHUNK: usize = 1 << 20;

/// A worker client that sends the bearer token, if any.
pub type Client = WorkerClient<InterceptedService<Channel, sylva_proto::auth::Attach>>;

/// Connects to a worker at `addr` (`host:port`), over TLS when `tls` is
/// set, sending `token` with every call.
pub async fn connect(
    addr: &str,
    token: Option<String>,
    tls: Option<&ClientTlsConfig>,
) -> anyhow::Result<Client> {
    let ch = sylva_proto::tls::connect(addr, tls, Duration::from_secs(10))
        .await
        .map_err(|e| anyhow::anyhow!("cannot reach worker {addr}: {e}"))?;
    Ok(WorkerClient::with_interceptor(ch, sylva_proto::auth::attach(token))
        .max_decoding_message_size(1 << 30)
        .max_encoding_message_size(1 << 30))
}

/// Sends `bundle` to a worker (a single empty chunk first, in case it is
/// cached); returns the bytes sent.
pub async fn upload(client: &mut Client, bundle: &SceneBundle) -> Result<u64, tonic::Status> {
    let probe = pb::SceneChunk {
        hash: bundle.hash.clone(),
        total_size: bundle.bytes.len() as u64,
        data: Vec::new(),
    };
    if bundle.bytes.is_empty()
        || client
            .load_scene(tokio_stream::iter(vec![probe]))
            .await
            .is_ok_and(|r| r.get_ref().was_cached)
    {
        return Ok(0);
    }
    let chunks: Vec<pb::SceneChunk> = bundle
        .bytes
        .chunks(CHUNK)
        .enumerate()
        .map(|(i, c)| pb::SceneChunk {
            hash: if i == 0 { bundle.hash.clone() } else { String::new() },
            total_size: if i == 0 { bundle.bytes.len() as u64 } else { 0 },
            data: c.to_vec(),
        })
        .collect();
    client.load_scene(tokio_stream::iter(chunks)).await.map(|_| bundle.bytes.len() as u64)
}

/// Sends the bundle to every worker at once (a slow one delays only
/// itself); a worker that cannot take it is reported and left out.
pub(super) async fn upload_to_all(
    workers: &Workers,
    bundle: &SceneBundle,
    events: &(impl Fn(FarmEvent) + Send + Sync),
) -> (Vec<Option<Client>>, Vec<WorkerReport>, f64) {
    let t = Instant::now();
    // Every worker gets the bundle at once; a slow one delays only itself.
    let uploads = workers.addrs.iter().map(|w| {
        let (w, token, tls) = (w.clone(), workers.token_for(w), workers.tls.clone());
        async move {
            let client = async {
                let mut c = connect(&w, token, tls.as_ref()).await?;
                let bytes = upload(&mut c, bundle).await.map_err(|e| {
                    anyhow::anyhow!("scene upload: {:?}: {}", e.code(), said(e.message()))
                })?;
                anyhow::Ok((c, bytes))
            }
            .await;
            (w, client)
        }
    });
    let uploaded = futures_util::future::join_all(uploads).await;
    let upload_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut clients = Vec::new();
    let mut reports: Vec<WorkerReport> = Vec::new();
    for (w, r) in uploaded {
        let mut report = WorkerReport { worker: w.clone(), ..Default::default() };
        match r {
            Ok((c, bytes)) => {
                if bytes > 0 {
                    events(FarmEvent::BundleSent { worker: w.clone(), bytes });
                }
                clients.push(Some(c));
            }
            Err(error) => {
                let error = error.to_string();
                report.dropped = true;
                report.last_error = Some(error.clone());
                events(FarmEvent::WorkerDropped { worker: w.clone(), error });
                clients.push(None);
            }
        }
        reports.push(report);
    }
    (clients, reports, upload_ms)
}
