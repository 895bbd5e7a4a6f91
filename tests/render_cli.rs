//! `sylva scene` and `sylva render` as a user runs them: real processes,
//! real files, the real GPU adapter (lavapipe in CI).

use crate::common;

use common::{fails, ok, scratch};

use serde_json::Value;
use std::path::{Path, PathBuf};

fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[1..4], b"PNG");
    (
        u32::from_be_bytes(b[16..20].try_into().unwrap()),
        u32::from_be_bytes(b[20..24].try_into().unwrap()),
    )
}

fn small_forest(dir: &Path) -> PathBuf {
    small_forest_seeded(dir, "forest.json", 1)
}

/// The 0.01 forest at a hundredth of its triangles, placed and shaped by `seed`.
fn small_forest_seeded(dir: &Path, name: &str, seed: u64) -> PathBuf {
    let scene = dir.join(name);
    let v: Value = serde_json::from_str(&ok(&[
        "scene",
        "forest",
        "--scale",
        "0.01",
        "--triangle-scale",
        "0.01",
        "--seed",
        &seed.to_string(),
        "-o",
        scene.to_str().unwrap(),
        "--json",
    ]))
    .unwrap();
    assert_eq!(v["instances"], 11);
    scene
}

#[test]
fn the_forest_scene_has_the_papers_counts_at_scale_one() {
    let dir = scratch("table2");
    let scene = dir.join("forest.json");
    let v: Value = serde_json::from_str(&ok(&[
        "scene",
        "forest",
        "--scale",
        "1",
        "-o",
        scene.to_str().unwrap(),
        "--json",
    ]))
    .unwrap();
    assert_eq!(v["instances"], 962);
    assert_eq!(v["triangles_instanced"], 273_376_528u64);
    let species: Vec<(String, u64, u64)> = v["species"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["species"].as_str().unwrap().to_string(),
                s["instances"].as_u64().unwrap(),
                s["triangles_per_instance"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(species[0], ("red_maple".into(), 12, 115_529));
    assert_eq!(species[4], ("american_beech".into(), 168, 496_719));
}

#[test]
fn render_writes_image_and_stats() {
    let dir = scratch("render");
    let scene = small_forest(&dir);
    let out = dir.join("frame.png");
    let stats: Value = serde_json::from_str(&ok(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--width",
        "96",
        "--height",
        "48",
        "--spp",
        "2",
        "--exr",
        "--local-workers",
        "0",
        "--json",
    ]))
    .unwrap();
    assert_eq!(png_size(&out), (96, 48));
    assert!(dir.join("frame.exr").exists());
    let on_disk: Value =
        serde_json::from_slice(&std::fs::read(dir.join("frame.stats.json")).unwrap()).unwrap();
    assert_eq!(on_disk, stats);
    assert_eq!(stats["rays"]["primary"], 96 * 48 * 2);
    assert!(stats["rays"]["shadow"].as_u64().unwrap() > 0);
    assert!(stats["rays"]["mrays_per_second"].as_f64().unwrap() > 0.0);
    assert_eq!(stats["instances"], 11);
    assert!(
        stats["triangles"]["instanced"].as_u64().unwrap()
            > stats["triangles"]["unique"].as_u64().unwrap()
    );
    let phases: Vec<&str> = stats["phases_ms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["phase"].as_str().unwrap())
        .collect();
    // The structures are built while the LB solves (their phases overlap;
    // `prepare` is the wall time of both); `auto` uploads the compressed
    // wide BVH too, and ray queries where the adapter has them, and
    // measures them.
    let rq = stats["adapter"]["ray_queries"].as_bool().unwrap();
    let mut want = vec!["load", "voxelize", "lb", "forest lb", "build"];
    if rq {
        want.push("coverage");
    }
    want.extend(["upload", "upload cwbvh"]);
    if rq {
        want.push("upload rq");
    }
    want.push("choose backend");
    want.extend(["pipeline", "prepare", "trace", "tone map"]);
    assert_eq!(phases, want);
    assert_eq!(stats["lb"].as_array().unwrap().len(), 5);
    assert!(stats["gpu_memory_bytes"]["scene"].as_u64().unwrap() > 0);
    let fg = &stats["forest_grid"];
    assert!(!fg["reason"].as_str().unwrap().is_empty());
    let (lo, hi) = (fg["scale_min"].as_f64().unwrap(), fg["scale_max"].as_f64().unwrap());
    assert!(0.0 < lo && lo <= hi && hi <= 1.0, "{fg}");
}

#[test]
fn the_forest_grid_can_be_switched_off() {
    let dir = scratch("nogrid");
    let scene = small_forest(&dir);
    let mut v: Value = serde_json::from_slice(&std::fs::read(&scene).unwrap()).unwrap();
    v["forest_grid"] = serde_json::json!({ "use": "never" });
    std::fs::write(&scene, serde_json::to_string(&v).unwrap()).unwrap();
    let out = dir.join("f.png");
    let stats: Value = serde_json::from_str(&ok(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--width",
        "32",
        "--height",
        "16",
        "--local-workers",
        "0",
        "--json",
    ]))
    .unwrap();
    assert_eq!(stats["forest_grid"]["used"], false);
    assert!(stats["forest_grid"]["reason"].as_str().unwrap().contains("never"));
}

#[test]
fn every_lighting_method_and_structure_renders() {
    let dir = scratch("methods");
    let scene = small_forest(&dir);
    let mut means = Vec::new();
    for (lighting, accel) in
        [("local", "kd"), ("ambient", "bvh"), ("lb", "kd"), ("lb-visualize", "bvh")]
    {
        let out = dir.join(format!("{lighting}.png"));
        let stats: Value = serde_json::from_str(&ok(&[
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--width",
            "64",
            "--height",
            "32",
            "--lighting",
            lighting,
            "--accel",
            accel,
            "--local-workers",
            "0",
            "--json",
        ]))
        .unwrap();
        assert_eq!(stats["lighting"], lighting);
        assert_eq!(stats["accel"], accel);
        if lighting == "local" {
            assert!(stats["lb"].as_array().unwrap().is_empty(), "local lighting needs no LB solve");
        }
        if lighting == "ambient" {
            assert!(
                stats["ambient"].as_array().unwrap().iter().all(|c| c.as_f64().unwrap() > 0.0),
                "{}",
                stats["ambient"]
            );
        }
        means.push(stats["tone_map"]["log_average"].as_f64().unwrap());
    }
    // Indirect light brightens the frame compared with direct light alone.
    assert!(means[2] > means[0], "lb {} vs local {}", means[2], means[0]);
}

#[test]
fn bad_render_requests_get_clear_errors() {
    let dir = scratch("bad");
    let scene = small_forest(&dir);
    let s = scene.to_str().unwrap();
    assert!(fails(&["render", s, "--spp", "5000"]).contains("spp 5000: valid range [1, 4096]"));
    assert!(fails(&["render", s, "--width", "20000"]).contains("each side must be in [1, 16384]"));
    assert!(
        fails(&["render", "/nonexistent/scene.json"])
            .contains("/nonexistent/scene.json: cannot read")
    );
    let text = std::fs::read_to_string(&scene).unwrap();
    let broken = dir.join("broken.json");
    std::fs::write(&broken, text.replacen("\"camera\"", "\"kamera\"", 1)).unwrap();
    let err = fails(&["render", broken.to_str().unwrap()]);
    assert!(err.contains("broken.json: kamera: unknown field `kamera`"), "{err}");
    std::fs::write(&broken, text.replacen("\"scale\":", "\"scale\": -1, \"x\":", 1)).unwrap();
    assert!(fails(&["render", broken.to_str().unwrap()]).contains("broken.json"));
    let missing = dir.join("missing.json");
    std::fs::write(
        &missing,
        text.replacen("\"tree\": {", "\"gltf\": \"nowhere.glb\", \"tree\": {", 1),
    )
    .unwrap();
    assert!(fails(&["render", missing.to_str().unwrap()]).contains("give exactly one of"));
    // Refused before the reference is traced, not after every method.
    let err = fails(&["compare", s, "--grids", "32", "--out", dir.join("cmp").to_str().unwrap()]);
    assert!(err.contains("--grids needs two sizes or more"), "{err}");
    assert!(!dir.join("cmp").join("reference.bin").exists());
}

/// `--lighting auto` on a scene: the stats JSON, with what it chose and why.
fn auto(dir: &Path, name: &str, scene: &str, goal: &[&str]) -> Value {
    auto_with(dir, name, scene, goal, &[])
}

/// [`auto`] with `env` set.
fn auto_with(dir: &Path, name: &str, scene: &str, goal: &[&str], env: &[(&str, &str)]) -> Value {
    let path = dir.join(format!("{name}.json"));
    std::fs::write(&path, scene).unwrap();
    let out = dir.join(format!("{name}.png"));
    let mut args = vec![
        "render",
        path.to_str().unwrap(),
        "--local-workers",
        "0",
        "--width",
        "160",
        "--height",
        "80",
        "--lighting",
        "auto",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(goal);
    let o = common::sylva(&args, env);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    // A sequence's frames are numbered.
    let first = match goal.contains(&"--frames") {
        true => dir.join(format!("{name}-0000.png")),
        false => out,
    };
    assert_eq!(png_size(&first), (160, 80));
    v
}

#[test]
fn lighting_auto_picks_for_the_scene_and_says_why() {
    let dir = scratch("auto");
    let scene = |instances: &str, camera: &str| {
        format!(
            r#"{{
            "models": {{ "maple": {{ "tree": {{ "species": "red_maple", "triangles": 6000, "seed": 3 }} }} }},
            "instances": [ {instances} ],
            "camera": {camera},
            "sun": {{ "elevation_deg": 45, "azimuth_deg": 120 }},
            "ground": {{ "color": [0.1, 0.08, 0.05] }},
            "lb": {{ "grid": 12, "preset": "leaf" }}
        }}"#
        )
    };
    let tree = scene(
        r#"{ "model": "maple", "position": [0, 0, 0] }"#,
        r#"{ "position": [0, 5, -9], "look_at": [0, 5, 0], "fov_y_deg": 45 }"#,
    );
    // Twenty maples 3.2 m apart, the camera among the first row's crowns.
    let stand: Vec<String> = (-2..3)
        .flat_map(|i: i32| (0..4).map(move |j: i32| (i, j)))
        .map(|(i, j)| {
            let (x, z) = (i as f32 * 3.2 + (j % 2) as f32 * 1.6, j as f32 * 3.2);
            let turn = (i * 37 + j * 71).rem_euclid(360);
            format!(r#"{{ "model": "maple", "position": [{x}, 0, {z}], "rotate_y_deg": {turn} }}"#)
        })
        .collect();
    let stand = scene(
        &stand.join(", "),
        r#"{ "position": [0, 4, -9], "look_at": [0, 4, 4], "fov_y_deg": 45 }"#,
    );
    let goal = ["--max-error", "0.1"];
    let (t, s) = (auto(&dir, "tree", &tree, &goal), auto(&dir, "stand", &stand, &goal));
    for v in [&t, &s] {
        let a = &v["auto"];
        let chosen = &a["chosen"];
        // The frame is what was chosen, and the choice meets the goal on the pilot.
        assert_eq!(v["lighting"], chosen["lighting"], "{a}");
        assert_eq!(v["spp"], chosen["spp"], "{a}");
        assert!(chosen["error"].as_f64().unwrap() <= 0.1, "{a}");
        let why = a["why"].as_str().unwrap();
        assert!(
            why.contains("within 10.0 % error") && why.contains(chosen["name"].as_str().unwrap()),
            "{why}"
        );
        let names: Vec<&str> = a["candidates"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["name"].as_str().unwrap())
            .collect();
        for n in [
            "local",
            "ambient",
            "lb",
            "path tracer 16 rays",
            "gather 1b 4 rays",
            "gather 2b 16 rays",
            "path tracer + denoised indirect 4 rays",
            "path tracer + denoised indirect 16 rays",
        ] {
            assert!(names.contains(&n), "{n} missing from {names:?}");
        }
        let phases = v["phases_ms"].as_array().unwrap();
        assert!(phases.iter().any(|p| p["phase"] == "pilot"));
        // A denoised choice is denoised.
        let denoised = chosen["denoise"] != "off";
        assert_eq!(phases.iter().any(|p| p["phase"] == "denoise"), denoised, "{a}");
    }
    // A lone tree: few paths stay among its leaves, so path tracing needs
    // no pre-process and few samples. A stand: paths bounce between crowns,
    // so brute force is noisy; without a denoiser the gather over the
    // lattice pays, and the pilot says why it has no denoised candidates.
    assert_eq!(t["auto"]["chosen"]["lighting"], "reference", "{}", t["auto"]["why"]);
    let no_oidn = [("SYLVA_OIDN_LIB", "/nonexistent/libOpenImageDenoise.so.2")];
    let plain = auto_with(&dir, "stand-plain", &stand, &goal, &no_oidn);
    assert_eq!(plain["auto"]["chosen"]["lighting"], "gather", "{}", plain["auto"]["why"]);
    let error = |v: &Value, name: &str| -> f64 {
        let c = v["auto"]["candidates"].as_array().unwrap().iter().find(|c| c["name"] == name);
        c.map(|c| c["error"].as_f64().unwrap()).unwrap_or(f64::NAN)
    };
    assert!(error(&plain, "path tracer + denoised indirect 4 rays").is_nan());
    let left_out = plain["auto"]["left_out"][0].as_str().unwrap_or_default();
    assert!(left_out.starts_with("denoised methods: "), "{}", plain["auto"]);
    // With one, the path tracer's indirect light denoised is far closer to
    // the reference than the same samples raw.
    let (raw, denoised) =
        (error(&s, "path tracer 16 rays"), error(&s, "path tracer + denoised indirect 16 rays"));
    assert!(denoised < 0.7 * raw, "{denoised} against {raw}: {}", s["auto"]);
    // A budget: the most accurate that fits.
    let b = auto(&dir, "stand-budget", &stand, &["--time-budget", "0.3"]);
    let chosen = &b["auto"]["chosen"];
    assert!(chosen["predicted_ms"].as_f64().unwrap() <= 300.0, "{}", b["auto"]);
    assert!(b["auto"]["why"].as_str().unwrap().contains("the most accurate within 0.3 s"));

    // A sequence: the pilot, on its middle frame, prices each method over
    // the whole job (six frames under one sun: a preparation once, six
    // frames), and the sequence renders with what it chose, going on from
    // the pilot's preparation (no prepared-data cache here: nothing is
    // built again).
    let sequence =
        ["--max-error", "0.3", "--frames", "6", "--sun-from", "45,120", "--sun-to", "45,120"];
    let v = auto_with(&dir, "seq", &tree, &sequence, &[("SYLVA_PREPARED_CACHE_MIB", "0")]);
    for f in v["frames"].as_array().unwrap() {
        let built = f["phases_ms"].as_array().unwrap().iter().any(|p| p["name"] == "build");
        assert!(!built, "the pilot's structures are the sequence's: {f}");
    }
    let a = &v["auto"];
    assert_eq!(a["job"], serde_json::json!({ "frames": 6, "suns": 1 }), "{a}");
    assert!(a["why"].as_str().unwrap().contains("for the whole job of 6 frames under one sun"));
    for c in a["candidates"].as_array().unwrap() {
        let f = |k: &str| c[k].as_f64().unwrap();
        let job = f("preprocess_ms") + 6.0 * f("frame_ms");
        assert!((f("predicted_ms") - job).abs() <= 1e-6 * job.max(1.0), "{c}");
    }
    assert_eq!(v["lighting"], a["chosen"]["lighting"], "{a}");
    assert!(dir.join("seq-0005.png").is_file());

    // Wrong uses are refused with what to do instead.
    let path = dir.join("tree.json");
    let p = path.to_str().unwrap();
    let err = fails(&["render", p, "--lighting", "auto", "--local-workers", "0"]);
    assert!(err.contains("--time-budget SECONDS or --max-error E"), "{err}");
    let err = fails(&[
        "render",
        p,
        "--lighting",
        "auto",
        "--max-error",
        "0.1",
        "--local-workers",
        "0",
        "--denoise",
    ]);
    assert!(err.contains("--lighting auto chooses whether to denoise"), "{err}");
    let err = fails(&["render", p, "--lighting", "auto", "--max-error", "0.1"]);
    assert!(err.contains("add --local-workers 0"), "{err}");
    let err = fails(&["render", p, "--time-budget", "3", "--local-workers", "0"]);
    assert!(err.contains("go with --lighting auto"), "{err}");
    let err =
        fails(&["render", p, "--lighting", "auto", "--max-error", "NaN", "--local-workers", "0"]);
    assert!(err.contains("--max-error NaN: must be a finite number > 0"), "{err}");
    let err = fails(&["submit", p, "--coordinator", "127.0.0.1:9", "--lighting", "auto"]);
    assert!(err.contains("--lighting auto runs its pilot on this machine"), "{err}");
}

#[test]
fn the_fern_example_renders() {
    let dir = scratch("fern");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/ferns.json");
    let out = dir.join("ferns.png");
    let stats: Value = serde_json::from_str(&ok(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--width",
        "64",
        "--height",
        "48",
        "--json",
    ]))
    .unwrap();
    assert_eq!(stats["triangles"]["unique"], 6232);
    assert!(
        stats["coverage"].as_f64().unwrap() > 0.1,
        "the ferns fill {} of the frame",
        stats["coverage"]
    );
}

