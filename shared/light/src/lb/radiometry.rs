//! Radiometry of the grounded LB model: what one unit of lattice density
//! is, how the sun and the sky set the boundary, how leaf area sets a
//! node's density and how the leaf's optics set σ_a, σ_s and g. The
//! derivations are in `docs/lighting.md`; every constant here has one.
//!
//! Units: `f_m(r)` is the fluence (W m⁻², or the scene's linear RGB
//! radiance units × sr) carried by the light whose direction lies in the
//! solid-angle bin of lattice direction `m` (the directions nearer to
//! `c_m` than to any other lattice direction). The node total `Σ_m f_m` is
//! then the scalar fluence φ = ∫ L dω, and a free field of radiance L in
//! every direction has φ = 4πL.

use super::boundary::{Boundary, GroundReflection, Sun};
use super::lattice::{Q, unit};
use super::params::{ChannelParams, LbParams};
use std::f64::consts::PI;
use std::sync::OnceLock;

/// G, the mean projection of unit one-sided leaf area onto a plane normal
/// to a direction, for leaves whose normals are spread evenly over the
/// sphere (Ross 1981): the extinction coefficient is κ = G · LAD.
pub const LEAF_PROJECTION: f64 = 0.5;

/// Mean cosine of the angle between the incoming and the outgoing direction
/// of light that a bi-Lambertian leaf of random orientation *transmits*
/// (the negative of it for reflected light): the hit weights a normal by
/// |n·ω| (mean |μ| = 2/3 under that weight), and a Lambertian lobe's mean
/// direction is 2/3 of its normal, so 4/9.
pub const BI_LAMBERTIAN_MEAN_COSINE: f64 = 4.0 / 9.0;

/// Samples per axis of the quadrature over the sphere (μ, then azimuth):
/// 256 × 512 equal-area cells, each 4π / 131072 sr.
const QUAD_MU: usize = 256;
const QUAD_PHI: usize = 512;

/// The lattice direction whose bin holds unit direction `w` (never 0).
fn bin_of(w: [f64; 3], units: &[[f64; 3]; Q]) -> usize {
    let mut best = 1;
    let mut best_dot = f64::NEG_INFINITY;
    for (m, n) in units.iter().enumerate().skip(1) {
        let d = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
        if d > best_dot {
            best_dot = d;
            best = m;
        }
    }
    best
}

/// `∫_{bin m} f(ω) dω` for every lattice direction, by the midpoint rule on
/// an equal-area grid of the sphere (uniform in μ is uniform in solid angle).
pub fn integrate_bins(f: impl Fn([f64; 3]) -> [f64; 3]) -> [[f64; 3]; Q] {
    let units: [[f64; 3]; Q] = std::array::from_fn(|m| if m == 0 { [0.0; 3] } else { unit(m) });
    let cell = 4.0 * PI / (QUAD_MU * QUAD_PHI) as f64;
    let mut out = [[0.0f64; 3]; Q];
    for a in 0..QUAD_MU {
        let mu = -1.0 + 2.0 * (a as f64 + 0.5) / QUAD_MU as f64;
        let r = (1.0 - mu * mu).max(0.0).sqrt();
        for b in 0..QUAD_PHI {
            let phi = 2.0 * PI * (b as f64 + 0.5) / QUAD_PHI as f64;
            // μ along y (up), so the horizon is a row of the grid.
            let w = [r * phi.cos(), mu, r * phi.sin()];
            let m = bin_of(w, &units);
            let v = f(w);
            for c in 0..3 {
                out[m][c] += v[c] * cell;
            }
        }
    }
    out
}

/// The solid angle of each lattice direction's bin, sr (0 for rest).
pub fn bin_solid_angles() -> &'static [f64; Q] {
    static ANGLES: OnceLock<[f64; Q]> = OnceLock::new();
    ANGLES.get_or_init(|| integrate_bins(|_| [1.0; 3]).map(|v| v[0]))
}

