//! The film: a linear HDR image assembled from strips, Reinhard et al.
//! (2002) global tone mapping of the whole frame, and PNG/EXR output.

use crate::color::luminance;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A linear-RGB image, rows from the top.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HdrImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height` pixels.
    pub pixels: Vec<[f32; 3]>,
}

impl HdrImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![[0.0; 3]; (width * height) as usize] }
    }

    /// Columns `[x0, x0 + width)`, as a strip's pixels: what
    /// [`HdrImage::paste_strip`] puts back.
    pub fn columns(&self, x0: u32, width: u32) -> HdrImage {
        assert!(x0 + width <= self.width, "columns outside the frame");
        let (w, x0) = (self.width as usize, x0 as usize);
        let pixels = self
            .pixels
            .chunks_exact(w)
            .flat_map(|row| row[x0..x0 + width as usize].iter().copied())
            .collect();
        HdrImage { width, height: self.height, pixels }
    }

    /// Copies a strip of columns `[x0, x0 + strip_width)` into place.
    pub fn paste_strip(&mut self, x0: u32, strip_width: u32, pixels: &[[f32; 3]]) {
        assert_eq!(pixels.len(), (strip_width * self.height) as usize, "strip size");
        assert!(x0 + strip_width <= self.width, "strip outside the frame");
        for y in 0..self.height {
            let src = &pixels[(y * strip_width) as usize..((y + 1) * strip_width) as usize];
            let start = (y * self.width + x0) as usize;
            self.pixels[start..start + strip_width as usize].copy_from_slice(src);
        }
    }

    /// Writes OpenEXR (32-bit float RGB).
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        let flat: Vec<f32> = self.pixels.iter().flatten().copied().collect();
        let img = image::Rgb32FImage::from_raw(self.width, self.height, flat)
            .ok_or_else(|| Error::Invalid("image size".into()))?;
        image::DynamicImage::ImageRgb32F(img).save(path).map_err(|error| Error::Image {
            context: format!("{}: cannot write EXR", path.display()),
            error,
        })
    }
}

/// What the tone mapper measured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ToneMapStats {
    /// Log-average luminance of the frame.
    pub log_average: f32,
    /// Luminance mapped to white (the frame's largest).
    pub white: f32,
    /// The key value `a`.
    pub key: f32,
}

/// Reinhard et al. 2002, global operator with burn-out: scales the frame
/// so its log-average luminance maps to `key`, then compresses with
/// `L (1 + L / L_white²) / (1 + L)`. Colours keep their ratios. Returns
/// 8-bit sRGB pixels.
pub fn reinhard(img: &HdrImage, key: f32) -> (Vec<[u8; 3]>, ToneMapStats) {
    reinhard_exposed(img, key, None)
}

/// [`reinhard`] with the exposure (log-average and white) of another frame,
/// so several renders of one scene can be compared by eye.
pub fn reinhard_like(img: &HdrImage, like: &ToneMapStats) -> Vec<[u8; 3]> {
    reinhard_exposed(img, like.key, Some((like.log_average, like.white))).0
}

fn reinhard_exposed(
    img: &HdrImage,
    key: f32,
    fixed: Option<(f32, f32)>,
) -> (Vec<[u8; 3]>, ToneMapStats) {
    const DELTA: f64 = 1e-4;
    let n = img.pixels.len().max(1) as f64;
    let lum: Vec<f32> = img.pixels.iter().map(|&p| luminance(p).max(0.0)).collect();
    let log_average = match fixed {
        Some((l, _)) => l,
        None => (lum.iter().map(|&l| (DELTA + l as f64).ln()).sum::<f64>() / n).exp() as f32,
    };
    let scale = key / log_average.max(1e-12);
    let white = match fixed {
        Some((_, w)) => w * scale,
        None => lum.iter().fold(0.0f32, |a, &b| a.max(b)) * scale,
    };
    let white2 = (white * white).max(1e-12);
    let out = img
        .pixels
        .iter()
        .zip(&lum)
        .map(|(p, &l)| {
            if l <= 0.0 {
                return [0, 0, 0];
            }
            let ls = l * scale;
            let ld = ls * (1.0 + ls / white2) / (1.0 + ls);
            p.map(|c| encode_srgb(c * ld / l))
        })
        .collect();
    (out, ToneMapStats { log_average, white: white / scale.max(1e-12), key })
}

/// Linear [0, 1] to an 8-bit sRGB value.
pub fn encode_srgb(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0).round() as u8
}

/// Writes 8-bit sRGB pixels as PNG.
pub fn write_png(path: &Path, width: u32, height: u32, pixels: &[[u8; 3]]) -> Result<()> {
    let flat: Vec<u8> = pixels.iter().flatten().copied().collect();
    let img = image::RgbImage::from_raw(width, height, flat)
        .ok_or_else(|| Error::Invalid("image size".into()))?;
    img.save(path).map_err(|error| Error::Image {
        context: format!("{}: cannot write PNG", path.display()),
        error,
    })
}

/// Rays traced for a strip or a whole frame, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayCounts {
    /// Camera rays.
    pub primary: u64,
    /// Rays towards the sun.
    pub shadow: u64,
    /// Transparent texels a ray passed through and went on.
    pub transparent: u64,
}

impl RayCounts {
    /// Primary plus shadow rays.
    pub fn traced(&self) -> u64 {
        self.primary + self.shadow
    }

    /// Adds another strip's counts.
    pub fn add(&mut self, o: &RayCounts) {
        self.primary += o.primary;
        self.shadow += o.shadow;
        self.transparent += o.transparent;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_average_maps_to_the_key_and_strips_assemble() {
        let mut img = HdrImage::new(4, 2);
        img.paste_strip(0, 2, &[[1.0; 3], [1.0; 3], [1.0; 3], [1.0; 3]]);
        img.paste_strip(2, 2, &[[4.0; 3], [4.0; 3], [4.0; 3], [4.0; 3]]);
        assert_eq!(img.pixels[2], [4.0; 3]);
        assert_eq!(img.pixels[4], [1.0; 3]);
        let (px, stats) = reinhard(&img, 0.18);
        assert!((stats.log_average - 2.0).abs() < 1e-3, "{stats:?}");
        assert_eq!(stats.white, 4.0);
        // Brighter input stays brighter, the brightest maps to white.
        assert!(px[2][0] > px[0][0]);
        assert_eq!(px[2], [255, 255, 255]);
    }
}
