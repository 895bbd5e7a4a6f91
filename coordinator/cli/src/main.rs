//! `sylva`: the command-line program. Parses flags and hands each
//! subcommand to its module: the services and farm commands here, the
//! studies (compare, bench, simulate) in [`lab`].

mod caps;
mod coordinator;
mod in_process;
mod jobs;
mod lab;
mod lb;
mod loopback;
mod progress;
mod render;
mod scene;
mod security;
mod worker;

use clap::{Parser, Subcommand};

/// Sylva renders lit forests: a lattice-Boltzmann light-transport
/// pre-process and a GPU ray tracer.
#[derive(Debug, Parser)]
#[command(name = "sylva", version, about)]
pub struct Cli {
    /// More logging (-v info, -vv debug); RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
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
enum Command {
    /// Lattice-Boltzmann lighting: solve a model's light field, verify the solver.
    #[command(subcommand)]
    Lb(lb::LbCommand),
    /// Render a scene to a PNG: through a coordinator and worker processes
    /// started on loopback (default), running workers, or in this process.
    Render(render::RenderArgs),
    /// Serve the coordinator API: queue jobs, cut them into strips for workers.
    Coordinator(coordinator::CoordinatorArgs),
    /// Send a render job to a running coordinator and follow it.
    Submit(coordinator::SubmitArgs),
    /// List a coordinator's jobs.
    Jobs(jobs::JobsArgs),
    /// List a coordinator's workers.
    Workers(jobs::WorkersArgs),
    /// Cancel queued or running jobs.
    Cancel(jobs::CancelArgs),
    /// Set a job's priority (higher runs first).
    Priority(jobs::PriorityArgs),
    /// Fetch a finished job's image.
    Fetch(jobs::FetchArgs),
    /// Serve the worker API: hold scenes, render strips on this machine's GPU.
    Worker(worker::WorkerArgs),
    /// Scene files: write the paper's forest, export to glTF or pbrt-v4,
    /// import an instanced glTF scene.
    #[command(subcommand)]
    Scene(scene::SceneCommand),
    /// Render a scene with every lighting method and chart error against time.
    Compare(lab::compare::CompareArgs),
    /// Benchmarks that print JSON.
    #[command(subcommand)]
    Bench(lab::bench::BenchCommand),
}

/// Runs the parsed command.
fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Lb(c) => lb::run(c),
        Command::Bench(c) => lab::bench::run(c),
        Command::Scene(c) => scene::run(c),
        Command::Render(a) => render::run(a),
        Command::Compare(a) => lab::compare::run(a),
        Command::Worker(a) => worker::run(a),
        Command::Coordinator(a) => coordinator::run_coordinator(a),
        Command::Submit(a) => coordinator::run_submit(a),
        Command::Jobs(a) => jobs::run_jobs(a),
        Command::Workers(a) => jobs::run_workers(a),
        Command::Cancel(a) => jobs::run_cancel(a),
        Command::Priority(a) => jobs::run_priority(a),
        Command::Fetch(a) => jobs::run_fetch(a),
    }
}

/// Whether log lines may carry colour codes: only on a terminal that
/// shows them (not `TERM=dumb`) and unless `NO_COLOR` is set.
fn colour_on_stderr() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal()
        && std::env::var("TERM").is_ok_and(|t| t != "dumb")
        && std::env::var_os("NO_COLOR").is_none()
}

fn main() {
    // SAFETY: the first thing the program does; no other thread exists yet.
    unsafe { sylva_worker::gpu::prefer_narrow_lavapipe_lanes() };
    let args = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| args.log_filter().into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(colour_on_stderr())
        .init();
    if let Err(e) = run(args) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
