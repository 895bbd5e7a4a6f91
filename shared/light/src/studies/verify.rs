//! Checks of the implementation against the model's mathematics (DESIGN.md,
//! "Properties the code must satisfy"). Each check measures a number and
//! compares it with a bound; `sylva lb verify` prints them and the unit
//! tests assert them.

use crate::lb::boundary::{Boundary, Sun};
use crate::lb::collision::Omega;
use crate::lb::cpu::{CpuLattice, CpuSolver};
use crate::lb::lattice::{DIRECTIONS, Q};
use crate::lb::medium::{GridDims, MediumGrid, NodeClass};
use crate::lb::params::{ChannelParams, LbParams};
use crate::lb::solver::{LightingSolver, SolveOptions, solve};
use serde::Serialize;
use sylva_scene::format::Preset;

/// One check's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct Check {
    /// Letter of the acceptance point ("a" … "g").
    pub id: &'static str,
    /// What is checked.
    pub name: String,
    /// The measured value.
    pub measured: f64,
    /// The bound it must stay within (`measured <= bound`).
    pub bound: f64,
    /// Whether it did.
    pub pass: bool,
    /// How it was measured, and the per-case figures.
    pub detail: String,
}

impl Check {
    /// A check that passes when `measured <= bound`.
    pub fn new(
        id: &'static str,
        name: impl Into<String>,
        measured: f64,
        bound: f64,
        detail: String,
    ) -> Self {
        Self {
            id,
            name: name.into(),
            measured,
            bound,
            pass: measured <= bound && measured.is_finite(),
            detail,
        }
    }
}

/// The g values the column-sum check covers besides isotropic.
pub const CHECKED_G: [f32; 4] = [-0.75, -0.12, 0.3, 0.9];

/// (a) Every column of Ω sums to zero, isotropic and anisotropic.
pub fn column_sums() -> Check {
    let mut worst = 0.0f64;
    let mut cases = Vec::new();
    for g in std::iter::once(0.0).chain(CHECKED_G) {
        for (sa, ss) in [(0.109, 0.891), (0.008, 0.792), (0.3, 1.2)] {
            let w = Omega::new(&ChannelParams { sigma_a: sa, sigma_s: ss, g });
            let case = (0..Q)
                .map(|j| (0..Q).map(|i| w.0[i][j] as f64).sum::<f64>().abs())
                .fold(0.0, f64::max);
            worst = worst.max(case);
            cases.push(format!("g={g} σa={sa} σs={ss}: {case:.2e}"));
        }
    }
    Check::new(
        "a",
        "every column of Ω sums to 0",
        worst,
        1e-6,
        format!("max |column sum| of the f32 Ω; {}", cases.join("; ")),
    )
}

/// The isotropic null vector v = (σ_a, 1/12 ×6, 1/24 ×12).
pub fn null_vector(sigma_a: f64) -> [f64; Q] {
    std::array::from_fn(|m| match m {
        0 => sigma_a,
        1..=6 => 1.0 / 12.0,
        _ => 1.0 / 24.0,
    })
}

/// (b) The isotropic Ω maps v to zero.
pub fn isotropic_null_vector() -> Check {
    let mut worst = 0.0f64;
    for (sa, ss) in [(0.109, 0.891), (0.0, 1.0), (0.4, 0.1)] {
        let w = Omega::new(&ChannelParams::isotropic(sa, ss));
        let v = null_vector(sa as f64);
        for row in &w.0 {
            let r: f64 = row.iter().zip(&v).map(|(&a, &b)| a as f64 * b).sum();
            worst = worst.max(r.abs());
        }
    }
    Check::new(
        "b",
        "isotropic Ω has null vector v = (σa, 1/12 ×6, 1/24 ×12)",
        worst,
        1e-6,
        "max |(Ω v)_i| over three (σa, σs)".into(),
    )
}

/// (c) Σ_m v_m c_mα c_mβ = ½ δ_αβ.
pub fn second_moment() -> Check {
    let v = null_vector(0.0);
    let mut worst = 0.0f64;
    for a in 0..3 {
        for b in 0..3 {
            let s: f64 = (0..Q).map(|m| v[m] * (DIRECTIONS[m][a] * DIRECTIONS[m][b]) as f64).sum();
            let want = if a == b { 0.5 } else { 0.0 };
            worst = worst.max((s - want).abs());
        }
    }
    Check::new(
        "c",
        "Σ_m v_m c_mα c_mβ = ½ δ_αβ",
        worst,
        1e-12,
        "max deviation over the 9 (α, β)".into(),
    )
}

