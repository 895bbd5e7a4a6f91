//! The voxelizer: triangles to an LB medium grid. Each cell of an N³ grid
//! over the model's bounds is split into 3 × 3 × 3 sub-cells; a sub-cell is
//! marked when a triangle overlaps it, and the cell's density is the marked
//! fraction. Cells whose marks come mostly from wood are brown, others green.

use crate::lb::radiometry::{ClumpedCell, LeafScattering, clumped_cell};
use crate::lb::{GridDims, MediumGrid, NodeClass};
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};
use sylva_scene::color::srgb8_to_linear;
use sylva_scene::leaf::LeafOptics;
use sylva_scene::model::{Model, Surface};

/// Sub-cells per cell edge.
pub const SUB: usize = 3;

/// A voxelized model and where its grid sits in model space.
#[derive(Clone, Debug)]
pub struct Voxelization {
    /// The medium, one node per cell.
    pub medium: MediumGrid,
    /// How the grid maps to model space.
    pub frame: GridFrame,
}

/// Placement of a cubic-celled grid in model space: node `(i, j, k)` is the
/// cell `[origin + (i, j, k) · cell, origin + (i + 1, j + 1, k + 1) · cell)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct GridFrame {
    /// Corner of node (0, 0, 0).
    pub origin: [f32; 3],
    /// Cell edge length.
    pub cell: f32,
}

impl GridFrame {
    /// A frame whose N³ grid holds `(min, max)` in its interior nodes
    /// `1 ..= N − 2`, so the model never overlaps the boundary shell.
    pub fn around(min: Vec3, max: Vec3, n: usize) -> Self {
        let extent = (max - min).max_element().max(f32::EPSILON);
        // A little slack keeps faces that touch the bounds off the shell.
        let cell = extent * (1.0 + 1e-3) / (n - 2) as f32;
        let centre = (min + max) * 0.5;
        let origin = centre - Vec3::splat(cell * n as f32 * 0.5);
        Self { origin: origin.to_array(), cell }
    }

    /// A frame and grid of about `n³` nodes with cubic cells fitted to
    /// `(min, max)`: the box's sides keep their proportions, so a tall
    /// narrow tree gets as many cells across its crown as its shape
    /// allows, and one node of shell lies all round. No side is given
    /// less than a sixteenth of the longest, so a flat model still has a
    /// few cells of height.
    pub fn fit(min: Vec3, max: Vec3, n: usize) -> (Self, GridDims) {
        let n = n.max(4);
        let e = (max - min).max(Vec3::splat(f32::EPSILON));
        let e = e.max(Vec3::splat(e.max_element() / 16.0));
        let inner = (n - 2) as f32;
        // Cubic cells whose count over the box is (n − 2)³, with slack so
        // faces stay off the shell; no side longer than 4n cells.
        let cell =
            ((e.x * e.y * e.z).cbrt() / inner).max(e.max_element() / (4 * n) as f32) * (1.0 + 1e-3);
        let nodes = |x: f32| ((x / cell).ceil() as usize).max(2) + 2;
        let dims = GridDims { nx: nodes(e.x), ny: nodes(e.y), nz: nodes(e.z) };
        let centre = (min + max) * 0.5;
        let size = Vec3::new(dims.nx as f32, dims.ny as f32, dims.nz as f32) * cell;
        (Self { origin: (centre - size * 0.5).to_array(), cell }, dims)
    }
}

/// Why a mesh cannot be voxelized.
#[derive(Debug, thiserror::Error)]
pub enum VoxelError {
    /// Nothing to voxelize.
    #[error("the model has no triangles")]
    Empty,
    /// A grid with no interior.
    #[error("grid size {0} is too small; use at least 4")]
    GridTooSmall(usize),
}

