// Renders a vertical strip [x0, x0 + strip_width) of the frame: N jittered
// primary rays per pixel, alpha-masked leaves passed through, direct sun
// light with shadow rays, LB indirect light, LB-lit clouds marched in front
// of what lies behind them, a sky and a ground plane; the
// box-filtered mean goes out as linear HDR. Dispatched by
// worker/src/trace/render.rs; scene.wgsl comes first.

struct Frame {
    cam_position: vec3<f32>,
    tan_half_fov_y: f32,
    cam_forward: vec3<f32>,
    aspect: f32,
    cam_right: vec3<f32>,
    width: u32,
    cam_up: vec3<f32>,
    height: u32,
    sun_towards: vec3<f32>,
    x0: u32,
    sun_radiance: vec3<f32>,
    strip_width: u32,
    sky_zenith: vec3<f32>,
    spp: u32,
    sky_horizon: vec3<f32>,
    seed: u32,
    ground_color: vec3<f32>,
    has_ground: u32,
    // Constant indirect light for the `ambient` method.
    ambient: vec3<f32>,
    // 0 local, 1 ambient, 2 lb, 3 lb-visualize.
    lighting: u32,
    // Paper LB model: total density of unobstructed sunlight (LB values are
    // divided by it) and the non-physical strength of the LB term.
    lb_free: f32,
    lb_strength: f32,
    // Offset that keeps secondary rays off the surface they leave.
    epsilon: f32,
    // The reference integrator's path length cap (Russian roulette ends most paths sooner).
    max_bounces: u32,
    // Leaf optics (shared/scene/src/leaf/mod.rs): multipliers of the texture colour.
    leaf_reflect_front: vec3<f32>,
    pad0: u32,
    leaf_reflect_back: vec3<f32>,
    pad1: u32,
    leaf_transmit_front: vec3<f32>,
    pad2: u32,
    leaf_transmit_back: vec3<f32>,
    pad3: u32,
    // Boulanger et al.: mean sky (or ground) radiance over each direction's octant.
    bl_sky: array<vec4<f32>, 8>,
    // The ground's light under the stand (grounded LB): x, z of the corner
    // of node (0, 0), cell; then nx, nz, offset in lb_data, 1 when present.
    ground_grid: vec4<f32>,
    ground_dims: vec4<u32>,
    // 0: the grounded LB model (docs/lighting.md), 1: the papers' as written.
    lb_model: u32,
    // The gather methods: bounces traced before the far end reads the
    // lattice (or the matched constant).
    gather_bounces: u32,
    // The per-sample kernel's first sample in this dispatch (a frame's
    // samples go out in batches that fit the adapter's output binding).
    sample_base: u32,
    // ... and how many samples it renders.
    batch_spp: u32,
}

// Rays traced, by kind: primary, shadow, transparent texels passed.
struct Counters {
    primary: atomic<u32>,
    shadow: atomic<u32>,
    transparent: atomic<u32>,
    pad: u32,
}

@group(1) @binding(0) var<uniform> frame: Frame;
@group(1) @binding(1) var<storage, read_write> out_pixels: array<vec4<f32>>;
@group(1) @binding(2) var<storage, read_write> counters: Counters;

// The LIGHTING_* codes of frame.lighting and the KERNEL_* values of
// LIGHTING_FAMILY are generated from worker/src/lighting/ (one module per
// method) and prepended to this source.

// Which kernel this pipeline is: KERNEL_DIRECT (local, ambient, lb,
// lb-visualize, chosen per frame by frame.lighting), KERNEL_REFERENCE or
// KERNEL_BOULANGER. One source, specialized per pipeline, so a pipeline
// compiles only the code it runs.
override LIGHTING_FAMILY: u32 = 0u;
// Whether the scene has clouds: without, the pipelines compile no cloud
// code at all (on lavapipe the reference's unused cloud loops, merely
// present, made some primary rays miss geometry; see docs/lighting.md).
override HAS_CLOUDS: bool = false;
// Whether the kernel writes the passes beside the image (docs/passes.md):
// the light split (direct, indirect, sky) and the guides (albedo, normal,
// depth, ids) of the frame's own camera rays, so no pass traces them
// again. A pipeline of its own, compiled on the first frame that asks, so
// frames without passes carry none of it.
override PASSES: bool = false;

