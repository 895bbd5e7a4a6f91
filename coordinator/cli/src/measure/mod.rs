//! What the product and the studies both measure: a lighting method's
//! error against the reference ([`error`]), the time–error front
//! ([`pareto`]) and the charts that draw them ([`chart`]). `render
//! --lighting auto`'s pilot chooses with them; `compare` reports them.

pub mod chart;
pub mod error;
pub mod pareto;
