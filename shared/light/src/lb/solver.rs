//! The seam between the LB model and the machines that solve it, with the
//! parts every solver shares: the state layout, the convergence rule and the
//! report.

use super::boundary::{Boundary, Sun};
use super::lattice::Q;
use super::medium::{GridDims, MediumGrid};
use super::params::{CHANNELS, ChannelParams, LbParams};
use serde::Serialize;
use std::time::Instant;

/// When to stop a solve.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SolveOptions {
    /// Step cap; `None` means the papers' 2 × the longest edge.
    pub max_steps: Option<usize>,
    /// Stop once the relative change of total density over one step falls
    /// below this; 0 runs every step up to the cap.
    pub tolerance: f64,
    /// Measure convergence every this many steps. Every solver uses the same
    /// rule, so CPU and GPU stop on the same step.
    pub check_every: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self { max_steps: None, tolerance: 1e-4, check_every: 8 }
    }
}

impl SolveOptions {
    /// Exactly `steps` steps, no early stop.
    pub fn fixed_steps(steps: usize) -> Self {
        Self { max_steps: Some(steps), tolerance: 0.0, check_every: 8 }
    }

    /// The step cap for a grid.
    pub fn cap(&self, dims: GridDims) -> usize {
        self.max_steps.unwrap_or(2 * dims.longest_edge())
    }
}

/// Tracks the relative change of total density between steps `t − 1` and
/// `t` for every `t` that is a multiple of `check_every`.
#[derive(Clone, Debug)]
pub struct Convergence {
    opts: SolveOptions,
    cap: usize,
    previous: Option<(usize, f64)>,
    /// The last measured relative change per step.
    pub last_change: Option<f64>,
}

impl Convergence {
    /// A monitor for a solve of `dims` with `opts`.
    pub fn new(opts: SolveOptions, dims: GridDims) -> Self {
        Self { opts, cap: opts.cap(dims), previous: None, last_change: None }
    }

    /// The step cap.
    pub fn cap(&self) -> usize {
        self.cap
    }

    /// Whether the solver must report the total density after `step`
    /// (steps count from 1).
    pub fn wants_total(&self, step: usize) -> bool {
        let k = self.opts.check_every.max(1);
        self.opts.tolerance > 0.0
            && (step.is_multiple_of(k) || (step + 1).is_multiple_of(k) || step == self.cap)
    }

    /// Records the total density after `step`; returns true when the solve
    /// should stop here.
    pub fn record(&mut self, step: usize, total: f64) -> bool {
        if let Some((s, prev)) = self.previous
            && s + 1 == step
        {
            self.last_change = Some(if total > 0.0 { (total - prev).abs() / total } else { 0.0 });
            if step.is_multiple_of(self.opts.check_every.max(1))
                && self.last_change.is_some_and(|c| c < self.opts.tolerance)
            {
                return true;
            }
        }
        self.previous = Some((step, total));
        false
    }

    /// The solution of a channel that ran `steps` steps and ended with
    /// per-node totals `total`.
    pub fn finish(&self, steps: usize, total: Vec<f32>, phases: PhaseTimer) -> ChannelSolution {
        let report = ChannelReport {
            steps,
            max_steps: self.cap,
            tolerance: self.opts.tolerance,
            final_change: self.last_change,
            converged: self.converged(),
            total_density: total.iter().map(|&v| v as f64).sum(),
            phases,
        };
        ChannelSolution { total, report }
    }

    /// Whether the last measured change was below the tolerance.
    pub fn converged(&self) -> bool {
        self.opts.tolerance > 0.0 && self.last_change.is_some_and(|c| c < self.opts.tolerance)
    }
}

/// Wall time of one phase of a solve.
#[derive(Clone, Debug, Serialize)]
pub struct Phase {
    /// What was done ("upload", "steps", ...).
    pub name: &'static str,
    /// Milliseconds.
    pub ms: f64,
}

/// Times phases in order.
#[derive(Clone, Debug, Default, Serialize)]
#[serde(transparent)]
pub struct PhaseTimer(pub Vec<Phase>);

