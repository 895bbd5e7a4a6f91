//! The reference integrator and the Boulanger et al. shading on the real
//! adapter, against what they must equal: the local image when nothing
//! bounces, their own 1/√spp convergence, and the CPU evaluation of the
//! Boulanger terms.

use std::path::Path;
use sylva_shared::accel::AccelKind;
use sylva_shared::color::luminance;
use sylva_shared::scene::{LightingMode, Scene, parse};
use sylva_worker::GpuContext;
use sylva_worker::prepare::prepare;
use sylva_worker::trace::{ReferenceOptions, RenderSettings, render_reference};

fn ctx() -> GpuContext {
    GpuContext::new().expect("these tests need a GPU adapter; on Debian install mesa-vulkan-drivers (lavapipe)")
}

/// A glTF file holding one square of material `material` (grey 0.5), 2 × 2
/// in the plane z = 0, facing +z.
fn write_quad_gltf(dir: &Path, material: &str) {
    let positions: [f32; 12] = [-1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 1.0, 1.0, 0.0, -1.0, 1.0, 0.0];
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut bytes: Vec<u8> = positions.iter().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    std::fs::write(dir.join("quad.bin"), &bytes).unwrap();
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}}]}}],
        "materials":[{{"name":"{material}","doubleSided":true,"pbrMetallicRoughness":{{"baseColorFactor":[0.5,0.5,0.5,1]}}}}],
        "buffers":[{{"byteLength":{},"uri":"quad.bin"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":12}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[-1,-1,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}}]}}"#,
        bytes.len()
    );
    std::fs::write(dir.join("quad.gltf"), gltf).unwrap();
}

fn quad_scene(name: &str, material: &str, sky: &str, ground: &str) -> Scene {
    let dir = std::env::temp_dir().join(format!("sylva-lighting-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_quad_gltf(&dir, material);
    let text = format!(
        r#"{{
        "models": {{ "quad": {{ "gltf": "quad.gltf" }} }},
        "instances": [ {{ "model": "quad", "position": [0, 1.6, 0], "scale": 1.5 }} ],
        "camera": {{ "position": [0, 1.6, 10], "look_at": [0, 1.6, 0], "fov_y_deg": 30 }},
        "sun": {{ "direction": [0.8660254, 0.2, 0.5], "intensity": 2.0 }},
        "sky": {sky}{ground}
    }}"#
    );
    Scene::build(parse(&text, "quad.json").unwrap(), &dir, "quad.json").unwrap()
}

fn frame(w: u32, h: u32) -> RenderSettings {
    RenderSettings { width: w, height: h, spp: 1, seed: 1, lighting: LightingMode::Local, ambient: [0.0; 3], lb_strength: 0.35 }
}

#[test]
fn with_nothing_to_bounce_off_the_reference_is_the_local_image() {
    // A wooden square under a black sky with no ground: every path ends
    // after the sun's next-event estimate at the first hit.
    let scene = quad_scene("direct", "bark", r#"{ "zenith": [0, 0, 0], "horizon": [0, 0, 0] }"#, "");
    let ctx = ctx();
    let p = prepare(&ctx, &scene, AccelKind::Bvh, LightingMode::Reference, &|_| {}).unwrap();
    let local = p.renderer.render_strip(&ctx, &frame(17, 17), 0, 17).unwrap();
    let opts = ReferenceOptions { batch_spp: 2, min_batches: 2, max_batches: 2, ..Default::default() };
    let r = render_reference(&ctx, &p.renderer, &frame(17, 17), &opts, &|_| {}).unwrap();
    let (want, got) = (local.pixels[8 * 17 + 8], r.image.pixels[8 * 17 + 8]);
    assert!(want[0] > 0.1, "the square is lit: {want:?}");
    for c in 0..3 {
        assert!((got[c] - want[c]).abs() <= 1e-4 * want[c], "channel {c}: reference {} vs local {}", got[c], want[c]);
    }
    // Only the pixel jitter at the square's edges is random here.
    assert_eq!(r.std_error[8 * 17 + 8], 0.0, "nothing random reaches the centre pixel");
}

#[test]
fn the_reference_error_falls_as_one_over_root_spp_and_it_says_so() {
    // A leaf square over a ground under a blue sky: sky light, transmission
    // and bounces between leaf and ground, all random.
    let scene = quad_scene(
        "converge",
        "leaf",
        r#"{ "zenith": [0.2, 0.3, 0.6], "horizon": [0.5, 0.5, 0.5] }"#,
        r#", "ground": { "color": [0.3, 0.25, 0.2] }"#,
    );
    let ctx = ctx();
    let p = prepare(&ctx, &scene, AccelKind::Bvh, LightingMode::Reference, &|_| {}).unwrap();
    let f = frame(24, 24);
    let run = |seed: u32, batches: u32| {
        let opts = ReferenceOptions { batch_spp: 4, min_batches: batches, max_batches: batches, target_error: 1e-9, ..Default::default() };
        render_reference(&ctx, &p.renderer, &RenderSettings { seed, ..f }, &opts, &|_| {}).unwrap()
    };
    let truth = run(1_000_000, 256);
    let rmse = |img: &sylva_worker::trace::ReferenceImage| -> f64 {
        let se: f64 = img.image.pixels.iter().zip(&truth.image.pixels).map(|(a, b)| ((luminance(*a) - luminance(*b)) as f64).powi(2)).sum();
        (se / img.image.pixels.len() as f64).sqrt()
    };
    let (coarse, fine) = (run(7, 4), run(9_000_000, 16));
    let (e4, e16) = (rmse(&coarse), rmse(&fine));
    // Four times the samples: half the error (the truth's own noise, 1/8 of
    // the coarse run's, and sampling of the error itself leave ±25 %).
    let ratio = e4 / e16;
    assert!((1.5..=2.6).contains(&ratio), "error ratio {ratio:.3} for 4× the samples (errors {e4:.5}, {e16:.5})");
    // The image's own estimate of its error tracks the measured one.
    let own = coarse.std_error.iter().map(|s| (*s as f64).powi(2)).sum::<f64>() / coarse.std_error.len() as f64;
    let own = own.sqrt();
    assert!(own > 0.5 * e4 && own < 2.0 * e4, "own estimate {own:.5} vs measured {e4:.5}");
    assert!(fine.stats.relative_error < coarse.stats.relative_error * 0.7, "{:?} vs {:?}", fine.stats, coarse.stats);
}

#[test]
fn boulanger_shading_on_the_gpu_matches_its_cpu_reference() {
    let scene = quad_scene(
        "boulanger",
        "leaf",
        r#"{ "zenith": [0.2, 0.3, 0.6], "horizon": [0.5, 0.5, 0.5] }"#,
        r#", "ground": { "color": [0.3, 0.25, 0.2] }"#,
    );
    let ctx = ctx();
    let p = prepare(&ctx, &scene, AccelKind::Bvh, LightingMode::Boulanger, &|_| {}).unwrap();
    assert_eq!(p.boulanger.len(), 1);
    let s = p.renderer.render_strip(&ctx, &RenderSettings { lighting: LightingMode::Boulanger, ..frame(17, 17) }, 0, 17).unwrap();
    let got = s.pixels[8 * 17 + 8];

    use glam::Vec3;
    use sylva_shared::boulanger::{precompute, shade, sky_radiance_per_direction, sun_terms};
    let model = &scene.models[0].model;
    let env = precompute(model);
    let terms = sun_terms(&env, scene.sun.towards);
    let sky = |d: Vec3| Vec3::from(scene.sky.horizon).lerp(Vec3::from(scene.sky.zenith), d.y.max(0.0).sqrt()).to_array();
    let per_dir = sky_radiance_per_direction(sky, scene.ground.as_ref().unwrap().color);
    let albedo = [0.5f32; 3];
    for c in 0..3 {
        let coeffs = scene.file.leaf_optics.coefficients(albedo, c);
        let sky_c: [f32; 8] = std::array::from_fn(|j| per_dir[j][c]);
        let e_sun = std::f32::consts::PI * scene.sun.radiance[c];
        let (lo_sky, lo_sun, lo_ind) = shade(&env, &terms, 0, Vec3::Z, Vec3::Z, coeffs, e_sun, &sky_c);
        // The highlight the direct methods add (ks 0.12 for leaves), dimmed like the sun.
        let r = (-scene.sun.towards).reflect(Vec3::Z);
        let depth = env.tau * (0..8).map(|j| terms.weights[j] * env.s_max[0][j]).sum::<f32>();
        let highlight = 0.12 * r.dot(Vec3::Z).max(0.0).powi(24) * (-depth).exp() * scene.sun.radiance[c];
        let want = lo_sky + lo_sun + lo_ind + highlight;
        assert!(lo_sky > 0.0 && lo_sun > 0.0, "both direct terms light the square");
        assert!((got[c] - want).abs() <= 1e-3 * want, "channel {c}: GPU {} vs CPU {want} (sky {lo_sky}, sun {lo_sun}, indirect {lo_ind})", got[c]);
    }
}
