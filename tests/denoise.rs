//! Denoising (issue 40): a sampled method's frame denoised by Open Image
//! Denoise, guided by the frame's albedo and normal, is nearer the
//! converged frame than the noisy one, keeps the noisy one in its EXR, and
//! comes back from the farm (denoised whole on the coordinator) as one
//! process denoises it, to the bit. Without the library, `--denoise` says
//! what is missing.

use crate::common;

use common::{coordinator, scratch, small_scene, spawn, sylva, wait_for_workers};
use std::path::Path;
use sylva_scene::passes::{ExrLayers, NOISY_LAYER};

fn ok(args: &[&str]) {
    let out = sylva(args, &[]);
    assert!(
        out.status.success(),
        "sylva {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn layers(p: &Path) -> ExrLayers {
    ExrLayers::read(&std::fs::read(p).unwrap()).unwrap()
}

/// A layer's RGB channels, one after another.
fn rgb(l: &ExrLayers, layer: &str) -> Vec<f64> {
    ["R", "G", "B"]
        .iter()
        .flat_map(|c| {
            let name = format!("ViewLayer.{layer}.{c}");
            l.channel(&name).unwrap_or_else(|| panic!("no {name}")).to_vec()
        })
        .map(f64::from)
        .collect()
}

/// Root-mean-square difference from `truth`, relative to its own.
fn error(a: &[f64], truth: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(truth).map(|(x, t)| (x - t).powi(2)).sum();
    let n: f64 = truth.iter().map(|t| t * t).sum();
    (d / n).sqrt()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_denoised_frame_is_nearer_the_converged_one_and_the_farm_gives_the_same_bits() {
    let dir = scratch("denoise");
    let scene = small_scene(&dir);
    let scene = scene.to_str().unwrap();
    // The gather without its filter: noisy at 2 rays a pixel.
    let frame = ["--width", "96", "--height", "48", "--lighting", "gather", "--gather-filter", "0"];
    let frame = [&frame[..], &["--accel", "bvh"]].concat();
    let here = dir.join("here.png");
    let args = ["render", scene, "--local-workers", "0", "-o", here.to_str().unwrap()];
    ok(&[&args[..], &frame, &["--spp", "2", "--denoise"]].concat());
    let converged = dir.join("converged.png");
    let args = ["render", scene, "--local-workers", "0", "-o", converged.to_str().unwrap()];
    ok(&[&args[..], &frame, &["--spp", "64", "--exr", "--passes", "indirect"]].concat());

    let denoised = layers(&here.with_extension("exr"));
    let truth = layers(&converged.with_extension("exr")).beauty().unwrap();
    let truth: Vec<f64> =
        (0..3).flat_map(|c| truth.pixels.iter().map(move |p| f64::from(p[c]))).collect();
    let (noisy, clean) = (rgb(&denoised, NOISY_LAYER), rgb(&denoised, "Combined"));
    let (before, after) = (error(&noisy, &truth), error(&clean, &truth));
    assert!(
        after < 0.8 * before,
        "error against 64 rays a pixel: noisy {before:.4}, denoised {after:.4}"
    );
    // Its guides are in the file too.
    for guide in ["DiffCol.R", "Normal.X"] {
        assert!(denoised.channel(&format!("ViewLayer.{guide}")).is_some(), "no {guide}");
    }

    // Through the farm: strips from two workers, the frame denoised whole.
    let (w1, w2) = (
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
    );
    let workers = format!("{},{}", w1.addr, w2.addr);
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &workers], &[]);
    let mut c = coordinator(&coord.addr, None).await;
    wait_for_workers(&mut c, 2).await;
    let farm = dir.join("farm.png");
    let args = ["submit", scene, "--coordinator", &coord.addr, "-o", farm.to_str().unwrap()];
    ok(&[&args[..], &frame, &["--spp", "2", "--denoise"]].concat());
    let from_farm = layers(&farm.with_extension("exr"));
    let mut names: Vec<&String> = from_farm.channels.iter().map(|c| &c.0).collect();
    names.sort();
    let mut want: Vec<&String> = denoised.channels.iter().map(|c| &c.0).collect();
    want.sort();
    assert_eq!(names, want);
    for (name, values) in &denoised.channels {
        let theirs = from_farm.channel(name).unwrap();
        assert!(
            values.iter().zip(theirs).all(|(a, b)| a.to_bits() == b.to_bits()),
            "{name} differs from the farm's"
        );
    }
    assert_eq!(std::fs::read(&farm).unwrap(), std::fs::read(&here).unwrap(), "the PNGs");

    // The indirect light alone denoised (`--denoise=indirect`): its
    // indirect light nearer the converged frame's, the direct light and
    // the sky as traced, and the farm's frame the same to the bit.
    let alone = dir.join("alone.png");
    let args = ["render", scene, "--local-workers", "0", "-o", alone.to_str().unwrap()];
    ok(&[&args[..], &frame, &["--spp", "2", "--denoise=indirect"]].concat());
    let alone_layers = layers(&alone.with_extension("exr"));
    let (noisy, clean) = (rgb(&alone_layers, NOISY_LAYER), rgb(&alone_layers, "Combined"));
    let traced = rgb(&alone_layers, "Indirect");
    // Combined = noisy − traced indirect + denoised indirect.
    let smooth: Vec<f64> =
        clean.iter().zip(&noisy).zip(&traced).map(|((c, n), t)| c - n + t).collect();
    let truth = rgb(&layers(&converged.with_extension("exr")), "Indirect");
    let (before, after) = (error(&traced, &truth), error(&smooth, &truth));
    assert!(
        after < 0.8 * before,
        "indirect error against 64 rays a pixel: noisy {before:.4}, denoised {after:.4}"
    );
    let farm_alone = dir.join("farm-alone.png");
    let args = ["submit", scene, "--coordinator", &coord.addr, "-o", farm_alone.to_str().unwrap()];
    ok(&[&args[..], &frame, &["--spp", "2", "--denoise=indirect"]].concat());
    let from_farm = layers(&farm_alone.with_extension("exr"));
    for (name, values) in &alone_layers.channels {
        let theirs = from_farm.channel(name).unwrap();
        assert!(
            values.iter().zip(theirs).all(|(a, b)| a.to_bits() == b.to_bits()),
            "{name} differs from the farm's"
        );
    }

    // A coordinator that cannot denoise says so at submit, before any
    // worker renders, and tells the client nothing of its own files.
    let blind = spawn(
        &["coordinator", "--listen", "127.0.0.1:0", "--workers", &w1.addr],
        &[("SYLVA_OIDN_LIB", "/nonexistent/libOpenImageDenoise.so.2")],
    );
    let args = ["submit", scene, "--coordinator", &blind.addr, "-o", farm.to_str().unwrap()];
    let out = sylva(&[&args[..], &frame, &["--spp", "1", "--denoise"]].concat(), &[]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && said.contains("cannot denoise"), "{said}");
    assert!(!said.contains("/nonexistent"), "{said}");

    // Without the library: a clear error, and nothing written.
    let gone = dir.join("gone.png");
    let out = sylva(
        &[
            &["render", scene, "--local-workers", "0", "-o", gone.to_str().unwrap()][..],
            &frame,
            &["--spp", "1", "--denoise"],
        ]
        .concat(),
        &[("SYLVA_OIDN_LIB", "/nonexistent/libOpenImageDenoise.so.2")],
    );
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{said}");
    assert!(
        said.contains("Open Image Denoise is not available") && said.contains("install-deps"),
        "{said}"
    );
    assert!(!gone.exists());
}
