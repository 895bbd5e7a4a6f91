// D3Q19 lattice-Boltzmann light transport: one step (pull streaming, then
// collision) and per-node totals. Dispatched by worker/src/lb/gpu_solver.rs.
//
// This file is a template: worker/src/lb/codegen.rs fills each `{{NAME}}`
// with code generated from the grid size, the storage layout and the
// channel's collision matrices, so every direction is unrolled and every
// Ω entry is a literal (a runtime loop over a private array is about 4×
// slower on lavapipe, and Ω re-read from memory slower still).
//
// State layout (shared with the CPU reference): direction-major, node index
// x + NX * (y + NY * z). Direction m lives in buffer m / DIRS_PER_BUFFER at
// offset (m % DIRS_PER_BUFFER) * NODES, so no binding exceeds the
// adapter's storage-binding limit.

const NX: u32 = {{NX}}u;
const NY: u32 = {{NY}}u;
const NZ: u32 = {{NZ}}u;
const NODES: u32 = {{NODES}}u;
// Invocations per dispatch row: the flat node index is gid.x + gid.y * ROW.
const ROW: u32 = {{ROW}}u;
const WORKGROUP: u32 = {{WORKGROUP}}u;

const CLASS_GREEN: u32 = 1u;
const CLASS_BROWN: u32 = 2u;

{{BINDINGS}}

fn is_boundary(idx: u32) -> bool {
    let x = idx % NX;
    let y = (idx / NX) % NY;
    let z = idx / (NX * NY);
    return x == 0u || y == 0u || z == 0u || x == NX - 1u || y == NY - 1u || z == NZ - 1u;
}

// Boundary nodes hold the sun's and sky's densities, and flow into them
// (or off the lattice) is dropped; over a reflecting ground the bottom
// face's nodes off the other faces re-emit upward what arrives downward
// (GroundReflection in shared/light/src/lb/boundary.rs). Interior nodes pull
// f_m(r - c_m), which always lies on the lattice.
@compute @workgroup_size(WORKGROUP)
fn step(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = gid.x + gid.y * ROW;
    if idx >= NODES {
        return;
    }
    if is_boundary(idx) {
{{GROUND}}
        return;
    }
{{GATHER}}
    let rho = density[idx];
    let kind = node_class[idx];
{{DECLARE_OUT}}
    if kind == CLASS_BROWN {
{{COLLIDE_BROWN}}
    } else {
{{COLLIDE_MEDIUM}}
    }
    // Green nodes: the light a leaf absorbs leaves the visible spectrum.
    if kind == CLASS_GREEN {
        o0 = 0.0;
    }
{{STORE}}
}

// The starting state (both copies, one dispatch each): boundary nodes hold
// the light that enters, interior nodes nothing. Written here rather than
// uploaded, so a solve sends 2 × 19 floats, not 2 × 19 per node.
@compute @workgroup_size(WORKGROUP)
fn init(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = gid.x + gid.y * ROW;
    if idx >= NODES {
        return;
    }
    let edge = is_boundary(idx);
{{INIT}}
}

var<workgroup> wg_partial: array<f32, WORKGROUP>;

// Writes each node's incoming field sum_m f_m(r - c_m) (what arrives
// before the collision; boundary nodes their fixed values), in direction
// order as the CPU reference sums, and per workgroup a partial sum of the
// state itself for the convergence measure (the CPU step's own sum).
@compute @workgroup_size(WORKGROUP)
fn totals(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let idx = gid.x + gid.y * ROW;
    var t = 0.0;
    if idx < NODES {
        t = {{SUM}};
        if is_boundary(idx) {
            node_total[idx] = t;
        } else {
            node_total[idx] = {{INCOMING}};
        }
    }
    wg_partial[lid] = t;
    workgroupBarrier();
    for (var stride = WORKGROUP / 2u; stride > 0u; stride = stride / 2u) {
        if lid < stride {
            wg_partial[lid] = wg_partial[lid] + wg_partial[lid + stride];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        group_sum[wid.x + wid.y * groups.x] = wg_partial[0];
    }
}
