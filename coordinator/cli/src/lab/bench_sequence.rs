//! `sylva bench sequence SCENE`: what rendering a sequence as one job buys,
//! measured on local worker processes in one run (these machines are
//! shared, so every figure has its baseline beside it):
//! - a camera path (an orbit around the scene's target) as one job,
//!   against the same frames as one job each, one after the other, on the
//!   same warm farm;
//! - a sun sweep rendered twice (a preview pass, then a final pass at more
//!   samples, as a shot is reviewed), on workers that keep the LB light per
//!   sun against workers that keep only the sun they are on: the final
//!   pass's per-frame cost and the LB solves each farm did.

use crate::flags::bench_sequence::*;
use crate::loopback::LoopbackProcesses;
use crate::spec::job_spec;
use anyhow::Context;
use serde_json::json;
use std::time::Instant;
use sylva_coordinator::client::submit_and_follow;
use sylva_proto::pb;
use sylva_scene::LightingMode;
use sylva_scene::bundle::SceneBundle;
use sylva_scene::frame::FrameSettings;
use sylva_scene::frame::ScheduleKind;
use sylva_scene::sequence::{CameraKey, SequenceSpec, SunAngles, SunSweep, View};

/// `ELEVATION,AZIMUTH`.
fn angles(s: &str) -> anyhow::Result<SunAngles> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{s:?}: ELEVATION,AZIMUTH"))?;
    anyhow::ensure!(v.len() == 2, "{s:?}: ELEVATION,AZIMUTH");
    Ok(SunAngles { elevation_deg: v[0], azimuth_deg: v[1] })
}

/// A farm of local processes for a benchmark.
pub(super) struct Farm {
    _processes: LoopbackProcesses,
    coordinator: String,
    workers: Vec<String>,
    token: String,
}

impl Farm {
    /// `n` workers (with `worker_flags`) and a coordinator over them.
    pub(super) fn start(n: usize, worker_flags: &[String]) -> anyhow::Result<Self> {
        let token = sylva_proto::auth::random_token();
        let mut p = LoopbackProcesses::default();
        let workers = p.start_workers_with(n, &token, worker_flags)?;
        let coordinator = p.start_coordinator(&workers, &token, &[])?;
        Ok(Self { _processes: p, coordinator, workers, token })
    }

    /// Renders `views` (empty: one plain frame) as one job; milliseconds.
    fn render(
        &self,
        rt: &tokio::runtime::Runtime,
        bundle: &SceneBundle,
        frame: &FrameSettings,
        views: &[View],
    ) -> anyhow::Result<f64> {
        let t = Instant::now();
        self.job(rt, bundle, frame, views)?;
        Ok(t.elapsed().as_secs_f64() * 1e3)
    }

    /// Renders `views` as one job, as `sylva submit` does.
    pub(super) fn job(
        &self,
        rt: &tokio::runtime::Runtime,
        bundle: &SceneBundle,
        frame: &FrameSettings,
        views: &[View],
    ) -> anyhow::Result<sylva_coordinator::client::FinishedJob> {
        let spec = job_spec(frame, views, ScheduleKind::Dynamic, 0, "bench");
        rt.block_on(submit_and_follow(
            &self.coordinator,
            Some(self.token.clone()),
            None,
            spec,
            bundle,
            false,
        ))
    }

    /// The workers' statuses.
    pub(super) fn statuses(
        &self,
        rt: &tokio::runtime::Runtime,
    ) -> anyhow::Result<Vec<pb::WorkerStatus>> {
        rt.block_on(async {
            let mut out = Vec::new();
            for w in &self.workers {
                let mut c =
                    sylva_coordinator::farm::connect(w, Some(self.token.clone()), None).await?;
                out.push(c.status(pb::StatusRequest {}).await?.into_inner());
            }
            Ok(out)
        })
    }

    /// LB solves the workers have done, all together.
    fn lb_solves(&self, rt: &tokio::runtime::Runtime) -> anyhow::Result<u64> {
        Ok(self.statuses(rt)?.iter().map(|s| s.lb_solves).sum())
    }
}

