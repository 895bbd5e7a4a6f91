//! Assembles the tracer's WGSL: the scene code shared by every entry
//! point, then one traversal backend: the compute walk (the kd-tree's
//! traversal template instantiated per level, the BVH's two-level loop) or
//! ray queries.

use sylva_scene::frame::Backend;

const SCENE: &str = include_str!("../../../shaders/trace/scene.wgsl");
const TRAVERSE: &str = include_str!("../../../shaders/trace/traverse.wgsl");
const BVH: &str = include_str!("../../../shaders/trace/bvh.wgsl");
const WALK: &str = include_str!("../../../shaders/trace/walk.wgsl");
const RQ: &str = include_str!("../../../shaders/trace/rq.wgsl");
const CWBVH: &str = include_str!("../../../shaders/trace/cwbvh.wgsl");

/// Invocations in every tracing entry point's workgroup: the compressed
/// wide BVH's stack in workgroup memory has a column per lane.
pub const TRACE_LANES: u32 = 64;

/// The constants the tracer's WGSL shares with the Rust that builds and
/// uploads what it reads, written from the Rust values so the two cannot
/// drift apart.
pub fn shared_constants() -> String {
    use sylva_accel::coverage;
    use sylva_accel::{KdNode, MIN_DIRECTION, bvh, cwbvh, kdtree};
    [
        // Direction components smaller than this are replaced by it.
        format!("const MIN_DIRECTION: f32 = {MIN_DIRECTION:e};"),
        // Entries of the wide BVH's traversal stack, both levels together;
        // the upload refuses deeper trees.
        format!("const BVH_STACK: u32 = {}u;", super::gpu_scene::GPU_BVH_STACK),
        // A wide BVH child reference: a leaf (its first record or prim
        // slot), or empty.
        format!("const BVH_LEAF: u32 = {}u;", bvh::LEAF),
        format!("const BVH_EMPTY: u32 = {}u;", bvh::EMPTY),
        // A triangle record's opacity micromap: micro-triangles per edge,
        // and the states that spare the alpha texel.
        format!("const MICRO_EDGE: u32 = {}u;", coverage::MICRO_EDGE),
        format!("const MICRO_OPAQUE: u32 = {}u;", coverage::MICRO_OPAQUE),
        format!("const MICRO_HOLE: u32 = {}u;", coverage::MICRO_HOLE),
        format!("const OPACITY_OPAQUE: u32 = {}u;", coverage::OPAQUE),
        format!("const SHORT_STACK: u32 = {}u;", kdtree::SHORT_STACK),
        // The compressed wide BVH: a group's flags, a node's entries, and
        // its stack (entries per lane, lanes).
        format!("const CW_LIST: u32 = {}u;", cwbvh::LIST),
        format!("const CW_VISIT: u32 = {}u;", cwbvh::VISIT),
        format!("const CW_NODE_ENTRIES: u32 = {}u;", cwbvh::NODE_ENTRIES),
        format!("const TRACE_LANES: u32 = {TRACE_LANES}u;"),
        format!("const CW_STACK_ENTRIES: u32 = {}u;", cwbvh::MAX_STACK as u32 * TRACE_LANES),
        format!("const KD_LEAF: u32 = {}u;", KdNode::LEAF),
        format!("const NO_TEXTURE: u32 = {}u;", super::gpu_scene::NO_TEXTURE),
        format!("const NO_HIT: u32 = {}u;", super::raycast::NO_HIT),
    ]
    .join("\n")
        + "\n"
}

