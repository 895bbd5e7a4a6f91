//! Triangle meshes whose triangles know whether they are leaf or wood, and
//! their loading from glTF 2.0.

use anyhow::{Context, bail};
use glam::{Mat4, Vec3};
use std::path::Path;

/// What a triangle is made of, for the LB medium: leaves are green nodes,
/// wood brown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    /// Leaf blade (alpha-masked in glTF, or anything not named as wood).
    Leaf,
    /// Trunk, branch or stem.
    Wood,
}

/// An indexed triangle mesh in model space.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Vertex indices, three per triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Material class per triangle.
    pub surface: Vec<Surface>,
}

impl Mesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Adds a triangle with its own three vertices.
    pub fn push_triangle(&mut self, v: [Vec3; 3], surface: Surface) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&v);
        self.triangles.push([base, base + 1, base + 2]);
        self.surface.push(surface);
    }

    /// Adds a quad `a b c d` (counter-clockwise) as two triangles.
    pub fn push_quad(&mut self, q: [Vec3; 4], surface: Surface) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&q);
        self.triangles.push([base, base + 1, base + 2]);
        self.triangles.push([base, base + 2, base + 3]);
        self.surface.extend([surface, surface]);
    }

    /// Corners of triangle `t`.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Axis-aligned bounds `(min, max)`, or `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.triangles.iter().flatten().map(|&i| self.positions[i as usize]);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }

    /// Number of wood triangles.
    pub fn wood_triangles(&self) -> usize {
        self.surface.iter().filter(|&&s| s == Surface::Wood).count()
    }
}

/// Names that mark a glTF material as wood rather than leaf.
const WOOD_WORDS: [&str; 6] = ["bark", "wood", "trunk", "branch", "stem", "twig"];

/// The surface class of a glTF material: wood when its name says so,
/// otherwise leaf (alpha-masked foliage and anything unnamed).
pub fn classify_material(name: Option<&str>) -> Surface {
    let name = name.unwrap_or("").to_ascii_lowercase();
    if WOOD_WORDS.iter().any(|w| name.contains(w)) { Surface::Wood } else { Surface::Leaf }
}

/// Loads every triangle of a glTF 2.0 file (`.gltf` or `.glb`) in the
/// default scene, with node transforms applied.
pub fn load_gltf(path: &Path) -> anyhow::Result<Mesh> {
    let (doc, buffers, _images) =
        gltf::import(path).with_context(|| format!("{}: cannot load glTF", path.display()))?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .with_context(|| format!("{}: the glTF file has no scene", path.display()))?;
    let mut mesh = Mesh::default();
    for node in scene.nodes() {
        add_node(&node, Mat4::IDENTITY, &buffers, &mut mesh, path)?;
    }
    if mesh.triangles.is_empty() {
        bail!("{}: the glTF scene has no triangles", path.display());
    }
    Ok(mesh)
}

fn add_node(
    node: &gltf::Node,
    parent: Mat4,
    buffers: &[gltf::buffer::Data],
    mesh: &mut Mesh,
    path: &Path,
) -> anyhow::Result<()> {
    let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
    if let Some(m) = node.mesh() {
        for prim in m.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                tracing::warn!(mesh = m.name(), mode = ?prim.mode(), "skipping a non-triangle primitive");
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else { continue };
            let base = mesh.positions.len() as u32;
            for p in pos {
                let v = world.transform_point3(Vec3::from(p));
                if !v.is_finite() {
                    bail!("{}: mesh {:?} has a non-finite vertex position", path.display(), m.name().unwrap_or("?"));
                }
                mesh.positions.push(v);
            }
            let count = mesh.positions.len() as u32 - base;
            let indices: Vec<u32> = match reader.read_indices() {
                Some(ix) => ix.into_u32().collect(),
                None => (0..count).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i >= count) {
                bail!("{}: mesh {:?} indexes vertex {bad} of {count}", path.display(), m.name().unwrap_or("?"));
            }
            let surface = classify_material(prim.material().name());
            for t in indices.chunks_exact(3) {
                mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
                mesh.surface.push(surface);
            }
        }
    }
    for child in node.children() {
        add_node(&child, world, buffers, mesh, path)?;
    }
    Ok(())
}
