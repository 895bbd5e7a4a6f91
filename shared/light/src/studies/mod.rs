//! Studies of the LB model rather than parts of a render: where it fails
//! ([`limits`]) and checks of the implementation against its mathematics
//! ([`verify`]).

// Matrix and lattice code reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

pub mod limits;
pub mod verify;
