//! An analog Monte Carlo reference for what the LB model approximates:
//! photon transport through the same [`MediumGrid`], with the same
//! [`ChannelParams`], lit by the same [`Sun`].
//!
//! # Geometry
//!
//! Node `i` along an axis owns the unit cell `[i − ½, i + ½)`. The LB solver
//! never updates the outer shell (it holds the sun's densities there), so the
//! transported region is the box of the interior nodes' cells,
//! `[½, n − 3/2)` along each axis, with vacuum outside it. The extinction
//! coefficient in a cell is `ρ · σ_t` per unit length (one node spacing is
//! one unit of length), as the brief of the LB model reads it.
//!
//! # Source
//!
//! The LB boundary holds, on every shell node, `I · max(0, n_m · ω)` in each
//! direction `m`: an infinitely wide collimated beam along ω, which in vacuum
//! fills the whole lattice with the same densities. The Monte Carlo source is
//! the same plane wave: photons enter through every face of the box that ω
//! points into, a face chosen with probability proportional to its area
//! times `|ω · n_face|` (its area seen from the sun), uniformly over the face.
//! With `N` photons and `P = Σ_faces A_f |ω · n_f|` (the box's projected area
//! perpendicular to ω), the photons carry a beam irradiance `E⊥ = N / P`
//! photons per unit area normal to the beam.
//!
//! # Normalisation
//!
//! Photons are tracked with delta (Woodcock) tracking against the majorant
//! `max ρσ_t`, and every flight segment is scored into the cells it crosses
//! (track-length estimator): `Σ track length / cell volume` is `N/P` times
//! the scalar fluence `φ` per unit beam irradiance. In vacuum `φ/E⊥ = 1`
//! everywhere. The LB free-stream density per node is
//! `S₀ = Σ_m I · max(0, n_m · ω)` (the sum of the boundary densities), so the
//! reported value is
//!
//! ```text
//! value(node) = S₀ · (φ(node) / E⊥) = S₀ · P · (Σ track length in the cell) / N
//! ```
//!
//! which equals the LB's `Σ_m f_m` on an empty grid exactly in expectation
//! (tested in `tests/lb_limits.rs`). In a medium this treats the LB total
//! density as a fluence whose vacuum value matches. For a sun along a lattice
//! axis this also matches the energy flux into the box (every lit lattice
//! direction then moves one unit along ω per step); for an oblique sun the
//! LB's free-stream flux `Σ f_m c_m · ω` differs from `S₀` (the diagonal
//! directions travel √2 per step), by −13 % for a sun along a face diagonal,
//! see [`lb_flux_ratio`]: part of what the elevation sweep measures.
//!
//! # Node classes, mirrored from the LB step
//!
//! - `Medium`: the LB moves the absorbed fraction σ_a into the rest
//!   direction f₀ and re-emits it isotropically (density is conserved). Here
//!   an absorption event re-emits the photon in a uniformly random direction,
//!   and, since the LB counts the resting density in `Σ_m f_m` (in steady
//!   state `f₀ = σ_a · Σ_{m>0} f_m` at any node with ρ > 0), the node's value
//!   is multiplied by `1 + σ_a`.
//! - `Green`: the LB zeroes f₀ every step, so absorption is real: the photon
//!   ends. No rest density is added.
//! - `Brown`: the LB uses Ω with g = −1, which sends the scattered fraction
//!   straight back along the opposite lattice direction. Here a scattering
//!   reverses the photon's direction exactly; absorption is as for `Medium`
//!   (brown nodes keep f₀).
//!
//! What is not mirrored: the LB collides once per step, so a diagonal
//! direction (length √2) sees the same collision probability `ρσ_t` per step
//! as an axial one (length 1), and the per-step survival `1 − ρσ_t` is the
//! first-order form of `exp(−ρσ_t)` (negative past ρσ_t = 1). The Monte Carlo
//! uses the continuous `exp(−ρσ_t s)`; those differences are the LB's error.
//! Shell nodes report the LB's fixed boundary value `S₀` with zero error.
//!
//! # Determinism
//!
//! The photons are split into at most [`BATCHES`] equal batches; batch `b`
//! draws from a `SplitMix64` seeded with the `b`-th output of a
//! `SplitMix64(seed)`, the batches run on rayon, and their tallies are added
//! in batch order, so a seed gives the same result on any number of threads.
//! The standard error per node is the spread of the per-batch estimates.

