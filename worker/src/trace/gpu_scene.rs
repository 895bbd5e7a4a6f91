//! The scene on the GPU: models' triangles, materials and textures, both
//! acceleration levels flattened into one node array, and instances.

use super::rq::{self, RqModel, RqStructures};
use crate::gpu::GpuContext;
use crate::lighting::clouds::CloudGrid;
use crate::lighting::lb::forest::GroundLight;
use bytemuck::{Pod, Zeroable};
use sylva_accel::bvh::{self, BvhNode};
use sylva_accel::coverage::{self, Coverage, Micromap, OpacityMaps};
use sylva_accel::cwbvh::{self, Cwbvh, CwbvhNode, CwbvhScene};
use sylva_accel::triangle::TriangleRecord;
use sylva_accel::{Accel, KdNode, SceneAccel};
use sylva_light::lb::LbGrid;
use sylva_scene::Scene;
use sylva_scene::frame::Backend;
use wgpu::util::DeviceExt;

/// What rays traverse, as the upload receives it: Sylva's own two levels
/// (walked by the compute kernel), or each model's triangle coverage, from
/// which the device builds its own structures (ray queries).
#[derive(Clone, Copy)]
pub enum SceneStructure<'a> {
    /// A kd-tree or BVH over both levels.
    Walk(&'a SceneAccel),
    /// The eight-wide compressed BVH derived from a BVH over both levels
    /// (derived as the scene goes up).
    Cwbvh(&'a SceneAccel),
    /// Per model, each triangle's coverage class (which BLAS geometry it
    /// goes to, or none).
    RayQuery(&'a [Vec<Coverage>]),
}

impl SceneStructure<'_> {
    /// The backend that traces it.
    pub fn backend(&self) -> Backend {
        match self {
            SceneStructure::Walk(a) => a.kind.into(),
            SceneStructure::Cwbvh(_) => Backend::Cwbvh,
            SceneStructure::RayQuery(_) => Backend::Rq,
        }
    }
}

/// `ACCEL_KIND` in the WGSL for a backend.
pub fn accel_kind(backend: Backend) -> u32 {
    match backend {
        // `auto` walks the BVH until its worker resolves it (`Backend::structure`).
        Backend::Auto | Backend::Bvh => 0,
        Backend::Kd => 1,
        Backend::Rq => 2,
        Backend::Cwbvh => 3,
    }
}

/// Stack entries of the GPU's BVH traversal, both levels together
/// (`BVH_STACK` in the WGSL, generated from this).
pub const GPU_BVH_STACK: usize = 96;
/// A material's texture index when it has none (`NO_TEXTURE` in the WGSL).
pub const NO_TEXTURE: u32 = u32::MAX;
/// Entries (16 bytes) of one wide BVH node.
const NODE_ENTRIES: u32 = (size_of::<BvhNode>() / 16) as u32;
/// Entries of one opacity micromap.
const MICROMAP_ENTRIES: u32 = (size_of::<Micromap>() / 16) as u32;
/// Entries of one triangle record (`test_record` in scene.wgsl reads three).
const RECORD_ENTRIES: u32 = (size_of::<TriangleRecord>() / 16) as u32;

/// A BVH child reference placed in the node buffer: an inner node at
/// `base` (its structure's first entry) plus its index times the node's
/// entries, a leaf at its records (`stride` entries each from `records_at`).
fn placed(reference: u32, base: u32, records_at: u32, stride: u32) -> u32 {
    match reference {
        bvh::EMPTY => bvh::EMPTY,
        r if r & bvh::LEAF != 0 => bvh::LEAF | (records_at + stride * (r & !bvh::LEAF)),
        inner => base + inner * NODE_ENTRIES,
    }
}

/// A material as `scene.wgsl` reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuMaterial {
    /// Linear RGBA multiplier.
    pub base_color: [f32; 4],
    /// Texture index, or `NO_TEXTURE`.
    pub texture: u32,
    /// Alpha cutoff; negative for opaque.
    pub alpha_cutoff: f32,
    /// 1 when both faces are lit.
    pub double_sided: u32,
    /// 0 leaf, 1 wood.
    pub surface: u32,
}

/// A texture's place in the texel array.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuTexture {
    /// First texel.
    pub offset: u32,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Padding.
    pub pad: u32,
}

/// A triangle: global vertex indices and material.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuTriangle {
    /// Vertex indices.
    pub v: [u32; 3],
    /// Global material index.
    pub material: u32,
}

/// An instance.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuInstance {
    /// World to model space: rows of a 3 × 4 affine matrix.
    pub to_model: [[f32; 4]; 3],
    /// Model space to the LB lookup frame: the instance's rotation (rows).
    pub to_lb: [[f32; 4]; 3],
    /// Model index.
    pub model: u32,
    /// Scale of the LB light at this instance.
    pub lb_scale: f32,
    /// Padding.
    pub pad: [u32; 2],
}

