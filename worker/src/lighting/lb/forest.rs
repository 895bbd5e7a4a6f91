//! The coarse LB grid over the whole forest (forest paper §3), solved on
//! the GPU. Its light where each crown stands scales that instance's
//! species grid, so a tree deep in the stand receives less light than one
//! at its edge; in the grounded model it also lights the ground under the
//! stand. What is CPU-only (leaf area per cell, the light reaching a
//! crown, the decision) is in `sylva_light::lb::coarse`.

use super::sun_of;
use crate::gpu::GpuContext;
use sylva_accel::Aabb;
use sylva_accel::two_level::model_bounds;
use sylva_light::lb::coarse::{
    ForestLight, ModelArea, Occupant, WorldGrid, crown_fill, crown_reach, forest_leaf_area,
    forest_medium,
};
use sylva_light::lb::{
    GridDims, Illumination, IndirectSolution, LbGrid, LbParams, LightingSolver, SolveOptions,
    solve, solve_indirect,
};
use sylva_light::voxel::medium_from_leaf_area;
use sylva_scene::format::Preset;
use sylva_scene::{ForestGridUse, Scene};

/// Each instance's world box. A model's own box is found once: walking a
/// model's vertices for each of its instances took about a second of the
/// full forest's preparation.
fn instance_boxes(scene: &Scene) -> Vec<Aabb> {
    let models: Vec<Aabb> = scene.models.iter().map(|m| model_bounds(&m.model)).collect();
    scene.instances.iter().map(|i| models[i.model as usize].transformed(&i.to_world)).collect()
}

/// The paper's forest grid: each instance's box filled by its crown's
/// fill, lit by a unit sun; scales are the light at each box's centre
/// over the best-lit instance's.
pub fn paper(
    ctx: &GpuContext,
    scene: &Scene,
    grids: &[Option<LbGrid>],
    scales: &mut [f32],
) -> anyhow::Result<ForestLight> {
    let spec = scene.file.forest_grid;
    if spec.use_grid == ForestGridUse::Never {
        return Ok(ForestLight::unused("forest_grid.use is \"never\"".into(), None));
    }
    if scene.instances.len() < 2 {
        return Ok(ForestLight::unused("a single instance has nothing to shade it".into(), None));
    }
    let fills: Vec<f32> = grids
        .iter()
        .zip(&scene.models)
        .map(|(g, m)| g.as_ref().map_or(0.0, |g| crown_fill(g, &m.model)))
        .collect();
    let occupants: Vec<Occupant> = instance_boxes(scene)
        .into_iter()
        .zip(&scene.instances)
        .map(|(bounds, i)| Occupant { bounds, fill: fills[i.model as usize] })
        .collect();
    let all = occupants.iter().fold(Aabb::EMPTY, |b, o| b.union(o.bounds));
    let grid = WorldGrid::around(all, spec.grid);
    let medium = forest_medium(&grid, &occupants);
    let sun = sun_of(scene)?;
    let mut solver = crate::lb::scene_solver(ctx);
    let sol = solve(
        solver.as_mut(),
        &medium,
        &LbParams::from_preset(Preset::Leaf),
        &sun,
        &SolveOptions::default(),
        &|_, _, _| {},
    )?;
    let free: f32 = sun.boundary().values.iter().sum();
    let light: Vec<f32> = occupants
        .iter()
        .map(|o| {
            let p = o.bounds.centroid();
            sol.channels.iter().map(|c| grid.sample(&c.total, p)).sum::<f32>() / (3.0 * free)
        })
        .collect();
    let max = light.iter().copied().fold(0.0f32, f32::max).max(f32::MIN_POSITIVE);
    let what = ("the instances' light", "all get full light");
    Ok(ForestLight::decide(spec, grid, &light, what, |l| l / max, scales))
}

