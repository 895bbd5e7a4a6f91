//! Generated leaf textures: an alpha mask in the species' outline, a midrib
//! and mottled colour. The stalk is at the bottom of the image, the tip at
//! the top, so a quad with v = 1 at its base shows the leaf upright.

use crate::model::Texture;
use crate::rng::SplitMix64;

/// A leaf outline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeafShape {
    /// Palmately lobed (maple).
    Lobed,
    /// Five leaflets from one point (buckeye).
    Palmate,
    /// Egg-shaped with a toothed edge (birch).
    Ovate,
    /// Heart-shaped (catalpa).
    Cordate,
    /// Elliptic (beech).
    Elliptic,
}

/// Texels along each side of a leaf texture.
pub const LEAF_TEXELS: u32 = 64;

impl LeafShape {
    /// Whether the point `(u, v)` is on the leaf: u ∈ [−1, 1] across, v ∈
    /// [0, 1] from the stalk to the tip.
    pub fn covers(self, u: f32, v: f32) -> bool {
        // The stalk.
        if v < 0.1 {
            return u.abs() < 0.04;
        }
        let t = (v - 0.1) / 0.9;
        match self {
            LeafShape::Ovate => {
                let w = 0.85 * (std::f32::consts::PI * t.powf(0.75)).sin() * (1.0 - 0.25 * t);
                u.abs() < w * (1.0 - 0.08 * (t * 45.0).sin().abs())
            }
            LeafShape::Elliptic => u.abs() < 0.7 * (std::f32::consts::PI * t).sin(),
            LeafShape::Cordate => {
                let w = 0.98 * (std::f32::consts::PI * t.powf(0.55)).sin();
                // The notch where the stalk meets the blade.
                let notch = t < 0.12 && u.abs() < 0.12 * (1.0 - t / 0.12);
                u.abs() < w && !notch
            }
            LeafShape::Lobed => {
                let (x, y) = (u, t - 0.42);
                let r = (x * x + y * y).sqrt();
                let theta = x.atan2(y);
                let lobes = 0.5 * (0.55 + 0.45 * (2.5 * theta).cos().abs().powf(0.6));
                r < lobes && theta.abs() < 2.6
            }
            LeafShape::Palmate => (0..5).any(|i| {
                let angle = (i as f32 - 2.0) * 0.55;
                let (s, c) = angle.sin_cos();
                let (x, y) = (u, t - 0.02);
                // Leaflet frame: along (s, c), across (c, −s).
                let along = x * s + y * c;
                let across = x * c - y * s;
                let len = if i == 2 { 0.95 } else { 0.95 - 0.12 * (i as f32 - 2.0).abs() };
                along > 0.0
                    && along < len
                    && across.abs() < 0.2 * (std::f32::consts::PI * along / len).sin()
            }),
        }
    }
}

/// The texture of a leaf of `shape` and base colour `rgb` (sRGB).
pub fn leaf_texture(shape: LeafShape, rgb: [u8; 3], seed: u64) -> Texture {
    let n = LEAF_TEXELS;
    let mut rng = SplitMix64::new(seed);
    let mut rgba = Vec::with_capacity((n * n * 4) as usize);
    for row in 0..n {
        for col in 0..n {
            let u = (col as f32 + 0.5) / n as f32 * 2.0 - 1.0;
            let v = 1.0 - (row as f32 + 0.5) / n as f32;
            let on = shape.covers(u, v);
            let shade = 0.85 + 0.3 * rng.next_f32() - if u.abs() < 0.03 { -0.15 } else { 0.0 };
            let c = rgb.map(|x| (x as f32 * shade).clamp(0.0, 255.0) as u8);
            rgba.extend_from_slice(&[c[0], c[1], c[2], if on { 255 } else { 0 }]);
        }
    }
    Texture { width: n, height: n, rgba }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_leaf_has_holes_and_blade() {
        for shape in [
            LeafShape::Lobed,
            LeafShape::Palmate,
            LeafShape::Ovate,
            LeafShape::Cordate,
            LeafShape::Elliptic,
        ] {
            let t = leaf_texture(shape, [80, 120, 40], 1);
            let on = t.rgba.as_chunks::<4>().0.iter().filter(|p| p[3] == 255).count() as f32
                / (t.width * t.height) as f32;
            assert!(on > 0.15 && on < 0.8, "{shape:?} covers {on}");
        }
    }
}