/// Worst |1 − exit flux / entry flux| over the columns of a dense medium lit
/// along +z, after the light has had time to cross it.
pub fn beam_transmission(params: &ChannelParams, n: usize) -> f64 {
    let dims = GridDims::cube(n);
    let medium = MediumGrid::uniform(dims, 1.0, NodeClass::Medium);
    let sun = Sun::towards([0.0, 0.0, -1.0], 1.0).expect("valid sun");
    let boundary = sun.boundary();
    let mut lattice = CpuLattice::new(&medium, params, &boundary);
    for _ in 0..2 * n {
        lattice.step(false);
    }
    let flux_z = |vals: &dyn Fn(usize) -> f32| {
        (0..Q).map(|m| vals(m) as f64 * DIRECTIONS[m][2] as f64).sum::<f64>()
    };
    let entry = flux_z(&|m| boundary.values[m]);
    let state = lattice.state();
    let total = dims.len();
    let mut worst = 0.0f64;
    for y in 1..n - 1 {
        for x in 1..n - 1 {
            let i = dims.index(x, y, n - 2);
            let exit = flux_z(&|m| state[m * total + i]);
            worst = worst.max((1.0 - exit / entry).abs());
        }
    }
    worst
}

/// (d) σ_a = 0 with g → 1 lets a beam through undiminished.
pub fn pass_through() -> Check {
    let n = 24;
    let exact = beam_transmission(&ChannelParams { sigma_a: 0.0, sigma_s: 1.0, g: 1.0 }, n);
    let near = beam_transmission(&ChannelParams { sigma_a: 0.0, sigma_s: 1.0, g: 0.999 }, n);
    let control = beam_transmission(&ChannelParams { sigma_a: 0.0, sigma_s: 1.0, g: 0.0 }, n);
    Check::new(
        "d",
        "σa = 0, g → 1 is a pass-through: a beam leaves the far face undiminished",
        exact.max(near),
        1e-4,
        format!(
            "{n}³ nodes, ρ = 1, σs = 1, light along +z, {} steps; max |1 − exit/entry flux| per column: g = 1: {exact:.2e}, g = 0.999: {near:.2e} (control, g = 0: {control:.3})",
            2 * n
        ),
    )
}

/// The lattice diffusion constant D = ((2/σ_t) − 1) / (4 (1 + σ_a)).
pub fn diffusion_constant(p: &ChannelParams) -> f64 {
    let st = p.sigma_t() as f64;
    ((2.0 / st) - 1.0) / (4.0 * (1.0 + p.sigma_a as f64))
}

/// Measured D of a point pulse in a uniform medium: the growth of ⟨r²⟩
/// between steps `t1` and `t2`, over 6.
pub fn measured_diffusion(p: &ChannelParams, n: usize, t1: usize, t2: usize) -> f64 {
    let dims = GridDims::cube(n);
    let medium = MediumGrid::uniform(dims, 1.0, NodeClass::Medium);
    let mut lattice = CpuLattice::new(&medium, p, &Boundary::DARK);
    let c = n / 2;
    let centre = dims.index(c, c, c);
    let v = null_vector(p.sigma_a as f64);
    let total = dims.len();
    for (m, vm) in v.iter().enumerate() {
        lattice.state_mut()[m * total + centre] = *vm as f32;
    }
    let second_moment = |l: &CpuLattice| {
        let t = l.node_totals();
        let (mut mass, mut r2) = (0.0f64, 0.0f64);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let w = t[dims.index(x, y, z)] as f64;
                    let d2 = [x, y, z].iter().map(|&a| (a as f64 - c as f64).powi(2)).sum::<f64>();
                    mass += w;
                    r2 += w * d2;
                }
            }
        }
        r2 / mass
    };
    for _ in 0..t1 {
        lattice.step(false);
    }
    let r1 = second_moment(&lattice);
    for _ in t1..t2 {
        lattice.step(false);
    }
    let r2 = second_moment(&lattice);
    (r2 - r1) / (t2 - t1) as f64 / 6.0
}

/// The (σ_a, σ_s) pairs the diffusion check covers.
pub const DIFFUSION_CASES: [(f32, f32); 4] = [(0.0, 1.0), (0.0, 0.5), (0.1, 0.9), (0.2, 0.3)];