/// A model: its root node and LB grid.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuModel {
    /// Root node of its acceleration structure.
    pub root: u32,
    /// First value of its LB grid in the LB buffer.
    pub lb_offset: u32,
    /// 1 when the model has an LB grid.
    pub has_lb: u32,
    /// Ray queries: its first entry in `rq_triangles`.
    pub rq_first: u32,
    /// Corner of LB node (0, 0, 0), model space.
    pub lb_origin: [f32; 3],
    /// LB cell size.
    pub lb_cell: f32,
    /// LB nodes per axis.
    pub lb_dims: [u32; 3],
    /// Ray queries: its opaque triangles (its BLAS's geometry 0).
    pub rq_opaque: u32,
    /// Boulanger optical thickness τ = ρA/2 of its foliage.
    pub tau: f32,
    /// Leaves per unit volume of its envelope.
    pub leaf_density: f32,
    /// Mean leaf area.
    pub leaf_area: f32,
    /// 1 when its leaves have envelope distances.
    pub has_envelope: u32,
    /// Boulanger et al.: its leaves' mean albedo, linear RGB (the
    /// neighbours whose scattered sun light reaches its wood).
    pub leaf_albedo: [f32; 3],
    /// Padding.
    pub pad2: u32,
}

/// A cloud as `scene.wgsl` reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuCloud {
    /// Lower corner of its cube.
    pub min: [f32; 3],
    /// Cube edge.
    pub size: f32,
    /// Grid size N; 0 marks the placeholder of a scene without clouds.
    pub n: u32,
    /// Its first value in the cloud data.
    pub offset: u32,
    /// Extinction per unit length at density 1.
    pub extinction: f32,
    /// Scattering albedo σ_s / σ_t.
    pub albedo: f32,
    /// Henyey–Greenstein asymmetry of its medium (the reference integrator's phase function).
    pub g: f32,
    pub pad: [u32; 3],
}

/// The solved light a scene is uploaded with.
#[derive(Clone, Debug, Default)]
pub struct SceneLight {
    /// Per model, its LB grid if solved.
    pub models: Vec<Option<LbGrid>>,
    /// Per instance, the scale of its model's LB light (missing: 1).
    pub instance_scales: Vec<f32>,
    /// Clouds.
    pub clouds: Vec<CloudGrid>,
    /// Per model, its Boulanger leaf envelope if precomputed.
    pub envelopes: Vec<Option<std::sync::Arc<sylva_light::boulanger::LeafEnvelope>>>,
    /// The indirect light under the stand, read by the ground (grounded LB).
    pub ground: Option<GroundLight>,
}

/// The scene's buffers and the bind group (group 0) every tracer kernel uses.
pub struct GpuScene {
    /// Bind group layout of group 0.
    pub layout: wgpu::BindGroupLayout,
    /// Group 0.
    pub bind_group: wgpu::BindGroup,
    /// Global index of each model's first triangle.
    pub triangle_offsets: Vec<u32>,
    /// Bytes uploaded, with the device's structures where it built them.
    pub bytes: u64,
    /// How rays traverse it.
    pub backend: Backend,
    /// The device's structures (ray queries only).
    pub rq: Option<RqStructures>,
    /// Where the ground's light lies in the LB buffer: `(origin x, origin z,
    /// cell, 0)` and `(nx, nz, offset, 1)`; all zero when there is none.
    pub ground: ([f32; 4], [u32; 4]),
    /// What a new sun's light needs to go up without the rest
    /// ([`GpuScene::relit`]); none with ray queries.
    relight: Option<Relight>,
    /// Bytes of what rays walk on the device: both levels' nodes and
    /// records, and the kd-tree's primitive lists (0 with ray queries).
    pub structure_bytes: u64,
}

/// A walked scene's buffers (group 0's, in binding order) and the parts
/// of its flat arrays the light is written into.
struct Relight {
    buffers: Vec<wgpu::Buffer>,
    instances: Vec<GpuInstance>,
    models: Vec<GpuModel>,
    lb_len: usize,
    envelopes: bool,
}

/// Group 0's bindings that hold light: instances (their LB scale), LB
/// grids, clouds and the clouds' data.
const LIGHT_BINDINGS: [usize; 4] = [8, 10, 11, 12];

/// The flat arrays before upload.
#[derive(Default)]
struct Flat {
    nodes: Vec<[u32; 4]>,
    prims: Vec<u32>,
    positions: Vec<f32>,
    uvs: Vec<[f32; 2]>,
    triangles: Vec<GpuTriangle>,
    materials: Vec<GpuMaterial>,
    textures: Vec<GpuTexture>,
    texels: Vec<u32>,
    instances: Vec<GpuInstance>,
    models: Vec<GpuModel>,
    lb: Vec<f32>,
    clouds: Vec<GpuCloud>,
    cloud_data: Vec<f32>,
    envelope: Vec<f32>,
    /// Ray queries: per model, its triangles in BLAS order.
    rq_models: Vec<RqModel>,
    /// Ray queries: model-local vertex indices, three per triangle, in BLAS order.
    rq_indices: Vec<u32>,
    /// Ray queries: the global triangle of each, in BLAS order.
    rq_triangles: Vec<u32>,
}

