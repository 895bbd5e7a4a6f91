//! Render passes through the farm as a user asks for them: `sylva submit
//! --passes` over two real workers gives the multi-layer EXR the
//! in-process renderer writes, to the bit; `sylva fetch` and sequences
//! keep it.

use crate::common;

use common::{coordinator, scratch, small_scene, spawn, sylva, wait_for_workers};
use std::path::Path;
use sylva_scene::passes::{ExrLayers, Pass, PassSet};

fn ok(args: &[&str]) -> String {
    let out = sylva(args, &[]);
    assert!(
        out.status.success(),
        "sylva {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn layers(p: &Path) -> ExrLayers {
    ExrLayers::read(&std::fs::read(p).unwrap()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn passes_come_back_from_the_farm_as_the_renderer_writes_them_and_sequences_keep_them() {
    let dir = scratch("passes");
    let scene = small_scene(&dir);
    let scene = scene.to_str().unwrap();
    let (w1, w2) = (
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
    );
    let workers = format!("{},{}", w1.addr, w2.addr);
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &workers], &[]);
    let addr = coord.addr.clone();
    let mut c = coordinator(&addr, None).await;
    wait_for_workers(&mut c, 2).await;
    let frame =
        ["--width", "72", "--height", "40", "--spp", "2", "--lighting", "lb", "--accel", "bvh"];

    // Through the farm: asking for passes is asking for the EXR.
    let farm = dir.join("farm.png");
    let mut args = vec![
        "submit",
        scene,
        "--coordinator",
        &addr,
        "-o",
        farm.to_str().unwrap(),
        "--passes",
        "all",
    ];
    args.extend(frame);
    let said = ok(&args);
    let id = said.split_whitespace().next().unwrap().to_string();
    let got = layers(&dir.join("farm.exr"));
    assert_eq!(
        got.pass_set(),
        PassSet::all(),
        "layers: {:?}",
        got.channels.iter().map(|c| &c.0).collect::<Vec<_>>()
    );
    for name in [
        "ViewLayer.Combined.R",
        "ViewLayer.Combined.A",
        "ViewLayer.Direct.G",
        "ViewLayer.Indirect.B",
        "ViewLayer.Env.R",
        "ViewLayer.DiffCol.R",
        "ViewLayer.Normal.X",
        "ViewLayer.Depth.Z",
        "ViewLayer.IndexOB.X",
        "ViewLayer.IndexSpecies.X",
    ] {
        assert!(got.channel(name).is_some(), "no {name}");
    }
    // Combined carries alpha as Cycles writes it: 1 on an opaque film.
    assert!(got.channel("ViewLayer.Combined.A").unwrap().iter().all(|&a| a == 1.0));

    // This process's renderer writes the same file, layer for layer.
    let here = dir.join("here.png");
    let mut args = vec![
        "render",
        scene,
        "--local-workers",
        "0",
        "-o",
        here.to_str().unwrap(),
        "--passes",
        "all",
    ];
    args.extend(frame);
    ok(&args);
    let want = layers(&dir.join("here.exr"));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for (name, values) in &want.channels {
        assert_eq!(bits(got.channel(name).unwrap()), bits(values), "{name}: the farm's differs");
    }
    // The split adds up to the image in the file too; both trees are named.
    let beauty = got.beauty().unwrap();
    let passes = got.passes(PassSet::all()).unwrap();
    let (d, i, s) = (
        passes.plane(Pass::Direct).unwrap(),
        passes.plane(Pass::Indirect).unwrap(),
        passes.plane(Pass::Sky).unwrap(),
    );
    for (n, p) in beauty.pixels.iter().enumerate() {
        for c in 0..3 {
            let sum = d[3 * n + c] + i[3 * n + c] + s[3 * n + c];
            assert!(
                (sum - p[c]).abs() <= 2e-6 * p[c].abs().max(1e-3),
                "pixel {n}: {sum} vs {}",
                p[c]
            );
        }
    }
    let mut ids: Vec<u32> =
        passes.plane(Pass::Instance).unwrap().iter().map(|&v| v as u32).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids, [0, 1, 2], "the ground or sky, and both instances");

    // `sylva fetch` gives the stored file back.
    let fetched = dir.join("fetched.exr");
    ok(&["fetch", &id, "--coordinator", &addr, "-o", fetched.to_str().unwrap()]);
    assert_eq!(std::fs::read(&fetched).unwrap(), std::fs::read(dir.join("farm.exr")).unwrap());

    // A sequence keeps each frame's passes; its first frame is the job above's view.
    let shot = dir.join("shot.png");
    let mut args = vec![
        "submit",
        scene,
        "--coordinator",
        &addr,
        "-o",
        shot.to_str().unwrap(),
        "--passes",
        "depth,instance",
        "--frames",
        "2",
        "--sun-from",
        "50,120",
        "--sun-to",
        "30,160",
    ];
    args.extend(frame);
    ok(&args);
    for k in 0..2 {
        let l = layers(&dir.join(format!("shot-{k:04}.exr")));
        let set = PassSet::parse("depth,instance").unwrap();
        assert_eq!(l.pass_set(), set);
        // The camera does not move: the guides are the single frame's.
        let p = l.passes(set).unwrap();
        assert_eq!(
            bits(p.plane(Pass::Depth).unwrap()),
            bits(passes.plane(Pass::Depth).unwrap()),
            "frame {k}"
        );
    }
}

/// Asking for one part of the light split writes all three, so the file's
/// layers add up to its image (`--passes direct` once wrote no Indirect).
#[test]
fn one_part_of_the_light_split_brings_the_other_two_and_they_add_up() {
    let dir = scratch("passes-split");
    let scene = small_scene(&dir);
    for (asked, name) in [("direct", "direct"), ("indirect", "indirect"), ("sky", "sky")] {
        let png = dir.join(format!("{name}.png"));
        ok(&[
            "render",
            scene.to_str().unwrap(),
            "--local-workers",
            "0",
            "-o",
            png.to_str().unwrap(),
            "--width",
            "48",
            "--height",
            "24",
            "--lighting",
            "lb",
            "--passes",
            asked,
        ]);
        let got = layers(&png.with_extension("exr"));
        let split = PassSet::of([Pass::Direct, Pass::Indirect, Pass::Sky]);
        assert_eq!(got.pass_set(), split, "--passes {asked}");
        for layer in ["Direct", "Indirect", "Env"] {
            assert!(got.channel(&format!("ViewLayer.{layer}.R")).is_some(), "{asked}: no {layer}");
        }
        let beauty = got.beauty().unwrap();
        let p = got.passes(split).unwrap();
        let (d, i, s) = (
            p.plane(Pass::Direct).unwrap(),
            p.plane(Pass::Indirect).unwrap(),
            p.plane(Pass::Sky).unwrap(),
        );
        for (n, px) in beauty.pixels.iter().enumerate() {
            for c in 0..3 {
                let sum = d[3 * n + c] + i[3 * n + c] + s[3 * n + c];
                assert!(
                    (sum - px[c]).abs() <= 2e-6 * px[c].abs().max(1e-3),
                    "--passes {asked}, pixel {n}: {sum} vs {}",
                    px[c]
                );
            }
        }
    }
}
