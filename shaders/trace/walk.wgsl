// The compute traversal: rays walk Sylva's own structures (the wide BVH
// of bvh.wgsl, or the kd-tree of traverse.wgsl), chosen by ACCEL_KIND.
// worker/src/trace/shaders.rs assembles it after scene.wgsl and the
// traversal loops; rq.wgsl is the hardware alternative with the same
// closest_hit and occluded.

struct KdEntry {
    node: u32,
    lo: f32,
    hi: f32,
}

// A triangle hit in (t_min, t_max), or no_hit().
fn test_triangle(ray: Ray, tri: u32, t_min: f32, t_max: f32) -> Hit {
    let h = intersect_triangle(ray, tri, t_min, t_max);
    if h.x > t_min {
        if !is_transparent(tri, triangle_uv(tri, h.y, h.z)) {
            return Hit(NO_HIT, tri, h.x, h.y, h.z);
        }
        transparent_passed += 1u;
    }
    return no_hit();
}

// The closest hit inside an instance (kd-tree): the ray carried into
// model space unnormalized, so t means the same in both spaces.
fn test_instance(ray: Ray, index: u32, t_min: f32, t_max: f32, any: bool) -> Hit {
    let inst = instances[index];
    let local = make_ray(to_model_point(inst, ray.origin), to_model_vector(inst, ray.dir));
    var h = traverse_kd_model(local, models[inst.model].root, t_min, t_max, any);
    h.instance = index;
    return h;
}

fn test_prim_top(ray: Ray, prim: u32, t_min: f32, t_max: f32, any: bool) -> Hit {
    return test_instance(ray, prim, t_min, t_max, any);
}

fn test_prim_model(ray: Ray, prim: u32, t_min: f32, t_max: f32, any: bool) -> Hit {
    return test_triangle(ray, prim, t_min, t_max);
}

// The closest opaque hit in the scene in (t_min, t_max).
fn closest_hit(ray: Ray, t_min: f32, t_max: f32) -> Hit {
    if ACCEL_KIND == 0u {
        return traverse_bvh(ray, t_min, t_max, false);
    }
    // A kd-tree's root follows its two bounds entries.
    return traverse_kd_top(ray, 2u, t_min, t_max, false);
}

// Whether anything opaque lies along the ray in (t_min, t_max).
fn occluded(ray: Ray, t_min: f32, t_max: f32) -> bool {
    if ACCEL_KIND == 0u {
        return traverse_bvh(ray, t_min, t_max, true).triangle != NO_HIT;
    }
    return traverse_kd_top(ray, 2u, t_min, t_max, true).triangle != NO_HIT;
}