/// (e) A pulse spreads with the lattice's diffusion constant, within 3 %.
pub fn diffusion() -> Check {
    let mut worst = 0.0f64;
    let mut cases = Vec::new();
    for (sa, ss) in DIFFUSION_CASES {
        let p = ChannelParams::isotropic(sa, ss);
        // A low σ_t spreads fast: give the pulse room so it never reaches the edge.
        let n = if p.sigma_t() < 0.75 { 96 } else { 64 };
        let want = diffusion_constant(&p);
        let got = measured_diffusion(&p, n, 40, 80);
        let err = (got / want - 1.0).abs();
        worst = worst.max(err);
        cases.push(format!(
            "σa={sa} σs={ss} ({n}³): D {got:.5} vs {want:.5} ({:+.2} %)",
            100.0 * (got / want - 1.0)
        ));
    }
    Check::new(
        "e",
        "a pulse diffuses with D = ((2/σt) − 1) / (4 (1 + σa))",
        worst,
        0.03,
        format!("relative error of D from ⟨r²⟩ growth over steps 40–80; {}", cases.join("; ")),
    )
}

/// (f) Invalid and unstable parameters are refused with a message that names
/// the parameter and its valid range.
pub fn invalid_parameters() -> Check {
    let cases: [(ChannelParams, &str, &str); 8] = [
        (ChannelParams { sigma_a: 0.9, sigma_s: 1.3, g: 0.0 }, "sigma_t", "(0, 2]"),
        (ChannelParams { sigma_a: 0.1, sigma_s: 0.9, g: 1.2 }, "g", "[-1, 1]"),
        (ChannelParams { sigma_a: 0.1, sigma_s: 0.9, g: -1.01 }, "g", "[-1, 1]"),
        (ChannelParams { sigma_a: -0.1, sigma_s: 0.9, g: 0.0 }, "sigma_a", "[0, 2]"),
        (ChannelParams { sigma_a: 0.1, sigma_s: -0.9, g: 0.0 }, "sigma_s", "[0, 2]"),
        (ChannelParams { sigma_a: f32::NAN, sigma_s: 0.9, g: 0.0 }, "sigma_a", "[0, 2]"),
        (ChannelParams { sigma_a: 0.1, sigma_s: f32::INFINITY, g: 0.0 }, "sigma_s", "[0, 2]"),
        (ChannelParams { sigma_a: 0.1, sigma_s: 0.9, g: f32::NEG_INFINITY }, "g", "[-1, 1]"),
    ];
    let mut failures = Vec::new();
    for (p, name, range) in &cases {
        match p.validate("") {
            Ok(()) => failures.push(format!("{p:?} accepted")),
            Err(e) => {
                let msg = e.to_string();
                if !msg.starts_with(name) || !msg.contains(range) {
                    failures.push(format!("{p:?}: message {msg:?} lacks {name} or {range}"));
                }
            }
        }
    }
    let valid = ChannelParams { sigma_a: 0.0, sigma_s: 2.0, g: -1.0 };
    if let Err(e) = valid.validate("") {
        failures.push(format!("the valid edge case {valid:?} was refused: {e}"));
    }
    let detail = if failures.is_empty() {
        format!(
            "{} invalid sets refused with named parameter and range; σt = 2, g = −1 accepted",
            cases.len()
        )
    } else {
        failures.join("; ")
    };
    Check::new(
        "f",
        "invalid and unstable parameters are refused by name and range",
        failures.len() as f64,
        0.0,
        detail,
    )
}

/// The maximum relative difference between two solutions of the same
/// channel. Values below `1e-6 ×` the largest value of `reference` are
/// compared against that floor, so round-off on values near zero is not
/// mistaken for disagreement.
pub fn max_relative_difference(candidate: &[f32], reference: &[f32]) -> f64 {
    assert_eq!(candidate.len(), reference.len());
    let peak = reference.iter().fold(0.0f64, |a, &b| a.max((b as f64).abs()));
    let floor = (peak * 1e-6).max(f64::MIN_POSITIVE);
    candidate
        .iter()
        .zip(reference)
        .map(|(&a, &b)| {
            let (a, b) = (a as f64, b as f64);
            if a.is_nan() || b.is_nan() {
                f64::INFINITY
            } else {
                (a - b).abs() / b.abs().max(floor)
            }
        })
        .fold(0.0, f64::max)
}

