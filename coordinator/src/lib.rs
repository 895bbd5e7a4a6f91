//! The coordinator: cuts frames into vertical strips ([`schedule`]), hands
//! them to GPU workers over gRPC and assembles what comes back ([`farm`]).

pub mod chart;
pub mod farm;
pub mod metrics;
pub mod schedule;
pub mod service;
pub mod simulate;
