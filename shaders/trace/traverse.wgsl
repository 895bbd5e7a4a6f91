// Traversal of one level of the two-level acceleration structure, a
// template: worker/src/trace/shaders.rs instantiates it with LEVEL = top
// (leaves hold instances) and LEVEL = model (leaves hold triangles), since
// WGSL has no generics and forbids recursion. Mirrors shared/src/accel.

// The closest hit of the tree rooted at `root` in (t_min, t_max); with
// `any`, the first hit found (shadow rays need no more). A BVH may start at
// any entry: `root_count` is its leaf count when it is a leaf.
fn traverse_LEVEL(ray: Ray, root: u32, root_count: u32, t_min: f32, t_max: f32, any: bool) -> Hit {
    if ACCEL_KIND == 0u {
        return traverse_bvh_LEVEL(ray, root, root_count, t_min, t_max, any);
    }
    return traverse_kd_LEVEL(ray, root, t_min, t_max, any);
}

// The wide BVH: the four children's boxes tested as one vec4 per bound,
// hit children sorted nearest first by a five-comparison network, the
// nearest visited next and the rest pushed with their entry distance.
// The stack lives at module scope: a function's arrays are zeroed on every
// call (WGSL's rule), a private one once per invocation.
var<private> stack_ref_LEVEL: array<u32, BVH_STACK>;
var<private> stack_count_LEVEL: array<u32, BVH_STACK>;
var<private> stack_near_LEVEL: array<f32, BVH_STACK>;

fn traverse_bvh_LEVEL(ray: Ray, root: u32, root_count: u32, t_min: f32, t_max: f32, any: bool) -> Hit {
    var best = no_hit();
    var closest = t_max;
    var sp = 0u;
    var cur = root;
    var count = root_count;
    let inf = bitcast<f32>(0x7f800000u);
    loop {
        var pushed = false;
        if (cur & BVH_LEAF) != 0u {
            let first = cur & ~BVH_LEAF;
            for (var k = 0u; k < count; k++) {
                let h = test_leaf_LEVEL(ray, first, k, t_min, closest, any);
                if h.triangle != NO_HIT {
                    best = h;
                    closest = h.t;
                    if any {
                        return best;
                    }
                }
            }
        } else {
            let o = ray.origin;
            let inv = ray.inv_dir;
            let x0 = (bitcast<vec4<f32>>(nodes[cur]) - o.x) * inv.x;
            let y0 = (bitcast<vec4<f32>>(nodes[cur + 1u]) - o.y) * inv.y;
            let z0 = (bitcast<vec4<f32>>(nodes[cur + 2u]) - o.z) * inv.z;
            let x1 = (bitcast<vec4<f32>>(nodes[cur + 3u]) - o.x) * inv.x;
            let y1 = (bitcast<vec4<f32>>(nodes[cur + 4u]) - o.y) * inv.y;
            let z1 = (bitcast<vec4<f32>>(nodes[cur + 5u]) - o.z) * inv.z;
            let child = nodes[cur + 6u];
            let counts = nodes[cur + 7u];
            let near = max(max(min(x0, x1), min(y0, y1)), max(min(z0, z1), vec4<f32>(t_min)));
            let far = min(min(max(x0, x1), max(y0, y1)), min(max(z0, z1), vec4<f32>(closest)));
            let hit = (near <= far) & (child != vec4<u32>(BVH_EMPTY));
            let n_hit = dot(select(vec4<u32>(0u), vec4<u32>(1u), hit), vec4<u32>(1u));
            if n_hit > 0u {
                // Misses sort last: their key is infinite, a hit's is finite.
                var d = select(vec4<f32>(inf), min(near, vec4<f32>(3.0e38)), hit);
                var i = vec4<u32>(0u, 1u, 2u, 3u);
                sort_pair(&d, &i, 0u, 1u);
                sort_pair(&d, &i, 2u, 3u);
                sort_pair(&d, &i, 0u, 2u);
                sort_pair(&d, &i, 1u, 3u);
                sort_pair(&d, &i, 1u, 2u);
                for (var k = n_hit - 1u; k > 0u; k--) {
                    stack_ref_LEVEL[sp] = child[i[k]];
                    stack_count_LEVEL[sp] = counts[i[k]];
                    stack_near_LEVEL[sp] = d[k];
                    sp += 1u;
                }
                cur = child[i[0]];
                count = counts[i[0]];
                pushed = true;
            }
        }
        if pushed {
            continue;
        }
        // Pop the next entry still in reach.
        var found = false;
        loop {
            if sp == 0u {
                break;
            }
            sp -= 1u;
            if stack_near_LEVEL[sp] <= closest {
                cur = stack_ref_LEVEL[sp];
                count = stack_count_LEVEL[sp];
                found = true;
                break;
            }
        }
        if !found {
            return best;
        }
    }
    return best;
}

fn traverse_kd_LEVEL(ray: Ray, root: u32, t_min: f32, t_max: f32, any: bool) -> Hit {
    var best = no_hit();
    var closest = t_max;
    // The tree's bounds sit in the two entries before its root.
    let bmin = bitcast<vec3<f32>>(nodes[root - 2u].xyz);
    let bmax = bitcast<vec3<f32>>(nodes[root - 1u].xyz);
    let sc = clip_box(bmin, bmax, ray, t_min, t_max);
    if sc.x > sc.y {
        return best;
    }
    let scene_max = sc.y;
    var stack: array<KdEntry, SHORT_STACK>;
    var top_i = 0u;
    var depth = 0u;
    var node = root;
    var lo = sc.x;
    var hi = sc.y;
    loop {
        // Descend to a leaf.
        loop {
            let n = nodes[node];
            if n.y == KD_LEAF {
                break;
            }
            let axis = n.y;
            let split = bitcast<f32>(n.x);
            let o = ray.origin[axis];
            let d = ray.dir[axis];
            let t_split = (split - o) * ray.inv_dir[axis];
            let below_first = o < split || (o == split && d <= 0.0);
            var first = n.z;
            var second = node + 1u;
            if below_first {
                first = node + 1u;
                second = n.z;
            }
            if t_split > hi || t_split <= 0.0 {
                node = first;
            } else if t_split < lo {
                node = second;
            } else {
                stack[top_i] = KdEntry(second, t_split, hi);
                top_i = (top_i + 1u) % SHORT_STACK;
                depth = min(depth + 1u, SHORT_STACK);
                node = first;
                hi = t_split;
            }
        }
        let leaf = nodes[node];
        for (var k = 0u; k < leaf.w; k++) {
            let h = test_prim_LEVEL(ray, prims[leaf.z + k], t_min, closest, any);
            if h.triangle != NO_HIT {
                best = h;
                closest = h.t;
                if any {
                    return best;
                }
            }
        }
        if closest <= hi {
            return best;
        }
        if depth == 0u {
            // Short stack empty: restart from the root past this leaf.
            if hi >= scene_max {
                return best;
            }
            node = root;
            lo = hi;
            hi = scene_max;
        } else {
            top_i = (top_i + SHORT_STACK - 1u) % SHORT_STACK;
            depth -= 1u;
            let e = stack[top_i];
            node = e.node;
            lo = e.lo;
            hi = e.hi;
        }
    }
    return best;
}

