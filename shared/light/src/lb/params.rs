//! Optical parameters of the LB medium, per colour channel, with the presets
//! of the papers and validation that names the parameter and its valid range.

use serde::{Deserialize, Serialize};
use sylva_scene::format::Preset;

/// The three colour channels the model solves, in order.
pub const CHANNELS: [&str; 3] = ["red", "green", "blue"];

/// σ_a, σ_s and g for one colour channel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelParams {
    /// Absorption coefficient σ_a ≥ 0.
    pub sigma_a: f32,
    /// Scattering coefficient σ_s ≥ 0.
    pub sigma_s: f32,
    /// Henyey–Greenstein asymmetry g ∈ [−1, 1]; 0 is isotropic.
    pub g: f32,
}

/// A parameter outside its valid range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ParamError {
    /// A value that is NaN or infinite.
    #[error("{name} = {value} is not a finite number; valid range: {range}")]
    NotFinite { name: String, value: f64, range: &'static str },
    /// A finite value outside its range.
    #[error("{name} = {value} is out of range; valid range: {range}{why}")]
    OutOfRange { name: String, value: f64, range: &'static str, why: &'static str },
}

/// The valid range of σ_a and σ_s.
pub const SIGMA_RANGE: &str = "[0, 2] with sigma_t = sigma_a + sigma_s in (0, 2]";
/// The valid range of g.
pub const G_RANGE: &str = "[-1, 1]";

fn check(
    name: &str,
    value: f32,
    range: &'static str,
    ok: bool,
    why: &'static str,
) -> Result<(), ParamError> {
    if !value.is_finite() {
        return Err(ParamError::NotFinite { name: name.to_string(), value: value as f64, range });
    }
    if !ok {
        return Err(ParamError::OutOfRange {
            name: name.to_string(),
            value: value as f64,
            range,
            why,
        });
    }
    Ok(())
}

impl ChannelParams {
    /// Isotropic parameters.
    pub const fn isotropic(sigma_a: f32, sigma_s: f32) -> Self {
        Self { sigma_a, sigma_s, g: 0.0 }
    }

    /// σ_t = σ_a + σ_s.
    pub fn sigma_t(&self) -> f32 {
        self.sigma_a + self.sigma_s
    }

    /// Refuses parameters the lattice cannot run: non-finite or negative
    /// coefficients, |g| > 1, and σ_t outside (0, 2] (the momentum modes of
    /// `I + ρΩ` have eigenvalue 1 − ρσ_t, unstable past 2 for ρ = 1).
    /// `channel` names the channel in the message ("red", ...).
    pub fn validate(&self, channel: &str) -> Result<(), ParamError> {
        let name =
            |p: &str| if channel.is_empty() { p.to_string() } else { format!("{p} ({channel})") };
        check(&name("sigma_a"), self.sigma_a, SIGMA_RANGE, self.sigma_a >= 0.0, "")?;
        check(&name("sigma_s"), self.sigma_s, SIGMA_RANGE, self.sigma_s >= 0.0, "")?;
        check(&name("g"), self.g, G_RANGE, self.g.abs() <= 1.0, "")?;
        let t = self.sigma_t();
        check(
            &name("sigma_t"),
            t,
            "(0, 2]",
            t > 0.0 && t <= 2.0,
            " (rho * sigma_t above 2 makes the LB step unstable; 0 scatters nothing)",
        )
    }
}

/// Parameters of all three colour channels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LbParams {
    /// Red, green and blue, in that order.
    pub channels: [ChannelParams; 3],
}

impl LbParams {
    /// The same parameters for every channel.
    pub const fn grey(p: ChannelParams) -> Self {
        Self { channels: [p, p, p] }
    }

    /// Validates every channel; the error names the channel.
    pub fn validate(&self) -> Result<(), ParamError> {
        for (p, name) in self.channels.iter().zip(CHANNELS) {
            p.validate(name)?;
        }
        Ok(())
    }

    /// A named preset's parameters.
    pub fn from_preset(preset: Preset) -> LbParams {
        let rgb = |a: [f32; 3], s: [f32; 3], g: [f32; 3]| LbParams {
            channels: [0, 1, 2].map(|i| ChannelParams { sigma_a: a[i], sigma_s: s[i], g: g[i] }),
        };
        match preset {
            Preset::Leaf => {
                rgb([0.109, 0.091, 0.118], [0.891, 0.909, 0.882], [-0.120, 0.091, -0.333])
            }
            Preset::Dogrose => {
                rgb([0.109, 0.091, 0.118], [0.891, 0.909, 0.882], [-0.231, 0.103, -0.750])
            }
            Preset::Cloud => {
                LbParams::grey(ChannelParams { sigma_a: 0.008, sigma_s: 0.792, g: 0.9 })
            }
            Preset::Pmma => rgb([0.01; 3], [0.99; 3], [0.80, -0.88, -0.88]),
        }
    }
}

/// g from forward and backward scattering fractions, forest paper eq. (10).
pub fn g_from_scattering_fractions(forward: f32, backward: f32) -> f32 {
    (forward - backward) / (forward + backward)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_is_valid() {
        for p in Preset::ALL {
            LbParams::from_preset(p).validate().unwrap();
            assert_eq!(Preset::from_name(p.name()), Some(p));
        }
    }

    #[test]
    fn leaf_g_follows_from_measured_scattering_fractions() {
        let fs = [0.055, 0.150, 0.020];
        let bs = [0.070, 0.125, 0.040];
        let leaf = LbParams::from_preset(Preset::Leaf);
        for i in 0..3 {
            let g = g_from_scattering_fractions(fs[i], bs[i]);
            assert!(
                (g - leaf.channels[i].g).abs() < 5e-4,
                "channel {i}: {g} vs {}",
                leaf.channels[i].g
            );
        }
    }

    #[test]
    fn errors_name_the_parameter_and_the_range() {
        let cases = [
            (
                ChannelParams { sigma_a: f32::NAN, sigma_s: 0.5, g: 0.0 },
                "sigma_a (red)",
                "not a finite",
            ),
            (ChannelParams { sigma_a: -0.1, sigma_s: 0.5, g: 0.0 }, "sigma_a (red)", "[0, 2]"),
            (
                ChannelParams { sigma_a: 0.1, sigma_s: f32::INFINITY, g: 0.0 },
                "sigma_s (red)",
                "not a finite",
            ),
            (ChannelParams { sigma_a: 0.1, sigma_s: 0.5, g: 1.5 }, "g (red)", "[-1, 1]"),
            (ChannelParams { sigma_a: 0.1, sigma_s: 0.5, g: f32::NAN }, "g (red)", "not a finite"),
            (ChannelParams { sigma_a: 0.5, sigma_s: 1.6, g: 0.0 }, "sigma_t (red)", "unstable"),
            (ChannelParams { sigma_a: 0.0, sigma_s: 0.0, g: 0.0 }, "sigma_t (red)", "(0, 2]"),
        ];
        for (p, name, part) in cases {
            let msg = p.validate("red").unwrap_err().to_string();
            assert!(msg.contains(name) && msg.contains(part), "{msg}");
        }
    }
}