/// The light the scene sends into a lattice from outside: the sun (a
/// collimated beam) and the sky (a radiance per direction), per colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Illumination {
    /// Propagation direction of the sunlight.
    pub sun: Sun,
    /// E⊥: the sun's irradiance on a plane facing it, per channel.
    pub sun_irradiance: [f64; 3],
    /// Sky radiance straight up, per channel.
    pub sky_zenith: [f64; 3],
    /// Sky radiance at (and, with no ground, below) the horizon.
    pub sky_horizon: [f64; 3],
    /// A ground plane's albedo per channel, if there is one: it hides the
    /// sky below the horizon, reflects as the lattice's lower face and,
    /// outside the lattice, sends the open ground's light up through the
    /// side faces (see `docs/lighting.md`).
    pub ground: Option<[f64; 3]>,
    /// Whether the lattice's lower face is that ground (the model stands on
    /// it) and reflects what reaches it; else the lower face holds the open
    /// ground's light, fixed like the other faces.
    pub floor_reflects: bool,
}

impl Illumination {
    /// The light the scene sends into an LB lattice: the sun's irradiance
    /// E⊥ = π × its radiance scale (a surface facing it shows ρ × radiance,
    /// docs/lighting.md), and the sky, per colour.
    pub fn of_scene(scene: &sylva_scene::Scene) -> Self {
        let sun = Sun::towards(scene.sun.towards.as_dvec3().to_array(), 1.0)
            .expect("the scene's sun was checked");
        let f = |v: [f32; 3]| v.map(|x| x as f64);
        Illumination {
            sun,
            sun_irradiance: f(scene.sun.radiance).map(|x| std::f64::consts::PI * x),
            sky_zenith: f(scene.sky.zenith),
            sky_horizon: f(scene.sky.horizon),
            ground: scene.ground.as_ref().map(|g| g.color.map(|x| x as f64)),
            floor_reflects: true,
        }
    }

    /// The sky's radiance arriving from direction `from` (a unit vector
    /// pointing at the sky), as the renderer and the reference draw it:
    /// horizon to zenith by the square root of the elevation's sine.
    pub fn sky_radiance(&self, from: [f64; 3]) -> [f64; 3] {
        if from[1] < 0.0 && self.ground.is_some() {
            return [0.0; 3];
        }
        let t = from[1].max(0.0).sqrt();
        std::array::from_fn(|c| {
            self.sky_horizon[c] + (self.sky_zenith[c] - self.sky_horizon[c]) * t
        })
    }

    /// Fluence of the sky in each lattice direction's bin: light travelling
    /// along ω comes from −ω.
    pub fn sky_bins(&self) -> [[f64; 3]; Q] {
        integrate_bins(|w| self.sky_radiance([-w[0], -w[1], -w[2]]))
    }

    /// The sun's share of each direction: E⊥ · max(0, n_m · ω) / Σ_k max(0, n_k · ω),
    /// so the bins add up to E⊥ (the beam's fluence).
    pub fn sun_bins(&self) -> [[f64; 3]; Q] {
        let b = Sun { intensity: 1.0, ..self.sun }.boundary();
        let s0: f64 = b.values.iter().map(|&v| v as f64).sum();
        std::array::from_fn(|m| {
            std::array::from_fn(|c| {
                if s0 > 0.0 { self.sun_irradiance[c] * b.values[m] as f64 / s0 } else { 0.0 }
            })
        })
    }

    /// Boundary densities of the three channels: sun, sky and, over a
    /// ground, the open ground's reflection in the upward directions and a
    /// reflecting lower face (the sky's quadrature done once for all three).
    /// The ground's gain is the open ground's irradiance, E⊥ sin(elevation)
    /// plus the sky's, over what the lattice's downward directions collect
    /// of the same boundary.
    pub fn boundaries(&self) -> [Boundary; 3] {
        let (sun, sky) = (self.sun_bins(), self.sky_bins());
        let sky_e = self.sky_irradiance_horizontal();
        std::array::from_fn(|c| {
            let values = std::array::from_fn(|m| (sun[m][c] + sky[m][c]) as f32);
            match self.ground {
                None => Boundary::fixed(values),
                Some(albedo) => {
                    let open =
                        self.sun_irradiance[c] * (-self.sun.propagation[1]).max(0.0) + sky_e[c];
                    let collected = GroundReflection::collected(&values) as f64;
                    let gain = if collected > 0.0 { (open / collected) as f32 } else { 1.0 };
                    let ground = GroundReflection { albedo: albedo[c] as f32, gain };
                    Boundary {
                        values: ground.reflect(&values),
                        ground: self.floor_reflects.then_some(ground),
                    }
                }
            }
        })
    }

