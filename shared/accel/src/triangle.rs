//! The Möller–Trumbore ray–triangle test, and the triangle record the
//! BVH's leaves hold so the test reads one contiguous 48-byte block.

use super::Ray;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// A triangle as the inner loop reads it, in a BVH's leaf order: its first
/// vertex and two edges, so no index chase precedes the test.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct TriangleRecord {
    /// First vertex.
    pub a: [f32; 3],
    /// Triangle index (in its model; the GPU's upload makes it global).
    pub triangle: u32,
    /// Second vertex minus the first.
    pub e1: [f32; 3],
    /// [`crate::coverage::OPAQUE`], or the index of its opacity micromap
    /// ([`crate::coverage::OpacityMaps`]): where it is opaque, a hole, or needs the alpha texel.
    pub opacity: u32,
    /// Third vertex minus the first.
    pub e2: [f32; 3],
    /// Material index (in its model; global on the GPU).
    pub material: u32,
}

impl TriangleRecord {
    /// The record of triangle `(a, b, c)`.
    pub fn new(triangle: u32, [a, b, c]: [Vec3; 3], opacity: u32, material: u32) -> Self {
        Self {
            a: a.to_array(),
            triangle,
            e1: (b - a).to_array(),
            opacity,
            e2: (c - a).to_array(),
            material,
        }
    }

    /// As [`intersect`].
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
        intersect_edges(ray, self.a.into(), self.e1.into(), self.e2.into(), t_min, t_max)
    }
}

/// Distance and barycentrics `(t, u, v)` of the hit of `ray` on triangle
/// `(a, b, c)`, the hit point being `(1 − u − v) a + u b + v c`, when
/// `t_min < t < t_max`. Both faces are hit.
#[inline]
pub fn intersect(
    ray: &Ray,
    a: Vec3,
    b: Vec3,
    c: Vec3,
    t_min: f32,
    t_max: f32,
) -> Option<(f32, f32, f32)> {
    intersect_edges(ray, a, b - a, c - a, t_min, t_max)
}

/// As [`intersect`], from the first vertex and the edges to the others.
#[inline]
pub fn intersect_edges(
    ray: &Ray,
    a: Vec3,
    e1: Vec3,
    e2: Vec3,
    t_min: f32,
    t_max: f32,
) -> Option<(f32, f32, f32)> {
    let p = ray.dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.origin - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = ray.dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > t_min && t < t_max).then_some((t, u, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_inside_misses_outside() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let r = Ray::new(Vec3::new(0.25, 0.25, 1.0), Vec3::NEG_Z);
        let (t, u, v) = intersect(&r, a, b, c, 0.0, 10.0).unwrap();
        assert!((t - 1.0).abs() < 1e-6 && (u - 0.25).abs() < 1e-6 && (v - 0.25).abs() < 1e-6);
        // From behind, too: leaves are two-sided.
        let back = Ray::new(Vec3::new(0.25, 0.25, -1.0), Vec3::Z);
        assert!(intersect(&back, a, b, c, 0.0, 10.0).is_some());
        assert!(
            intersect(&Ray::new(Vec3::new(0.8, 0.8, 1.0), Vec3::NEG_Z), a, b, c, 0.0, 10.0)
                .is_none()
        );
        assert!(intersect(&r, a, b, c, 0.0, 0.5).is_none());
    }
}
