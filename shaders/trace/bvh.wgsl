// Both levels of the wide BVH in one loop. A nested traversal (one loop for
// the instances, another inside it for an instance's triangles) leaves
// lanes idle: while one lane of a SIMD group walks a tree, the others wait
// at the top level. Here every lane runs the same step each iteration (a
// node's four boxes, or a leaf), whichever level it is on; entering an
// instance swaps in the ray carried into model space, and popping an entry
// pushed before that swaps the world ray back. Visits are in the order of
// the CPU reference (shared/accel/src/two_level.rs), so ties resolve alike.

// The stack lives at module scope: a function's arrays are zeroed on every
// call (WGSL's rule), a private one once per invocation.
var<private> bvh_stack_ref: array<u32, BVH_STACK>;
var<private> bvh_stack_count: array<u32, BVH_STACK>;
var<private> bvh_stack_near: array<f32, BVH_STACK>;

// Orders lanes a and b by the distances d, carrying the children's
// references c and leaf counts n along: constant lanes only, since a
// dynamically indexed vector costs a chain of selects on lavapipe.
fn sort_pair(d: ptr<function, vec4<f32>>, c: ptr<function, vec4<u32>>, n: ptr<function, vec4<u32>>, a: u32, b: u32) {
    let da = (*d)[a];
    let db = (*d)[b];
    if db < da {
        (*d)[a] = db;
        (*d)[b] = da;
        let ca = (*c)[a];
        (*c)[a] = (*c)[b];
        (*c)[b] = ca;
        let na = (*n)[a];
        (*n)[a] = (*n)[b];
        (*n)[b] = na;
    }
}

// Pushes a child (its reference, leaf count and entry distance).
fn push_entry(sp: ptr<function, u32>, reference: u32, count: u32, near: f32) {
    bvh_stack_ref[*sp] = reference;
    bvh_stack_count[*sp] = count;
    bvh_stack_near[*sp] = near;
    *sp += 1u;
}

// Where a walk is: the ray in the current level's space, the instance
// being walked (NO_HIT at the top level) and the stack depth when it was
// entered (entries below it are the top level's), the entry to visit next
// with its leaf count and entry distance. (The stack pointer is apart: a
// pointer to a struct's member cannot be passed on.)
struct Walk {
    ray: Ray,
    inst: u32,
    inst_sp: u32,
    cur: u32,
    count: u32,
    near: f32,
}

// Pops the next entry still in reach into the walk, back in world space
// once below the instance's entries; false when none is left.
fn pop_entry(w: ptr<function, Walk>, sp: ptr<function, u32>, world: Ray, closest: f32) -> bool {
    loop {
        if *sp == 0u {
            return false;
        }
        *sp -= 1u;
        if *sp < (*w).inst_sp {
            (*w).inst = NO_HIT;
            (*w).inst_sp = 0u;
            (*w).ray = world;
        }
        let i = *sp;
        if bvh_stack_near[i] <= closest {
            (*w).cur = bvh_stack_ref[i];
            (*w).count = bvh_stack_count[i];
            (*w).near = bvh_stack_near[i];
            return true;
        }
    }
    return false;
}

// The closest opaque hit in (t_min, t_max); with `any`, the first found.
// The top level's root is entry 0; its leaves hold instance parts
// (instance, entry of a subtree of the model's BVH, leaf count).
//
// Each pass of the loop runs up to three steps in turn, each for the lanes
// it concerns: entering an instance part, one node's four boxes, one
// leaf's triangles. A lane that enters a part tests its root's boxes in
// the same pass, and one that reaches a leaf tests it in the same pass,
// so the lanes of a SIMD group share passes instead of taking turns.
fn traverse_bvh(world: Ray, t_min: f32, t_max: f32, any: bool) -> Hit {
    let inf = bitcast<f32>(0x7f800000u);
    var best = no_hit();
    var closest = t_max;
    var w = Walk(world, NO_HIT, 0u, 0u, 0u, t_min);
    var sp = 0u;
    loop {
        if (w.cur & BVH_LEAF) != 0u && w.inst == NO_HIT {
            // A top-level leaf: enter its first part, keep the rest.
            let first = w.cur & ~BVH_LEAF;
            if w.count > 1u {
                push_entry(&sp, BVH_LEAF | (first + 1u), w.count - 1u, w.near);
            }
            let part = nodes[first];
            w.inst = part.x;
            w.inst_sp = sp;
            let instance = instances[w.inst];
            w.ray = make_ray(to_model_point(instance, world.origin), to_model_vector(instance, world.dir));
            w.cur = part.y;
            w.count = part.z;
        }
        if (w.cur & BVH_LEAF) == 0u {
            let cur = w.cur;
            // (grid origin, exponents), children, (lo x y z, hi x), (hi y z, counts).
            let e0 = nodes[cur];
            let child = nodes[cur + 1u];
            let q0 = nodes[cur + 2u];
            let q1 = nodes[cur + 3u];
            let org = bitcast<vec3<f32>>(e0.xyz);
            let step = grid_step(e0.w);
            let box = slabs4(org, step, w.ray, q0.x, q0.y, q0.z, q0.w, q1.x, q1.y, t_min, closest);
            let near = box.near;
            let far = box.far;
            let counts = vec4<u32>(q1.z & 0xffffu, q1.z >> 16u, q1.w & 0xffffu, q1.w >> 16u);
            let hit = (near <= far) & (child != vec4<u32>(BVH_EMPTY));
            let n_hit = dot(select(vec4<u32>(0u), vec4<u32>(1u), hit), vec4<u32>(1u));
            if n_hit > 0u {
                // Misses sort last: their key is infinite, a hit's is finite.
                var dist = select(vec4<f32>(inf), min(near, vec4<f32>(3.0e38)), hit);
                var kids = child;
                var kid_counts = counts;
                sort_pair(&dist, &kids, &kid_counts, 0u, 1u);
                sort_pair(&dist, &kids, &kid_counts, 2u, 3u);
                sort_pair(&dist, &kids, &kid_counts, 0u, 2u);
                sort_pair(&dist, &kids, &kid_counts, 1u, 3u);
                sort_pair(&dist, &kids, &kid_counts, 1u, 2u);
                // The farther hit children wait on the stack, farthest first.
                if n_hit > 3u {
                    push_entry(&sp, kids.w, kid_counts.w, dist.w);
                }
                if n_hit > 2u {
                    push_entry(&sp, kids.z, kid_counts.z, dist.z);
                }
                if n_hit > 1u {
                    push_entry(&sp, kids.y, kid_counts.y, dist.y);
                }
                w.cur = kids.x;
                w.count = kid_counts.x;
                w.near = dist.x;
            } else {
                let more = pop_entry(&w, &sp, world, closest);
                if !more {
                    return best;
                }
            }
        }
        if (w.cur & BVH_LEAF) != 0u && w.inst != NO_HIT {
            let first = w.cur & ~BVH_LEAF;
            for (var k = 0u; k < w.count; k++) {
                let h = test_record(w.ray, first, k, t_min, closest);
                if h.triangle != NO_HIT {
                    best = h;
                    best.instance = w.inst;
                    closest = h.t;
                    if any {
                        return best;
                    }
                }
            }
            let more = pop_entry(&w, &sp, world, closest);
            if !more {
                return best;
            }
        }
    }
    return best;
}