use crate::lb::boundary::Sun;
use crate::lb::lattice::{DIRECTIONS, Q};
use crate::lb::medium::{MediumGrid, NodeClass};
use crate::lb::params::ChannelParams;
use rayon::prelude::*;
use std::time::Instant;
use sylva_scene::rng::SplitMix64;

/// Number of independent batches the photons are split into (the standard
/// error comes from their spread).
pub const BATCHES: u64 = 64;

/// Batches traced at once; bounds the memory of the per-batch tallies.
const BATCHES_IN_FLIGHT: usize = 16;

/// The Monte Carlo estimate of the LB total density `Σ_m f_m` per node.
#[derive(Clone, Debug)]
pub struct McFluence {
    /// Per node in grid order, in the LB's units (see the module docs).
    pub values: Vec<f32>,
    /// Standard error of each value (0 on the shell).
    pub std_error: Vec<f32>,
    /// Photons traced (the request rounded down to a multiple of the batch count).
    pub photons: u64,
    /// Wall time in milliseconds.
    pub ms: f64,
}

/// The LB's free-stream total density `S₀ = Σ_m` boundary density, summed in
/// f32 in direction order as the solvers sum node totals.
pub fn free_stream_density(sun: &Sun) -> f32 {
    sun.boundary().values.iter().fold(0.0f32, |a, &b| a + b)
}

/// The LB's free-stream energy flux along the sun, `Σ_m f_m (c_m · ω)`,
/// over its free-stream density `S₀`. 1 for a sun along a lattice axis; the
/// Monte Carlo's collimated beam has flux equal to its fluence (ratio 1).
pub fn lb_flux_ratio(sun: &Sun) -> f64 {
    let b = sun.boundary();
    let w = sun.propagation;
    let flux: f64 = (1..Q)
        .map(|m| {
            let c = DIRECTIONS[m];
            b.values[m] as f64 * (c[0] as f64 * w[0] + c[1] as f64 * w[1] + c[2] as f64 * w[2])
        })
        .sum();
    flux / free_stream_density(sun) as f64
}

/// Fluence of `photons` analog photons, tallied per node, in the LB's units.
///
/// Panics if `photons` is 0 or the medium's arrays disagree with its dimensions.
pub fn fluence(
    medium: &MediumGrid,
    params: &ChannelParams,
    sun: &Sun,
    photons: u64,
    seed: u64,
) -> McFluence {
    fluence_of(medium, params, sun, photons, seed, false)
}

/// The part of [`fluence`] carried by photons that have scattered at least
/// once: what the LB's indirect term ([`solve_indirect`](crate::lb::indirect))
/// must equal. Shell nodes report 0 (the sun alone lights the boundary).
pub fn scattered_fluence(
    medium: &MediumGrid,
    params: &ChannelParams,
    sun: &Sun,
    photons: u64,
    seed: u64,
) -> McFluence {
    fluence_of(medium, params, sun, photons, seed, true)
}

