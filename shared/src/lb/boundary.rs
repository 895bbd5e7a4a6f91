//! The sun's boundary condition: every node of the lattice's outer shell
//! holds, in each direction that points along the light, a density
//! proportional to the cosine between that direction and the light.

use super::lattice::{self, Q};
use serde::{Deserialize, Serialize};

/// The sun as the LB solve sees it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sun {
    /// Unit vector along which sunlight travels (from the sun into the scene).
    pub propagation: [f64; 3],
    /// Density held in a direction exactly aligned with the light.
    pub intensity: f64,
}

/// A sun that cannot light anything.
#[derive(Debug, thiserror::Error)]
pub enum SunError {
    /// A zero, NaN or infinite direction.
    #[error("sun direction {0:?} must be a finite, non-zero vector")]
    BadDirection([f64; 3]),
    /// A negative, NaN or infinite intensity.
    #[error("sun intensity {0} must be finite and ≥ 0")]
    BadIntensity(f64),
    /// Elevation outside [−90°, 90°] or a non-finite angle.
    #[error("sun elevation {0}° must be a finite angle in [-90, 90]")]
    BadElevation(f64),
}

impl Sun {
    /// A sun at `elevation` degrees above the horizon (y is up) and
    /// `azimuth` degrees from +x towards +z.
    pub fn from_elevation_azimuth(elevation: f64, azimuth: f64, intensity: f64) -> Result<Self, SunError> {
        if !elevation.is_finite() || elevation.abs() > 90.0 {
            return Err(SunError::BadElevation(elevation));
        }
        if !azimuth.is_finite() {
            return Err(SunError::BadDirection([f64::NAN; 3]));
        }
        let (e, a) = (elevation.to_radians(), azimuth.to_radians());
        let towards = [e.cos() * a.cos(), e.sin(), e.cos() * a.sin()];
        Self::towards(towards, intensity)
    }

    /// A sun that lies along `towards` (a vector from the scene to the sun).
    pub fn towards(towards: [f64; 3], intensity: f64) -> Result<Self, SunError> {
        let len = (towards[0] * towards[0] + towards[1] * towards[1] + towards[2] * towards[2]).sqrt();
        if !len.is_finite() || len == 0.0 {
            return Err(SunError::BadDirection(towards));
        }
        if !intensity.is_finite() || intensity < 0.0 {
            return Err(SunError::BadIntensity(intensity));
        }
        Ok(Self { propagation: towards.map(|v| -v / len), intensity })
    }

    /// The fixed boundary densities per direction.
    pub fn boundary(&self) -> Boundary {
        let mut values = [0.0f32; Q];
        for (m, v) in values.iter_mut().enumerate().skip(1) {
            let n = lattice::unit(m);
            let dot = n[0] * self.propagation[0] + n[1] * self.propagation[1] + n[2] * self.propagation[2];
            if dot > 0.0 {
                *v = (self.intensity * dot) as f32;
            }
        }
        Boundary { values }
    }
}

impl Default for Sun {
    /// High afternoon sun: 60° up, from +x +z.
    fn default() -> Self {
        Self::from_elevation_azimuth(60.0, 30.0, 1.0).expect("valid default")
    }
}

/// The densities every boundary node holds, per direction, for the whole solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Boundary {
    /// `values[m]`: density in direction `m` at every boundary node.
    pub values: [f32; Q],
}

impl Boundary {
    /// No light enters (for pulse experiments).
    pub const DARK: Boundary = Boundary { values: [0.0; Q] };
}
