//! How far a lighting method's image is from the reference, in the terms
//! `compare` and `render --lighting auto` both use: the error of its
//! indirect light, over the pixels that show a lit model.

use sylva_scene::color::luminance;
use sylva_scene::film::HdrImage;
use sylva_worker::frame::reference::ReferenceImage;

/// The pixels whose error counts: at least half covered by a model in the
/// reference's own samples, and lit.
pub fn lit_pixels(r: &ReferenceImage) -> Vec<bool> {
    r.coverage.iter().zip(&r.image.pixels).map(|(&c, &p)| c >= 0.5 && luminance(p) > 0.0).collect()
}

/// The indirect error of a method: its indirect part (method − `local`
/// on the same samples) against the reference's (its estimate minus
/// `local` along its own samples), so leaf edges against the sky, sampled
/// differently by the two, do not count as indirect light; raw, and with
/// each image's own sampling noise taken out.
///
/// A squared difference of two noisy estimates is, in expectation, the
/// squared difference of their means plus both variances. The reference
/// knows its variance per pixel (the spread of its batches); a method's
/// comes from rendering it twice with other seeds: E[(a − b)²] = 2σ².
/// Subtracting both leaves the error of the method's expected image
/// against the reference's, which is what the lighting method controls:
/// the 4-ray edge aliasing and the reference's finite samples are not.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndirectError {
    /// √(Σ d² / Σ i_r²) over lit pixels and channels.
    pub raw: f64,
    /// √(max(0, Σ d² − Σ σ_m² − Σ σ_r²) / (Σ i_r² − Σ σ_r²)).
    pub net: f64,
    /// √(Σ σ_r²) over the reference's noise-free indirect RMS.
    pub reference_noise: f64,
    /// √(Σ σ_m²) over the same.
    pub method_noise: f64,
    /// √(max(0, Σ d² − Σ σ_r²) / (Σ i_r² − Σ σ_r²)): the error against the
    /// reference's expectation, the method's own noise kept. What a viewer
    /// of the method's image sees, whatever the reference's samples.
    pub seen: f64,
}

impl IndirectError {
    /// `m` and `l`: the method and `local`, each rendered with two seeds
    /// (the first pair on the same samples, the second pair too).
    pub fn measure(m: [&HdrImage; 2], l: [&HdrImage; 2], r: &ReferenceImage, lit: &[bool]) -> Self {
        let (mut d2, mut r2, mut var_r, mut var_m) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (i, _) in lit.iter().enumerate().filter(|(_, lit)| **lit) {
            for c in 0..3 {
                let ind = |k: usize| (m[k].pixels[i][c] - l[k].pixels[i][c]) as f64;
                let ind_r = (r.image.pixels[i][c] - r.local.pixels[i][c]) as f64;
                d2 += (ind(0) - ind_r).powi(2);
                r2 += ind_r.powi(2);
                var_r += r.indirect_variance[i][c] as f64;
                var_m += (ind(0) - ind(1)).powi(2) / 2.0;
            }
        }
        if r2 <= 0.0 {
            return Self { raw: 0.0, net: 0.0, reference_noise: 0.0, method_noise: 0.0, seen: 0.0 };
        }
        let signal = (r2 - var_r).max(f64::MIN_POSITIVE);
        Self {
            raw: (d2 / r2).sqrt(),
            net: ((d2 - var_m - var_r).max(0.0) / signal).sqrt(),
            reference_noise: (var_r / signal).sqrt(),
            method_noise: (var_m / signal).sqrt(),
            seen: ((d2 - var_r).max(0.0) / signal).sqrt(),
        }
    }
}