// PCG hash (Jarzynski & Olano 2020); shared/scene/src/sampler.rs mirrors it.
fn pcg(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// The random numbers of sample `s` of pixel (x, y): a hash of the pixel,
// the sample and the frame seed, never of the thread or strip, so a frame
// is the same however it is split.
fn sample_2d(x: u32, y: u32, s: u32, seed: u32) -> vec2<f32> {
    let h = pcg(x ^ pcg(y ^ pcg(s ^ pcg(seed))));
    let h2 = pcg(h);
    return vec2<f32>(f32(h >> 8u), f32(h2 >> 8u)) / 16777216.0;
}

// Sample `s` of `n` in the pixel: the first m² samples (m = ⌊√n⌋) each
// jitter `u` within their own cell of an m × m grid, the rest anywhere.
fn stratified(u: vec2<f32>, s: u32, n: u32) -> vec2<f32> {
    let m = u32(floor(sqrt(f32(n)) + 1e-3));
    if s >= m * m {
        return u;
    }
    return (vec2<f32>(f32(s % m), f32(s / m)) + u) / f32(m);
}

fn sky(dir: vec3<f32>) -> vec3<f32> {
    return mix(frame.sky_horizon, frame.sky_zenith, sqrt(max(dir.y, 0.0)));
}

// Whether the sun is hidden from `p`.
fn in_shadow(p: vec3<f32>) -> bool {
    return occluded(make_ray(p, frame.sun_towards), frame.epsilon, 3.0e38);
}

// The LB grid's value at a model-space point of an instance, trilinear
// between node centres (as GridDims::trilinear), times the instance's
// forest scale; zero where the model has no grid.
fn lb_light(inst: Instance, p_model: vec3<f32>) -> vec3<f32> {
    let m = models[inst.model];
    if m.has_lb == 0u {
        return vec3<f32>(0.0);
    }
    let p = vec3<f32>(dot(inst.to_lb[0].xyz, p_model), dot(inst.to_lb[1].xyz, p_model), dot(inst.to_lb[2].xyz, p_model));
    let d = m.lb_dims;
    let top = vec3<f32>(d - vec3<u32>(1u));
    let g = clamp((p - m.lb_origin) / m.lb_cell - 0.5, vec3<f32>(0.0), top);
    let i0 = vec3<u32>(min(floor(g), top - 1.0));
    let f = g - vec3<f32>(i0);
    let plane = d.x * d.y * d.z;
    var rgb = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        let base = m.lb_offset + c * plane;
        var acc = 0.0;
        for (var k = 0u; k < 8u; k++) {
            let o = vec3<u32>(k & 1u, (k >> 1u) & 1u, (k >> 2u) & 1u);
            let q = i0 + o;
            let w = select(1.0 - f.x, f.x, o.x == 1u) * select(1.0 - f.y, f.y, o.y == 1u) * select(1.0 - f.z, f.z, o.z == 1u);
            acc += w * lb_data[base + q.x + d.x * (q.y + d.y * q.z)];
        }
        rgb[c] = acc;
    }
    return rgb * inst.lb_scale;
}

const INV_FOUR_PI: f32 = 0.07957747;

// What the LB adds at a surface point, per unit of the surface's albedo
// (its reflectance plus transmittance): grounded, the indirect fluence φ
// over 4π (each side of a surface in a diffuse field receives φ/4, and a
// Lambertian surface sends ρE/π); paper, LB / LB_free × lb_strength × sun.
fn lb_indirect(inst: Instance, p_model: vec3<f32>) -> vec3<f32> {
    let raw = lb_light(inst, p_model);
    if frame.lb_model == 1u {
        return raw / frame.lb_free * frame.lb_strength * frame.sun_radiance;
    }
    return raw * INV_FOUR_PI;
}

