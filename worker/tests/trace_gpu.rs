//! The GPU traversal kernel against the CPU reference traversal, for both
//! acceleration structures, on the machine's real adapter.

use glam::Vec3;
use sylva_accel::{Accel, AccelKind, KdNode, Ray, SceneAccel};
use sylva_scene::rng::SplitMix64;
use sylva_scene::{Scene, parse};
use sylva_worker::GpuContext;
use sylva_worker::trace::{GpuRay, GpuScene, RayCaster};

fn scene() -> Scene {
    let text = r#"{
        "models": {
            "maple": { "tree": { "species": "red_maple", "triangles": 30000, "seed": 4 } },
            "birch": { "tree": { "species": "paper_birch", "triangles": 12000, "seed": 5 } }
        },
        "instances": [ { "model": "maple", "position": [0, 0, 0] },
                       { "model": "birch", "position": [9, 0, 2], "rotate_y_deg": 70, "scale": 0.7 },
                       { "model": "maple", "position": [-8, 0, 5], "rotate_y_deg": -30, "scale": 1.3 },
                       { "model": "birch", "matrix": [0.8,0,0,0, 0,1.2,0,0, 0,0,0.8,0, 3,0,-9,1] } ],
        "camera": { "position": [0, 5, -30], "look_at": [0, 5, 0] },
        "sun": { "elevation_deg": 40, "azimuth_deg": 30 }
    }"#;
    Scene::build(parse(text, "t.json").unwrap(), std::path::Path::new("."), "t.json").unwrap()
}

/// Random rays into the trees, plus rays lying in the kd-trees' split planes.
fn rays(accel: &SceneAccel, n: usize) -> Vec<Ray> {
    let mut rng = SplitMix64::new(17);
    let mut out = Vec::with_capacity(n);
    let mut planes = Vec::new();
    for a in std::iter::once(&accel.top).chain(&accel.models) {
        if let Accel::Kd(k) = a {
            planes.extend(
                k.nodes
                    .iter()
                    .filter(|n| n.axis != KdNode::LEAF)
                    .map(|n| (n.axis as usize, n.split))
                    .take(2000),
            );
        }
    }
    while out.len() < n {
        let o = Vec3::new(rng.range(-20.0, 20.0), rng.range(0.0, 25.0), rng.range(-25.0, 25.0));
        let target =
            Vec3::new(rng.range(-10.0, 10.0), rng.range(1.0, 18.0), rng.range(-10.0, 10.0));
        let mut d = target - o;
        let mut o2 = o;
        if !planes.is_empty() && out.len() % 10 == 0 {
            // In a split plane (model or world space: both are exercised).
            let (axis, split) = planes[out.len() / 10 % planes.len()];
            o2[axis] = split;
            d[axis] = 0.0;
        }
        out.push(Ray::new(o2, d));
    }
    out
}

#[test]
fn gpu_traversal_matches_the_cpu_reference_for_both_structures() {
    let ctx = GpuContext::new()
        .expect("these tests need a GPU adapter; on Debian install mesa-vulkan-drivers (lavapipe)");
    let scene = scene();
    for kind in [AccelKind::Bvh, AccelKind::Kd] {
        let accel = SceneAccel::build(&scene, kind);
        let gpu_scene = GpuScene::upload(&ctx, &scene, &accel, &Default::default()).unwrap();
        let caster = RayCaster::new(&ctx, &gpu_scene).unwrap();
        let rays = rays(&accel, 100_000);
        let gpu_rays: Vec<GpuRay> = rays
            .iter()
            .map(|r| GpuRay {
                origin: r.origin.to_array(),
                t_min: 1e-4,
                dir: r.dir.to_array(),
                t_max: f32::MAX,
            })
            .collect();
        let hits = caster.cast(&ctx, &gpu_scene, &gpu_rays).unwrap();
        let (mut hit_count, mut transparent_passed, mut mismatches) = (0, 0, Vec::new());
        for (i, (r, g)) in rays.iter().zip(&hits).enumerate() {
            let c = accel.closest(&scene, r, 1e-4, f32::MAX);
            match c {
                None => {
                    if g.triangle != u32::MAX {
                        mismatches.push(format!("ray {i}: cpu miss, gpu {g:?}"));
                    }
                }
                Some(c) => {
                    hit_count += 1;
                    let global = gpu_scene.triangle_offsets
                        [scene.instances[c.instance as usize].model as usize]
                        + c.triangle;
                    let same = g.instance == c.instance
                        && g.triangle == global
                        && (g.t - c.t).abs() <= 1e-4 * c.t.max(1e-3);
                    if !same {
                        mismatches
                            .push(format!("ray {i}: cpu {c:?} (global tri {global}), gpu {g:?}"));
                    }
                    // Did this ray pass through a transparent texel before its hit?
                    let m = scene.instances[c.instance as usize].model as usize;
                    let local = Ray::new(
                        accel.to_model[c.instance as usize].transform_point3(r.origin),
                        accel.to_model[c.instance as usize].transform_vector3(r.dir),
                    );
                    let mut first = None;
                    accel.models[m].closest(&local, 1e-4, f32::MAX, &mut |t, lim| {
                        let [a, b, cc] = scene.models[m].model.triangle(t as usize);
                        let h = sylva_accel::triangle::intersect(&local, a, b, cc, 1e-4, lim)?;
                        first = Some(t);
                        Some(h.0)
                    });
                    transparent_passed += (first.is_some() && first != Some(c.triangle)) as usize;
                }
            }
        }
        // Shadow rays from every hit toward a sun: blocked or not, the same.
        let sun = Vec3::new(0.4, 0.8, 0.3);
        let shadow: Vec<Ray> = rays
            .iter()
            .zip(&hits)
            .filter(|(_, g)| g.triangle != u32::MAX)
            .map(|(r, g)| Ray::new(r.at(g.t), sun))
            .collect();
        let shadow_gpu: Vec<GpuRay> = shadow
            .iter()
            .map(|r| GpuRay {
                origin: r.origin.to_array(),
                t_min: 1e-3,
                dir: r.dir.to_array(),
                t_max: f32::MAX,
            })
            .collect();
        let blocked = RayCaster::shadow(&ctx, &gpu_scene)
            .unwrap()
            .cast(&ctx, &gpu_scene, &shadow_gpu)
            .unwrap();
        let mut shadow_mismatches = 0;
        let mut blocked_count = 0;
        for (r, b) in shadow.iter().zip(&blocked) {
            let cpu = accel.occluded(&scene, r, 1e-3, f32::MAX);
            blocked_count += cpu as usize;
            shadow_mismatches += (cpu != (b.triangle != u32::MAX)) as usize;
            // Occlusion is whether a closest hit exists.
            assert_eq!(cpu, accel.closest(&scene, r, 1e-3, f32::MAX).is_some(), "{kind:?} {r:?}");
        }
        assert!(
            blocked_count > shadow.len() / 10 && blocked_count < shadow.len(),
            "{kind:?}: {blocked_count} of {} blocked",
            shadow.len()
        );
        assert_eq!(shadow_mismatches, 0, "{kind:?}: shadow rays differ");
        assert!(hit_count > 20_000, "{kind:?}: only {hit_count} hits");
        assert!(
            transparent_passed > 100,
            "{kind:?}: only {transparent_passed} rays crossed a transparent texel"
        );
        assert!(
            mismatches.is_empty(),
            "{kind:?}: {} of {} rays differ, e.g.\n{}",
            mismatches.len(),
            rays.len(),
            mismatches.iter().take(8).cloned().collect::<Vec<_>>().join("\n")
        );
    }
}
