// The eight-wide compressed BVH's walk (Ylitie, Karras & Laine 2017), both
// levels in one loop as bvh.wgsl, built for a GPU's compute units:
// - a node is five vec4<u32> loads (80 bytes), its eight boxes tested as
//   two vec4 slabs;
// - a visited node's hit children are sorted by entry distance in
//   registers (a 19-exchange network over 8 keys) and kept as one group:
//   their slots, 3 bits each;
// - the stack holds such groups, at most one per level, in workgroup
//   memory: no dynamically indexed private array, so nothing spills to
//   local memory.
// shared/accel/src/cwbvh.rs is its reference, in the same order, so ties
// resolve alike. worker/src/trace/shaders.rs puts it after scene.wgsl.
//
// A group is vec2(base, bits): CW_VISIT | node (an entry) to visit;
// CW_LIST | node with the slots of its hit children still to visit,
// nearest first (3 bits each from bit 0, how many in bits 24-27); or a
// first record (an entry) with a mask of records from it (triangle records
// in a model, instance parts at the top).

// Entry i of lane l is at i * TRACE_LANES + l: lanes at the same depth
// touch neighbouring words.
var<workgroup> cw_stack: array<vec2<u32>, CW_STACK_ENTRIES>;

fn cw_push(sp: ptr<function, u32>, g: vec2<u32>) {
    cw_stack[*sp * TRACE_LANES + trace_lane] = g;
    *sp += 1u;
}

fn cw_has_work(g: vec2<u32>) -> bool {
    return (g.x & (CW_LIST | CW_VISIT)) != 0u || g.y != 0u;
}

// Orders two keys.
fn cw_exchange(a: ptr<function, u32>, b: ptr<function, u32>) {
    let lo = min(*a, *b);
    *b = max(*a, *b);
    *a = lo;
}

// The sort keys of four children (a byte each of the words) the ray
// crosses in (t_min, t_max) among `used` (bit i for byte i): the entry
// distance's bits, sign cleared, with slot `first + i` in the lowest three
// (cwbvh::sort_key); 0xffffffff for the rest.
fn cw_keys4(org: vec3<f32>, step: vec3<f32>, ray: Ray, lx: u32, ly: u32, lz: u32, hx: u32, hy: u32, hz: u32, t_min: f32, t_max: f32, used: u32, first: u32) -> vec4<u32> {
    let box = slabs4(org, step, ray, lx, ly, lz, hx, hy, hz, t_min, t_max);
    let near = box.near;
    let far = box.far;
    let lanes = vec4<u32>(0u, 1u, 2u, 3u);
    let in_use = ((vec4<u32>(used) >> lanes) & vec4<u32>(1u)) != vec4<u32>(0u);
    let key = (bitcast<vec4<u32>>(near) & vec4<u32>(0x7ffffff8u)) | (lanes + vec4<u32>(first));
    return select(vec4<u32>(0xffffffffu), key, (near <= far) & in_use);
}

// The meta byte of slot s.
fn cw_meta(e1: vec4<u32>, s: u32) -> u32 {
    return (select(e1.w, e1.z, s < 4u) >> ((s & 3u) * 8u)) & 0xffu;
}

// What slot s of the node at entry `node` holds: a node to visit, or a
// leaf's records (count in its meta byte's bits 5-7, offset in 0-4).
fn cw_child(node: u32, s: u32) -> vec2<u32> {
    let imask = nodes[node].w >> 24u;
    let e1 = nodes[node + 1u];
    if ((imask >> s) & 1u) != 0u {
        return vec2<u32>(CW_VISIT | (e1.x + CW_NODE_ENTRIES * countOneBits(imask & ((1u << s) - 1u))), 0u);
    }
    let m = cw_meta(e1, s);
    return vec2<u32>(e1.y, ((1u << (m >> 5u)) - 1u) << (m & 31u));
}