pub fn run(a: SequenceBenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(a.frames >= 2, "--frames {}: a sequence of at least 2", a.frames);
    let text = std::fs::read_to_string(&a.scene)
        .with_context(|| format!("{}: cannot read", a.scene.display()))?;
    let access = sylva_scene::FileAccess::Inside(sylva_scene::folder_of(&a.scene));
    let file = sylva_scene::parse_with(
        &text,
        &a.scene.display().to_string(),
        &access,
        &Default::default(),
    )?;
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    let rt = tokio::runtime::Runtime::new()?;
    let frame = FrameSettings {
        width: a.width,
        height: a.height,
        spp: a.spp,
        lighting: Some(LightingMode::Lb),
        ..Default::default()
    };
    frame.check()?;

    // A quarter orbit around the scene's target, keys every third of the way.
    let (eye, target) =
        (glam::Vec3::from(file.camera.position), glam::Vec3::from(file.camera.look_at));
    let last = a.frames - 1;
    let camera: Vec<CameraKey> = (0..4)
        .map(|k| {
            let turn = glam::Quat::from_rotation_y(std::f32::consts::FRAC_PI_2 * k as f32 / 3.0);
            CameraKey {
                frame: last * k / 3,
                position: (target + turn * (eye - target)).to_array(),
                look_at: file.camera.look_at,
                up: file.camera.up,
                fov_y_deg: file.camera.fov_y_deg,
            }
        })
        .collect();
    let path =
        SequenceSpec { frames: a.frames, sun: None, camera }.views().map_err(anyhow::Error::msg)?;
    let sweep = SunSweep { from: angles(&a.sun_from)?, to: angles(&a.sun_to)? };
    let suns = SequenceSpec { frames: a.frames, sun: Some(sweep), camera: Vec::new() }
        .views()
        .map_err(anyhow::Error::msg)?;
    let n = a.frames as f64;

    // The camera path: warm the farm with one frame, then one job against
    // one job per frame.
    let farm = Farm::start(a.workers, &[])?;
    let warm_ms = farm.render(&rt, &bundle, &frame, &[])?;
    let adapter = farm.statuses(&rt)?.first().map(|s| s.adapter.clone()).unwrap_or_default();
    let sequence_ms = farm.render(&rt, &bundle, &frame, &path)?;
    let mut separate_ms = 0.0;
    for v in &path {
        separate_ms += farm.render(&rt, &bundle, &frame, std::slice::from_ref(v))?;
    }
    drop(farm);

    // The sun sweep, twice, on workers with and without the LB kept per sun.
    let mut sweeps = Vec::new();
    for (name, flags) in [
        ("lb cache", vec![]),
        ("no lb cache", vec!["--lb-cache-entries".to_string(), "0".to_string()]),
    ] {
        let farm = Farm::start(a.workers, &flags)?;
        let preview = FrameSettings { spp: 1, ..frame };
        let preview_ms = farm.render(&rt, &bundle, &preview, &suns)?;
        let preview_solves = farm.lb_solves(&rt)?;
        let final_ms = farm.render(&rt, &bundle, &frame, &suns)?;
        let final_solves = farm.lb_solves(&rt)? - preview_solves;
        sweeps.push(json!({
            "workers": name,
            "preview_pass": { "spp": 1, "ms": preview_ms, "ms_per_frame": preview_ms / n, "lb_solves": preview_solves },
            "final_pass": { "spp": a.spp, "ms": final_ms, "ms_per_frame": final_ms / n, "lb_solves": final_solves },
        }));
    }
    let per_frame =
        |v: &serde_json::Value| v["final_pass"]["ms_per_frame"].as_f64().unwrap_or(f64::NAN);
    let out = json!({
        "benchmark": "sequence",
        "scene": a.scene,
        "frames": a.frames,
        "workers": a.workers,
        "width": a.width,
        "height": a.height,
        "spp": a.spp,
        "lighting": "lb",
        "machine": super::bench::machine(),
        "adapter": adapter,
        "camera_path": {
            "warm_up_frame_ms": warm_ms,
            "one_job_ms": sequence_ms,
            "one_job_ms_per_frame": sequence_ms / n,
            "job_per_frame_ms": separate_ms,
            "job_per_frame_ms_per_frame": separate_ms / n,
            "speedup": separate_ms / sequence_ms,
        },
        "sun_sweep": {
            "from": sweep.from,
            "to": sweep.to,
            "passes": sweeps,
            "final_pass_speedup_from_lb_cache": per_frame(&sweeps[1]) / per_frame(&sweeps[0]),
        },
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
