//! The medium the light moves through: a density ρ ∈ [0, 1] and a class per
//! lattice node, on a grid whose x index runs fastest.

use serde::{Deserialize, Serialize};

/// Lattice dimensions in nodes. Node `(x, y, z)` lives at
/// `x + nx · (y + ny · z)`, so arrays on disk have shape `(nz, ny, nx)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct GridDims {
    /// Nodes along x (fastest index).
    pub nx: usize,
    /// Nodes along y (up).
    pub ny: usize,
    /// Nodes along z (slowest index).
    pub nz: usize,
}

impl GridDims {
    /// A cube of `n³` nodes.
    pub const fn cube(n: usize) -> Self {
        Self { nx: n, ny: n, nz: n }
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    /// Whether the grid has no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index of node `(x, y, z)`.
    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.nx * (y + self.ny * z)
    }

    /// Whether the node lies on the lattice's outer shell, where the
    /// boundary condition holds the densities fixed.
    #[inline]
    pub fn is_boundary(&self, x: usize, y: usize, z: usize) -> bool {
        x == 0 || y == 0 || z == 0 || x + 1 == self.nx || y + 1 == self.ny || z + 1 == self.nz
    }

    /// The longest edge, in nodes.
    pub fn longest_edge(&self) -> usize {
        self.nx.max(self.ny).max(self.nz)
    }

    /// Trilinear interpolation of per-node `values` at node coordinates
    /// `q` (node `(i, j, k)` at `q = (i, j, k)`), clamped to the grid. The
    /// one CPU sampler of LB grids; `render.wgsl`'s `lb_light` mirrors it.
    pub fn trilinear(&self, values: &[f32], q: [f32; 3]) -> f32 {
        let size = [self.nx, self.ny, self.nz];
        let mut i0 = [0usize; 3];
        let mut f = [0.0f32; 3];
        for a in 0..3 {
            let top = (size[a] - 1) as f32;
            let v = if q[a].is_nan() { 0.0 } else { q[a].clamp(0.0, top) };
            let lo = v.floor().min((size[a].max(2) - 2) as f32);
            i0[a] = lo as usize;
            f[a] = v - lo;
        }
        let mut acc = 0.0;
        for k in 0..8 {
            let o = [k & 1, (k >> 1) & 1, (k >> 2) & 1];
            let w: f32 = (0..3).map(|a| if o[a] == 1 { f[a] } else { 1.0 - f[a] }).product();
            if w != 0.0 {
                acc += w * values[self.index(i0[0] + o[0], i0[1] + o[1], i0[2] + o[2])];
            }
        }
        acc
    }

    /// Linear offset of the lattice vector `c`.
    pub fn offset(&self, c: [i32; 3]) -> isize {
        c[0] as isize + self.nx as isize * (c[1] as isize + self.ny as isize * c[2] as isize)
    }
}

impl std::fmt::Display for GridDims {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}×{}×{}", self.nx, self.ny, self.nz)
    }
}

/// How a node treats the light it scatters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
pub enum NodeClass {
    /// A participating medium (cloud, plastic): absorbed light stays in f_0
    /// and is re-emitted, so density is conserved.
    Medium = 0,
    /// Leaf matter: f_0 is zeroed each step, since the light a leaf absorbs
    /// leaves the visible spectrum.
    Green = 1,
    /// Wood-dominated: scatters backwards only (g = −1).
    Brown = 2,
}

/// A grid of densities and classes. Nodes with ρ = 0 pass light through.
#[derive(Clone, Debug, PartialEq)]
pub struct MediumGrid {
    /// Lattice size.
    pub dims: GridDims,
    /// ρ per node, in [0, 1].
    pub density: Vec<f32>,
    /// Class per node.
    pub class: Vec<NodeClass>,
}

/// A grid that cannot be solved.
#[derive(Debug, thiserror::Error)]
pub enum MediumError {
    /// Arrays whose length disagrees with the dimensions.
    #[error("medium grid {dims} needs {expected} values, got {got}")]
    WrongLength { dims: GridDims, expected: usize, got: usize },
    /// A lattice too small to have an interior.
    #[error(
        "medium grid {0} is too small: every side needs at least 3 nodes (the outer shell holds the boundary condition)"
    )]
    TooSmall(GridDims),
    /// A density outside [0, 1] or not finite.
    #[error("density at node (x={x}, y={y}, z={z}) is {value}; valid range: [0, 1]")]
    BadDensity { x: usize, y: usize, z: usize, value: f32 },
}

impl MediumGrid {
    /// An empty (all pass-through) grid.
    pub fn empty(dims: GridDims) -> Self {
        Self { dims, density: vec![0.0; dims.len()], class: vec![NodeClass::Medium; dims.len()] }
    }

    /// A grid of uniform density and class.
    pub fn uniform(dims: GridDims, density: f32, class: NodeClass) -> Self {
        Self { dims, density: vec![density; dims.len()], class: vec![class; dims.len()] }
    }

    /// Checks the sizes and that every density is finite and in [0, 1].
    pub fn validate(&self) -> Result<(), MediumError> {
        let d = self.dims;
        if d.nx < 3 || d.ny < 3 || d.nz < 3 {
            return Err(MediumError::TooSmall(d));
        }
        for got in [self.density.len(), self.class.len()] {
            if got != d.len() {
                return Err(MediumError::WrongLength { dims: d, expected: d.len(), got });
            }
        }
        if let Some(i) = self.density.iter().position(|v| !(0.0..=1.0).contains(v)) {
            let (x, y, z) = (i % d.nx, (i / d.nx) % d.ny, i / (d.nx * d.ny));
            return Err(MediumError::BadDensity { x, y, z, value: self.density[i] });
        }
        Ok(())
    }

    /// Fraction of nodes with non-zero density.
    pub fn occupancy(&self) -> f64 {
        self.density.iter().filter(|&&v| v > 0.0).count() as f64 / self.dims.len().max(1) as f64
    }

    /// Sets every occupied node to `class`.
    pub fn with_class(mut self, class: NodeClass) -> Self {
        self.class.iter_mut().for_each(|c| *c = class);
        self
    }
}
