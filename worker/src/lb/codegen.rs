//! Generates the LB kernels' WGSL from `shaders/lb/step.wgsl`: every
//! direction unrolled, every Ω entry a literal, zero entries dropped.

use std::fmt::Write;
use sylva_light::lb::collision::{PAIRS, PairedOmega};
use sylva_light::lb::lattice::{DIRECTIONS, Q};
use sylva_light::lb::{Boundary, Collision, GridDims, GroundReflection};

/// The kernel template.
const TEMPLATE: &str = include_str!("../../../shaders/lb/step.wgsl");
/// Invocations per workgroup (64 and 128 measured alike on lavapipe).
pub const WORKGROUP: u32 = 64;
/// Largest dispatch extent per dimension that every backend allows.
const MAX_GROUPS_PER_DIM: u32 = 65_535;

/// How a grid's state is split over storage bindings and dispatched.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StateLayout {
    /// The lattice.
    pub dims: GridDims,
    /// Directions stored in each binding.
    pub dirs_per_buffer: usize,
    /// Bindings per state copy.
    pub buffers: usize,
    /// Workgroups dispatched along x and y.
    pub groups: [u32; 2],
}

/// A grid this adapter cannot hold.
#[derive(Debug, thiserror::Error)]
pub enum LayoutError {
    /// One direction's array alone exceeds a storage binding.
    #[error(
        "grid {dims} needs {need} bytes per direction, more than this adapter's {limit}-byte storage-binding limit"
    )]
    DirectionTooLarge { dims: GridDims, need: u64, limit: u64 },
    /// Too many bindings for the adapter.
    #[error(
        "grid {dims} needs {need} storage buffers per shader stage; this adapter allows {limit}"
    )]
    TooManyBindings { dims: GridDims, need: u32, limit: u32 },
    /// Indices would overflow the kernel's u32 arithmetic.
    #[error("grid {0} is too large for 32-bit node indices")]
    TooManyNodes(GridDims),
}

impl StateLayout {
    /// The layout with the fewest bindings that respects `limits`.
    pub fn new(dims: GridDims, limits: &wgpu::Limits) -> Result<Self, LayoutError> {
        let nodes = dims.len() as u64;
        if nodes * Q as u64 >= u32::MAX as u64 {
            return Err(LayoutError::TooManyNodes(dims));
        }
        let per_dir = nodes * 4;
        let limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        if per_dir > limit {
            return Err(LayoutError::DirectionTooLarge { dims, need: per_dir, limit });
        }
        let dirs_per_buffer = ((limit / per_dir) as usize).min(Q);
        let buffers = Q.div_ceil(dirs_per_buffer);
        // Two state copies, density, class, node totals, group sums, light in.
        let need = 2 * buffers as u32 + 5;
        if need > limits.max_storage_buffers_per_shader_stage {
            return Err(LayoutError::TooManyBindings {
                dims,
                need,
                limit: limits.max_storage_buffers_per_shader_stage,
            });
        }
        let total_groups = (nodes as u32).div_ceil(WORKGROUP);
        let gx = total_groups.min(MAX_GROUPS_PER_DIM);
        let groups = [gx, total_groups.div_ceil(gx)];
        Ok(Self { dims, dirs_per_buffer, buffers, groups })
    }

    /// The binding and element offset holding direction `m`.
    pub fn location(&self, m: usize) -> (usize, usize) {
        (m / self.dirs_per_buffer, (m % self.dirs_per_buffer) * self.dims.len())
    }

    /// Directions held by binding `b`.
    pub fn dirs_in(&self, b: usize) -> std::ops::Range<usize> {
        b * self.dirs_per_buffer..((b + 1) * self.dirs_per_buffer).min(Q)
    }

    /// Invocations per dispatch row.
    pub fn row(&self) -> u32 {
        self.groups[0] * WORKGROUP
    }

    /// Number of workgroups (and of group sums).
    pub fn group_count(&self) -> u32 {
        self.groups[0] * self.groups[1]
    }

    /// Binding numbers: state copies `0..B` (read) and `B..2B` (written),
    /// then density, class, node totals, group sums, and the light that
    /// enters ([`light_in`]).
    pub fn binding_density(&self) -> u32 {
        2 * self.buffers as u32
    }
}

/// The light that enters a lattice, as the kernels read it (binding
/// `binding_density() + 4`): per direction the boundary density, then per
/// direction the reflecting ground's emission per unit irradiance (zeros
/// without a ground). The sun lives here rather than in the generated
/// code, so a new sun compiles nothing.
pub fn light_in(boundary: &Boundary) -> [f32; 2 * Q] {
    let emit = boundary.ground.map_or([0.0; Q], |g| g.emit());
    std::array::from_fn(|i| if i < Q { boundary.values[i] } else { emit[i - Q] })
}