/// How every tracing kernel is compiled: with `constants` (its overrides),
/// and without zeroing workgroup memory first (WGSL's default), which
/// for the compressed wide BVH's stack would write 16 KB a workgroup each
/// dispatch: the walk writes every stack entry before it reads it.
pub fn tracer_options<'a>(constants: &'a [(&'a str, f64)]) -> wgpu::PipelineCompilationOptions<'a> {
    wgpu::PipelineCompilationOptions { constants, zero_initialize_workgroup_memory: false }
}

/// The full module for an entry-point file's source, tracing with
/// `backend` (the kd-tree and the BVH share one module, chosen between by
/// the `ACCEL_KIND` override; ray queries need a module of their own,
/// which only a device with the feature accepts, and the compressed wide
/// BVH one whose stack in workgroup memory no other backend pays for).
pub fn tracer_source(entry: &str, backend: Backend) -> String {
    let constants = shared_constants();
    let mut s = String::with_capacity(
        constants.len() + SCENE.len() + 2 * TRAVERSE.len() + BVH.len() + WALK.len() + entry.len(),
    );
    if backend == Backend::Rq {
        // A directive must come before every declaration.
        s.push_str("enable wgpu_ray_query;\n");
    }
    s.push_str(&constants);
    s.push_str(SCENE);
    if backend == Backend::Rq {
        s.push('\n');
        s.push_str(RQ);
    } else if backend == Backend::Cwbvh {
        s.push('\n');
        s.push_str(CWBVH);
    } else {
        for level in ["top", "model"] {
            s.push('\n');
            s.push_str(&TRAVERSE.replace("LEVEL", level));
        }
        s.push('\n');
        s.push_str(BVH);
        s.push('\n');
        s.push_str(WALK);
    }
    s.push('\n');
    s.push_str(entry);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses and validates a module; panics with naga's message.
    pub fn validate(src: &str) -> naga::Module {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{}", e.emit_to_string(src)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(src)));
        module
    }

    #[test]
    fn ray_casting_and_render_modules_are_valid_wgsl() {
        for backend in [Backend::Bvh, Backend::Rq, Backend::Cwbvh] {
            validate(&tracer_source(include_str!("../../../shaders/trace/rays.wgsl"), backend));
            validate(&crate::trace::kernels::render_source(backend));
        }
    }

    /// Every tracing entry point's workgroup has `TRACE_LANES` lanes, the
    /// columns of the compressed wide BVH's stack, and sets its lane.
    #[test]
    fn every_tracing_entry_point_has_the_stacks_lanes() {
        for src in [
            tracer_source(include_str!("../../../shaders/trace/rays.wgsl"), Backend::Cwbvh),
            crate::trace::kernels::render_source(Backend::Cwbvh),
        ] {
            let m = validate(&src);
            for e in &m.entry_points {
                let [x, y, z] = e.workgroup_size;
                assert_eq!(x * y * z, TRACE_LANES, "{}", e.name);
                let body = &src[src.find(&format!("fn {}(", e.name)).expect("the entry")..];
                let body = &body[..body.find("\n}\n").expect("its end")];
                assert!(body.contains("trace_lane = "), "{} does not set its lane", e.name);
            }
        }
    }

    /// The WGSL structs the Rust side uploads have the Rust layouts.
    #[test]
    fn gpu_structs_match_their_rust_twins() {
        use crate::trace::{
            FrameUniform, GpuCloud, GpuInstance, GpuMaterial, GpuModel, GpuTexture, GpuTriangle,
        };
        let m = validate(&crate::trace::kernels::render_source(Backend::Bvh));
        let size_of_struct = |name: &str| -> u32 {
            let (_, ty) = m
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("no struct {name}"));
            match &ty.inner {
                naga::TypeInner::Struct { span, .. } => *span,
                _ => panic!("{name} is not a struct"),
            }
        };
        assert_eq!(size_of_struct("Material") as usize, size_of::<GpuMaterial>());
        assert_eq!(size_of_struct("Texture") as usize, size_of::<GpuTexture>());
        assert_eq!(size_of_struct("Triangle") as usize, size_of::<GpuTriangle>());
        assert_eq!(size_of_struct("Instance") as usize, size_of::<GpuInstance>());
        assert_eq!(size_of_struct("Model") as usize, size_of::<GpuModel>());
        assert_eq!(size_of_struct("Cloud") as usize, size_of::<GpuCloud>());
        assert_eq!(size_of_struct("Frame") as usize, size_of::<FrameUniform>());
    }
}
