//! The CPU reference solver: the same pull-style step, state layout and f32
//! arithmetic as the GPU kernel, spread over cores with rayon.
//!
//! One step, for every interior node `r`: gather `f_m(r − c_m)` from the
//! previous state (streaming), then collide, `f'_m = f_m + ρ Σ_n Ω[m][n] f_n`
//! with Ω in its pair form ([`PairedOmega`]), zero `f'_0` at green nodes,
//! and store. Boundary
//! nodes are never written, so they hold the sun's densities for the whole
//! solve, and flow into them or off the lattice is dropped.

use super::boundary::{Boundary, GroundReflection};
use super::collision::{Collision, PAIRS, PairedOmega};
use super::lattice::{DIRECTIONS, Q};
use super::medium::{MediumGrid, NodeClass};
use super::params::ChannelParams;
use super::solver::{
    ChannelSolution, Convergence, LightingSolver, PhaseTimer, SolveOptions, SolverError,
    initial_state,
};
use rayon::prelude::*;

/// Nodes collided together: two AVX2 registers per direction (measured
/// 52 MLUPS against 46 with 8 lanes at 64³ on 2 cores).
const LANES: usize = 16;

/// The CPU reference solver.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuSolver;

impl LightingSolver for CpuSolver {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }

    fn solve_channel(
        &mut self,
        medium: &MediumGrid,
        params: &ChannelParams,
        boundary: &Boundary,
        opts: &SolveOptions,
        progress: &dyn Fn(usize, usize),
    ) -> Result<ChannelSolution, SolverError> {
        let mut phases = PhaseTimer::default();
        let mut lattice = phases.time("set-up", || CpuLattice::new(medium, params, boundary));
        let mut conv = Convergence::new(*opts, medium.dims);
        let steps = phases.time("steps", || {
            let mut step = 0;
            while step < conv.cap() {
                step += 1;
                let total = lattice.step(conv.wants_total(step));
                if step % 8 == 0 || step == conv.cap() {
                    progress(step, conv.cap());
                }
                if let Some(t) = total
                    && conv.record(step, t)
                {
                    break;
                }
            }
            step
        });
        let total = phases.time("totals", || lattice.node_totals());
        Ok(conv.finish(steps, total, phases))
    }
}

/// The lattice state of one channel on the CPU, stepped explicitly; the
/// verification experiments (pulses, beams) drive it directly.
pub struct CpuLattice<'m> {
    medium: &'m MediumGrid,
    collision: Collision,
    /// Direction-major state: `state[m · n + node]`.
    state: Vec<f32>,
    next: Vec<f32>,
    /// `(collect, emit)` weights of a reflecting lower face.
    ground: Option<([f32; Q], [f32; Q])>,
}

/// A raw pointer the row workers write disjoint ranges through.
#[derive(Clone, Copy)]
struct RowWriter(*mut f32);
// SAFETY: each (y, z) row writes only its own x range of each direction.
unsafe impl Send for RowWriter {}
unsafe impl Sync for RowWriter {}

/// What every row of one step reads and writes: the state of `n` nodes
/// per direction, where the new state goes, the streaming offsets, and
/// what the nodes are made of.
#[derive(Clone, Copy)]
struct StepData<'a> {
    src: &'a [f32],
    dst: RowWriter,
    n: usize,
    offsets: &'a [isize; Q],
    medium: &'a MediumGrid,
    coll: &'a Collision,
    /// Whether the new densities' sum is wanted.
    want_total: bool,
}

impl<'m> CpuLattice<'m> {
    /// A lattice at the boundary-lit zero state.
    pub fn new(medium: &'m MediumGrid, params: &ChannelParams, boundary: &Boundary) -> Self {
        let state = initial_state(medium.dims, boundary);
        let next = state.clone();
        let ground = boundary.ground.map(|g| (GroundReflection::collect(), g.emit()));
        Self { medium, collision: Collision::new(params), state, next, ground }
    }

    /// The direction-major state, `state[m · n + node]`.
    pub fn state(&self) -> &[f32] {
        &self.state
    }

    /// Mutable state, for experiments that start from a pulse. Boundary
    /// nodes must keep equal values in both buffers; only set interior nodes.
    pub fn state_mut(&mut self) -> &mut [f32] {
        &mut self.state
    }

