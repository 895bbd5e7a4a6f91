//! `--accel auto`: which traversal backend a worker's adapter runs faster:
//! the four-wide BVH, the eight-wide compressed one, and ray queries where
//! the device has them. Each is uploaded, the same probe rays (the
//! camera's, and shadow rays toward the sun from their hits) are cast
//! through each, and the fastest is kept.
//!
//! The probe grows its batches fourfold until one backend is clearly the
//! faster or its time is spent: on lavapipe ray queries trace some 300
//! times slower than the BVH (benchmarks/results/issue-28), and a fixed
//! batch big enough to time the BVH would take the other seconds.

use super::{GpuRay, GpuScene, RayCaster};
use crate::gpu::GpuContext;
use serde::Serialize;
use std::time::Instant;
use sylva_scene::Scene;
use sylva_scene::frame::Backend;

/// Probe image: one camera ray per pixel of this many columns and rows.
const PROBE_SIZE: (u32, u32) = (128, 64);
/// Camera rays (and as many shadow rays) in the first timed batch.
const FIRST_BATCH: usize = 256;
/// Speed ratio at which one backend is clearly the faster.
const CLEAR_RATIO: f64 = 1.5;
/// Seconds the probe may spend on timed batches before it settles on what
/// it has measured.
const PROBE_SECONDS: f64 = 1.0;
/// A batch this long is timed, not lost in a shared machine's noise.
const TIMED_SECONDS: f64 = 0.01;
/// Rounds over all the probe's rays, when no backend has left the race.
const FULL_ROUNDS: usize = 3;

/// One backend's speed on the probe rays.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ProbeTime {
    /// The backend.
    pub backend: Backend,
    /// Camera and shadow rays per second, millions (best round).
    pub mrays_per_second: f64,
}

/// The backend a preparation chose, and why.
#[derive(Clone, Debug, Serialize)]
pub struct BackendChoice {
    /// What the frame asked for.
    pub asked: Backend,
    /// What rays traverse.
    pub backend: Backend,
    /// Why, in a sentence.
    pub why: String,
    /// `auto`'s measurement (empty when nothing was measured).
    pub probe: Vec<ProbeTime>,
}

impl BackendChoice {
    /// The choice when only one backend was a candidate.
    pub fn asked(asked: Backend, backend: Backend, ctx: &GpuContext) -> Self {
        let why = match asked {
            Backend::Auto => format!(
                "auto: {}, the one candidate on {} that holds this scene",
                backend.name(),
                ctx.adapter_name()
            ),
            _ => format!("asked for {}", backend.name()),
        };
        Self { asked, backend, why, probe: Vec::new() }
    }
}

/// The backends a preparation builds for `asked` on this device.
pub fn candidates(ctx: &GpuContext, asked: Backend) -> anyhow::Result<Vec<Backend>> {
    Ok(match asked.resolved() {
        Some(Backend::Rq) if !ctx.has_ray_queries() => anyhow::bail!(
            "--accel rq: {} offers no ray queries (wgpu's EXPERIMENTAL_RAY_QUERY); use auto, bvh, cwbvh or kd",
            ctx.adapter_name()
        ),
        Some(b) => vec![b],
        // The BVH first: its hits make the probe's shadow rays (the walk is
        // never pathologically slow).
        None if ctx.has_ray_queries() => vec![Backend::Bvh, Backend::Cwbvh, Backend::Rq],
        None => vec![Backend::Bvh, Backend::Cwbvh],
    })
}

/// How many times slower than the fastest a backend must have been on an
/// adapter's last probe (of any scene) to be left out of the next scene's:
/// neither built nor measured. Well outside what separates the compute
/// walks (within 2×: 0.13 against 0.26 Mrays/s on the 0.01 forest, on a
/// busy machine), inside what separates lavapipe's ray queries from its
/// BVH (50, 80 and 300 times on one tree, the full forest and the 0.05
/// forest; 8 times on the 0.01 forest, which is then measured again).
pub const LEFT_BEHIND: f64 = 10.0;

/// The candidates still worth measuring after the adapter's `last` probe,
/// and a sentence for each one left out. The first candidate, the BVH,
/// always stays: it runs everywhere, and its hits make the probe's rays.
pub fn worth_measuring(
    candidates: Vec<Backend>,
    last: &[ProbeTime],
) -> (Vec<Backend>, Vec<String>) {
    let best = last.iter().max_by(|a, b| a.mrays_per_second.total_cmp(&b.mrays_per_second));
    let Some(best) = best else { return (candidates, Vec::new()) };
    let mut why = Vec::new();
    let kept = candidates
        .into_iter()
        .enumerate()
        .filter(|&(i, b)| {
            let slow = last.iter().find(|t| t.backend == b).filter(|t| {
                i > 0 && t.mrays_per_second * LEFT_BEHIND < best.mrays_per_second
            });
            if let Some(t) = slow {
                why.push(format!(
                    "{} left out: {:.4} Mrays/s against {}'s {:.2} when this adapter was last measured",
                    b.name(),
                    t.mrays_per_second,
                    best.backend.name(),
                    best.mrays_per_second
                ));
            }
            slow.is_none()
        })
        .map(|(_, b)| b)
        .collect();
    (kept, why)
}

