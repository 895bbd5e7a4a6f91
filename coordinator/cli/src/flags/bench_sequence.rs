//! `sylva bench sequence`. Flags only (clap), and their conversion to settings.

use clap::Args;

#[derive(Debug, Args)]
pub struct SequenceBenchArgs {
    /// Scene file.
    pub scene: std::path::PathBuf,
    /// Frames in each sequence.
    #[arg(long, default_value_t = 24)]
    pub frames: u32,
    /// Local worker processes.
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// Frame width.
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 160)]
    pub height: u32,
    /// Rays per pixel of the camera path and of the sweep's final pass (its
    /// preview pass has 1).
    #[arg(long, default_value_t = 2)]
    pub spp: u32,
    /// The sun sweep: first position, ELEVATION,AZIMUTH in degrees.
    #[arg(long, default_value = "15,90")]
    pub sun_from: String,
    /// The sun sweep: last position.
    #[arg(long, default_value = "60,200")]
    pub sun_to: String,
    /// Print JSON (always JSON; accepted for scripts).
    #[arg(long)]
    pub json: bool,
}
