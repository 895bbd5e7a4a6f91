//! `sylva`: the command-line program. Its flags are in [`flags`] (clap
//! only); each command's module turns them into settings and runs it: the
//! services and farm commands here, the studies (compare, bench, simulate)
//! in [`lab`]; `render --lighting auto`'s [`pilot`] is product, and
//! measures with [`measure`] as the studies do.

mod coordinator;
mod flags;
mod in_process;
mod jobs;
mod lab;
mod lb;
mod loopback;
mod measure;
mod pilot;
mod progress;
mod render;
mod scene;
mod spec;
mod users;
mod worker;

use crate::flags::cli::*;
use clap::Parser;

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
        Command::Requeue(a) => jobs::run_requeue(a),
        Command::Priority(a) => jobs::run_priority(a),
        Command::Fetch(a) => jobs::run_fetch(a),
        Command::Token(c) => users::run_token(c),
        Command::Audit(a) => users::run_audit(a),
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
