//! The strip renderer on the machine's real adapter: an analytic image,
//! determinism across strip splits, and holes in alpha-masked leaves.

use crate::common;

use common::{QUAD, TestMaterial, ctx, ray_queries, scratch, write_squares_gltf};
use std::path::Path;
use sylva_accel::AccelKind;
use sylva_scene::frame::Backend;
use sylva_scene::{LightingMode, Scene, parse};
use sylva_worker::prepare::prepare;
use sylva_worker::trace::RenderSettings;

/// A glTF file `quad.gltf` holding one opaque grey (0.5) square, 2 × 2 in
/// the plane z = 0, facing +z.
fn write_quad_gltf(dir: &Path) -> std::path::PathBuf {
    let m = TestMaterial { name: "bark", rgb: [0.5; 3], double_sided: false };
    write_squares_gltf(dir, "quad", m, &[QUAD])
}

#[test]
fn a_lit_quad_matches_the_shading_formula() {
    let dir = scratch("quad");
    write_quad_gltf(&dir);
    // Camera straight on; sun 60° from the quad's normal, off to the side so
    // the specular lobe (exponent 24) is negligible at the centre.
    let text = r#"{
        "models": { "quad": { "gltf": "quad.gltf" } },
        "instances": [ { "model": "quad", "position": [0, 0, 0], "scale": 1.5 } ],
        "camera": { "position": [0, 0, 10], "look_at": [0, 0, 0], "fov_y_deg": 30 },
        "sun": { "direction": [0.8660254, 0, 0.5], "intensity": 2.0 },
        "sky": { "zenith": [0, 0, 0], "horizon": [0, 0, 0] },
        "lighting": "local"
    }"#;
    let scene = Scene::build(parse(text, "quad.json").unwrap(), &dir, "quad.json").unwrap();
    let ctx = ctx();
    let mut kinds = vec![Backend::Bvh, Backend::Cwbvh, Backend::Kd];
    if ray_queries(&ctx) {
        kinds.push(Backend::Rq);
    }
    for kind in kinds {
        let p = prepare(&ctx, &scene, kind, LightingMode::Local, &|_| {}).unwrap();
        assert_eq!(Some(p.backend.backend), kind.resolved());
        let f = RenderSettings {
            width: 33,
            height: 33,
            spp: 1,
            seed: 1,
            lighting: LightingMode::Local,
            ambient: [0.0; 3],
            lb_strength: 0.0,
            view: Default::default(),
            gather_bounces: 1,
            gather_filter: 0,
            passes: Default::default(),
        };
        let s = p.renderer.render_strip(&ctx, &f, 0, 33).unwrap();
        let centre = s.pixels[16 * 33 + 16];
        // kd (N·L) + ks (V·R)^24 with V = +z, R = reflect(−L, N) = (−0.866, 0, 0.5).
        let n_dot_l = 0.5f32;
        let spec = 0.04 * 0.5f32.powi(24);
        for (c, (&got, &sun)) in centre.iter().zip(&scene.sun.radiance).enumerate() {
            let want = sun * (0.5 * n_dot_l + spec);
            assert!((got - want).abs() <= 1e-4 * want, "{kind:?} channel {c}: {got} vs {want}");
        }
        // Off the quad: the black sky.
        assert_eq!(s.pixels[0], [0.0; 3]);
        assert_eq!(s.coverage[16 * 33 + 16], 1.0);
        assert_eq!(s.rays.primary, 33 * 33);
    }
}

fn small_forest() -> Scene {
    let text = r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 20000, "seed": 1 } },
                    "beech": { "tree": { "species": "american_beech", "triangles": 20000, "seed": 2 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] },
                       { "model": "beech", "position": [12, 0, 6], "rotate_y_deg": 40, "scale": 0.8 } ],
        "camera": { "position": [4, 8, -28], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lb": { "grid": 16, "preset": "leaf" }
    }"#;
    Scene::build(parse(text, "f.json").unwrap(), Path::new("."), "f.json").unwrap()
}