    /// Boundary densities of channel `c` with the sun alone (the
    /// uncollided pass that [`solve_indirect`](super::indirect::solve_indirect) subtracts).
    pub fn sun_boundary(&self, c: usize) -> Boundary {
        let sun = self.sun_bins();
        Boundary::fixed(std::array::from_fn(|m| sun[m][c] as f32))
    }

    /// φ of the free field (no medium): what a boundary node holds, E⊥
    /// plus the sky's fluence plus, over a ground, the open ground's.
    pub fn free_fluence(&self) -> [f64; 3] {
        self.boundaries().map(|b| b.values.iter().map(|&v| v as f64).sum())
    }

    /// Irradiance the open sky gives a horizontal surface, ∫ L cos θ dω
    /// over the upper hemisphere (π (0.2 horizon + 0.8 zenith) for this sky).
    pub fn sky_irradiance_horizontal(&self) -> [f64; 3] {
        std::array::from_fn(|c| PI * (0.2 * self.sky_horizon[c] + 0.8 * self.sky_zenith[c]))
    }
}

/// A leaf's reflectance and transmittance, per channel, each averaged over
/// its two sides (the lattice does not know which side a leaf turns to the light).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafScattering {
    /// ρ_r: fraction of the light hitting the leaf that it reflects.
    pub reflect: [f64; 3],
    /// ρ_t: fraction it transmits.
    pub transmit: [f64; 3],
}

impl LeafScattering {
    /// The LB's parameters for a medium of these leaves: a collision is a
    /// leaf hit, so σ_t = 1 per collision and ρ carries the probability;
    /// the single-scattering albedo is ρ_r + ρ_t (σ_s), the rest absorbed
    /// (σ_a); g is the mean scattering cosine of randomly oriented
    /// bi-Lambertian leaves, (4/9)(ρ_t − ρ_r)/(ρ_t + ρ_r).
    pub fn params(&self) -> LbParams {
        LbParams {
            channels: std::array::from_fn(|c| {
                let (r, t) = (self.reflect[c].max(0.0), self.transmit[c].max(0.0));
                let albedo = (r + t).min(1.0);
                let g =
                    if r + t > 0.0 { BI_LAMBERTIAN_MEAN_COSINE * (t - r) / (t + r) } else { 0.0 };
                ChannelParams {
                    sigma_a: (1.0 - albedo) as f32,
                    sigma_s: albedo as f32,
                    g: g as f32,
                }
            }),
        }
    }
}

/// A node's density from the one-sided leaf area `area` in its cubic cell
/// of edge `cell`: the probability that light crossing the cell along an
/// axis meets a leaf, 1 − exp(−G · area / cell²) (κ = G · LAD, path = cell).
pub fn density_from_leaf_area(area: f64, cell: f64) -> f32 {
    if area <= 0.0 || cell <= 0.0 {
        return 0.0;
    }
    (1.0 - (-LEAF_PROJECTION * area / (cell * cell)).exp()) as f32
}

/// What a cell's sub-cell columns of leaf area make of it: how much light
/// it stops and how much of its light its own leaves receive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClumpedCell {
    /// The probability that light crossing the cell along an axis meets a
    /// leaf, 1 − ⟨exp(−τ_column)⟩ with τ_column = G · a_column / sub_cell².
    /// Leaves clumped into a few columns leave the others open, so the cell
    /// stops less light than [`density_from_leaf_area`] of the same area
    /// spread evenly (Jensen: ⟨e^(−τ)⟩ ≥ e^(−⟨τ⟩)); with one column per
    /// axis the two agree.
    pub density: f32,
    /// The mean light on the cell's leaves over what an even medium of the
    /// same density would give them: each leaf in a column of depth τ is
    /// shaded by its neighbours to (1 − e^(−τ))/τ of the light around the
    /// column (the depth average of a two-sided slab), weighted by leaf
    /// area, over the same factor at the cell's effective depth. 1 without
    /// finer structure.
    pub readout: f32,
}

/// (1 − e^(−τ))/τ: the mean over a slab of optical depth τ of the light
/// reaching a depth from its nearer face, lit equally from both faces.
fn slab_mean(tau: f64) -> f64 {
    if tau < 1e-6 { 1.0 - 0.5 * tau } else { -(-tau).exp_m1() / tau }
}