#[test]
fn compare_lists_every_method_with_its_time_and_error() {
    let dir = scratch("compare");
    let scene = dir.join("one-tree.json");
    std::fs::write(
        &scene,
        r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 6000, "seed": 3 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "maple", "position": [5, 0, 3], "rotate_y_deg": 50 } ],
        "camera": { "position": [2, 6, -16], "look_at": [2, 5, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 45, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lb": { "grid": 12, "preset": "leaf" }
    }"#,
    )
    .unwrap();
    let out = dir.join("cmp");
    let compare = |width: &str, extra: &[&str]| -> Value {
        let (scene, out) = (scene.to_str().unwrap(), out.to_str().unwrap());
        let mut args = vec![
            "compare",
            scene,
            "--width",
            width,
            "--height",
            "24",
            "--spp",
            "2",
            "--grids",
            "8,12",
            "--target-error",
            "0.1",
            "--gather-rays",
            "2",
            "--gather-filters",
            "0,2",
            "--budget",
            "60",
            "--out",
            out,
            "--json",
        ];
        args.extend_from_slice(extra);
        serde_json::from_str(&ok(&args)).unwrap()
    };
    let v = compare("40", &[]);
    let methods = v["methods"].as_array().unwrap();
    let names: Vec<&str> = methods.iter().map(|m| m["name"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "local",
            "ambient",
            "lb 8³",
            "lb 12³",
            "lb 12³ + forest grid",
            "lb paper 12³ + forest grid",
            "boulanger",
            "gather 1b r0 2 rays",
            "gather 1b r2 2 rays",
            "gather-ambient 1b r3 2 rays",
            "gather 2b r0 2 rays",
            "gather 2b r2 2 rays",
            "gather 2b + denoise 2 rays",
            "gather 2b + denoised indirect 2 rays",
            "gather-ambient 2b r3 2 rays",
            "path tracer + denoise 2 spp",
            "path tracer + denoised indirect 2 spp",
            "lb auto",
            "reference"
        ]
    );
    for m in methods {
        let f = |k: &str| m[k].as_f64().unwrap_or_else(|| panic!("{k} of {m}"));
        assert!(f("frame_ms") > 0.0 && f("preprocess_ms") >= 0.0, "{m}");
        for k in ["rmse", "mean_relative_error", "indirect_relative_error"] {
            assert!(f(k).is_finite() && f(k) >= 0.0, "{k} of {m}");
        }
        if m["name"] != "reference" {
            assert!(
                f("mean_relative_error") > 0.0,
                "a method that is not the reference differs from it: {m}"
            );
        }
        assert!(Path::new(m["image"].as_str().unwrap()).exists(), "{m}");
    }
    assert!(v["reference"]["converged"].as_bool().unwrap(), "{}", v["reference"]);
    // The grid choice says what it chose and why.
    let choice = &methods[17]["notes"]["grid_choice"][0];
    assert!(
        [8, 12].contains(&choice["grid"].as_u64().unwrap())
            && !choice["reason"].as_str().unwrap().is_empty(),
        "{choice}"
    );
    assert!(methods[6]["notes"]["boulanger"][0]["tau"].as_f64().unwrap() > 0.0);
    // The denoised gather is denoised, and says so (issue 40).
    assert_eq!(methods[12]["notes"]["denoised"], "frame", "{}", methods[12]);
    assert_eq!(methods[13]["notes"]["denoised"], "indirect", "{}", methods[13]);
    assert!(methods[10]["notes"]["denoised"].is_null());
    // The paper model is there, and its non-physical strength is named.
    assert_eq!(methods[5]["notes"]["lb_model"], "paper");
    assert!(
        methods[5]["notes"]["non_physical"]["lb_strength"].as_f64().is_some(),
        "{}",
        methods[5]["notes"]
    );
    assert_eq!(methods[3]["notes"]["lb_model"], "grounded");
    assert!(methods[3]["notes"]["non_physical"].is_null());
    assert!(v["summary"].as_str().unwrap().starts_with("most accurate: "));
    for f in ["figure2.svg", "compare.svg", "compare.json", "reference.png"] {
        assert!(out.join(f).exists(), "{f}");
    }
    // The gathers say how deep they trace and how they filter.
    assert_eq!(methods[10]["notes"]["gather_bounces"], 2);
    assert_eq!(methods[11]["notes"]["gather_filter"], 2);
    assert!(methods[10]["notes"]["gather_filter"].is_null(), "{}", methods[10]["notes"]);
    assert_eq!(methods[10]["notes"]["spp"], 2);
    // The chart is a Pareto front over every method and the progressive
    // path tracer, whose error falls as it runs; the front names the best
    // method for the budget asked.
    let chart = std::fs::read_to_string(out.join("compare.svg")).unwrap();
    assert!(chart.contains("Pareto front") && chart.contains("progressive path tracer"));
    assert!(out.join("compare-net.svg").exists());
    let pt = v["progressive"].as_array().unwrap();
    assert_eq!(pt.len(), 5, "{pt:?}");
    let raw = |p: &Value| p["raw"].as_f64().unwrap();
    assert!(raw(&pt[4]) < raw(&pt[0]), "{pt:?}");
    // Each point has more samples than the one before, however fast the reference was.
    let spp =
        |p: &Value| p["name"].as_str().unwrap().split(' ').nth(2).unwrap().parse::<u32>().unwrap();
    assert!(pt.windows(2).all(|w| spp(&w[1]) >= 2 * spp(&w[0])), "{pt:?}");
    assert!(pt.windows(2).all(|w| w[1]["ms"].as_f64() >= w[0]["ms"].as_f64()), "{pt:?}");
    let front = v["front"].as_array().unwrap();
    assert!(!front.is_empty() && front.windows(2).all(|w| raw(&w[1]) < raw(&w[0])), "{front:?}");
    assert!(v["budget"].as_str().unwrap().starts_with("best within 60 s: "), "{}", v["budget"]);
    // Per crown: both maples are in view, each with its reference and method light.
    let crowns = &v["crowns"];
    assert_eq!(crowns["rows"].as_array().unwrap().len(), 2, "{crowns}");
    assert_eq!(crowns["rows"][0]["methods"].as_array().unwrap().len(), names.len() - 2);
    assert!(out.join("instances.png").exists() && out.join("crowns.md").exists());
    // The noise of both images is measured and taken out of the net error:
    // local's indirect light is zero on both its renders, a method's at two
    // jittered rays per pixel is not; no net error exceeds the raw one by more than noise allows.
    assert_eq!(methods[0]["indirect_noise_method"].as_f64(), Some(0.0));
    assert!(methods[3]["indirect_noise_method"].as_f64().unwrap() > 0.0, "{}", methods[3]);
    assert!(methods[3]["indirect_noise_reference"].as_f64().unwrap() > 0.0, "{}", methods[3]);
    assert!(
        methods[3]["indirect_error_net"].as_f64().unwrap()
            <= methods[3]["indirect_relative_error"].as_f64().unwrap() * 1.2
    );

    // A second run reuses the saved reference (no path tracing) and gives the same errors.
    let w = compare("40", &["--reuse-reference", "--hdr"]);
    assert_eq!(w["reference"]["reused"], true);
    assert_eq!(w["reference"]["spp"], v["reference"]["spp"]);
    assert_eq!(
        w["methods"][3]["indirect_relative_error"],
        v["methods"][3]["indirect_relative_error"]
    );
    for f in [
        "reference.npy",
        "reference-local.npy",
        "reference-indirect-variance.npy",
        "reference-coverage.npy",
        "lb-12.npy",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    // Another image size does not reuse it.
    assert_eq!(compare("32", &["--reuse-reference"])["reference"]["reused"], false);
}