#[test]
fn a_frame_is_bit_identical_however_it_is_split_and_repeated() {
    let ctx = ctx();
    let scene = small_forest();
    let p = prepare(&ctx, &scene, AccelKind::Bvh, LightingMode::Lb, &|_| {}).unwrap();
    let f = RenderSettings {
        width: 70,
        height: 40,
        spp: 3,
        seed: 7,
        lighting: LightingMode::Lb,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: Default::default(),
        gather_bounces: 1,
        gather_filter: 0,
        passes: Default::default(),
    };
    let whole = p.renderer.render_strip(&ctx, &f, 0, 70).unwrap();
    let again = p.renderer.render_strip(&ctx, &f, 0, 70).unwrap();
    assert_eq!(whole.pixels, again.pixels);
    let mut frame = sylva_scene::film::HdrImage::new(70, 40);
    for (x0, x1) in [(0, 23), (23, 24), (24, 70)] {
        let s = p.renderer.render_strip(&ctx, &f, x0, x1).unwrap();
        frame.paste_strip(x0, s.width, &s.pixels);
    }
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&frame.pixels), bits(&whole.pixels));
    // A different seed moves the samples.
    let other = p.renderer.render_strip(&ctx, &RenderSettings { seed: 8, ..f }, 0, 70).unwrap();
    assert_ne!(bits(&other.pixels), bits(&whole.pixels));
}

/// Every ray of the reference path tracer (camera, shadow, bounces through
/// alpha-cut leaves) through the device's structures: the frame the BVH
/// gives, but for the few pixels whose paths cross an edge or a texel line
/// on the other side (trace_gpu.rs measures those ties).
#[test]
fn ray_queries_render_the_frame_the_bvh_renders() {
    let ctx = ctx();
    if !ray_queries(&ctx) {
        return;
    }
    let scene = small_forest();
    let f = reference_frame();
    let frame = |kind: Backend| {
        let p = prepare(&ctx, &scene, kind, LightingMode::Reference, &|_| {}).unwrap();
        p.renderer.render_strip(&ctx, &f, 0, f.width).unwrap()
    };
    let (rq, bvh) = (frame(Backend::Rq), frame(Backend::Bvh));
    assert_eq!(rq.rays.primary, bvh.rays.primary);
    assert_eq!(rq.coverage, bvh.coverage, "the camera rays hit the same leaves");
    let differ = rq
        .pixels
        .iter()
        .zip(&bvh.pixels)
        .filter(|(a, b)| a.iter().zip(b.iter()).any(|(x, y)| (x - y).abs() > 1e-3 * y.max(1e-2)))
        .count();
    assert!(differ * 50 <= rq.pixels.len(), "{differ} of {} pixels differ", rq.pixels.len());
    let lit = bvh.coverage.iter().filter(|&&c| c > 0.0).count();
    assert!(lit > rq.pixels.len() / 20, "the trees cover {lit} pixels");
}

/// A small reference frame: camera, shadow and bounce rays through
/// alpha-cut leaves.
fn reference_frame() -> RenderSettings {
    RenderSettings {
        width: 48,
        height: 32,
        spp: 2,
        seed: 3,
        lighting: LightingMode::Reference,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: Default::default(),
        gather_bounces: 1,
        gather_filter: 0,
        passes: Default::default(),
    }
}

/// The reference path tracer's every ray (camera, shadow, bounces through
/// alpha-cut leaves) through the compressed wide BVH: the BVH's frame to
/// the bit, as both find the same hits with the same arithmetic.
#[test]
fn the_compressed_wide_bvh_renders_the_frame_the_bvh_renders() {
    let ctx = ctx();
    let scene = small_forest();
    let f = reference_frame();
    let frame = |kind: Backend| {
        let p = prepare(&ctx, &scene, kind, LightingMode::Reference, &|_| {}).unwrap();
        assert_eq!(p.backend.backend, kind);
        p.renderer.render_strip(&ctx, &f, 0, f.width).unwrap()
    };
    let (wide, bvh) = (frame(Backend::Cwbvh), frame(Backend::Bvh));
    assert_eq!(wide.rays.primary, bvh.rays.primary);
    let lit = bvh.coverage.iter().filter(|&&c| c > 0.0).count();
    assert!(lit > bvh.pixels.len() / 20, "the trees cover {lit} pixels");
    assert_eq!(wide.coverage, bvh.coverage);
    assert!(wide.pixels == bvh.pixels, "the frames differ");
}

