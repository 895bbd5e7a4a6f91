//! The collision matrix Ω of the LB step, isotropic or with the normalized
//! Henyey–Greenstein phase function (forest paper eqs. 6–9).

use super::lattice::{self, Q};
use super::params::ChannelParams;

/// Ω as a row-major 19 × 19 matrix: `Ω[i][j]` moves density from direction
/// `j` into direction `i`. Computed in f64, stored in the f32 both solvers use.
#[derive(Clone, Debug, PartialEq)]
pub struct Omega(pub [[f32; Q]; Q]);

/// Normalized Henyey–Greenstein weights `pn[i][j]` for `i, j > 0` (row and
/// column 0 unused). At |g| = 1 the limit sends a column's whole weight to
/// the one direction with `n_i · n_j = g`.
pub fn hg_weights(g: f64) -> [[f64; Q]; Q] {
    let mut pn = [[0.0; Q]; Q];
    for j in 1..Q {
        let nj = lattice::unit(j);
        let mut p = [0.0f64; Q];
        for (i, pi) in p.iter_mut().enumerate().skip(1) {
            let ni = lattice::unit(i);
            let cos = ni[0] * nj[0] + ni[1] * nj[1] + ni[2] * nj[2];
            *pi = if g.abs() >= 1.0 {
                // Limit of (1 − g²)/(1 − 2g cos + g²)^{3/2}: a delta on cos = g.
                if (cos - g).abs() < 1e-9 { 1.0 } else { 0.0 }
            } else {
                (1.0 - g * g) / (1.0 - 2.0 * g * cos + g * g).powf(1.5)
            };
        }
        let norm: f64 = (1..Q).map(|i| p[i] * 24.0 / lattice::weight_denominator(i)).sum::<f64>() / 24.0;
        for i in 1..Q {
            pn[i][j] = p[i] / norm;
        }
    }
    pn
}

impl Omega {
    /// Ω for one channel's parameters (g = 0 gives the isotropic matrix).
    pub fn new(p: &ChannelParams) -> Self {
        Self::from_f64(&Self::matrix_f64(p))
    }

    /// Ω evaluated in f64, for checks of the model's identities.
    pub fn matrix_f64(p: &ChannelParams) -> [[f64; Q]; Q] {
        let (sa, ss) = (p.sigma_a as f64, p.sigma_s as f64);
        let st = sa + ss;
        let pn = hg_weights(p.g as f64);
        let mut w = [[0.0f64; Q]; Q];
        w[0][0] = -1.0;
        for j in 1..Q {
            w[0][j] = sa;
        }
        for i in 1..Q {
            let d = lattice::weight_denominator(i);
            w[i][0] = 1.0 / d;
            for j in 1..Q {
                w[i][j] = ss * pn[i][j] / d;
                if i == j {
                    w[i][j] -= st;
                }
            }
        }
        w
    }

    fn from_f64(w: &[[f64; Q]; Q]) -> Self {
        Self(w.map(|row| row.map(|v| v as f32)))
    }
}

/// What one channel's step needs: Ω for ordinary and green nodes, and Ω with
/// g = −1 (back-scatter only) for brown, wood-dominated nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct Collision {
    /// Ω of the channel's parameters.
    pub medium: Omega,
    /// Ω of the same σ_a, σ_s with g = −1.
    pub brown: Omega,
}

impl Collision {
    /// Both matrices for one channel.
    pub fn new(p: &ChannelParams) -> Self {
        Self { medium: Omega::new(p), brown: Omega::new(&ChannelParams { g: -1.0, ..*p }) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hg_with_g_one_is_a_pass_through() {
        let w = Omega::matrix_f64(&ChannelParams { sigma_a: 0.0, sigma_s: 0.9, g: 1.0 });
        for i in 1..Q {
            for j in 1..Q {
                assert!(w[i][j].abs() < 1e-12, "Ω[{i}][{j}] = {}", w[i][j]);
            }
        }
    }

    #[test]
    fn brown_scatters_only_backwards() {
        let w = Omega::matrix_f64(&ChannelParams { sigma_a: 0.1, sigma_s: 0.9, g: -1.0 });
        for j in 1..Q {
            let back = lattice::opposite(j);
            for i in 1..Q {
                if i != j && i != back {
                    assert_eq!(w[i][j], 0.0);
                }
            }
            assert!((w[back][j] - 0.9).abs() < 1e-6);
        }
    }
}
