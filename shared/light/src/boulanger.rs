//! CPU side of the Boulanger, Bouatouch & Pattanaik (2008) tree-lighting
//! model, "Rendering Trees with Indirect Lighting in Real Time": per-leaf
//! envelope distances `s_max(P, ω_j)` for eight directions, per-sun
//! constants (G1 split in two geometric factors, G2, G3), and a plain CPU
//! evaluation of the three lighting terms (sky, sun, one-bounce indirect
//! sun) that a GPU shader is tested against.
//!
//! # How `s_max` is computed
//!
//! Eqs. 6 and 23 integrate e^{−τ s(P, ω)} over each direction's bin (an
//! octant): what they need from the precomputation is the bin's *mean*
//! transmittance T_j, and `s_max(P, ω_j) = −ln T_j / τ` states it so that
//! e^{−τ s_max} = T_j. The paper (§6) estimates T_j as Π(1 − o) over the
//! neighbours in the bin, each occluding o = Ω_leaf / Ω_bin, which is the
//! mean transmittance only if the occluders are spread independently over
//! the bin: in a crown they are not. A leaf near the crown's surface has
//! open sky over part of its bin and the whole crown over the rest; the
//! product gives e^{−mean optical depth}, far below the mean of e^{−depth}
//! (Jensen), and every visible leaf came out darker than its direct sun
//! alone (issue 26: whole-image means 0.46–0.90 of the reference's). Here
//! T_j is measured: 16 rays per bin from the leaf's centre, on a 4 × 4
//! grid of equal solid angle over the octant (turned per leaf), through
//! the model's own triangles with the alpha test, counting those that
//! escape. A bin with no open ray gets half a ray's worth (T = 1/32), the
//! estimate's resolution. Everything downstream (eqs. 6–8, 11, 18–25) is
//! the paper's, unchanged; the renderer takes the direct sun from its own
//! shadow ray rather than eq. 8, and lets the sun light the ground below
//! the horizon (docs/lighting.md, "Boulanger et al.").
//!
//! τ = ρ A / 2 with ρ = leaves / envelope volume, the volume being the
//! occupied cells of a coarse grid of leaf centres (24 cells on the
//! longest side, made coarser until cells hold ≥ 8 leaves on average, so
//! the volume does not collapse to "one cell per leaf" on sparse trees).
//! Only the product τ s_max and the ratio ρ/τ = 2/A enter the lighting, so
//! the choice mostly matters for reading `s_max` as a distance.
//!
//! Leaves are "cards": two consecutive leaf triangles that share an edge
//! (the generator's quads) count as one leaf, with the summed area and the
//! area-weighted centre; both triangles get the same `s_max`.
//!
//! Wood (trunk and branches) receives the same sky and one bounce: the
//! paper shades leaves only, and a bark surface left at its direct sun is
//! black wherever the sun does not reach it, where the reference shows
//! the sky and the leaves' light on it (on `examples/tree.json` the
//! branches are a large share of the tree's pixels). Its cards are its
//! triangles (paired like the leaves'), its transmittance is measured the
//! same way, and the neighbours that scatter sun light onto it are the
//! model's leaves, of their mean albedo ([`LeafEnvelope::leaf_albedo`]).
//!
//! Directions: the paper's eq. 26 lists ω_0..ω_3 (all with y = −1/√3) and
//! ω_j = −ω_{7−j}; here ω_{j+4} = −ω_j instead, so a shader recovers the
//! upper four by negating the lower four in order. y is up.

use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::PI;
use std::time::Instant;
use sylva_accel::coverage::triangle_coverage;
use sylva_accel::triangle::intersect;
use sylva_accel::two_level::{triangle_bounds, uv_at};
use sylva_accel::{Accel, AccelKind, Ray};
use sylva_scene::model::{Model, Surface};

/// Number of sample directions ω_j.
pub const N_DIR: usize = 8;

/// 1/√3: the cube diagonals' coordinates.
const XI: f32 = 0.577_350_26;
/// Grid cells on the longest side of the leaf-centre bounds, at most.
const GRID_CELLS: usize = 24;
/// Coarsen the grid until occupied cells hold this many leaves on average.
const MIN_LEAVES_PER_CELL: f32 = 8.0;
/// Rays per bin side: RAYS² rays measure each bin's transmittance.
const RAYS: usize = 4;

/// The eight sample directions: cube diagonals, ω_0..ω_3 below the horizon
/// (y < 0), and ω_{j+4} = −ω_j.
pub fn directions() -> [Vec3; N_DIR] {
    let low = [
        Vec3::new(-XI, -XI, -XI),
        Vec3::new(XI, -XI, -XI),
        Vec3::new(-XI, -XI, XI),
        Vec3::new(XI, -XI, XI),
    ];
    [low[0], low[1], low[2], low[3], -low[0], -low[1], -low[2], -low[3]]
}

/// The index of the direction nearest to `d` (its octant), by signs only.
pub fn bin_of(d: Vec3) -> usize {
    if d.y < 0.0 {
        (d.x > 0.0) as usize + 2 * (d.z > 0.0) as usize
    } else {
        4 + (d.x < 0.0) as usize + 2 * (d.z < 0.0) as usize
    }
}

/// M(x) = max(x, 0).
#[inline]
fn m(x: f32) -> f32 {
    x.max(0.0)
}

