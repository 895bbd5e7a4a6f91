//! The leaf: its generated texture ([`texture`]) and its optics, shared by
//! the reference path tracer and the Boulanger et al. model: Lambertian reflection and transmission per side (ρ_rf, ρ_rb,
//! ρ_tf, ρ_tb), as multipliers of the leaf's texture colour.
//!
//! Defaults come from the measured leaf scattering behind the `leaf` LB
//! preset (forest paper, Table 1): per colour, a leaf sends back (reflects)
//! a fraction b = (0.070, 0.125, 0.040) and forward (transmits) a fraction
//! f = (0.055, 0.150, 0.020) of the light it scatters. The renderer's
//! direct light already reflects the texture colour, so reflection keeps
//! the texture colour (×1) and transmission is the texture colour × f/b.
//! The measurement does not tell the two sides apart, so front and back
//! get the same values.

pub mod texture;

pub use texture::{LeafShape, leaf_texture};

use serde::{Deserialize, Serialize};

/// Measured backward-scattered (reflected) fractions, red, green, blue.
pub const MEASURED_REFLECTED: [f32; 3] = [0.070, 0.125, 0.040];
/// Measured forward-scattered (transmitted) fractions, red, green, blue.
pub const MEASURED_TRANSMITTED: [f32; 3] = [0.055, 0.150, 0.020];

/// Lambertian reflection and transmission per side, per colour, each a
/// multiplier of the texture colour.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LeafOptics {
    /// ρ_rf: reflectance of the front face (the side the normal points to).
    pub reflect_front: [f32; 3],
    /// ρ_rb: reflectance of the back face.
    pub reflect_back: [f32; 3],
    /// ρ_tf: transmittance for light entering the front face.
    pub transmit_front: [f32; 3],
    /// ρ_tb: transmittance for light entering the back face.
    pub transmit_back: [f32; 3],
}

impl Default for LeafOptics {
    fn default() -> Self {
        let t = [0, 1, 2].map(|i| MEASURED_TRANSMITTED[i] / MEASURED_REFLECTED[i]);
        Self {
            reflect_front: [1.0; 3],
            reflect_back: [1.0; 3],
            transmit_front: t,
            transmit_back: t,
        }
    }
}

impl LeafOptics {
    /// The four coefficients for a leaf of texture colour `albedo`, one
    /// colour channel `c`: (ρ_rf, ρ_rb, ρ_tf, ρ_tb), each clamped so a leaf
    /// never scatters more than it receives (ρ_r + ρ_t ≤ 1 per side).
    pub fn coefficients(&self, albedo: [f32; 3], c: usize) -> [f32; 4] {
        let a = albedo[c];
        let (mut rf, mut rb, mut tf, mut tb) = (
            a * self.reflect_front[c],
            a * self.reflect_back[c],
            a * self.transmit_front[c],
            a * self.transmit_back[c],
        );
        // Front face: light arriving on the front is reflected (ρ_rf) or transmitted (ρ_tf).
        let front = rf + tf;
        if front > 1.0 {
            rf /= front;
            tf /= front;
        }
        let back = rb + tb;
        if back > 1.0 {
            rb /= back;
            tb /= back;
        }
        [rf, rb, tf, tb]
    }

    /// Refuses negative or non-finite coefficients.
    pub fn validate(&self) -> crate::Result<()> {
        for (name, v) in [
            ("reflect_front", self.reflect_front),
            ("reflect_back", self.reflect_back),
            ("transmit_front", self.transmit_front),
            ("transmit_back", self.transmit_back),
        ] {
            if v.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(crate::Error::Invalid(format!(
                    "leaf optics {name} = {v:?}: each must be a finite number ≥ 0"
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_follow_the_measured_fractions_and_conserve_energy() {
        let o = LeafOptics::default();
        assert!((o.transmit_front[1] - 1.2).abs() < 1e-6);
        let c = o.coefficients([0.9, 0.9, 0.9], 1);
        assert!(c[0] + c[2] <= 1.0 + 1e-6 && c[1] + c[3] <= 1.0 + 1e-6, "{c:?}");
        let dark = o.coefficients([0.1, 0.3, 0.05], 0);
        assert!((dark[0] - 0.1).abs() < 1e-6 && (dark[2] - 0.1 * 0.055 / 0.070).abs() < 1e-6);
    }
}
