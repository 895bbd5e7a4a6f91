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

/// Opaque-texel tables of a model's alpha-masked materials, from which a
/// triangle's class (or a micro-triangle's) is counted.
pub struct AlphaTables<'a> {
    model: &'a Model,
    tables: Vec<Option<OpaqueTable>>,
}

impl<'a> AlphaTables<'a> {
    /// One summed-area table per textured, alpha-masked material.
    pub fn new(model: &'a Model) -> Self {
        let tables = model
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
        Self { model, tables }
    }

    /// The class of a piece of triangle `t` whose texture coordinates
    /// are `uv` (the whole triangle's, or a micro-triangle's).
    fn class(&self, t: usize, uv: [Vec2; 3]) -> Coverage {
        let mat = self.model.material[t] as usize;
        let m = &self.model.materials[mat];
        match (m.alpha_cutoff, &self.tables[mat]) {
            (None, _) => Coverage::Opaque,
            (Some(cut), None) => {
                if m.base_color[3] < cut {
                    Coverage::Cut
                } else {
                    Coverage::Opaque
                }
            }
            (Some(_), Some(table)) => match table.over(uv) {
                (0, _) => Coverage::Cut,
                (o, all) if o == all => Coverage::Opaque,
                _ => Coverage::Mixed,
            },
        }
    }

    /// Triangle `t`'s texture coordinates.
    fn uvs(&self, t: usize) -> [Vec2; 3] {
        self.model.triangles[t].map(|i| self.model.uvs[i as usize])
    }
}

/// Each triangle's coverage, from its material and the texels its texture
/// coordinates can reach.
pub fn triangle_coverage(model: &Model) -> Vec<Coverage> {
    let tables = AlphaTables::new(model);
    (0..model.triangle_count()).map(|t| tables.class(t, tables.uvs(t))).collect()
}

/// Micro-triangles along each edge of a triangle's opacity micromap: 256
/// in all, 2 bits each, sixteen `u32` (four of the GPU's 16-byte entries).
/// At 4 a side a leaf card's micromap knew 12–31 % of its area, at 8
/// 47–53 %, at 16 67–70 % (the forest's species, 64² textures).
pub const MICRO_EDGE: u32 = 16;
/// Words of one micromap.
pub const MICROMAP_WORDS: usize = (MICRO_EDGE * MICRO_EDGE / 16) as usize;
/// One micromap: 2 bits per micro-triangle, micro-triangle `k` in bits
/// `2(k mod 16)` of word `k / 16`.
pub type Micromap = [u32; MICROMAP_WORDS];
/// A micro-triangle whose texels the micromap does not know: the alpha
/// test fetches the texel.
pub const MICRO_UNKNOWN: u32 = 0;
/// A micro-triangle every texel of which is opaque: a hit there is a hit.
pub const MICRO_OPAQUE: u32 = 1;
/// A micro-triangle every texel of which is a hole: a hit there passes.
pub const MICRO_HOLE: u32 = 2;
/// A triangle record's opacity word when the triangle is opaque everywhere
/// (otherwise the word is its micromap's index).
pub const OPAQUE: u32 = u32::MAX;

/// The micro-triangle that barycentrics `(u, v)` fall in, as a micromap's
/// index: row `j = ⌊v·n⌋` holds `2(n − j) − 1` micro-triangles, the cell
/// `i = ⌊u·n⌋`'s lower one at `2i`, its upper one at `2i + 1`. Values a
/// hair outside the triangle are clamped to its edge's micro-triangles,
/// whose texels (with a texel's margin) cover them. The GPU's
/// `micro_index` is the same arithmetic.
#[inline]
pub fn micro_index(u: f32, v: f32) -> u32 {
    let n = MICRO_EDGE as f32;
    let (fu, fv) = (u * n, v * n);
    let j = (fv.floor().max(0.0) as u32).min(MICRO_EDGE - 1);
    let i = (fu.floor().max(0.0) as u32).min(MICRO_EDGE - 1 - j);
    let upper = (fu - i as f32) + (fv - j as f32) > 1.0 && i + j < MICRO_EDGE - 1;
    j * (2 * MICRO_EDGE - j) + 2 * i + upper as u32
}

/// What micromap `map` says of the micro-triangle at `(u, v)`.
#[inline]
pub fn micro_state(map: &Micromap, u: f32, v: f32) -> u32 {
    let k = micro_index(u, v);
    (map[(k / 16) as usize] >> (2 * (k % 16))) & 3
}

/// A model's opacity micromaps (a software opacity micromap, after the
/// hardware ones of DirectX 12 and Vulkan): per micro-triangle of a mixed
/// triangle ([`micro_index`]), [`MICRO_OPAQUE`] where every texel its
/// texture coordinates can reach is opaque, [`MICRO_HOLE`] where none is,
/// else [`MICRO_UNKNOWN`], counted as the triangles' classes are (with a
/// texel's margin) so a map never contradicts the texel test. Triangles
/// that map their texture alike share a map: a tree's leaf cards all do.
#[derive(Clone, Debug, Default)]
pub struct OpacityMaps {
    /// The distinct maps.
    pub maps: Vec<Micromap>,
    /// Per triangle, its map's index, or [`OPAQUE`] (cut triangles, never
    /// in a structure, get an all-holes map).
    pub of_triangle: Vec<u32>,
}