impl Flat {
    /// Appends one level's structure; returns the entries of its root and
    /// of its first leaf record. A kd-tree's leaves list primitives (plus
    /// `prim_shift`) in `prims`; a BVH's leaves point at `records`
    /// (`stride` entries each, in the BVH's slot order), which follow its
    /// nodes.
    fn push_accel(
        &mut self,
        accel: &Accel,
        prim_shift: u32,
        records: &[[u32; 4]],
        stride: u32,
    ) -> anyhow::Result<(u32, u32)> {
        let prim_base = self.prims.len() as u32;
        Ok(match accel {
            Accel::Bvh(b) => {
                let base = self.nodes.len() as u32;
                let nodes: &[BvhNode] = if b.nodes.is_empty() {
                    std::slice::from_ref(&BvhNode::EMPTY)
                } else {
                    &b.nodes
                };
                let record_base = base + nodes.len() as u32 * NODE_ENTRIES;
                anyhow::ensure!(
                    record_base as usize + records.len() < bvh::LEAF as usize,
                    "the scene's BVH is too large to address"
                );
                for n in nodes {
                    let mut n = *n;
                    n.child = n.child.map(|c| placed(c, base, record_base, stride));
                    self.nodes.extend_from_slice(bytemuck::cast_slice::<BvhNode, [u32; 4]>(
                        std::slice::from_ref(&n),
                    ));
                }
                self.nodes.extend_from_slice(records);
                (base, record_base)
            }
            Accel::Kd(k) => {
                let [x0, y0, z0] = k.bounds.min.to_array().map(f32::to_bits);
                let [x1, y1, z1] = k.bounds.max.to_array().map(f32::to_bits);
                self.nodes.push([x0, y0, z0, 0]);
                self.nodes.push([x1, y1, z1, 0]);
                let base = self.nodes.len() as u32;
                for n in &k.nodes {
                    let first =
                        if n.axis == KdNode::LEAF { n.first + prim_base } else { n.first + base };
                    self.nodes.push([n.split.to_bits(), n.axis, first, n.count]);
                }
                self.prims.extend(k.prims.iter().map(|p| p + prim_shift));
                (base, 0)
            }
        })
    }
}

impl Flat {
    /// Appends one level's eight-wide tree and its `records` (`stride`
    /// entries each, in the tree's order) after its nodes; returns the
    /// entries of its root and of its first record.
    fn push_cwbvh(
        &mut self,
        tree: &Cwbvh,
        records: &[[u32; 4]],
        stride: u32,
    ) -> anyhow::Result<(u32, u32)> {
        let base = self.nodes.len() as u32;
        let empty = CwbvhNode::zeroed();
        let nodes = if tree.nodes.is_empty() { std::slice::from_ref(&empty) } else { &tree.nodes };
        let records_at = base as u64 + nodes.len() as u64 * cwbvh::NODE_ENTRIES as u64;
        // Groups flag nodes in bits 30 and 31 of an entry's index.
        anyhow::ensure!(
            records_at + (records.len() as u64) < cwbvh::VISIT as u64,
            "the scene's compressed wide BVH is too large to address"
        );
        let records_at = records_at as u32;
        for n in nodes {
            let n = CwbvhNode {
                // Inner children as entries (the walk adds NODE_ENTRIES a slot).
                child_base: base + n.child_base * cwbvh::NODE_ENTRIES,
                record_base: records_at + n.record_base * stride,
                ..*n
            };
            self.nodes.extend_from_slice(bytemuck::cast_slice::<CwbvhNode, [u32; 4]>(
                std::slice::from_ref(&n),
            ));
        }
        self.nodes.extend_from_slice(records);
        Ok((base, records_at))
    }
}

impl Flat {
    /// wgpu refuses empty bindings: gives every array at least one element.
    fn pad(&mut self) {
        if self.textures.is_empty() {
            self.textures.push(GpuTexture::zeroed());
        }
        if self.texels.is_empty() {
            self.texels.push(0);
        }
        if self.prims.is_empty() {
            self.prims.push(0);
        }
        if self.lb.is_empty() {
            self.lb.push(0.0);
        }
        if self.clouds.is_empty() {
            self.clouds.push(GpuCloud::zeroed());
        }
        if self.cloud_data.is_empty() {
            self.cloud_data.push(0.0);
        }
        if self.envelope.is_empty() {
            self.envelope.push(0.0);
        }
        if self.rq_indices.is_empty() {
            self.rq_indices.extend([0; 3]);
        }
        if self.rq_triangles.is_empty() {
            self.rq_triangles.push(0);
        }
    }
}

