// The eight-wide compressed BVH's walk (Ylitie, Karras & Laine 2017), both
// levels in one loop as bvh.wgsl, built for a GPU's compute units:
// - a node is five vec4<u32> loads (80 bytes), its eight boxes tested as
//   two vec4 slabs;
// - children are visited by slot XOR the ray's octant, nearly nearest
//   first with no sort (slots were assigned by direction when built);
// - the stack holds groups (what is left of one node's inner children, or
//   of its leaves' records), at most one per level, in workgroup memory:
//   no dynamically indexed private array, so nothing spills to local memory.
// shared/accel/src/cwbvh.rs is its reference, in the same order, so ties
// resolve alike. worker/src/trace/shaders.rs puts it after scene.wgsl.
//
// A group is vec2(base, bits): a node group has CW_NODE_GROUP set, the
// children still to visit in bits 8-15 (by position: slot ^ octant) and
// the node's inner-slot mask in bits 0-7, base its first inner child's
// entry; a record group has a mask of records from entry `base`
// (triangle records at a model, instance parts at the top).

// Entry i of lane l is at i * TRACE_LANES + l: lanes at the same depth
// touch neighbouring words.
var<workgroup> cw_stack: array<vec2<u32>, CW_STACK_ENTRIES>;

fn cw_push(sp: ptr<function, u32>, g: vec2<u32>) {
    cw_stack[*sp * TRACE_LANES + trace_lane] = g;
    *sp += 1u;
}

// Bit a set where the direction is negative on axis a.
fn cw_octant(d: vec3<f32>) -> u32 {
    return select(0u, 1u, d.x < 0.0) | select(0u, 2u, d.y < 0.0) | select(0u, 4u, d.z < 0.0);
}

// Moves bit s of an 8-bit mask to bit s ^ oct.
fn cw_permute(mask: u32, oct: u32) -> u32 {
    var m = mask;
    if (oct & 1u) != 0u {
        m = ((m & 0x55u) << 1u) | ((m >> 1u) & 0x55u);
    }
    if (oct & 2u) != 0u {
        m = ((m & 0x33u) << 2u) | ((m >> 2u) & 0x33u);
    }
    if (oct & 4u) != 0u {
        m = ((m & 0x0fu) << 4u) | ((m >> 4u) & 0x0fu);
    }
    return m;
}

fn cw_has_work(g: vec2<u32>) -> bool {
    return select(g.y != 0u, (g.y & 0xff00u) != 0u, (g.y & CW_NODE_GROUP) != 0u);
}

// A group stored by slot (a part, the root) in positions for `oct`.
fn cw_in_positions(g: vec2<u32>, oct: u32) -> vec2<u32> {
    if (g.y & CW_NODE_GROUP) == 0u {
        return g;
    }
    return vec2<u32>(g.x, (g.y & ~0xff00u) | (cw_permute((g.y >> 8u) & 0xffu, oct) << 8u));
}

// Which of four children (a byte each of the words) the ray crosses in
// (t_min, t_max): bit i for byte i.
fn cw_hits4(org: vec3<f32>, step: vec3<f32>, ray: Ray, lx: u32, ly: u32, lz: u32, hx: u32, hy: u32, hz: u32, t_min: f32, t_max: f32) -> u32 {
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
    return dot(select(vec4<u32>(0u), vec4<u32>(1u, 2u, 4u, 8u), near <= far), vec4<u32>(1u));
}

// The closest opaque hit in (t_min, t_max); with `any`, the first found.
// The top level's tree is at entry 0; its records are instance parts
// (instance, start group in the model's tree).
fn traverse_cwbvh(world: Ray, t_min: f32, t_max: f32, any: bool) -> Hit {
    var best = no_hit();
    var closest = t_max;
    var ray = world;
    let world_oct = cw_octant(world.dir);
    var oct = world_oct;
    // The instance being walked (NO_HIT at the top level), and the stack
    // depth when it was entered (entries below are the top level's).
    var inst = NO_HIT;
    var inst_sp = 0u;
    var sp = 0u;
    // The root: node 0 as the one inner child in slot 0.
    var g = cw_in_positions(vec2<u32>(0u, CW_NODE_GROUP | 0x101u), oct);
    loop {
        var records = vec2<u32>(0u);
        if (g.y & CW_NODE_GROUP) != 0u && (g.y & 0xff00u) != 0u {
            // The group's next child, by position; the rest wait.
            let p = firstTrailingBit((g.y >> 8u) & 0xffu);
            let slot = p ^ oct;
            let node = g.x + CW_NODE_ENTRIES * countOneBits(g.y & 0xffu & ((1u << slot) - 1u));
            g.y &= ~(0x100u << p);
            if (g.y & 0xff00u) != 0u {
                cw_push(&sp, g);
            }
            // (grid origin, exponents | imask << 24), (child base, record
            // base, meta 0-3, meta 4-7), then the quantized corners:
            // (lo x, lo y), (lo z, hi x), (hi y, hi z), slots 0-3 then 4-7.
            let e0 = nodes[node];
            let e1 = nodes[node + 1u];
            let e2 = nodes[node + 2u];
            let e3 = nodes[node + 3u];
            let e4 = nodes[node + 4u];
            let org = bitcast<vec3<f32>>(e0.xyz);
            let step = vec3<f32>(
                bitcast<f32>((e0.w & 0xffu) << 23u),
                bitcast<f32>(((e0.w >> 8u) & 0xffu) << 23u),
                bitcast<f32>(((e0.w >> 16u) & 0xffu) << 23u),
            );
            let hit = cw_hits4(org, step, ray, e2.x, e2.z, e3.x, e3.z, e4.x, e4.z, t_min, closest)
                | (cw_hits4(org, step, ray, e2.y, e2.w, e3.y, e3.w, e4.y, e4.w, t_min, closest) << 4u);
            let imask = e0.w >> 24u;
            // Hit leaves add their records: count in a meta byte's bits
            // 5-7, offset in bits 0-4.
            var leaves = hit & ~imask;
            var mask = 0u;
            loop {
                if leaves == 0u {
                    break;
                }
                let s = firstTrailingBit(leaves);
                leaves &= leaves - 1u;
                let m = (select(e1.w, e1.z, s < 4u) >> ((s & 3u) * 8u)) & 0xffu;
                mask |= ((1u << (m >> 5u)) - 1u) << (m & 31u);
            }
            g = vec2<u32>(e1.x, CW_NODE_GROUP | (cw_permute(hit & imask, oct) << 8u) | imask);
            records = vec2<u32>(e1.y, mask);
        } else {
            records = g;
            g = vec2<u32>(0u);
        }
        loop {
            if records.y == 0u {
                break;
            }
            let k = firstTrailingBit(records.y);
            records.y &= records.y - 1u;
            if inst == NO_HIT {
                // An instance part: keep what is left at the top level
                // (the parts after the node group, so they come first),
                // then walk the part in model space.
                let part = nodes[records.x + k];
                if cw_has_work(g) {
                    cw_push(&sp, g);
                }
                if records.y != 0u {
                    cw_push(&sp, records);
                }
                inst = part.x;
                inst_sp = sp;
                let instance = instances[inst];
                ray = make_ray(to_model_point(instance, world.origin), to_model_vector(instance, world.dir));
                oct = cw_octant(ray.dir);
                g = cw_in_positions(part.yz, oct);
                break;
            }
            let h = test_record(ray, records.x, k, t_min, closest);
            if h.triangle != NO_HIT {
                best = h;
                best.instance = inst;
                closest = h.t;
                if any {
                    return best;
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
                oct = world_oct;
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
