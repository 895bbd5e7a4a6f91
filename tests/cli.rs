//! The `sylva` program as a user runs it: real processes, real files, the
//! real GPU adapter (lavapipe in CI).

use crate::common;

use common::{fails, ok, scratch};

use serde_json::Value;
use std::path::{Path, PathBuf};

fn fern() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/fern_02.glb")
}

/// The shape in a `.npy` header.
fn npy_shape(path: &Path) -> String {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..6], b"\x93NUMPY");
    let header = String::from_utf8_lossy(&bytes[10..128]).to_string();
    assert!(header.contains("'descr': '<f4'"), "{header}");
    let start = header.find("'shape': (").unwrap() + 10;
    header[start..start + header[start..].find(')').unwrap()]
        .trim_end_matches([',', ' '])
        .to_string()
}

#[test]
fn verify_reports_every_check_passing_as_json() {
    let v: Value = serde_json::from_str(&ok(&["lb", "verify", "--json"])).unwrap();
    assert_eq!(v["pass"], true, "{v:#}");
    let checks = v["checks"].as_array().unwrap();
    let ids: Vec<&str> = checks.iter().map(|c| c["id"].as_str().unwrap()).collect();
    assert_eq!(ids, ["a", "b", "c", "d", "e", "f", "g"]);
    for c in checks {
        assert!(c["measured"].as_f64().unwrap() <= c["bound"].as_f64().unwrap(), "{c:#}");
        assert_eq!(c["pass"], true);
    }
}