// Whether this frame's direct methods use the papers' shading as written
// (the paper LB model's `lb`): texture colour only, no leaf transmission.
fn paper_shading() -> bool {
    return frame.lb_model == 1u && (frame.lighting == LIGHTING_LB || frame.lighting == LIGHTING_AMBIENT);
}

// The albedo a diffuse field sees on surface `s` viewed from the side of
// `n`: a leaf's reflectance on that side plus its transmittance from the
// other (the leaf optics, one BSDF for every method); wood its colour.
fn diffuse_albedo(s: SurfacePoint, n: vec3<f32>) -> vec3<f32> {
    if s.kind != KIND_LEAF || paper_shading() {
        return s.albedo;
    }
    let c = leaf_coefficients(s.albedo);
    if dot(s.n, n) >= 0.0 {
        return c[0] + c[3];
    }
    return c[1] + c[2];
}

// The sun's direct light on `s` (n faces the viewer):
// reflected when it lights the viewer's side, transmitted through a leaf
// when it lights the other; shadow rays honour alpha.
fn direct_sun(s: SurfacePoint, n: vec3<f32>) -> vec3<f32> {
    let n_dot_l = dot(n, frame.sun_towards);
    if n_dot_l > 0.0 {
        atomicAdd(&counters.shadow, 1u);
        if in_shadow(s.p + n * frame.epsilon) {
            return vec3<f32>(0.0);
        }
        var reflect_c = s.albedo;
        if s.kind == KIND_LEAF && !paper_shading() {
            let c = leaf_coefficients(s.albedo);
            reflect_c = select(c[1], c[0], dot(s.n, n) >= 0.0);
        }
        return frame.sun_radiance * reflect_c * n_dot_l;
    }
    if n_dot_l < 0.0 && s.kind == KIND_LEAF && !paper_shading() {
        atomicAdd(&counters.shadow, 1u);
        if in_shadow(s.p - n * frame.epsilon) {
            return vec3<f32>(0.0);
        }
        let c = leaf_coefficients(s.albedo);
        // Seen from the front, the light entered the back face (ρ_tb); from the back, the front (ρ_tf).
        let t = select(c[2], c[3], dot(s.n, n) >= 0.0);
        return frame.sun_radiance * t * (-n_dot_l);
    }
    return vec3<f32>(0.0);
}

// Sky irradiance over π on open ground: the cosine-weighted integral of the
// sky gradient, 0.2 horizon + 0.8 zenith (docs/lighting.md).
fn open_sky_on_ground() -> vec3<f32> {
    return 0.2 * frame.sky_horizon + 0.8 * frame.sky_zenith;
}

// Irradiance over π that the ground at world (x, z) receives besides the
// direct sun: under the stand, from the forest grid's indirect fluence φ
// (light from above only: E = φ/2); elsewhere, the open sky.
fn ground_indirect(p: vec3<f32>) -> vec3<f32> {
    let d = frame.ground_dims;
    if d.w == 0u || (frame.lighting != LIGHTING_LB && frame.lighting != LIGHTING_GATHER) {
        return open_sky_on_ground();
    }
    let cell = frame.ground_grid.z;
    let g = (vec2<f32>(p.x, p.z) - frame.ground_grid.xy) / cell - 0.5;
    let top = vec2<f32>(f32(d.x - 1u), f32(d.y - 1u));
    if any(g < vec2<f32>(0.0)) || any(g > top) {
        return open_sky_on_ground();
    }
    let i0 = vec2<u32>(min(floor(g), top - 1.0));
    let f = g - vec2<f32>(i0);
    var rgb = vec3<f32>(0.0);
    for (var c = 0u; c < 3u; c++) {
        let base = d.z + c * d.x * d.y;
        let a = lb_data[base + i0.x + d.x * i0.y];
        let b = lb_data[base + i0.x + 1u + d.x * i0.y];
        let e = lb_data[base + i0.x + d.x * (i0.y + 1u)];
        let h = lb_data[base + i0.x + 1u + d.x * (i0.y + 1u)];
        rgb[c] = mix(mix(a, b, f.x), mix(e, h, f.x), f.y);
    }
    return rgb / 3.14159265;
}

