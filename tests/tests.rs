//! Every integration test of the `sylva` program, one module per
//! subject, in one test binary (ripgrep's `tests/tests.rs`): the heavy
//! dependencies (wgpu, tonic, sqlx) are linked once, not once per file.
//! Run one subject with a filter: `cargo test -p sylva --test tests durable::`.

mod common;

mod cancel;
mod cli;
mod cluster;
mod dashboard;
mod denoise;
mod durable;
mod farm_cli;
mod hostile;
mod interchange;
mod passes;
mod render_cli;
mod sequence;
mod service;
mod storage;
mod users;
mod worker_grpc;
