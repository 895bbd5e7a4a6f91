//! Builds a tree model from a species preset, a triangle count and a seed.

use super::species::Species;
use crate::leaf::leaf_texture;
use crate::model::{Material, Model, Surface};
use crate::rng::SplitMix64;
use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};

/// What to generate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TreeParams {
    /// The species preset.
    pub species: Species,
    /// Exact triangle count of the model; default the paper's for the species.
    #[serde(default)]
    pub triangles: Option<u32>,
    /// Random seed: the same seed gives the same tree.
    #[serde(default)]
    pub seed: u64,
}

/// A tree that cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum TreeError {
    /// Too few triangles for a trunk, a branch and some leaves.
    #[error("{species} needs at least {min} triangles, got {got}")]
    TooFewTriangles { species: &'static str, min: u32, got: u32 },
    /// More than the renderer indexes.
    #[error("{species}: {got} triangles is more than the {max} a model may have")]
    TooManyTriangles { species: &'static str, max: u32, got: u32 },
}

const TRUNK_SIDES: usize = 10;
const TRUNK_SEGMENTS: usize = 8;
const BRANCH_SIDES: usize = 6;
const BRANCH_SEGMENTS: usize = 4;
const TWIG_SIDES: usize = 3;
/// Largest model, in triangles.
pub const MAX_TRIANGLES: u32 = 50_000_000;
/// Fewest leaves worth drawing.
const MIN_LEAVES: u32 = 16;

/// Generates the tree, with exactly the requested number of triangles.
pub fn generate(p: &TreeParams) -> Result<Model, TreeError> {
    let s = p.species.shape();
    let target = p.triangles.unwrap_or(s.paper_triangles);
    let name = p.species.name();
    if target > MAX_TRIANGLES {
        return Err(TreeError::TooManyTriangles { species: name, max: MAX_TRIANGLES, got: target });
    }
    // Wood costs: trunk, then per branch and per twig.
    let trunk = (2 * TRUNK_SIDES * TRUNK_SEGMENTS) as u32;
    let per_branch = (2 * BRANCH_SIDES * BRANCH_SEGMENTS) as u32;
    let per_twig = (2 * TWIG_SIDES) as u32;
    let min = trunk + per_branch + 2 * MIN_LEAVES;
    if target < min {
        return Err(TreeError::TooFewTriangles { species: name, min, got: target });
    }
    // Keep wood within a quarter of the budget: fewer branches and twigs
    // for small triangle counts.
    let wood_budget = (target / 4).max(trunk + per_branch);
    let branches = s.branches.min((wood_budget - trunk) / per_branch).max(1);
    let twigs =
        s.twigs.min((wood_budget - trunk - branches * per_branch) / (branches * per_twig).max(1));

    let mut rng = SplitMix64::new(p.seed ^ (p.species as u64) << 32);
    let mut m = Model::default();
    let bark = m.add_material(Material::plain("bark", Surface::Wood, s.bark));
    m.textures.push(leaf_texture(s.leaf_shape, s.leaf_rgb, p.seed));
    let leaf = m.add_material(Material {
        name: "leaf".into(),
        surface: Surface::Leaf,
        base_color: [1.0; 4],
        texture: Some(0),
        alpha_cutoff: Some(0.5),
        double_sided: true,
    });

    // Trunk: a slightly leaning, tapering tube up to 90 % of the height.
    let lean = Vec3::new(rng.range(-0.03, 0.03), 1.0, rng.range(-0.03, 0.03)).normalize();
    let trunk_top = 0.9 * s.height;
    let trunk_pts: Vec<(Vec3, f32)> = (0..=TRUNK_SEGMENTS)
        .map(|i| {
            let t = i as f32 / TRUNK_SEGMENTS as f32;
            (lean * trunk_top * t, s.trunk_radius * (1.0 - 0.75 * t))
        })
        .collect();
    tube(&mut m, &trunk_pts, TRUNK_SIDES, bark);

    // Branches: golden-angle spiral up the crown, lengths from the crown profile.
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut twig_tips: Vec<(Vec3, Vec3, f32)> = Vec::new();
    let base = s.crown_base * s.height;
    for b in 0..branches {
        let t = (b as f32 + 0.5) / branches as f32;
        let y = base + t * (trunk_top - base) * 0.92;
        let az = b as f32 * golden + rng.range(-0.3, 0.3);
        let pitch = (s.branch_pitch_deg + rng.range(-8.0, 8.0)).to_radians() * (1.0 - 0.35 * t);
        let dir = Vec3::new(pitch.sin() * az.cos(), pitch.cos(), pitch.sin() * az.sin());
        let len =
            s.crown_radius * s.crown.profile(t) * rng.range(0.85, 1.1) / pitch.sin().max(0.35);
        let r0 = s.trunk_radius * (1.0 - 0.75 * y / trunk_top) * 0.55;
        let start = lean * y;
        let pts: Vec<(Vec3, f32)> = (0..=BRANCH_SEGMENTS)
            .map(|i| {
                let u = i as f32 / BRANCH_SEGMENTS as f32;
                let bend = Vec3::Y * s.branch_bend * len * u * u;
                (start + dir * len * u + bend, r0 * (1.0 - 0.7 * u))
            })
            .collect();
        tube(&mut m, &pts, BRANCH_SIDES, bark);
        // Twigs along the outer two thirds of the branch.
        for k in 0..twigs {
            let u = 0.35 + 0.65 * (k as f32 + rng.next_f32()) / twigs.max(1) as f32;
            let at = along(&pts, u);
            let spin = Quat::from_axis_angle(dir, rng.range(0.0, std::f32::consts::TAU));
            let side = spin * dir.any_orthonormal_vector();
            let tdir = (dir + side * rng.range(0.5, 1.0) + Vec3::Y * 0.3).normalize();
            let tlen = 0.3 * len * (1.2 - u);
            let r = r0 * 0.25;
            tube(&mut m, &[(at, r), (at + tdir * tlen, r * 0.4)], TWIG_SIDES, bark);
            twig_tips.push((at, tdir, tlen));
        }
        if twigs == 0 {
            twig_tips.push((along(&pts, 0.5), dir, 0.5 * len));
        }
    }

    // Leaves fill the rest of the budget exactly: quads, and one triangle
    // when the remainder is odd.
    let left = target - m.triangle_count() as u32;
    let quads = left / 2;
    for k in 0..quads {
        let (at, dir, len) = twig_tips[k as usize % twig_tips.len()];
        let on_twig = at + dir * len * rng.range(0.1, 1.0);
        leaf_quad(&mut m, &mut rng, on_twig, len, s.leaf_size, leaf);
    }
    if left % 2 == 1 {
        let (at, dir, len) = twig_tips[0];
        let p = at + dir * len;
        let w = Vec3::X * s.leaf_size * 0.5;
        let uv = [glam::Vec2::new(0.0, 1.0), glam::Vec2::new(1.0, 1.0), glam::Vec2::new(0.5, 0.0)];
        m.push_triangle([p - w, p + w, p + Vec3::Y * s.leaf_size], uv, leaf);
    }
    debug_assert_eq!(m.triangle_count() as u32, target);
    Ok(m)
}

/// The point a fraction `u` along a polyline of (point, radius).
fn along(pts: &[(Vec3, f32)], u: f32) -> Vec3 {
    let x = u.clamp(0.0, 1.0) * (pts.len() - 1) as f32;
    let i = (x.floor() as usize).min(pts.len() - 2);
    pts[i].0.lerp(pts[i + 1].0, x - i as f32)
}

/// One leaf near `at`, scattered within the twig's reach, facing mostly up
/// and outwards.
fn leaf_quad(m: &mut Model, rng: &mut SplitMix64, at: Vec3, reach: f32, size: f32, material: u32) {
    let scatter =
        Vec3::new(rng.range(-1.0, 1.0), rng.range(-0.6, 1.0), rng.range(-1.0, 1.0)) * reach * 0.45;
    let base = at + scatter;
    let outward = Vec3::new(base.x, 0.0, base.z).normalize_or(Vec3::X);
    let normal = (Vec3::Y * 0.8
        + outward * 0.5
        + Vec3::new(rng.range(-0.6, 0.6), rng.range(-0.3, 0.3), rng.range(-0.6, 0.6)))
    .normalize_or(Vec3::Y);
    let tip = normal.any_orthonormal_vector();
    let tip = Quat::from_axis_angle(normal, rng.range(0.0, std::f32::consts::TAU)) * tip;
    let across = normal.cross(tip);
    let (len, half) = (size * rng.range(0.8, 1.2), size * 0.5);
    m.push_quad(
        [
            base - across * half,
            base + across * half,
            base + across * half + tip * len,
            base - across * half + tip * len,
        ],
        material,
    );
}

/// A tube through `pts` (centre, radius) with `sides` sides, open at both ends.
fn tube(m: &mut Model, pts: &[(Vec3, f32)], sides: usize, material: u32) {
    let base = m.positions.len() as u32;
    for (i, &(c, r)) in pts.iter().enumerate() {
        let next = pts[(i + 1).min(pts.len() - 1)].0;
        let prev = pts[i.saturating_sub(1)].0;
        let axis = (next - prev).normalize_or(Vec3::Y);
        let u = axis.any_orthonormal_vector();
        let v = axis.cross(u);
        for k in 0..sides {
            let a = k as f32 / sides as f32 * std::f32::consts::TAU;
            m.positions.push(c + (u * a.cos() + v * a.sin()) * r);
            m.uvs.push(glam::Vec2::new(k as f32 / sides as f32, i as f32));
        }
    }
    for i in 0..pts.len() as u32 - 1 {
        for k in 0..sides as u32 {
            let k1 = (k + 1) % sides as u32;
            let (a, b) = (base + i * sides as u32 + k, base + i * sides as u32 + k1);
            let (c, d) = (a + sides as u32, b + sides as u32);
            m.triangles.push([a, b, d]);
            m.triangles.push([a, d, c]);
            m.material.extend([material, material]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_species_hits_its_triangle_count_exactly() {
        for sp in Species::ALL {
            for n in [500, 2_001, 40_000] {
                let m = generate(&TreeParams { species: sp, triangles: Some(n), seed: 3 }).unwrap();
                assert_eq!(m.triangle_count(), n as usize, "{sp:?}");
                assert!(
                    m.wood_triangles() > 0 && m.wood_triangles() <= n as usize / 2 + 200,
                    "{sp:?} wood {}",
                    m.wood_triangles()
                );
                assert!(m.positions.iter().all(|p| p.is_finite()));
            }
        }
    }

    #[test]
    fn species_differ_in_shape() {
        let extent = |sp| {
            let m =
                generate(&TreeParams { species: sp, triangles: Some(20_000), seed: 1 }).unwrap();
            let (lo, hi) = m.bounds().unwrap();
            let e = hi - lo;
            e.y / e.x.max(e.z)
        };
        // The birch is narrow, the beech and catalpa broad.
        assert!(extent(Species::PaperBirch) > 1.5 * extent(Species::AmericanBeech));
        assert!(extent(Species::PaperBirch) > 1.5 * extent(Species::SouthernCatalpa));
    }

    #[test]
    fn same_seed_same_tree_and_too_few_triangles_refused() {
        let p = TreeParams { species: Species::RedMaple, triangles: Some(3000), seed: 9 };
        assert_eq!(generate(&p).unwrap().positions, generate(&p).unwrap().positions);
        let err = generate(&TreeParams { triangles: Some(10), ..p }).unwrap_err();
        assert!(err.to_string().contains("red_maple needs at least"), "{err}");
    }
}
