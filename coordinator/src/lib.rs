//! The coordinator, which links no GPU stack: the job service
//! ([`service`]: queue, runs, workers, live view, stats) over the job
//! states ([`job_state`]) and the durable queue ([`store`]), its
//! clients ([`client`]) and web page ([`dashboard`]); a frame cut into
//! vertical strips ([`schedule`]), rendered by gRPC workers ([`farm`])
//! behind one interface ([`executor`]) and put together ([`assembly`]);
//! finished images ([`results`]), a sequence's outputs ([`sequence`]), the
//! worker's registration ([`registration`]), Prometheus [`metrics`] and
//! clean [`shutdown`].
//!
//! ```
//! use sylva_coordinator::schedule::{Scheduler, Static};
//! // The paper's schedule: one equal strip per worker.
//! assert_eq!(Static.plan(896, 2, &[]), vec![(0, 448), (448, 896)]);
//! ```

pub mod access;
pub mod assembly;
pub mod client;
pub mod dashboard;
pub mod executor;
pub mod farm;
pub mod job_state;
pub mod metrics;
pub mod registration;
pub mod results;
pub mod schedule;
pub mod sequence;
pub mod service;
pub mod shutdown;
pub mod store;
