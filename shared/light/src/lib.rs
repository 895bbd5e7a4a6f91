//! Light in a forest, computed before the frame is traced: the
//! lattice-Boltzmann (LB) model and its CPU reference solver ([`lb`]), the
//! voxelizer that turns triangles into an LB medium ([`voxel`]), built-in
//! media ([`shapes`]), the Boulanger et al. tree-lighting model
//! ([`boulanger`]), an analog Monte Carlo reference in the same medium
//! ([`montecarlo`]), the studies of where the LB model holds
//! ([`studies`]), and grids on disk ([`npy`]) and on screen
//! ([`visualize`]). The GPU solvers in `sylva-worker` share these types and
//! are tested against this crate's CPU code.
//!
//! ```
//! use sylva_light::lb::{CpuSolver, GridDims, LbParams, MediumGrid, SolveOptions, Sun, solve};
//! let medium = MediumGrid::empty(GridDims { nx: 8, ny: 8, nz: 8 });
//! let params = LbParams::from_preset(sylva_scene::format::Preset::Leaf);
//! let sun = Sun::towards([0.0, -1.0, 0.0], 1.0).unwrap();
//! let solution = solve(&mut CpuSolver, &medium, &params, &sun, &SolveOptions::fixed_steps(16), &|_, _, _| {}).unwrap();
//! assert_eq!(solution.channels.len(), 3);
//! ```

pub mod boulanger;
mod error;
pub mod lb;
pub mod montecarlo;
pub mod npy;
pub mod shapes;
pub mod studies;
pub mod visualize;
pub mod voxel;

pub use error::{Error, Result};