/// A 48 × 24 render of `scene` in this process as `dir/NAME.png`, with
/// `flags` and `env`; it must succeed. The PNG's bytes and the log.
fn small_render(
    dir: &Path,
    scene: &Path,
    name: &str,
    flags: &[&str],
    env: &[(&str, &str)],
) -> (Vec<u8>, String) {
    let out = dir.join(format!("{name}.png"));
    let args = ["render", scene.to_str().unwrap(), "--local-workers", "0", "--width", "48"];
    let o = common::sylva(
        &[&args[..], &["--height", "24", "-o", out.to_str().unwrap()], flags].concat(),
        env,
    );
    let said = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{said}");
    (std::fs::read(out).unwrap(), said)
}

/// The stats [`small_render`] wrote beside its PNG `name`.
fn stats_of(dir: &Path, name: &str) -> Value {
    serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.stats.json"))).unwrap()).unwrap()
}

/// Compiled kernels are kept beside the prepared data (issue 39): the
/// first process leaves a file named by the adapter and driver, holding
/// the hash of its data; the next reads it; a file changed on disk is
/// refused, compiled anew and written again, and the image is the same
/// every time. (On lavapipe the driver keeps little in a pipeline cache —
/// Mesa keeps compiled shaders in its own disk cache — so what is timed
/// is for a real GPU, in `benchmarks/gpu/run.sh`.)
#[test]
fn compiled_kernels_are_kept_checked_and_read_back() {
    let dir = scratch("kept-kernels");
    let cache = dir.join("cache");
    let scene = small_forest(&dir);
    let env = [
        ("SYLVA_PREPARED_CACHE_MIB", "64"),
        ("SYLVA_PREPARED_CACHE_DIR", cache.to_str().unwrap()),
        ("RUST_LOG", "sylva_worker::gpu=info"),
    ];
    let render = |name: &str| small_render(&dir, &scene, name, &[], &env);
    let kept = || -> Vec<PathBuf> {
        std::fs::read_dir(&cache)
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "kernels"))
            .collect()
    };
    let (first, _) = render("first");
    let files = kept();
    assert_eq!(files.len(), 1, "one file for this adapter and driver: {files:?}");
    let raw = std::fs::read(&files[0]).unwrap();
    assert_eq!(&raw[..64], blake3::hash(&raw[64..]).to_hex().as_bytes(), "the hash, then the data");
    let (second, said) = render("second");
    assert!(said.contains("compiled kernels read from the cache"), "{said}");
    assert_eq!(second, first);
    // One byte changed: refused, compiled anew, written again whole.
    let mut bad = raw.clone();
    let k = bad.len() - 1;
    bad[k] ^= 0x5a;
    std::fs::write(&files[0], &bad).unwrap();
    let (third, said) = render("third");
    assert!(said.contains("kept kernels refused"), "{said}");
    assert_eq!(third, first);
    let again = std::fs::read(&files[0]).unwrap();
    assert_eq!(&again[..64], blake3::hash(&again[64..]).to_hex().as_bytes());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `auto` keeps what its probe measured on this adapter (issue 39): a