/// Fills the inside of a closed surface: every empty cell that no path of
/// empty cells (6-connected) links to the grid's shell becomes full (ρ = 1)
/// of `class`. Solid objects (the chapter's PMMA teapot) scatter inside,
/// not only in the shell of cells their triangles cross.
pub fn fill_interior(v: &mut Voxelization, class: NodeClass) -> usize {
    let d = v.medium.dims;
    let mut outside = vec![false; d.len()];
    let mut stack = Vec::new();
    for z in 0..d.nz {
        for y in 0..d.ny {
            for x in 0..d.nx {
                let i = d.index(x, y, z);
                if d.is_boundary(x, y, z) && v.medium.density[i] == 0.0 {
                    outside[i] = true;
                    stack.push((x, y, z));
                }
            }
        }
    }
    while let Some((x, y, z)) = stack.pop() {
        let near = [
            (x.wrapping_sub(1), y, z),
            (x + 1, y, z),
            (x, y.wrapping_sub(1), z),
            (x, y + 1, z),
            (x, y, z.wrapping_sub(1)),
            (x, y, z + 1),
        ];
        for (a, b, c) in near {
            if a < d.nx && b < d.ny && c < d.nz {
                let j = d.index(a, b, c);
                if !outside[j] && v.medium.density[j] == 0.0 {
                    outside[j] = true;
                    stack.push((a, b, c));
                }
            }
        }
    }
    let mut filled = 0;
    for (i, out) in outside.iter().enumerate().take(d.len()) {
        if !out && v.medium.density[i] == 0.0 {
            v.medium.density[i] = 1.0;
            v.medium.class[i] = class;
            filled += 1;
        }
    }
    filled
}

/// Voxelizes `mesh` into an `n³` grid over its bounding cube (the papers' grid).
pub fn voxelize(mesh: &Model, n: usize) -> Result<Voxelization, VoxelError> {
    if n < 4 {
        return Err(VoxelError::GridTooSmall(n));
    }
    let (min, max) = mesh.bounds().ok_or(VoxelError::Empty)?;
    voxelize_in(mesh, GridFrame::around(min, max, n), GridDims::cube(n))
}

/// Voxelizes `mesh` into the grid `dims` placed by `frame`: each cell's
/// density is the fraction of its 3 × 3 × 3 sub-cells a triangle overlaps.
pub fn voxelize_in(
    mesh: &Model,
    frame: GridFrame,
    dims: GridDims,
) -> Result<Voxelization, VoxelError> {
    if dims.nx < 4 || dims.ny < 4 || dims.nz < 4 {
        return Err(VoxelError::GridTooSmall(dims.nx.min(dims.ny).min(dims.nz)));
    }
    if mesh.triangle_count() == 0 {
        return Err(VoxelError::Empty);
    }
    let (sx, sy, sz) = (dims.nx * SUB, dims.ny * SUB, dims.nz * SUB);
    let words = (sx * sy * sz).div_ceil(64);
    let leaf: Vec<AtomicU64> = (0..words).map(|_| AtomicU64::new(0)).collect();
    let wood: Vec<AtomicU64> = (0..words).map(|_| AtomicU64::new(0)).collect();
    let origin = Vec3::from(frame.origin);
    let sub = frame.cell / SUB as f32;
    // A hair larger than half a sub-cell, so a triangle lying exactly on a
    // face between sub-cells marks them rather than slipping through both.
    let half = Vec3::splat(sub * 0.5 * (1.0 + 1e-5));

    (0..mesh.triangle_count()).into_par_iter().for_each(|t| {
        let tri = mesh.triangle(t);
        let bits = if mesh.surface(t) == Surface::Wood { &wood } else { &leaf };
        let lo = tri[0].min(tri[1]).min(tri[2]);
        let hi = tri[0].max(tri[1]).max(tri[2]);
        // Never mark the boundary shell: its nodes hold the sun's densities.
        let to_index =
            |v: f32, s: usize| -> usize { (v.max(SUB as f32) as usize).min(s - SUB - 1) };
        let (l, h) = (((lo - origin) / sub).floor(), ((hi - origin) / sub).floor());
        let a = [to_index(l.x, sx), to_index(l.y, sy), to_index(l.z, sz)];
        let b = [to_index(h.x, sx), to_index(h.y, sy), to_index(h.z, sz)];
        for k in a[2]..=b[2] {
            for j in a[1]..=b[1] {
                for i in a[0]..=b[0] {
                    let centre = origin + (Vec3::new(i as f32, j as f32, k as f32) + 0.5) * sub;
                    if triangle_overlaps_box(&tri, centre, half) {
                        let bit = i + sx * (j + sy * k);
                        bits[bit / 64].fetch_or(1 << (bit % 64), Ordering::Relaxed);
                    }
                }
            }
        }
    });

    let is_set = |bits: &[AtomicU64], bit: usize| {
        bits[bit / 64].load(Ordering::Relaxed) >> (bit % 64) & 1 == 1
    };
    let cells: Vec<(f32, NodeClass)> = (0..dims.len())
        .into_par_iter()
        .map(|idx| {
            let (x, y, z) = (idx % dims.nx, (idx / dims.nx) % dims.ny, idx / (dims.nx * dims.ny));
            let (mut l, mut w, mut any) = (0, 0, 0);
            for dz in 0..SUB {
                for dy in 0..SUB {
                    for dx in 0..SUB {
                        let bit = (x * SUB + dx) + sx * ((y * SUB + dy) + sy * (z * SUB + dz));
                        let (il, iw) = (is_set(&leaf, bit), is_set(&wood, bit));
                        l += il as u32;
                        w += iw as u32;
                        any += (il || iw) as u32;
                    }
                }
            }
            let class = if w > l { NodeClass::Brown } else { NodeClass::Green };
            (any as f32 / (SUB * SUB * SUB) as f32, class)
        })
        .collect();
    let medium = MediumGrid {
        dims,
        density: cells.iter().map(|c| c.0).collect(),
        class: cells.iter().map(|c| c.1).collect(),
    };
    Ok(Voxelization { medium, frame })
}