/// A cell's [`ClumpedCell`] from the one-sided leaf area of the columns of
/// sub-cells (edge `sub_cell`) that cross it along the three axes.
pub fn clumped_cell(columns: &[f64], sub_cell: f64) -> ClumpedCell {
    let total: f64 = columns.iter().map(|&a| a.max(0.0)).sum();
    if total <= 0.0 || sub_cell <= 0.0 {
        return ClumpedCell { density: 0.0, readout: 1.0 };
    }
    let k = LEAF_PROJECTION / (sub_cell * sub_cell);
    let open: f64 =
        columns.iter().map(|&a| (-k * a.max(0.0)).exp()).sum::<f64>() / columns.len() as f64;
    let on_leaves: f64 =
        columns.iter().map(|&a| a.max(0.0) * slab_mean(k * a.max(0.0))).sum::<f64>() / total;
    let effective = -open.max(f64::MIN_POSITIVE).ln();
    ClumpedCell { density: (1.0 - open) as f32, readout: (on_leaves / slab_mean(effective)) as f32 }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn illumination(sky: f64, ground: bool) -> Illumination {
        Illumination {
            sun: Sun::from_elevation_azimuth(50.0, 30.0, 1.0).unwrap(),
            sun_irradiance: [3.0, 2.0, 1.0],
            sky_zenith: [sky; 3],
            sky_horizon: [sky; 3],
            ground: ground.then_some([0.0; 3]),
            floor_reflects: true,
        }
    }

    #[test]
    fn the_bins_tile_the_sphere() {
        let a = bin_solid_angles();
        assert!((a.iter().sum::<f64>() - 4.0 * PI).abs() < 1e-9);
        // By symmetry the six axial bins are equal, and so are the twelve diagonal ones.
        for m in 2..=6 {
            assert!((a[m] - a[1]).abs() < 2e-3 * a[1], "{a:?}");
        }
        for m in 8..Q {
            assert!((a[m] - a[7]).abs() < 2e-3 * a[7], "{a:?}");
        }
    }

    #[test]
    fn a_uniform_sky_over_a_ground_has_fluence_two_pi_l() {
        let il = illumination(0.5, true);
        let phi: f64 = il.sky_bins().iter().map(|v| v[0]).sum();
        assert!((phi - 2.0 * PI * 0.5).abs() < 2e-3, "{phi}");
        // Without a ground the horizon colour fills the lower half too.
        let phi: f64 = illumination(0.5, false).sky_bins().iter().map(|v| v[0]).sum();
        assert!((phi - 4.0 * PI * 0.5).abs() < 2e-3, "{phi}");
        // No bin that points up (light from below) carries sky over a ground.
        let bins = il.sky_bins();
        for m in 1..Q {
            if super::super::lattice::DIRECTIONS[m][1] > 0 {
                assert_eq!(bins[m][0], 0.0, "direction {m}");
            }
        }
    }

    #[test]
    fn the_sun_bins_add_up_to_its_irradiance() {
        let il = illumination(0.0, true);
        for c in 0..3 {
            let s: f64 = il.sun_bins().iter().map(|v| v[c]).sum();
            assert!((s - il.sun_irradiance[c]).abs() < 1e-9);
        }
    }

    #[test]
    fn the_horizontal_sky_irradiance_is_the_cosine_weighted_integral() {
        let il = Illumination {
            sky_zenith: [0.2, 0.4, 0.9],
            sky_horizon: [0.8, 0.8, 0.9],
            ..illumination(0.0, true)
        };
        let bins = integrate_bins(|w| {
            if w[1] > 0.0 { il.sky_radiance(w).map(|l| l * w[1]) } else { [0.0; 3] }
        });
        for c in 0..3 {
            let e: f64 = bins.iter().map(|v| v[c]).sum();
            assert!((e - il.sky_irradiance_horizontal()[c]).abs() < 1e-3 * e, "{c}: {e}");
        }
    }

    #[test]
    fn the_open_ground_reflects_lambertianly_and_conserves_energy() {
        let il = Illumination { ground: Some([1.0, 0.5, 0.0]), ..illumination(0.3, true) };
        let omega = bin_solid_angles();
        let collect = GroundReflection::collect();
        for (c, b) in il.boundaries().iter().enumerate() {
            let albedo = [1.0, 0.5, 0.0][c];
            let g = b.ground.unwrap();
            assert_eq!(g.albedo, albedo as f32);
            let down: f64 = (1..Q).map(|m| collect[m] as f64 * b.values[m] as f64).sum();
            let up: f64 =
                (1..Q).filter(|&m| unit(m)[1] > 0.0).map(|m| unit(m)[1] * b.values[m] as f64).sum();
            // Sun at 50° plus a uniform sky: E = E⊥ sin 50° + π L. The
            // downward directions collect 0.71–0.77 of it; the gain restores it.
            let e = il.sun_irradiance[c] * 50f64.to_radians().sin() + PI * 0.3;
            assert!(down < e && down > 0.6 * e, "channel {c}: {down} against {e}");
            assert!(
                (g.gain as f64 * down - e).abs() < 1e-5 * e,
                "channel {c}: gain {} × {down} against {e}",
                g.gain
            );
            assert!((up - albedo * e).abs() < 1e-5 * e, "channel {c}: up {up}, E {e}");
            // One radiance in every upward bin: fluence in proportion to solid angle.
            let radiance: Vec<f64> = (1..Q)
                .filter(|&m| unit(m)[1] > 0.0)
                .map(|m| b.values[m] as f64 / omega[m])
                .collect();
            assert!(
                radiance.iter().all(|r| (r - radiance[0]).abs() <= 1e-5 * radiance[0].max(1e-9)),
                "{radiance:?}"
            );
        }
        // The sun-only boundary of the uncollided pass has no ground: its reflection is scattered light.
        assert_eq!(il.sun_boundary(0).ground, None);
    }

    #[test]
    fn leaf_parameters_follow_from_the_optics() {
        let p = LeafScattering { reflect: [0.1, 0.2, 0.0], transmit: [0.1, 0.4, 0.0] }.params();
        p.validate().unwrap();
        assert!((p.channels[0].sigma_s - 0.2).abs() < 1e-6 && p.channels[0].g.abs() < 1e-6);
        assert!(
            (p.channels[1].sigma_s - 0.6).abs() < 1e-6
                && (p.channels[1].g as f64 - 4.0 / 27.0).abs() < 1e-6
        );
        assert_eq!(p.channels[2].sigma_s, 0.0);
    }

    #[test]
    fn clumped_leaves_stop_what_their_columns_stop() {
        let h = 0.25;
        // Two sub-cells per edge: 4 columns per axis. Even: every column
        // holds the same area, as one cell of twice the edge holding 4 × it.
        let even = clumped_cell(&[0.1; 12], h);
        assert!((even.readout - 1.0).abs() < 1e-6);
        let even = even.density as f64;
        let mean = density_from_leaf_area(0.4, 2.0 * h) as f64;
        assert!((even - (1.0 - (-LEAF_PROJECTION * 0.1 / (h * h)).exp())).abs() < 1e-6);
        assert!((even - mean).abs() < 1e-6, "{even} {mean}");
        // The same area in a quarter of the columns: three quarters open.
        let mut clumped = [0.0; 12];
        clumped.iter_mut().step_by(4).for_each(|a| *a = 0.4);
        let cell = clumped_cell(&clumped, h);
        let (rho, tau) = (cell.density as f64, LEAF_PROJECTION * 0.4 / (h * h));
        assert!((rho - 0.25 * (1.0 - (-tau).exp())).abs() < 1e-6 && rho < even, "{rho} {even}");
        // Its leaves, deep in their clumps, get less than an even medium's.
        let expect = slab_mean(tau) / slab_mean(-(1.0 - rho).ln());
        assert!((cell.readout as f64 - expect).abs() < 1e-6 && cell.readout < 0.8, "{cell:?}");
    }

    #[test]
    fn leaf_area_density_is_a_hit_probability_independent_of_the_grid() {
        // A slab 1 m thick with LAD 2: optical depth G·LAD·1 = 1 whatever the cell.
        for cells in [2usize, 4, 8, 16, 32] {
            let h = 1.0 / cells as f64;
            let rho = density_from_leaf_area(2.0 * h * h * h, h) as f64;
            let transmitted = (1.0 - rho).powi(cells as i32);
            assert!((transmitted - (-1.0f64).exp()).abs() < 1e-6, "{cells}: {transmitted}");
        }
    }
}
