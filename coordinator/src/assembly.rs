//! One frame put together from its strips, whoever rendered them: the
//! in-process renderer and the gRPC farm both hand their strips here. A
//! strip is checked before it touches the frame, so a wrong one is refused
//! (and re-rendered elsewhere) rather than panicking or corrupting the image.

use crate::schedule::Strip;
use sylva_scene::film::{HdrImage, RayCounts};
use sylva_scene::passes::{PassImage, PassSet};

/// Why a strip does not fit its frame: the renderer's (or the worker's)
/// failure, never a reason to touch the frame.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StripError {
    /// Other counts of pixels or coverage values than the strip's.
    #[error(
        "strip [{x0}, {x1}) came back with {pixels} pixels and {coverage} coverage values where {due} were due"
    )]
    Size { x0: u32, x1: u32, pixels: usize, coverage: usize, due: usize },
    /// A pixel that is no radiance.
    #[error("strip [{x0}, {x1}) has a pixel {pixel:?} that is not a finite radiance ≥ 0")]
    Radiance { x0: u32, x1: u32, pixel: [f32; 3] },
    /// A coverage that is no fraction.
    #[error("strip [{x0}, {x1}) has a coverage outside [0, 1]")]
    Coverage { x0: u32, x1: u32 },
    /// Passes of another width or height than the strip's.
    #[error("strip [{x0}, {x1}) came back with passes of another size")]
    PassesSize { x0: u32, x1: u32 },
    /// Passes whose values are wrong (as the pass image says).
    #[error("strip [{x0}, {x1}): {why}")]
    Passes { x0: u32, x1: u32, why: String },
    /// Columns outside the frame.
    #[error("strip [{x0}, {x1}) is not inside a frame {width} wide")]
    Outside { x0: u32, x1: u32, width: u32 },
    /// Passes that do not paste into the frame's (as the pass image says).
    #[error("{0}")]
    Paste(String),
    /// No passes where the frame has some.
    #[error("strip [{x0}, {x1}) came back without the passes {set}")]
    MissingPasses { x0: u32, x1: u32, set: PassSet },
    /// Passes where the frame has none.
    #[error("strip [{x0}, {x1}) came back with passes nobody asked for")]
    UnaskedPasses { x0: u32, x1: u32 },
}

/// Warnings a frame keeps at most (a worker's reply is bounded too).
pub const MAX_WARNINGS: usize = 16;

/// A strip's pixels, decoded and checked.
#[derive(Clone, Debug)]
pub struct StripPixels {
    /// Its columns.
    pub strip: Strip,
    /// Linear HDR, `width × height`, rows from the top.
    pub rgb: Vec<[f32; 3]>,
    /// Per pixel, the fraction of samples that hit a model.
    pub coverage: Vec<f32>,
    /// Rays traced.
    pub rays: RayCounts,
    /// The frame's passes beside the image, when it asks for any.
    pub passes: Option<PassImage>,
    /// What the worker's lighting found about the scene (checked, clipped).
    pub warnings: Vec<String>,
}

impl StripPixels {
    /// The strip as 8-bit sRGB for a live preview, tone mapped per pixel
    /// (x / (1 + x)): the frame's exposure is not known until it is whole.
    pub fn preview(&self) -> Vec<[u8; 3]> {
        let srgb = |v: f32| {
            let v = v / (1.0 + v);
            let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
            (s.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
        };
        self.rgb.iter().map(|p| p.map(srgb)).collect()
    }

    /// Checks a strip's sizes and values against the columns it was asked
    /// for and the frame's height.
    pub fn check(&self, height: u32) -> Result<(), StripError> {
        let (x0, x1) = self.strip;
        let n = (x1 - x0) as usize * height as usize;
        if self.rgb.len() != n || self.coverage.len() != n {
            return Err(StripError::Size {
                x0,
                x1,
                pixels: self.rgb.len(),
                coverage: self.coverage.len(),
                due: n,
            });
        }
        if let Some(p) = self.rgb.iter().find(|p| p.iter().any(|v| !v.is_finite() || *v < 0.0)) {
            return Err(StripError::Radiance { x0, x1, pixel: *p });
        }
        if self.coverage.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(StripError::Coverage { x0, x1 });
        }
        if let Some(p) = &self.passes {
            if (p.width, p.height) != (x1 - x0, height) {
                return Err(StripError::PassesSize { x0, x1 });
            }
            p.check().map_err(|e| StripError::Passes { x0, x1, why: e.to_string() })?;
        }
        Ok(())
    }
}

/// A frame being assembled.
#[derive(Clone, Debug)]
pub struct Assembly {
    /// Linear HDR.
    pub image: HdrImage,
    /// Per pixel, the fraction of samples that hit a model.
    pub coverage: Vec<f32>,
    /// Rays traced.
    pub rays: RayCounts,
    /// The passes beside the image, when the frame asks for any.
    pub passes: Option<PassImage>,
    /// The strips' warnings, each once, in the order first heard.
    pub warnings: Vec<String>,
    /// Columns filled so far.
    filled: Vec<bool>,
}

