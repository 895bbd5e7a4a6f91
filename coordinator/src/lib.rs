//! The coordinator: cuts frames into vertical strips ([`schedule`]), hands
//! them to GPU workers over gRPC ([`farm`]) and assembles what comes back
//! ([`assembly`]); the service that queues jobs ([`service`]) and its
//! clients ([`client`]) and web page ([`dashboard`]); the worker's registration ([`registration`]); a sequence's outputs ([`sequence`]).

pub mod assembly;
pub mod client;
pub mod dashboard;
pub mod executor;
pub mod farm;
pub mod metrics;
pub mod registration;
pub mod results;
pub mod schedule;
pub mod sequence;
pub mod service;
pub mod shutdown;
