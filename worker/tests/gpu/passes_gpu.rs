//! Render passes on the real adapter: the light split sums to the image
//! for every lighting method without changing it, each part is what its
//! closed form says, and the guides name what each pixel sees.

use crate::common;

use common::{QUAD, TestMaterial, ctx, scratch, write_squares_gltf};
use glam::Vec3;
use std::path::Path;
use sylva_accel::AccelKind;
use sylva_scene::passes::{NO_DEPTH, Pass, PassImage, PassSet};
use sylva_scene::{LightingMode, Scene, parse};
use sylva_worker::prepare::prepare;
use sylva_worker::trace::{RenderSettings, RenderedStrip, Tracer};

fn settings(w: u32, h: u32, spp: u32, lighting: LightingMode) -> RenderSettings {
    RenderSettings {
        width: w,
        height: h,
        spp,
        seed: 5,
        lighting,
        ambient: [0.0; 3],
        lb_strength: 0.35,
        view: Default::default(),
        gather_bounces: 1,
        gather_filter: 0,
        passes: PassSet::NONE,
    }
}

/// Two generated trees over a ground, under a sky; with `cloud`, a cloud
/// in front of one (the clouds' light and what they let through).
fn forest(cloud: bool) -> Scene {
    let clouds = if cloud {
        r#", "clouds": [ { "center": [-3, 9, -6], "size": 8, "grid": 12, "seed": 3 } ]"#
    } else {
        ""
    };
    let text = format!(
        r#"{{
        "models": {{ "maple": {{ "tree": {{ "species": "red_maple", "triangles": 6000, "seed": 1 }} }},
                    "beech": {{ "tree": {{ "species": "american_beech", "triangles": 6000, "seed": 2 }} }} }},
        "instances": [ {{ "model": "maple", "position": [0, 0, 0] }},
                       {{ "model": "beech", "position": [10, 0, 6], "rotate_y_deg": 40, "scale": 0.8 }} ],
        "camera": {{ "position": [4, 8, -28], "look_at": [4, 7, 0], "fov_y_deg": 45 }},
        "sun": {{ "elevation_deg": 50, "azimuth_deg": 120 }},
        "sky": {{ "zenith": [0.2, 0.35, 0.8], "horizon": [0.6, 0.7, 0.8] }},
        "ground": {{ "color": [0.1, 0.08, 0.05] }},
        "lb": {{ "grid": 12, "preset": "leaf" }}{clouds}
    }}"#
    );
    Scene::build(parse(&text, "f.json").unwrap(), Path::new("."), "f.json").unwrap()
}

fn plane(s: &RenderedStrip, p: Pass) -> &[f32] {
    s.passes.as_ref().expect("passes asked for").plane(p).expect("the pass asked for")
}

fn bits(v: &[[f32; 3]]) -> Vec<u32> {
    v.iter().flatten().map(|x| x.to_bits()).collect()
}

/// Renders `f` with every pass and without: checks the beauty is the same
/// to the bit, and that direct + indirect + sky is the beauty to float
/// precision. Returns the render with passes.
fn split_checked(
    ctx: &sylva_worker::trace::Tracer,
    scene: &Scene,
    f: RenderSettings,
) -> RenderedStrip {
    let p = prepare(ctx, scene, AccelKind::Bvh, f.lighting, &|_| {}).unwrap();
    let plain = p.renderer.render_strip(ctx, &f, 0, f.width).unwrap();
    let with = RenderSettings { passes: PassSet::all(), ..f };
    let s = p.renderer.render_strip(ctx, &with, 0, f.width).unwrap();
    assert_eq!(bits(&s.pixels), bits(&plain.pixels), "{:?}: passes changed the image", f.lighting);
    assert!(plain.passes.is_none());
    let (d, i, k) = (plane(&s, Pass::Direct), plane(&s, Pass::Indirect), plane(&s, Pass::Sky));
    let mut worst = 0.0f32;
    for (n, px) in s.pixels.iter().enumerate() {
        for c in 0..3 {
            let sum = d[3 * n + c] + i[3 * n + c] + k[3 * n + c];
            worst = worst.max((sum - px[c]).abs() / px[c].abs().max(1e-3));
        }
    }
    assert!(worst <= 2e-6, "{:?}: direct + indirect + sky is off the image by {worst}", f.lighting);
    s
}