/// A model's leaf area per cell of a grid, and the optics of what fills it.
#[derive(Clone, Debug)]
pub struct LeafArea {
    /// Per node: the area that blocks light, as one-sided leaf area: a
    /// leaf's own area (mean projection G = ½ of it) plus half of a wood
    /// surface's (a closed surface's mean projection is a quarter of its area).
    pub area: Vec<f32>,
    /// Area-weighted mean reflectance and transmittance of what blocks
    /// light (leaves by the leaf optics × texture colour, wood by its colour).
    pub scattering: LeafScattering,
    /// Per node: the probability that light crossing its cell along an
    /// axis meets a leaf, from the leaf area's columns at the clumping
    /// resolution ([`ClumpedCell::density`]); the medium's density.
    pub density: Vec<f32>,
    /// Per node: the light on its leaves over the node's light
    /// ([`ClumpedCell::readout`]), which the solved field is scaled by.
    pub readout: Vec<f32>,
    /// Sub-cells per cell edge the clumping statistics used (1: none finer than the grid).
    pub clumping_sub: usize,
    /// Σ area, in model units².
    pub total_area: f64,
    /// Fraction of the leaf triangles' area their alpha masks cut away.
    pub cut_fraction: f64,
}

/// Samples per triangle edge: at least two per cell edge, and at least 4
/// (16 samples) on alpha-masked triangles, whose mask cuts within a card.
fn subdivisions(tri: &[Vec3; 3], cell: f32, masked: bool) -> usize {
    let edge =
        (tri[1] - tri[0]).length().max((tri[2] - tri[1]).length()).max((tri[0] - tri[2]).length());
    let m = (2.0 * edge / cell).ceil() as usize;
    m.max(if masked { 4 } else { 1 }).min(32)
}

/// Sub-cells per model-grid axis at which leaf clumping is resolved: a
/// cell of a coarser grid takes its gap fraction from the columns of this
/// finer grid, so every grid sees the same clumps (the finest grid the
/// auto choice tries is 128³).
pub const CLUMPING_RESOLUTION: usize = 256;

/// Sub-cells per cell edge that put `dims`' longest side at
/// [`CLUMPING_RESOLUTION`] sub-cells (1 when the grid is that fine already).
pub fn clumping_sub(dims: GridDims) -> usize {
    (CLUMPING_RESOLUTION / dims.nx.max(dims.ny).max(dims.nz).max(1)).max(1)
}

