//! Studies rather than services: lighting methods against the reference
//! ([`compare`], per crown in [`crowns`]), speed ([`bench`](mod@bench), [`bench_sequence`]), the strip schedule
//! in simulation ([`simulate`]) and the charts they draw ([`chart`]); and the
//! pilot that picks `render --lighting auto`'s method ([`pilot`]).

pub mod bench;
pub mod bench_sequence;
pub mod chart;
pub mod compare;
pub mod crowns;
pub mod error;
pub mod pareto;
pub mod pilot;
pub mod simulate;