#[test]
fn the_light_split_sums_to_the_image_for_every_method_and_each_part_is_its_own() {
    let ctx = ctx();
    let scene = forest(false);
    let (w, h) = (48, 32);
    let local = split_checked(&ctx, &scene, settings(w, h, 1, LightingMode::Local));
    let lb = split_checked(&ctx, &scene, settings(w, h, 1, LightingMode::Lb));
    let ambient = split_checked(
        &ctx,
        &scene,
        RenderSettings { ambient: [0.2, 0.25, 0.3], ..settings(w, h, 1, LightingMode::Ambient) },
    );
    split_checked(&ctx, &scene, settings(w, h, 1, LightingMode::Boulanger));
    let reference = split_checked(&ctx, &scene, settings(w, h, 4, LightingMode::Reference));
    split_checked(&ctx, &scene, settings(w, h, 2, LightingMode::Gather));

    // Every method's direct light is the sun's, traced alike: `lb`'s is
    // `local`'s to the bit; and `local` adds nothing on the trees.
    assert_eq!(plane(&lb, Pass::Direct), plane(&local, Pass::Direct));
    let on_trees: Vec<usize> =
        (0..(w * h) as usize).filter(|&n| local.coverage[n] == 1.0).collect();
    assert!(on_trees.len() > 50, "the trees fill {} pixels", on_trees.len());
    for &n in &on_trees {
        assert_eq!(&plane(&local, Pass::Indirect)[3 * n..3 * n + 3], &[0.0; 3]);
        assert_eq!(&plane(&local, Pass::Sky)[3 * n..3 * n + 3], &[0.0; 3]);
    }
    // `ambient`'s indirect light is the albedo pass times its constant.
    let (albedo, ind) = (plane(&ambient, Pass::Albedo), plane(&ambient, Pass::Indirect));
    for &n in &on_trees {
        for (c, k) in [0.2f32, 0.25, 0.3].iter().enumerate() {
            let want = albedo[3 * n + c] * k;
            assert!((ind[3 * n + c] - want).abs() <= 1e-6 * want.max(1e-3), "pixel {n}");
        }
    }
    // The reference's direct light is `local`'s along the same camera
    // samples: its paths' first sun estimate, with the same shadow rays.
    let local4 = split_checked(&ctx, &scene, settings(w, h, 4, LightingMode::Local));
    let (rd, ld) = (plane(&reference, Pass::Direct), plane(&local4, Pass::Direct));
    for n in 0..rd.len() {
        assert!(
            (rd[n] - ld[n]).abs() <= 1e-4 * ld[n].max(1e-2),
            "value {n}: {} vs {}",
            rd[n],
            ld[n]
        );
    }
    // And the sky seen is the sky: the same in every method.
    assert_eq!(plane(&reference, Pass::Sky).len(), plane(&local4, Pass::Sky).len());
    let (rs, ls) = (plane(&reference, Pass::Sky), plane(&local4, Pass::Sky));
    assert!(rs.iter().zip(ls).all(|(a, b)| (a - b).abs() <= 1e-5 * b.max(1e-2)));
    assert!(ls.iter().any(|&v| v > 0.1), "the frame shows some sky");
}

#[test]
fn through_a_cloud_the_split_still_sums_to_the_image() {
    let ctx = ctx();
    let scene = forest(true);
    let lb = split_checked(&ctx, &scene, settings(40, 28, 1, LightingMode::Lb));
    split_checked(&ctx, &scene, settings(40, 28, 4, LightingMode::Reference));
    // The cloud's own light is indirect: where it hides the sky, the
    // indirect pass glows over the sky pass.
    let (i, k) = (plane(&lb, Pass::Indirect), plane(&lb, Pass::Sky));
    assert!((0..i.len() / 3).any(|n| lb.coverage[n] == 0.0 && i[3 * n] > 0.05 && k[3 * n] < 0.5));
}