/// Casts the probe through each upload and keeps the fastest.
pub fn choose(
    ctx: &GpuContext,
    scene: &Scene,
    asked: Backend,
    uploads: Vec<GpuScene>,
) -> anyhow::Result<(GpuScene, BackendChoice)> {
    let (w, h) = PROBE_SIZE;
    let cam = scene.camera;
    let primary: Vec<GpuRay> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| GpuRay {
            origin: cam.position.to_array(),
            t_min: 0.0,
            dir: cam.direction(x as f32 + 0.5, y as f32 + 0.5, w, h).to_array(),
            t_max: f32::MAX,
        })
        .collect();
    let mut shadow: Option<Vec<GpuRay>> = None;
    let mut casters = Vec::new();
    let mut kept = Vec::new();
    for (i, g) in uploads.into_iter().enumerate() {
        let ready = (|| -> anyhow::Result<(RayCaster, RayCaster)> {
            let closest = RayCaster::new(ctx, &g)?;
            let blocked = RayCaster::shadow(ctx, &g)?;
            // The first structure's hits give every structure's shadow rays.
            if shadow.is_none() {
                let hits = closest.cast(ctx, &g, &primary)?;
                let towards = scene.sun.towards;
                shadow = Some(
                    primary
                        .iter()
                        .zip(&hits)
                        .filter(|(_, h)| h.triangle != super::raycast::NO_HIT)
                        .map(|(r, h)| {
                            let o = glam::Vec3::from(r.origin) + glam::Vec3::from(r.dir) * h.t;
                            GpuRay {
                                origin: o.to_array(),
                                t_min: 1e-3,
                                dir: towards.to_array(),
                                t_max: f32::MAX,
                            }
                        })
                        .collect(),
                );
            }
            // The first dispatches compile the kernels.
            closest.cast(ctx, &g, &primary[..64])?;
            let s = shadow.as_deref().expect("made above");
            blocked.cast(ctx, &g, &s[..s.len().min(64)])?;
            Ok((closest, blocked))
        })();
        match ready {
            Ok(c) => {
                casters.push(c);
                kept.push(g);
            }
            // A candidate whose kernels this device refuses (the wide
            // BVH's stack needs 16 KB of workgroup memory) is left out;
            // the first, the BVH, runs everywhere.
            Err(e) if i > 0 => tracing::warn!("auto: leaving {} out: {e:#}", g.backend.name()),
            Err(e) => return Err(e),
        }
    }
    let uploads = kept;
    let shadow = shadow.expect("one candidate at least");
    // A machine's noise only ever slows a batch down, so each backend's
    // best speed so far is a bound it surely reaches. A backend leaves the
    // race once the leader is clearly faster and its own batch took long
    // enough to time (its slowness is then measured, not noise); at full
    // size, rounds repeat for the best of several.
    let start = Instant::now();
    let mut n = FIRST_BATCH;
    let mut best = vec![0f64; uploads.len()];
    let mut racing = vec![true; uploads.len()];
    let mut full_rounds = 0;
    loop {
        let (p, s) = (&primary[..n.min(primary.len())], &shadow[..n.min(shadow.len())]);
        let mut took = vec![0f64; uploads.len()];
        for (i, (g, (closest, blocked))) in uploads.iter().zip(&casters).enumerate() {
            if !racing[i] {
                continue;
            }
            let t = Instant::now();
            closest.cast(ctx, g, p)?;
            blocked.cast(ctx, g, s)?;
            took[i] = t.elapsed().as_secs_f64();
            best[i] = best[i].max((p.len() + s.len()) as f64 / took[i] / 1e6);
        }
        let lead = best.iter().copied().fold(0f64, f64::max);
        for i in 0..uploads.len() {
            if racing[i] && lead > CLEAR_RATIO * best[i] && took[i] >= TIMED_SECONDS {
                racing[i] = false;
            }
        }
        if n >= primary.len().max(shadow.len()) {
            full_rounds += 1;
        } else {
            n *= 4;
        }
        let racers = racing.iter().filter(|&&r| r).count();
        if racers <= 1
            || full_rounds >= FULL_ROUNDS
            || start.elapsed().as_secs_f64() > PROBE_SECONDS
        {
            break;
        }
    }
    let k = (0..uploads.len()).max_by(|&a, &b| best[a].total_cmp(&best[b])).expect("candidates");
    let probe: Vec<ProbeTime> = uploads
        .iter()
        .zip(&best)
        .map(|(g, &m)| ProbeTime { backend: g.backend, mrays_per_second: m })
        .collect();
    let figures: Vec<String> =
        probe.iter().map(|p| format!("{} {:.2}", p.backend.name(), p.mrays_per_second)).collect();
    let chosen = uploads[k].backend;
    let why = format!(
        "auto: {} is the faster on {} (Mrays/s on camera rays and their shadow rays: {})",
        chosen.name(),
        ctx.adapter_name(),
        figures.join(", ")
    );
    tracing::info!("{why}");
    let gpu_scene = uploads.into_iter().nth(k).expect("chosen");
    Ok((gpu_scene, BackendChoice { asked, backend: chosen, why, probe }))
}