/// The WGSL for one channel's collision matrices on `layout`, with the
/// bottom face reflecting when `ground` (its emission is read from
/// [`light_in`]).
pub fn step_shader(layout: &StateLayout, collision: &Collision, ground: bool) -> String {
    let d = layout.dims;
    let b = layout.buffers;
    let mut bindings = String::new();
    for i in 0..b {
        writeln!(bindings, "@group(0) @binding({i}) var<storage, read> src{i}: array<f32>;")
            .unwrap();
    }
    for i in 0..b {
        writeln!(
            bindings,
            "@group(0) @binding({}) var<storage, read_write> dst{i}: array<f32>;",
            b + i
        )
        .unwrap();
    }
    let base = layout.binding_density();
    writeln!(bindings, "@group(0) @binding({base}) var<storage, read> density: array<f32>;")
        .unwrap();
    writeln!(
        bindings,
        "@group(0) @binding({}) var<storage, read> node_class: array<u32>;",
        base + 1
    )
    .unwrap();
    writeln!(
        bindings,
        "@group(0) @binding({}) var<storage, read_write> node_total: array<f32>;",
        base + 2
    )
    .unwrap();
    writeln!(
        bindings,
        "@group(0) @binding({}) var<storage, read_write> group_sum: array<f32>;",
        base + 3
    )
    .unwrap();
    writeln!(bindings, "@group(0) @binding({}) var<storage, read> light_in: array<f32>;", base + 4)
        .unwrap();

    let mut gather = String::new();
    let mut store = String::new();
    let mut declare = String::new();
    let mut sum = Vec::new();
    let mut incoming = Vec::new();
    let mut init = String::new();
    for (m, &c) in DIRECTIONS.iter().enumerate() {
        let (buf, at) = layout.location(m);
        let off = d.offset(c);
        let shift = pull_shift(off);
        writeln!(gather, "    let f{m} = src{buf}[{at}u + idx{shift}];").unwrap();
        writeln!(store, "    dst{buf}[{at}u + idx] = o{m};").unwrap();
        writeln!(init, "    dst{buf}[{at}u + idx] = select(0.0, light_in[{m}u], edge);").unwrap();
        writeln!(declare, "    var o{m}: f32;").unwrap();
        sum.push(format!("src{buf}[{at}u + idx]"));
        incoming.push(format!("src{buf}[{at}u + idx{shift}]"));
    }
    let ground = if ground { ground_code(layout) } else { String::new() };
    TEMPLATE
        .replace("{{NX}}", &d.nx.to_string())
        .replace("{{NY}}", &d.ny.to_string())
        .replace("{{NZ}}", &d.nz.to_string())
        .replace("{{NODES}}", &d.len().to_string())
        .replace("{{ROW}}", &layout.row().to_string())
        .replace("{{WORKGROUP}}", &WORKGROUP.to_string())
        .replace("{{BINDINGS}}", &bindings)
        .replace("{{GATHER}}", gather.trim_end())
        .replace("{{DECLARE_OUT}}", declare.trim_end())
        .replace("{{COLLIDE_MEDIUM}}", &collide(&collision.medium))
        .replace("{{COLLIDE_BROWN}}", &collide(&collision.brown))
        .replace("{{STORE}}", store.trim_end())
        .replace("{{INIT}}", init.trim_end())
        .replace("{{GROUND}}", &ground)
        .replace("{{SUM}}", &sum.join(" + "))
        .replace("{{INCOMING}}", &incoming.join(" + "))
}

/// The index arithmetic that pulls from `r − c` for a direction of node offset `off`.
fn pull_shift(off: isize) -> String {
    match off {
        0 => String::new(),
        o if o > 0 => format!(" - {o}u"),
        o => format!(" + {}u", -o),
    }
}

/// The reflecting ground for nodes of the bottom face off the other faces:
/// `e = Σ collect_m f_m(r − c_m)` over downward directions, in direction
/// order as the CPU reference sums, then `emit_m × e` upward where
/// `emit_m` is not zero (as the CPU reference skips it).
fn ground_code(layout: &StateLayout) -> String {
    let d = layout.dims;
    let collect = GroundReflection::collect();
    let mut terms = Vec::new();
    let mut stores = String::new();
    for (m, &c) in DIRECTIONS.iter().enumerate() {
        let (buf, at) = layout.location(m);
        if collect[m] != 0.0 {
            terms.push(format!(
                "{} * src{buf}[{at}u + idx{}]",
                literal(collect[m]),
                pull_shift(d.offset(c))
            ));
        }
        if DIRECTIONS[m][1] > 0 {
            let w = Q + m;
            writeln!(
                stores,
                "            if light_in[{w}u] != 0.0 {{ dst{buf}[{at}u + idx] = light_in[{w}u] * e; }}"
            )
            .unwrap();
        }
    }
    format!(
        "        let gx = idx % NX;\n        let gz = idx / (NX * NY);\n        if (idx / NX) % NY == 0u && gx > 0u && gz > 0u && gx < NX - 1u && gz < NZ - 1u {{\n            let e = {};\n{}        }}",
        terms.join(" + "),
        stores
    )
}

