//! Studies rather than services: lighting methods against the reference
//! ([`compare`], per crown in [`crowns`]), speed ([`bench`](mod@bench),
//! [`bench_sequence`]) and the strip schedule in simulation ([`simulate`]).
//! Product code never imports this module (`scripts/layers.sh`).

pub mod bench;
pub mod bench_sequence;
pub mod compare;
pub mod crowns;
pub mod simulate;