/// Per-leaf envelope distances and the per-model medium constants.
#[derive(Clone, Debug, Default)]
pub struct LeafEnvelope {
    /// s_max(P, ω_j) per model triangle (both triangles of a card get the
    /// card's values), leaves and wood alike.
    pub s_max: Vec<[f32; N_DIR]>,
    /// Optical thickness per unit length, τ = ρ A / 2.
    pub tau: f32,
    /// Leaf density ρ: leaves per unit volume of the envelope.
    pub leaf_density: f32,
    /// Mean leaf (card) area A.
    pub leaf_area: f32,
    /// Number of leaves (cards) found.
    pub leaves: usize,
    /// The leaves' mean albedo, linear RGB, weighted by area: the
    /// neighbours' in the one-bounce term that lights wood.
    pub leaf_albedo: [f32; 3],
    /// Wall time of [`precompute`], milliseconds.
    pub precompute_ms: f64,
}

/// One leaf: one triangle or two sharing an edge.
#[derive(Clone, Copy, Debug)]
struct Card {
    centre: Vec3,
    area: f32,
    tris: [usize; 2],
    n_tris: usize,
}

/// Leaf cards of a model: consecutive leaf triangles sharing two vertex
/// indices (a quad) are merged, others stand alone.
fn leaf_cards(model: &Model) -> Vec<Card> {
    cards_of(model, Surface::Leaf)
}

/// The cards of `surface`: consecutive triangles of it sharing two vertices pair up.
fn cards_of(model: &Model, surface: Surface) -> Vec<Card> {
    let tri = |t: usize| {
        let [a, b, c] = model.triangle(t);
        let n2 = (b - a).cross(c - a); // twice the area, along the normal
        (n2, (a + b + c) / 3.0)
    };
    let mut cards = Vec::new();
    let mut t = 0;
    while t < model.triangle_count() {
        if model.surface(t) != surface {
            t += 1;
            continue;
        }
        let paired = t + 1 < model.triangle_count()
            && model.surface(t + 1) == surface
            && model.triangles[t].iter().filter(|i| model.triangles[t + 1].contains(i)).count()
                == 2;
        let (n0, c0) = tri(t);
        let (centre, area, tris, n_tris) = if paired {
            let (n1, c1) = tri(t + 1);
            let (a0, a1) = (0.5 * n0.length(), 0.5 * n1.length());
            let centre =
                if a0 + a1 > 0.0 { (c0 * a0 + c1 * a1) / (a0 + a1) } else { 0.5 * (c0 + c1) };
            (centre, a0 + a1, [t, t + 1], 2)
        } else {
            (c0, 0.5 * n0.length(), [t, t], 1)
        };
        cards.push(Card { centre, area, tris, n_tris });
        t += n_tris;
    }
    cards
}

/// The envelope's volume: the cells of a uniform grid of leaf centres
/// that hold a leaf (24 cells on the longest side, made coarser until
/// occupied cells hold ≥ 8 leaves on average).
fn envelope_volume(cards: &[Card]) -> f32 {
    let (lo, hi) = cards.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), c| {
        (lo.min(c.centre), hi.max(c.centre))
    });
    let ext = (hi - lo).max_element();
    let mean_area = cards.iter().map(|c| c.area).sum::<f32>() / cards.len() as f32;
    let mut res = GRID_CELLS;
    loop {
        let cell = if ext > 0.0 { ext / res as f32 } else { mean_area.sqrt().max(1e-6) };
        let occupied: std::collections::HashSet<[i64; 3]> = cards
            .iter()
            .map(|c| {
                ((c.centre - lo) / cell)
                    .to_array()
                    .map(|q| (q.floor() as i64).min(res as i64 - 1).max(0))
            })
            .collect();
        if res <= 4 || cards.len() as f32 >= MIN_LEAVES_PER_CELL * occupied.len() as f32 {
            return occupied.len() as f32 * cell.powi(3);
        }
        res -= 2;
    }
}

/// Optical depth −ln T_j of each bin around leaf `card` (number `i`):
/// the fraction of RAYS² rays over the octant that leave the model.
fn optical_depths(i: usize, card: &Card, model: &Model, accel: &Accel, t_min: f32) -> [f32; N_DIR] {
    let mut depth = [0.0f32; N_DIR];
    // A turn of the grid per leaf, so neighbouring leaves' rays interleave.
    let turn = (i as f32 * 0.618_034).fract() / RAYS as f32;
    for (j, w) in directions().iter().enumerate() {
        let sign = w.signum();
        let mut open = 0usize;
        for a in 0..RAYS {
            // |y| uniform: each cell covers the same solid angle.
            let y = (a as f32 + 0.5) / RAYS as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            for b in 0..RAYS {
                let phi = ((b as f32 + 0.5) / RAYS as f32 + turn) * std::f32::consts::FRAC_PI_2;
                let d = Vec3::new(r * phi.cos(), y, r * phi.sin()) * sign;
                if !blocked(model, accel, card, &Ray::new(card.centre, d), t_min) {
                    open += 1;
                }
            }
        }
        let n = (RAYS * RAYS) as f32;
        depth[j] = -(open as f32 / n).max(0.5 / n).ln();
    }
    depth
}

/// Whether anything of `model` but the card itself (alpha-cut texels passed) lies along `ray`.
fn blocked(model: &Model, accel: &Accel, card: &Card, ray: &Ray, t_min: f32) -> bool {
    accel
        .closest(ray, t_min, f32::INFINITY, &mut |tri, limit| {
            let t = tri as usize;
            if card.tris[..card.n_tris].contains(&t) {
                return None;
            }
            let [a, b, c] = model.triangle(t);
            let (d, u, v) = intersect(ray, a, b, c, t_min, limit)?;
            if model.is_transparent(t, uv_at(model, tri, u, v)) {
                return None;
            }
            Some(d)
        })
        .is_some()
}