/// The random medium the GPU-against-CPU check uses: densities uniform in
/// [0, 1] and all three node classes, deterministic from `seed`.
pub fn random_medium(dims: GridDims, seed: u64) -> MediumGrid {
    let mut rng = sylva_scene::rng::SplitMix64::new(seed);
    let n = dims.len();
    let density = (0..n).map(|_| rng.next_f32()).collect();
    let class = (0..n)
        .map(|_| match rng.next_u64() % 3 {
            0 => NodeClass::Medium,
            1 => NodeClass::Green,
            _ => NodeClass::Brown,
        })
        .collect();
    MediumGrid { dims, density, class }
}

/// Solves a random medium of `dims` for `steps` steps with the leaf preset
/// on `candidate` and on the CPU reference; returns the maximum relative
/// difference per channel.
pub fn compare_with_reference(
    candidate: &mut dyn LightingSolver,
    dims: GridDims,
    steps: usize,
    seed: u64,
) -> crate::Result<[f64; 3]> {
    let medium = random_medium(dims, seed);
    let params = LbParams::from_preset(Preset::Leaf);
    let sun = Sun::from_elevation_azimuth(50.0, 20.0, 1.0)?;
    let opts = SolveOptions::fixed_steps(steps);
    let got = solve(candidate, &medium, &params, &sun, &opts, &|_, _, _| {})?;
    let want = solve(&mut CpuSolver, &medium, &params, &sun, &opts, &|_, _, _| {})?;
    Ok(std::array::from_fn(|c| {
        max_relative_difference(&got.channels[c].total, &want.channels[c].total)
    }))
}

/// (g) `candidate` (the GPU solver) matches the CPU reference within 1e-4
/// after 64 steps on a 32³ grid of random densities, all three channels.
pub fn reference_check(candidate: &mut dyn LightingSolver) -> Check {
    let name = "GPU solver matches the CPU reference (32³ random medium, 64 steps, R/G/B)";
    match compare_with_reference(candidate, GridDims::cube(32), 64, 11) {
        Ok(d) => {
            let detail = format!(
                "max relative difference R {:.2e}, G {:.2e}, B {:.2e} on {}",
                d[0],
                d[1],
                d[2],
                candidate.name()
            );
            Check::new("g", name, d.iter().copied().fold(0.0, f64::max), 1e-4, detail)
        }
        Err(e) => Check::new("g", name, f64::INFINITY, 1e-4, format!("could not run: {e:#}")),
    }
}

/// Checks (a)–(f), which need no GPU.
pub fn model_checks() -> Vec<Check> {
    vec![
        column_sums(),
        isotropic_null_vector(),
        second_moment(),
        pass_through(),
        diffusion(),
        invalid_parameters(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_pass(c: Check) {
        assert!(
            c.pass,
            "check {} failed: {} — measured {} > bound {} ({})",
            c.id, c.name, c.measured, c.bound, c.detail
        );
    }

    #[test]
    fn columns_of_omega_sum_to_zero() {
        assert_pass(column_sums());
    }

    #[test]
    fn isotropic_omega_has_the_null_vector() {
        assert_pass(isotropic_null_vector());
    }

    #[test]
    fn lattice_second_moment_is_isotropic() {
        assert_pass(second_moment());
    }

    #[test]
    fn forward_scattering_without_absorption_passes_light_through() {
        let c = pass_through();
        assert_pass(c.clone());
        // And the check can fail: isotropic scattering does diminish the beam.
        let iso = beam_transmission(&ChannelParams::isotropic(0.0, 1.0), 24);
        assert!(iso > 0.1, "isotropic scattering should block a beam, got {iso}");
    }

    #[test]
    fn pulse_spreads_with_the_diffusion_constant() {
        assert_pass(diffusion());
    }

    #[test]
    fn invalid_parameters_are_refused() {
        assert_pass(invalid_parameters());
    }

    #[test]
    fn relative_difference_sees_disagreement() {
        let a = [1.0, 2.0, 0.0];
        assert_eq!(max_relative_difference(&a, &a), 0.0);
        let b = [1.0, 2.002, 0.0];
        assert!((max_relative_difference(&b, &a) - 1e-3).abs() < 1e-6);
        assert!(max_relative_difference(&[f32::NAN, 2.0, 0.0], &a).is_infinite());
    }
}
