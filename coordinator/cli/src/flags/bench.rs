//! `sylva bench …`. Flags only (clap), and their conversion to settings.

use crate::flags::lb::Backend;
use clap::{Args, Subcommand, ValueEnum};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// The LB solve on the CPU reference and on the GPU, in one run.
    Lb(LbBenchArgs),
    /// Ray traversal (kd-tree and BVH, GPU and CPU) and frame time on the forest.
    Trace(TraceBenchArgs),
    /// Strip-scaling speedup over worker counts, static against dynamic.
    Scaling(ScalingBenchArgs),
    /// Sequences: a camera path as one job against one job per frame, and
    /// a sun sweep's second pass with the workers' LB cache against without.
    Sequence(crate::flags::bench_sequence::SequenceBenchArgs),
    /// Where one frame's time goes between `sylva submit` and its file, on
    /// one warm local worker: the farm's own overhead beside the trace.
    Farm(crate::flags::bench_farm::FarmBenchArgs),
}

/// What the benchmark solves.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum BenchMedium {
    /// Every node holds leaf matter of random density: every node collides,
    /// the plain D3Q19 step.
    Dense,
    /// The built-in plant voxelized: mostly empty space, as real models are.
    Plant,
}

#[derive(Debug, Args)]
pub struct LbBenchArgs {
    /// Grid size N (N³ nodes).
    #[arg(long, default_value_t = 64)]
    pub grid: usize,
    /// Medium to solve.
    #[arg(long, value_enum, default_value = "dense")]
    pub medium: BenchMedium,
    /// Backends to run, in order.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "cpu,gpu")]
    pub backends: Vec<Backend>,
    /// Timed repetitions per backend (the median is reported).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Print JSON (the default output is also JSON; this flag is accepted for scripts).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct TraceBenchArgs {
    /// Forest scale (instance count multiplier of the paper's Table 2).
    #[arg(long, default_value_t = 0.05)]
    pub scale: f64,
    /// Triangle count multiplier per tree.
    #[arg(long, default_value_t = 1.0)]
    pub triangle_scale: f64,
    /// Frame width.
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    /// Skip the CPU traversal (slow on big scenes).
    #[arg(long)]
    pub no_cpu: bool,
    /// Backends to measure, in order (`rq` is left out, and says so, where
    /// the adapter has no ray queries).
    #[arg(long, value_delimiter = ',', default_value = "kd,bvh,rq")]
    pub accel: Vec<sylva_scene::frame::Backend>,
    /// Skip the whole frames.
    #[arg(long)]
    pub no_frames: bool,
    /// Backends whose whole frames are rendered (default: those of
    /// `--accel`, less `rq` on a CPU adapter such as lavapipe, where a
    /// ray-query frame takes minutes; the output's `frames_left_out` says so).
    #[arg(long, value_delimiter = ',')]
    pub frames_accel: Option<Vec<sylva_scene::frame::Backend>>,
    /// Skip the time to the first frame (two `sylva render` processes, cold
    /// and then warm from the prepared-data cache).
    #[arg(long)]
    pub no_first_frame: bool,
    /// Also write the rays (`rays.npy`: origin and direction per row) and
    /// every instance's triangles that a ray can hit, flattened to world
    /// space (`triangles.npy`), for `benchmarks/embree.py`.
    #[arg(long)]
    pub export: Option<std::path::PathBuf>,
    /// Also time the CPU BVH over those flattened triangles, opaque, as
    /// one level: the setup `benchmarks/embree.py` gives Embree (memory
    /// grows with the instanced triangles: for small scales only).
    #[arg(long)]
    pub flat: bool,
    /// Rays each kernel timing casts at least (the frame's rays cast again
    /// and again in one GPU-timed pass), per ray kind and backend.
    #[arg(long, default_value_t = 4 << 20)]
    pub kernel_rays: u64,
    /// Print JSON (always JSON; accepted for scripts).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ScalingBenchArgs {
    /// Scene file.
    pub scene: std::path::PathBuf,
    /// Worker counts.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16")]
    pub workers: Vec<usize>,
    /// Schedules to compare.
    #[arg(long, value_delimiter = ',', default_value = "static,dynamic")]
    pub schedule: Vec<String>,
    /// Frame width.
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    /// Rays per pixel.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    /// Running workers for measured wall times (`host:port,…`); without them
    /// up to --local-real local workers are started for measured runs.
    #[arg(long = "real-workers", value_delimiter = ',')]
    pub real_workers: Vec<String>,
    /// The token the `--real-workers` require.
    #[command(flatten)]
    pub auth: crate::flags::security::TokenArgs,
    /// How to reach the `--real-workers` over TLS.
    #[command(flatten)]
    pub tls: crate::flags::security::ConnectTlsArgs,
    /// Largest worker count measured with local worker processes.
    #[arg(long, default_value_t = 2)]
    pub local_real: usize,
    /// Strips the frame is profiled in, one at a time.
    #[arg(long, default_value_t = 64)]
    pub profile_strips: u32,
    /// Where to draw the chart (SVG).
    #[arg(long, default_value = "sylva-out/scaling.svg")]
    pub chart: std::path::PathBuf,
    /// Print JSON (always JSON; accepted for scripts).
    #[arg(long)]
    pub json: bool,
}
