//! A worker's reply to a strip, decoded and checked before any use.

use crate::assembly::{StripError, StripPixels};
use crate::schedule::Strip;
use sylva_proto::pb;
use sylva_scene::film::RayCounts;
use sylva_scene::passes::{PassImage, PassSet};

/// Characters of a worker's warning kept (an LB finding is about 400).
const MAX_WARNING_CHARS: usize = 600;

/// Why a worker's reply is refused: the worker's failure.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BadReply {
    /// Other columns or rows than asked for.
    #[error(
        "worker replied with columns [{x0}, {x1}) × {rows} rows to a request for [{want_x0}, {want_x1}) × {want_rows}"
    )]
    Shape { x0: u32, x1: u32, rows: u32, want_x0: u32, want_x1: u32, want_rows: u32 },
    /// Other byte counts than the strip's.
    #[error(
        "worker replied with {rgb} bytes of pixels and {coverage} of coverage where {rgb_due} and {coverage_due} were due"
    )]
    Size { rgb: usize, coverage: usize, rgb_due: usize, coverage_due: usize },
    /// Passes where the frame has none.
    #[error("worker replied with passes nobody asked for")]
    UnaskedPasses,
    /// Passes that do not decode (as the pass image says).
    #[error("{0}")]
    Passes(String),
    /// Pixels that do not fit the strip.
    #[error(transparent)]
    Strip(#[from] StripError),
}

/// Decodes a worker's reply to `strip` and checks it before any use: a
/// reply for other columns, of another size or with values that are no
/// radiance is the worker's failure.
pub fn decode_reply(
    r: &pb::RenderStripReply,
    strip: Strip,
    height: u32,
    passes: PassSet,
) -> Result<StripPixels, BadReply> {
    if r.x0 != strip.0 || r.width != strip.1 - strip.0 || r.height != height {
        return Err(BadReply::Shape {
            x0: r.x0,
            x1: r.x0.saturating_add(r.width),
            rows: r.height,
            want_x0: strip.0,
            want_x1: strip.1,
            want_rows: height,
        });
    }
    let n = (strip.1 - strip.0) as usize * height as usize;
    if r.rgb_f32.len() != n * 12 || r.coverage_f32.len() != n * 4 {
        return Err(BadReply::Size {
            rgb: r.rgb_f32.len(),
            coverage: r.coverage_f32.len(),
            rgb_due: n * 12,
            coverage_due: n * 4,
        });
    }
    let f = |c: &[u8]| f32::from_le_bytes(c.try_into().expect("4 bytes"));
    let rgb = r
        .rgb_f32
        .as_chunks::<12>()
        .0
        .iter()
        .map(|c| [f(&c[0..4]), f(&c[4..8]), f(&c[8..12])])
        .collect();
    let coverage = r.coverage_f32.as_chunks::<4>().0.iter().map(|c| f(c)).collect();
    let rays = r.rays.as_ref().map_or(RayCounts::default(), |c| RayCounts {
        primary: c.primary,
        shadow: c.shadow,
        transparent: c.transparent,
    });
    let passes = if passes.is_empty() {
        if !r.passes_f32.is_empty() {
            return Err(BadReply::UnaskedPasses);
        }
        None
    } else {
        Some(
            PassImage::from_bytes(strip.1 - strip.0, height, passes, &r.passes_f32)
                .map_err(|e| BadReply::Passes(e.to_string()))?,
        )
    };
    // Words from a worker, bounded and made printable before they reach
    // a stats file, a terminal or the page.
    let warnings = r
        .warnings
        .iter()
        .take(crate::assembly::MAX_WARNINGS)
        .map(|w| sylva_scene::sandbox::printable(w, MAX_WARNING_CHARS))
        .collect();
    let px = StripPixels { strip, rgb, coverage, rays, passes, warnings };
    px.check(height)?;
    Ok(px)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A worker's reply to a 2 × 3 strip at column 4, with `passes`' bytes.
    fn reply(passes: Vec<u8>) -> pb::RenderStripReply {
        pb::RenderStripReply {
            x0: 4,
            width: 2,
            height: 3,
            rgb_f32: [0.5f32; 18].iter().flat_map(|v| v.to_le_bytes()).collect(),
            coverage_f32: [1.0f32; 6].iter().flat_map(|v| v.to_le_bytes()).collect(),
            passes_f32: passes,
            ..Default::default()
        }
    }

    #[test]
    fn a_workers_passes_are_checked_before_use() {
        let set = PassSet::parse("depth,instance").unwrap();
        let mut good = PassImage::new(2, 3, set);
        good.planes[1].fill(2.0);
        let px = decode_reply(&reply(good.to_bytes()), (4, 6), 3, set).unwrap();
        assert_eq!(px.passes.as_ref(), Some(&good));
        // Passes nobody asked for, too few bytes, an id that is no index,
        // a NaN depth: each the worker's failure, said so.
        let no = decode_reply(&reply(good.to_bytes()), (4, 6), 3, PassSet::NONE)
            .unwrap_err()
            .to_string();
        assert!(no.contains("nobody asked for"), "{no}");
        let short = decode_reply(&reply(good.to_bytes()[4..].to_vec()), (4, 6), 3, set)
            .unwrap_err()
            .to_string();
        assert!(short.contains("bytes where"), "{short}");
        let mut bad = good.clone();
        bad.planes[1][0] = 0.5;
        let e = decode_reply(&reply(bad.to_bytes()), (4, 6), 3, set).unwrap_err().to_string();
        assert!(e.contains("instance"), "{e}");
        bad = good.clone();
        bad.planes[0][0] = f32::NAN;
        assert!(
            decode_reply(&reply(bad.to_bytes()), (4, 6), 3, set)
                .unwrap_err()
                .to_string()
                .contains("depth")
        );
        assert!(decode_reply(&reply(Vec::new()), (4, 6), 3, set).is_err(), "passes missing");
    }
}