impl PhaseTimer {
    /// Runs `f` and records its wall time as `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        self.0.push(Phase { name, ms: t.elapsed().as_secs_f64() * 1e3 });
        out
    }

    /// Milliseconds of the named phase (0 if absent).
    pub fn ms(&self, name: &str) -> f64 {
        self.0.iter().filter(|p| p.name == name).map(|p| p.ms).sum()
    }
}

/// What one channel's solve did.
#[derive(Clone, Debug, Serialize)]
pub struct ChannelReport {
    /// Steps run.
    pub steps: usize,
    /// The step cap in force.
    pub max_steps: usize,
    /// The tolerance in force (0: none).
    pub tolerance: f64,
    /// Relative change of total density over the last measured step.
    pub final_change: Option<f64>,
    /// Whether the solve stopped on the tolerance rather than the cap.
    pub converged: bool,
    /// Σ over nodes and directions at the end.
    pub total_density: f64,
    /// Wall time per phase.
    pub phases: PhaseTimer,
}

/// One channel's solved total density per node, `Σ_m f_m`.
#[derive(Clone, Debug)]
pub struct ChannelSolution {
    /// Per node, in grid order.
    pub total: Vec<f32>,
    /// How the solve went.
    pub report: ChannelReport,
}

/// All three channels.
#[derive(Clone, Debug)]
pub struct Solution {
    /// Grid the solution lives on.
    pub dims: GridDims,
    /// Red, green, blue.
    pub channels: Vec<ChannelSolution>,
}

/// What a [`LightingSolver`] fails with: its own error, boxed, so a GPU
/// solver's `?` on its own errors works (and `anyhow`'s, chain and all).
pub type SolverError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// A machine that runs the LB model: the CPU reference or the GPU.
pub trait LightingSolver {
    /// Short name for reports ("cpu", or the GPU adapter's name).
    fn name(&self) -> String;

    /// Solves one channel from the zero interior state with `boundary`
    /// held on the outer shell, calling `progress(step, cap)` as it goes. The
    /// medium and parameters are already validated by [`solve`].
    fn solve_channel(
        &mut self,
        medium: &MediumGrid,
        params: &ChannelParams,
        boundary: &Boundary,
        opts: &SolveOptions,
        progress: &dyn Fn(usize, usize),
    ) -> Result<ChannelSolution, SolverError>;
}

/// Validates the inputs, then solves the three colour channels in turn.
/// `progress(channel, step, cap)` follows the work.
pub fn solve(
    solver: &mut dyn LightingSolver,
    medium: &MediumGrid,
    params: &LbParams,
    sun: &Sun,
    opts: &SolveOptions,
    progress: &dyn Fn(usize, usize, usize),
) -> crate::Result<Solution> {
    params.validate()?;
    medium.validate()?;
    let boundary = sun.boundary();
    let mut channels = Vec::with_capacity(3);
    for (c, (p, name)) in params.channels.iter().zip(CHANNELS).enumerate() {
        let span = tracing::info_span!("lb_channel", channel = name, solver = %solver.name());
        let _g = span.enter();
        let s = solver
            .solve_channel(medium, p, &boundary, opts, &|step, cap| progress(c, step, cap))?;
        tracing::info!(steps = s.report.steps, change = ?s.report.final_change, "channel solved");
        channels.push(s);
    }
    Ok(Solution { dims: medium.dims, channels })
}

/// The starting state every solver uses, direction-major
/// (`state[m · n + node]`): boundary nodes hold the boundary densities,
/// interior nodes zero.
pub fn initial_state(dims: GridDims, boundary: &Boundary) -> Vec<f32> {
    let n = dims.len();
    let mut state = vec![0.0f32; Q * n];
    for z in 0..dims.nz {
        for y in 0..dims.ny {
            for x in 0..dims.nx {
                if dims.is_boundary(x, y, z) {
                    let i = dims.index(x, y, z);
                    for m in 0..Q {
                        state[m * n + i] = boundary.values[m];
                    }
                }
            }
        }
    }
    state
}

/// Bytes one node update reads and writes: 19 densities in and out, the
/// density and the class.
pub const BYTES_PER_NODE_UPDATE: usize = 2 * Q * 4 + 4 + 4;