fn fluence_of(
    medium: &MediumGrid,
    params: &ChannelParams,
    sun: &Sun,
    photons: u64,
    seed: u64,
    scattered_only: bool,
) -> McFluence {
    assert!(photons > 0, "at least one photon");
    let start = Instant::now();
    let dims = medium.dims;
    let n = dims.len();
    assert_eq!(medium.density.len(), n);
    assert_eq!(medium.class.len(), n);
    let scene = Scene { scattered_only, ..Scene::new(medium, params, sun) };
    let batches = BATCHES.min(photons);
    let per_batch = photons / batches;
    let mut master = SplitMix64::new(seed);
    let seeds: Vec<u64> = (0..batches).map(|_| master.next_u64()).collect();

    let mut sum = vec![0.0f64; n];
    let mut sum_sq = vec![0.0f64; n];
    for chunk in seeds.chunks(BATCHES_IN_FLIGHT) {
        let tallies: Vec<Vec<f64>> =
            chunk.par_iter().map(|&s| scene.trace_batch(per_batch, s)).collect();
        for t in &tallies {
            for i in 0..n {
                sum[i] += t[i];
                sum_sq[i] += t[i] * t[i];
            }
        }
    }

    // A batch's estimate of node i is k_i · t_i with k_i = S₀ · P · factor_i / per_batch.
    let s0 = free_stream_density(sun) as f64;
    let b = batches as f64;
    let mut values = vec![0.0f32; n];
    let mut std_error = vec![0.0f32; n];
    for z in 0..dims.nz {
        for y in 0..dims.ny {
            for x in 0..dims.nx {
                let i = dims.index(x, y, z);
                if dims.is_boundary(x, y, z) {
                    values[i] = if scattered_only { 0.0 } else { s0 as f32 };
                    continue;
                }
                let k = s0 * scene.projected_area * scene.rest_factor(i) / per_batch as f64;
                let mean = sum[i] / b;
                let var = if batches > 1 {
                    ((sum_sq[i] / b - mean * mean) * b / (b - 1.0)).max(0.0)
                } else {
                    0.0
                };
                values[i] = (k * mean) as f32;
                std_error[i] = (k * (var / b).sqrt()) as f32;
            }
        }
    }
    McFluence {
        values,
        std_error,
        photons: per_batch * batches,
        ms: start.elapsed().as_secs_f64() * 1e3,
    }
}

/// One lit face of the box: its axis, the coordinate of the plane, and its
/// cumulative share of the projected area.
#[derive(Clone, Copy, Debug)]
struct Face {
    axis: usize,
    plane: f64,
    cell: i64,
    cumulative: f64,
}

/// Everything a photon needs, in "shifted" coordinates where node `i`'s cell
/// is `[i, i + 1)` and the box is `[1, n − 1)` along each axis.
struct Scene<'m> {
    medium: &'m MediumGrid,
    params: ChannelParams,
    dir: [f64; 3],
    lo: [i64; 3],
    hi: [i64; 3],
    majorant: f64,
    faces: Vec<Face>,
    projected_area: f64,
    /// Score only photons that have scattered at least once.
    scattered_only: bool,
}

impl<'m> Scene<'m> {
    fn new(medium: &'m MediumGrid, params: &ChannelParams, sun: &Sun) -> Self {
        let d = medium.dims;
        let size = [d.nx as i64, d.ny as i64, d.nz as i64];
        let lo = [1i64; 3];
        let hi = size.map(|s| s - 1);
        let sigma_t = params.sigma_t() as f64;
        let mut majorant = 0.0f64;
        for z in 1..d.nz - 1 {
            for y in 1..d.ny - 1 {
                for x in 1..d.nx - 1 {
                    majorant = majorant.max(medium.density[d.index(x, y, z)] as f64 * sigma_t);
                }
            }
        }
        let dir = sun.propagation;
        let mut faces = Vec::new();
        let mut area = 0.0;
        for axis in 0..3 {
            let w = dir[axis];
            if w.abs() < 1e-12 {
                continue;
            }
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let face_area = ((hi[a] - lo[a]) * (hi[b] - lo[b])) as f64;
            area += face_area * w.abs();
            let (plane, cell) =
                if w > 0.0 { (lo[axis] as f64, lo[axis]) } else { (hi[axis] as f64, hi[axis] - 1) };
            faces.push(Face { axis, plane, cell, cumulative: area });
        }
        for f in &mut faces {
            f.cumulative /= area;
        }
        Self {
            medium,
            params: *params,
            dir,
            lo,
            hi,
            majorant,
            faces,
            projected_area: area,
            scattered_only: false,
        }
    }

