//! The command line's flags, and only them: clap's types for every
//! command, with their conversions to the settings the commands run on
//! (ripgrep's low-level arguments, turned into settings in one place).
//! Each command's module (`render`, `coordinator`, `lab::compare`, …) reads
//! its flags from here.

pub mod bench;
pub mod bench_farm;
pub mod bench_sequence;
pub mod caps;
pub mod cli;
pub mod compare;
pub mod coordinator;
pub mod jobs;
pub mod lb;
pub mod render;
pub mod scene;
pub mod security;
pub mod users;
pub mod worker;
