//! The wgpu LB solver against the CPU reference, on the machine's real GPU
//! adapter (lavapipe in CI).

use sylva_shared::lb::verify::{compare_with_reference, random_medium};
use sylva_shared::lb::{CpuSolver, GridDims, LightingSolver, Preset, SolveOptions, Sun};
use sylva_worker::GpuSolver;

fn gpu() -> GpuSolver {
    GpuSolver::open().expect("these tests need a GPU adapter; on Debian install mesa-vulkan-drivers (lavapipe)")
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
    let params = Preset::Leaf.params();
    let sun = Sun::default();
    let opts = SolveOptions { tolerance: 1e-4, max_steps: Some(400), check_every: 8 };
    let mut gpu = gpu();
    let g = gpu.solve_channel(&medium, &params.channels[0], &sun.boundary(), &opts, &|_, _| {}).unwrap();
    let c = CpuSolver.solve_channel(&medium, &params.channels[0], &sun.boundary(), &opts, &|_, _| {}).unwrap();
    assert!(g.report.converged && c.report.converged, "{:?} {:?}", g.report, c.report);
    assert_eq!(g.report.steps, c.report.steps);
    assert!(g.report.steps < g.report.max_steps);
}

#[test]
fn vacuum_holds_exactly_the_boundary_light() {
    let dims = GridDims { nx: 10, ny: 13, nz: 7 };
    let medium = sylva_shared::lb::MediumGrid::empty(dims);
    let b = Sun::from_elevation_azimuth(35.0, 70.0, 2.0).unwrap().boundary();
    let opts = SolveOptions::fixed_steps(2 * dims.longest_edge());
    let s = gpu().solve_channel(&medium, &Preset::Leaf.params().channels[0], &b, &opts, &|_, _| {}).unwrap();
    let want: f32 = b.values.iter().sum();
    for (i, t) in s.total.iter().enumerate() {
        assert!((t - want).abs() <= 1e-6 * want, "node {i}: {t} vs {want}");
    }
}