#[test]
fn solving_the_builtin_plant_writes_grid_picture_and_summary() {
    let dir = scratch("plant");
    let out = dir.to_str().unwrap();
    let summary: Value = serde_json::from_str(&ok(&[
        "lb",
        "solve",
        "plant",
        "--grid",
        "20",
        "--backend",
        "cpu",
        "-o",
        out,
        "--json",
    ]))
    .unwrap();
    assert_eq!(npy_shape(&dir.join("density.npy")), "3, 20, 20, 20");
    let png = image_size(&dir.join("density.png"));
    assert!(png.0 > 200 && png.1 > 100, "{png:?}");
    let on_disk: Value =
        serde_json::from_slice(&std::fs::read(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(on_disk, summary);
    assert_eq!(summary["preset"], "leaf");
    assert_eq!(summary["triangles"], 8016);
    for c in summary["channels"].as_array().unwrap() {
        let r = &c["report"];
        assert_eq!(r["max_steps"], 40, "the default cap is 2 × the longest edge");
        assert!(r["steps"].as_u64().unwrap() <= 40);
        assert!(r["final_change"].as_f64().is_some());
    }
    let phases: Vec<&str> = summary["phases_ms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["phase"].as_str().unwrap())
        .collect();
    assert_eq!(phases, ["load", "voxelize", "open solver", "solve", "write"]);
}

fn image_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[1..4], b"PNG");
    (
        u32::from_be_bytes(b[16..20].try_into().unwrap()),
        u32::from_be_bytes(b[20..24].try_into().unwrap()),
    )
}

#[test]
fn gpu_and_cpu_solve_a_gltf_model_alike() {
    let dir = scratch("fern");
    let model = fern();
    let (cpu, gpu) = (dir.join("cpu"), dir.join("gpu"));
    let run = |backend: &str, out: &Path| -> Value {
        serde_json::from_str(&ok(&[
            "lb",
            "solve",
            model.to_str().unwrap(),
            "--grid",
            "24",
            "--backend",
            backend,
            "--max-steps",
            "30",
            "--tolerance",
            "0",
            "-o",
            out.to_str().unwrap(),
            "--json",
        ]))
        .unwrap()
    };
    let (c, g) = (run("cpu", &cpu), run("gpu", &gpu));
    assert_eq!(c["triangles"], 6232);
    assert!(c["grid"]["occupancy"].as_f64().unwrap() > 0.0);
    for (a, b) in c["channels"].as_array().unwrap().iter().zip(g["channels"].as_array().unwrap()) {
        assert_eq!(a["report"]["steps"], 30);
        let (x, y) = (
            a["report"]["total_density"].as_f64().unwrap(),
            b["report"]["total_density"].as_f64().unwrap(),
        );
        assert!((x - y).abs() / x < 1e-5, "cpu {x} gpu {y}");
    }
}

#[test]
fn a_density_grid_from_npy_is_solved_with_its_own_shape() {
    let dir = scratch("npy");
    let grid = dir.join("grid.npy");
    // (Z, Y, X) = (6, 7, 8), a dense block in the middle.
    let dims = sylva_light::lb::GridDims { nx: 8, ny: 7, nz: 6 };
    let mut m = sylva_light::lb::MediumGrid::empty(dims);
    for z in 2..4 {
        for y in 2..5 {
            for x in 2..6 {
                m.density[dims.index(x, y, z)] = 0.8;
            }
        }
    }
    sylva_light::npy::write_density(&grid, &m).unwrap();
    let out = dir.join("out");
    let s: Value = serde_json::from_str(&ok(&[
        "lb",
        "solve",
        grid.to_str().unwrap(),
        "--preset",
        "cloud",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]))
    .unwrap();
    assert_eq!(npy_shape(&out.join("density.npy")), "3, 6, 7, 8");
    assert_eq!(s["preset"], "cloud");
    assert_eq!(s["channels"][0]["report"]["max_steps"], 16);
    let err = fails(&["lb", "solve", grid.to_str().unwrap(), "--grid", "32"]);
    assert!(err.contains("--grid does not apply to a .npy"), "{err}");
}

#[test]
fn bad_input_gets_a_clear_error() {
    let dir = scratch("bad");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["nope.glb".into()], "nope.glb: no such file"),
        (vec!["plant".into(), "--sun".into(), "NaN,10".into()], "sun elevation NaN"),
        (vec!["plant".into(), "--sun".into(), "0,0,0".into()], "must be a finite, non-zero vector"),
        (
            vec!["plant".into(), "--sun".into(), "north".into()],
            "expected ELEVATION,AZIMUTH or X,Y,Z",
        ),
        (vec!["plant".into(), "--sun-intensity".into(), "-1".into()], "sun intensity -1"),
        (vec!["plant".into(), "--preset".into(), "oak".into()], "unknown preset \"oak\""),
        (vec!["plant".into(), "--grid".into(), "2".into()], "use at least 4"),
        (vec!["plant".into(), "--tolerance".into(), "NaN".into()], "--tolerance NaN"),
        (
            vec!["plant".into(), "--class".into(), "green".into()],
            "--class applies to .npy grids only",
        ),
    ];
    for (args, want) in cases {
        let mut full = vec!["lb".to_string(), "solve".to_string()];
        full.extend(args);
        full.extend(["-o".to_string(), dir.to_str().unwrap().to_string()]);
        let refs: Vec<&str> = full.iter().map(|s| s.as_str()).collect();
        let err = fails(&refs);
        assert!(err.contains(want), "{refs:?}: {err}");
    }
    // Files that are not what they claim.
    let junk = dir.join("junk.npy");
    std::fs::write(&junk, b"not numpy at all").unwrap();
    assert!(fails(&["lb", "solve", junk.to_str().unwrap()]).contains("not a .npy file"));
    let bad_glb = dir.join("broken.glb");
    std::fs::write(&bad_glb, b"glTF\x02\x00\x00\x00garbage").unwrap();
    assert!(fails(&["lb", "solve", bad_glb.to_str().unwrap()]).contains("cannot load glTF"));
    let out_of_range = dir.join("range.npy");
    let dims = sylva_light::lb::GridDims::cube(5);
    let mut m = sylva_light::lb::MediumGrid::empty(dims);
    m.density[dims.index(2, 2, 2)] = f32::NAN;
    sylva_light::npy::write_density(&out_of_range, &m).unwrap();
    let err = fails(&["lb", "solve", out_of_range.to_str().unwrap()]);
    assert!(err.contains("density at node (x=2, y=2, z=2) is NaN; valid range: [0, 1]"), "{err}");
}

#[test]
fn lb_benchmark_prints_both_backends_as_json() {
    let v: Value = serde_json::from_str(&ok(&["bench", "lb", "--grid", "16", "--json"])).unwrap();
    assert_eq!(v["grid"], 16);
    let results = v["results"].as_array().unwrap();
    assert_eq!(results.len(), 2);
    for r in results {
        for key in ["mlups", "step_mlups", "ms_per_step", "bytes_per_second", "wall_ms"] {
            assert!(r[key].as_f64().unwrap() > 0.0, "{key} in {r:#}");
        }
        assert!(!r["device"].as_str().unwrap().is_empty());
        assert_eq!(r["steps_per_channel"].as_array().unwrap().len(), 3);
    }
    assert!(v["gpu_over_cpu"].as_f64().unwrap() > 0.0);
}

