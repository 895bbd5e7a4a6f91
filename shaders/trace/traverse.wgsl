// The kd-tree's traversal of one level of the two-level structure, a
// template: worker/src/trace/shaders.rs instantiates it with LEVEL = top
// (leaves hold instances) and LEVEL = model (leaves hold triangles), since
// WGSL has no generics and forbids recursion. Mirrors shared/accel/src.

// The closest hit of the kd-tree rooted at `root` in (t_min, t_max); with
// `any`, the first hit found (shadow rays need no more). (The BVH walks
// both levels in one loop: bvh.wgsl.)
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