/// Computes the leaf envelope of `model` (see the module doc), in parallel.
pub fn precompute(model: &Model) -> LeafEnvelope {
    let t0 = Instant::now();
    let cards = leaf_cards(model);
    let mut env = LeafEnvelope {
        s_max: vec![[0.0; N_DIR]; model.triangle_count()],
        leaves: cards.len(),
        ..Default::default()
    };
    if cards.is_empty() {
        env.precompute_ms = t0.elapsed().as_secs_f64() * 1e3;
        return env;
    }
    let n = cards.len() as f32;
    env.leaf_area = cards.iter().map(|c| c.area).sum::<f32>() / n;
    env.leaf_density = n / envelope_volume(&cards);
    env.tau = 0.5 * env.leaf_density * env.leaf_area;
    env.leaf_albedo = mean_leaf_albedo(model, &cards);
    let mut cards = cards;
    cards.extend(cards_of(model, Surface::Wood));
    let triangles: Vec<[Vec3; 3]> =
        (0..model.triangle_count()).map(|t| model.triangle(t)).collect();
    let coverage = triangle_coverage(model);
    let accel =
        Accel::build_triangles(AccelKind::Bvh, &triangle_bounds(&triangles, &coverage), &triangles);
    let (lo, hi) = model.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE));
    let t_min = 1e-5 * (hi - lo).max_element().max(1e-3);
    let depths: Vec<[f32; N_DIR]> = cards
        .par_iter()
        .enumerate()
        .map(|(i, c)| optical_depths(i, c, model, &accel, t_min))
        .collect();
    if env.tau > 0.0 && env.tau.is_finite() {
        for (card, depth) in cards.iter().zip(&depths) {
            let s = depth.map(|x| x / env.tau);
            for &t in &card.tris[..card.n_tris] {
                env.s_max[t] = s;
            }
        }
    }
    env.precompute_ms = t0.elapsed().as_secs_f64() * 1e3;
    env
}

/// The area-weighted mean albedo of the leaf cards, linear RGB: each
/// material's base colour times the mean of its texture's opaque texels
/// (those its alpha test keeps), as the renderer reads them.
fn mean_leaf_albedo(model: &Model, cards: &[Card]) -> [f32; 3] {
    let srgb = |c: u8| {
        let c = c as f32 / 255.0;
        if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
    };
    let per_material: Vec<[f32; 3]> = model
        .materials
        .iter()
        .map(|m| {
            let base = [m.base_color[0], m.base_color[1], m.base_color[2]];
            let Some(tex) = m.texture.and_then(|t| model.textures.get(t as usize)) else {
                return base;
            };
            let cut = m.alpha_cutoff.unwrap_or(0.0);
            let (mut sum, mut n) = ([0.0f64; 3], 0usize);
            for px in tex.rgba.chunks_exact(4).filter(|px| px[3] as f32 / 255.0 >= cut) {
                for c in 0..3 {
                    sum[c] += srgb(px[c]) as f64;
                }
                n += 1;
            }
            if n == 0 {
                return base;
            }
            std::array::from_fn(|c| base[c] * (sum[c] / n as f64) as f32)
        })
        .collect();
    let (mut sum, mut area) = ([0.0f64; 3], 0.0f64);
    for card in cards {
        let a = per_material[model.material[card.tris[0]] as usize];
        for c in 0..3 {
            sum[c] += (a[c] * card.area) as f64;
        }
        area += card.area as f64;
    }
    if area > 0.0 { sum.map(|x| (x / area) as f32) } else { [0.0; 3] }
}

/// Average of M(N·a) M(N·b) over uniformly distributed unit normals N, for
/// unit vectors at angle γ (paper eq. 31; the Appendix's A_vt).
pub fn normal_average(gamma: f32) -> f32 {
    ((PI - gamma) * gamma.cos() + gamma.sin()) / (6.0 * PI)
}

/// Per-model, per-sun constants of the indirect and sun terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunTerms {
    /// ω_l, the unit direction towards the sun.
    pub sun: Vec3,
    /// M(ω_l·ω_j).
    pub m: [f32; N_DIR],
    /// M(ω_l·ω_j) / Σ_j' M(ω_l·ω_j'): the weights of eq. 7.
    pub weights: [f32; N_DIR],
    /// a_j = 2ρ(sin α_j − α_j cos α_j) / (3π N_dir): G1's factor of ρ̄.
    pub a: [f32; N_DIR],
    /// b_j = 2ρ π cos α_j / (3π N_dir): G1's factor of ρ_tf + ρ_tb.
    pub b: [f32; N_DIR],
    /// G2 = τ / Σ_j M(ω_l·ω_j) (eq. 24).
    pub g2: f32,
    /// G3_j = τ (1 − Σ_j' M(ω_l·ω_j')(ω_j·ω_j') / Σ_j' M(ω_l·ω_j')) (eq. 25).
    pub g3: [f32; N_DIR],
}

impl SunTerms {
    /// G1(j, ω_l) (eq. 18) for one channel's coefficients [ρ_rf, ρ_rb, ρ_tf, ρ_tb].
    pub fn g1(&self, j: usize, coeffs: [f32; 4]) -> f32 {
        let [rf, rb, tf, tb] = coeffs;
        (rf + rb + tf + tb) * self.a[j] + (tf + tb) * self.b[j]
    }
}