impl GpuScene {
    /// Uploads `scene` with what its rays traverse and its solved light.
    pub fn upload(
        ctx: &GpuContext,
        scene: &Scene,
        structure: SceneStructure,
        light: &SceneLight,
    ) -> anyhow::Result<Self> {
        match structure {
            SceneStructure::Walk(accel) => Self::upload_walk(ctx, scene, accel, light),
            SceneStructure::Cwbvh(accel) => {
                let wide = CwbvhScene::from_accel(scene, accel)?;
                Self::upload_cwbvh(ctx, scene, &wide, light)
            }
            SceneStructure::RayQuery(coverage) => Self::upload_rq(ctx, scene, coverage, light),
        }
    }

    /// The ray-query upload: the scene's data as for the walk, without
    /// nodes, and the device's structures built over its triangles.
    fn upload_rq(
        ctx: &GpuContext,
        scene: &Scene,
        coverage: &[Vec<Coverage>],
        light: &SceneLight,
    ) -> anyhow::Result<Self> {
        anyhow::ensure!(
            ctx.has_ray_queries(),
            "{} offers no ray queries: choose --accel bvh, cwbvh or kd (or auto)",
            ctx.adapter_name()
        );
        anyhow::ensure!(coverage.len() == scene.models.len(), "one coverage list per model");
        let mut f = Flat::default();
        // The walk's node buffer is bound but unread.
        f.nodes.push([0; 4]);
        let mut triangle_offsets = Vec::with_capacity(scene.models.len());
        for (m, (sm, cov)) in scene.models.iter().zip(coverage).enumerate() {
            anyhow::ensure!(
                cov.len() == sm.model.triangle_count(),
                "coverage of model {} has the wrong size",
                sm.name
            );
            let tri0 = f.triangles.len() as u32;
            let (order, opaque) = rq::blas_order(cov);
            let rm = RqModel {
                vert0: (f.positions.len() / 3) as u32,
                vertices: sm.model.positions.len() as u32,
                first: f.rq_triangles.len() as u32,
                opaque,
                mixed: order.len() as u32 - opaque,
            };
            f.rq_triangles.extend(order.iter().map(|t| tri0 + t));
            f.rq_indices.extend(order.iter().flat_map(|&t| sm.model.triangles[t as usize]));
            push_model(&mut f, m, sm, ModelTree::None, light)?;
            let gm = f.models.last_mut().expect("pushed");
            (gm.rq_first, gm.rq_opaque) = (rm.first, rm.opaque);
            f.rq_models.push(rm);
            triangle_offsets.push(tri0);
        }
        let to_model: Vec<glam::Affine3A> =
            scene.instances.iter().map(|i| i.to_world.inverse()).collect();
        push_instances(&mut f, scene, &to_model, &light.instance_scales);
        push_clouds(&mut f, &light.clouds)?;
        let ground = push_ground(&mut f, light)?;
        let instances: Vec<(glam::Affine3A, u32)> =
            scene.instances.iter().map(|i| (i.to_world, i.model)).collect();
        let mut scene = Self::create(ctx, f, triangle_offsets, Backend::Rq, &instances)?;
        scene.ground = ground;
        Ok(scene)
    }

    /// The compute walk's upload: both levels flattened into the node buffer.
    fn upload_walk(
        ctx: &GpuContext,
        scene: &Scene,
        accel: &SceneAccel,
        light: &SceneLight,
    ) -> anyhow::Result<Self> {
        let lb_scales = &light.instance_scales;
        let mut f = Flat::default();
        if let Accel::Bvh(top) = &accel.top {
            // The top level's entries, one part's remainder, then a model's.
            let deepest_model = accel
                .models
                .iter()
                .map(|m| if let Accel::Bvh(b) = m { b.stack_depth } else { 0 })
                .max()
                .unwrap_or(0);
            let need = top.stack_depth + 1 + deepest_model;
            anyhow::ensure!(
                need <= GPU_BVH_STACK,
                "the scene's BVH needs {need} stack entries, more than the GPU traversal's {GPU_BVH_STACK}"
            );
        }
        // With a BVH the top level's leaves hold instance parts, one entry
        // each: (instance, entry of its subtree, leaf count, 0), the entry
        // patched once the models' places are known.
        let top_records: Vec<[u32; 4]> = match &accel.top {
            Accel::Bvh(b) => {
                b.prims.iter().map(|&p| bytemuck::cast(accel.parts[p as usize])).collect()
            }
            Accel::Kd(_) => Vec::new(),
        };
        let (top_root, parts_at) = f.push_accel(&accel.top, 0, &top_records, 1)?;
        debug_assert_eq!(top_root, if matches!(accel.top, Accel::Kd(_)) { 2 } else { 0 });
        let mut model_places = Vec::with_capacity(scene.models.len());
        let mut triangle_offsets = Vec::with_capacity(scene.models.len());
        for (m, sm) in scene.models.iter().enumerate() {
            let (tri0, root, records_at) =
                push_model(&mut f, m, sm, ModelTree::Walk(accel), light)?;
            triangle_offsets.push(tri0);
            model_places.push((root, records_at));
        }
        for k in 0..top_records.len() {
            let e = &mut f.nodes[parts_at as usize + k];
            let (root, records_at) = model_places[scene.instances[e[0] as usize].model as usize];
            e[1] = placed(e[1], root, records_at, RECORD_ENTRIES);
        }
        push_instances(&mut f, scene, &accel.to_model, lb_scales);
        push_clouds(&mut f, &light.clouds)?;
        let ground = push_ground(&mut f, light)?;
        let mut scene = Self::create(ctx, f, triangle_offsets, accel.kind.into(), &[])?;
        scene.ground = ground;
        Ok(scene)
    }