impl OpacityMaps {
    /// The maps of `model`'s triangles, given their classes.
    pub fn new(model: &Model, coverage: &[Coverage]) -> Self {
        let tables = AlphaTables::new(model);
        let n = MICRO_EDGE;
        let mut index = std::collections::HashMap::<Micromap, u32>::new();
        let mut maps = Vec::new();
        let mut of = |map: Micromap| {
            *index.entry(map).or_insert_with(|| {
                maps.push(map);
                maps.len() as u32 - 1
            })
        };
        let mut seen = std::collections::HashMap::<([u32; 6], u32), u32>::new();
        let of_triangle = coverage
            .iter()
            .enumerate()
            .map(|(t, &c)| match c {
                Coverage::Opaque => OPAQUE,
                Coverage::Cut => of([0xaaaa_aaaa; MICROMAP_WORDS]),
                Coverage::Mixed => {
                    let uv = tables.uvs(t);
                    // Triangles with the same coordinates and material share a map.
                    let [a, b, c] = uv.map(|p| [p.x.to_bits(), p.y.to_bits()]);
                    let key = ([a[0], a[1], b[0], b[1], c[0], c[1]], model.material[t]);
                    if let Some(&m) = seen.get(&key) {
                        return m;
                    }
                    let at = |i: u32, j: u32| {
                        let (bu, bv) = (i as f32 / n as f32, j as f32 / n as f32);
                        uv[0] * (1.0 - bu - bv) + uv[1] * bu + uv[2] * bv
                    };
                    let mut map = [0u32; MICROMAP_WORDS];
                    let mut k = 0;
                    let mut put = |piece: [Vec2; 3]| {
                        let state = match tables.class(t, piece) {
                            Coverage::Opaque => MICRO_OPAQUE,
                            Coverage::Cut => MICRO_HOLE,
                            Coverage::Mixed => MICRO_UNKNOWN,
                        };
                        map[k / 16] |= state << (2 * (k % 16));
                        k += 1;
                    };
                    for j in 0..n {
                        for i in 0..n - j {
                            put([at(i, j), at(i + 1, j), at(i, j + 1)]);
                            if i + j < n - 1 {
                                put([at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)]);
                            }
                        }
                    }
                    let m = of(map);
                    seen.insert(key, m);
                    m
                }
            })
            .collect();
        Self { maps, of_triangle }
    }

    /// Whether a hit at barycentrics `(u, v)` on triangle `t`, whose
    /// opacity word is `word`, falls on a hole: from its map where the map
    /// knows, else from the texel.
    #[inline]
    pub fn is_hole(&self, model: &Model, word: u32, t: u32, u: f32, v: f32) -> bool {
        if word == OPAQUE {
            return false;
        }
        match micro_state(&self.maps[word as usize], u, v) {
            MICRO_OPAQUE => false,
            MICRO_HOLE => true,
            _ => model.is_transparent(t as usize, crate::two_level::uv_at(model, t, u, v)),
        }
    }
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

    /// A micromap never contradicts the texel test, anywhere on a mixed
    /// triangle (edges and corners too), and knows most of the area.
    #[test]
    fn micromaps_agree_with_the_texel_test_everywhere() {
        let model =
            generate(&TreeParams { species: Species::OhioBuckeye, triangles: Some(6000), seed: 3 })
                .unwrap();
        let cov = triangle_coverage(&model);
        let maps = OpacityMaps::new(&model, &cov);
        // The leaf cards share their maps.
        assert!(maps.maps.len() < 10, "{} maps", maps.maps.len());
        let mut rng = SplitMix64::new(11);
        let (mut known, mut points) = (0, 0);
        for (t, &c) in cov.iter().enumerate() {
            if c != Coverage::Mixed {
                continue;
            }
            for k in 0..200 {
                let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                // Some on the micro-triangles' edges and a hair outside.
                if k % 4 == 0 {
                    u = (u * MICRO_EDGE as f32).round() / MICRO_EDGE as f32;
                    v = v.min(1.0 - u);
                }
                if k % 8 == 1 {
                    v = -1e-7;
                }
                let word = maps.of_triangle[t];
                let state = micro_state(&maps.maps[word as usize], u, v);
                let hole = model.is_transparent(t, uv_at(&model, t as u32, u, v));
                match state {
                    MICRO_OPAQUE => assert!(!hole, "triangle {t} at ({u}, {v}): opaque in the map"),
                    MICRO_HOLE => assert!(hole, "triangle {t} at ({u}, {v}): a hole in the map"),
                    _ => {}
                }
                assert_eq!(maps.is_hole(&model, word, t as u32, u, v), hole);
                points += 1;
                known += (state != MICRO_UNKNOWN) as u32;
            }
        }
        assert!(points > 0);
        eprintln!("micromaps know {known} of {points} points on mixed triangles");
        assert!(known * 2 > points, "the micromaps know only {known} of {points} points");
    }

    /// Every barycentric point maps to a micro-triangle that contains it.
    #[test]
    fn micro_indices_tile_the_triangle() {
        let n = MICRO_EDGE as f32;
        let mut rng = SplitMix64::new(2);
        let mut seen = [false; (MICRO_EDGE * MICRO_EDGE) as usize];
        for _ in 0..200_000 {
            let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let k = micro_index(u, v);
            seen[k as usize] = true;
            // Recover (i, j, upper) from the index and check containment.
            let (mut j, mut rest) = (0, k);
            while rest >= 2 * (MICRO_EDGE - j) - 1 {
                rest -= 2 * (MICRO_EDGE - j) - 1;
                j += 1;
            }
            let (i, upper) = (rest / 2, rest % 2 == 1);
            let (fu, fv) = (u * n - i as f32, v * n - j as f32);
            assert!((-1e-5..=1.0 + 1e-5).contains(&fu) && (-1e-5..=1.0 + 1e-5).contains(&fv));
            assert_eq!(upper, fu + fv > 1.0, "({u}, {v}) in {k}");
        }
        assert!(seen.iter().all(|&s| s));
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
