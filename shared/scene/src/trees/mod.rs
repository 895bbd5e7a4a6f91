//! Procedural trees: five species named after the forest paper's (red
//! maple, Ohio buckeye, paper birch, southern catalpa, American beech),
//! each a tapered trunk, first-order branches shaped by the species' crown,
//! twigs, and alpha-masked leaf quads with a generated leaf texture. The
//! triangle count is a parameter: leaves fill whatever the wood leaves.

mod generator;
mod species;

pub use generator::{TreeError, TreeParams, generate};
pub use species::{CrownShape, Species, SpeciesShape};