/// Where `mesh`'s opaque area lies in the grid `dims` placed by `frame`.
/// Each triangle is cut into m² equal sub-triangles whose centres carry
/// their area to the cell they fall in, unless the alpha mask cuts them.
/// The area is gathered on sub-cells ([`clumping_sub`] per cell edge) whose
/// columns give each cell its gap fraction: leaves clumped in a corner of a
/// cell stop less light than the same area spread through it.
pub fn leaf_area_in(
    mesh: &Model,
    optics: &LeafOptics,
    frame: GridFrame,
    coarse: GridDims,
) -> LeafArea {
    let sub = clumping_sub(coarse);
    let dims = GridDims { nx: coarse.nx * sub, ny: coarse.ny * sub, nz: coarse.nz * sub };
    let frame = GridFrame { origin: frame.origin, cell: frame.cell / sub as f32 };
    let origin = Vec3::from(frame.origin);
    #[derive(Clone)]
    struct Acc {
        area: SubCells,
        reflect: [f64; 3],
        transmit: [f64; 3],
        weight: f64,
        leaf: f64,
        cut: f64,
    }
    let empty = || Acc {
        area: SubCells::new(coarse, sub),
        reflect: [0.0; 3],
        transmit: [0.0; 3],
        weight: 0.0,
        leaf: 0.0,
        cut: 0.0,
    };
    // One accumulator per thread, not per split: each holds the whole sub-cell grid.
    let per_thread = mesh.triangle_count().div_ceil(rayon::current_num_threads()).max(4096);
    let acc = (0..mesh.triangle_count())
        .into_par_iter()
        .with_min_len(per_thread)
        .fold(empty, |mut acc, t| {
            let tri = mesh.triangle(t);
            let uv =
                mesh.triangles[t].map(|i| mesh.uvs.get(i as usize).copied().unwrap_or_default());
            let mat = &mesh.materials[mesh.material[t] as usize];
            let wood = mat.surface == Surface::Wood;
            let masked = mat.alpha_cutoff.is_some();
            let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length() as f64;
            let m = subdivisions(&tri, frame.cell, masked);
            let share = area / (m * m) as f64;
            let mut sample = |u: f32, v: f32| {
                let uvp = uv[0] + (uv[1] - uv[0]) * u + (uv[2] - uv[0]) * v;
                if !wood {
                    acc.leaf += share;
                }
                // One texel read serves the mask and the colour.
                let texel = mat.texture.map(|i| mesh.textures[i as usize].texel(uvp));
                if masked && mat.is_hole(texel) {
                    acc.cut += share;
                    return;
                }
                let p = tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v;
                let g = ((p - origin) / frame.cell).floor();
                let (x, y, z) =
                    (g.x.max(0.0) as usize, g.y.max(0.0) as usize, g.z.max(0.0) as usize);
                if x >= dims.nx || y >= dims.ny || z >= dims.nz {
                    return;
                }
                let mut albedo = [mat.base_color[0], mat.base_color[1], mat.base_color[2]];
                if let Some(px) = texel {
                    for c in 0..3 {
                        albedo[c] *= srgb8_to_linear(px[c]);
                    }
                }
                let w = if wood { 0.5 * share } else { share };
                *acc.area.at(x, y, z) += w;
                acc.weight += w;
                for c in 0..3 {
                    if wood {
                        acc.reflect[c] += w * albedo[c] as f64;
                    } else {
                        let k = optics.coefficients(albedo, c);
                        acc.reflect[c] += w * 0.5 * (k[0] + k[1]) as f64;
                        acc.transmit[c] += w * 0.5 * (k[2] + k[3]) as f64;
                    }
                }
            };
            let inv = 1.0 / m as f32;
            for i in 0..m {
                for j in 0..m - i {
                    sample((i as f32 + 1.0 / 3.0) * inv, (j as f32 + 1.0 / 3.0) * inv);
                    if i + j + 1 < m {
                        sample((i as f32 + 2.0 / 3.0) * inv, (j as f32 + 2.0 / 3.0) * inv);
                    }
                }
            }
            acc
        })
        .reduce(empty, |mut a, b| {
            a.area.add(b.area);
            for c in 0..3 {
                a.reflect[c] += b.reflect[c];
                a.transmit[c] += b.transmit[c];
            }
            a.weight += b.weight;
            a.leaf += b.leaf;
            a.cut += b.cut;
            a
        });
    let w = acc.weight.max(f64::MIN_POSITIVE);
    let (area, cells) = coarsen(&acc.area, frame.cell as f64);
    LeafArea {
        area,
        density: cells.iter().map(|c| c.density).collect(),
        readout: cells.iter().map(|c| c.readout).collect(),
        clumping_sub: sub,
        scattering: LeafScattering {
            reflect: acc.reflect.map(|r| r / w),
            transmit: acc.transmit.map(|t| t / w),
        },
        total_area: acc.weight,
        cut_fraction: if acc.leaf > 0.0 { acc.cut / acc.leaf } else { 0.0 },
    }
}

