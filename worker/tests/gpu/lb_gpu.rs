//! The wgpu LB solver against the CPU reference, on the machine's real GPU
//! adapter (lavapipe in CI).

use sylva_light::lb::LbParams;
use sylva_light::lb::{CpuSolver, GridDims, LightingSolver, SolveOptions, Sun};
use sylva_light::studies::verify::{compare_with_reference, random_medium};
use sylva_scene::format::Preset;
use sylva_worker::GpuSolver;

fn gpu() -> GpuSolver {
    GpuSolver::open()
        .expect("these tests need a GPU adapter; on Debian install mesa-vulkan-drivers (lavapipe)")
}

fn assert_matches(dims: GridDims, steps: usize, seed: u64) {
    let diffs = compare_with_reference(&mut gpu(), dims, steps, seed).unwrap();
    for (c, d) in diffs.iter().enumerate() {
        assert!(*d <= 1e-4, "channel {c}: max relative difference {d:e} > 1e-4");
    }
}

#[test]
fn gpu_matches_cpu_reference_on_random_medium() {
    assert_matches(GridDims::cube(32), 64, 11);
}

#[test]
fn grid_larger_than_one_storage_binding_runs() {
    // 128³ × 19 f32 = 159 MB: more than lavapipe's 128 MiB per binding.
    assert_matches(GridDims::cube(128), 3, 5);
}

#[test]
fn gpu_stops_on_the_same_convergence_rule_as_cpu() {
    let dims = GridDims::cube(24);
    let medium = random_medium(dims, 3);
    let params = LbParams::from_preset(Preset::Leaf);
    let sun = Sun::default();
    let opts = SolveOptions { tolerance: 1e-4, max_steps: Some(400), check_every: 8 };
    let mut gpu = gpu();
    let g = gpu
        .solve_channel(&medium, &params.channels[0], &sun.boundary(), &opts, &|_, _| {})
        .unwrap();
    let c = CpuSolver
        .solve_channel(&medium, &params.channels[0], &sun.boundary(), &opts, &|_, _| {})
        .unwrap();
    assert!(g.report.converged && c.report.converged, "{:?} {:?}", g.report, c.report);
    assert_eq!(g.report.steps, c.report.steps);
    assert!(g.report.steps < g.report.max_steps);
}

#[test]
fn vacuum_holds_exactly_the_boundary_light() {
    let dims = GridDims { nx: 10, ny: 13, nz: 7 };
    let medium = sylva_light::lb::MediumGrid::empty(dims);
    let b = Sun::from_elevation_azimuth(35.0, 70.0, 2.0).unwrap().boundary();
    let opts = SolveOptions::fixed_steps(2 * dims.longest_edge());
    let s = gpu()
        .solve_channel(
            &medium,
            &LbParams::from_preset(Preset::Leaf).channels[0],
            &b,
            &opts,
            &|_, _| {},
        )
        .unwrap();
    let want: f32 = b.values.iter().sum();
    for (i, t) in s.total.iter().enumerate() {
        assert!((t - want).abs() <= 1e-6 * want, "node {i}: {t} vs {want}");
    }
}

/// Sun, a blue sky and a green-grey ground of albedo (0.3, 0.4, 0.2).
fn over_ground() -> sylva_light::lb::Illumination {
    sylva_light::lb::Illumination {
        sun: Sun::from_elevation_azimuth(40.0, 60.0, 1.0).unwrap(),
        sun_irradiance: [3.0, 2.8, 2.5],
        sky_zenith: [0.2, 0.3, 0.6],
        sky_horizon: [0.5, 0.5, 0.6],
        ground: Some([0.3, 0.4, 0.2]),
        floor_reflects: true,
    }
}

#[test]
fn a_reflecting_ground_matches_the_cpu_reference() {
    let dims = GridDims { nx: 18, ny: 14, nz: 16 };
    let medium = random_medium(dims, 7);
    let params = LbParams::from_preset(Preset::Leaf);
    let opts = SolveOptions::fixed_steps(40);
    let mut gpu = gpu();
    for (c, b) in over_ground().boundaries().iter().enumerate() {
        assert!(b.ground.is_some());
        let g = gpu.solve_channel(&medium, &params.channels[c], b, &opts, &|_, _| {}).unwrap();
        let want =
            CpuSolver.solve_channel(&medium, &params.channels[c], b, &opts, &|_, _| {}).unwrap();
        let d = sylva_light::studies::verify::max_relative_difference(&g.total, &want.total);
        assert!(d <= 1e-4, "channel {c}: max relative difference {d:e}");
    }
}