    /// The incoming field per node, `Σ_m f_m(r − c_m)`: what arrives at
    /// each node before it collides (the model's equation reads a node's
    /// density there; after the collision a green node has already lost
    /// what its leaves absorbed). Boundary nodes report their fixed values.
    /// Summed in direction order in f32, as the GPU does.
    pub fn node_totals(&self) -> Vec<f32> {
        let dims = self.medium.dims;
        let n = dims.len();
        let offsets: [isize; Q] = std::array::from_fn(|m| dims.offset(DIRECTIONS[m]));
        (0..n)
            .into_par_iter()
            .map(|i| {
                let (x, y, z) = (i % dims.nx, (i / dims.nx) % dims.ny, i / (dims.nx * dims.ny));
                let boundary = dims.is_boundary(x, y, z);
                let mut s = 0.0f32;
                for m in 0..Q {
                    let from = if boundary { i } else { (i as isize - offsets[m]) as usize };
                    s += self.state[m * n + from];
                }
                s
            })
            .collect()
    }

    /// Runs one step; with `want_total`, returns Σ over nodes and
    /// directions of the new state.
    pub fn step(&mut self, want_total: bool) -> Option<f64> {
        let dims = self.medium.dims;
        let n = dims.len();
        let offsets: [isize; Q] = std::array::from_fn(|m| dims.offset(DIRECTIONS[m]));
        let step = StepData {
            src: &self.state,
            dst: RowWriter(self.next.as_mut_ptr()),
            n,
            offsets: &offsets,
            medium: self.medium,
            coll: &self.collision,
            want_total,
        };
        let interior: f64 = (1..dims.nz - 1)
            .into_par_iter()
            .map(|z| {
                let mut sum = 0.0;
                for y in 1..dims.ny - 1 {
                    let base = dims.index(1, y, z);
                    sum += update_row(&step, base, dims.nx - 2);
                }
                sum
            })
            .sum();
        self.reflect_ground();
        std::mem::swap(&mut self.state, &mut self.next);
        want_total.then(|| interior + self.boundary_total())
    }

    /// The bottom face's nodes off the other faces (the ground under the
    /// interior) send up what their downward directions bring.
    fn reflect_ground(&mut self) {
        let Some((collect, emit)) = self.ground else { return };
        let dims = self.medium.dims;
        let n = dims.len();
        let offsets: [isize; Q] = std::array::from_fn(|m| dims.offset(DIRECTIONS[m]));
        for z in 1..dims.nz - 1 {
            for x in 1..dims.nx - 1 {
                let node = dims.index(x, 0, z);
                let mut e = 0.0f32;
                for m in 0..Q {
                    if collect[m] != 0.0 {
                        e += collect[m]
                            * self.state[((m * n + node) as isize - offsets[m]) as usize];
                    }
                }
                for m in 0..Q {
                    if emit[m] != 0.0 {
                        self.next[m * n + node] = emit[m] * e;
                    }
                }
            }
        }
    }

    fn boundary_total(&self) -> f64 {
        let d = self.medium.dims;
        let n = d.len();
        let shell = n - (d.nx - 2) * (d.ny - 2) * (d.nz - 2);
        let node_sum = |i: usize| (0..Q).map(|m| self.state[m * n + i] as f64).sum::<f64>();
        // Node 0 is a corner: it always holds the fixed values.
        let per_node = node_sum(0);
        if self.ground.is_none() {
            return shell as f64 * per_node;
        }
        let ground: f64 = (1..d.nz - 1)
            .flat_map(|z| (1..d.nx - 1).map(move |x| d.index(x, 0, z)))
            .map(node_sum)
            .sum();
        (shell - (d.nx - 2) * (d.nz - 2)) as f64 * per_node + ground
    }
}

/// Streams and collides `len` nodes starting at node `base`; returns the sum
/// of their new densities when asked. Runs the AVX2 + FMA build of the same
/// code where the processor has it (fused multiply-adds, as the GPU's
/// `fma`); elsewhere separate multiplies and adds.
fn update_row(step: &StepData, base: usize, len: usize) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the processor supports AVX2 and FMA, checked just above.
        return unsafe { update_row_avx2(step, base, len) };
    }
    update_row_portable::<false>(step, base, len)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn update_row_avx2(step: &StepData, base: usize, len: usize) -> f64 {
    update_row_portable::<true>(step, base, len)
}

