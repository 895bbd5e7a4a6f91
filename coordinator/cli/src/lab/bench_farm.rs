//! `sylva bench farm SCENE`: where one frame's time goes between `sylva
//! submit` and its file, on a farm of one warm local worker: the client's
//! packing, hashing and upload, the coordinator's dispatch, the worker's
//! render, the strip's way back, the store, the tone map and PNG, the
//! fetch. The worker's render is the in-process trace of the same frame:
//! the rest is the farm's own overhead (issue 39's target: under 50 ms).

use super::bench_sequence::Farm;
use crate::flags::bench_farm::FarmBenchArgs;
use anyhow::Context;
use serde_json::{Value, json};
use std::time::Instant;
use sylva_scene::frame::FrameSettings;

/// The median of `v` (NaN when empty).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// One submission's stages, ms.
fn stages(pack_ms: f64, job: &sylva_coordinator::client::FinishedJob) -> anyhow::Result<Value> {
    let s = &job.stats;
    let f = |v: &Value| v.as_f64().context("a figure missing from the job's stats");
    let strips =
        s["strips"].as_array().with_context(|| format!("the job's stats have no strips: {s}"))?;
    // One worker takes the strips one after another: the sums are its
    // render and the calls' time.
    let sum = |k: &str| -> anyhow::Result<f64> { strips.iter().map(|x| f(&x[k])).sum() };
    let (render, rpc) = (sum("render_ms")?, sum("rpc_ms")?);
    let (upload, farm) = (f(&s["upload_ms"])?, f(&s["phases"]["farm_ms"])?);
    let (store, tone) = (f(&s["phases"]["store_ms"])?, f(&s["phases"]["tone_map_ms"])?);
    // The store ends after the farm (a single frame is stored once whole).
    let stored = f(&s["phases"]["stored_ms"])?.max(farm);
    let t = job.times;
    let total = pack_ms + t.submit_ms + t.wait_ms + t.fetch_ms;
    Ok(json!({
        "pack_ms": pack_ms,
        "submit_ms": t.submit_ms,
        "upload_to_worker_ms": upload,
        "strips": strips.len(),
        "render_ms": render,
        "strip_transfer_ms": rpc - render,
        "dispatch_and_assembly_ms": farm - upload - rpc,
        "store_ms": store,
        "tone_map_and_png_ms": tone,
        "queue_and_events_ms": t.wait_ms - stored - tone,
        "fetch_ms": t.fetch_ms,
        "total_ms": total,
        "overhead_ms": total - render,
    }))
}

pub fn run(a: FarmBenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(a.repeat >= 1, "--repeat {}: at least 1", a.repeat);
    let frame =
        FrameSettings { width: a.width, height: a.height, spp: a.spp, ..Default::default() };
    frame.check()?;
    let rt = tokio::runtime::Runtime::new()?;
    let farm = Farm::start(1, &[])?;
    // A warm worker: the scene prepared and its kernels compiled.
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    let warm = Instant::now();
    farm.job(&rt, &bundle, &frame, &[])?;
    let warm_ms = warm.elapsed().as_secs_f64() * 1e3;
    let adapter = farm.statuses(&rt)?.first().map(|s| s.adapter.clone()).unwrap_or_default();
    let mut runs = Vec::with_capacity(a.repeat);
    for _ in 0..a.repeat {
        // As `sylva submit` does: the scene packed and hashed each time.
        let t = Instant::now();
        let bundle = sylva_scene::bundle::pack(&a.scene)?;
        let pack_ms = t.elapsed().as_secs_f64() * 1e3;
        let job = farm.job(&rt, &bundle, &frame, &[])?;
        runs.push(stages(pack_ms, &job)?);
    }
    let keys: Vec<String> =
        runs[0].as_object().map(|o| o.keys().cloned().collect()).unwrap_or_default();
    let medians: serde_json::Map<String, Value> = keys
        .iter()
        .map(|k| (k.clone(), json!(median(runs.iter().filter_map(|r| r[k].as_f64()).collect()))))
        .collect();
    let out = json!({
        "benchmark": "farm",
        "scene": a.scene,
        "width": a.width,
        "height": a.height,
        "spp": a.spp,
        "bundle_bytes": bundle.bytes.len(),
        "machine": super::bench::machine(),
        "adapter": adapter,
        "workers": 1,
        "warm_up_ms": warm_ms,
        "repeat": a.repeat,
        "figures": {
            "render_ms": "the worker's render of the frame's strips, summed: the trace a single process does",
            "strip_transfer_ms": "the strips' calls less their render: sending the strips back and checking them",
            "overhead_ms": "everything else between packing the scene and holding the PNG: the farm's own cost",
            "dispatch_and_assembly_ms": "the coordinator's farm phase less the scene's upload and the strips' calls",
            "queue_and_events_ms": "the client's wait less the coordinator's farm, store and tone-map phases: queueing, events, recording the end (negative when the job started before the submission's reply reached the client)",
        },
        "median": medians,
        "runs": runs,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
