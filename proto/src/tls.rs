//! Optional TLS (rustls) for both services and every client of them: a
//! server with a certificate and key serves `https`; a client given a CA
//! certificate connects over TLS and checks the server against it.

use std::path::Path;
use std::time::Duration;
use tonic::transport::{
    Certificate, Channel, ClientTlsConfig, Endpoint, Identity, ServerTlsConfig,
};

/// Why TLS could not be set up.
#[derive(Debug)]
pub struct TlsError(pub String);

impl std::fmt::Display for TlsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for TlsError {}

fn read(path: &Path, what: &str) -> Result<Vec<u8>, TlsError> {
    let bytes = std::fs::read(path)
        .map_err(|e| TlsError(format!("{}: cannot read the {what}: {e}", path.display())))?;
    if !String::from_utf8_lossy(&bytes).contains("-----BEGIN ") {
        return Err(TlsError(format!(
            "{}: the {what} is not PEM (no -----BEGIN line)",
            path.display()
        )));
    }
    Ok(bytes)
}

/// A server identity from PEM files: the certificate chain and its private key.
pub fn server_config(cert: &Path, key: &Path) -> Result<ServerTlsConfig, TlsError> {
    Ok(ServerTlsConfig::new().identity(Identity::from_pem(
        read(cert, "TLS certificate")?,
        read(key, "TLS private key")?,
    )))
}

/// A client that trusts the CA certificate in `ca` (PEM); `domain`, when
/// given, is the name checked in the server's certificate instead of the
/// host it is reached at.
pub fn client_config(ca: &Path, domain: Option<&str>) -> Result<ClientTlsConfig, TlsError> {
    let c =
        ClientTlsConfig::new().ca_certificate(Certificate::from_pem(read(ca, "CA certificate")?));
    Ok(match domain {
        Some(d) => c.domain_name(d),
        None => c,
    })
}

/// An endpoint for `addr` (`host:port`): `https` with `tls`, else `http`.
pub fn endpoint(
    addr: &str,
    tls: Option<&ClientTlsConfig>,
    connect_timeout: Duration,
) -> Result<Endpoint, tonic::transport::Error> {
    let scheme = if tls.is_some() { "https" } else { "http" };
    let e = Endpoint::from_shared(format!("{scheme}://{addr}"))?.connect_timeout(connect_timeout);
    match tls {
        Some(t) => e.tls_config(t.clone()),
        None => Ok(e),
    }
}

/// Connects to `addr`, over TLS when `tls` is set.
pub async fn connect(
    addr: &str,
    tls: Option<&ClientTlsConfig>,
    connect_timeout: Duration,
) -> Result<Channel, tonic::transport::Error> {
    endpoint(addr, tls, connect_timeout)?.connect().await
}

/// The connections `listener` accepts, with Nagle's algorithm off: a gRPC
/// reply's last small frames (trailers) otherwise wait for the peer's
/// delayed acknowledgement, 40 ms on Linux (`sylva bench farm` saw the
/// scene's offer to a worker and a submission take 41–43 ms instead of
/// under 1).
pub fn incoming(
    listener: tokio::net::TcpListener,
) -> impl tokio_stream::Stream<Item = std::io::Result<tokio::net::TcpStream>> {
    use tokio_stream::StreamExt;
    tokio_stream::wrappers::TcpListenerStream::new(listener).map(|s| {
        if let Ok(s) = &s {
            // A socket that refuses the option still serves, only slower.
            let _ = s.set_nodelay(true);
        }
        s
    })
}