/// `a · b + c`, fused when `FMA` (inside the FMA build only: elsewhere a
/// fused multiply-add is a library call).
#[inline(always)]
fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

#[inline(always)]
fn update_row_portable<const FMA: bool>(step: &StepData, base: usize, len: usize) -> f64 {
    // Scratch reused by every block of the row.
    let mut f = [[0.0f32; LANES]; Q];
    let mut out = [[0.0f32; LANES]; Q];
    if len < LANES {
        return block::<FMA, false>(step, base, len, 0, &mut f, &mut out);
    }
    // Whole blocks only, the last one overlapping its neighbour (its
    // nodes are recomputed to the same values), so every copy has a
    // constant length: inlined vector moves rather than library calls.
    let mut sum = 0.0f64;
    let mut x = 0;
    while x < len {
        let start = x.min(len - LANES);
        sum += block::<FMA, true>(step, base + start, LANES, x - start, &mut f, &mut out);
        x += LANES;
    }
    sum
}

/// Streams and collides the `lanes` nodes from `node` (`LANES` of them
/// when `FULL`); returns the new densities' sum over lanes from `counted`
/// on, when asked.
#[inline(always)]
fn block<const FMA: bool, const FULL: bool>(
    step: &StepData,
    node: usize,
    lanes: usize,
    counted: usize,
    f: &mut [[f32; LANES]; Q],
    out: &mut [[f32; LANES]; Q],
) -> f64 {
    let StepData { src, dst, n, offsets, medium, coll, want_total } = *step;
    let lanes = if FULL { LANES } else { lanes };
    for m in 0..Q {
        let start = ((m * n + node) as isize - offsets[m]) as usize;
        f[m][..lanes].copy_from_slice(&src[start..start + lanes]);
        prefetch_ahead(src.as_ptr().wrapping_add(start), dst.0.wrapping_add(m * n + node));
    }
    let rho = &medium.density[node..node + lanes];
    let class = &medium.class[node..node + lanes];
    let res = if rho.iter().any(|&r| r != 0.0) {
        if class.iter().all(|&c| c == class[0]) {
            let mut r = [0.0f32; LANES];
            r[..lanes].copy_from_slice(rho);
            collide_lanes::<FMA>(f, &r, omega_for(coll, class[0]), out);
            if class[0] == NodeClass::Green {
                out[0] = [0.0; LANES];
            }
        } else {
            *out = *f;
            for k in 0..lanes {
                collide_one::<FMA>(f, k, rho[k], omega_for(coll, class[k]), class[k], out);
            }
        }
        &*out
    } else {
        &*f
    };
    for m in 0..Q {
        // SAFETY: `node..node + lanes` lies in this row, which no other
        // worker writes; `m · n + node + lanes ≤ Q · n`.
        unsafe {
            std::ptr::copy_nonoverlapping(res[m].as_ptr(), dst.0.add(m * n + node), lanes);
        }
    }
    let mut sum = 0.0;
    if want_total {
        for k in counted..lanes {
            sum += (0..Q).map(|m| res[m][k] as f64).sum::<f64>();
        }
    }
    sum
}

/// How far ahead of a block its streams are prefetched, in nodes (four
/// blocks). The step reads 19 streams and writes 19 more, more than the
/// hardware prefetchers follow: at 128³ on 2 cores the step went from
/// about 60 to 100 MLUPS with this (0.35 to 0.6–0.7 of the triad), and
/// from 99 to 114 at 64³; 32 to 256 nodes ahead were all within 10 %.
const PREFETCH_AHEAD: usize = 4 * LANES;

/// Asks for the lines `PREFETCH_AHEAD` nodes past a block's read and
/// write positions (the write for ownership), so they arrive while this
/// block collides. A prefetch never faults, so addresses past the end of
/// the state are harmless.
#[inline(always)]
fn prefetch_ahead(read: *const f32, write: *mut f32) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetches only hint the cache; they never dereference.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_ET0, _MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(read.wrapping_add(PREFETCH_AHEAD) as *const i8);
        _mm_prefetch::<_MM_HINT_ET0>(write.wrapping_add(PREFETCH_AHEAD) as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (read, write);
}

fn omega_for(coll: &Collision, class: NodeClass) -> &PairedOmega {
    match class {
        NodeClass::Brown => &coll.brown,
        NodeClass::Medium | NodeClass::Green => &coll.medium,
    }
}

