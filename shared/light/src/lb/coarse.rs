//! The coarse LB grid over a whole forest (forest paper §3): its nodes'
//! densities come from the trees in each cell, and its light at an
//! instance scales that instance's species grid, so a tree deep in the
//! stand receives less light than one at its edge.

use super::light::LbGrid;
use super::medium::{GridDims, MediumGrid, NodeClass};
use super::radiometry::LeafScattering;
use crate::voxel::{GridFrame, LeafArea};
use glam::Vec3;
use serde::Serialize;
use sylva_accel::Aabb;
use sylva_scene::model::Model;
use sylva_scene::{ForestGridSpec, ForestGridUse, Scene};

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
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
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

/// What the forest grid decided for the instances.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ForestLight {
    /// Whether instances' LB light is scaled by it.
    pub used: bool,
    /// Why.
    pub reason: String,
    /// The grid, when solved.
    pub grid: Option<WorldGrid>,
    /// (max − min) / max of the instances' light.
    pub spread: f32,
    /// Smallest scale applied (all 1 when unused).
    pub scale_min: f32,
    /// Mean scale.
    pub scale_mean: f32,
    /// Largest scale.
    pub scale_max: f32,
}

impl ForestLight {
    /// The grid was not used, for `reason`; every instance keeps scale 1.
    pub fn unused(reason: String, grid: Option<WorldGrid>) -> Self {
        Self {
            used: false,
            reason,
            grid,
            spread: 0.0,
            scale_min: 1.0,
            scale_mean: 1.0,
            scale_max: 1.0,
        }
    }

    /// Whether the per-instance `light` differs enough (by the scene's
    /// rule) to scale each instance by `scale(light)`; fills `scales` and
    /// says why. `what` names the light and what happens without the grid.
    pub fn decide(
        spec: ForestGridSpec,
        grid: WorldGrid,
        light: &[f32],
        what: (&str, &str),
        scale: impl Fn(f32) -> f32,
        scales: &mut [f32],
    ) -> Self {
        let max = light.iter().copied().fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
        let min = light.iter().copied().fold(f32::INFINITY, f32::min);
        let spread = (max - min) / max;
        let used = spec.use_grid == ForestGridUse::Always || spread > spec.threshold;
        let (t, s) = (100.0 * spec.threshold, 100.0 * spread);
        let reason = match spec.use_grid {
            ForestGridUse::Always => "forest_grid.use is \"always\"".to_string(),
            _ if used => format!("{} differs by {s:.0} % (threshold {t:.0} %)", what.0),
            _ => format!("{} differs by only {s:.0} % (threshold {t:.0} %): {}", what.0, what.1),
        };
        if used {
            for (s, &l) in scales.iter_mut().zip(light) {
                *s = scale(l);
            }
        }
        let n = scales.len() as f32;
        Self {
            used,
            reason,
            grid: Some(grid),
            spread,
            scale_min: scales.iter().copied().fold(f32::INFINITY, f32::min),
            scale_mean: scales.iter().sum::<f32>() / n,
            scale_max: scales.iter().copied().fold(0.0, f32::max),
        }
    }
}

/// How much of its bounding box a model's crown fills (the paper model's
/// occupant fill): its grid's occupied volume over the box's volume.
pub fn crown_fill(grid: &LbGrid, model: &Model) -> f32 {
    let Some((lo, hi)) = model.bounds() else { return 0.0 };
    let e = (hi - lo).max(Vec3::splat(grid.frame.cell));
    let occupied = grid.occupancy as f32 * grid.dims.len() as f32 * grid.frame.cell.powi(3);
    (occupied / (e.x * e.y * e.z)).clamp(0.0, 1.0)
}

/// A model's leaf area on its own grid (the grounded model's), which the
/// forest grid gathers per instance.
pub struct ModelArea {
    /// The model's grid in model space.
    pub frame: GridFrame,
    /// Its nodes per axis.
    pub dims: GridDims,
    /// Its blocking area and optics.
    pub area: LeafArea,
}

