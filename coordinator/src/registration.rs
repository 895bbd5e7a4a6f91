//! A worker announcing itself to its coordinator, again every few seconds
//! (a restarted coordinator learns its workers back within one period).
//! The coordinator answers by checking the worker's identity (see
//! `sylva_proto::auth::prove`); a refusal is logged with its reason.

use std::time::Duration;
use sylva_proto::pb;
use tonic::transport::ClientTlsConfig;

/// Time between registrations.
pub const PERIOD: Duration = Duration::from_secs(5);

/// What the coordinator's role check calls a worker's registration: a
/// token refused it ("a submitter token cannot register workers: …") will
/// never register, however often it tries.
pub const REGISTER: &str = "register workers";

/// Why a registration failed; the loop logs again only when the reason
/// changes.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RegistrationError {
    /// No connection to the coordinator.
    #[error("cannot reach the coordinator: {0}")]
    Unreachable(String),
    /// The coordinator answered no.
    #[error("the coordinator refused: {code:?}: {message}")]
    Refused {
        /// The call's status code.
        code: tonic::Code,
        /// What the coordinator said.
        message: String,
    },
}

/// Registers `me` (the address the coordinator should dial) with
/// `coordinator` once, under a fresh claim kept in `claims` (the worker's
/// identity service answers the coordinator's check only for it) and
/// showing the key `held` from before, if any: the key the coordinator
/// will call with, or its reason.
pub async fn register_once(
    coordinator: &str,
    me: &str,
    token: Option<String>,
    tls: Option<&ClientTlsConfig>,
    claims: &sylva_proto::auth::Claims,
    held: Option<String>,
) -> Result<String, RegistrationError> {
    let ch = sylva_proto::tls::connect(coordinator, tls, Duration::from_secs(10))
        .await
        .map_err(|e| RegistrationError::Unreachable(e.to_string()))?;
    let mut c = pb::coordinator_client::CoordinatorClient::with_interceptor(
        ch,
        sylva_proto::auth::attach(token),
    );
    c.register_worker(pb::RegisterWorkerRequest {
        addr: me.to_string(),
        claim: claims.fresh(),
        session_key: held.unwrap_or_default(),
    })
    .await
    .map(|r| r.into_inner().session_key)
    .map_err(|s| RegistrationError::Refused { code: s.code(), message: s.message().into() })
}

/// Registers forever, logging each change between success and failure,
/// and keeps the coordinator's key in `session` (the worker takes calls
/// made with it). Returns only when the coordinator refuses the token's
/// role: retrying cannot help, and the worker should stop and say why.
pub async fn register_loop(
    coordinator: String,
    me: String,
    token: Option<String>,
    tls: Option<ClientTlsConfig>,
    session: std::sync::Arc<std::sync::RwLock<Option<String>>>,
    claims: sylva_proto::auth::Claims,
) -> RegistrationError {
    let mut last: Option<Result<(), RegistrationError>> = None;
    loop {
        let held = sylva_proto::sync::read(&session).clone();
        let now = match register_once(&coordinator, &me, token.clone(), tls.as_ref(), &claims, held)
            .await
        {
            Ok(key) => {
                *sylva_proto::sync::write(&session) = Some(key).filter(|k| !k.is_empty());
                Ok(())
            }
            Err(e @ RegistrationError::Refused { code: tonic::Code::PermissionDenied, .. })
                if e.to_string().contains(&format!("token cannot {REGISTER}")) =>
            {
                return e;
            }
            Err(e) => Err(e),
        };
        if last.as_ref() != Some(&now) {
            match &now {
                Ok(()) => tracing::info!(%coordinator, "registered with the coordinator"),
                Err(e) => {
                    tracing::warn!(%coordinator, "cannot register: {e}; retrying every {}s", PERIOD.as_secs())
                }
            }
        }
        last = Some(now);
        tokio::time::sleep(PERIOD).await;
    }
}
