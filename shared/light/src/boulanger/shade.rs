//! The per-sun constants (G1 in two factors, G2, G3) and the CPU
//! evaluation of the three lighting terms: sky, sun and one-bounce
//! indirect sun.

use super::{LeafEnvelope, N_DIR, directions, m};
use glam::Vec3;
use std::f32::consts::PI;

/// Average of M(N·a) M(N·b) over uniformly distributed unit normals N, for
/// unit vectors at angle γ (paper eq. 31; the Appendix's A_vt).
pub fn normal_average(gamma: f32) -> f32 {
    ((PI - gamma) * gamma.cos() + gamma.sin()) / (6.0 * PI)
}

/// Per-model, per-sun constants of the indirect and sun terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunTerms {
    /// ω_l, the unit direction towards the sun.
    pub sun: Vec3,
    /// M(ω_l·ω_j).
    pub m: [f32; N_DIR],
    /// M(ω_l·ω_j) / Σ_j' M(ω_l·ω_j'): the weights of eq. 7.
    pub weights: [f32; N_DIR],
    /// a_j = 2ρ(sin α_j − α_j cos α_j) / (3π N_dir): G1's factor of ρ̄.
    pub a: [f32; N_DIR],
    /// b_j = 2ρ π cos α_j / (3π N_dir): G1's factor of ρ_tf + ρ_tb.
    pub b: [f32; N_DIR],
    /// G2 = τ / Σ_j M(ω_l·ω_j) (eq. 24).
    pub g2: f32,
    /// G3_j = τ (1 − Σ_j' M(ω_l·ω_j')(ω_j·ω_j') / Σ_j' M(ω_l·ω_j')) (eq. 25).
    pub g3: [f32; N_DIR],
}

impl SunTerms {
    /// G1(j, ω_l) (eq. 18) for one channel's coefficients [ρ_rf, ρ_rb, ρ_tf, ρ_tb].
    pub fn g1(&self, j: usize, coeffs: [f32; 4]) -> f32 {
        let [rf, rb, tf, tb] = coeffs;
        (rf + rb + tf + tb) * self.a[j] + (tf + tb) * self.b[j]
    }
}

/// The per-sun constants for a model's envelope and the direction
/// `sun_towards` (from the leaves towards the sun; normalised here).
pub fn sun_terms(env: &LeafEnvelope, sun_towards: Vec3) -> SunTerms {
    let sun = sun_towards.normalize();
    let dirs = directions();
    let m = dirs.map(|w| m(sun.dot(w)));
    // Some diagonal is within 55° of any direction, so the sum is ≥ 1/√3.
    let sum: f32 = m.iter().sum();
    let weights = m.map(|x| x / sum);
    let scale = 2.0 * env.leaf_density / (3.0 * PI * N_DIR as f32);
    let alpha = dirs.map(|w| sun.dot(w).clamp(-1.0, 1.0).acos());
    let a = alpha.map(|al| scale * (al.sin() - al * al.cos()));
    let b = alpha.map(|al| scale * PI * al.cos());
    let g3 = dirs.map(|wj| {
        let c: f32 = (0..N_DIR).map(|k| weights[k] * wj.dot(dirs[k])).sum();
        // c ≤ 1 exactly; rounding may overshoot.
        (env.tau * (1.0 - c)).max(0.0)
    });
    SunTerms { sun, m, weights, a, b, g2: env.tau / sum, g3 }
}

/// The leaf's cosine-weighted BSDF F(P, ω_o, ω) (eq. 4) for a front normal,
/// the direction to the viewer and coefficients [ρ_rf, ρ_rb, ρ_tf, ρ_tb].
pub fn bsdf(normal: Vec3, to_eye: Vec3, coeffs: [f32; 4], w: Vec3) -> f32 {
    let [rf, rb, tf, tb] = coeffs;
    let c = normal.dot(w);
    if normal.dot(to_eye) >= 0.0 {
        (rf * m(c) + tb * m(-c)) / PI
    } else {
        (tf * m(c) + rb * m(-c)) / PI
    }
}

/// s_max(P, ω_l) for the terms' sun (eq. 7).
pub fn sun_distance(terms: &SunTerms, s: &[f32; N_DIR]) -> f32 {
    (0..N_DIR).map(|j| terms.weights[j] * s[j]).sum()
}

/// Lo_sample(P, j) (eq. 23): radiance scattered towards P by the leaves in
/// direction ω_j, before P's own BSDF and the leaf area A.
pub fn lo_sample(
    terms: &SunTerms,
    s: &[f32; N_DIR],
    j: usize,
    coeffs: [f32; 4],
    e_sun: f32,
) -> f32 {
    lo_sample_from(terms, s, j, coeffs, e_sun, 0.0)
}

/// Lo_sample with the slices starting at distance `s0` instead of 0 (the
/// tests leave out a small ball around P).
pub(super) fn lo_sample_from(
    terms: &SunTerms,
    s: &[f32; N_DIR],
    j: usize,
    coeffs: [f32; 4],
    e_sun: f32,
    s0: f32,
) -> f32 {
    let len = s[j] - s0;
    if len <= 0.0 {
        return 0.0;
    }
    // G2 Σ M s_max = τ s_max(P, ω_l).
    let sun_depth = terms.g2 * (0..N_DIR).map(|k| terms.m[k] * s[k]).sum::<f32>();
    let g3 = terms.g3[j];
    // ∫_{s0}^{s_max} e^{−G3 s} ds, with the G3 → 0 limit.
    let integral = if g3 > 0.0 { (-g3 * s0).exp() * -(-g3 * len).exp_m1() / g3 } else { len };
    terms.g1(j, coeffs) * e_sun * (-sun_depth).exp() * integral
}

