//! The lattice-Boltzmann (LB) light-transport model of Geist et al.
//!
//! A D3Q19 lattice carries photon densities `f_m(r)` along 19 directions.
//! One step, at every interior node `r` and for every direction `m`:
//!
//! ```text
//! f_m(r + c_m, t + 1) = f_m(r, t) + ρ(r) · Σ_n Ω[m][n] · f_n(r, t)
//! ```
//!
//! - [`lattice`]: the 19 directions and their weights.
//! - [`params`]: σ_a, σ_s and g per colour channel, the presets' values and validation.
//! - [`collision`]: the collision matrix Ω, isotropic and Henyey–Greenstein.
//! - [`medium`]: the density grid and the class (medium, green, brown) of each node.
//! - [`boundary`]: the sun's boundary condition.
//! - [`coarse`]: the forest grid over all instances: its medium, the light reaching each crown, and whether it is used.
//! - [`light`]: a model's solved light ([`LbGrid`]) and the CPU reading of it.
//! - [`radiometry`]: units, sun and sky on the boundary, leaf area to density, leaf optics to σ_a, σ_s, g.
//! - [`indirect`]: the field split into the uncollided sun (the tracer's) and the rest (the LB's).
//! - [`solver`]: the [`LightingSolver`] seam, its options and its report.
//! - [`cpu`]: the CPU reference solver (rayon) that the GPU solver is tested against.

// Matrix and lattice code reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

pub mod boundary;
pub mod coarse;
pub mod collision;
pub mod cpu;
pub mod indirect;
pub mod lattice;
pub mod light;
pub mod medium;
pub mod params;
pub mod radiometry;
pub mod solver;

pub use boundary::{Boundary, GroundReflection, Sun};
pub use collision::{Collision, Omega};
pub use cpu::CpuSolver;
pub use indirect::{IndirectSolution, solve_indirect};
pub use lattice::{DIRECTIONS, Q};
pub use light::LbGrid;
pub use medium::{GridDims, MediumGrid, NodeClass};
pub use params::{ChannelParams, LbParams, ParamError};
pub use radiometry::{Illumination, LeafScattering};
pub use solver::{
    ChannelReport, ChannelSolution, LightingSolver, Solution, SolveOptions, SolverError, solve,
};