    /// The eight-wide walk's upload: both levels' trees flattened into the
    /// node buffer, each followed by its records (instance parts at the
    /// top, whose start groups are placed once the models' places are
    /// known; triangle records in a model).
    fn upload_cwbvh(
        ctx: &GpuContext,
        scene: &Scene,
        wide: &CwbvhScene,
        light: &SceneLight,
    ) -> anyhow::Result<Self> {
        let need = wide.stack_need();
        anyhow::ensure!(
            need <= cwbvh::MAX_STACK,
            "the scene's compressed wide BVH needs {need} stack entries, more than the GPU walk's {} (use --accel bvh)",
            cwbvh::MAX_STACK
        );
        let mut f = Flat::default();
        let parts: Vec<[u32; 4]> = wide.parts.iter().map(|p| bytemuck::cast(*p)).collect();
        let (top_root, parts_at) = f.push_cwbvh(&wide.top, &parts, 1)?;
        debug_assert_eq!(top_root, 0);
        let mut model_places = Vec::with_capacity(scene.models.len());
        let mut triangle_offsets = Vec::with_capacity(scene.models.len());
        for (m, sm) in scene.models.iter().enumerate() {
            let (tri0, root, records_at) =
                push_model(&mut f, m, sm, ModelTree::Cwbvh(wide), light)?;
            triangle_offsets.push(tri0);
            model_places.push((root, records_at));
        }
        for k in 0..parts.len() {
            let e = &mut f.nodes[parts_at as usize + k];
            let (root, records_at) = model_places[scene.instances[e[0] as usize].model as usize];
            e[1] = if e[1] & cwbvh::VISIT != 0 {
                cwbvh::VISIT | (root + (e[1] & !cwbvh::VISIT) * cwbvh::NODE_ENTRIES)
            } else {
                records_at + e[1] * RECORD_ENTRIES
            };
        }
        push_instances(&mut f, scene, &wide.to_model, &light.instance_scales);
        push_clouds(&mut f, &light.clouds)?;
        let ground = push_ground(&mut f, light)?;
        let mut scene = Self::create(ctx, f, triangle_offsets, Backend::Cwbvh, &[])?;
        scene.ground = ground;
        Ok(scene)
    }