// Trilinear sample of plane `plane` of a cloud's data at grid coordinates g.
fn cloud_sample(c: Cloud, plane: u32, g: vec3<f32>) -> f32 {
    let n = c.n;
    let gc = clamp(g, vec3<f32>(0.0), vec3<f32>(f32(n - 1u)));
    let i0 = vec3<u32>(min(floor(gc), vec3<f32>(f32(n - 2u))));
    let f = gc - vec3<f32>(i0);
    let base = c.offset + plane * n * n * n;
    var acc = 0.0;
    for (var k = 0u; k < 8u; k++) {
        let d = vec3<u32>(k & 1u, (k >> 1u) & 1u, (k >> 2u) & 1u);
        let q = i0 + d;
        let w = select(1.0 - f.x, f.x, d.x == 1u) * select(1.0 - f.y, f.y, d.y == 1u) * select(1.0 - f.z, f.z, d.z == 1u);
        acc += w * cloud_data[base + q.x + n * (q.y + n * q.z)];
    }
    return acc;
}

// Light a cloud adds along [t0, t1) of the ray (rgb) and what it lets
// through (a): opacity from density, in-scattered light from its LB grid.
fn march_cloud(c: Cloud, ray: Ray, t0: f32, t1: f32) -> vec4<f32> {
    let cell = c.size / f32(c.n);
    let len = length(ray.dir);
    let dt = 0.5 * cell / len;
    var transmittance = 1.0;
    var light = vec3<f32>(0.0);
    var t = t0 + 0.5 * dt;
    loop {
        if t >= t1 || transmittance < 1e-3 {
            break;
        }
        let p = ray.origin + ray.dir * t;
        let g = (p - c.min) / cell - 0.5;
        let rho = cloud_sample(c, 0u, g);
        if rho > 0.0 {
            let sigma = rho * c.extinction * len;
            let lb = vec3<f32>(cloud_sample(c, 1u, g), cloud_sample(c, 2u, g), cloud_sample(c, 3u, g)) / frame.lb_free;
            let absorbed = 1.0 - exp(-sigma * dt);
            light += transmittance * absorbed * c.albedo * lb * frame.sun_radiance;
            transmittance *= 1.0 - absorbed;
        }
        t += dt;
    }
    return vec4<f32>(light, transmittance);
}

// Composites the clouds a ray crosses before what it met (`behind.t`) over
// the light behind them, nearest cloud in front: what the clouds let
// through of each part, and their own light as indirect.
fn through_clouds(ray: Ray, behind: Light) -> Light {
    if !HAS_CLOUDS {
        return behind;
    }
    let t_max = behind.t;
    var color = behind;
    var done = 0u;
    let count = arrayLength(&clouds);
    // Farthest first, so each nearer cloud is composited over the result.
    for (var k = 0u; k < count; k++) {
        var pick = count;
        var pick_t = -1.0;
        for (var i = 0u; i < count; i++) {
            let c = clouds[i];
            if c.n == 0u || (done & (1u << i)) != 0u {
                continue;
            }
            let span = clip_box(c.min, c.min + vec3<f32>(c.size), ray, 0.0, t_max);
            if span.x <= span.y && span.x > pick_t {
                pick = i;
                pick_t = span.x;
            }
        }
        if pick == count {
            break;
        }
        done |= 1u << pick;
        let c = clouds[pick];
        let span = clip_box(c.min, c.min + vec3<f32>(c.size), ray, 0.0, t_max);
        let m = march_cloud(c, ray, span.x, span.y);
        color.direct *= m.a;
        color.sky *= m.a;
        color.indirect = m.rgb + m.a * color.indirect;
    }
    return color;
}