impl Assembly {
    /// An empty frame, with room for `passes`.
    pub fn new(width: u32, height: u32, passes: PassSet) -> Self {
        Self {
            image: HdrImage::new(width, height),
            coverage: vec![0.0; (width * height) as usize],
            rays: RayCounts::default(),
            passes: (!passes.is_empty()).then(|| PassImage::new(width, height, passes)),
            warnings: Vec::new(),
            filled: vec![false; width as usize],
        }
    }

    /// Puts a strip in place, after checking it fits the frame.
    pub fn add(&mut self, s: &StripPixels) -> Result<(), StripError> {
        let (x0, x1) = s.strip;
        if x0 >= x1 || x1 > self.image.width {
            return Err(StripError::Outside { x0, x1, width: self.image.width });
        }
        s.check(self.image.height)?;
        match (&mut self.passes, &s.passes) {
            (None, None) => {}
            (Some(frame), Some(strip)) => {
                frame.paste_strip(x0, strip).map_err(|e| StripError::Paste(e.to_string()))?;
            }
            (Some(frame), None) => {
                return Err(StripError::MissingPasses { x0, x1, set: frame.set });
            }
            (None, Some(_)) => return Err(StripError::UnaskedPasses { x0, x1 }),
        }
        let w = x1 - x0;
        self.image.paste_strip(x0, w, &s.rgb);
        for y in 0..self.image.height {
            let row = (y * w) as usize;
            let at = (y * self.image.width + x0) as usize;
            self.coverage[at..at + w as usize].copy_from_slice(&s.coverage[row..row + w as usize]);
        }
        self.rays.add(&s.rays);
        for w in &s.warnings {
            if !self.warnings.contains(w) && self.warnings.len() < MAX_WARNINGS {
                self.warnings.push(w.clone());
            }
        }
        self.filled[x0 as usize..x1 as usize].fill(true);
        Ok(())
    }

    /// Whether every column has been filled.
    pub fn complete(&self) -> bool {
        self.filled.iter().all(|&f| f)
    }

    /// The parts of `plan`'s strips whose columns are not filled yet, in
    /// plan order: what is left to render of a frame begun before.
    pub fn open_columns(&self, plan: &[Strip]) -> Vec<Strip> {
        let mut out = Vec::new();
        for &(x0, x1) in plan {
            let mut start = None;
            for x in x0..=x1.min(self.image.width) {
                let open = x < x1 && !self.filled[x as usize];
                match (open, start) {
                    (true, None) => start = Some(x),
                    (false, Some(s)) => {
                        out.push((s, x));
                        start = None;
                    }
                    _ => {}
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strip(x0: u32, x1: u32, h: u32) -> StripPixels {
        let n = ((x1 - x0) * h) as usize;
        StripPixels {
            strip: (x0, x1),
            rgb: vec![[0.5; 3]; n],
            coverage: vec![1.0; n],
            rays: RayCounts { primary: n as u64, ..RayCounts::default() },
            passes: None,
            warnings: Vec::new(),
        }
    }

    #[test]
    fn a_frame_begun_before_leaves_only_its_open_columns() {
        let mut a = Assembly::new(10, 2, PassSet::NONE);
        a.add(&strip(2, 4, 2)).unwrap();
        a.add(&strip(6, 10, 2)).unwrap();
        assert_eq!(a.open_columns(&[(0, 5), (5, 10)]), vec![(0, 2), (4, 5), (5, 6)]);
        a.add(&strip(0, 2, 2)).unwrap();
        a.add(&strip(4, 6, 2)).unwrap();
        assert!(a.open_columns(&[(0, 10)]).is_empty() && a.complete());
    }

    #[test]
    fn wrong_strips_are_refused_and_right_ones_fill_the_frame() {
        let mut a = Assembly::new(10, 4, PassSet::NONE);
        let mut short = strip(0, 5, 4);
        short.rgb.pop();
        assert!(a.add(&short).is_err());
        assert!(a.add(&strip(5, 11, 4)).is_err(), "wider than the frame");
        assert!(
            a.add(&StripPixels {
                strip: (3, 3),
                rgb: vec![],
                coverage: vec![],
                rays: RayCounts::default(),
                warnings: Vec::new(),
                passes: None,
            })
            .is_err(),
            "zero width"
        );
        let mut nan = strip(0, 5, 4);
        nan.rgb[3] = [f32::NAN, 0.0, 0.0];
        assert!(a.add(&nan).is_err());
        assert!(!a.complete());
        a.add(&strip(0, 5, 4)).unwrap();
        a.add(&strip(5, 10, 4)).unwrap();
        assert!(a.complete());
        assert_eq!(a.rays.primary, 40);
    }
}