/// The per-sun constants for a model's envelope and the direction
/// `sun_towards` (from the leaves towards the sun; normalised here).
pub fn sun_terms(env: &LeafEnvelope, sun_towards: Vec3) -> SunTerms {
    let sun = sun_towards.normalize();
    let dirs = directions();
    let m = dirs.map(|w| m(sun.dot(w)));
    // Some diagonal is within 55° of any direction, so the sum is ≥ 1/√3.
    let sum: f32 = m.iter().sum();
    let weights = m.map(|x| x / sum);
    let scale = 2.0 * env.leaf_density / (3.0 * PI * N_DIR as f32);
    let alpha = dirs.map(|w| sun.dot(w).clamp(-1.0, 1.0).acos());
    let a = alpha.map(|al| scale * (al.sin() - al * al.cos()));
    let b = alpha.map(|al| scale * PI * al.cos());
    let g3 = dirs.map(|wj| {
        let c: f32 = (0..N_DIR).map(|k| weights[k] * wj.dot(dirs[k])).sum();
        // c ≤ 1 exactly; rounding may overshoot.
        (env.tau * (1.0 - c)).max(0.0)
    });
    SunTerms { sun, m, weights, a, b, g2: env.tau / sum, g3 }
}

/// The leaf's cosine-weighted BSDF F(P, ω_o, ω) (eq. 4) for a front normal,
/// the direction to the viewer and coefficients [ρ_rf, ρ_rb, ρ_tf, ρ_tb].
pub fn bsdf(normal: Vec3, to_eye: Vec3, coeffs: [f32; 4], w: Vec3) -> f32 {
    let [rf, rb, tf, tb] = coeffs;
    let c = normal.dot(w);
    if normal.dot(to_eye) >= 0.0 {
        (rf * m(c) + tb * m(-c)) / PI
    } else {
        (tf * m(c) + rb * m(-c)) / PI
    }
}

/// s_max(P, ω_l) for the terms' sun (eq. 7).
pub fn sun_distance(terms: &SunTerms, s: &[f32; N_DIR]) -> f32 {
    (0..N_DIR).map(|j| terms.weights[j] * s[j]).sum()
}

/// Lo_sample(P, j) (eq. 23): radiance scattered towards P by the leaves in
/// direction ω_j, before P's own BSDF and the leaf area A.
pub fn lo_sample(
    terms: &SunTerms,
    s: &[f32; N_DIR],
    j: usize,
    coeffs: [f32; 4],
    e_sun: f32,
) -> f32 {
    lo_sample_from(terms, s, j, coeffs, e_sun, 0.0)
}

/// Lo_sample with the slices starting at distance `s0` instead of 0 (the
/// tests leave out a small ball around P).
fn lo_sample_from(
    terms: &SunTerms,
    s: &[f32; N_DIR],
    j: usize,
    coeffs: [f32; 4],
    e_sun: f32,
    s0: f32,
) -> f32 {
    let len = s[j] - s0;
    if len <= 0.0 {
        return 0.0;
    }
    // G2 Σ M s_max = τ s_max(P, ω_l).
    let sun_depth = terms.g2 * (0..N_DIR).map(|k| terms.m[k] * s[k]).sum::<f32>();
    let g3 = terms.g3[j];
    // ∫_{s0}^{s_max} e^{−G3 s} ds, with the G3 → 0 limit.
    let integral = if g3 > 0.0 { (-g3 * s0).exp() * -(-g3 * len).exp_m1() / g3 } else { len };
    terms.g1(j, coeffs) * e_sun * (-sun_depth).exp() * integral
}

/// The three terms (sky, sun, indirect sun) of outgoing radiance from leaf
/// triangle `tri` towards the viewer, for one colour channel: `normal` is
/// the leaf's front normal, `to_eye` the unit direction to the viewer,
/// `coeffs` [ρ_rf, ρ_rb, ρ_tf, ρ_tb], `e_sun` the sun's irradiance and `sky`
/// the per-direction sky radiance (see [`sky_radiance_per_direction`]).
#[allow(clippy::too_many_arguments)] // mirrors the shader's inputs one to one
pub fn shade(
    env: &LeafEnvelope,
    terms: &SunTerms,
    tri: usize,
    normal: Vec3,
    to_eye: Vec3,
    coeffs: [f32; 4],
    e_sun: f32,
    sky: &[f32; N_DIR],
) -> (f32, f32, f32) {
    let f = |w: Vec3| bsdf(normal, to_eye, coeffs, w);
    let (lo_sky, lo_ind) = sky_and_bounce(env, terms, tri, &f, coeffs, e_sun, sky);
    let lo_sun = f(terms.sun) * (-env.tau * sun_distance(terms, &env.s_max[tri])).exp() * e_sun; // eq. 8
    (lo_sky, lo_sun, lo_ind)
}

/// The sky and one-bounce terms on wood triangle `tri` (Lambertian of
/// `albedo`, its `normal` facing the viewer), lit by the model's leaves,
/// whose coefficients are `leaves` (of their mean albedo).
#[allow(clippy::too_many_arguments)] // mirrors the shader's inputs one to one
pub fn shade_wood(
    env: &LeafEnvelope,
    terms: &SunTerms,
    tri: usize,
    normal: Vec3,
    albedo: f32,
    leaves: [f32; 4],
    e_sun: f32,
    sky: &[f32; N_DIR],
) -> (f32, f32) {
    let f = |w: Vec3| albedo * normal.dot(w).max(0.0) / PI;
    sky_and_bounce(env, terms, tri, &f, leaves, e_sun, sky)
}