// What a primary ray brings back, split as the passes split it
// (docs/passes.md): the sun's light off the first surface, all other light
// off it (and what clouds in front add), and the sky seen directly. Their
// sum is the radiance.
struct Light {
    direct: vec3<f32>,
    // 1 where the ray met a model (not the ground or the sky).
    hit: f32,
    indirect: vec3<f32>,
    // Distance to what the ray met (ground or model), or 3e38.
    t: f32,
    sky: vec3<f32>,
}

fn light_total(l: Light) -> vec3<f32> {
    return l.direct + l.indirect + l.sky;
}

// Radiance along one primary ray, clouds included.
fn radiance(ray: Ray, surf: SurfacePoint) -> Light {
    return through_clouds(ray, surface_radiance(ray, surf));
}

const KIND_LEAF: u32 = 0u;
const KIND_WOOD: u32 = 1u;
const KIND_GROUND: u32 = 2u;
const KIND_SKY: u32 = 3u;

// The first thing a ray meets: where, its geometric normal in world space
// (as the triangle winds, not turned to the viewer), its colour and kind.
struct SurfacePoint {
    p: vec3<f32>,
    t: f32,
    n: vec3<f32>,
    kind: u32,
    albedo: vec3<f32>,
    instance: u32,
    triangle: u32,
}

fn first_surface(ray: Ray) -> SurfacePoint {
    let hit = closest_hit(ray, 0.0, 3.0e38);
    var ground_t = 3.0e38;
    if frame.has_ground == 1u && ray.dir.y < 0.0 {
        ground_t = -ray.origin.y / ray.dir.y;
    }
    if hit.triangle == NO_HIT || ground_t < hit.t {
        if ground_t < 3.0e38 {
            return SurfacePoint(ray.origin + ray.dir * ground_t, ground_t, vec3<f32>(0.0, 1.0, 0.0), KIND_GROUND, frame.ground_color, 0u, 0u);
        }
        return SurfacePoint(vec3<f32>(0.0), 3.0e38, vec3<f32>(0.0), KIND_SKY, vec3<f32>(0.0), 0u, 0u);
    }
    let inst = instances[hit.instance];
    let tri = triangles[hit.triangle];
    let mat = materials[tri.material];
    var albedo = mat.base_color.rgb;
    if mat.texture != NO_TEXTURE {
        let t = texel(textures[mat.texture], triangle_uv(hit.triangle, hit.u, hit.v));
        albedo *= vec3<f32>(srgb_to_linear(t.r), srgb_to_linear(t.g), srgb_to_linear(t.b));
    }
    // Geometric normal to world space by the inverse transpose.
    let a = position(tri.v.x);
    let n_model = cross(position(tri.v.y) - a, position(tri.v.z) - a);
    let tm = inst.to_model;
    let n = normalize(vec3<f32>(
        tm[0].x * n_model.x + tm[1].x * n_model.y + tm[2].x * n_model.z,
        tm[0].y * n_model.x + tm[1].y * n_model.y + tm[2].y * n_model.z,
        tm[0].z * n_model.x + tm[1].z * n_model.y + tm[2].z * n_model.z,
    ));
    return SurfacePoint(ray.origin + ray.dir * hit.t, hit.t, n, select(KIND_LEAF, KIND_WOOD, mat.surface == 1u), albedo, hit.instance, hit.triangle);
}

// A leaf's (ρ_rf, ρ_rb, ρ_tf, ρ_tb) for texture colour `albedo`: the
// frame's leaf optics times the colour, each side scaled back so it never
// scatters more than it receives (as LeafOptics::coefficients does).
fn leaf_coefficients(albedo: vec3<f32>) -> array<vec3<f32>, 4> {
    var rf = albedo * frame.leaf_reflect_front;
    var rb = albedo * frame.leaf_reflect_back;
    var tf = albedo * frame.leaf_transmit_front;
    var tb = albedo * frame.leaf_transmit_back;
    let front = max(rf + tf, vec3<f32>(1.0));
    let back = max(rb + tb, vec3<f32>(1.0));
    return array<vec3<f32>, 4>(rf / front, rb / back, tf / front, tb / back);
}

