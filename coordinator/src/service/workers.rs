//! The workers the coordinator knows: named on its command line or
//! registered (after proving they hold the farm's token), polled by
//! heartbeats, listed for clients.

use super::{CoordinatorService, MAX_ID, State, caller};
use crate::access::Caller;
use crate::farm;
use std::sync::Arc;
use std::time::{Duration, Instant};
use sylva_proto::pb;
use sylva_proto::sync::lock;
use sylva_scene::sandbox::clip;
use tonic::{Request, Response, Status};

/// A worker the coordinator knows.
pub(super) struct KnownWorker {
    pub(super) info: pb::WorkerInfo,
    /// Named on the command line: never forgotten.
    pub(super) named: bool,
    /// Last registration or answered heartbeat.
    pub(super) seen: Instant,
    /// The key this coordinator calls it with, given at registration (a
    /// named worker is called with the coordinator's `--token`).
    pub(super) key: Option<String>,
}

impl KnownWorker {
    /// A worker the database remembers from before a restart: alive until
    /// a heartbeat says otherwise, forgotten when its registration expires.
    pub(super) fn restored(w: &crate::store::WorkerRow) -> Self {
        let ago = (crate::store::now_ms() as u64).saturating_sub(w.last_seen_ms);
        KnownWorker {
            info: pb::WorkerInfo {
                addr: w.addr.clone(),
                alive: true,
                strips_done: w.strips_done,
                strips_failed: w.strips_failed,
                ..Default::default()
            },
            named: false,
            seen: Instant::now()
                .checked_sub(Duration::from_millis(ago))
                .unwrap_or_else(Instant::now),
            // Keys are not kept: the worker gets a new one when it
            // registers again (within one period).
            key: None,
        }
    }

    fn row(&self) -> crate::store::WorkerRow {
        let ago = self.seen.elapsed().as_millis() as u64;
        crate::store::WorkerRow {
            addr: self.info.addr.clone(),
            strips_done: self.info.strips_done,
            strips_failed: self.info.strips_failed,
            last_seen_ms: (crate::store::now_ms() as u64).saturating_sub(ago),
        }
    }
}

impl CoordinatorService {
    pub(super) async fn workers(
        &self,
        _: Request<pb::ListWorkersRequest>,
    ) -> Result<Response<pb::WorkerList>, Status> {
        let workers = lock(&self.state.workers).values().map(|w| w.info.clone()).collect();
        Ok(Response::new(pb::WorkerList { workers }))
    }

    pub(super) async fn register(
        &self,
        request: Request<pb::RegisterWorkerRequest>,
    ) -> Result<Response<pb::RegisterWorkerReply>, Status> {
        let caller = caller(&self.state.access, &request)?;
        let pb::RegisterWorkerRequest { addr, claim, session_key: shown } = request.into_inner();
        if addr.len() > MAX_ID
            || addr.parse::<std::net::SocketAddr>().is_err() && !addr.contains(':')
        {
            return Err(Status::invalid_argument(format!(
                "worker address {:?} is not host:port",
                clip(&addr)
            )));
        }
        let known = lock(&self.state.workers)
            .get(&addr)
            .and_then(|w| w.key.clone().filter(|_| w.info.alive));
        // A worker renewing shows the key it was given (only it holds it).
        // Otherwise nothing — not a key, not a bundle — goes to an address
        // before the worker there proves it holds the caller's token *and*
        // sent this very registration (its claim): a key is never handed
        // to another holder of the token who names the address.
        let renewed = known
            .as_deref()
            .is_some_and(|k| sylva_proto::auth::constant_time_eq(k.as_bytes(), shown.as_bytes()));
        if !renewed {
            self.state.verify_worker(&addr, &caller, &claim).await?;
        }
        let key = known.unwrap_or_else(sylva_proto::auth::random_token);
        let (row, fresh) = {
            let mut w = lock(&self.state.workers);
            let entry = w.entry(addr.clone()).or_insert_with(|| KnownWorker {
                info: pb::WorkerInfo { addr: addr.clone(), ..Default::default() },
                named: false,
                seen: Instant::now(),
                key: None,
            });
            let fresh = entry.key.as_deref() != Some(key.as_str());
            entry.info.alive = true;
            entry.seen = Instant::now();
            entry.key = Some(key.clone());
            (entry.row(), fresh)
        };
        if fresh {
            tracing::info!(%addr, user = %caller.user, "worker registered");
            self.state.audit(&caller.user, "register worker", &addr, "").await;
            // A restarted coordinator finds it at once.
            if let Err(e) = self.state.store.put_workers(&[row]).await {
                tracing::warn!(%addr, "worker record not written: {e:#}");
            }
        }
        Ok(Response::new(pb::RegisterWorkerReply { session_key: key }))
    }
}

