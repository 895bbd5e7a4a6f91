//! The bearer-token and TLS flags every networked subcommand shares.

use anyhow::Context;
use clap::Args;
use std::path::PathBuf;
use tonic::transport::{ClientTlsConfig, ServerTlsConfig};

#[derive(Debug, Args)]
pub struct TokenArgs {
    /// Bearer token for every call (also `SYLVA_TOKEN`, or `--token-file`).
    #[arg(long)]
    pub token: Option<String>,
    /// Read the bearer token from this file.
    #[arg(long)]
    pub token_file: Option<PathBuf>,
}

impl TokenArgs {
    /// The token from the flag, `SYLVA_TOKEN` or the file, if any.
    pub fn load(&self) -> anyhow::Result<Option<String>> {
        sylva_proto::auth::load_token(self.token.as_deref(), self.token_file.as_deref())
            .context("cannot take the token")
    }
}

/// TLS for the API a process serves.
#[derive(Debug, Args)]
pub struct ServeTlsArgs {
    /// Serve over TLS with this certificate chain (PEM); needs --tls-key.
    #[arg(long, requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The certificate's private key (PEM).
    #[arg(long, requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
}

impl ServeTlsArgs {
    /// The server identity, when asked for.
    pub fn load(&self) -> anyhow::Result<Option<ServerTlsConfig>> {
        match (&self.tls_cert, &self.tls_key) {
            (Some(c), Some(k)) => Ok(Some(sylva_proto::tls::server_config(c, k)?)),
            _ => Ok(None),
        }
    }
}

/// TLS for the Sylva services a process calls.
#[derive(Debug, Args)]
pub struct ConnectTlsArgs {
    /// Call other Sylva services over TLS, trusting this CA certificate (PEM).
    #[arg(long)]
    pub tls_ca: Option<PathBuf>,
    /// The name to check in their certificates (default: the host dialled).
    #[arg(long, requires = "tls_ca")]
    pub tls_domain: Option<String>,
}

impl ConnectTlsArgs {
    /// The client settings, when asked for.
    pub fn load(&self) -> anyhow::Result<Option<ClientTlsConfig>> {
        self.tls_ca
            .as_ref()
            .map(|ca| sylva_proto::tls::client_config(ca, self.tls_domain.as_deref()))
            .transpose()
            .map_err(Into::into)
    }

    /// The same flags, for a child process.
    pub fn to_args(&self) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(ca) = &self.tls_ca {
            v.extend(["--tls-ca".to_string(), ca.display().to_string()]);
        }
        if let Some(d) = &self.tls_domain {
            v.extend(["--tls-domain".to_string(), d.clone()]);
        }
        v
    }
}
