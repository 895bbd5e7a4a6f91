//! Helpers every GPU test file shares: the adapter, a scratch folder, and
//! the one generator of small glTF models the tests render.

#![allow(dead_code)] // each test file uses its own share of these

use glam::Vec3;
use std::path::{Path, PathBuf};
use sylva_worker::GpuContext;
use sylva_worker::trace::Tracer;

/// The machine's GPU adapter (lavapipe without a GPU).
pub fn ctx() -> Tracer {
    Tracer::new()
        .expect("these tests need a GPU adapter; on Debian install mesa-vulkan-drivers (lavapipe)")
}

/// Whether the adapter offers ray queries; lavapipe (Mesa 25, which the
/// install scripts give) must, so only a GPU without them skips.
#[allow(dead_code)] // not every test file traces with ray queries
pub fn ray_queries(ctx: &GpuContext) -> bool {
    if !ctx.has_ray_queries() {
        assert_ne!(
            ctx.adapter.get_info().device_type,
            wgpu::DeviceType::Cpu,
            "lavapipe should offer ray queries: is Mesa older than 25?"
        );
        eprintln!("ray queries skipped: {} offers none", ctx.adapter_name());
    }
    ctx.has_ray_queries()
}

/// A fresh folder for one test's files.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sylva-gpu-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The square 2 × 2 in the plane z = 0 around the origin, facing +z.
pub const QUAD: [Vec3; 4] = [
    Vec3::new(-1.0, -1.0, 0.0),
    Vec3::new(1.0, -1.0, 0.0),
    Vec3::new(1.0, 1.0, 0.0),
    Vec3::new(-1.0, 1.0, 0.0),
];

/// A material of a test model: its name (which says leaf or wood), its
/// colour and whether both sides face out.
#[derive(Clone, Copy, Debug)]
pub struct TestMaterial<'a> {
    /// Material name ("leaf" or "bark").
    pub name: &'a str,
    /// Linear RGB base colour.
    pub rgb: [f32; 3],
    /// glTF `doubleSided`.
    pub double_sided: bool,
}

/// Writes `name.gltf` and `name.bin` in `dir`: squares, each given by its
/// four corners, of one material. Returns the `.gltf` path.
pub fn write_squares_gltf(
    dir: &Path,
    name: &str,
    material: TestMaterial,
    squares: &[[Vec3; 4]],
) -> PathBuf {
    let positions: Vec<f32> =
        squares.iter().flat_map(|q| q.iter().flat_map(|v| v.to_array())).collect();
    let indices: Vec<u32> =
        (0..squares.len() as u32).flat_map(|k| [0, 1, 2, 0, 2, 3].map(|i| 4 * k + i)).collect();
    let (lo, hi) = positions.chunks(3).fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
        (std::array::from_fn(|c| lo[c].min(p[c])), std::array::from_fn(|c| hi[c].max(p[c])))
    });
    let mut bytes: Vec<u8> = positions.iter().flat_map(|v| v.to_le_bytes()).collect();
    let vertex_bytes = bytes.len();
    bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    std::fs::write(dir.join(format!("{name}.bin")), &bytes).unwrap();
    let [r, g, b] = material.rgb;
    let gltf = serde_json::json!({
        "asset": { "version": "2.0" },
        "scene": 0,
        "scenes": [ { "nodes": [0] } ],
        "nodes": [ { "mesh": 0 } ],
        "meshes": [ { "primitives": [ { "attributes": { "POSITION": 0 }, "indices": 1, "material": 0 } ] } ],
        "materials": [ {
            "name": material.name,
            "doubleSided": material.double_sided,
            "pbrMetallicRoughness": { "baseColorFactor": [r, g, b, 1.0] }
        } ],
        "buffers": [ { "byteLength": bytes.len(), "uri": format!("{name}.bin") } ],
        "bufferViews": [
            { "buffer": 0, "byteOffset": 0, "byteLength": vertex_bytes },
            { "buffer": 0, "byteOffset": vertex_bytes, "byteLength": bytes.len() - vertex_bytes }
        ],
        "accessors": [
            { "bufferView": 0, "componentType": 5126, "count": positions.len() / 3, "type": "VEC3",
              "min": lo, "max": hi },
            { "bufferView": 1, "componentType": 5125, "count": indices.len(), "type": "SCALAR" }
        ]
    });
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, serde_json::to_vec(&gltf).unwrap()).unwrap();
    path
}
