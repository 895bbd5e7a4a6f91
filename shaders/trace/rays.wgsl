// Casts a batch of rays through the scene: the traversal kernel on its own,
// for tests against the CPU reference and for the traversal benchmark.
// Dispatched by worker/src/trace/raycast.rs; scene.wgsl comes first.

struct RayIn {
    origin: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

struct HitOut {
    instance: u32,
    triangle: u32,
    t: f32,
    u: f32,
    v: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// Shadow rays: write whether anything is hit (triangle 0) or not (NO_HIT),
// stopping at the first hit found.
override ANY_HIT: bool = false;

@group(1) @binding(0) var<storage, read> rays_in: array<RayIn>;
@group(1) @binding(1) var<storage, read_write> hits_out: array<HitOut>;

@compute @workgroup_size(64)
fn cast_rays(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    trace_lane = li;
    let i = gid.x + gid.y * groups.x * 64u;
    if i >= arrayLength(&rays_in) {
        return;
    }
    let r = rays_in[i];
    if ANY_HIT {
        let blocked = occluded(make_ray(r.origin, r.dir), r.t_min, r.t_max);
        hits_out[i] = HitOut(NO_HIT, select(NO_HIT, 0u, blocked), 0.0, 0.0, 0.0, 0u, 0u, 0u);
        return;
    }
    let h = closest_hit(make_ray(r.origin, r.dir), r.t_min, r.t_max);
    hits_out[i] = HitOut(h.instance, h.triangle, h.t, h.u, h.v, 0u, 0u, 0u);
}
