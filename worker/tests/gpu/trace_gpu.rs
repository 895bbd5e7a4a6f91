//! The GPU traversal against the CPU reference traversal, for every
//! backend (both structures the compute kernel walks, and ray queries),
//! on the machine's real adapter.

use glam::Vec3;
use sylva_accel::cwbvh::CwbvhScene;
use sylva_accel::{Accel, AccelKind, KdNode, Ray, SceneAccel};
use sylva_scene::rng::SplitMix64;
use sylva_scene::{Scene, parse};
use sylva_worker::GpuContext;
use sylva_worker::trace::{GpuRay, GpuScene, RayCaster, SceneStructure};

use crate::common;

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
        let gpu_scene =
            GpuScene::upload(&ctx, &scene, SceneStructure::Walk(&accel), &Default::default())
                .unwrap();
        // The walk's arithmetic is the CPU's.
        let cpu = Cpu::Walk(&accel);
        check_against_cpu(&ctx, &scene, &gpu_scene, &accel, cpu, &format!("{kind:?}"), true);
    }
}

/// The eight-wide compressed BVH's walk (stack in workgroup memory,
/// children by octant) against its CPU twin, which visits in the same
/// order: the same hits, ties included.
#[test]
fn compressed_wide_bvh_traversal_matches_its_cpu_reference() {
    let ctx = common::ctx();
    let scene = scene();
    let accel = SceneAccel::build(&scene, AccelKind::Bvh);
    let wide = CwbvhScene::from_accel(&scene, &accel).unwrap();
    let gpu_scene =
        GpuScene::upload(&ctx, &scene, SceneStructure::Cwbvh(&accel), &Default::default()).unwrap();
    check_against_cpu(&ctx, &scene, &gpu_scene, &accel, Cpu::Wide(&wide), "cwbvh", true);
}

/// A CPU traversal the GPU's is checked against.
#[derive(Clone, Copy)]
enum Cpu<'a> {
    /// The kd-tree's or the four-wide BVH's.
    Walk(&'a SceneAccel),
    /// The eight-wide compressed BVH's.
    Wide(&'a CwbvhScene),
}

impl Cpu<'_> {
    fn closest(
        self,
        scene: &Scene,
        r: &Ray,
        t_min: f32,
        t_max: f32,
    ) -> Option<sylva_accel::SceneHit> {
        match self {
            Cpu::Walk(a) => a.closest(scene, r, t_min, t_max),
            Cpu::Wide(w) => w.closest(scene, r, t_min, t_max),
        }
    }

    fn occluded(self, scene: &Scene, r: &Ray, t_min: f32, t_max: f32) -> bool {
        match self {
            Cpu::Walk(a) => a.occluded(scene, r, t_min, t_max),
            Cpu::Wide(w) => w.occluded(scene, r, t_min, t_max),
        }
    }
}

/// The ray-query backend: the device's structures over the same scene
/// (alpha-cut leaves confirmed by the shader) give the CPU's hits.
#[test]
fn ray_query_traversal_matches_the_cpu_reference() {
    let ctx = common::ctx();
    if !common::ray_queries(&ctx) {
        return;
    }
    let scene = scene();
    let accel = SceneAccel::build(&scene, AccelKind::Bvh);
    let coverage: Vec<_> =
        scene.models.iter().map(|m| sylva_accel::coverage::triangle_coverage(&m.model)).collect();
    let gpu_scene =
        GpuScene::upload(&ctx, &scene, SceneStructure::RayQuery(&coverage), &Default::default())
            .unwrap();
    let rq = gpu_scene.rq.as_ref().expect("the device's structures");
    assert!(rq.triangles > 0);
    // The device transforms rays into model space with its own inverse of
    // each instance's matrix and tests triangles its own (watertight) way:
    // the same triangles, t to float precision of the transforms.
    check_against_cpu(&ctx, &scene, &gpu_scene, &accel, Cpu::Walk(&accel), "ray queries", false);
}

