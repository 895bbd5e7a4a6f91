//! The clouds' LB light: each cloud's density generated from its seed and
//! lit with the chapter's cloud parameters (strongly forward scattering,
//! almost no absorption). The LB methods read the light; the reference
//! path-traces the same density.

use crate::gpu::GpuContext;
use sylva_light::lb::LbParams;
use sylva_light::lb::{SolveOptions, Sun, solve};
use sylva_scene::Scene;
use sylva_scene::format::Preset;

/// Every cloud of `scene`, solved.
pub fn solve_clouds(ctx: &GpuContext, scene: &Scene) -> anyhow::Result<Vec<CloudGrid>> {
    let sun = Sun::towards(scene.sun.towards.as_dvec3().to_array(), 1.0)?;
    let params = LbParams::from_preset(Preset::Cloud);
    let mut solver = crate::lb::scene_solver(ctx);
    scene
        .clouds
        .iter()
        .map(|c| {
            let medium = sylva_light::shapes::cloud(c.grid, c.seed);
            let s = solve(
                solver.as_mut(),
                &medium,
                &params,
                &sun,
                &SolveOptions::default(),
                &|_, _, _| {},
            )?;
            let p = params.channels[0];
            Ok(CloudGrid {
                min: (glam::Vec3::from(c.center) - glam::Vec3::splat(c.size / 2.0)).to_array(),
                size: c.size,
                n: c.grid,
                light: s.channels.iter().flat_map(|ch| ch.total.iter().copied()).collect(),
                density: medium.density,
                sigma_t: p.sigma_t(),
                albedo: p.sigma_s / p.sigma_t(),
                g: p.g,
            })
        })
        .collect()
}

/// A cloud's density and solved LB light.
#[derive(Clone, Debug)]
pub struct CloudGrid {
    /// Lower corner of its cube, world space.
    pub min: [f32; 3],
    /// Cube edge.
    pub size: f32,
    /// Grid size N.
    pub n: usize,
    /// Density per node (N³).
    pub density: Vec<f32>,
    /// LB total density: three channel planes of N³ values.
    pub light: Vec<f32>,
    /// σ_t of the cloud's medium per lattice cell at density 1.
    pub sigma_t: f32,
    /// σ_s / σ_t.
    pub albedo: f32,
    /// Henyey–Greenstein asymmetry.
    pub g: f32,
}
