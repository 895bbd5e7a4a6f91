//! `sylva compare`. Flags only (clap), and their conversion to settings.

use clap::Args;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct CompareArgs {
    /// Scene file (JSON).
    pub scene: PathBuf,
    /// Image width.
    #[arg(long, default_value_t = 448)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 224)]
    pub height: u32,
    /// Rays per pixel of the direct methods (the reference takes as many as it needs).
    #[arg(long, default_value_t = 4)]
    pub spp: u32,
    /// LB grid sizes to compare.
    #[arg(long, value_delimiter = ',', default_value = "16,32,64,128")]
    pub grids: Vec<usize>,
    /// Gather rays per pixel of the final gathers (each a variant, one and
    /// two bounces deep).
    #[arg(long, value_delimiter = ',', default_value = "4,16")]
    pub gather_rays: Vec<u32>,
    /// Filter radii (pixels) of the final gathers, each a variant (0: unfiltered).
    #[arg(long, value_delimiter = ',', default_value = "0,3")]
    pub gather_filters: Vec<u32>,
    /// Also say which method is the most accurate within this many seconds
    /// of pre-process and frame (the Pareto front says it for every budget).
    #[arg(long)]
    pub budget: Option<f64>,
    /// `lb auto`: the largest relative difference from the next finer grid it accepts.
    #[arg(long, default_value_t = 0.2)]
    pub auto_tolerance: f64,
    /// The reference stops once its own relative standard error is below this.
    #[arg(long, default_value_t = 0.02)]
    pub target_error: f64,
    /// The reference stops after this many seconds, converged or not.
    #[arg(long, default_value_t = 600.0)]
    pub max_seconds: f64,
    /// Also run the LB failure-mode sweeps (LB against Monte Carlo on small media).
    #[arg(long)]
    pub sweeps: bool,
    /// Folder for the images, grid and sweep charts.
    #[arg(long, default_value = "sylva-out/compare")]
    pub out: PathBuf,
    /// The error-against-time chart (SVG); default OUT/compare.svg.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Reuse OUT/reference.bin when it was made for the same scene bundle,
    /// image size, reference budget and `sylva` binary (it is always saved):
    /// re-running the fast methods then skips the path tracer.
    #[arg(long)]
    pub reuse_reference: bool,
    /// Also write every image as linear float32 `.npy` (height × width × 3)
    /// beside its PNG, and the reference's local light, indirect variance
    /// and coverage, for analysis outside Sylva.
    #[arg(long)]
    pub hdr: bool,
    /// Print the table as JSON.
    #[arg(long)]
    pub json: bool,
}