// The light of the first surface `s` (or the sky) along a primary ray.
fn surface_radiance(ray: Ray, s: SurfacePoint) -> Light {
    let none = vec3<f32>(0.0);
    if s.kind == KIND_SKY {
        return Light(none, 0.0, none, 3.0e38, sky(ray.dir));
    }
    if s.kind == KIND_GROUND {
        var direct = vec3<f32>(0.0);
        if frame.sun_towards.y > 0.0 && frame.lighting != LIGHTING_LB_VISUALIZE {
            atomicAdd(&counters.shadow, 1u);
            if !in_shadow(s.p + vec3<f32>(0.0, frame.epsilon, 0.0)) {
                direct = frame.sun_radiance * frame.sun_towards.y;
            }
        }
        return Light(frame.ground_color * direct, 0.0, frame.ground_color * ground_indirect(s.p), s.t, none);
    }
    let inst = instances[s.instance];
    let n = select(s.n, -s.n, dot(s.n, ray.dir) > 0.0);
    let p_model = to_model_point(inst, s.p);
    if frame.lighting == LIGHTING_LB_VISUALIZE {
        return Light(none, 1.0, lb_indirect(inst, p_model), s.t, none);
    }
    let direct = direct_sun(s, n);
    var indirect = none;
    if LIGHTING_FAMILY == KERNEL_BOULANGER && models[inst.model].has_envelope == 1u {
        indirect = boulanger_light(s, ray.dir);
    } else if frame.lighting == LIGHTING_LB {
        indirect = diffuse_albedo(s, n) * lb_indirect(inst, p_model);
    } else if frame.lighting == LIGHTING_AMBIENT {
        indirect = diffuse_albedo(s, n) * frame.ambient;
    }
    return Light(direct, 1.0, indirect, s.t, none);
}

// A camera ray's guide images (docs/passes.md): (albedo, depth),
// (normal, 0), (instance + 1, model + 1, 0, 0). The albedo and normal are
// the first surface's, its normal turned to the camera, and zero for the
// sky; the depth is along the camera's axis (1e10 for the sky); the ids
// are 0 for the ground and the sky. The frame's kernels write them from
// the camera rays they trace anyway.
fn guides(ray: Ray, surf: SurfacePoint) -> array<vec4<f32>, 3> {
    if surf.kind == KIND_SKY {
        return array<vec4<f32>, 3>(vec4<f32>(0.0, 0.0, 0.0, 1.0e10), vec4<f32>(0.0), vec4<f32>(0.0));
    }
    let n = select(surf.n, -surf.n, dot(surf.n, ray.dir) > 0.0);
    let depth = dot(surf.p - frame.cam_position, frame.cam_forward);
    var ids = vec2<f32>(0.0);
    if surf.kind != KIND_GROUND {
        ids = vec2<f32>(f32(surf.instance + 1u), f32(instances[surf.instance].model + 1u));
    }
    return array<vec4<f32>, 3>(vec4<f32>(diffuse_albedo(surf, n), depth), vec4<f32>(n, 0.0), vec4<f32>(ids, 0.0, 0.0));
}

// Camera ray of sample `s` of pixel (x, y). One sample sits at the pixel
// centre; more are stratified: jittered within the cells of the largest
// square grid that fits, so edges and sun flecks inside a pixel are
// sampled evenly.
fn camera_ray(x: u32, y: u32, s: u32) -> Ray {
    var j = vec2<f32>(0.5, 0.5);
    if frame.spp > 1u {
        j = stratified(sample_2d(x, y, s, frame.seed), s, frame.spp);
    }
    let px = f32(x) + j.x;
    let py = f32(y) + j.y;
    let sx = (2.0 * px / f32(frame.width) - 1.0) * frame.tan_half_fov_y * frame.aspect;
    let sy = (1.0 - 2.0 * py / f32(frame.height)) * frame.tan_half_fov_y;
    return make_ray(frame.cam_position, normalize(frame.cam_forward + frame.cam_right * sx + frame.cam_up * sy));
}