    /// `1 + σ_a` where the LB keeps a resting density (medium and brown nodes
    /// with ρ > 0), 1 elsewhere.
    fn rest_factor(&self, i: usize) -> f64 {
        if self.medium.density[i] > 0.0 && self.medium.class[i] != NodeClass::Green {
            1.0 + self.params.sigma_a as f64
        } else {
            1.0
        }
    }

    fn index(&self, c: [i64; 3]) -> usize {
        self.medium.dims.index(c[0] as usize, c[1] as usize, c[2] as usize)
    }

    /// Traces `photons` photons; returns the track length scored per node.
    fn trace_batch(&self, photons: u64, seed: u64) -> Vec<f64> {
        let mut rng = SplitMix64::new(seed);
        let mut tally = vec![0.0f64; self.medium.dims.len()];
        let sigma_t = self.params.sigma_t() as f64;
        let absorb = if sigma_t > 0.0 { self.params.sigma_a as f64 / sigma_t } else { 0.0 };
        let g = self.params.g as f64;
        for _ in 0..photons {
            let (mut pos, mut cell) = self.emit(&mut rng);
            let mut dir = self.dir;
            let mut scattered = false;
            loop {
                let flight = if self.majorant > 0.0 {
                    -(1.0 - rng.next_f64()).ln() / self.majorant
                } else {
                    f64::INFINITY
                };
                if !self.fly(
                    &mut pos,
                    &mut cell,
                    dir,
                    flight,
                    &mut tally,
                    scattered || !self.scattered_only,
                ) {
                    break;
                }
                let i = self.index(cell);
                let local = self.medium.density[i] as f64 * sigma_t;
                if rng.next_f64() * self.majorant >= local {
                    continue; // a null collision
                }
                let class = self.medium.class[i];
                scattered = true;
                if rng.next_f64() < absorb {
                    if class == NodeClass::Green {
                        break;
                    }
                    dir = isotropic(&mut rng);
                } else if class == NodeClass::Brown {
                    dir = dir.map(|v| -v);
                } else {
                    dir = henyey_greenstein(&mut rng, dir, g);
                }
            }
        }
        tally
    }

    /// A photon entering the box from the sun: a point on a lit face, and the
    /// cell it enters.
    fn emit(&self, rng: &mut SplitMix64) -> ([f64; 3], [i64; 3]) {
        let u = rng.next_f64();
        let face = self
            .faces
            .iter()
            .find(|f| u < f.cumulative)
            .unwrap_or(self.faces.last().expect("a lit face"));
        let mut pos = [0.0; 3];
        let mut cell = [0i64; 3];
        for a in 0..3 {
            if a == face.axis {
                pos[a] = face.plane;
                cell[a] = face.cell;
            } else {
                let span = (self.hi[a] - self.lo[a]) as f64;
                pos[a] = self.lo[a] as f64 + span * rng.next_f64();
                cell[a] = (pos[a].floor() as i64).clamp(self.lo[a], self.hi[a] - 1);
            }
        }
        (pos, cell)
    }