/// The forest grid's blocking leaf area per cell (world units²) and the
/// area-weighted optics of what blocks light. Each of a model's cells
/// carries its effective leaf area ([`effective_area`]: what its clumped
/// leaves stop, spread evenly) to the forest cell its centre falls in, turned
/// and scaled with the instance, so the crown's area stays up in the
/// crown. (Spread evenly over the instance's box, 40 % of a tall tree's
/// leaves sat in its trunk zone and shaded the ground from the low sky
/// under the stand.) `areas` is indexed by model.
pub fn forest_leaf_area(
    scene: &Scene,
    areas: &[Option<&ModelArea>],
    grid: &WorldGrid,
) -> (Vec<f32>, LeafScattering) {
    let d = grid.dims;
    let mut area = vec![0.0f32; d.len()];
    let (mut reflect, mut transmit, mut weight) = ([0.0f64; 3], [0.0f64; 3], 0.0f64);
    let last = Vec3::new((d.nx - 2) as f32, (d.ny - 2) as f32, (d.nz - 2) as f32);
    for inst in &scene.instances {
        let Some(m) = areas.get(inst.model as usize).copied().flatten() else { continue };
        let a = &m.area;
        let scale2 = inst.to_world.matrix3.determinant().abs().powf(2.0 / 3.0) as f64;
        let world_area = a.total_area * scale2;
        for c in 0..3 {
            reflect[c] += world_area * a.scattering.reflect[c];
            transmit[c] += world_area * a.scattering.transmit[c];
        }
        weight += world_area;
        let md = m.dims;
        for z in 0..md.nz {
            for y in 0..md.ny {
                for x in 0..md.nx {
                    let i = md.index(x, y, z);
                    if a.area[i] <= 0.0 {
                        continue;
                    }
                    // What the cell stops, as evenly spread area: its clumps leave gaps.
                    let cell_area = effective_area(a.density[i], m.frame.cell);
                    let centre = Vec3::from(m.frame.origin)
                        + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * m.frame.cell;
                    let q = ((inst.to_world.transform_point3(centre) - Vec3::from(grid.origin))
                        / grid.cell)
                        .floor()
                        .clamp(Vec3::ONE, last);
                    area[d.index(q.x as usize, q.y as usize, q.z as usize)] +=
                        (cell_area as f64 * scale2) as f32;
                }
            }
        }
    }
    let w = weight.max(f64::MIN_POSITIVE);
    (area, LeafScattering { reflect: reflect.map(|r| r / w), transmit: transmit.map(|t| t / w) })
}

/// The evenly spread one-sided leaf area that stops what a cell of edge
/// `cell` and density `density` stops (the inverse of
/// [`density_from_leaf_area`](super::radiometry::density_from_leaf_area)).
pub fn effective_area(density: f32, cell: f32) -> f32 {
    let open = (1.0 - density as f64).max(1e-12);
    (-open.ln() * (cell as f64).powi(2) / super::radiometry::LEAF_PROJECTION) as f32
}

/// The fraction of the open field's fluence `free` (summed over channels)
/// that reaches each crown in `boxes` from outside: the mean of the grid's
/// `total` fluence (three channel planes) over points one cell outside the
/// box, on its top and on its sides that face the sun (`towards`), where
/// its own crown casts no shadow.
pub fn crown_reach(
    grid: &WorldGrid,
    total: &[Vec<f32>],
    free: f64,
    towards: Vec3,
    boxes: &[Aabb],
) -> Vec<f32> {
    boxes
        .iter()
        .map(|b| {
            let (lo, hi) = (b.min - Vec3::splat(grid.cell), b.max + Vec3::splat(grid.cell));
            let mut sum = 0.0f64;
            let mut count = 0usize;
            let faces = [(1usize, 1.0f32), (0, 1.0), (0, -1.0), (2, 1.0), (2, -1.0)];
            for (axis, sign) in faces {
                if axis != 1 && towards[axis] * sign <= 0.0 {
                    continue;
                }
                let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
                for i in 0..3 {
                    for j in 0..3 {
                        let (u, v) = ((i as f32 + 0.5) / 3.0, (j as f32 + 0.5) / 3.0);
                        let mut p = lo;
                        p[a1] = lo[a1] + (hi[a1] - lo[a1]) * u;
                        p[a2] = lo[a2] + (hi[a2] - lo[a2]) * v;
                        p[axis] = if sign > 0.0 { hi[axis] } else { lo[axis] };
                        sum += total.iter().map(|plane| grid.sample(plane, p) as f64).sum::<f64>();
                        count += 1;
                    }
                }
            }
            (sum / count.max(1) as f64 / free) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trees_fill_the_cells_they_stand_in() {
        let trees: Vec<Occupant> = (0..4)
            .map(|i| Occupant {
                bounds: Aabb {
                    min: Vec3::new(i as f32 * 10.0, 0.0, 0.0),
                    max: Vec3::new(i as f32 * 10.0 + 8.0, 16.0, 8.0),
                },
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
