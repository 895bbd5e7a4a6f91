//! `sylva`: the command-line program. Parses flags and hands each
//! subcommand to its module in `cli/`.

mod cli;

use clap::Parser;

fn main() {
    // SAFETY: the first thing the program does; no other thread exists yet.
    unsafe { sylva_worker::gpu::prefer_narrow_lavapipe_lanes() };
    let args = cli::Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| args.log_filter().into()))
        .with_writer(std::io::stderr)
        .init();
    if let Err(e) = cli::run(args) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