#[test]
fn leaves_have_holes_where_their_texture_is_transparent() {
    let ctx = ctx();
    let scene = small_forest();
    let p = prepare(&ctx, &scene, AccelKind::Kd, LightingMode::Lb, &|_| {}).unwrap();
    let f = RenderSettings {
        width: 96,
        height: 64,
        spp: 1,
        seed: 1,
        lighting: LightingMode::Lb,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: Default::default(),
        gather_bounces: 1,
        gather_filter: 0,
        passes: Default::default(),
    };
    let s = p.renderer.render_strip(&ctx, &f, 0, 96).unwrap();
    assert!(s.rays.transparent > 100, "rays passed {} transparent texels", s.rays.transparent);
    let lit = s.coverage.iter().filter(|&&c| c > 0.0).count();
    assert!(lit > 96 * 64 / 30, "the trees cover {lit} pixels");
    assert!(s.pixels.iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
    assert!(p.light.iter().all(|l| l.grid == 16 && l.occupancy > 0.0));
}

#[test]
fn a_cloud_dims_what_lies_behind_it_and_glows_where_lit() {
    let ctx = ctx();
    let base = r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 4000, "seed": 1 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 30] } ],
        "camera": { "position": [0, 20, -40], "look_at": [0, 20, 0], "fov_y_deg": 40 },
        "sun": { "elevation_deg": 40, "azimuth_deg": 60 },
        "sky": { "zenith": [0.2, 0.4, 0.9], "horizon": [0.2, 0.4, 0.9] },
        "lb": { "grid": 8, "preset": "leaf" } CLOUDS
    }"#;
    let render = |clouds: &str| {
        let text = base.replace("CLOUDS", clouds);
        let scene =
            Scene::build(parse(&text, "c.json").unwrap(), Path::new("."), "c.json").unwrap();
        let p = prepare(&ctx, &scene, AccelKind::Bvh, LightingMode::Lb, &|_| {}).unwrap();
        let f = RenderSettings {
            width: 32,
            height: 32,
            spp: 1,
            seed: 1,
            lighting: LightingMode::Lb,
            ambient: [0.0; 3],
            lb_strength: 0.35,
            view: Default::default(),
            gather_bounces: 1,
            gather_filter: 0,
            passes: Default::default(),
        };
        p.renderer.render_strip(&ctx, &f, 0, 32).unwrap()
    };
    let clear = render("");
    let cloudy =
        render(r#", "clouds": [ { "center": [0, 20, 0], "size": 24, "grid": 24, "seed": 3 } ]"#);
    let centre = 16 * 32 + 16;
    // The cloud's heart hides the blue sky behind it and shows its own,
    // nearly white, scattered sunlight.
    let (sky, cloud) = (clear.pixels[centre], cloudy.pixels[centre]);
    assert!(cloud[2] / cloud[0] < 0.5 * sky[2] / sky[0], "cloud {cloud:?} vs sky {sky:?}");
    assert!(cloud.iter().all(|v| v.is_finite() && *v > sky[0]), "cloud {cloud:?} vs sky {sky:?}");
    // Corners miss the cloud and are untouched.
    assert_eq!(clear.pixels[0], cloudy.pixels[0]);
}

/// A sun sweep's next sun sends the device its light alone (no
/// voxelizing, no upload of the structures) and renders the frame that
/// a whole preparation under that sun renders, to the bit.
#[test]
fn a_new_sun_relights_the_uploaded_scene_and_renders_what_a_whole_upload_renders() {
    use sylva_scene::sequence::View;
    use sylva_worker::frame::{Fresh, Preparer};
    let ctx = ctx();
    let scene = small_forest();
    let sun = |s: [f32; 3]| View { camera: None, sun_towards: Some(s) };
    let (first, next) = (sun([0.3, 0.8, 0.2]), sun([-0.5, 0.5, 0.6]));
    let mut sweep = Fresh::default();
    let (bvh, lb) = (Backend::Bvh, LightingMode::Lb);
    let a = sweep.prepared(&ctx, &scene, bvh, lb, &first, &|_| {}).unwrap();
    let relit = sweep.prepared(&ctx, &scene, bvh, lb, &next, &|_| {}).unwrap();
    let names = |p: &sylva_worker::prepare::PreparedScene| {
        p.phases.0.iter().map(|p| p.name).collect::<Vec<_>>()
    };
    assert!(names(&a).contains(&"voxelize") && names(&a).contains(&"upload"), "{:?}", names(&a));
    let n = names(&relit);
    assert!(n.contains(&"relight") && n.contains(&"lb"), "{n:?}");
    assert!(!n.contains(&"upload") && !n.contains(&"voxelize") && !n.contains(&"build"), "{n:?}");
    let whole = Fresh::default().prepared(&ctx, &scene, bvh, lb, &next, &|_| {}).unwrap();
    assert!(names(&whole).contains(&"upload"));
    let f = RenderSettings {
        width: 64,
        height: 40,
        spp: 2,
        seed: 5,
        lighting: lb,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: next,
        gather_bounces: 1,
        gather_filter: 0,
        passes: Default::default(),
    };
    let (x, y) = (
        relit.renderer.render_strip(&ctx, &f, 0, 64).unwrap(),
        whole.renderer.render_strip(&ctx, &f, 0, 64).unwrap(),
    );
    assert!(x.pixels == y.pixels, "the relit frame differs from the whole upload's");
    let before = a.renderer.render_strip(&ctx, &f, 0, 64).unwrap();
    assert!(before.pixels != x.pixels, "the new sun's light changed nothing");
}