/// The grounded forest grid: each instance's blocking area (its model's,
/// × its scale², where its model has it: [`forest_leaf_area`]) sets the
/// coarse medium; the leaves' mean optics set σ_a, σ_s, g; sun and sky
/// light it. An instance's species grid, solved in the open, is scaled by
/// the fraction of the open field's fluence that reaches its crown from
/// outside ([`crown_reach`]). The ground under the stand reads the grid's
/// indirect light (returned as a [`GroundLight`]).
pub fn grounded(
    ctx: &GpuContext,
    scene: &Scene,
    areas: &[Option<&ModelArea>],
    scales: &mut [f32],
) -> anyhow::Result<(ForestLight, Option<GroundLight>)> {
    let spec = scene.file.forest_grid;
    if scene.instances.is_empty()
        || (spec.use_grid == ForestGridUse::Never && scene.ground.is_none())
    {
        return Ok((
            ForestLight::unused("forest_grid.use is \"never\" and there is no ground".into(), None),
            None,
        ));
    }
    let boxes = instance_boxes(scene);
    let all = boxes.iter().fold(Aabb::EMPTY, |b, o| b.union(*o));
    let grid = WorldGrid::around(all, spec.grid);
    let d = grid.dims;
    let (area, leaves) = forest_leaf_area(scene, areas, &grid);
    let medium = medium_from_leaf_area(&area, d, grid.cell);
    let light = Illumination::of_scene(scene);
    let mut solver = crate::lb::scene_solver(ctx);
    let sol = solve_indirect(
        solver.as_mut(),
        &medium,
        &leaves.params(),
        &light,
        &SolveOptions::default(),
        &|_| {},
    )?;
    let sun_y = scene.sun.towards.y.max(0.0);
    let ground = match scene.ground.as_ref().map(|g| g.color) {
        None => None,
        Some(albedo) => {
            // The first layer above the floor, read as isotropic halves: the
            // downward half brings E = φ↓/2, the upward half is what the
            // ground sends back of it and of the direct sun, φ↑ = 2a(E +
            // E_sun). So E = (φ_indirect/2 − a E_sun) / (1 + a), with E_sun =
            // sin(elevation) × the uncollided beam's fluence.
            let read = |sol: &IndirectSolution, c: usize, i: usize| {
                let a = albedo[c];
                let e_sun = sun_y * (sol.total[c][i] - sol.indirect[c][i]).max(0.0);
                ((sol.indirect[c][i] / 2.0 - a * e_sun) / (1.0 + a)).max(0.0)
            };
            // That read-out is biased (an anisotropic sky is not φ/2; a low
            // sun crosses the lattice between its directions), and the open
            // ground outside the grid gets the exact cosine-weighted sky: a
            // step at the grid's edge. So the ground under the stand is the
            // open ground's exact irradiance times the fraction the lattice
            // lets through, each node's read-out over the same read-out of
            // an empty lattice under the same sky (docs/lighting.md, "The
            // forest grid, the ground and the trunks under the stand").
            let open = open_floor(solver.as_mut(), &leaves.params(), &light, grid.cell)?;
            let exact = light.sky_irradiance_horizontal();
            let middle = GridDims { nx: OPEN, ny: OPEN, nz: OPEN }.index(OPEN / 2, 1, OPEN / 2);
            let scale: [f32; 3] = std::array::from_fn(|c| {
                let e = read(&open, c, middle);
                if e > 0.0 { exact[c] as f32 / e } else { 0.0 }
            });
            Some(GroundLight {
                origin: [grid.origin[0], grid.origin[2]],
                cell: grid.cell,
                nx: d.nx,
                nz: d.nz,
                rgb: (0..3)
                    .flat_map(|c| (0..d.nz).flat_map(move |z| (0..d.nx).map(move |x| (c, x, z))))
                    .map(|(c, x, z)| read(&sol, c, d.index(x, 1, z)) * scale[c])
                    .collect(),
            })
        }
    };
    if scene.instances.len() < 2 && spec.use_grid != ForestGridUse::Always {
        return Ok((
            ForestLight::unused(
                "a single instance has nothing to shade it; the grid lights the ground".into(),
                Some(grid),
            ),
            ground,
        ));
    }
    if spec.use_grid == ForestGridUse::Never {
        return Ok((
            ForestLight::unused(
                "forest_grid.use is \"never\"; the grid lights the ground".into(),
                Some(grid),
            ),
            ground,
        ));
    }
    let free: f64 = light.free_fluence().iter().sum();
    let reach = crown_reach(&grid, &sol.total, free, scene.sun.towards, &boxes);
    // Scattering from neighbours can lift a crown's surroundings a hair
    // above the open field's; the species grid is already lit by that field.
    let what = ("the light reaching the crowns", "all get the open field's");
    Ok((ForestLight::decide(spec, grid, &reach, what, |r| r.min(1.0), scales), ground))
}

/// Nodes per side of the empty lattice [`open_floor`] solves.
const OPEN: usize = 8;

/// An empty lattice of the forest grid's cell under the same sun, sky and
/// reflecting ground: the open field as the lattice holds it.
fn open_floor(
    solver: &mut dyn LightingSolver,
    params: &LbParams,
    light: &Illumination,
    cell: f32,
) -> anyhow::Result<IndirectSolution> {
    let dims = GridDims { nx: OPEN, ny: OPEN, nz: OPEN };
    let empty = medium_from_leaf_area(&vec![0.0; OPEN * OPEN * OPEN], dims, cell);
    Ok(solve_indirect(solver, &empty, params, light, &SolveOptions::default(), &|_| {})?)
}