/// Leaf area on the sub-cells of a coarse grid, held per coarse cell in
/// blocks of `sub`³ made where area lands: a crown fills a fraction of
/// its box, and a dense 256³ grid of f64 per thread cost more in page
/// faults and sums than the sampling itself. Sums are taken in the same
/// order as over a dense grid, so the result is the same to the bit.
#[derive(Clone)]
struct SubCells {
    coarse: GridDims,
    sub: usize,
    /// Per coarse cell, its sub-cells (x fastest), if any area landed.
    blocks: Vec<Option<Box<[f64]>>>,
}

impl SubCells {
    fn new(coarse: GridDims, sub: usize) -> Self {
        Self { coarse, sub, blocks: vec![None; coarse.len()] }
    }

    /// The sub-cell at fine coordinates `(x, y, z)`.
    fn at(&mut self, x: usize, y: usize, z: usize) -> &mut f64 {
        let s = self.sub;
        let block = self.coarse.index(x / s, y / s, z / s);
        let b = self.blocks[block].get_or_insert_with(|| vec![0.0; s * s * s].into());
        &mut b[x % s + s * (y % s + s * (z % s))]
    }

    /// Adds `other`'s area in (where only one holds a block, it is taken
    /// as is: adding a zero changes nothing).
    fn add(&mut self, other: SubCells) {
        for (a, b) in self.blocks.iter_mut().zip(other.blocks) {
            match (a.as_mut(), b) {
                (Some(a), Some(b)) => a.iter_mut().zip(b.iter()).for_each(|(x, y)| *x += y),
                (None, b) => *a = b,
                (Some(_), None) => {}
            }
        }
    }
}

/// Each coarse cell's leaf area (the sum of its `sub`³ sub-cells') and
/// what its sub-cell columns along the three axes make of it.
fn coarsen(fine: &SubCells, sub_cell: f64) -> (Vec<f32>, Vec<ClumpedCell>) {
    let (coarse, sub) = (fine.coarse, fine.sub);
    let zeros = vec![0.0; sub * sub * sub];
    let cells: Vec<(f32, ClumpedCell)> = (0..coarse.len())
        .into_par_iter()
        .map(|i| {
            let block = fine.blocks[i].as_deref().unwrap_or(&zeros);
            let at = |a: usize, b: usize, c: usize| block[a + sub * (b + sub * c)];
            let mut total = 0.0;
            let mut columns = Vec::with_capacity(3 * sub * sub);
            for a in 0..sub {
                for b in 0..sub {
                    let (mut cx, mut cy, mut cz) = (0.0, 0.0, 0.0);
                    for c in 0..sub {
                        cx += at(c, a, b);
                        cy += at(a, c, b);
                        cz += at(a, b, c);
                    }
                    total += cx;
                    columns.extend([cx, cy, cz]);
                }
            }
            (total as f32, clumped_cell(&columns, sub_cell))
        })
        .collect();
    cells.into_iter().unzip()
}

/// The grounded LB medium of a model's densities ([`LeafArea::density`]):
/// every occupied node absorbs for real (green). The shell stays empty.
pub fn medium_from_density(density: &[f32], dims: GridDims) -> MediumGrid {
    let mut m = MediumGrid::empty(dims).with_class(NodeClass::Green);
    for z in 0..dims.nz {
        for y in 0..dims.ny {
            for x in 0..dims.nx {
                if !dims.is_boundary(x, y, z) {
                    let i = dims.index(x, y, z);
                    m.density[i] = density[i];
                }
            }
        }
    }
    m
}

/// The grounded LB medium of a leaf-area grid with no finer structure
/// (the forest grid): each node's density is the probability that light
/// crossing its cell meets a leaf, the area spread evenly (see
/// [`density_from_leaf_area`](crate::lb::radiometry::density_from_leaf_area)).
pub fn medium_from_leaf_area(area: &[f32], dims: GridDims, cell: f32) -> MediumGrid {
    let density: Vec<f32> = area
        .iter()
        .map(|&a| crate::lb::radiometry::density_from_leaf_area(a as f64, cell as f64))
        .collect();
    medium_from_density(&density, dims)
}

