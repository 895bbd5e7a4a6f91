//! The coarse LB grid over a whole forest (forest paper §3): its nodes'
//! densities come from the trees in each cell, and its light at an
//! instance scales that instance's species grid, so a tree deep in the
//! stand receives less light than one at its edge.

use super::medium::{GridDims, MediumGrid, NodeClass};
use crate::accel::Aabb;
use glam::Vec3;
use serde::Serialize;

/// A tree as the coarse grid sees it: its world bounds and how much of
/// that box its crown fills.
#[derive(Clone, Copy, Debug)]
pub struct Occupant {
    /// World bounds.
    pub bounds: Aabb,
    /// Mean density of the model's voxels inside its bounds, in [0, 1].
    pub fill: f32,
}

/// A lattice over world space with cubic cells.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WorldGrid {
    /// Nodes per axis.
    pub dims: GridDims,
    /// Corner of node (0, 0, 0).
    pub origin: [f32; 3],
    /// Cell edge.
    pub cell: f32,
}

impl WorldGrid {
    /// `cells` cells along the longest horizontal side of `bounds`, cubic
    /// cells, and one empty layer of nodes all round for the boundary.
    pub fn around(bounds: Aabb, cells: usize) -> Self {
        let e = bounds.max - bounds.min;
        let cell = (e.x.max(e.z) / cells as f32).max(e.y / cells as f32).max(1e-3);
        let n = |extent: f32| (extent / cell).ceil() as usize + 2;
        let dims = GridDims { nx: n(e.x), ny: n(e.y), nz: n(e.z) };
        let origin = bounds.min - Vec3::splat(cell);
        Self { dims, origin: origin.to_array(), cell }
    }

    /// The box of node `(x, y, z)`.
    pub fn cell_box(&self, x: usize, y: usize, z: usize) -> Aabb {
        let min = Vec3::from(self.origin) + Vec3::new(x as f32, y as f32, z as f32) * self.cell;
        Aabb { min, max: min + Vec3::splat(self.cell) }
    }

    /// Trilinear sample of per-node `values` at world point `p` (node
    /// centres at cell centres, clamped at the edges).
    pub fn sample(&self, values: &[f32], p: Vec3) -> f32 {
        let g = (p - Vec3::from(self.origin)) / self.cell - 0.5;
        self.dims.trilinear(values, g.to_array())
    }
}

/// The coarse medium: each cell's density is the fill-weighted fraction of
/// its volume that trees' boxes overlap, at most 1; green nodes.
pub fn forest_medium(grid: &WorldGrid, occupants: &[Occupant]) -> MediumGrid {
    let d = grid.dims;
    let mut m = MediumGrid::empty(d);
    let volume = grid.cell.powi(3);
    for o in occupants {
        let lo = ((o.bounds.min - Vec3::from(grid.origin)) / grid.cell).floor().max(Vec3::ONE);
        let hi = ((o.bounds.max - Vec3::from(grid.origin)) / grid.cell).floor();
        let hi = hi.min(Vec3::new((d.nx - 2) as f32, (d.ny - 2) as f32, (d.nz - 2) as f32));
        for z in lo.z as usize..=hi.z as usize {
            for y in lo.y as usize..=hi.y as usize {
                for x in lo.x as usize..=hi.x as usize {
                    let b = grid.cell_box(x, y, z).intersection(o.bounds);
                    if b.is_empty() {
                        continue;
                    }
                    let e = b.max - b.min;
                    let i = d.index(x, y, z);
                    m.density[i] = (m.density[i] + o.fill * e.x * e.y * e.z / volume).min(1.0);
                }
            }
        }
    }
    m.with_class(NodeClass::Green)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trees_fill_the_cells_they_stand_in() {
        let trees: Vec<Occupant> = (0..4)
            .map(|i| Occupant {
                bounds: Aabb { min: Vec3::new(i as f32 * 10.0, 0.0, 0.0), max: Vec3::new(i as f32 * 10.0 + 8.0, 16.0, 8.0) },
                fill: 0.5,
            })
            .collect();
        let all = trees.iter().fold(Aabb::EMPTY, |b, t| b.union(t.bounds));
        let g = WorldGrid::around(all, 19);
        let m = forest_medium(&g, &trees);
        m.validate().unwrap();
        assert!(m.occupancy() > 0.2);
        let inside = g.sample(&m.density, Vec3::new(4.0, 8.0, 4.0));
        let outside = g.sample(&m.density, Vec3::new(9.0, 30.0, 4.0));
        assert!(inside > 0.3 && outside == 0.0, "inside {inside}, outside {outside}");
    }
}