/// The indirect light that reaches the ground under a stand: the forest
/// grid's first layer above its shell, per channel.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct GroundLight {
    /// World x and z of the corner of node (0, ·, 0).
    pub origin: [f32; 2],
    /// Cell edge.
    pub cell: f32,
    /// Nodes along x.
    pub nx: usize,
    /// Nodes along z.
    pub nz: usize,
    /// Indirect irradiance on the ground (sky and scattered sun) per node:
    /// three channel planes of `nx × nz`, x fastest.
    pub rgb: Vec<f32>,
}

#[cfg(test)]
mod tests {
    use super::super::medium_of;
    use super::*;
    use sylva_light::lb::coarse::effective_area;
    use sylva_scene::parse;

    #[test]
    fn the_forest_grid_keeps_each_crowns_leaf_area_where_the_crown_is() {
        let text = r#"{
            "models": { "maple": { "tree": { "species": "red_maple", "triangles": 20000, "seed": 1 } } },
            "instances": [
                { "model": "maple", "position": [0, 0, 0] },
                { "model": "maple", "position": [9, 0, 3], "rotate_y_deg": 70, "scale": 1.5 }
            ],
            "camera": { "position": [0, 6, -30], "look_at": [0, 6, 0] },
            "sun": { "elevation_deg": 50, "azimuth_deg": 30 },
            "ground": { "color": [0.2, 0.2, 0.2] }
        }"#;
        let scene =
            Scene::build(parse(text, "forest.json").unwrap(), &std::env::temp_dir(), "forest.json")
                .unwrap();
        let m = &scene.models[0];
        let mm = medium_of(&scene, m, 32).unwrap();
        let area = mm.area.unwrap();
        // The model's own effective area (what its cells stop, spread
        // evenly) and its area-weighted mean height, in model space.
        let md = area.dims;
        let (mut model_total, mut model_height) = (0.0f64, 0.0f64);
        for z in 0..md.nz {
            for y in 0..md.ny {
                for x in 0..md.nx {
                    let i = md.index(x, y, z);
                    if area.area.area[i] > 0.0 {
                        let a = effective_area(area.area.density[i], area.frame.cell) as f64;
                        model_total += a;
                        model_height +=
                            a * (area.frame.origin[1] + (y as f32 + 0.5) * area.frame.cell) as f64;
                    }
                }
            }
        }
        model_height /= model_total;
        // Clumps stop less than their leaves' area spread evenly would.
        assert!(model_total < area.area.total_area, "{model_total} of {}", area.area.total_area);
        let boxes = scene
            .instances
            .iter()
            .map(|i| sylva_accel::two_level::model_bounds(&m.model).transformed(&i.to_world));
        let grid = WorldGrid::around(boxes.fold(Aabb::EMPTY, |b, o| b.union(o)), 16);
        let (cells, _) = forest_leaf_area(&scene, &[Some(&area)], &grid);
        // All of it arrives: the first instance's area plus 1.5² the second's.
        let total: f64 = cells.iter().map(|&a| a as f64).sum();
        let want = 1.0 + 1.5 * 1.5;
        let got = total / model_total;
        assert!((got - want).abs() < 1e-3 * want, "area {got:.4}× the model's, want {want}");
        // At the crowns' height: the area-weighted mean height is the
        // instances' (1 and 1.5 × the model's), within a forest cell.
        let d = grid.dims;
        let mut height = 0.0f64;
        for z in 0..d.nz {
            for y in 0..d.ny {
                for x in 0..d.nx {
                    height += cells[d.index(x, y, z)] as f64
                        * (grid.origin[1] + (y as f32 + 0.5) * grid.cell) as f64;
                }
            }
        }
        height /= total;
        let want_height = (model_height + 1.5 * 1.5 * 1.5 * model_height) / want;
        assert!(
            (height - want_height).abs() <= grid.cell as f64,
            "mean height {height:.2} m, the crowns' {want_height:.2} m (cell {:.2} m)",
            grid.cell
        );
        // Above the middle of the trees' boxes, where an even spread put it.
        let even: f64 = scene
            .instances
            .iter()
            .zip([1.0, 1.5 * 1.5])
            .map(|(i, w)| {
                let b = sylva_accel::two_level::model_bounds(&m.model).transformed(&i.to_world);
                w * 0.5 * (b.min.y + b.max.y) as f64
            })
            .sum::<f64>()
            / want;
        assert!(
            height > even + 0.5 * grid.cell as f64,
            "mean height {height:.2} m, an even spread's {even:.2} m"
        );
    }
}
