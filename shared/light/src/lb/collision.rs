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
        let norm: f64 =
            (1..Q).map(|i| p[i] * 24.0 / lattice::weight_denominator(i)).sum::<f64>() / 24.0;
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

/// Opposite-direction pairs of the moving directions: pair `b` is
/// directions `2b + 1` and `2b + 2`.
pub const PAIRS: usize = (Q - 1) / 2;

/// Ω rewritten on opposite pairs, the form both solvers step with.
///
/// Ω's moving block depends only on the angle between two directions (and
/// on each direction's class), so it is unchanged when both directions are
/// reversed: `Ω[ī][j] = Ω[i][j̄]`. With `S_b = f_j + f_j̄` and
/// `D_b = f_j − f_j̄` for pair `b = (j, j̄)`, the rows of a pair `a = (i, ī)` are
/// `Σ_j Ω[i][j] f_j = A_a + B_a` and `Σ_j Ω[ī][j] f_j = A_a − B_a`, with
/// `A_a = Σ_b even[a][b] S_b` and `B_a = Σ_b odd[a][b] D_b`: 162
/// multiply-adds for the 18 moving rows instead of 324.
#[derive(Clone, Debug, PartialEq)]
pub struct PairedOmega {
    /// `(Ω[i][j] + Ω[i][j̄]) / 2` for pair rows `a`, pair columns `b`.
    pub even: [[f32; PAIRS]; PAIRS],
    /// `(Ω[i][j] − Ω[i][j̄]) / 2`.
    pub odd: [[f32; PAIRS]; PAIRS],
    /// Column 0: `Ω[m][0]`, the rest direction into `m`.
    pub from_rest: [f32; Q],
    /// Row 0 on pairs: `(Ω[0][j] + Ω[0][j̄]) / 2`.
    pub rest_even: [f32; PAIRS],
    /// `(Ω[0][j] − Ω[0][j̄]) / 2`.
    pub rest_odd: [f32; PAIRS],
}

impl PairedOmega {
    /// The pair form of Ω evaluated in f64 (`Omega::matrix_f64`).
    pub fn new(w: &[[f64; Q]; Q]) -> Self {
        let (j, jb) = (|b: usize| 2 * b + 1, |b: usize| 2 * b + 2);
        Self {
            even: std::array::from_fn(|a| {
                std::array::from_fn(|b| ((w[j(a)][j(b)] + w[j(a)][jb(b)]) / 2.0) as f32)
            }),
            odd: std::array::from_fn(|a| {
                std::array::from_fn(|b| ((w[j(a)][j(b)] - w[j(a)][jb(b)]) / 2.0) as f32)
            }),
            from_rest: std::array::from_fn(|m| w[m][0] as f32),
            rest_even: std::array::from_fn(|b| ((w[0][j(b)] + w[0][jb(b)]) / 2.0) as f32),
            rest_odd: std::array::from_fn(|b| ((w[0][j(b)] - w[0][jb(b)]) / 2.0) as f32),
        }
    }

    /// `Σ_n Ω[m][n] f_n` for every `m`, as the solvers compute it: pair
    /// sums and differences, then each pair row's even and odd sums as
    /// chains of fused multiply-adds in column order, starting from the
    /// rest direction's term. The CPU solver runs the same on lanes.
    pub fn apply(&self, f: &[f32; Q]) -> [f32; Q] {
        let s: [f32; PAIRS] = std::array::from_fn(|b| f[2 * b + 1] + f[2 * b + 2]);
        let d: [f32; PAIRS] = std::array::from_fn(|b| f[2 * b + 1] - f[2 * b + 2]);
        let mut out = [0.0f32; Q];
        let mut rest = self.from_rest[0] * f[0];
        for b in 0..PAIRS {
            rest = self.rest_even[b].mul_add(s[b], rest);
            rest = self.rest_odd[b].mul_add(d[b], rest);
        }
        out[0] = rest;
        for a in 0..PAIRS {
            let (mut even, mut odd) = (0.0f32, 0.0f32);
            for b in 0..PAIRS {
                even = self.even[a][b].mul_add(s[b], even);
                odd = self.odd[a][b].mul_add(d[b], odd);
            }
            out[2 * a + 1] = self.from_rest[2 * a + 1].mul_add(f[0], even + odd);
            out[2 * a + 2] = self.from_rest[2 * a + 2].mul_add(f[0], even - odd);
        }
        out
    }
}

/// What one channel's step needs: Ω for ordinary and green nodes, and Ω with
/// g = −1 (back-scatter only) for brown, wood-dominated nodes, each in its
/// pair form.
#[derive(Clone, Debug, PartialEq)]
pub struct Collision {
    /// Ω of the channel's parameters.
    pub medium: PairedOmega,
    /// Ω of the same σ_a, σ_s with g = −1.
    pub brown: PairedOmega,
}

impl Collision {
    /// Both matrices for one channel.
    pub fn new(p: &ChannelParams) -> Self {
        Self {
            medium: PairedOmega::new(&Omega::matrix_f64(p)),
            brown: PairedOmega::new(&Omega::matrix_f64(&ChannelParams { g: -1.0, ..*p })),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pair form is Ω: the lattice's pairs are opposites, Ω is
    /// unchanged under reversing both directions, and applying the pair
    /// form equals the plain product.
    #[test]
    fn the_pair_form_applies_omega() {
        for b in 0..PAIRS {
            assert_eq!(lattice::opposite(2 * b + 1), 2 * b + 2);
        }
        let mut rng = sylva_scene::rng::SplitMix64::new(3);
        for g in [0.0, 0.4, -0.7, 0.95, -1.0] {
            let p = ChannelParams { sigma_a: 0.13, sigma_s: 0.81, g };
            let w = Omega::matrix_f64(&p);
            for i in 1..Q {
                for j in 1..Q {
                    let (ib, jb) = (lattice::opposite(i), lattice::opposite(j));
                    assert!(
                        (w[ib][j] - w[i][jb]).abs() < 1e-12,
                        "g {g}: Ω[{ib}][{j}] ≠ Ω[{i}][{jb}]"
                    );
                }
            }
            let paired = PairedOmega::new(&w);
            for _ in 0..50 {
                let f: [f32; Q] = std::array::from_fn(|_| rng.next_f32());
                let got = paired.apply(&f);
                for m in 0..Q {
                    let want: f64 = (0..Q).map(|n| w[m][n] * f[n] as f64).sum();
                    assert!(
                        (got[m] as f64 - want).abs() < 2e-6 * (1.0 + want.abs()),
                        "g {g}, m {m}: {} vs {want}",
                        got[m]
                    );
                }
            }
        }
    }

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
