//! `sylva jobs`, `workers`, `cancel`, `requeue`, `priority` and `fetch`. Flags only (clap), and their
//! conversion to settings.

use crate::flags::security::{ConnectTlsArgs, TokenArgs};
use clap::Args;
use std::path::PathBuf;
use sylva_coordinator::client::{Client, connect};
use sylva_coordinator::job_state::JobState;

/// Where the coordinator is and how to reach it.
#[derive(Args, Debug)]
pub struct CoordinatorArg {
    /// The coordinator, `host:port`.
    #[arg(long, env = "SYLVA_COORDINATOR")]
    pub coordinator: String,
    #[command(flatten)]
    pub auth: TokenArgs,
    #[command(flatten)]
    pub tls: ConnectTlsArgs,
}

impl CoordinatorArg {
    /// Runs `f` with a connected client on a fresh runtime.
    pub(crate) fn call<T>(
        &self,
        f: impl AsyncFnOnce(Client) -> anyhow::Result<T>,
    ) -> anyhow::Result<T> {
        let (token, tls) = (self.auth.load()?, self.tls.load()?);
        let rt = tokio::runtime::Runtime::new()?;
        rt.block_on(async { f(connect(&self.coordinator, token, tls.as_ref()).await?).await })
    }
}

/// `sylva jobs`: every job the coordinator knows.
#[derive(Args, Debug)]
pub struct JobsArgs {
    #[command(flatten)]
    pub at: CoordinatorArg,
    /// Only jobs in this state (queued, running, done, failed, cancelled).
    #[arg(long, value_parser = job_state)]
    pub state: Option<JobState>,
    /// Every column (submitter, retries, times queued and running, stage,
    /// error) on one line per job, however wide; the default keeps to 80.
    #[arg(long)]
    pub wide: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `sylva workers`: the workers, alive or not.
#[derive(Args, Debug)]
pub struct WorkersArgs {
    #[command(flatten)]
    pub at: CoordinatorArg,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `sylva cancel` and `sylva requeue`: the jobs they act on.
#[derive(Args, Debug)]
pub struct JobIdsArgs {
    /// Job ids.
    #[arg(required = true)]
    pub ids: Vec<String>,
    #[command(flatten)]
    pub at: CoordinatorArg,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `sylva priority`: moves a job in the queue.
#[derive(Args, Debug)]
pub struct PriorityArgs {
    /// Job id.
    pub id: String,
    /// The new priority; higher runs first.
    #[arg(allow_negative_numbers = true)]
    pub priority: i32,
    #[command(flatten)]
    pub at: CoordinatorArg,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `sylva fetch`: a finished job's image.
#[derive(Args, Debug)]
pub struct FetchArgs {
    /// Job id.
    pub id: String,
    /// Output file: PNG, or OpenEXR (linear HDR) when it ends in `.exr`.
    #[arg(short, long, default_value = "sylva-out/fetched.png")]
    pub out: PathBuf,
    /// Which frame of a sequence (from 0).
    #[arg(long, default_value_t = 0)]
    pub frame: u32,
    /// Every frame of a sequence: numbered files beside --out, a contact
    /// sheet and an animated preview.
    #[arg(long, conflicts_with = "frame")]
    pub all: bool,
    #[command(flatten)]
    pub at: CoordinatorArg,
}

/// A job state named on the command line.
pub(crate) fn job_state(name: &str) -> Result<JobState, String> {
    JobState::from_name(name).ok_or_else(|| {
        let names: Vec<_> = JobState::ALL.iter().map(|s| s.name()).collect();
        format!("one of {}", names.join(", "))
    })
}
