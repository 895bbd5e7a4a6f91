// The scene as the tracer sees it: two levels (instances, then each
// model's triangles), Möller–Trumbore triangle tests and alpha-masked
// texels passed through. Prepended to every tracer entry point (rays.wgsl,
// render.wgsl) with one traversal backend after it: walk.wgsl (a
// four-wide BVH or a kd-tree with the short-stack algorithm, walked by
// the shader) or rq.wgsl (the device's own structures, through ray
// queries). Uploaded by worker/src/trace/gpu_scene.rs, whose #[repr(C)]
// structs these mirror (a test checks the offsets).
//
// The CPU reference is shared/accel/src: the same node layouts, the same
// traversal order, the same arithmetic.

// 0: BVH, 1: kd-tree, 2: ray queries, 3: the compressed wide BVH
// (accel_kind in gpu_scene.rs). Set when the pipeline is built.
override ACCEL_KIND: u32 = 0u;

// The constants (MIN_DIRECTION, BVH_*, MICRO_*, OPACITY_OPAQUE, CW_*,
// TRACE_LANES, SHORT_STACK, KD_LEAF, NO_TEXTURE, NO_HIT) come before this
// file, generated from their Rust twins (worker/src/trace/shaders.rs).

struct Material {
    base_color: vec4<f32>,
    texture: u32,
    // Texels with alpha below this are holes; negative: opaque.
    alpha_cutoff: f32,
    double_sided: u32,
    surface: u32,
}

struct Texture {
    offset: u32,
    width: u32,
    height: u32,
    pad: u32,
}

struct Triangle {
    v: vec3<u32>,
    material: u32,
}

struct Instance {
    // World to model space, rows of a 3 × 4 affine matrix.
    to_model: array<vec4<f32>, 3>,
    // Model space to where the model's LB grid is read: the instance's
    // rotation, so the side facing the sun reads the grid's sunlit side.
    to_lb: array<vec4<f32>, 3>,
    model: u32,
    // Scale of the LB light at this instance (the coarse forest grid).
    lb_scale: f32,
    pad0: u32,
    pad1: u32,
}

struct Model {
    root: u32,
    lb_offset: u32,
    has_lb: u32,
    // Ray queries: its first entry in rq_triangles (rq.wgsl).
    rq_first: u32,
    lb_origin: vec3<f32>,
    lb_cell: f32,
    // LB nodes per axis, fitted to the model's bounds.
    lb_dims: vec3<u32>,
    // Ray queries: how many of its triangles are opaque (its BLAS's
    // geometry 0; the mixed ones follow as geometry 1).
    rq_opaque: u32,
    // Boulanger et al.: optical thickness, leaf density and area of the foliage.
    tau: f32,
    leaf_density: f32,
    leaf_area: f32,
    has_envelope: u32,
    // Its leaves' mean albedo: the neighbours that light its wood.
    leaf_albedo: vec3<f32>,
    pad2: u32,
}

// Four-wide BVH nodes take four entries (the grid's origin and exponents,
// the four children's references, their boxes in 8-bit grid cells and
// their leaf counts: shared/accel/src/bvh/mod.rs), eight-wide ones five
// (shared/accel/src/cwbvh.rs); each model's triangle records take three
// (first vertex + triangle, edge 1 + opacity word, edge 2 + material),
// after its nodes, and its opacity micromaps four each, before them; kd
// nodes take one (split, axis, first, count). References are entry
// indices. The top level's root is entry 0.
@group(0) @binding(0) var<storage, read> nodes: array<vec4<u32>>;
// Leaf contents: instance indices (top level) and global triangle indices.
@group(0) @binding(1) var<storage, read> prims: array<u32>;
// Vertex positions, x y z packed.
@group(0) @binding(2) var<storage, read> positions: array<f32>;
@group(0) @binding(3) var<storage, read> uvs: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> triangles: array<Triangle>;
@group(0) @binding(5) var<storage, read> materials: array<Material>;
@group(0) @binding(6) var<storage, read> textures: array<Texture>;
// RGBA8 texels, sRGB colour, linear alpha.
@group(0) @binding(7) var<storage, read> texels: array<u32>;
@group(0) @binding(8) var<storage, read> instances: array<Instance>;
@group(0) @binding(9) var<storage, read> models: array<Model>;
// LB light per model (three channel planes of nx·ny·nz values, x fastest),
// then the ground's light under the stand (three planes of nx·nz).
@group(0) @binding(10) var<storage, read> lb_data: array<f32>;

