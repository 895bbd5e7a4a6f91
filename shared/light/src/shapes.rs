//! Built-in shapes for solving and testing without input files: a small
//! plant (a wooden trunk under a sphere of leaves) and a procedural cloud.

use crate::lb::{GridDims, MediumGrid, NodeClass};
use glam::Vec3;
use sylva_scene::model::{Material, Model, Surface};
use sylva_scene::rng::SplitMix64;

/// Leaves in the built-in plant's crown.
pub const PLANT_LEAVES: usize = 4000;

/// The built-in plant: an eight-sided trunk 1.3 high and a crown of
/// [`PLANT_LEAVES`] randomly oriented square leaves filling a sphere of
/// radius 0.7 around (0, 1.4, 0).
pub fn plant(seed: u64) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut mesh = Model::default();
    let bark = mesh.add_material(Material::plain("bark", Surface::Wood, [0.3, 0.2, 0.12]));
    let leaf = mesh.add_material(Material::plain("leaf", Surface::Leaf, [0.18, 0.42, 0.1]));
    let (r, h, sides) = (0.06f32, 1.3f32, 8);
    for s in 0..sides {
        let a0 = s as f32 / sides as f32 * std::f32::consts::TAU;
        let a1 = (s + 1) as f32 / sides as f32 * std::f32::consts::TAU;
        let (p0, p1) = (
            Vec3::new(a0.cos() * r, 0.0, a0.sin() * r),
            Vec3::new(a1.cos() * r, 0.0, a1.sin() * r),
        );
        let up = Vec3::Y * h;
        mesh.push_quad([p0, p0 + up, p1 + up, p1], bark);
    }
    let centre = Vec3::new(0.0, 1.4, 0.0);
    let (radius, size) = (0.7f32, 0.09f32);
    let mut placed = 0;
    while placed < PLANT_LEAVES {
        let p = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        if p.length_squared() > 1.0 {
            continue;
        }
        let at = centre + p * radius;
        let normal = random_unit(&mut rng);
        let u = normal.any_orthonormal_vector() * size * 0.5;
        let v = normal.cross(u);
        mesh.push_quad([at - u - v, at + u - v, at + u + v, at - u + v], leaf);
        placed += 1;
    }
    mesh
}

fn random_unit(rng: &mut SplitMix64) -> Vec3 {
    loop {
        let p = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let l = p.length_squared();
        if l > 1e-4 && l <= 1.0 {
            return p / l.sqrt();
        }
    }
}

/// A procedural cumulus on an `n³` grid: a heap of soft spheres, flatter at
/// the base, with value noise eroding its edges. Densities in [0, 1], class
/// [`NodeClass::Medium`], nothing on the boundary shell.
pub fn cloud(n: usize, seed: u64) -> MediumGrid {
    let mut rng = SplitMix64::new(seed);
    let dims = GridDims::cube(n);
    // Puffs in unit-cube coordinates: centre and radius.
    let mut puffs = vec![(Vec3::new(0.5, 0.42, 0.5), 0.22f32)];
    for _ in 0..10 {
        let c = Vec3::new(rng.range(0.28, 0.72), rng.range(0.36, 0.6), rng.range(0.28, 0.72));
        puffs.push((c, rng.range(0.1, 0.17)));
    }
    let noise = ValueNoise::new(seed ^ 0xC10D);
    let mut medium = MediumGrid::empty(dims);
    for z in 1..n - 1 {
        for y in 1..n - 1 {
            for x in 1..n - 1 {
                let p = (Vec3::new(x as f32, y as f32, z as f32) + 0.5) / n as f32;
                let inside = puffs
                    .iter()
                    .map(|&(c, r)| 1.0 - (p - c).length() / r)
                    .fold(f32::NEG_INFINITY, f32::max);
                let base = ((p.y - 0.3) / 0.06).clamp(0.0, 1.0); // flat bottom
                let d = (inside * 3.0 + 0.35 * (noise.fbm(p * 8.0) - 0.5)).clamp(0.0, 1.0) * base;
                medium.density[dims.index(x, y, z)] = d;
            }
        }
    }
    medium.with_class(NodeClass::Medium)
}

/// Smoothly interpolated lattice noise in [0, 1].
struct ValueNoise {
    seed: u64,
}

impl ValueNoise {
    fn new(seed: u64) -> Self {
        Self { seed }
    }

    fn lattice(&self, i: i32, j: i32, k: i32) -> f32 {
        let key = (i as u64).wrapping_mul(0x9E37_79B9)
            ^ (j as u64).wrapping_mul(0x85EB_CA6B) << 1
            ^ (k as u64).wrapping_mul(0xC2B2_AE35) << 2
            ^ self.seed;
        SplitMix64::new(key).next_f32()
    }

    fn at(&self, p: Vec3) -> f32 {
        let f = p.floor();
        let t = p - f;
        let s = t * t * (Vec3::splat(3.0) - 2.0 * t);
        let (i, j, k) = (f.x as i32, f.y as i32, f.z as i32);
        let mut acc = 0.0;
        for dz in 0..2 {
            for dy in 0..2 {
                for dx in 0..2 {
                    let w = (if dx == 1 { s.x } else { 1.0 - s.x })
                        * (if dy == 1 { s.y } else { 1.0 - s.y })
                        * (if dz == 1 { s.z } else { 1.0 - s.z });
                    acc += w * self.lattice(i + dx, j + dy, k + dz);
                }
            }
        }
        acc
    }

    fn fbm(&self, p: Vec3) -> f32 {
        (0..3).map(|o| self.at(p * (1 << o) as f32) / (1 << o) as f32).sum::<f32>() / 1.75
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plant_is_deterministic_and_has_wood_and_leaves() {
        let a = plant(1);
        let b = plant(1);
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangle_count(), 16 + 2 * PLANT_LEAVES);
        assert_eq!(a.wood_triangles(), 16);
    }

    #[test]
    fn cloud_is_a_valid_medium_away_from_the_boundary() {
        let c = cloud(24, 3);
        c.validate().unwrap();
        assert!(c.occupancy() > 0.05 && c.occupancy() < 0.6, "occupancy {}", c.occupancy());
    }
}