/// `bench trace` times the traversal kernel on the GPU itself (timestamp
/// queries, which lavapipe has), per ray kind, over at least
/// `--kernel-rays` rays: the camera rays, shadow rays and diffuse bounces
/// of the same frame, apart from uploads and read-backs.
#[test]
fn trace_benchmark_leaves_ray_query_frames_out_on_a_cpu_adapter() {
    // `sylva bench trace` as a user first types it renders no ray-query
    // frame on lavapipe (minutes each), and says so (issue 41, point 4).
    let out = ok(&[
        "bench",
        "trace",
        "--scale",
        "0.01",
        "--triangle-scale",
        "0.01",
        "--width",
        "16",
        "--height",
        "8",
        "--accel",
        "bvh,rq",
        "--no-cpu",
        "--no-first-frame",
        "--kernel-rays",
        "1000",
    ]);
    let v: Value = serde_json::from_str(&out).unwrap();
    let framed: Vec<&str> =
        v["frames"].as_array().unwrap().iter().map(|f| f["accel"].as_str().unwrap()).collect();
    if v["adapter"]["device_type"] == "Cpu" {
        assert!(!framed.contains(&"rq") && framed.contains(&"bvh"), "{framed:?}");
        if v["adapter"]["ray_queries"] == true {
            assert!(v["frames_left_out"].as_str().unwrap().starts_with("rq:"), "{v:#}");
        }
    } else {
        assert!(v["frames_left_out"].is_null(), "{v:#}");
    }
}

#[test]
fn trace_benchmark_times_each_ray_kind_on_the_gpu() {
    let out = ok(&[
        "bench",
        "trace",
        "--scale",
        "0.01",
        "--width",
        "32",
        "--height",
        "16",
        "--accel",
        "bvh,cwbvh",
        "--no-cpu",
        "--no-frames",
        "--no-first-frame",
        "--kernel-rays",
        "2000",
    ]);
    let v: Value = serde_json::from_str(&out).unwrap();
    let backends: Vec<&str> =
        v["traversal"].as_array().unwrap().iter().map(|t| t["accel"].as_str().unwrap()).collect();
    assert_eq!(backends, ["bvh", "cwbvh"]);
    for t in v["traversal"].as_array().unwrap() {
        assert!(t["bounce_rays"].as_u64().unwrap() > 0, "{t:#}");
        // Both walk the same scene: the same hits.
        assert_eq!(t["gpu"]["hits"], v["traversal"][0]["gpu"]["hits"]);
        for kind in ["camera", "shadow", "bounce"] {
            let k = &t["kernel"][kind];
            assert!(k["rays"].as_u64().unwrap() >= 2000, "{kind}: {k:#}");
            assert!(k["mrays_per_second"].as_f64().unwrap() > 0.0, "{kind}: {k:#}");
            assert!(
                k["rays"].as_u64().unwrap().is_multiple_of(k["batch"].as_u64().unwrap()),
                "{k:#}"
            );
        }
    }
}

/// `sylva bench farm`: one frame's time through a coordinator and a warm
/// worker, accounted for stage by stage (the client's stages sum to the
/// total; the worker's render is apart from the overhead).
#[test]
fn farm_benchmark_accounts_for_a_frames_time() {
    let scene = format!("{}/../../examples/tree.json", env!("CARGO_MANIFEST_DIR"));
    let out = ok(&["bench", "farm", &scene, "--repeat", "2", "--width", "64", "--height", "32"]);
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["runs"].as_array().unwrap().len(), 2);
    let runs = v["runs"].as_array().unwrap();
    // Its cost measured, a short frame goes to the one worker whole.
    let last = runs.last().unwrap();
    assert_eq!(last["strips"], 1, "one worker renders a measured short frame as one strip: {v:#}");
    for r in runs {
        let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r:#}"));
        assert!(f("render_ms") > 0.0 && f("total_ms") > f("render_ms"), "{r:#}");
        assert!((f("overhead_ms") - (f("total_ms") - f("render_ms"))).abs() < 1e-6);
        for k in ["submit_ms", "store_ms", "tone_map_and_png_ms", "fetch_ms", "strip_transfer_ms"] {
            assert!(f(k) >= 0.0, "{k} in {r:#}");
        }
    }
    assert!(v["median"]["total_ms"].as_f64().unwrap() > 0.0);
}