struct Cloud {
    // Lower corner of the cloud's cube and its edge.
    min: vec3<f32>,
    size: f32,
    // Grid size N (0: no cloud).
    n: u32,
    // Density (N³ values), then three channel planes of LB light, in cloud_data.
    offset: u32,
    // Extinction per unit length at density 1: sigma_t / cell size.
    extinction: f32,
    // sigma_s / sigma_t.
    albedo: f32,
    // Henyey–Greenstein asymmetry (the reference integrator's phase function).
    g: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(11) var<storage, read> clouds: array<Cloud>;
@group(0) @binding(12) var<storage, read> cloud_data: array<f32>;
// Boulanger envelope distances s_max, eight per triangle (global index).
@group(0) @binding(13) var<storage, read> envelope: array<f32>;

struct Ray {
    origin: vec3<f32>,
    dir: vec3<f32>,
    inv_dir: vec3<f32>,
}

struct Hit {
    instance: u32,
    triangle: u32,
    t: f32,
    u: f32,
    v: f32,
}

fn safe_component(d: f32) -> f32 {
    if abs(d) < MIN_DIRECTION {
        return select(MIN_DIRECTION, -MIN_DIRECTION, d < 0.0 || (d == 0.0 && bitcast<u32>(d) != 0u));
    }
    return d;
}

fn make_ray(origin: vec3<f32>, dir: vec3<f32>) -> Ray {
    let d = vec3<f32>(safe_component(dir.x), safe_component(dir.y), safe_component(dir.z));
    return Ray(origin, d, 1.0 / d);
}

fn no_hit() -> Hit {
    return Hit(NO_HIT, NO_HIT, 0.0, 0.0, 0.0);
}

// The parameter interval inside a box, clipped to [t_min, t_max]; x > y
// when missed.
fn clip_box(bmin: vec3<f32>, bmax: vec3<f32>, ray: Ray, t_min: f32, t_max: f32) -> vec2<f32> {
    let t0 = (bmin - ray.origin) * ray.inv_dir;
    let t1 = (bmax - ray.origin) * ray.inv_dir;
    let lo = min(t0, t1);
    let hi = max(t0, t1);
    let near = max(max(max(lo.x, lo.y), lo.z), t_min);
    let far = min(min(min(hi.x, hi.y), hi.z), t_max);
    return vec2<f32>(near, far);
}

fn position(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        return c / 12.92;
    }
    return pow((c + 0.055) / 1.055, 2.4);
}

// The nearest texel of a texture at uv, wrapping; as the CPU's Texture::texel.
fn texel(tex: Texture, uv: vec2<f32>) -> vec4<f32> {
    let x = u32((uv.x - floor(uv.x)) * f32(tex.width)) % tex.width;
    let y = u32((uv.y - floor(uv.y)) * f32(tex.height)) % tex.height;
    let p = texels[tex.offset + y * tex.width + x];
    return vec4<f32>(f32(p & 0xffu), f32((p >> 8u) & 0xffu), f32((p >> 16u) & 0xffu), f32(p >> 24u)) / 255.0;
}

fn triangle_uv(tri: u32, u: f32, v: f32) -> vec2<f32> {
    let t = triangles[tri].v;
    return uvs[t.x] * (1.0 - u - v) + uvs[t.y] * u + uvs[t.z] * v;
}

fn is_transparent(tri: u32, uv: vec2<f32>) -> bool {
    return is_transparent_material(triangles[tri].material, uv);
}

fn is_transparent_material(material: u32, uv: vec2<f32>) -> bool {
    let m = materials[material];
    if m.alpha_cutoff < 0.0 {
        return false;
    }
    var alpha = m.base_color.a;
    if m.texture != NO_TEXTURE {
        alpha = texel(textures[m.texture], uv).a * m.base_color.a;
    }
    return alpha < m.alpha_cutoff;
}

// Möller–Trumbore; (t, u, v) with t < 0 when missed. Both faces count.
fn intersect_triangle(ray: Ray, tri: u32, t_min: f32, t_max: f32) -> vec3<f32> {
    let ix = triangles[tri].v;
    let a = position(ix.x);
    return intersect_edges(ray, a, position(ix.y) - a, position(ix.z) - a, t_min, t_max);
}

// As intersect_triangle, from the first vertex and the edges to the others.
fn intersect_edges(ray: Ray, a: vec3<f32>, e1: vec3<f32>, e2: vec3<f32>, t_min: f32, t_max: f32) -> vec3<f32> {
    let p = cross(ray.dir, e2);
    let det = dot(e1, p);
    let miss = vec3<f32>(-1.0, 0.0, 0.0);
    if det == 0.0 {
        return miss;
    }
    let inv = 1.0 / det;
    let s = ray.origin - a;
    let u = dot(s, p) * inv;
    if u < 0.0 || u > 1.0 {
        return miss;
    }
    let q = cross(s, e1);
    let v = dot(ray.dir, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return miss;
    }
    let t = dot(e2, q) * inv;
    if t > t_min && t < t_max {
        return vec3<f32>(t, u, v);
    }
    return miss;
}

fn to_model_point(inst: Instance, p: vec3<f32>) -> vec3<f32> {
    let h = vec4<f32>(p, 1.0);
    return vec3<f32>(dot(inst.to_model[0], h), dot(inst.to_model[1], h), dot(inst.to_model[2], h));
}

