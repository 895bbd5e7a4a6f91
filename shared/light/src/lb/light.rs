//! A model's solved LB light as the tracer reads it, and the CPU reading
//! of it (`render.wgsl`'s `lb_light` is the GPU's).

use super::medium::GridDims;
use crate::voxel::GridFrame;
use glam::Vec3;

/// A model's solved LB light on its own grid, in model space.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LbGrid {
    /// Nodes per axis.
    pub dims: GridDims,
    /// Where the grid sits in model space.
    pub frame: GridFrame,
    /// Light per node: three channel planes of `dims.len()` values, x
    /// fastest (grounded: indirect fluence; paper: total density of a unit sun).
    pub rgb: Vec<f32>,
    /// Fraction of the grid's nodes with matter.
    pub occupancy: f64,
}

impl LbGrid {
    /// The light at a model-space point per channel: trilinear between
    /// node centres, clamped at the edges, as the render kernel reads it.
    pub fn sample(&self, p: Vec3) -> [f32; 3] {
        let q = ((p - Vec3::from(self.frame.origin)) / self.frame.cell - 0.5).to_array();
        let plane = self.dims.len();
        std::array::from_fn(|c| self.dims.trilinear(&self.rgb[c * plane..(c + 1) * plane], q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_node_centre_reads_its_node_and_midway_reads_the_mean() {
        let dims = GridDims { nx: 2, ny: 1, nz: 1 };
        let frame = GridFrame { origin: [0.0; 3], cell: 2.0 };
        let g = LbGrid { dims, frame, rgb: vec![1.0, 3.0, 10.0, 30.0, 0.0, 0.0], occupancy: 0.0 };
        assert_eq!(g.sample(Vec3::new(1.0, 1.0, 1.0)), [1.0, 10.0, 0.0]);
        assert_eq!(g.sample(Vec3::new(2.0, 1.0, 1.0)), [2.0, 20.0, 0.0]);
        assert_eq!(g.sample(Vec3::new(-5.0, 1.0, 1.0)), [1.0, 10.0, 0.0], "clamped at the edge");
    }
}