impl State {
    /// Polls every worker's status at once; a worker that does not answer
    /// is not given new jobs until it does; registrations not renewed
    /// within the TTL are forgotten, and so are finished jobs past their
    /// retention.
    pub(super) async fn heartbeat_loop(self: Arc<Self>) {
        loop {
            let addrs: Vec<(String, Option<String>)> = lock(&self.workers)
                .iter()
                .map(|(a, w)| (a.clone(), w.key.clone().or_else(|| self.config.token.clone())))
                .collect();
            let config = &self.config;
            let polls = addrs.into_iter().map(|(a, key)| async move {
                let status = async {
                    let mut c = farm::connect(&a, key, config.worker_tls.as_ref()).await.ok()?;
                    let mut req = Request::new(pb::StatusRequest {});
                    req.set_timeout(Duration::from_secs(5));
                    c.status(req).await.ok().map(|r| r.into_inner())
                }
                .await;
                (a, status)
            });
            for (a, status) in futures_util::future::join_all(polls).await {
                if let Some(w) = lock(&self.workers).get_mut(&a) {
                    match status {
                        Some(s) => {
                            if !w.info.alive {
                                tracing::info!(addr = %a, "worker answers again");
                            }
                            w.info.alive = true;
                            w.seen = Instant::now();
                            // A worker's reply is bounded before it is kept and listed.
                            w.info.adapter = clip(&s.adapter);
                            w.info.gpu_memory_bytes = s.gpu_memory_bytes;
                            w.info.cached_scenes =
                                s.cached_scenes.iter().take(1024).map(|h| clip(h)).collect();
                            w.info.busy_strips = s.busy_strips;
                            w.info.ray_queries = s.ray_queries;
                            w.info.backend = clip(&s.backend);
                            w.info.backend_why = clip(&s.backend_why);
                        }
                        None => {
                            // Said once, when it stops answering, not every poll.
                            if w.info.alive {
                                tracing::warn!(addr = %a, "worker does not answer its status poll");
                            }
                            w.info.alive = false;
                        }
                    }
                }
            }
            let ttl = self.config.registration_ttl;
            let mut forgotten = Vec::new();
            let rows: Vec<crate::store::WorkerRow> = {
                let mut workers = lock(&self.workers);
                workers.retain(|addr, w| {
                    let keep = w.named || w.seen.elapsed() < ttl;
                    if !keep {
                        tracing::info!(%addr, "forgot a worker whose registration expired");
                        forgotten.push(addr.clone());
                    }
                    keep
                });
                workers.values().map(KnownWorker::row).collect()
            };
            // Per-worker records, for a restarted coordinator and for audits.
            if let Err(e) = self.store.put_workers(&rows).await {
                tracing::warn!("worker records not written: {e:#}");
            }
            for addr in forgotten {
                let _ = self.store.delete_worker(&addr).await;
            }
            self.sweep().await;
            // Tokens added or revoked on the state folder take effect here.
            match self.store.tokens().await {
                Ok(t) => self.access.set(t),
                Err(e) => tracing::warn!("tokens not re-read: {e:#}"),
            }
            tokio::time::sleep(self.config.heartbeat).await;
        }
    }

    /// Checks that the worker at `addr` holds the token `caller` registered
    /// with: it must answer a fresh nonce with the keyed hash only a
    /// holder of that token can make (a user's token: keyed by the token's
    /// record; the coordinator's own: by Argon2id of it).
    pub(super) async fn verify_worker(
        &self,
        addr: &str,
        caller: &Caller,
        claim: &[u8],
    ) -> Result<(), Status> {
        let refused =
            |why: &str| Status::permission_denied(format!("worker {}: {why}", clip(addr)));
        let ch = sylva_proto::tls::connect(
            addr,
            self.config.worker_tls.as_ref(),
            Duration::from_secs(5),
        )
        .await
        .map_err(|_| refused("cannot be reached at that address from the coordinator"))?;
        let nonce = sylva_proto::auth::random_bytes(32);
        let mut c = pb::worker_identity_client::WorkerIdentityClient::new(ch);
        let mut req =
            Request::new(pb::ProveRequest { nonce: nonce.clone(), claim: claim.to_vec() });
        req.set_timeout(Duration::from_secs(5));
        let reply = c
            .prove(req)
            .await
            .map_err(|s| {
                if s.code() == tonic::Code::PermissionDenied {
                    refused("did not send this registration: only the worker at an address may register it")
                } else {
                    refused("does not answer the identity check (is it a Sylva worker?)")
                }
            })?
            .into_inner();
        let checked = if !reply.token_id.is_empty() || !caller.token_id.is_empty() {
            // A user's token: the address must hold the very token the
            // registration came with.
            reply.token_id == caller.token_id
                && self.access.key_of(&reply.token_id).is_some_and(|key| {
                    sylva_proto::auth::constant_time_eq(
                        &sylva_proto::auth::prove_with_key(&key, &nonce),
                        &reply.proof,
                    )
                })
        } else {
            let token = self.config.token.clone();
            tokio::task::spawn_blocking(move || {
                sylva_proto::auth::check_proof(token.as_deref(), &nonce, &reply.salt, &reply.proof)
            })
            .await
            .unwrap_or(false)
        };
        if !checked {
            return Err(refused(
                "could not prove it holds the token it registered with; start it with the farm's token (--token-file)",
            ));
        }
        Ok(())
    }
}
