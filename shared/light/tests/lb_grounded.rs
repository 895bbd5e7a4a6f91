//! The grounded LB model against Monte Carlo transport in the same medium:
//! leaf media whose density comes from leaf area and whose σ_a, σ_s, g come
//! from the leaf optics, lit by a sun whose boundary carries its
//! irradiance. Tolerances and their reasons are in docs/lighting.md
//! ("How close the lattice comes"): the lattice's 18 directions, with the
//! diagonals crossing √2 per step, are the error; the slab (a canopy layer)
//! is where it is smallest, the ball where it is largest.

use sylva_light::lb::radiometry::{LeafScattering, density_from_leaf_area};
use sylva_light::lb::{
    CpuSolver, GridDims, Illumination, MediumGrid, NodeClass, Sun, solve_indirect,
};
use sylva_light::montecarlo::{fluence, scattered_fluence};
use sylva_light::studies::limits::{converged_options, slab, sphere};

/// A green leaf of texture colour (0.15, 0.35, 0.08) under the default
/// leaf optics (reflect ×1, transmit × f/b).
fn green_leaf() -> LeafScattering {
    let albedo = [0.15, 0.35, 0.08];
    let ratio = [0.055 / 0.070, 0.150 / 0.125, 0.020 / 0.040];
    LeafScattering { reflect: albedo, transmit: std::array::from_fn(|c| albedo[c] * ratio[c]) }
}

fn sun() -> Sun {
    Sun::from_elevation_azimuth(60.0, 30.0, 1.0).unwrap()
}

fn sun_only(e: f64) -> Illumination {
    Illumination {
        sun: sun(),
        sun_irradiance: [e; 3],
        sky_zenith: [0.0; 3],
        sky_horizon: [0.0; 3],
        ground: Some([0.0; 3]),
        floor_reflects: true,
    }
}

/// Mean over the medium's nodes, weighted by density (where the leaves are).
fn leaf_mean(values: &[f32], medium: &MediumGrid) -> f64 {
    let w: f64 = medium.density.iter().map(|&d| d as f64).sum();
    values.iter().zip(&medium.density).map(|(&v, &d)| v as f64 * d as f64).sum::<f64>() / w
}

/// A node density for leaf area density `lad` (m²/m³) in cells of 1 m.
fn rho(lad: f64) -> f32 {
    density_from_leaf_area(lad, 1.0)
}

/// The Monte Carlo's medium for an LB medium made by [`rho`]: the
/// continuous extinction κ = −ln(1 − ρ) per cell that ρ was made from
/// (the Monte Carlo reads density × σ_t as extinction per unit length).
fn continuous(medium: &MediumGrid) -> MediumGrid {
    MediumGrid {
        density: medium.density.iter().map(|&r| -(1.0 - r).ln()).collect(),
        ..medium.clone()
    }
}

/// LB total and indirect against Monte Carlo total and scattered, as
/// means over the leaves relative to the free field, per channel.
fn compare(medium: &MediumGrid, leaf: &LeafScattering, photons: u64) -> Vec<(f64, f64, f64, f64)> {
    let params = leaf.params();
    let mc_medium = continuous(medium);
    let e = 2.0;
    let lb = solve_indirect(
        &mut CpuSolver,
        medium,
        &params,
        &sun_only(e),
        &converged_options(medium.dims),
        &|_| {},
    )
    .unwrap();
    let s0 = sylva_light::montecarlo::free_stream_density(&sun()) as f64;
    (0..3)
        .map(|c| {
            let mc = fluence(&mc_medium, &params.channels[c], &sun(), photons, 7 + c as u64);
            let mc_s =
                scattered_fluence(&mc_medium, &params.channels[c], &sun(), photons, 7 + c as u64);
            (
                leaf_mean(&lb.total[c], medium) / e,
                leaf_mean(&mc.values, medium) / s0,
                leaf_mean(&lb.indirect[c], medium) / e,
                leaf_mean(&mc_s.values, medium) / s0,
            )
        })
        .collect()
}

#[test]
fn a_slab_of_leaves_matches_monte_carlo() {
    // 8 m of leaves at LAD 0.5: vertical optical depth G·LAD·8 = 2.
    let medium = slab(GridDims::cube(26), 8, rho(0.5), NodeClass::Green);
    for (c, (lb, mc, lb_s, mc_s)) in
        compare(&medium, &green_leaf(), 400_000).into_iter().enumerate()
    {
        eprintln!(
            "slab channel {c}: total LB {lb:.4} MC {mc:.4}; scattered LB {lb_s:.4} MC {mc_s:.4}"
        );
        assert!((lb - mc).abs() < 0.10 * mc, "channel {c}: total LB {lb} MC {mc}");
        assert!(
            (lb_s - mc_s).abs() < 0.15 * mc_s + 0.005,
            "channel {c}: scattered LB {lb_s} MC {mc_s}"
        );
    }
}

#[test]
fn a_ball_of_leaves_matches_monte_carlo() {
    // Radius 8 m at LAD 0.5: optical radius 2.
    let medium = sphere(26, 8.0, rho(0.5), NodeClass::Green);
    for (c, (lb, mc, lb_s, mc_s)) in
        compare(&medium, &green_leaf(), 400_000).into_iter().enumerate()
    {
        eprintln!(
            "ball channel {c}: total LB {lb:.4} MC {mc:.4}; scattered LB {lb_s:.4} MC {mc_s:.4}"
        );
        // The total holds the uncollided beam, which the tracer adds itself.
        assert!((lb - mc).abs() < 0.35 * mc, "channel {c}: total LB {lb} MC {mc}");
        assert!(
            (lb_s - mc_s).abs() < 0.20 * mc_s + 0.005,
            "channel {c}: scattered LB {lb_s} MC {mc_s}"
        );
    }
}

#[test]
fn leaves_that_scatter_nothing_leave_no_indirect_sunlight() {
    let medium = sphere(20, 7.0, rho(1.0), NodeClass::Green);
    let black = LeafScattering { reflect: [0.0; 3], transmit: [0.0; 3] };
    let lb = solve_indirect(
        &mut CpuSolver,
        &medium,
        &black.params(),
        &sun_only(3.0),
        &converged_options(medium.dims),
        &|_| {},
    )
    .unwrap();
    for c in 0..3 {
        let max = lb.indirect[c].iter().copied().fold(0.0f32, f32::max);
        assert!(max < 1e-5, "channel {c}: {max}");
        // The whole field is not zero: the uncollided beam is there, and the tracer adds it.
        assert!(leaf_mean(&lb.total[c], &medium) > 0.1);
    }
}

#[test]
fn in_a_thin_medium_the_indirect_term_is_single_scattering() {
    // Optical radius 0.1: nearly every scattered photon has scattered once,
    // so the scattered fluence is linear in the density and equals MC's.
    let thin = |lad: f64| sphere(26, 8.0, rho(lad), NodeClass::Green);
    let leaf = LeafScattering { reflect: [0.4; 3], transmit: [0.4; 3] };
    let a = compare(&thin(0.025), &leaf, 400_000);
    let b = compare(&thin(0.0125), &leaf, 400_000);
    let (lb_a, mc_a) = (a[0].2, a[0].3);
    let lb_b = b[0].2;
    eprintln!("thin ball: LB scattered {lb_a:.5} (half density {lb_b:.5}), MC {mc_a:.5}");
    assert!((lb_a / lb_b - 2.0).abs() < 0.1, "not linear in density: {lb_a} vs {lb_b}");
    assert!((lb_a - mc_a).abs() < 0.25 * mc_a, "LB {lb_a} MC {mc_a}");
}