fn to_model_vector(inst: Instance, v: vec3<f32>) -> vec3<f32> {
    let h = vec4<f32>(v, 0.0);
    return vec3<f32>(dot(inst.to_model[0], h), dot(inst.to_model[1], h), dot(inst.to_model[2], h));
}

// Hits on transparent texels this invocation passed through (for statistics).
var<private> transparent_passed: u32;

// The micro-triangle barycentrics (u, v) fall in: coverage::micro_index's
// arithmetic (which micro-triangle a hair's breadth decides, either is
// right: a map knows only what holds with a texel's margin).
fn micro_index(u: f32, v: f32) -> u32 {
    let n = f32(MICRO_EDGE);
    let fu = u * n;
    let fv = v * n;
    let j = min(u32(max(floor(fv), 0.0)), MICRO_EDGE - 1u);
    let i = min(u32(max(floor(fu), 0.0)), MICRO_EDGE - 1u - j);
    let upper = (fu - f32(i)) + (fv - f32(j)) > 1.0 && i + j < MICRO_EDGE - 1u;
    return j * (2u * MICRO_EDGE - j) + 2u * i + select(0u, 1u, upper);
}

// Triangle record k from entry `first` (three entries each; the wide
// BVHs' leaves hold them). Its opacity word (b.w) is OPACITY_OPAQUE or the
// entry of its micromap (four entries, 2 bits per micro-triangle), which
// says where it is opaque or a hole; only where the map does not know is
// the alpha texel fetched.
fn test_record(ray: Ray, first: u32, k: u32, t_min: f32, t_max: f32) -> Hit {
    let r = first + 3u * k;
    let a = nodes[r];
    let b = nodes[r + 1u];
    let c = nodes[r + 2u];
    let h = intersect_edges(ray, bitcast<vec3<f32>>(a.xyz), bitcast<vec3<f32>>(b.xyz), bitcast<vec3<f32>>(c.xyz), t_min, t_max);
    if h.x > t_min {
        var state = MICRO_OPAQUE;
        if b.w != OPACITY_OPAQUE {
            let m = micro_index(h.y, h.z);
            let word = nodes[b.w + (m >> 6u)][(m >> 4u) & 3u];
            state = (word >> (2u * (m & 15u))) & 3u;
        }
        if state == MICRO_OPAQUE || (state != MICRO_HOLE && !is_transparent_material(c.w, triangle_uv(a.w, h.y, h.z))) {
            return Hit(NO_HIT, a.w, h.x, h.y, h.z);
        }
        transparent_passed += 1u;
    }
    return no_hit();
}

// The four bytes of `w` as grid cells (the wide BVHs' quantized boxes).
fn cells(w: u32) -> vec4<f32> {
    return vec4<f32>(vec4<u32>(w, w >> 8u, w >> 16u, w >> 24u) & vec4<u32>(0xffu));
}

// A wide node's grid step per axis from its exponent bytes (bytes 0-2 of
// `w`: biased exponents of powers of two).
fn grid_step(w: u32) -> vec3<f32> {
    return vec3<f32>(
        bitcast<f32>((w & 0xffu) << 23u),
        bitcast<f32>(((w >> 8u) & 0xffu) << 23u),
        bitcast<f32>(((w >> 16u) & 0xffu) << 23u),
    );
}

// Where the ray enters and leaves four boxes within (t_min, t_max): boxes
// in cells of a grid (`org`, `step`), lower and upper corners a byte each
// of the words `l*` and `h*`. A box is crossed where near <= far. The
// arithmetic of the CPU's (bvh::child_entries, CwbvhNode::keys).
struct Slabs4 {
    near: vec4<f32>,
    far: vec4<f32>,
}

fn slabs4(org: vec3<f32>, step: vec3<f32>, ray: Ray, lx: u32, ly: u32, lz: u32, hx: u32, hy: u32, hz: u32, t_min: f32, t_max: f32) -> Slabs4 {
    let o = ray.origin;
    let inv = ray.inv_dir;
    let x0 = (org.x + cells(lx) * step.x - o.x) * inv.x;
    let y0 = (org.y + cells(ly) * step.y - o.y) * inv.y;
    let z0 = (org.z + cells(lz) * step.z - o.z) * inv.z;
    let x1 = (org.x + cells(hx) * step.x - o.x) * inv.x;
    let y1 = (org.y + cells(hy) * step.y - o.y) * inv.y;
    let z1 = (org.z + cells(hz) * step.z - o.z) * inv.z;
    let near = max(max(min(x0, x1), min(y0, y1)), max(min(z0, z1), vec4<f32>(t_min)));
    let far = min(min(max(x0, x1), max(y0, y1)), min(max(z0, z1), vec4<f32>(t_max)));
    return Slabs4(near, far);
}

// This invocation's index in its workgroup (every tracing entry point sets
// it first): the compressed wide BVH's stack is shared by the workgroup's
// lanes.
var<private> trace_lane: u32;