#[test]
fn ids_depth_normals_and_albedo_name_what_each_pixel_sees() {
    let ctx = ctx();
    let dir = scratch("passes-ids");
    let bark = |rgb| TestMaterial { name: "bark", rgb, double_sided: true };
    write_squares_gltf(&dir, "a", bark([0.5, 0.4, 0.3]), &[QUAD]);
    write_squares_gltf(&dir, "b", bark([0.2, 0.6, 0.1]), &[QUAD]);
    // Instance 1 is a `b` on the left, 2 an `a` on the right, 3 an `a`
    // behind the camera; sorted, `a` is model 1 and `b` model 2.
    let text = r#"{
        "models": { "b": { "gltf": "b.gltf" }, "a": { "gltf": "a.gltf" } },
        "instances": [ { "model": "b", "position": [-1.5, 0, 0] },
                       { "model": "a", "position": [1.5, 0, -2] },
                       { "model": "a", "position": [0, 0, 20] } ],
        "camera": { "position": [0, 0, 10], "look_at": [0, 0, 0], "fov_y_deg": 30 },
        "sun": { "direction": [0.3, 0.5, 0.8] },
        "sky": { "zenith": [0.1, 0.2, 0.4], "horizon": [0.1, 0.2, 0.4] }
    }"#;
    let scene = Scene::build(parse(text, "ids.json").unwrap(), &dir, "ids.json").unwrap();
    // Both kernel families: the direct methods' sum their samples' guides
    // in the kernel, the path tracer's write a normal per sample.
    for (lighting, spp) in [(LightingMode::Local, 70), (LightingMode::Reference, 3)] {
        guides_name_what_each_pixel_sees(&ctx, &scene, lighting, spp);
    }
}

fn guides_name_what_each_pixel_sees(ctx: &Tracer, scene: &Scene, lighting: LightingMode, spp: u32) {
    let p = prepare(ctx, scene, AccelKind::Bvh, lighting, &|_| {}).unwrap();
    let (w, h) = (64u32, 32u32);
    let f = RenderSettings { passes: PassSet::all(), ..settings(w, h, spp, lighting) };
    // Two strips, as a farm cuts the frame: the passes land by column.
    let mut frame = PassImage::new(w, h, PassSet::all());
    for (x0, x1) in [(0, 29), (29, 64)] {
        let s = p.renderer.render_strip(ctx, &f, x0, x1).unwrap();
        frame.paste_strip(x0, s.passes.as_ref().unwrap()).unwrap();
    }
    frame.check().unwrap();
    let at = |x: f32, y: f32| ((y * h as f32) as usize) * w as usize + (x * w as f32) as usize;
    let get = |pass: Pass, n: usize| {
        let k = pass.channels().len();
        frame.plane(pass).unwrap()[k * n..k * n + k].to_vec()
    };
    // The camera's frame: x = ±tan(15°)·aspect·10 m at the edges.
    let half = (15f32.to_radians().tan() * 2.0 * 10.0, 15f32.to_radians().tan() * 10.0);
    let pixel_of = |x: f32, z: f32| {
        let d = 10.0 - z;
        at(0.5 + 0.5 * x * 10.0 / d / half.0, 0.5)
    };
    let (left, right, sky) = (pixel_of(-1.5, 0.0), pixel_of(1.5, -2.0), at(0.02, 0.05));
    assert_eq!(get(Pass::Instance, left), [1.0]);
    assert_eq!(get(Pass::Species, left), [2.0]);
    assert_eq!(get(Pass::Instance, right), [2.0]);
    assert_eq!(get(Pass::Species, right), [1.0]);
    assert_eq!(get(Pass::Instance, sky), [0.0]);
    assert_eq!(get(Pass::Depth, sky), [NO_DEPTH]);
    // Depth along the camera's axis, not along the ray.
    assert!((get(Pass::Depth, left)[0] - 10.0).abs() < 1e-4);
    assert!((get(Pass::Depth, right)[0] - 12.0).abs() < 1e-4);
    for n in [left, right] {
        let v = get(Pass::Normal, n);
        assert!(
            (Vec3::from_slice(&v) - Vec3::Z).length() < 1e-5,
            "{lighting:?}: normal {v:?} faces the camera"
        );
    }
    assert!(get(Pass::Normal, sky).iter().all(|&v| v == 0.0));
    let near = |a: Vec<f32>, b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    assert!(near(get(Pass::Albedo, left), [0.2, 0.6, 0.1]));
    assert!(near(get(Pass::Albedo, right), [0.5, 0.4, 0.3]));
    // The sky's own pass is the sky's colour where the frame sees it.
    assert!(near(get(Pass::Sky, sky), [0.1, 0.2, 0.4]));
}
