//! `sylva token …` and `sylva audit`: the farm's users and its audit log,
//! on the coordinator's state folder or database. Flags only (clap).

use clap::{Args, Subcommand};
use std::path::PathBuf;

/// Where the farm's database is: as the coordinator was given it.
#[derive(Debug, Args)]
pub struct StateArgs {
    /// The coordinator's state folder (default as `sylva coordinator`'s).
    #[arg(long, env = "SYLVA_STATE_DIR")]
    pub state_dir: Option<PathBuf>,
    /// The coordinator's database, when not SQLite in the state folder.
    #[arg(long, env = "SYLVA_DATABASE_URL", hide_env_values = true)]
    pub database: Option<String>,
}

impl StateArgs {
    /// The database's URL.
    pub fn url(&self) -> anyhow::Result<String> {
        if let Some(u) = &self.database {
            return Ok(u.clone());
        }
        let dir = match &self.state_dir {
            Some(d) => d.clone(),
            None => super::coordinator::default_state_dir()?,
        };
        anyhow::ensure!(
            dir.join("sylva.db").exists(),
            "no coordinator state in {} (start the coordinator once, or give --state-dir)",
            dir.display()
        );
        Ok(format!("sqlite://{}", dir.join("sylva.db").display()))
    }
}

#[derive(Debug, Subcommand)]
pub enum TokenCommand {
    /// Make a token for a user: 256 random bits, shown once, kept hashed.
    Add(TokenAddArgs),
    /// List the tokens (who, role, when; never the tokens themselves).
    List(TokenListArgs),
    /// Revoke a token by its id (the coordinator stops taking it within 2 s).
    Revoke(TokenRevokeArgs),
}

#[derive(Debug, Args)]
pub struct TokenAddArgs {
    /// The user's name (letters, digits, `.`, `_`, `-`, `@`).
    pub user: String,
    /// What the token may do.
    #[arg(long, value_parser = ["admin", "submitter", "worker"])]
    pub role: String,
    #[command(flatten)]
    pub state: StateArgs,
}

#[derive(Debug, Args)]
pub struct TokenListArgs {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub state: StateArgs,
}

#[derive(Debug, Args)]
pub struct TokenRevokeArgs {
    /// The token's id (as `sylva token list` shows it).
    pub id: String,
    #[command(flatten)]
    pub state: StateArgs,
}

#[derive(Debug, Args)]
pub struct AuditArgs {
    /// The newest entries shown.
    #[arg(long, default_value_t = 50)]
    pub limit: u32,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub state: StateArgs,
}
