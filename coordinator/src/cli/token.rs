//! The bearer-token flags every networked subcommand shares.

use anyhow::Context;
use clap::Args;
use std::path::PathBuf;

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
        sylva_proto::auth::load_token(self.token.as_deref(), self.token_file.as_deref()).context("cannot read the token file")
    }
}
