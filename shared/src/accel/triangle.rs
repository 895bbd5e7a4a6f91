//! The Möller–Trumbore ray–triangle test.

use super::Ray;
use glam::Vec3;

/// Distance and barycentrics `(t, u, v)` of the hit of `ray` on triangle
/// `(a, b, c)`, the hit point being `(1 − u − v) a + u b + v c`, when
/// `t_min < t < t_max`. Both faces are hit.
#[inline]
pub fn intersect(ray: &Ray, a: Vec3, b: Vec3, c: Vec3, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
    let e1 = b - a;
    let e2 = c - a;
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
        assert!(intersect(&Ray::new(Vec3::new(0.8, 0.8, 1.0), Vec3::NEG_Z), a, b, c, 0.0, 10.0).is_none());
        assert!(intersect(&r, a, b, c, 0.0, 0.5).is_none());
    }
}