    /// Moves the photon `dist` along `dir` through the cells (a 3-D DDA),
    /// scoring each cell's chord. Returns false when it leaves the box.
    fn fly(
        &self,
        pos: &mut [f64; 3],
        cell: &mut [i64; 3],
        dir: [f64; 3],
        dist: f64,
        tally: &mut [f64],
        score: bool,
    ) -> bool {
        let score = if score { 1.0 } else { 0.0 };
        let mut t_next = [f64::INFINITY; 3];
        let mut t_step = [f64::INFINITY; 3];
        for a in 0..3 {
            if dir[a] > 0.0 {
                t_next[a] = ((cell[a] + 1) as f64 - pos[a]).max(0.0) / dir[a];
                t_step[a] = 1.0 / dir[a];
            } else if dir[a] < 0.0 {
                t_next[a] = (cell[a] as f64 - pos[a]).min(0.0) / dir[a];
                t_step[a] = -1.0 / dir[a];
            }
        }
        let mut t = 0.0;
        loop {
            let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
                0
            } else if t_next[1] <= t_next[2] {
                1
            } else {
                2
            };
            let i = self.index(*cell);
            if t_next[a] >= dist {
                tally[i] += score * (dist - t);
                for k in 0..3 {
                    pos[k] += dir[k] * dist;
                    // Keep the position in the tracked cell despite round-off.
                    pos[k] = pos[k].clamp(cell[k] as f64, (cell[k] + 1) as f64);
                }
                return true;
            }
            tally[i] += score * (t_next[a] - t);
            t = t_next[a];
            cell[a] += if dir[a] > 0.0 { 1 } else { -1 };
            if cell[a] < self.lo[a] || cell[a] >= self.hi[a] {
                return false;
            }
            t_next[a] += t_step[a];
        }
    }
}

/// A uniformly random unit vector.
fn isotropic(rng: &mut SplitMix64) -> [f64; 3] {
    let cos = 2.0 * rng.next_f64() - 1.0;
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
    [sin * phi.cos(), sin * phi.sin(), cos]
}

/// The cosine of the scattering angle drawn exactly from Henyey–Greenstein
/// by inverting its cumulative distribution.
pub fn sample_hg_cos(g: f64, u: f64) -> f64 {
    if g.abs() < 1e-6 {
        return 2.0 * u - 1.0;
    }
    if g.abs() >= 1.0 {
        return g.signum();
    }
    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// A new direction scattered from `dir` by Henyey–Greenstein with asymmetry `g`.
fn henyey_greenstein(rng: &mut SplitMix64, dir: [f64; 3], g: f64) -> [f64; 3] {
    let cos = sample_hg_cos(g, rng.next_f64());
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
    // An orthonormal frame around dir.
    let helper = if dir[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let mut u = cross(helper, dir);
    let len = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    u = u.map(|v| v / len);
    let v = cross(dir, u);
    let (cp, sp) = (phi.cos(), phi.sin());
    let out: [f64; 3] = std::array::from_fn(|k| dir[k] * cos + sin * (cp * u[k] + sp * v[k]));
    let len = (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt();
    out.map(|v| v / len)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Relative RMS difference `‖a − b‖ / ‖b‖` over the nodes `mask` selects.
pub fn relative_rms(a: &[f32], b: &[f32], mask: &[bool]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for ((&x, &y), &m) in a.iter().zip(b).zip(mask) {
        if m {
            num += (x as f64 - y as f64).powi(2);
            den += (y as f64).powi(2);
        }
    }
    if den > 0.0 { (num / den).sqrt() } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hg_sampling_has_mean_cosine_g() {
        for g in [-0.9, -0.3, 0.0, 0.5, 0.95] {
            let n = 200_000;
            let mut rng = SplitMix64::new(3);
            let mean: f64 =
                (0..n).map(|_| sample_hg_cos(g, rng.next_f64())).sum::<f64>() / n as f64;
            assert!((mean - g).abs() < 0.01, "g = {g}: mean cosine {mean}");
        }
    }

    #[test]
    fn lb_flux_matches_density_for_an_axial_sun() {
        let sun = Sun::towards([0.0, 1.0, 0.0], 1.0).unwrap();
        assert!((lb_flux_ratio(&sun) - 1.0).abs() < 1e-6);
        let diag = Sun::towards([1.0, 1.0, 0.0], 1.0).unwrap();
        assert!(lb_flux_ratio(&diag) < 0.9);
    }
}
