//! `sylva coordinator` and `sylva submit`. Flags only (clap), and their conversion to settings.

use clap::Args;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct CoordinatorArgs {
    /// Address to listen on (port 0 picks one; the bound address is printed).
    #[arg(long, default_value = "127.0.0.1:50150")]
    pub listen: String,
    /// Workers to use from the start (`host:port,…`); others register themselves.
    #[arg(long, value_delimiter = ',')]
    pub workers: Vec<String>,
    /// Jobs rendered at the same time.
    #[arg(long, default_value_t = 2)]
    pub max_running: usize,
    /// Largest scene bundle accepted, MiB.
    #[arg(long, default_value_t = 1024)]
    pub max_bundle_mib: u64,
    /// Seconds one strip may take before it goes to another worker.
    #[arg(long, default_value_t = 600)]
    pub strip_deadline_s: u64,
    /// The token clients must send, and workers are sent.
    #[command(flatten)]
    pub auth: crate::flags::security::TokenArgs,
    #[command(flatten)]
    pub tls: crate::flags::security::ServeTlsArgs,
    /// How to reach the workers over TLS.
    #[command(flatten)]
    pub worker_tls: crate::flags::security::ConnectTlsArgs,
    /// Serve Prometheus metrics on this address (`GET /metrics`).
    #[arg(long)]
    pub metrics: Option<String>,
    /// Serve the web dashboard on this address (`http://ADDR/`).
    #[arg(long)]
    pub http: Option<String>,
    #[command(flatten)]
    pub limits: crate::flags::caps::LimitArgs,
    /// Seconds a finished job (and its image) is kept for FetchResult.
    #[arg(long, default_value_t = 3600)]
    pub keep_results_s: u64,
    /// Most finished jobs kept; the oldest are forgotten first.
    #[arg(long, default_value_t = 1000)]
    pub keep_jobs: usize,
    /// The state folder: the queue's database (unless --database names
    /// another), the bundles of waiting jobs and every result. A restart on
    /// the same folder resumes where the coordinator stopped. Default:
    /// `$XDG_STATE_HOME/sylva/coordinator`, else `~/.local/state/sylva/coordinator`.
    #[arg(long, env = "SYLVA_STATE_DIR", conflicts_with = "ephemeral")]
    pub state_dir: Option<PathBuf>,
    /// A fresh state folder in $TMPDIR, removed at exit: a coordinator for
    /// one command or test, which nothing needs to survive.
    #[arg(long)]
    pub ephemeral: bool,
    /// The queue's database instead of SQLite in the state folder:
    /// `postgres://USER:PASSWORD@HOST/DB` (or `sqlite://PATH`).
    #[arg(long, env = "SYLVA_DATABASE_URL", hide_env_values = true)]
    pub database: Option<String>,
    /// Most pixels one job may render, all its frames together
    /// (2^30: e.g. 2,675 frames of 896 × 448).
    #[arg(long, default_value_t = 1 << 30)]
    pub max_job_pixels: u64,
    /// Disk the results of all kept jobs may take, MiB; a job that would
    /// go over is refused at submit.
    #[arg(long, default_value_t = 32 * 1024)]
    pub results_disk_mib: u64,
    /// Seconds after which a worker that registered itself and stopped
    /// answering is forgotten.
    #[arg(long, default_value_t = 30)]
    pub registration_ttl_s: u64,
}

#[derive(Debug, Args)]
pub struct SubmitArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// The coordinator, `host:port`.
    #[arg(long, env = "SYLVA_COORDINATOR")]
    pub coordinator: String,
    /// The job's name in `sylva jobs` and on the dashboard (default: the scene file).
    #[arg(long)]
    pub name: Option<String>,
    /// Output PNG (an EXR beside it with --exr, or when NAME.exr is given); the stats go beside
    /// it as NAME.stats.json.
    #[arg(short, long, default_value = "sylva-out/render.png")]
    pub out: PathBuf,
    #[command(flatten)]
    pub frame: crate::flags::render::FrameArgs,
    /// How the frame is cut into strips.
    #[arg(long, value_enum, default_value = "dynamic")]
    pub schedule: sylva_scene::frame::ScheduleKind,
    /// Higher runs first.
    #[arg(long, default_value_t = 0)]
    pub priority: i32,
    /// Also fetch the linear HDR frame as OpenEXR.
    #[arg(long)]
    pub exr: bool,
    #[command(flatten)]
    pub auth: crate::flags::security::TokenArgs,
    #[command(flatten)]
    pub tls: crate::flags::security::ConnectTlsArgs,
}

impl CoordinatorArgs {
    /// The state folder: the flag's, else the documented default.
    pub fn state_dir(&self) -> anyhow::Result<PathBuf> {
        if self.ephemeral {
            return Ok(
                std::env::temp_dir().join(format!("sylva-coordinator-{}", std::process::id()))
            );
        }
        match &self.state_dir {
            Some(d) => Ok(d.clone()),
            None => default_state_dir(),
        }
    }
}

/// `$XDG_STATE_HOME/sylva/coordinator`, else `~/.local/state/sylva/coordinator`.
pub fn default_state_dir() -> anyhow::Result<PathBuf> {
    let base =
        match std::env::var_os("XDG_STATE_HOME").filter(|v| !v.is_empty()) {
            Some(x) => PathBuf::from(x),
            None => PathBuf::from(std::env::var_os("HOME").ok_or_else(|| {
                anyhow::anyhow!("no HOME and no XDG_STATE_HOME: give --state-dir")
            })?)
            .join(".local/state"),
        };
    Ok(base.join("sylva").join("coordinator"))
}
