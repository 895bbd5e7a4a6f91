//! Studies rather than services: lighting methods against the reference
//! ([`compare`], per crown in [`crowns`]), speed ([`bench`](mod@bench), [`bench_sequence`]), the strip schedule
//! in simulation ([`simulate`]) and the charts they draw ([`chart`]).

pub mod bench;
pub mod bench_sequence;
pub mod chart;
pub mod compare;
pub mod crowns;
pub mod pareto;
pub mod simulate;