    /// The buffers and the bind group; with ray queries, the device's
    /// structures over `instances` (to world, model) too.
    fn create(
        ctx: &GpuContext,
        mut f: Flat,
        triangle_offsets: Vec<u32>,
        backend: Backend,
        instances: &[(glam::Affine3A, u32)],
    ) -> anyhow::Result<Self> {
        let device = &ctx.device;
        f.pad();
        let rq = backend == Backend::Rq;
        let structure_bytes = if rq { 0 } else { (f.nodes.len() * 16 + f.prims.len() * 4) as u64 };
        let light_parts = (!rq)
            .then(|| (f.instances.clone(), f.models.clone(), f.lb.len(), f.envelope.len() > 1));
        let mut bytes = 0u64;
        let mut buffer = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            bytes += contents.len() as u64;
            anyhow::ensure!(
                contents.len() as u64 <= ctx.limits.max_storage_buffer_binding_size,
                "scene {label} needs {} bytes, more than this GPU's {}-byte storage-binding limit",
                contents.len(),
                ctx.limits.max_storage_buffer_binding_size
            );
            Ok(device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            }))
        };
        let storage = wgpu::BufferUsages::STORAGE;
        // The device's structures read the positions as vertices.
        let positions_usage = if rq { storage | wgpu::BufferUsages::BLAS_INPUT } else { storage };
        let mut buffers = vec![
            buffer("nodes", bytemuck::cast_slice(&f.nodes), storage)?,
            buffer("prims", bytemuck::cast_slice(&f.prims), storage)?,
            buffer("positions", bytemuck::cast_slice(&f.positions), positions_usage)?,
            buffer("uvs", bytemuck::cast_slice(&f.uvs), storage)?,
            buffer("triangles", bytemuck::cast_slice(&f.triangles), storage)?,
            buffer("materials", bytemuck::cast_slice(&f.materials), storage)?,
            buffer("textures", bytemuck::cast_slice(&f.textures), storage)?,
            buffer("texels", bytemuck::cast_slice(&f.texels), storage)?,
            buffer("instances", bytemuck::cast_slice(&f.instances), storage)?,
            buffer("models", bytemuck::cast_slice(&f.models), storage)?,
            buffer("lb", bytemuck::cast_slice(&f.lb), storage)?,
            buffer("clouds", bytemuck::cast_slice(&f.clouds), storage)?,
            buffer("cloud data", bytemuck::cast_slice(&f.cloud_data), storage)?,
            buffer("leaf envelopes", bytemuck::cast_slice(&f.envelope), storage)?,
        ];
        let rq_structures = if rq {
            let indices = buffer(
                "rq indices",
                bytemuck::cast_slice(&f.rq_indices),
                wgpu::BufferUsages::BLAS_INPUT,
            )?;
            let s = rq::build(ctx, &buffers[2], &indices, &f.rq_models, instances)?;
            // Binding 15 (binding 14 is the TLAS).
            buffers.push(buffer("rq triangles", bytemuck::cast_slice(&f.rq_triangles), storage)?);
            Some(s)
        } else {
            None
        };
        let binding_of = |i: usize| if rq && i >= 14 { i as u32 + 1 } else { i as u32 };
        debug_assert_eq!(buffers.len(), if rq { 15 } else { 14 });
        let layout = Self::layout_for(device, backend);
        let mut bg_entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: binding_of(i),
                resource: b.as_entire_binding(),
            })
            .collect();
        if let Some(s) = &rq_structures {
            bg_entries.push(wgpu::BindGroupEntry { binding: 14, resource: s.tlas.as_binding() });
        }
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &layout,
            entries: &bg_entries,
        });
        let relight = light_parts.map(|(instances, models, lb_len, envelopes)| Relight {
            buffers: buffers.clone(),
            instances,
            models,
            lb_len,
            envelopes,
        });
        Ok(Self {
            layout,
            bind_group,
            triangle_offsets,
            bytes: bytes + rq_structures.as_ref().and_then(|s| s.bytes).unwrap_or(0),
            backend,
            rq: rq_structures,
            ground: ([0.0; 4], [0; 4]),
            relight,
            structure_bytes,
        })
    }

    /// This scene under new light (a new sun's LB grids, instance scales,
    /// ground and clouds), sharing every other buffer with it: a sun
    /// sweep sends the device its light, not its structures again. `None`
    /// where the light does not fit this scene's places (other grids,
    /// envelopes, ray queries): upload the scene whole.
    pub fn relit(&self, ctx: &GpuContext, light: &SceneLight) -> anyhow::Result<Option<Self>> {
        let Some(r) = &self.relight else { return Ok(None) };
        if r.envelopes || light.envelopes.iter().any(Option::is_some) {
            return Ok(None);
        }
        let mut f = Flat::default();
        for (m, gm) in r.models.iter().enumerate() {
            match light.models.get(m).and_then(Option::as_ref) {
                Some(g) => {
                    let d = g.dims;
                    let same = gm.has_lb == 1
                        && gm.lb_offset as usize == f.lb.len()
                        && gm.lb_dims == [d.nx as u32, d.ny as u32, d.nz as u32]
                        && gm.lb_origin == g.frame.origin
                        && gm.lb_cell == g.frame.cell
                        && g.rgb.len() == 3 * d.len();
                    if !same {
                        return Ok(None);
                    }
                    f.lb.extend_from_slice(&g.rgb);
                }
                None if gm.has_lb == 0 => {}
                None => return Ok(None),
            }
        }
        let ground = push_ground(&mut f, light)?;
        push_clouds(&mut f, &light.clouds)?;
        f.pad();
        if f.lb.len() != r.lb_len {
            return Ok(None);
        }
        let mut instances = r.instances.clone();
        for (i, inst) in instances.iter_mut().enumerate() {
            inst.lb_scale = light.instance_scales.get(i).copied().unwrap_or(1.0);
        }
        let contents: [&[u8]; 4] = [
            bytemuck::cast_slice(&instances),
            bytemuck::cast_slice(&f.lb),
            bytemuck::cast_slice(&f.clouds),
            bytemuck::cast_slice(&f.cloud_data),
        ];
        let mut buffers = r.buffers.clone();
        for (b, bytes) in LIGHT_BINDINGS.into_iter().zip(contents) {
            anyhow::ensure!(
                bytes.len() as u64 <= ctx.limits.max_storage_buffer_binding_size,
                "the scene's light needs {} bytes, more than this GPU's storage-binding limit",
                bytes.len()
            );
            buffers[b] = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("scene light"),
                contents: bytes,
                usage: wgpu::BufferUsages::STORAGE,
            });
        }
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &self.layout,
            entries: &entries,
        });
        Ok(Some(Self {
            layout: self.layout.clone(),
            bind_group,
            triangle_offsets: self.triangle_offsets.clone(),
            bytes: self.bytes,
            backend: self.backend,
            rq: None,
            ground,
            structure_bytes: self.structure_bytes,
            relight: Some(Relight {
                buffers,
                instances,
                models: r.models.clone(),
                lb_len: r.lb_len,
                envelopes: false,
            }),
        }))
    }

    /// Group 0's layout for a scene traced by `backend`: 14 storage buffers
    /// (bindings 0–13), and with ray queries the TLAS (14) and the BLAS
    /// order's triangles (15). Alike layouts are one to wgpu, so kernels
    /// can be built from this before any scene is uploaded.
    pub fn layout_for(device: &wgpu::Device, backend: Backend) -> wgpu::BindGroupLayout {
        let storage = |binding| crate::gpu::storage_entry(binding, true);
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> = (0..14).map(storage).collect();
        if backend == Backend::Rq {
            entries.push(wgpu::BindGroupLayoutEntry {
                binding: 14,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::AccelerationStructure { vertex_return: false },
                count: None,
            });
            entries.push(storage(15));
        }
        device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("scene"),
            entries: &entries,
        })
    }

    /// `ACCEL_KIND` for pipelines over this scene.
    pub fn accel_kind(&self) -> u32 {
        accel_kind(self.backend)
    }
}