/// Eq. 6 (sky) and eq. 11 (one bounce of sun light off neighbours of
/// coefficients `neighbours`) for a receiver whose cosine-weighted BSDF
/// towards the viewer is `f`.
fn sky_and_bounce(
    env: &LeafEnvelope,
    terms: &SunTerms,
    tri: usize,
    f: &dyn Fn(Vec3) -> f32,
    neighbours: [f32; 4],
    e_sun: f32,
    sky: &[f32; N_DIR],
) -> (f32, f32) {
    let s = &env.s_max[tri];
    let dirs = directions();
    let (mut lo_sky, mut lo_ind) = (0.0, 0.0);
    for j in 0..N_DIR {
        let f = f(dirs[j]);
        lo_sky += f * (-env.tau * s[j]).exp() * sky[j]; // eq. 6
        lo_ind += f * lo_sample(terms, s, j, neighbours, e_sun); // eq. 11
    }
    (lo_sky * 4.0 * PI / N_DIR as f32, lo_ind * env.leaf_area)
}

/// Mean sky radiance over each direction's octant, for eq. 6. `sky` gives
/// the radiance arriving from a unit direction (y up). The four octants
/// below the horizon see the ground: a Lambertian ground of albedo
/// `ground_albedo` lit by the sky, i.e. albedo × the cosine-weighted mean
/// of the upper-hemisphere radiance (equal to its plain mean for a uniform
/// sky). Each octant is sampled on a 32 × 32 grid of equal solid angle.
pub fn sky_radiance_per_direction(
    sky: impl Fn(Vec3) -> [f32; 3],
    ground_albedo: [f32; 3],
) -> [[f32; 3]; N_DIR] {
    const K: usize = 32;
    let dirs = directions();
    let mut out = [[0.0f32; 3]; N_DIR];
    let mut cos_weighted = [0.0f64; 3];
    for (j, w) in dirs.iter().enumerate().filter(|(_, w)| w.y > 0.0) {
        let mut sum = [0.0f64; 3];
        for a in 0..K {
            // Uniform in y is uniform in solid angle (Archimedes).
            let y = (a as f32 + 0.5) / K as f32;
            let r = (1.0 - y * y).sqrt();
            for b in 0..K {
                let phi = (b as f32 + 0.5) / K as f32 * 0.5 * PI;
                let d = Vec3::new(w.x.signum() * r * phi.cos(), y, w.z.signum() * r * phi.sin());
                let l = sky(d);
                for c in 0..3 {
                    sum[c] += l[c] as f64;
                    cos_weighted[c] += (l[c] * y) as f64;
                }
            }
        }
        out[j] = sum.map(|x| (x / (K * K) as f64) as f32);
    }
    // (1/π)∫ L cos dω over the hemisphere = 2 × mean of L·cos over uniform samples.
    let ground =
        [0, 1, 2].map(|c| ground_albedo[c] * (2.0 * cos_weighted[c] / (4 * K * K) as f64) as f32);
    for (j, w) in dirs.iter().enumerate() {
        if w.y < 0.0 {
            out[j] = ground;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_scene::model::Material;
    use sylva_scene::rng::SplitMix64;
    use sylva_scene::trees::{Species, TreeParams, generate};

    const COEFFS: [f32; 4] = [0.30, 0.40, 0.20, 0.25];

    fn unit(rng: &mut SplitMix64) -> Vec3 {
        let z = 2.0 * rng.next_f64() - 1.0;
        let phi = std::f64::consts::TAU * rng.next_f64();
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32)
    }

    /// Distance from `q` (inside) to the sphere of radius `r` at the origin along unit `d`.
    fn chord(q: Vec3, d: Vec3, r: f32) -> f32 {
        let b = q.dot(d);
        -b + (b * b - (q.length_squared() - r * r)).max(0.0).sqrt()
    }

    fn sphere_env(p: Vec3, r: f32, tau: f32, area: f32) -> LeafEnvelope {
        LeafEnvelope {
            s_max: vec![directions().map(|w| chord(p, w, r))],
            tau,
            leaf_density: 2.0 * tau / area,
            leaf_area: area,
            ..Default::default()
        }
    }

    #[test]
    fn directions_are_diagonals_in_opposite_pairs_and_bins_are_nearest() {
        let d = directions();
        for j in 0..4 {
            assert!((d[j + 4] + d[j]).length() < 1e-6);
            assert!(d[j].y < 0.0);
        }
        assert!(d.iter().all(|w| (w.length() - 1.0).abs() < 1e-6));
        let mut rng = SplitMix64::new(5);
        for _ in 0..10_000 {
            let v = unit(&mut rng);
            let best = (0..N_DIR).max_by(|&a, &b| v.dot(d[a]).total_cmp(&v.dot(d[b]))).unwrap();
            assert_eq!(bin_of(v), best, "{v}");
        }
    }

    #[test]
    fn normal_average_matches_a_numerical_sum_and_g1_assembles_it() {
        let n = 4_000_000;
        for alpha in [0.1f32, 0.7, 1.5, 2.3, 3.0] {
            let (wj, wl) = (Vec3::X, Vec3::new(alpha.cos(), 0.0, alpha.sin()));
            let mut rng = SplitMix64::new(42);
            let (mut refl, mut trans) = (0.0f64, 0.0f64);
            for _ in 0..n {
                let nn = unit(&mut rng);
                refl += (m(nn.dot(wl)) * m(nn.dot(-wj))) as f64;
                trans += (m(nn.dot(wl)) * m(nn.dot(wj))) as f64;
            }
            let (refl, trans) = ((refl / n as f64) as f32, (trans / n as f64) as f32);
            let (er, et) = (normal_average(PI - alpha), normal_average(alpha));
            let (rel_r, rel_t) = ((refl / er - 1.0).abs(), (trans / et - 1.0).abs());
            eprintln!(
                "alpha {alpha}: reflection {refl:.6e} vs {er:.6e} ({:.3} %), transmission {trans:.6e} vs {et:.6e} ({:.3} %)",
                100.0 * rel_r,
                100.0 * rel_t
            );
            assert!(rel_r < 0.02 && rel_t < 0.02, "alpha {alpha}: {rel_r} {rel_t}");
            // Paper's A_vr(α) = (sin α − α cos α)/(6π).
            assert!((er - (alpha.sin() - alpha * alpha.cos()) / (6.0 * PI)).abs() < 1e-6);
        }
        // G1 = ρ 4π/N_dir × [(ρ_rf+ρ_rb) A_vr + (ρ_tf+ρ_tb) A_vt] / π (eqs. 10, 15, 16).
        let env =
            LeafEnvelope { tau: 1.3, leaf_density: 7.0, leaf_area: 0.37, ..Default::default() };
        let t = sun_terms(&env, Vec3::new(0.3, 1.0, -0.4));
        for j in 0..N_DIR {
            let al = t.sun.dot(directions()[j]).clamp(-1.0, 1.0).acos();
            let [rf, rb, tf, tb] = COEFFS;
            let want = 7.0 * 4.0 * PI / 8.0
                * ((rf + rb) * normal_average(PI - al) + (tf + tb) * normal_average(al))
                / PI;
            assert!(
                (t.g1(j, COEFFS) - want).abs() < 1e-5 * want.abs().max(1e-3),
                "j {j}: {} vs {want}",
                t.g1(j, COEFFS)
            );
        }
    }

    fn test_points() -> [Vec3; 3] {
        [Vec3::ZERO, Vec3::new(0.4, -0.3, 0.2), Vec3::new(0.85, 0.3, -0.1)]
    }

    fn test_suns() -> [Vec3; 4] {
        [
            Vec3::new(0.3, 1.0, 0.2),
            Vec3::new(-1.0, 0.2, 0.5),
            directions()[4],
            Vec3::new(0.1, -0.2, 1.0),
        ]
    }

    #[test]
    fn closed_form_lo_sample_matches_the_slice_sum() {
        let (r, tau, area, e_sun) = (1.0, 2.0, 1e-4, 3.0);
        let dirs = directions();
        let mut worst = 0.0f32;
        let mut worst_true = 0.0f32;
        for p in test_points() {
            let env = sphere_env(p, r, tau, area);
            let s = env.s_max[0];
            for sun in test_suns() {
                let t = sun_terms(&env, sun);
                for j in 0..N_DIR {
                    let closed = lo_sample(&t, &s, j, COEFFS, e_sun);
                    let ns = 20_000;
                    let ds = s[j] / ns as f32;
                    let (mut sum, mut sum_true) = (0.0f64, 0.0f64);
                    for i in 1..=ns {
                        let si = i as f32 * ds;
                        // Eq. 22: the model's sun distance from P + s ω_j.
                        let s22: f32 = (0..N_DIR)
                            .map(|k| t.weights[k] * (s[k] - dirs[j].dot(dirs[k]) * si))
                            .sum();
                        sum += ((-tau * si).exp() * (-tau * s22).exp() * e_sun * ds) as f64;
                        // The sphere's exact sun distance, for information.
                        let exact = chord(p + dirs[j] * si, t.sun, r);
                        sum_true += ((-tau * si).exp() * (-tau * exact).exp() * e_sun * ds) as f64;
                    }
                    let slice = t.g1(j, COEFFS) * sum as f32;
                    let rel = (closed / slice - 1.0).abs();
                    worst = worst.max(rel);
                    worst_true =
                        worst_true.max((closed / (t.g1(j, COEFFS) * sum_true as f32) - 1.0).abs());
                    assert!(rel < 0.02, "P {p} sun {sun} j {j}: closed {closed} slices {slice}");
                    assert!(closed.is_finite() && closed >= 0.0);
                }
            }
        }
        eprintln!(
            "Lo_sample closed form vs eq. 17 slice sum: worst {:.4} %; vs exact sphere irradiance: worst {:.1} %",
            100.0 * worst,
            100.0 * worst_true
        );
    }

    /// Lo_ind as an explicit sum over random leaves around `p`, and the
    /// closed form, both leaving out the ball of radius `r0` around P.
    /// `model_geometry`: leaves fill the model's envelope (octant sectors
    /// of radius s_max(P, ω_j)), directions snap to ω_j and the neighbours'
    /// sun distance is eq. 22: this isolates the normal averaging, leaf
    /// counting and integration. Otherwise: leaves fill the true sphere,
    /// with exact directions and exact sun distances.
    fn lo_ind_explicit(p: Vec3, sun: Vec3, model_geometry: bool, seed: u64) -> (f32, f32) {
        let (r, tau, density, e_sun, r0) = (1.0f32, 2.0f32, 2.0e5f32, 1.0f32, 0.08f32);
        let area = 2.0 * tau / density;
        let env = sphere_env(p, r, tau, area);
        let s = env.s_max[0];
        let t = sun_terms(&env, sun);
        let dirs = directions();
        let (normal, to_eye) =
            (Vec3::new(0.2, 0.9, -0.3).normalize(), Vec3::new(0.5, 0.4, 0.7).normalize());
        let closed: f32 = area
            * (0..N_DIR)
                .map(|j| {
                    bsdf(normal, to_eye, COEFFS, dirs[j])
                        * lo_sample_from(&t, &s, j, COEFFS, e_sun, r0)
                })
                .sum::<f32>();
        // Leaves uniform in a ball around `centre` of radius `radius`.
        let (centre, radius) = if model_geometry {
            (p, s.iter().cloned().fold(0.0, f32::max))
        } else {
            (Vec3::ZERO, r)
        };
        let count = (density * 4.0 / 3.0 * PI * radius.powi(3)).round() as usize;
        let mut rng = SplitMix64::new(seed);
        let mut sum = 0.0f64;
        for _ in 0..count {
            let q = centre + unit(&mut rng) * radius * (rng.next_f64() as f32).cbrt();
            let n_leaf = unit(&mut rng);
            let d = q - p;
            let dist = d.length();
            if dist < r0 {
                continue;
            }
            let j = bin_of(d);
            let (w, sun_dist) = if model_geometry {
                if dist > s[j] {
                    continue;
                }
                (
                    dirs[j],
                    (0..N_DIR)
                        .map(|k| t.weights[k] * (s[k] - dirs[j].dot(dirs[k]) * dist))
                        .sum::<f32>(),
                )
            } else {
                (d / dist, chord(q, t.sun, r))
            };
            // Eq. 9: F(P, ω_o, PP') Lo_sun(P', −PP') V |N'·PP'| / |PP'|².
            let lo_sun = bsdf(n_leaf, -w, COEFFS, t.sun) * (-tau * sun_dist).exp() * e_sun;
            sum += (bsdf(normal, to_eye, COEFFS, w)
                * lo_sun
                * (-tau * dist).exp()
                * n_leaf.dot(w).abs()
                / (dist * dist)) as f64;
        }
        (closed, area * sum as f32)
    }

    #[test]
    fn closed_form_lo_ind_matches_a_sum_over_random_leaves() {
        let mut worst = 0.0f32;
        for (k, (p, sun)) in [
            (Vec3::ZERO, Vec3::new(0.3, 1.0, 0.2)),
            (Vec3::new(0.4, -0.3, 0.2), Vec3::new(-1.0, 0.2, 0.5)),
            (Vec3::new(0.1, 0.5, 0.3), Vec3::new(0.2, 1.0, -0.6)),
        ]
        .into_iter()
        .enumerate()
        {
            let (closed, explicit) = lo_ind_explicit(p, sun, true, 100 + k as u64);
            let rel = (closed / explicit - 1.0).abs();
            worst = worst.max(rel);
            let (closed_t, explicit_t) = lo_ind_explicit(p, sun, false, 200 + k as u64);
            eprintln!(
                "P {p} sun {sun}: model geometry closed {closed:.5e} explicit {explicit:.5e} ({:.2} %); true sphere closed {closed_t:.5e} explicit {explicit_t:.5e} ({:+.1} %)",
                100.0 * rel,
                100.0 * (closed_t / explicit_t - 1.0)
            );
            assert!(rel < 0.02, "P {p} sun {sun}: closed {closed} explicit {explicit}");
        }
        eprintln!("worst model-geometry error {:.2} %", 100.0 * worst);
    }

    #[test]
    fn precompute_on_a_generated_tree() {
        let model =
            generate(&TreeParams { species: Species::RedMaple, triangles: Some(20_000), seed: 1 })
                .unwrap();
        let env = precompute(&model);
        eprintln!(
            "tree: {} leaves, tau {}, density {}, area {}, {:.1} ms",
            env.leaves, env.tau, env.leaf_density, env.leaf_area, env.precompute_ms
        );
        assert!(env.tau > 0.0 && env.tau.is_finite());
        assert_eq!(env.s_max.len(), model.triangle_count());
        assert!(env.s_max.iter().flatten().all(|s| s.is_finite() && *s >= 0.0));
        let leaf_tris: Vec<usize> =
            (0..model.triangle_count()).filter(|&t| model.surface(t) == Surface::Leaf).collect();
        // Wood is measured too: the branches inside the crown see leaves.
        let wood: Vec<usize> =
            (0..model.triangle_count()).filter(|&t| model.surface(t) == Surface::Wood).collect();
        let shaded = wood.iter().filter(|&&t| env.s_max[t].iter().any(|&s| s > 0.0)).count();
        assert!(shaded * 2 > wood.len(), "{shaded} of {} wood triangles see foliage", wood.len());
        // The leaves' mean albedo is a leaf's: green above red above blue, all in (0, 1).
        let [r, g, b] = env.leaf_albedo;
        assert!(0.0 < b && b < r && r < g && g < 1.0, "{:?}", env.leaf_albedo);
        // Quads are cards: both halves share their values.
        assert!(env.leaves * 2 <= leaf_tris.len() + 1);
        assert_eq!(env.s_max[leaf_tris[0]], env.s_max[leaf_tris[1]]);
        let centre_of = |t: usize| model.triangle(t).iter().sum::<Vec3>() / 3.0;
        // Each leaf sees more foliage towards the octant holding the most
        // leaves within 4 m than towards the one holding the fewest.
        let cards: Vec<(usize, Vec3)> =
            leaf_tris.iter().step_by(2).map(|&t| (t, centre_of(t))).collect();
        let (mut more, mut ratio_in, mut ratio_out) = (0usize, 0.0f64, 0.0f64);
        for &(t, p) in &cards {
            let mut count = [0usize; N_DIR];
            for &(u, q) in &cards {
                let d = q - p;
                if u != t && d.length_squared() < 16.0 {
                    count[bin_of(d)] += 1;
                }
            }
            let most = (0..N_DIR).max_by_key(|&j| count[j]).unwrap();
            let fewest = (0..N_DIR).min_by_key(|&j| count[j]).unwrap();
            more += (env.s_max[t][most] > env.s_max[t][fewest]) as usize;
            ratio_in += env.s_max[t][most] as f64;
            ratio_out += env.s_max[t][fewest] as f64;
        }
        let frac = more as f32 / cards.len() as f32;
        eprintln!(
            "tree: s_max towards the fullest octant > towards the emptiest for {:.1} % of leaves; means {:.3} vs {:.3}",
            100.0 * frac,
            ratio_in / cards.len() as f64,
            ratio_out / cards.len() as f64
        );
        assert!(frac > 0.8 && ratio_in > 2.0 * ratio_out, "{frac} {ratio_in} {ratio_out}");
        // The shading terms are finite on a real tree.
        let t = sun_terms(&env, Vec3::Y);
        let sky = [0.0; N_DIR];
        let (_, sun_in, ind_in) =
            shade(&env, &t, leaf_tris[0], Vec3::Y, Vec3::Y, COEFFS, 1.0, &sky);
        assert!(sun_in.is_finite() && ind_in.is_finite() && ind_in >= 0.0);
    }

    #[test]
    fn precompute_on_a_sphere_of_cards_recovers_density_and_thickness() {
        // 20,000 random square cards uniformly in a unit sphere.
        let mut model = Model::default();
        let leaf = model.add_material(Material::plain("leaf", Surface::Leaf, [0.2, 0.6, 0.1]));
        let mut rng = SplitMix64::new(7);
        let (n, side) = (20_000usize, 0.02f32);
        for _ in 0..n {
            let c = unit(&mut rng) * (rng.next_f64() as f32).cbrt();
            let nn = unit(&mut rng);
            let u = nn.any_orthonormal_vector() * side * 0.5;
            let v = nn.cross(u);
            model.push_quad([c - u - v, c + u - v, c + u + v, c - u + v], leaf);
        }
        let env = precompute(&model);
        let true_tau = 0.5 * n as f32 / (4.0 / 3.0 * PI) * side * side;
        eprintln!("sphere: tau {} (true {true_tau}), {:.1} ms", env.tau, env.precompute_ms);
        assert_eq!(env.leaves, n);
        assert_eq!(env.leaf_albedo, [0.2, 0.6, 0.1], "one untextured material: its colour");
        assert!((env.tau / true_tau - 1.0).abs() < 0.35, "tau {} true {true_tau}", env.tau);
        // Near the centre, τ s_max ≈ τ R in every direction.
        let mut depth = Vec::new();
        for t in (0..model.triangle_count()).step_by(2) {
            let c = model.triangle(t).iter().sum::<Vec3>() / 3.0;
            if c.length() < 0.25 {
                depth.extend(env.s_max[t].iter().map(|s| s * env.tau));
            }
        }
        let mean = depth.iter().sum::<f32>() / depth.len() as f32;
        eprintln!("centre leaves: mean optical depth {mean}, true about {true_tau}");
        assert!((mean / true_tau - 1.0).abs() < 0.3, "mean depth {mean} true {true_tau}");
        // Leaves at the surface near a diagonal see (almost) nothing outwards:
        // every direction of that octant leaves the sphere at once.
        let mut out = Vec::new();
        for t in (0..model.triangle_count()).step_by(2) {
            let c = model.triangle(t).iter().sum::<Vec3>() / 3.0;
            let j = bin_of(c);
            if c.length() > 0.93 && c.normalize().dot(directions()[j]) > 25f32.to_radians().cos() {
                out.push(env.s_max[t][j] * env.tau);
            }
        }
        let out_mean = out.iter().sum::<f32>() / out.len() as f32;
        eprintln!("{} surface leaves: mean optical depth outwards {out_mean}", out.len());
        assert!(out.len() > 20 && out_mean < 0.3 * mean, "{out_mean} vs {mean}");
    }

    #[test]
    fn sky_average_and_ground_reflection() {
        let sky = |d: Vec3| [1.0 + d.y, 2.0, 0.5 * d.x.max(0.0)];
        let l = sky_radiance_per_direction(sky, [0.5, 0.25, 0.1]);
        let d = directions();
        for j in 4..8 {
            // Mean of y over an upper octant is 1/2.
            assert!((l[j][0] - 1.5).abs() < 1e-3 && (l[j][1] - 2.0).abs() < 1e-5, "{:?}", l[j]);
            if d[j].x < 0.0 {
                assert_eq!(l[j][2], 0.0);
            }
        }
        // Ground: albedo × (1/π)∫(1 + cos θ) cos θ dω = albedo × (1 + 2/3).
        for lj in &l[..4] {
            assert!(
                (lj[0] - 0.5 * (1.0 + 2.0 / 3.0)).abs() < 2e-3 && (lj[1] - 0.25 * 2.0).abs() < 1e-4,
                "{lj:?}"
            );
        }
    }

    #[test]
    fn shade_terms_match_the_equations_for_a_single_direction() {
        let env = sphere_env(Vec3::ZERO, 1.0, 1.5, 1e-3);
        let t = sun_terms(&env, Vec3::Y);
        let mut sky = [0.0; N_DIR];
        sky[4] = 2.0;
        let n = directions()[4];
        let (lo_sky, lo_sun, lo_ind) = shade(&env, &t, 0, n, n, COEFFS, 3.0, &sky);
        let want_sky = 4.0 * PI / 8.0 * COEFFS[0] / PI * (-1.5f32).exp() * 2.0;
        assert!((lo_sky - want_sky).abs() < 1e-5, "{lo_sky} {want_sky}");
        let want_sun = COEFFS[0] / PI * XI * (-1.5f32).exp() * 3.0;
        assert!((lo_sun - want_sun).abs() < 1e-5, "{lo_sun} {want_sun}");
        assert!(lo_ind > 0.0 && lo_ind.is_finite());
    }
}