/// backend more than `LEFT_BEHIND` (10) times slower than the fastest on
/// one scene is neither built nor measured for the next (on lavapipe, ray
/// queries), the stats say why, and its figure is kept for the scene after.
#[test]
fn auto_leaves_out_a_backend_far_behind_on_this_adapters_last_probe() {
    let dir = scratch("left-behind");
    let cache = dir.join("cache");
    let scenes: Vec<PathBuf> = (1..=3)
        .map(|seed| small_forest_seeded(&dir, &format!("forest-{seed}.json"), seed))
        .collect();
    let env =
        [("SYLVA_PREPARED_CACHE_MIB", "64"), ("SYLVA_PREPARED_CACHE_DIR", cache.to_str().unwrap())];
    let backend = |i: usize| -> Value {
        let name = format!("render-{i}");
        small_render(&dir, &scenes[i], &name, &["--accel", "auto"], &env);
        stats_of(&dir, &name)["backend"].clone()
    };
    let speed = |b: &Value, name: &str| {
        b["probe"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["backend"] == name)
            .map(|p| p["mrays_per_second"].as_f64().unwrap())
    };
    let first = backend(0);
    let measured: Vec<String> = first["probe"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["backend"].as_str().unwrap().to_string())
        .collect();
    assert!(measured.len() >= 2, "auto measured {measured:?}");
    // The adapter's record: each backend's figure from the last probe that
    // measured it (a probe that leaves one out keeps its older figure).
    let mut record: Vec<(String, f64)> =
        measured.iter().map(|n| (n.clone(), speed(&first, n).unwrap())).collect();
    for i in [1, 2] {
        let best = record.iter().map(|r| r.1).fold(0.0, f64::max);
        let behind: Vec<&String> =
            record[1..].iter().filter(|r| r.1 * 10.0 < best).map(|r| &r.0).collect();
        let later = backend(i);
        let why = later["why"].as_str().unwrap();
        for n in &measured {
            let left_out = behind.contains(&n);
            assert_eq!(why.contains(&format!("{n} left out")), left_out, "{n}: {why}");
            // With one backend left nothing is measured; otherwise the
            // rest are measured again.
            if left_out || measured.len() - behind.len() == 1 {
                assert_eq!(speed(&later, n), None, "{n} was measured: {later}");
            } else {
                assert!(speed(&later, n).is_some(), "{n} was not measured: {later}");
            }
        }
        for r in &mut record {
            r.1 = speed(&later, &r.0).unwrap_or(r.1);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Boulanger's envelopes are kept beside the prepared data (issue 39):
/// the second process reads them instead of casting every leaf's rays
/// again, and renders the same image.
#[test]
fn boulanger_envelopes_are_kept_and_read_back() {
    let dir = scratch("kept-envelopes");
    let cache = dir.join("cache");
    let scene = small_forest(&dir);
    let env = [
        ("SYLVA_PREPARED_CACHE_MIB", "64"),
        ("SYLVA_PREPARED_CACHE_DIR", cache.to_str().unwrap()),
        ("RUST_LOG", "sylva_worker=info"),
    ];
    let render = |name: &str| {
        let (png, said) = small_render(&dir, &scene, name, &["--lighting", "boulanger"], &env);
        let stats = stats_of(&dir, name);
        let phases: Vec<String> = stats["phases_ms"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["phase"].as_str().unwrap().to_string())
            .collect();
        (png, said, phases, stats["boulanger"].clone())
    };
    let (first, _, phases, report) = render("first");
    assert!(phases.iter().any(|p| p == "boulanger precompute"), "{phases:?}");
    let (second, said, phases, again) = render("second");
    assert!(!phases.iter().any(|p| p == "boulanger precompute"), "{phases:?}");
    assert!(said.contains("envelopes=true"), "{said}");
    assert_eq!(again, report, "the same envelopes are reported");
    assert_eq!(second, first);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `-o NAME.exr` gets the user an OpenEXR (issue 41): before, it failed
/// with "cannot write PNG … Rgb8". The PNG and the stats sit beside it.
#[test]
fn an_exr_name_writes_the_exr() {
    let dir = scratch("exr-name");
    let scene = common::small_scene(&dir);
    let out = dir.join("shot.exr");
    ok(&[
        "render",
        scene.to_str().unwrap(),
        "--local-workers",
        "0",
        "--width",
        "32",
        "--height",
        "16",
        "-o",
        out.to_str().unwrap(),
    ]);
    let exr = std::fs::read(&out).unwrap();
    assert_eq!(&exr[..4], &[0x76, 0x2f, 0x31, 0x01], "OpenEXR's magic number");
    assert!(dir.join("shot.png").exists() && dir.join("shot.stats.json").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A sequence solves the LB again for each sun; a finding about a model
/// (an optically thin crown, a small grid) is logged once, not once per
/// frame (issue 41, point 3). The stats still carry every frame's.
#[test]
fn a_sequence_logs_each_lb_warning_once() {
    let dir = scratch("warn-once");
    let scene = small_forest(&dir);
    let out = dir.join("seq.png");
    let o = common::sylva(
        &["render", scene.to_str().unwrap(), "--local-workers", "0", "--width", "48"]
            .into_iter()
            .chain(["--height", "24", "-o", out.to_str().unwrap(), "--lighting", "lb"])
            .chain(["--frames", "3", "--sun-from", "30,90", "--sun-to", "50,130"])
            .collect::<Vec<_>>(),
        &[],
    );
    let said = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{said}");
    let warned: Vec<&str> =
        said.lines().filter(|l| l.contains("WARN") && l.contains("LB: ")).collect();
    assert!(!warned.is_empty(), "the small forest's crowns are thin: {said}");
    let mut seen = std::collections::HashSet::new();
    for l in &warned {
        let model = l.split("model=").nth(1).unwrap_or_default();
        let kind = l.split("LB: ").nth(1).and_then(|w| w.split(':').next()).unwrap_or_default();
        assert!(seen.insert((model, kind)), "said twice: {l}\n{said}");
    }
}

/// A sequence keeps its clouds' LB light per sun, as it keeps the
/// models': frames under a sun seen before solve nothing again, and look
/// as the first did.
#[test]
fn a_sequence_under_one_sun_solves_its_clouds_once() {
    let dir = scratch("clouds-once");
    let scene = dir.join("cloud.json");
    std::fs::write(
        &scene,
        r#"{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 800, "seed": 3 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] } ],
        "camera": { "position": [0, 4, -14], "look_at": [0, 5, 0], "fov_y_deg": 60 },
        "sun": { "elevation_deg": 45, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lb": { "grid": 12, "preset": "leaf" },
        "clouds": [ { "center": [0, 14, 20], "size": 12, "grid": 12, "seed": 7 } ]
    }"#,
    )
    .unwrap();
    let out = dir.join("seq.png");
    let v: Value = serde_json::from_str(&ok(&[
        "render",
        scene.to_str().unwrap(),
        "--local-workers",
        "0",
        "--width",
        "48",
        "--height",
        "24",
        "--lighting",
        "lb",
        "--frames",
        "3",
        "--sun-from",
        "45,120",
        "--sun-to",
        "45,120",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]))
    .unwrap();
    let solved: Vec<bool> = v["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["phases_ms"].as_array().unwrap().iter().any(|p| p["name"] == "cloud lb"))
        .collect();
    assert_eq!(solved, [true, false, false], "in the order rendered: {}", v["frames"]);
    let png = |i: usize| std::fs::read(dir.join(format!("seq-{i:04}.png"))).unwrap();
    assert!(png(0) == png(1) && png(1) == png(2), "one view, one sun: one image");
}
