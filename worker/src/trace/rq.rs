//! The ray-query backend's structures: one BLAS per model and a TLAS over
//! the instances, built by the device (wgpu's `EXPERIMENTAL_RAY_QUERY`),
//! compacted, and measured. `shaders/trace/rq.wgsl` traces through them.
//!
//! A model's BLAS has up to two geometries: its opaque triangles (flagged
//! opaque: the device confirms their hits itself) and its mixed ones
//! (candidates the shader confirms after the alpha test). Cut triangles,
//! which no ray can hit, are left out, as the BVH leaves them out.

use crate::gpu::GpuContext;
use glam::Affine3A;
use std::sync::atomic::{AtomicU64, Ordering};
use sylva_accel::coverage::Coverage;

/// Most instances a TLAS may index: the custom data that carries an
/// instance's index to the shader has 24 bits.
pub const MAX_INSTANCES: usize = 1 << 24;

/// One model's triangles in BLAS order, as the upload lays them out.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct RqModel {
    /// Its first vertex in the positions buffer.
    pub vert0: u32,
    /// Its vertices.
    pub vertices: u32,
    /// Its first entry in the index list (three per triangle) and in
    /// `rq_triangles` (one per triangle), in triangles.
    pub first: u32,
    /// Opaque triangles (geometry 0), then mixed ones (geometry 1).
    pub opaque: u32,
    /// Mixed triangles.
    pub mixed: u32,
}

/// Each model's triangles in BLAS order, given their coverage: the opaque
/// ones, then the mixed ones, by model-local index.
pub(super) fn blas_order(coverage: &[Coverage]) -> (Vec<u32>, u32) {
    let of = |c: Coverage| {
        coverage.iter().enumerate().filter(move |&(_, &k)| k == c).map(|(t, _)| t as u32)
    };
    let mut order: Vec<u32> = of(Coverage::Opaque).collect();
    let opaque = order.len() as u32;
    order.extend(of(Coverage::Mixed));
    (order, opaque)
}

/// The device's structures for one scene (kept alive with it).
pub struct RqStructures {
    /// The instances' structure, bound at `@binding(14)`.
    pub tlas: wgpu::Tlas,
    /// Per model, its structure (none when it has no triangle a ray can hit).
    pub blases: Vec<Option<wgpu::Blas>>,
    /// Bytes the device's allocator gave the structures, after compaction
    /// (`None` where the allocator does not report by name).
    pub bytes: Option<u64>,
    /// Bytes of the BLASes as built, before compaction.
    pub built_bytes: Option<u64>,
    /// Triangles in the BLASes, each counted once per model.
    pub triangles: u64,
    /// Wall time of the build and compaction, seconds.
    pub build_seconds: f64,
}

/// Tells this process's structures apart in the allocator's report.
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

