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
    pub fn from_elevation_azimuth(
        elevation: f64,
        azimuth: f64,
        intensity: f64,
    ) -> Result<Self, SunError> {
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
        let len =
            (towards[0] * towards[0] + towards[1] * towards[1] + towards[2] * towards[2]).sqrt();
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
            let dot = n[0] * self.propagation[0]
                + n[1] * self.propagation[1]
                + n[2] * self.propagation[2];
            if dot > 0.0 {
                *v = (self.intensity * dot) as f32;
            }
        }
        Boundary::fixed(values)
    }
}

impl Default for Sun {
    /// High afternoon sun: 60° up, from +x +z.
    fn default() -> Self {
        Self::from_elevation_azimuth(60.0, 30.0, 1.0).expect("valid default")
    }
}

/// The densities every boundary node holds, per direction, for the whole
/// solve, and whether the bottom face is a reflecting ground.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Boundary {
    /// `values[m]`: density in direction `m` at every boundary node (the
    /// bottom face's upward directions start from these when it reflects).
    pub values: [f32; Q],
    /// A Lambertian ground as the lattice's lower face, or none (black).
    pub ground: Option<GroundReflection>,
}

impl Boundary {
    /// No light enters (for pulse experiments).
    pub const DARK: Boundary = Boundary { values: [0.0; Q], ground: None };

    /// Fixed values, no reflecting ground.
    pub fn fixed(values: [f32; Q]) -> Self {
        Self { values, ground: None }
    }
}

/// A Lambertian ground under the lattice. Each step, every node of the
/// bottom face that is not on another face collects the irradiance its
/// downward directions bring, `E = Σ_{c_m·y<0} |ĉ_m·y| f_m(r − c_m)`,
/// and sends `f_m = k_m E` up, where `k_m = gain · albedo · Ω_m / Σ_{up} Ω_n ĉ_n·y`:
/// a Lambertian lobe (radiance ∝ 1, so fluence ∝ the bin's solid angle Ω_m)
/// whose discrete upward irradiance `Σ_{up} ĉ_m·y f_m` is exactly
/// `gain × albedo × E`. The gain makes the open ground's reflection exact:
/// D3Q19 carries part of the sun's and sky's light along its horizontal
/// directions, which never reach a floor (docs/lighting.md, "The ground").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundReflection {
    /// The ground's albedo in this channel, in [0, 1].
    pub albedo: f32,
    /// The open ground's true irradiance over the lattice's collected one
    /// (see [`Illumination::boundaries`](super::radiometry::Illumination::boundaries)).
    pub gain: f32,
}

impl GroundReflection {
    /// Per direction, the weight of its density in the ground's
    /// irradiance: `|ĉ_m·y|` for downward directions, else 0.
    pub fn collect() -> [f32; Q] {
        std::array::from_fn(|m| {
            if lattice::DIRECTIONS[m][1] < 0 { (-lattice::unit(m)[1]) as f32 } else { 0.0 }
        })
    }

    /// Per direction, the density sent up per unit irradiance: `k_m` for
    /// upward directions, else 0.
    pub fn emit(&self) -> [f32; Q] {
        let omega = super::radiometry::bin_solid_angles();
        let up: f64 = (1..Q)
            .filter(|&m| lattice::DIRECTIONS[m][1] > 0)
            .map(|m| omega[m] * lattice::unit(m)[1])
            .sum();
        let k = self.gain as f64 * self.albedo as f64;
        std::array::from_fn(|m| {
            if lattice::DIRECTIONS[m][1] > 0 { (k * omega[m] / up) as f32 } else { 0.0 }
        })
    }

    /// The irradiance the lattice collects from densities `values`, in the
    /// order and precision the solvers sum it.
    pub fn collected(values: &[f32; Q]) -> f32 {
        let collect = Self::collect();
        let mut e = 0.0f32;
        for m in 0..Q {
            if collect[m] != 0.0 {
                e += collect[m] * values[m];
            }
        }
        e
    }

    /// `values` with the upward directions replaced by the ground's
    /// reflection of `values`' downward ones (the open ground outside the lattice).
    pub fn reflect(&self, values: &[f32; Q]) -> [f32; Q] {
        let (e, emit) = (Self::collected(values), self.emit());
        std::array::from_fn(|m| if emit[m] > 0.0 { emit[m] * e } else { values[m] })
    }
}