/// The ground's light under the stand into the LB buffer: where it lies,
/// `(origin x, origin z, cell, 0)` and `(nx, nz, offset, 1)`; zeros when
/// there is none.
fn push_ground(f: &mut Flat, light: &SceneLight) -> anyhow::Result<([f32; 4], [u32; 4])> {
    let Some(g) = &light.ground else { return Ok(([0.0; 4], [0; 4])) };
    anyhow::ensure!(
        g.nx >= 2 && g.nz >= 2 && g.rgb.len() == 3 * g.nx * g.nz,
        "the ground's light has the wrong size"
    );
    let place =
        ([g.origin[0], g.origin[1], g.cell, 0.0], [g.nx as u32, g.nz as u32, f.lb.len() as u32, 1]);
    f.lb.extend_from_slice(&g.rgb);
    Ok(place)
}

/// What rays walk in a model, as [`push_model`] flattens it.
#[derive(Clone, Copy)]
enum ModelTree<'a> {
    /// Nothing (ray queries: the device builds its own).
    None,
    /// The model's kd-tree or BVH.
    Walk(&'a SceneAccel),
    /// The model's eight-wide compressed BVH.
    Cwbvh(&'a CwbvhScene),
}

/// One model into the flat buffers: with a BVH, its opacity micromaps and
/// then its structure and records (placed after the triangles before
/// it); its vertices, triangles, materials, textures, LB grid and
/// Boulanger envelope. Returns its first triangle, its structure's root
/// and where its records start (zeros without one).
fn push_model(
    f: &mut Flat,
    m: usize,
    sm: &sylva_scene::SceneModel,
    tree: ModelTree,
    light: &SceneLight,
) -> anyhow::Result<(u32, u32, u32)> {
    let model = &sm.model;
    let (tri0, vert0) = (f.triangles.len() as u32, (f.positions.len() / 3) as u32);
    let (mat0, tex0) = (f.materials.len() as u32, f.textures.len() as u32);
    // The model's micromaps, then its triangle records, numbered globally
    // (an opacity word names its map's entry).
    let maps_at = f.nodes.len() as u32;
    let mut records = |records: Option<&Vec<TriangleRecord>>, opacity: Option<&OpacityMaps>| {
        if let Some(o) = opacity {
            f.nodes
                .extend(o.maps.iter().flat_map(|m| bytemuck::cast::<Micromap, [[u32; 4]; 4]>(*m)));
        }
        records
            .map_or(&[][..], |r| r.as_slice())
            .iter()
            .flat_map(|r| {
                let opacity = match r.opacity {
                    coverage::OPAQUE => coverage::OPAQUE,
                    map => maps_at + MICROMAP_ENTRIES * map,
                };
                let r = TriangleRecord {
                    triangle: r.triangle + tri0,
                    material: r.material + mat0,
                    opacity,
                    ..*r
                };
                bytemuck::cast::<TriangleRecord, [[u32; 4]; 3]>(r)
            })
            .collect::<Vec<[u32; 4]>>()
    };
    let (root, records_at) = match tree {
        ModelTree::Walk(accel) => {
            let r = records(accel.records.get(m), accel.opacity.get(m));
            f.push_accel(&accel.models[m], tri0, &r, RECORD_ENTRIES)?
        }
        ModelTree::Cwbvh(wide) => {
            let r = records(wide.records.get(m), wide.opacity.get(m));
            f.push_cwbvh(&wide.models[m], &r, RECORD_ENTRIES)?
        }
        ModelTree::None => (0, 0),
    };
    f.positions.extend(model.positions.iter().flat_map(|p| p.to_array()));
    f.uvs.extend(model.uvs.iter().map(|uv| uv.to_array()));
    f.triangles.extend(
        model
            .triangles
            .iter()
            .zip(&model.material)
            .map(|(t, &mat)| GpuTriangle { v: t.map(|i| i + vert0), material: mat + mat0 }),
    );
    f.materials.extend(model.materials.iter().map(|mt| GpuMaterial {
        base_color: mt.base_color,
        texture: mt.texture.map_or(NO_TEXTURE, |t| t + tex0),
        alpha_cutoff: mt.alpha_cutoff.unwrap_or(-1.0),
        double_sided: mt.double_sided as u32,
        surface: (mt.surface == sylva_scene::model::Surface::Wood) as u32,
    }));
    for t in &model.textures {
        f.textures.push(GpuTexture {
            offset: f.texels.len() as u32,
            width: t.width,
            height: t.height,
            pad: 0,
        });
        f.texels.extend(t.rgba.as_chunks::<4>().0.iter().map(|&p| u32::from_le_bytes(p)));
    }
    let mut gm = GpuModel { root, ..GpuModel::zeroed() };
    if let Some(Some(g)) = light.models.get(m) {
        let d = g.dims;
        anyhow::ensure!(
            d.nx >= 2 && d.ny >= 2 && d.nz >= 2 && g.rgb.len() == 3 * d.len(),
            "LB grid of model {} has the wrong size",
            sm.name
        );
        gm = GpuModel {
            root,
            lb_offset: f.lb.len() as u32,
            has_lb: 1,
            lb_origin: g.frame.origin,
            lb_cell: g.frame.cell,
            lb_dims: [d.nx as u32, d.ny as u32, d.nz as u32],
            ..GpuModel::zeroed()
        };
        f.lb.extend_from_slice(&g.rgb);
    }
    // Envelope distances are indexed by global triangle: eight per triangle.
    if light.envelopes.iter().any(|e| e.is_some()) {
        match light.envelopes.get(m).and_then(|e| e.as_ref()) {
            Some(e) => {
                anyhow::ensure!(
                    e.s_max.len() == model.triangles.len(),
                    "envelope of model {} has the wrong size",
                    sm.name
                );
                (gm.tau, gm.leaf_density, gm.leaf_area, gm.has_envelope, gm.leaf_albedo) =
                    (e.tau, e.leaf_density, e.leaf_area, 1, e.leaf_albedo);
                f.envelope.extend(e.s_max.iter().flatten());
            }
            None => f.envelope.extend(std::iter::repeat_n(0.0, 8 * model.triangles.len())),
        }
    }
    f.models.push(gm);
    Ok((tri0, root, records_at))
}

/// Each instance's transforms (world to model, and its orientation for
/// the LB grid) and the forest grid's scale of its light.
fn push_instances(f: &mut Flat, scene: &Scene, to_model: &[glam::Affine3A], lb_scales: &[f32]) {
    for (i, inst) in scene.instances.iter().enumerate() {
        let m = to_model[i];
        let c = [m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis];
        let to_model = std::array::from_fn(|r| [c[0][r], c[1][r], c[2][r], m.translation[r]]);
        // The instance's own orientation, scale removed.
        let w = inst.to_world.matrix3;
        let scale = w.determinant().abs().cbrt().max(f32::MIN_POSITIVE);
        let wc = [w.x_axis / scale, w.y_axis / scale, w.z_axis / scale];
        let to_lb = std::array::from_fn(|r| [wc[0][r], wc[1][r], wc[2][r], 0.0]);
        let lb_scale = lb_scales.get(i).copied().unwrap_or(1.0);
        f.instances.push(GpuInstance { to_model, to_lb, model: inst.model, lb_scale, pad: [0; 2] });
    }
}

/// The clouds' density and light grids, after checking their sizes.
fn push_clouds(f: &mut Flat, clouds: &[CloudGrid]) -> anyhow::Result<()> {
    for c in clouds {
        anyhow::ensure!(
            c.n >= 2 && c.density.len() == c.n.pow(3) && c.light.len() == 3 * c.n.pow(3),
            "cloud grid has the wrong size"
        );
        f.clouds.push(GpuCloud {
            min: c.min,
            size: c.size,
            n: c.n as u32,
            offset: f.cloud_data.len() as u32,
            extinction: c.sigma_t * c.n as f32 / c.size,
            albedo: c.albedo,
            g: c.g,
            pad: [0; 3],
        });
        f.cloud_data.extend_from_slice(&c.density);
        f.cloud_data.extend_from_slice(&c.light);
    }
    Ok(())
}
