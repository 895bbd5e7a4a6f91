//! The crate every side of Sylva uses: the lattice-Boltzmann lighting model
//! and its CPU reference solver, triangle meshes and their voxelizer, the
//! built-in shapes, and grids on disk (`.npy`) and on screen (PNG).

pub mod accel;
pub mod boulanger;
pub mod bundle;
pub mod camera;
pub mod color;
pub mod film;
pub mod frame;
pub mod interchange;
pub mod lb;
pub mod leaf;
pub mod model;
pub mod npy;
pub mod rng;
pub mod scene;
pub mod sequence;
pub mod shapes;
pub mod trees;
pub mod visualize;
pub mod voxel;