#[test]
fn vacuum_over_a_reflecting_ground_is_the_open_field() {
    // The ground under the lattice sends up exactly what the open ground
    // outside does, so an empty lattice holds the boundary's light everywhere.
    let dims = GridDims { nx: 9, ny: 11, nz: 8 };
    let medium = sylva_light::lb::MediumGrid::empty(dims);
    let opts = SolveOptions::fixed_steps(2 * dims.longest_edge());
    for (c, b) in over_ground().boundaries().iter().enumerate() {
        let want: f32 = b.values.iter().sum();
        for s in [
            gpu()
                .solve_channel(
                    &medium,
                    &LbParams::from_preset(Preset::Leaf).channels[c],
                    b,
                    &opts,
                    &|_, _| {},
                )
                .unwrap(),
            CpuSolver
                .solve_channel(
                    &medium,
                    &LbParams::from_preset(Preset::Leaf).channels[c],
                    b,
                    &opts,
                    &|_, _| {},
                )
                .unwrap(),
        ] {
            for (i, t) in s.total.iter().enumerate() {
                assert!((t - want).abs() <= 1e-5 * want, "channel {c}, node {i}: {t} vs {want}");
            }
        }
    }
}

#[test]
fn a_new_sun_on_a_kept_grid_compiles_and_uploads_nothing_and_solves_as_a_fresh_device() {
    let dims = GridDims { nx: 18, ny: 14, nz: 16 };
    let medium = random_medium(dims, 9);
    let params = LbParams::from_preset(Preset::Leaf);
    let opts = SolveOptions::default();
    let mut kept = gpu();
    let before = kept.made();
    for b in over_ground().boundaries() {
        kept.solve_channel(&medium, &params.channels[0], &b, &opts, &|_, _| {}).unwrap();
    }
    let first = kept.made();
    assert_eq!(first.uploaded - before.uploaded, 1, "one medium, uploaded once");
    assert_eq!(first.compiled - before.compiled, 1, "one collision, one ground: compiled once");
    // A new sun, every channel's own collision.
    let low = sylva_light::lb::Illumination {
        sun: Sun::from_elevation_azimuth(12.0, 200.0, 1.0).unwrap(),
        ..over_ground()
    };
    let mut fresh = gpu();
    for (c, b) in low.boundaries().iter().enumerate() {
        let again = kept.solve_channel(&medium, &params.channels[c], b, &opts, &|_, _| {}).unwrap();
        let new = fresh.solve_channel(&medium, &params.channels[c], b, &opts, &|_, _| {}).unwrap();
        assert_eq!(again.report.steps, new.report.steps, "channel {c}");
        assert!(again.total == new.total, "channel {c}: a kept grid solves as a fresh one");
    }
    let second = kept.made();
    assert_eq!(second.uploaded, first.uploaded, "the medium stays on the device");
    assert_eq!(second.compiled - first.compiled, 2, "green and blue's collisions; no sun compiled");
}

#[test]
fn solves_side_by_side_on_one_device_compile_each_kernel_once_and_match_solves_one_by_one() {
    // Two media, each solved for all three channels on two threads at
    // once (as a forest's species are on a GPU), against the same solves
    // one after another on a device of their own.
    let media = [
        random_medium(GridDims { nx: 14, ny: 12, nz: 10 }, 21),
        random_medium(GridDims::cube(12), 22),
    ];
    let params = LbParams::from_preset(Preset::Leaf);
    let b = Sun::default().boundary();
    let opts = SolveOptions::default();
    let solve_all = |solver: &mut GpuSolver, medium: &sylva_light::lb::MediumGrid| {
        params
            .channels
            .iter()
            .map(|p| solver.solve_channel(medium, p, &b, &opts, &|_, _| {}).unwrap())
            .collect::<Vec<_>>()
    };
    let shared = gpu().context().clone();
    let side_by_side: Vec<_> = std::thread::scope(|s| {
        let handles: Vec<_> = media
            .iter()
            .map(|m| {
                let ctx = shared.clone();
                let solve_all = &solve_all;
                s.spawn(move || solve_all(&mut GpuSolver::new(ctx), m))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut alone = gpu();
    for (m, together) in media.iter().zip(&side_by_side) {
        for (c, (a, t)) in solve_all(&mut alone, m).iter().zip(together).enumerate() {
            assert_eq!(a.report.steps, t.report.steps, "channel {c}");
            assert!(a.total == t.total, "channel {c}: the same light side by side as alone");
        }
    }
    let made = GpuSolver::new(shared).made();
    assert_eq!(made.compiled, 6, "two grids × three collisions, each compiled once");
    assert_eq!(made.uploaded, 2);
}
