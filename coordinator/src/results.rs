//! Finished frames as files of the state folder (`results/JOB/FRAME.exr`
//! and `.png`), indexed in the database ([`crate::store`]) and forgotten,
//! files and rows, when their job is. A frame's linear EXR is written as
//! soon as its last strip is in; its PNG once the job's exposure is known
//! (a sequence's is its middle frame's), read back from the EXRs one frame
//! at a time: a job holds no more than the frames in flight.

use std::path::{Path, PathBuf};
use std::time::Duration;
use sylva_scene::film::HdrImage;

/// How long and how many finished jobs are kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Retention {
    /// A finished job is forgotten this long after it ended.
    pub keep: Duration,
    /// At most this many finished jobs are kept (oldest forgotten first).
    pub max_jobs: usize,
}

impl Default for Retention {
    fn default() -> Self {
        Self { keep: Duration::from_secs(3600), max_jobs: 1000 }
    }
}

/// A job's folder of results under the state folder `state`.
pub fn job_dir(state: &Path, id: &str) -> PathBuf {
    state.join("results").join(id)
}

/// A file of a job's results, relative to the state folder.
pub fn relative(id: &str, name: &str) -> String {
    format!("results/{id}/{name}")
}

/// An 8-bit sRGB image as PNG.
pub fn encode_png(w: u32, h: u32, px: &[[u8; 3]]) -> anyhow::Result<Vec<u8>> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    anyhow::ensure!(px.len() == w as usize * h as usize, "image size");
    let mut out = Vec::new();
    // Fast deflate: the PNG is a preview beside the EXR, and the default
    // level cost a frame more than its trace through the farm.
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(px.as_flattened(), w, h, image::ExtendedColorType::Rgb8)?;
    Ok(out)
}

/// A linear HDR image as OpenEXR (32-bit floats: read back bit for bit).
pub fn encode_exr(img: &HdrImage) -> anyhow::Result<Vec<u8>> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    let buf = image::Rgb32FImage::from_raw(img.width, img.height, flat)
        .ok_or_else(|| anyhow::anyhow!("image size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb32F(buf).write_to(&mut out, image::ImageFormat::OpenExr)?;
    Ok(out.into_inner())
}

/// The beauty image of an EXR this module (or, with passes,
/// [`sylva_scene::passes::encode_layers`]) wrote, read back.
pub fn decode_exr(bytes: &[u8]) -> anyhow::Result<HdrImage> {
    Ok(sylva_scene::passes::ExrLayers::read(bytes)?.beauty()?)
}

/// A result file's hash as the database keeps it: BLAKE3, hex.
pub fn hash(bytes: &[u8]) -> String {
    blake3::hash(bytes).to_hex().to_string()
}

/// A stored result read back and checked against the hash recorded when
/// it was written: a file changed or cut since reads as damaged, one
/// removed as missing; neither is ever served. (Rows from before hashes
/// were kept have none, and are served as they are.)
pub fn read_checked(state: &Path, rel: &str, want: &str) -> Result<Vec<u8>, ResultFault> {
    let bytes = std::fs::read(state.join(rel)).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => ResultFault::Missing,
        _ => ResultFault::Unreadable,
    })?;
    if !want.is_empty() && hash(&bytes) != want {
        return Err(ResultFault::Damaged);
    }
    Ok(bytes)
}

/// Why a stored result cannot be served.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResultFault {
    /// Its file is gone from the state folder.
    Missing,
    /// Its file cannot be read.
    Unreadable,
    /// Its bytes are not the ones written.
    Damaged,
}

impl std::fmt::Display for ResultFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ResultFault::Missing => "its file is missing from the coordinator's state folder",
            ResultFault::Unreadable => "its file cannot be read on the coordinator",
            ResultFault::Damaged => {
                "its file on the coordinator no longer matches what was written (damaged)"
            }
        })
    }
}

/// Writes `bytes` to `path` whole or not at all: a crash leaves the old
/// file or the new one, never half of one.
pub fn write_whole(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    let tmp = path.with_extension("part");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_comes_back_from_its_exr_bit_for_bit() {
        let mut img = HdrImage::new(7, 3);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [i as f32 * 0.137, 1e-7 * i as f32, 3.0e4 / (i as f32 + 1.0)];
        }
        let back = decode_exr(&encode_exr(&img).unwrap()).unwrap();
        assert_eq!((back.width, back.height), (7, 3));
        let bits =
            |i: &HdrImage| i.pixels.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&img));
    }
}
