//! The coordinator: cuts frames into vertical strips ([`schedule`]), hands
//! them to GPU workers over gRPC and assembles what comes back ([`farm`]).

pub mod farm;
pub mod schedule;
