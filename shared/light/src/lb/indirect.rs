//! Direct and indirect light kept apart: the tracer adds the sun's
//! uncollided beam with shadow rays, so the LB must supply only the light
//! that has scattered at least once, plus the sky.
//!
//! The lattice is linear in its boundary, so the split is exact on the
//! lattice: solve once with sun and sky on the boundary and the leaves'
//! σ_s (the whole field), once with the sun alone and σ_s = 0 (its
//! uncollided beam, attenuated exactly as in the first solve, since σ_t is
//! the same), and subtract. The second solve has one grey channel, scaled
//! per colour, because the leaves' σ_t does not depend on colour.

use super::medium::{MediumGrid, NodeClass};
use super::params::{ChannelParams, LbParams};
use super::radiometry::Illumination;
use super::solver::{ChannelReport, LightingSolver, SolveOptions};

/// The LB field split into what the tracer adds itself and what it does not.
#[derive(Clone, Debug)]
pub struct IndirectSolution {
    /// Per channel, per node: the whole field, φ (sun and sky, every order of scattering).
    pub total: [Vec<f32>; 3],
    /// Per channel, per node: φ minus the sun's uncollided beam: the
    /// scattered sunlight and all of the sky's light.
    pub indirect: [Vec<f32>; 3],
    /// The whole-field solve per channel, then the uncollided pass.
    pub reports: Vec<ChannelReport>,
}

/// Solves `medium` under `light` and splits off the uncollided sun.
/// `params` must have the same σ_t in every channel (true of any leaf
/// medium, whose σ_t counts leaf hits).
pub fn solve_indirect(
    solver: &mut dyn LightingSolver,
    medium: &MediumGrid,
    params: &LbParams,
    light: &Illumination,
    opts: &SolveOptions,
    progress: &dyn Fn(&str),
) -> crate::Result<IndirectSolution> {
    params.validate()?;
    medium.validate()?;
    let sigma_t = params.channels[0].sigma_t();
    if !params.channels.iter().all(|p| (p.sigma_t() - sigma_t).abs() <= 1e-6 * sigma_t) {
        return Err(crate::Error::Invalid(format!(
            "the direct/indirect split needs one σ_t for all channels (got {:?})",
            params.channels.map(|p| p.sigma_t())
        )));
    }
    let mut reports = Vec::with_capacity(4);
    let mut total: [Vec<f32>; 3] = Default::default();
    for (c, (p, boundary)) in params.channels.iter().zip(light.boundaries()).enumerate() {
        progress(["red", "green", "blue"][c]);
        let s = solver.solve_channel(medium, p, &boundary, opts, &|_, _| {})?;
        reports.push(s.report);
        total[c] = s.total;
    }
    // The uncollided beam of a unit sun; scaled per channel below. Every
    // node absorbs for real here: a medium or brown node would re-emit what
    // it absorbs (its f_0), which is scattered light, not the beam.
    progress("uncollided sun");
    let unit = Illumination { sun_irradiance: [1.0; 3], ..*light };
    let absorb = ChannelParams { sigma_a: sigma_t, sigma_s: 0.0, g: 0.0 };
    let absorbing;
    let beam_medium = if medium.class.iter().all(|&c| c == NodeClass::Green) {
        medium
    } else {
        absorbing = medium.clone().with_class(NodeClass::Green);
        &absorbing
    };
    let beam =
        solver.solve_channel(beam_medium, &absorb, &unit.sun_boundary(0), opts, &|_, _| {})?;
    reports.push(beam.report);
    let indirect = std::array::from_fn(|c| {
        let e = light.sun_irradiance[c] as f32;
        // The two solves round differently; a hair below zero is zero light.
        total[c].iter().zip(&beam.total).map(|(t, b)| (t - e * b).max(0.0)).collect()
    });
    Ok(IndirectSolution { total, indirect, reports })
}