/// The light on one model in one colour channel, as the shader receives
/// it: the model's envelope, the per-sun constants, the sun's irradiance
/// `e_sun` and the per-direction sky radiance `sky` (see
/// [`sky_radiance_per_direction`]).
#[derive(Clone, Copy, Debug)]
pub struct ChannelLight<'a> {
    /// The model's envelope.
    pub env: &'a LeafEnvelope,
    /// The per-sun constants for it.
    pub terms: &'a SunTerms,
    /// The sun's irradiance in this channel.
    pub e_sun: f32,
    /// Mean sky radiance per direction's octant, this channel.
    pub sky: &'a [f32; N_DIR],
}

/// The three terms (sky, sun, indirect sun) of outgoing radiance from leaf
/// triangle `tri` under `light` towards the viewer, for one colour
/// channel: `normal` is the leaf's front normal, `to_eye` the unit
/// direction to the viewer, `coeffs` [ρ_rf, ρ_rb, ρ_tf, ρ_tb].
pub fn shade(
    light: &ChannelLight,
    tri: usize,
    normal: Vec3,
    to_eye: Vec3,
    coeffs: [f32; 4],
) -> (f32, f32, f32) {
    let ChannelLight { env, terms, e_sun, .. } = *light;
    let f = |w: Vec3| bsdf(normal, to_eye, coeffs, w);
    let (lo_sky, lo_ind) = sky_and_bounce(light, tri, &f, coeffs);
    let lo_sun = f(terms.sun) * (-env.tau * sun_distance(terms, &env.s_max[tri])).exp() * e_sun; // eq. 8
    (lo_sky, lo_sun, lo_ind)
}

/// The sky and one-bounce terms on wood triangle `tri` under `light`
/// (Lambertian of `albedo`, its `normal` facing the viewer), lit by the
/// model's leaves, whose coefficients are `leaves` (of their mean albedo).
pub fn shade_wood(
    light: &ChannelLight,
    tri: usize,
    normal: Vec3,
    albedo: f32,
    leaves: [f32; 4],
) -> (f32, f32) {
    let f = |w: Vec3| albedo * normal.dot(w).max(0.0) / PI;
    sky_and_bounce(light, tri, &f, leaves)
}

/// Eq. 6 (sky) and eq. 11 (one bounce of sun light off neighbours of
/// coefficients `neighbours`) for a receiver whose cosine-weighted BSDF
/// towards the viewer is `f`.
fn sky_and_bounce(
    light: &ChannelLight,
    tri: usize,
    f: &dyn Fn(Vec3) -> f32,
    neighbours: [f32; 4],
) -> (f32, f32) {
    let ChannelLight { env, terms, e_sun, sky } = *light;
    let s = &env.s_max[tri];
    let dirs = directions();
    let (mut lo_sky, mut lo_ind) = (0.0, 0.0);
    for j in 0..N_DIR {
        let f = f(dirs[j]);
        lo_sky += f * (-env.tau * s[j]).exp() * sky[j]; // eq. 6
        lo_ind += f * lo_sample(terms, s, j, neighbours, e_sun); // eq. 11
    }
    (lo_sky * 4.0 * PI / N_DIR as f32, lo_ind * env.leaf_area)
}

/// Mean sky radiance over each direction's octant, for eq. 6. `sky` gives
/// the radiance arriving from a unit direction (y up). The four octants
/// below the horizon see the ground: a Lambertian ground of albedo
/// `ground_albedo` lit by the sky, i.e. albedo × the cosine-weighted mean
/// of the upper-hemisphere radiance (equal to its plain mean for a uniform
/// sky). Each octant is sampled on a 32 × 32 grid of equal solid angle.
pub fn sky_radiance_per_direction(
    sky: impl Fn(Vec3) -> [f32; 3],
    ground_albedo: [f32; 3],
) -> [[f32; 3]; N_DIR] {
    const K: usize = 32;
    let dirs = directions();
    let mut out = [[0.0f32; 3]; N_DIR];
    let mut cos_weighted = [0.0f64; 3];
    for (j, w) in dirs.iter().enumerate().filter(|(_, w)| w.y > 0.0) {
        let mut sum = [0.0f64; 3];
        for a in 0..K {
            // Uniform in y is uniform in solid angle (Archimedes).
            let y = (a as f32 + 0.5) / K as f32;
            let r = (1.0 - y * y).sqrt();
            for b in 0..K {
                let phi = (b as f32 + 0.5) / K as f32 * 0.5 * PI;
                let d = Vec3::new(w.x.signum() * r * phi.cos(), y, w.z.signum() * r * phi.sin());
                let l = sky(d);
                for c in 0..3 {
                    sum[c] += l[c] as f64;
                    cos_weighted[c] += (l[c] * y) as f64;
                }
            }
        }
        out[j] = sum.map(|x| (x / (K * K) as f64) as f32);
    }
    // (1/π)∫ L cos dω over the hemisphere = 2 × mean of L·cos over uniform samples.
    let ground =
        [0, 1, 2].map(|c| ground_albedo[c] * (2.0 * cos_weighted[c] / (4 * K * K) as f64) as f32);
    for (j, w) in dirs.iter().enumerate() {
        if w.y < 0.0 {
            out[j] = ground;
        }
    }
    out
}
