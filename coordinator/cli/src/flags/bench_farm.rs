//! `sylva bench farm`. Flags only (clap).

use clap::Args;

#[derive(Debug, Args)]
pub struct FarmBenchArgs {
    /// Scene file.
    pub scene: std::path::PathBuf,
    /// Timed submissions (the median is reported, beside each).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Frame width.
    #[arg(long, default_value_t = 896)]
    pub width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 448)]
    pub height: u32,
    /// Rays per pixel.
    #[arg(long, default_value_t = 1)]
    pub spp: u32,
    /// Print JSON (always JSON; accepted for scripts).
    #[arg(long)]
    pub json: bool,
}
