//! The pinhole camera.

use glam::Vec3;
use serde::Serialize;

/// A pinhole camera: rays leave `position` through a film one unit ahead.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Camera {
    /// Eye position.
    pub position: Vec3,
    /// Unit view direction.
    pub forward: Vec3,
    /// Unit vector to the image's right.
    pub right: Vec3,
    /// Unit vector to the image's top.
    pub up: Vec3,
    /// tan(vertical field of view / 2).
    pub tan_half_fov_y: f32,
}

/// A camera that cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// Eye and target coincide, or a value is not finite.
    #[error("camera position and look_at must be distinct finite points")]
    Degenerate,
    /// `up` is parallel to the view direction.
    #[error("camera up vector is parallel to the view direction")]
    UpParallel,
    /// Field of view outside (0°, 180°).
    #[error("camera fov_y_deg = {0}: valid range (0, 180)")]
    BadFov(f32),
}

impl Camera {
    /// A camera at `position` looking at `target`, `up` towards the top of
    /// the image, with a vertical field of view of `fov_y_deg` degrees.
    pub fn look_at(
        position: Vec3,
        target: Vec3,
        up: Vec3,
        fov_y_deg: f32,
    ) -> Result<Self, CameraError> {
        if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) {
            return Err(CameraError::BadFov(fov_y_deg));
        }
        let d = target - position;
        if !position.is_finite() || !target.is_finite() || d.length_squared() < 1e-12 {
            return Err(CameraError::Degenerate);
        }
        let forward = d.normalize();
        let right = forward.cross(up);
        if !up.is_finite() || right.length_squared() < 1e-10 {
            return Err(CameraError::UpParallel);
        }
        let right = right.normalize();
        Ok(Self {
            position,
            forward,
            right,
            up: right.cross(forward),
            tan_half_fov_y: (fov_y_deg.to_radians() / 2.0).tan(),
        })
    }

    /// The unit direction through film point `(px, py)` (pixels, y down) of
    /// a `width × height` image.
    pub fn direction(&self, px: f32, py: f32, width: u32, height: u32) -> Vec3 {
        let aspect = width as f32 / height as f32;
        let sx = (2.0 * px / width as f32 - 1.0) * self.tan_half_fov_y * aspect;
        let sy = (1.0 - 2.0 * py / height as f32) * self.tan_half_fov_y;
        (self.forward + self.right * sx + self.up * sy).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_pixel_looks_at_the_target_and_bad_cameras_are_refused() {
        let c = Camera::look_at(Vec3::new(0.0, 2.0, 10.0), Vec3::new(0.0, 2.0, 0.0), Vec3::Y, 40.0)
            .unwrap();
        let d = c.direction(50.0, 25.0, 100, 50);
        assert!((d - Vec3::NEG_Z).length() < 1e-6);
        // Top-left is up and to the left.
        let tl = c.direction(0.0, 0.0, 100, 50);
        assert!(tl.x < 0.0 && tl.y > 0.0);
        assert!(Camera::look_at(Vec3::ZERO, Vec3::ZERO, Vec3::Y, 40.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::Y, Vec3::Y, 40.0).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::X, Vec3::Y, f32::NAN).is_err());
    }
}
