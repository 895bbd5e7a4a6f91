//! The per-leaf precomputation: leaf cards, the envelope's density and
//! τ, and each card's s_max(P, ω_j) from its measured transmittance.

use super::{N_DIR, directions};
use glam::Vec3;
use rayon::prelude::*;
use std::time::Instant;
use sylva_accel::coverage::triangle_coverage;
use sylva_accel::triangle::intersect;
use sylva_accel::two_level::{triangle_bounds, uv_at};
use sylva_accel::{Accel, AccelKind, Ray};
use sylva_scene::color::srgb8_to_linear;
use sylva_scene::model::{Model, Surface};

/// Grid cells on the longest side of the leaf-centre bounds, at most.
const GRID_CELLS: usize = 24;
/// Coarsen the grid until occupied cells hold this many leaves on average.
const MIN_LEAVES_PER_CELL: f32 = 8.0;
/// Rays per bin side: RAYS² rays measure each bin's transmittance.
const RAYS: usize = 4;

/// Per-leaf envelope distances and the per-model medium constants.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
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

impl LeafEnvelope {
    /// Checks an envelope read back (from a cache) against the model of
    /// `triangles` triangles it claims to be of, before any of it is used:
    /// one entry a triangle, every distance and constant finite and not
    /// negative.
    pub fn check(&self, triangles: usize) -> Result<(), String> {
        if self.s_max.len() != triangles {
            return Err(format!(
                "{} envelope distances for a model of {triangles} triangles",
                self.s_max.len()
            ));
        }
        let fine = |v: f32| v.is_finite() && v >= 0.0;
        let constants = [self.tau, self.leaf_density, self.leaf_area];
        if !(self.s_max.iter().flatten().all(|&v| fine(v))
            && constants.iter().chain(&self.leaf_albedo).all(|&v| fine(v))
            && self.leaves <= triangles)
        {
            return Err("an envelope distance or constant out of range".into());
        }
        Ok(())
    }
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
    accel.any_hit(ray, t_min, f32::INFINITY, &mut |tri, limit| {
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
                    sum[c] += srgb8_to_linear(px[c]) as f64;
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