/// Builds and compacts a BLAS per model over `positions` (a `BLAS_INPUT`
/// buffer of packed x y z) and `indices` (model-local, in BLAS order), then
/// the TLAS over `instances` (to world, model).
pub(super) fn build(
    ctx: &GpuContext,
    positions: &wgpu::Buffer,
    indices: &wgpu::Buffer,
    models: &[RqModel],
    instances: &[(Affine3A, u32)],
) -> anyhow::Result<RqStructures> {
    anyhow::ensure!(
        instances.len() <= MAX_INSTANCES,
        "{} instances: ray queries carry an instance's index in 24 bits, at most {MAX_INSTANCES}",
        instances.len()
    );
    let start = std::time::Instant::now();
    let device = &ctx.device;
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    let ours = format!("sylva rq {id} ");
    let (blas_label, tlas_label) = (format!("{ours}blas"), format!("{ours}tlas"));
    let geometry =
        |count: u32, vertices: u32, opaque: bool| wgpu::BlasTriangleGeometrySizeDescriptor {
            vertex_format: wgpu::VertexFormat::Float32x3,
            vertex_count: vertices,
            index_format: Some(wgpu::IndexFormat::Uint32),
            index_count: Some(3 * count),
            flags: if opaque {
                wgpu::AccelerationStructureGeometryFlags::OPAQUE
            } else {
                // Each candidate once: its alpha test counts it as passed.
                wgpu::AccelerationStructureGeometryFlags::NO_DUPLICATE_ANY_HIT_INVOCATION
            },
        };
    // Per model: its geometries' sizes and where their indices start.
    let sizes: Vec<Vec<(wgpu::BlasTriangleGeometrySizeDescriptor, u32)>> = models
        .iter()
        .map(|m| {
            let mut g = Vec::new();
            if m.opaque > 0 {
                g.push((geometry(m.opaque, m.vertices, true), 3 * m.first));
            }
            if m.mixed > 0 {
                g.push((geometry(m.mixed, m.vertices, false), 3 * (m.first + m.opaque)));
            }
            g
        })
        .collect();
    let flags = wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE
        | wgpu::AccelerationStructureFlags::ALLOW_COMPACTION;
    let blases: Vec<Option<wgpu::Blas>> = sizes
        .iter()
        .map(|g| {
            (!g.is_empty()).then(|| {
                device.create_blas(
                    &wgpu::CreateBlasDescriptor {
                        label: Some(&blas_label),
                        flags,
                        update_mode: wgpu::AccelerationStructureUpdateMode::Build,
                    },
                    wgpu::BlasGeometrySizeDescriptors::Triangles {
                        descriptors: g.iter().map(|(d, _)| d.clone()).collect(),
                    },
                )
            })
        })
        .collect();
    let entries: Vec<wgpu::BlasBuildEntry> = blases
        .iter()
        .zip(&sizes)
        .zip(models)
        .filter_map(|((b, g), m)| {
            let blas = b.as_ref()?;
            let geometries = g
                .iter()
                .map(|(size, first_index)| wgpu::BlasTriangleGeometry {
                    size,
                    vertex_buffer: positions,
                    first_vertex: m.vert0,
                    vertex_stride: 12,
                    index_buffer: Some(indices),
                    first_index: Some(*first_index),
                    transform_buffer: None,
                    transform_buffer_offset: None,
                })
                .collect();
            Some(wgpu::BlasBuildEntry {
                blas,
                geometry: wgpu::BlasGeometries::TriangleGeometries(geometries),
            })
        })
        .collect();
    let mut enc = device.create_command_encoder(&Default::default());
    enc.build_acceleration_structures(entries.iter(), std::iter::empty());
    ctx.queue.submit([enc.finish()]);
    // Compaction: each BLAS copied into one of the size the build found it
    // needs (drivers reserve for the worst case before building).
    for b in blases.iter().flatten() {
        b.prepare_compaction_async(|_| {});
    }
    ctx.wait()?;
    let built_bytes = allocated(device, &ours);
    let blases: Vec<Option<wgpu::Blas>> = blases
        .into_iter()
        .map(|b| b.map(|b| if b.ready_for_compaction() { ctx.queue.compact_blas(&b) } else { b }))
        .collect();
    let mut tlas = device.create_tlas(&wgpu::CreateTlasDescriptor {
        label: Some(&tlas_label),
        max_instances: instances.len().max(1) as u32,
        flags: wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE,
        update_mode: wgpu::AccelerationStructureUpdateMode::Build,
    });
    for (i, (to_world, model)) in instances.iter().enumerate() {
        let Some(Some(blas)) = blases.get(*model as usize) else { continue };
        let (c, t) = (to_world.matrix3, to_world.translation);
        let rows: [f32; 12] = std::array::from_fn(|k| {
            let (r, col) = (k / 4, k % 4);
            [c.x_axis[r], c.y_axis[r], c.z_axis[r], t[r]][col]
        });
        tlas[i] = Some(wgpu::TlasInstance::new(blas, rows, i as u32, 0xff));
    }
    let mut enc = device.create_command_encoder(&Default::default());
    enc.build_acceleration_structures(std::iter::empty(), std::iter::once(&tlas));
    ctx.queue.submit([enc.finish()]);
    ctx.wait()?;
    // Uncompacted BLASes were given back by the wait above.
    let bytes = allocated(device, &ours);
    let triangles = models.iter().map(|m| (m.opaque + m.mixed) as u64).sum();
    Ok(RqStructures {
        tlas,
        blases,
        bytes,
        built_bytes,
        triangles,
        build_seconds: start.elapsed().as_secs_f64(),
    })
}

/// Bytes the device's allocator holds under labels starting `prefix`
/// (`None` where it reports none by name).
fn allocated(device: &wgpu::Device, prefix: &str) -> Option<u64> {
    let r = device.generate_allocator_report()?;
    let ours = r.allocations.iter().filter(|a| a.name.starts_with(prefix));
    let (n, total) = ours.fold((0, 0), |(n, s), a| (n + 1, s + a.size));
    (n > 0).then_some(total)
}