/// `o_m = f_m + rho * (Σ_n Ω[m][n] f_n)` in Ω's pair form, with the CPU
/// reference's order of fused multiply-adds (`PairedOmega::apply`); zero
/// coefficients are left out (a fused add of 0 · x changes nothing).
fn collide(w: &PairedOmega) -> String {
    let mut out = String::new();
    // A chain of fma over the non-zero terms, starting from `start`.
    let chain = |start: String, terms: &[(f32, String)]| {
        terms
            .iter()
            .filter(|(c, _)| *c != 0.0)
            .fold(start, |acc, (c, x)| format!("fma({}, {x}, {acc})", literal(*c)))
    };
    for b in 0..PAIRS {
        let (j, jb) = (2 * b + 1, 2 * b + 2);
        writeln!(out, "        let s{b} = f{j} + f{jb};\n        let d{b} = f{j} - f{jb};")
            .unwrap();
    }
    let rest_terms: Vec<(f32, String)> = (0..PAIRS)
        .flat_map(|b| [(w.rest_even[b], format!("s{b}")), (w.rest_odd[b], format!("d{b}"))])
        .collect();
    let rest = chain(format!("{} * f0", literal(w.from_rest[0])), &rest_terms);
    writeln!(out, "        o0 = fma(rho, {rest}, f0);").unwrap();
    for a in 0..PAIRS {
        let even = chain(
            "0.0".into(),
            &(0..PAIRS).map(|b| (w.even[a][b], format!("s{b}"))).collect::<Vec<_>>(),
        );
        let odd = chain(
            "0.0".into(),
            &(0..PAIRS).map(|b| (w.odd[a][b], format!("d{b}"))).collect::<Vec<_>>(),
        );
        let (i, ib) = (2 * a + 1, 2 * a + 2);
        writeln!(out, "        let e{a} = {even};\n        let q{a} = {odd};").unwrap();
        writeln!(
            out,
            "        o{i} = fma(rho, fma({}, f0, e{a} + q{a}), f{i});",
            literal(w.from_rest[i])
        )
        .unwrap();
        writeln!(
            out,
            "        o{ib} = fma(rho, fma({}, f0, e{a} - q{a}), f{ib});",
            literal(w.from_rest[ib])
        )
        .unwrap();
    }
    out.trim_end().to_string()
}

/// A WGSL f32 literal that parses to exactly `v`.
fn literal(v: f32) -> String {
    // Debug prints the shortest decimal that round-trips.
    let s = format!("{v:?}");
    if v < 0.0 { format!("({s}f)") } else { format!("{s}f") }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_light::lb::ChannelParams;

    fn validate(src: &str) {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{}\n{src}", e.emit_to_string(src)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{e:?}"));
    }

    fn limits(binding: u64) -> wgpu::Limits {
        wgpu::Limits {
            max_storage_buffer_binding_size: binding,
            max_storage_buffers_per_shader_stage: 32,
            max_buffer_size: 1 << 32,
            ..wgpu::Limits::default()
        }
    }

    #[test]
    fn generated_kernels_are_valid_wgsl_for_every_layout() {
        let coll = Collision::new(&ChannelParams { sigma_a: 0.109, sigma_s: 0.891, g: -0.12 });
        for (n, binding) in [(8usize, 128u64 << 20), (128, 128 << 20), (64, 2 << 20)] {
            let layout = StateLayout::new(GridDims::cube(n), &limits(binding)).unwrap();
            validate(&step_shader(&layout, &coll, false));
            validate(&step_shader(&layout, &coll, true));
        }
    }

    #[test]
    fn large_grids_split_across_bindings() {
        let layout = StateLayout::new(GridDims::cube(128), &limits(128 << 20)).unwrap();
        assert_eq!(layout.dirs_per_buffer, 16);
        assert_eq!(layout.buffers, 2);
        assert_eq!(layout.location(17), (1, 128 * 128 * 128));
        let small = StateLayout::new(GridDims::cube(32), &limits(128 << 20)).unwrap();
        assert_eq!(small.buffers, 1);
        let err = StateLayout::new(GridDims::cube(512), &limits(128 << 20)).unwrap_err();
        assert!(err.to_string().contains("storage-binding limit"), "{err}");
    }

    #[test]
    fn literals_round_trip() {
        for v in [1.0f32 / 12.0, -0.891, 1e-7, 0.0375, -1.0] {
            let s = literal(v);
            let parsed: f32 =
                s.trim_matches(|c| c == '(' || c == ')').trim_end_matches('f').parse().unwrap();
            assert_eq!(parsed, v, "{s}");
        }
    }
}
