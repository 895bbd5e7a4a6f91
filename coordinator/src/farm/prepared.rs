//! The scene prepared once for the farm: made or found on one worker,
//! exported, and imported by the others.

use super::{Client, PreparedShare, said};
use std::sync::Arc;
use std::time::{Duration, Instant};
use sylva_proto::pb;

/// Most bytes of prepared data the coordinator forwards between workers.
const MAX_PREPARED_BYTES: u64 = 4 << 30;

/// Has the farm pre-process the scene once: asks every worker whether it
/// holds what `frame` needs prepared; unless all do, one that does (or the
/// first, told to prepare it now) exports it, and the coordinator forwards
/// it to the others, which check it before keeping it. When every one of
/// them refuses it, that source is not trusted again and a refusing worker
/// (it checked the data, so it is sound) prepares and exports instead.
/// Meanwhile no strip is sent, so the others do not start the same work.
pub(super) async fn share_prepared(
    clients: &[Option<Client>],
    addrs: &[String],
    hash: &str,
    job: &str,
    frame: &pb::FrameSettings,
    deadline: Duration,
    stage: &(dyn Fn(String) + Sync),
) -> anyhow::Result<Option<PreparedShare>> {
    let live: Vec<(usize, Client)> =
        clients.iter().enumerate().filter_map(|(i, c)| c.clone().map(|c| (i, c))).collect();
    if live.len() < 2 {
        return Ok(None);
    }
    let ask = |build: bool| pb::PrepareRequest {
        scene_hash: hash.to_string(),
        frame: Some(frame.clone()),
        build,
        job: job.to_string(),
    };
    let mut held = futures_util::future::join_all(live.iter().map(|(_, c)| {
        let (mut c, req) = (c.clone(), ask(false));
        async move { c.prepare(req).await.ok().map(|r| r.into_inner().held) }
    }))
    .await;
    let t = Instant::now();
    let mut distrusted = Vec::new();
    let mut last = None;
    // Two rounds: the second only after every worker refused the first
    // source's data.
    for _ in 0..2 {
        // Workers that cannot answer (an older build) are left to prepare alone.
        let lacking: Vec<usize> = (0..live.len()).filter(|&k| held[k] == Some(false)).collect();
        if lacking.is_empty() {
            break;
        }
        let holder = (0..live.len()).find(|&k| held[k] == Some(true) && !distrusted.contains(&k));
        let (source, prepare_ms) = match holder {
            Some(k) => (k, 0.0),
            None => {
                let k = lacking[0];
                stage(format!(
                    "{} preparing the scene (structures, voxels, LB light)",
                    addrs[live[k].0]
                ));
                let mut req = tonic::Request::new(ask(true));
                req.set_timeout(deadline);
                let r = live[k].1.clone().prepare(req).await.map_err(|s| {
                    anyhow::anyhow!("{} could not prepare: {}", addrs[live[k].0], said(s.message()))
                })?;
                held[k] = Some(true);
                (k, r.into_inner().prepare_ms)
            }
        };
        let from = addrs[live[source].0].clone();
        let to: Vec<usize> = lacking.into_iter().filter(|&k| k != source).collect();
        let plural = if to.len() == 1 { "" } else { "s" };
        stage(format!("sharing the prepared scene from {from} with {} worker{plural}", to.len()));
        let mut exported = export_from(&live[source].1, ask(false), &from).await?;
        // The coordinator says which job the data serves, whatever the
        // exporter wrote: the importers use it for this job only.
        if let Some(first) = exported.first_mut() {
            first.job = job.to_string();
        }
        let chunks = Arc::new(exported);
        let bytes = chunks.iter().map(|c| c.data.len() as u64).sum();
        let imported = futures_util::future::join_all(to.iter().map(|&k| {
            let (mut c, chunks) = (live[k].1.clone(), chunks.clone());
            async move {
                c.import_prepared(tokio_stream::iter(chunks.iter().cloned().collect::<Vec<_>>()))
                    .await
                    .map(|r| r.into_inner().held)
            }
        }))
        .await;
        let mut sent = Vec::new();
        for (&k, r) in to.iter().zip(imported) {
            let addr = addrs[live[k].0].clone();
            match r {
                Ok(true) => {
                    held[k] = Some(true);
                    sent.push(addr);
                }
                Ok(false) => {
                    tracing::warn!(worker = %addr, "took the prepared data but does not hold it")
                }
                Err(s) => {
                    tracing::warn!(worker = %addr, from = %from, "refused the prepared data: {}", said(s.message()))
                }
            }
        }
        let refused_by_all = sent.is_empty() && !to.is_empty();
        last = Some(PreparedShare {
            from,
            to: sent,
            bytes,
            prepare_ms,
            share_ms: t.elapsed().as_secs_f64() * 1e3 - prepare_ms,
        });
        if !refused_by_all {
            break;
        }
        distrusted.push(source);
    }
    Ok(last)
}

/// Every chunk of a worker's export, counted against what it declared.
async fn export_from(
    client: &Client,
    req: pb::PrepareRequest,
    from: &str,
) -> anyhow::Result<Vec<pb::PreparedChunk>> {
    let mut stream = client
        .clone()
        .export_prepared(req)
        .await
        .map_err(|s| anyhow::anyhow!("{from} could not export: {}", said(s.message())))?
        .into_inner();
    let mut chunks: Vec<pb::PreparedChunk> = Vec::new();
    let (mut bytes, mut declared) = (0u64, None);
    while let Some(c) = stream
        .message()
        .await
        .map_err(|s| anyhow::anyhow!("{from} broke off its export: {}", said(s.message())))?
    {
        let total = *declared.get_or_insert(c.total_size);
        bytes += c.data.len() as u64;
        if bytes > total || total > MAX_PREPARED_BYTES {
            anyhow::bail!(
                "{from} exported more than its declared {total} bytes, or over {MAX_PREPARED_BYTES}"
            );
        }
        chunks.push(c);
    }
    Ok(chunks)
}
