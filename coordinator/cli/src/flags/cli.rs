//! The top level: the program, its verbosity and its commands. Flags only (clap), and their
//! conversion to settings.

use clap::{Parser, Subcommand};

/// Sylva renders lit forests: a lattice-Boltzmann light-transport
/// pre-process and a GPU ray tracer.
#[derive(Debug, Parser)]
#[command(name = "sylva", version, about)]
pub struct Cli {
    /// More logging (-v info, -vv debug); RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub(crate) verbose: u8,
    #[command(subcommand)]
    pub(crate) command: Command,
}

impl Cli {
    /// The tracing filter the verbosity asks for.
    pub fn log_filter(&self) -> &'static str {
        match self.verbose {
            0 => "warn",
            1 => "info",
            _ => "debug",
        }
    }
}

#[derive(Debug, Subcommand)]
pub(crate) enum Command {
    /// Lattice-Boltzmann lighting: solve a model's light field, verify the solver.
    #[command(subcommand)]
    Lb(super::lb::LbCommand),
    /// Render a scene to a PNG: through a coordinator and worker processes
    /// started on loopback (default), running workers, or in this process.
    Render(super::render::RenderArgs),
    /// Serve the coordinator API: queue jobs, cut them into strips for workers.
    Coordinator(super::coordinator::CoordinatorArgs),
    /// Send a render job to a running coordinator and follow it.
    Submit(super::coordinator::SubmitArgs),
    /// List a coordinator's jobs.
    Jobs(super::jobs::JobsArgs),
    /// List a coordinator's workers.
    Workers(super::jobs::WorkersArgs),
    /// Cancel queued or running jobs.
    Cancel(super::jobs::JobIdsArgs),
    /// Run failed or cancelled jobs again, each as a new job.
    Requeue(super::jobs::JobIdsArgs),
    /// Set a job's priority (higher runs first).
    Priority(super::jobs::PriorityArgs),
    /// Fetch a finished job's image.
    Fetch(super::jobs::FetchArgs),
    /// The farm's users: tokens with roles, made and revoked on the
    /// coordinator's state folder or database.
    #[command(subcommand)]
    Token(super::users::TokenCommand),
    /// The farm's audit log: who submitted, cancelled, re-prioritised,
    /// registered or changed tokens.
    Audit(super::users::AuditArgs),
    /// Serve the worker API: hold scenes, render strips on this machine's GPU.
    Worker(super::worker::WorkerArgs),
    /// Scene files: write the paper's forest, export to glTF or pbrt-v4,
    /// import an instanced glTF scene.
    #[command(subcommand)]
    Scene(super::scene::SceneCommand),
    /// Render a scene with every lighting method and chart error against time.
    Compare(super::compare::CompareArgs),
    /// Benchmarks that print JSON.
    #[command(subcommand)]
    Bench(super::bench::BenchCommand),
}
