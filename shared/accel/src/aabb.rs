//! Axis-aligned bounding boxes.

use super::Ray;
use glam::Vec3;

/// An axis-aligned box; empty when `min > max`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box.
    pub const EMPTY: Aabb =
        Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    /// The box around `points`.
    pub fn around(points: &[Vec3]) -> Self {
        points.iter().fold(Self::EMPTY, |b, &p| b.grow(p))
    }

    /// This box grown to hold `p`.
    pub fn grow(self, p: Vec3) -> Self {
        Self { min: self.min.min(p), max: self.max.max(p) }
    }

    /// The smallest box holding both.
    pub fn union(self, o: Aabb) -> Self {
        Self { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    /// The overlap of both (empty if none).
    pub fn intersection(self, o: Aabb) -> Self {
        Self { min: self.min.max(o.min), max: self.max.min(o.max) }
    }

    /// Whether the box holds nothing.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// Surface area (0 when empty).
    pub fn area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let e = self.max - self.min;
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// Centre.
    pub fn centroid(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// The parameter interval where `ray` is inside the box, clipped to
    /// `[t_min, t_max]`, or `None`.
    #[inline]
    pub fn clip(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32)> {
        let t0 = (self.min - ray.origin) * ray.inv_dir;
        let t1 = (self.max - ray.origin) * ray.inv_dir;
        let near = t0.min(t1).max_element().max(t_min);
        let far = t0.max(t1).min_element().min(t_max);
        (near <= far).then_some((near, far))
    }

    /// Transformed by an affine map: the box around its transformed corners.
    pub fn transformed(&self, m: &glam::Affine3A) -> Self {
        let mut b = Self::EMPTY;
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            );
            b = b.grow(m.transform_point3(c));
        }
        b
    }
}