/// Closest hits and shadow rays of `gpu_scene` against the CPU's `cpu`
/// (`accel` the scene's structures, for the rays and statistics) on random rays through the trees (alpha-cut leaves among them): the
/// same instance and triangle, `t` to 1e-4 (relative). Unless `exact` (the
/// walk, whose arithmetic is the CPU's): `t` to 1e-3, and a ray through an
/// edge or a texel line may take either side of it, in at most one ray in
/// 5,000.
fn check_against_cpu(
    ctx: &GpuContext,
    scene: &Scene,
    gpu_scene: &GpuScene,
    accel: &SceneAccel,
    cpu: Cpu,
    kind: &str,
    exact: bool,
) {
    {
        let caster = RayCaster::new(ctx, gpu_scene).unwrap();
        let rays = rays(accel, 100_000);
        let gpu_rays: Vec<GpuRay> = rays
            .iter()
            .map(|r| GpuRay {
                origin: r.origin.to_array(),
                t_min: 1e-4,
                dir: r.dir.to_array(),
                t_max: f32::MAX,
            })
            .collect();
        let hits = caster.cast(ctx, gpu_scene, &gpu_rays).unwrap();
        let (mut hit_count, mut transparent_passed, mut mismatches) = (0, 0, Vec::new());
        let (mut worst_dt, mut ties) = (0f32, 0);
        let t_tol = if exact { 1e-4 } else { 1e-3 };
        for (i, (r, g)) in rays.iter().zip(&hits).enumerate() {
            let c = cpu.closest(scene, r, 1e-4, f32::MAX);
            // The GPU's hit as (instance, model-local triangle), if any.
            let g_local = (g.triangle != u32::MAX).then(|| {
                let m = scene.instances[g.instance as usize].model as usize;
                (g.instance, g.triangle - gpu_scene.triangle_offsets[m])
            });
            // Where the two arithmetics may rightly disagree (never for the
            // walk, whose arithmetic is the CPU's): a ray through an edge
            // hits both triangles sharing it at one t, or a leaf's rim, or
            // neither (Möller–Trumbore is not watertight; u = -0.0 is
            // inside for it, outside for a watertight test); a hit on the
            // line between an opaque and a cut texel is either.
            let on_edge = |u: f32, v: f32| u.min(v).min(1.0 - u - v) < 1e-3;
            let texel_line = |inst: u32, tri: u32, u: f32, v: f32| {
                near_texel_line(scene, scene.instances[inst as usize].model as usize, tri, u, v)
            };
            let tie = |c: Option<&sylva_accel::SceneHit>| {
                !exact
                    && (c.is_some_and(|c| {
                        on_edge(c.u, c.v) || texel_line(c.instance, c.triangle, c.u, c.v)
                    }) || g_local.is_some_and(|(inst, tri)| {
                        c.is_none_or(|c| g.t <= c.t * (1.0 + t_tol))
                            && (on_edge(g.u, g.v) || texel_line(inst, tri, g.u, g.v))
                    }))
            };
            match c {
                None => {
                    if g.triangle != u32::MAX {
                        if tie(None) {
                            ties += 1;
                        } else {
                            mismatches.push(format!("ray {i}: cpu miss, gpu {g:?}"));
                        }
                    }
                }
                Some(c) => {
                    hit_count += 1;
                    let global = gpu_scene.triangle_offsets
                        [scene.instances[c.instance as usize].model as usize]
                        + c.triangle;
                    let dt = (g.t - c.t).abs() / c.t.max(1e-3);
                    let same = g.instance == c.instance && g.triangle == global && dt <= t_tol;
                    if same {
                        worst_dt = worst_dt.max(dt);
                    } else if tie(Some(&c)) {
                        ties += 1;
                    } else {
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
        let blocked =
            RayCaster::shadow(ctx, gpu_scene).unwrap().cast(ctx, gpu_scene, &shadow_gpu).unwrap();
        // Where the two disagree, the closest hits say why.
        let gpu_closest = caster.cast(ctx, gpu_scene, &shadow_gpu).unwrap();
        let (mut shadow_mismatches, mut grazing) = (Vec::new(), 0);
        let mut blocked_count = 0;
        for ((r, b), g) in shadow.iter().zip(&blocked).zip(&gpu_closest) {
            let blocked_cpu = cpu.occluded(scene, r, 1e-3, f32::MAX);
            blocked_count += blocked_cpu as usize;
            // Occlusion is whether a closest hit exists.
            let c = cpu.closest(scene, r, 1e-3, f32::MAX);
            assert_eq!(blocked_cpu, c.is_some(), "{kind} {r:?}");
            if blocked_cpu != (b.triangle != u32::MAX) {
                // A ray leaving the surface it starts on at a grazing angle
                // meets it again about t_min away, where the device's
                // intersection test and Möller–Trumbore round differently:
                // self-intersection, not traversal. Only the device's
                // watertight test can differ so (the walk's arithmetic is
                // the CPU's).
                let t = c.map_or(g.t, |c| c.t.min(g.t));
                if !exact && t < 2e-3 {
                    grazing += 1;
                } else {
                    shadow_mismatches.push(format!("{r:?}: cpu {c:?}, gpu closest {g:?}"));
                }
            }
        }
        assert!(
            grazing * 5000 <= shadow.len(),
            "{kind}: {grazing} of {} shadow rays differ at their start",
            shadow.len()
        );
        assert!(
            blocked_count > shadow.len() / 10 && blocked_count < shadow.len(),
            "{kind}: {blocked_count} of {} blocked",
            shadow.len()
        );
        assert!(
            shadow_mismatches.is_empty(),
            "{kind}: {} of {} shadow rays differ, e.g.\n{}",
            shadow_mismatches.len(),
            shadow.len(),
            shadow_mismatches.iter().take(8).cloned().collect::<Vec<_>>().join("\n")
        );
        assert!(hit_count > 20_000, "{kind}: only {hit_count} hits");
        eprintln!(
            "{kind}: {hit_count} hits, {ties} ties on an edge or a texel line, \
             largest relative difference in t {worst_dt:e}; {grazing} shadow rays grazing their start"
        );
        assert!(ties * 5000 <= rays.len(), "{kind}: {ties} ties");
        assert!(
            transparent_passed > 100,
            "{kind}: only {transparent_passed} rays crossed a transparent texel"
        );
        assert!(
            mismatches.is_empty(),
            "{kind}: {} of {} rays differ, e.g.\n{}",
            mismatches.len(),
            rays.len(),
            mismatches.iter().take(8).cloned().collect::<Vec<_>>().join("\n")
        );
    }
}

/// Whether barycentrics (u, v) of a model's triangle fall within a
/// hundredth of a texel of a line between texels of its texture (where
/// the alpha test may go either way).
fn near_texel_line(scene: &Scene, model: usize, tri: u32, u: f32, v: f32) -> bool {
    let m = &scene.models[model].model;
    let Some(t) = m.materials[m.material[tri as usize] as usize].texture else {
        return false;
    };
    let tex = &m.textures[t as usize];
    let uv = sylva_accel::two_level::uv_at(m, tri, u, v);
    let off = |x: f32, n: u32| {
        let p = x * n as f32;
        (p - p.round()).abs() < 0.01
    };
    off(uv.x, tex.width) || off(uv.y, tex.height)
}
