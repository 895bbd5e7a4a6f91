//! Which triangles need the alpha test at all. A triangle's texture
//! coordinates span a rectangle of texels; when every texel there is opaque
//! the triangle is opaque wherever a ray hits it, and when none is, no ray
//! can ever hit it. Only the rest pay for a texel fetch in the inner loop.
//! Counts come from a summed-area table per material, so classifying a
//! triangle costs four lookups however many texels it spans.

use glam::Vec2;
use sylva_scene::model::Model;

/// How the alpha test can end on a triangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum Coverage {
    /// Every texel it can fetch is opaque: no test needed.
    Opaque = 0,
    /// Some texels are holes: test each hit.
    Mixed = 1,
    /// Every texel is a hole: no ray hits it.
    Cut = 2,
}

/// Opaque-texel counts of one material's texture, summed over rectangles.
struct OpaqueTable {
    width: usize,
    height: usize,
    /// `(width + 1) × (height + 1)`, row-major: opaque texels above-left.
    sums: Vec<u32>,
}

impl OpaqueTable {
    fn new(width: usize, height: usize, opaque: impl Fn(usize) -> bool) -> Self {
        let stride = width + 1;
        let mut sums = vec![0u32; stride * (height + 1)];
        for y in 0..height {
            let mut row = 0;
            for x in 0..width {
                row += opaque(y * width + x) as u32;
                sums[(y + 1) * stride + x + 1] = sums[y * stride + x + 1] + row;
            }
        }
        Self { width, height, sums }
    }

    /// Opaque texels in columns `x0..x1`, rows `y0..y1` (no wrapping).
    fn count(&self, x0: usize, x1: usize, y0: usize, y1: usize) -> u64 {
        let s = |x: usize, y: usize| self.sums[y * (self.width + 1) + x] as u64;
        s(x1, y1) + s(x0, y0) - s(x0, y1) - s(x1, y0)
    }

    /// The texel ranges a coordinate interval can fetch, wrapping as
    /// `Texture::texel` does, with a texel's margin for rounding: one or two
    /// plain ranges (an empty second one when one suffices).
    fn spans(lo: f32, hi: f32, n: usize) -> [(usize, usize); 2] {
        let (a, b) = ((lo * n as f32).floor() - 1.0, (hi * n as f32).floor() + 1.0);
        if !(a.is_finite() && b.is_finite())
            || b - a + 1.0 >= n as f32
            || a.abs() > 1e7
            || b.abs() > 1e7
        {
            return [(0, n), (0, 0)];
        }
        let start = (a as i64).rem_euclid(n as i64) as usize;
        let len = (b - a) as usize + 1;
        if start + len <= n {
            [(start, start + len), (0, 0)]
        } else {
            [(start, n), (0, start + len - n)]
        }
    }

    /// Opaque texels and all texels a triangle with these coordinates can fetch.
    fn over(&self, uv: [Vec2; 3]) -> (u64, u64) {
        let lo = uv[0].min(uv[1]).min(uv[2]);
        let hi = uv[0].max(uv[1]).max(uv[2]);
        let (mut opaque, mut all) = (0, 0);
        for (x0, x1) in Self::spans(lo.x, hi.x, self.width) {
            for (y0, y1) in Self::spans(lo.y, hi.y, self.height) {
                opaque += self.count(x0, x1, y0, y1);
                all += ((x1 - x0) * (y1 - y0)) as u64;
            }
        }
        (opaque, all)
    }
}

/// Each triangle's coverage, from its material and the texels its texture
/// coordinates can reach.
pub fn triangle_coverage(model: &Model) -> Vec<Coverage> {
    let tables: Vec<Option<OpaqueTable>> = model
        .materials
        .iter()
        .map(|m| match (m.alpha_cutoff, m.texture) {
            (Some(cut), Some(t)) => {
                let tex = &model.textures[t as usize];
                let alpha = m.base_color[3];
                Some(OpaqueTable::new(tex.width as usize, tex.height as usize, |i| {
                    tex.rgba[4 * i + 3] as f32 / 255.0 * alpha >= cut
                }))
            }
            _ => None,
        })
        .collect();
    (0..model.triangle_count())
        .map(|t| {
            let m = &model.materials[model.material[t] as usize];
            match (m.alpha_cutoff, &tables[model.material[t] as usize]) {
                (None, _) => Coverage::Opaque,
                (Some(cut), None) => {
                    if m.base_color[3] < cut {
                        Coverage::Cut
                    } else {
                        Coverage::Opaque
                    }
                }
                (Some(_), Some(table)) => {
                    let uv = model.triangles[t].map(|i| model.uvs[i as usize]);
                    match table.over(uv) {
                        (0, _) => Coverage::Cut,
                        (o, all) if o == all => Coverage::Opaque,
                        _ => Coverage::Mixed,
                    }
                }
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_level::uv_at;
    use sylva_scene::rng::SplitMix64;
    use sylva_scene::trees::{Species, TreeParams, generate};

    /// Every hit a classified triangle can take agrees with the texel test:
    /// opaque triangles are never holes, cut ones always are.
    #[test]
    fn classes_agree_with_the_texel_test_everywhere_on_the_triangle() {
        let model =
            generate(&TreeParams { species: Species::OhioBuckeye, triangles: Some(6000), seed: 3 })
                .unwrap();
        let cov = triangle_coverage(&model);
        let count = |c| cov.iter().filter(|&&x| x == c).count();
        assert!(
            count(Coverage::Opaque) > 0 && count(Coverage::Mixed) > 0,
            "{} opaque, {} mixed",
            count(Coverage::Opaque),
            count(Coverage::Mixed)
        );
        let mut rng = SplitMix64::new(9);
        for (t, &c) in cov.iter().enumerate() {
            if c == Coverage::Mixed {
                continue;
            }
            for _ in 0..64 {
                let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let hole = model.is_transparent(t, uv_at(&model, t as u32, u, v));
                assert_eq!(hole, c == Coverage::Cut, "triangle {t} classed {c:?}");
            }
        }
    }

    #[test]
    fn spans_wrap_and_cover_the_whole_texture_when_wide() {
        assert_eq!(OpaqueTable::spans(0.25, 0.5, 16), [(3, 10), (0, 0)]);
        assert_eq!(OpaqueTable::spans(0.95, 1.05, 16), [(14, 16), (0, 2)]);
        assert_eq!(OpaqueTable::spans(-2.0, 3.0, 16), [(0, 16), (0, 0)]);
        assert_eq!(OpaqueTable::spans(f32::NAN, 0.5, 16), [(0, 16), (0, 0)]);
        let table = OpaqueTable::new(4, 2, |i| i % 2 == 0);
        assert_eq!(table.count(0, 4, 0, 2), 4);
        assert_eq!(table.count(1, 2, 0, 2), 0);
    }
}
