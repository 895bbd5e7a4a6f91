//! Studies rather than services: lighting methods against the reference
//! ([`compare`], per crown in [`crowns`]), speed ([`bench`](mod@bench),
//! [`bench_sequence`], the farm's overhead in [`bench_farm`]) and the strip
//! schedule in simulation ([`simulate`]).
//! Product code never imports this module (`scripts/layers.sh`).

pub mod bench;
pub mod bench_farm;
pub mod bench_sequence;
pub mod compare;
pub mod crowns;
pub mod simulate;