/// `out_m = f_m + ρ · Σ_n Ω[m][n] f_n` for all lanes at once, in the
/// order of [`PairedOmega::apply`].
#[inline(always)]
fn collide_lanes<const FMA: bool>(
    f: &[[f32; LANES]; Q],
    rho: &[f32; LANES],
    w: &PairedOmega,
    out: &mut [[f32; LANES]; Q],
) {
    let mut s = [[0.0f32; LANES]; PAIRS];
    let mut d = [[0.0f32; LANES]; PAIRS];
    for b in 0..PAIRS {
        for k in 0..LANES {
            s[b][k] = f[2 * b + 1][k] + f[2 * b + 2][k];
            d[b][k] = f[2 * b + 1][k] - f[2 * b + 2][k];
        }
    }
    let mut rest = [0.0f32; LANES];
    for k in 0..LANES {
        rest[k] = w.from_rest[0] * f[0][k];
    }
    for b in 0..PAIRS {
        for k in 0..LANES {
            rest[k] = madd::<FMA>(w.rest_even[b], s[b][k], rest[k]);
            rest[k] = madd::<FMA>(w.rest_odd[b], d[b][k], rest[k]);
        }
    }
    for k in 0..LANES {
        out[0][k] = madd::<FMA>(rho[k], rest[k], f[0][k]);
    }
    for a in 0..PAIRS {
        let mut even = [0.0f32; LANES];
        let mut odd = [0.0f32; LANES];
        for b in 0..PAIRS {
            let (e, o) = (w.even[a][b], w.odd[a][b]);
            for k in 0..LANES {
                even[k] = madd::<FMA>(e, s[b][k], even[k]);
                odd[k] = madd::<FMA>(o, d[b][k], odd[k]);
            }
        }
        let (i, ib) = (2 * a + 1, 2 * a + 2);
        for k in 0..LANES {
            let p = madd::<FMA>(w.from_rest[i], f[0][k], even[k] + odd[k]);
            let q = madd::<FMA>(w.from_rest[ib], f[0][k], even[k] - odd[k]);
            out[i][k] = madd::<FMA>(rho[k], p, f[i][k]);
            out[ib][k] = madd::<FMA>(rho[k], q, f[ib][k]);
        }
    }
}

/// The same arithmetic for one lane whose class differs from its neighbours'.
#[inline(always)]
fn collide_one<const FMA: bool>(
    f: &[[f32; LANES]; Q],
    k: usize,
    rho: f32,
    w: &PairedOmega,
    class: NodeClass,
    out: &mut [[f32; LANES]; Q],
) {
    let acc = w.apply(&std::array::from_fn(|m| f[m][k]));
    for m in 0..Q {
        out[m][k] = madd::<FMA>(rho, acc[m], f[m][k]);
    }
    if class == NodeClass::Green {
        out[0][k] = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lb::{GridDims, Sun};

    #[test]
    fn vacuum_carries_the_boundary_light_unchanged() {
        // Non-cubic, so index arithmetic along each axis is exercised.
        let dims = GridDims { nx: 10, ny: 13, nz: 7 };
        let medium = MediumGrid::empty(dims);
        let sun = Sun::from_elevation_azimuth(35.0, 70.0, 2.0).unwrap();
        let b = sun.boundary();
        let mut lattice = CpuLattice::new(&medium, &ChannelParams::isotropic(0.1, 0.9), &b);
        for _ in 0..2 * dims.longest_edge() {
            lattice.step(false);
        }
        let n = dims.len();
        for i in 0..n {
            for m in 0..Q {
                assert_eq!(lattice.state()[m * n + i], b.values[m], "node {i} direction {m}");
            }
        }
    }

    #[test]
    fn green_nodes_absorb_and_medium_nodes_conserve() {
        let dims = GridDims::cube(12);
        let sun = Sun::default();
        let p = ChannelParams::isotropic(0.2, 0.8);
        let total = |class| {
            let medium = MediumGrid::uniform(dims, 1.0, class);
            let mut s = CpuSolver;
            s.solve_channel(
                &medium,
                &p,
                &sun.boundary(),
                &SolveOptions::fixed_steps(24),
                &|_, _| {},
            )
            .unwrap()
            .report
            .total_density
        };
        let (medium, green) = (total(NodeClass::Medium), total(NodeClass::Green));
        assert!(green < 0.8 * medium, "green {green} vs medium {medium}");
    }
}
