// The hardware traversal: rays go through the device's own acceleration
// structures by ray queries (wgpu's EXPERIMENTAL_RAY_QUERY), in place of
// walk.wgsl, with the same closest_hit and occluded. Built by
// worker/src/trace/rq.rs: one BLAS per model whose triangles the coverage
// classes call opaque (geometry 0, flagged opaque, so the device never
// returns to the shader for them) or mixed (geometry 1: each candidate
// takes the alpha test here and is confirmed only on an opaque texel);
// cut triangles are left out. A TLAS holds the instances, each with its
// index as custom data. Hits are the walk's: the instance, the global
// triangle, t along the unnormalized world ray, barycentrics (u, v) of
// the second and third vertices.

@group(0) @binding(14) var tlas: acceleration_structure;
// Per model, from its rq_first: the global index of each triangle in
// BLAS order (the opaque ones, then the mixed ones).
@group(0) @binding(15) var<storage, read> rq_triangles: array<u32>;

// The global triangle an intersection names.
fn rq_triangle(i: RayIntersection) -> u32 {
    let m = models[instances[i.instance_custom_data].model];
    return rq_triangles[m.rq_first + select(0u, m.rq_opaque, i.geometry_index == 1u) + i.primitive_index];
}

// The closest opaque hit in (t_min, t_max); with `any`, the first found.
fn traverse_rq(ray: Ray, t_min: f32, t_max: f32, any: bool) -> Hit {
    var q: ray_query;
    let flags = select(RAY_FLAG_NONE, RAY_FLAG_TERMINATE_ON_FIRST_HIT, any);
    rayQueryInitialize(&q, tlas, RayDesc(flags, 0xffu, t_min, t_max, ray.origin, ray.dir));
    while rayQueryProceed(&q) {
        // Only the mixed geometry's triangles come back as candidates.
        let c = rayQueryGetCandidateIntersection(&q);
        let tri = rq_triangle(c);
        if is_transparent(tri, triangle_uv(tri, c.barycentrics.x, c.barycentrics.y)) {
            transparent_passed += 1u;
        } else {
            rayQueryConfirmIntersection(&q);
        }
    }
    let h = rayQueryGetCommittedIntersection(&q);
    if h.kind == RAY_QUERY_INTERSECTION_NONE {
        return no_hit();
    }
    return Hit(h.instance_custom_data, rq_triangle(h), h.t, h.barycentrics.x, h.barycentrics.y);
}

// The closest opaque hit in the scene in (t_min, t_max).
fn closest_hit(ray: Ray, t_min: f32, t_max: f32) -> Hit {
    return traverse_rq(ray, t_min, t_max, false);
}

// Whether anything opaque lies along the ray in (t_min, t_max).
fn occluded(ray: Ray, t_min: f32, t_max: f32) -> bool {
    return traverse_rq(ray, t_min, t_max, true).triangle != NO_HIT;
}