// Visits the node at entry `node`: its hit children nearest first, as a
// list group (nothing when none is hit).
fn cw_visit(node: u32, ray: Ray, t_min: f32, t_max: f32) -> vec2<u32> {
    // (grid origin, exponents | imask << 24), (child base, record base,
    // meta 0-3, meta 4-7), then the quantized corners: (lo x, lo y),
    // (lo z, hi x), (hi y, hi z), slots 0-3 then 4-7.
    let e0 = nodes[node];
    let e1 = nodes[node + 1u];
    let e2 = nodes[node + 2u];
    let e3 = nodes[node + 3u];
    let e4 = nodes[node + 4u];
    let org = bitcast<vec3<f32>>(e0.xyz);
    let step = grid_step(e0.w);
    // Used slots: inner children, and leaves (a non-zero meta byte).
    let metas = vec4<u32>(e1.z, e1.z >> 8u, e1.z >> 16u, e1.z >> 24u) & vec4<u32>(0xffu);
    let metas_hi = vec4<u32>(e1.w, e1.w >> 8u, e1.w >> 16u, e1.w >> 24u) & vec4<u32>(0xffu);
    let leaves = dot(select(vec4<u32>(0u), vec4<u32>(1u, 2u, 4u, 8u), metas != vec4<u32>(0u)), vec4<u32>(1u))
        | (dot(select(vec4<u32>(0u), vec4<u32>(1u, 2u, 4u, 8u), metas_hi != vec4<u32>(0u)), vec4<u32>(1u)) << 4u);
    let used = (e0.w >> 24u) | leaves;
    let a = cw_keys4(org, step, ray, e2.x, e2.z, e3.x, e3.z, e4.x, e4.z, t_min, t_max, used, 0u);
    let b = cw_keys4(org, step, ray, e2.y, e2.w, e3.y, e3.w, e4.y, e4.w, t_min, t_max, used >> 4u, 4u);
    var k0 = a.x;
    var k1 = a.y;
    var k2 = a.z;
    var k3 = a.w;
    var k4 = b.x;
    var k5 = b.y;
    var k6 = b.z;
    var k7 = b.w;
    cw_exchange(&k0, &k2);
    cw_exchange(&k1, &k3);
    cw_exchange(&k4, &k6);
    cw_exchange(&k5, &k7);
    cw_exchange(&k0, &k4);
    cw_exchange(&k1, &k5);
    cw_exchange(&k2, &k6);
    cw_exchange(&k3, &k7);
    cw_exchange(&k0, &k1);
    cw_exchange(&k2, &k3);
    cw_exchange(&k4, &k5);
    cw_exchange(&k6, &k7);
    cw_exchange(&k2, &k4);
    cw_exchange(&k3, &k5);
    cw_exchange(&k1, &k4);
    cw_exchange(&k3, &k6);
    cw_exchange(&k1, &k2);
    cw_exchange(&k3, &k4);
    cw_exchange(&k5, &k6);
    let lo = vec4<u32>(k0, k1, k2, k3);
    let hi = vec4<u32>(k4, k5, k6, k7);
    let none = vec4<u32>(0xffffffffu);
    let count = dot(select(vec4<u32>(0u), vec4<u32>(1u), lo != none), vec4<u32>(1u))
        + dot(select(vec4<u32>(0u), vec4<u32>(1u), hi != none), vec4<u32>(1u));
    if count == 0u {
        return vec2<u32>(0u);
    }
    let slots = dot((lo & vec4<u32>(7u)) << vec4<u32>(0u, 3u, 6u, 9u), vec4<u32>(1u))
        | dot((hi & vec4<u32>(7u)) << vec4<u32>(12u, 15u, 18u, 21u), vec4<u32>(1u));
    // Slots past the count are masked off.
    let list = slots & ((1u << (3u * count)) - 1u);
    return vec2<u32>(CW_LIST | node, list | (count << 24u));
}

// The closest opaque hit in (t_min, t_max); with `any`, the first found.
// The top level's tree is at entry 0; its records are instance parts
// (instance, start group in the model's tree).
fn traverse_cwbvh(world: Ray, t_min: f32, t_max: f32, any: bool) -> Hit {
    var best = no_hit();
    var closest = t_max;
    var ray = world;
    // The instance being walked (NO_HIT at the top level), and the stack
    // depth when it was entered (entries below are the top level's).
    var inst = NO_HIT;
    var inst_sp = 0u;
    var sp = 0u;
    // The top level's root.
    var g = vec2<u32>(CW_VISIT, 0u);
    loop {
        if (g.x & CW_LIST) != 0u {
            // The list's next child; the rest wait.
            let count = g.y >> 24u;
            if count > 1u {
                cw_push(&sp, vec2<u32>(g.x, ((g.y >> 3u) & 0x1fffffu) | ((count - 1u) << 24u)));
            }
            g = cw_child(g.x & ~CW_LIST, g.y & 7u);
        }
        if (g.x & CW_VISIT) != 0u {
            g = cw_visit(g.x & ~CW_VISIT, ray, t_min, closest);
        } else {
            loop {
                if g.y == 0u {
                    break;
                }
                let k = firstTrailingBit(g.y);
                g.y &= g.y - 1u;
                if inst == NO_HIT {
                    // An instance part: keep the parts left, then walk this
                    // one in model space.
                    let part = nodes[g.x + k];
                    if g.y != 0u {
                        cw_push(&sp, g);
                    }
                    inst = part.x;
                    inst_sp = sp;
                    let instance = instances[inst];
                    ray = make_ray(to_model_point(instance, world.origin), to_model_vector(instance, world.dir));
                    g = part.yz;
                    break;
                }
                let h = test_record(ray, g.x, k, t_min, closest);
                if h.triangle != NO_HIT {
                    best = h;
                    best.instance = inst;
                    closest = h.t;
                    if any {
                        return best;
                    }
                }
            }
        }
        if !cw_has_work(g) {
            if sp == 0u {
                return best;
            }
            sp -= 1u;
            if sp < inst_sp {
                inst = NO_HIT;
                inst_sp = 0u;
                ray = world;
            }
            g = cw_stack[sp * TRACE_LANES + trace_lane];
        }
    }
    return best;
}

// The closest opaque hit in the scene in (t_min, t_max).
fn closest_hit(ray: Ray, t_min: f32, t_max: f32) -> Hit {
    return traverse_cwbvh(ray, t_min, t_max, false);
}

// Whether anything opaque lies along the ray in (t_min, t_max).
fn occluded(ray: Ray, t_min: f32, t_max: f32) -> bool {
    return traverse_cwbvh(ray, t_min, t_max, true).triangle != NO_HIT;
}