@compute @workgroup_size(8, 8)
fn render_strip(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    trace_lane = li;
    // The tile's pixels in Morton order: lanes that run in lock-step
    // (8 on lavapipe, a warp's quarter on a GPU) cover 4 × 2 pixels
    // rather than a row of 8, so their rays stay closer together.
    let lx = (li & 1u) | ((li >> 1u) & 2u) | ((li >> 2u) & 4u);
    let ly = ((li >> 1u) & 1u) | ((li >> 2u) & 2u) | ((li >> 3u) & 4u);
    let gid = vec3<u32>(wid.x * 8u + lx, wid.y * 8u + ly, wid.z);
    if gid.x >= frame.strip_width || gid.y >= frame.height || gid.z >= select(1u, frame.batch_spp, LIGHTING_FAMILY == KERNEL_REFERENCE) {
        return;
    }
    let x = frame.x0 + gid.x;
    let y = gid.y;
    transparent_passed = 0u;
    let pixel = gid.x + gid.y * frame.strip_width;
    if LIGHTING_FAMILY == KERNEL_REFERENCE {
        // The reference and the gathers: one path per invocation, sample
        // sample_base + gid.z of the frame's, in its own slot of this
        // batch (the worker sums them); after the batch's samples, what
        // `local` shows along the same camera rays and the first hit's
        // distance, then its albedo, then the indirect light of a sample
        // whose first event is a surface (reference.wgsl).
        let r = reference_sample(x, y, frame.sample_base + gid.z);
        let slots = frame.strip_width * frame.height;
        // Two more images only for passes: the first event's split and the
        // camera ray's normal; then, once per pixel, the frame's sample 0's
        // depth and ids (a guide's mean albedo is the third image's).
        for (var k = 0u; k < select(4u, 6u, PASSES); k++) {
            out_pixels[pixel + (k * frame.batch_spp + gid.z) * slots] = r[k];
        }
        if PASSES && frame.sample_base + gid.z == 0u {
            out_pixels[pixel + 6u * frame.batch_spp * slots] = r[6];
        }
        atomicAdd(&counters.transparent, transparent_passed);
        atomicAdd(&counters.primary, 1u);
        return;
    } else {
        var sum = vec4<f32>(0.0);
        var direct = vec3<f32>(0.0);
        var indirect = vec3<f32>(0.0);
        var sky_seen = vec3<f32>(0.0);
        // The guides: albedo and normal summed over the samples (the
        // worker divides), depth and ids of sample 0.
        var guide_sum = array<vec4<f32>, 3>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
        for (var s = 0u; s < frame.spp; s++) {
            let ray = camera_ray(x, y, s);
            let surf = first_surface(ray);
            let l = radiance(ray, surf);
            sum += vec4<f32>(light_total(l), l.hit);
            if PASSES {
                direct += l.direct;
                indirect += l.indirect;
                sky_seen += l.sky;
                let g = guides(ray, surf);
                if s == 0u {
                    guide_sum = g;
                } else {
                    guide_sum[0] += vec4<f32>(g[0].xyz, 0.0);
                    guide_sum[1] += g[1];
                }
            }
        }
        // Box filter: the mean of the samples; alpha is the fraction that hit a model.
        let spp = f32(frame.spp);
        out_pixels[pixel] = sum / spp;
        if PASSES {
            let slots = frame.strip_width * frame.height;
            out_pixels[pixel + slots] = vec4<f32>(direct / spp, 0.0);
            out_pixels[pixel + 2u * slots] = vec4<f32>(indirect / spp, 0.0);
            out_pixels[pixel + 3u * slots] = vec4<f32>(sky_seen / spp, 0.0);
            for (var k = 0u; k < 3u; k++) {
                out_pixels[pixel + (4u + k) * slots] = guide_sum[k];
            }
        }
    }
    // One atomic per invocation, outside the loops.
    atomicAdd(&counters.transparent, transparent_passed);
    atomicAdd(&counters.primary, frame.spp);
}