/// Triangle–box overlap by the separating axis theorem (Akenine-Möller
/// 2001): the box's three axes, the triangle's normal and the nine cross
/// products of edges with axes.
pub fn triangle_overlaps_box(tri: &[Vec3; 3], centre: Vec3, half: Vec3) -> bool {
    let v = [tri[0] - centre, tri[1] - centre, tri[2] - centre];
    // Box axes: the triangle's bounds against the box.
    for a in 0..3 {
        let (lo, hi) = (v[0][a].min(v[1][a]).min(v[2][a]), v[0][a].max(v[1][a]).max(v[2][a]));
        if lo > half[a] || hi < -half[a] {
            return false;
        }
    }
    let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    // Triangle normal: the box's projection radius against the plane offset.
    let normal = e[0].cross(e[1]);
    let r = half.dot(normal.abs());
    let d = normal.dot(v[0]);
    if d.abs() > r {
        return false;
    }
    // Edge × axis.
    for edge in e {
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let l = edge.cross(axis);
            let p = [l.dot(v[0]), l.dot(v[1]), l.dot(v[2])];
            let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
            let r = half.dot(l.abs());
            if lo > r || hi < -r {
                return false;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_closed_box_fills_and_an_open_sheet_does_not() {
        let mut cube = Model::default();
        let m =
            cube.add_material(sylva_scene::model::Material::plain("pmma", Surface::Leaf, [0.9; 3]));
        let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        for (a, b, cc, d) in [
            (c(0., 0., 0.), c(1., 0., 0.), c(1., 1., 0.), c(0., 1., 0.)),
            (c(0., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(0., 1., 1.)),
            (c(0., 0., 0.), c(0., 1., 0.), c(0., 1., 1.), c(0., 0., 1.)),
            (c(1., 0., 0.), c(1., 1., 0.), c(1., 1., 1.), c(1., 0., 1.)),
            (c(0., 0., 0.), c(1., 0., 0.), c(1., 0., 1.), c(0., 0., 1.)),
            (c(0., 1., 0.), c(1., 1., 0.), c(1., 1., 1.), c(0., 1., 1.)),
        ] {
            cube.push_quad([a, b, cc, d], m);
        }
        let mut v = voxelize(&cube, 12).unwrap();
        let shell = v.medium.density.iter().filter(|&&d| d > 0.0).count();
        let filled = fill_interior(&mut v, NodeClass::Medium);
        assert!(filled > 0, "a closed cube has an inside");
        let centre = v.medium.dims.index(6, 6, 6);
        assert_eq!((v.medium.density[centre], v.medium.class[centre]), (1.0, NodeClass::Medium));
        assert_eq!(v.medium.density.iter().filter(|&&d| d > 0.0).count(), shell + filled);
        // Outside stays empty.
        assert_eq!(v.medium.density[v.medium.dims.index(0, 0, 0)], 0.0);
        // One open square: nothing inside.
        let mut sheet = Model::default();
        let m = sheet.add_material(sylva_scene::model::Material::plain(
            "leaf",
            Surface::Leaf,
            [0.2; 3],
        ));
        sheet.push_quad([c(0., 0.5, 0.), c(0., 0.5, 1.), c(1., 0.5, 1.), c(1., 0.5, 0.)], m);
        let mut v = voxelize(&sheet, 9).unwrap();
        assert_eq!(fill_interior(&mut v, NodeClass::Medium), 0);
    }

    #[test]
    fn overlap_test_agrees_with_obvious_cases() {
        let tri = [Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.0, 0.0, 1.0)];
        let h = Vec3::splat(0.1);
        assert!(triangle_overlaps_box(&tri, Vec3::ZERO, h));
        assert!(triangle_overlaps_box(&tri, Vec3::new(0.0, 0.09, 0.0), h));
        assert!(!triangle_overlaps_box(&tri, Vec3::new(0.0, 0.11, 0.0), h));
        // Beside the hypotenuse: inside the triangle's bounds, outside the triangle.
        assert!(!triangle_overlaps_box(&tri, Vec3::new(0.9, 0.0, 0.8), h));
        // A box containing the whole triangle.
        assert!(triangle_overlaps_box(&tri, Vec3::ZERO, Vec3::splat(5.0)));
    }

    #[test]
    fn a_fitted_grid_follows_the_shape_of_a_tall_narrow_box() {
        // 2 × 13 × 2: a cube of 32³ would give it 32 · 2/13 ≈ 5 cells across.
        let (lo, hi) = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 13.0, 1.0));
        let (frame, dims) = GridFrame::fit(lo, hi, 32);
        assert!(dims.nx >= 15 && dims.nz >= 15 && dims.ny > 5 * dims.nx, "{dims}");
        let nodes = dims.len() as f64;
        assert!(nodes > 0.8 * 32f64.powi(3) && nodes < 1.6 * 32f64.powi(3), "{dims}");
        // The box lies in the interior nodes, off the shell.
        let o = Vec3::from(frame.origin);
        let far = o + Vec3::new(dims.nx as f32, dims.ny as f32, dims.nz as f32) * frame.cell;
        assert!(
            (lo - o).min_element() >= frame.cell && (far - hi).min_element() >= frame.cell,
            "{frame:?} {dims}"
        );
    }

    #[test]
    fn clumped_leaves_stop_the_same_light_on_a_coarse_grid_as_on_the_fine_one() {
        // A horizontal layer of small dense clumps (stacks of leaf squares),
        // light falling straight down: the transmitted fraction is the
        // open area's plus what the stacks let through, whatever the grid.
        let mut mesh = Model::default();
        let leaf = mesh.add_material(sylva_scene::model::Material::plain(
            "leaf",
            Surface::Leaf,
            [0.2, 0.5, 0.1],
        ));
        let (size, pitch, layers) = (0.06f32, 0.5f32, 6);
        for i in 0..8 {
            for k in 0..8 {
                let (x, z) = (0.1 + i as f32 * pitch, 0.1 + k as f32 * pitch);
                for l in 0..layers {
                    let y = 1.0 + 0.005 * l as f32;
                    mesh.push_quad(
                        [
                            Vec3::new(x, y, z),
                            Vec3::new(x, y, z + size),
                            Vec3::new(x + size, y, z + size),
                            Vec3::new(x + size, y, z),
                        ],
                        leaf,
                    );
                }
            }
        }
        let (lo, hi) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(4.0, 2.0, 4.0));
        let down = |n: usize| {
            let (frame, dims) = GridFrame::fit(lo, hi, n);
            let a = leaf_area_in(&mesh, &LeafOptics::default(), frame, dims);
            let mut open = 0.0;
            for z in 0..dims.nz {
                for x in 0..dims.nx {
                    open += (0..dims.ny)
                        .map(|y| 1.0 - a.density[dims.index(x, y, z)] as f64)
                        .product::<f64>();
                }
            }
            (open / (dims.nx * dims.nz) as f64, a.clumping_sub)
        };
        let (fine, s_fine) = down(CLUMPING_RESOLUTION);
        let (coarse, s_coarse) = down(16);
        assert_eq!(s_fine, 1);
        assert!(s_coarse >= 4, "{s_coarse}");
        // The clumps cover 64 · 0.06² / 16 = 1.4 % of the ground (a little
        // more where they straddle sub-cells).
        assert!(fine > 0.95 && fine < 0.995, "{fine}");
        assert!((coarse - fine).abs() < 0.01, "16³ {coarse} against {CLUMPING_RESOLUTION}³ {fine}");
        // Spread evenly through each 16³ cell the same area would stop far more.
        let (frame, dims) = GridFrame::fit(lo, hi, 16);
        let a = leaf_area_in(&mesh, &LeafOptics::default(), frame, dims);
        let even = medium_from_leaf_area(&a.area, dims, frame.cell);
        let mut open = 0.0;
        for z in 0..dims.nz {
            for x in 0..dims.nx {
                open += (0..dims.ny)
                    .map(|y| 1.0 - even.density[dims.index(x, y, z)] as f64)
                    .product::<f64>();
            }
        }
        let even = open / (dims.nx * dims.nz) as f64;
        assert!(1.0 - even > 2.0 * (1.0 - coarse), "even {even}, clumped {coarse}");
    }

    #[test]
    fn leaf_area_counts_only_what_the_alpha_mask_keeps() {
        // A 1 m² card whose texture is opaque on its left half only.
        let mut mesh = Model::default();
        let (w, h) = (8u32, 8u32);
        let rgba =
            (0..w * h).flat_map(|i| [60, 120, 30, if i % w < w / 2 { 255 } else { 0 }]).collect();
        mesh.textures.push(sylva_scene::model::Texture { width: w, height: h, rgba });
        let mut mat = sylva_scene::model::Material::plain("leaf", Surface::Leaf, [1.0; 3]);
        (mat.texture, mat.alpha_cutoff) = (Some(0), Some(0.5));
        let leaf = mesh.add_material(mat);
        mesh.push_quad(
            [
                Vec3::new(0.0, 0.5, 0.0),
                Vec3::new(1.0, 0.5, 0.0),
                Vec3::new(1.0, 0.5, 1.0),
                Vec3::new(0.0, 0.5, 1.0),
            ],
            leaf,
        );
        let (lo, hi) = mesh.bounds().unwrap();
        let (frame, dims) = GridFrame::fit(lo, hi, 12);
        let a = leaf_area_in(&mesh, &LeafOptics::default(), frame, dims);
        assert!((a.total_area - 0.5).abs() < 0.05, "{}", a.total_area);
        assert!((a.cut_fraction - 0.5).abs() < 0.05, "{}", a.cut_fraction);
        let sum: f64 = a.area.iter().map(|&x| x as f64).sum();
        assert!((sum - a.total_area).abs() < 1e-4);
        // Only the opaque half's cells hold area: x < 0.5.
        for z in 0..dims.nz {
            for y in 0..dims.ny {
                for x in 0..dims.nx {
                    let centre = frame.origin[0] + (x as f32 + 0.5) * frame.cell;
                    if a.area[dims.index(x, y, z)] > 0.0 {
                        assert!(centre < 0.5 + frame.cell, "cell at x = {centre}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_flat_square_fills_one_layer_of_cells() {
        let mut mesh = Model::default();
        let leaf = mesh.add_material(sylva_scene::model::Material::plain(
            "leaf",
            Surface::Leaf,
            [0.2, 0.5, 0.1],
        ));
        // A square in the plane y = 0.5 spanning x, z ∈ [0, 1].
        let y = 0.5;
        mesh.push_quad(
            [
                Vec3::new(0.0, y, 0.0),
                Vec3::new(0.0, y, 1.0),
                Vec3::new(1.0, y, 1.0),
                Vec3::new(1.0, y, 0.0),
            ],
            leaf,
        );
        // Odd n puts the plane through the middle of the centre cell's
        // middle layer of sub-cells: 9 of 27 marked, density 1/3.
        let n = 9;
        let v = voxelize(&mesh, n).unwrap();
        let d = &v.medium;
        let column: Vec<f32> = (0..n).map(|y| d.density[d.dims.index(n / 2, y, n / 2)]).collect();
        let mut want = vec![0.0; n];
        want[n / 2] = 1.0 / 3.0;
        assert_eq!(column, want);
        assert!(d.class.iter().zip(&d.density).all(|(c, &r)| r == 0.0 || *c == NodeClass::Green));
        // Nothing on the boundary shell.
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    if d.dims.is_boundary(x, y, z) {
                        assert_eq!(d.density[d.dims.index(x, y, z)], 0.0);
                    }
                }
            }
        }
    }

    #[test]
    fn wood_triangles_make_brown_cells() {
        let mut mesh = crate::shapes::plant(7);
        let v = voxelize(&mesh, 24).unwrap();
        let brown = v
            .medium
            .class
            .iter()
            .zip(&v.medium.density)
            .filter(|(c, r)| **r > 0.0 && **c == NodeClass::Brown)
            .count();
        let green = v
            .medium
            .class
            .iter()
            .zip(&v.medium.density)
            .filter(|(c, r)| **r > 0.0 && **c == NodeClass::Green)
            .count();
        assert!(brown > 0 && green > brown, "brown {brown}, green {green}");
        mesh.materials.iter_mut().for_each(|m| m.surface = Surface::Leaf);
        let v = voxelize(&mesh, 24).unwrap();
        assert!(v.medium.class.iter().all(|c| *c == NodeClass::Green));
    }
}
