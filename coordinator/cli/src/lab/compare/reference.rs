//! The path-traced reference every method is measured against (saved and
//! reused when asked), the one-bounce reference Boulanger et al.'s terms
//! model, and the progressive path tracer measured as a method of its own.

use super::methods::prepared;
use super::*;

/// The path-traced reference every method is measured against: the one
/// saved for this scene, binary and flags when asked to reuse it, else
/// traced now; with its build and pre-process times and whether it was reused.
pub(super) fn reference(
    a: &CompareArgs,
    ctx: &Tracer,
    scene: &Scene,
    settings: &RenderSettings,
    bar: &ProgressBar,
) -> anyhow::Result<(ReferenceImage, f64, f64, bool)> {
    let cache = a.out.join("reference.bin");
    let key = reference_key(a)?;
    let cached =
        if a.reuse_reference { load_reference(&cache, &key, a.width, a.height) } else { None };
    Ok(match cached {
        Some(r) => (r, 0.0, 0.0, true),
        None => {
            let prepared =
                prepared(ctx, scene, LightingMode::Reference, &|m| bar.set_message(m.to_string()))?;
            let opts = ReferenceOptions {
                target_error: a.target_error,
                max_seconds: a.max_seconds,
                ..Default::default()
            };
            let build_ms = prepared.phases.ms("build");
            let pre = prepared.lighting_ms();
            let frame = Frame::of(ctx, prepared.clone(), *settings);
            let r = frame.reference(&[(0, settings.width)], &opts, &|s| {
                bar.set_message(format!(
                    "reference: {} spp, relative standard error {:.4} (target {})",
                    s.spp, s.relative_error, a.target_error
                ))
            })?;
            save_reference(&cache, &key, &r)?;
            (r, build_ms, pre, false)
        }
    })
}

/// The fractions of the reference's time at which the progressive path
/// tracer's error is measured.
pub(super) const PROGRESSIVE_FRACTIONS: [f64; 5] = [0.01, 0.02, 0.05, 0.1, 0.2];

/// The reference's path tracer run progressively as a method of its own,
/// with other seeds, [`PROGRESSIVE_PASS_SPP`] samples per pixel per pass
/// (jittered over the pixel as the reference's are: a single sample sits at
/// the pixel's centre, and centre samples alone would count edge aliasing
/// as error that never falls): its raw indirect error
/// against the reference (indirect light along its own samples, as the
/// reference's) at 1, 2, 5, 10 and 20 % of the reference's time, and at
/// least twice the passes of the point before (a fast reference would
/// otherwise put every point at one pass). What brute force reaches at the
/// cost of each fast method.
pub(super) fn progressive_path_tracer(
    ctx: &Tracer,
    scene: &Scene,
    f: &RenderSettings,
    r: &ReferenceImage,
    lit: &[bool],
    say: &dyn Fn(&str),
) -> anyhow::Result<Vec<pareto::Point>> {
    let frame = Frame::of(ctx, prepared(ctx, scene, LightingMode::Reference, say)?, *f);
    let n = (f.width * f.height) as usize;
    let (mut sum, mut local) = (vec![[0.0f64; 3]; n], vec![[0.0f64; 3]; n]);
    let mut points = Vec::new();
    let t = Instant::now();
    let mut passes = 0u32;
    for &fraction in &PROGRESSIVE_FRACTIONS {
        let until = fraction * r.stats.ms;
        let at_least = (2 * passes).max(1);
        while passes < at_least || ms(t) < until {
            let settings = RenderSettings {
                spp: PROGRESSIVE_PASS_SPP,
                seed: (f.seed ^ PROGRESSIVE_SEED).wrapping_add(passes.wrapping_mul(0x9E37_79B9)),
                lighting: LightingMode::Reference,
                ..*f
            };
            let s = frame.with_settings(settings).strip(0, f.width)?;
            for i in 0..n {
                for c in 0..3 {
                    sum[i][c] += s.pixels[i][c] as f64;
                    local[i][c] += s.first_light[i][c] as f64;
                }
            }
            passes += 1;
        }
        let mean = |v: &[[f64; 3]]| HdrImage {
            width: f.width,
            height: f.height,
            pixels: v.iter().map(|p| p.map(|x| (x / passes as f64) as f32)).collect(),
        };
        let (image, own) = (mean(&sum), mean(&local));
        let e = IndirectError::measure([&image, &image], [&own, &own], r, lit);
        say(&format!("progressive path tracer: {passes} spp, {:.1} %", 100.0 * e.raw));
        points.push(pareto::Point {
            name: format!("path tracer {} spp", passes * PROGRESSIVE_PASS_SPP),
            family: "progressive path tracer".into(),
            ms: ms(t),
            raw: e.raw,
            net: None,
        });
    }
    Ok(points)
}

/// Samples per pixel of one pass of the progressive path tracer (2 × 2 strata).
pub(super) const PROGRESSIVE_PASS_SPP: u32 = 4;

/// The seed bits of the progressive path tracer's samples.
pub(super) const PROGRESSIVE_SEED: u32 = 0x5EED_0003;

/// The one-bounce image Boulanger et al.'s terms model, converged as the
/// reference is: a gather one bounce deep whose far end is dark (the
/// matched constant set to zero) and whose ground is lit by the sky, with
/// a quarter of the reference's time at most (its paths are short).
pub(super) fn one_bounce_reference(
    a: &CompareArgs,
    ctx: &Tracer,
    scene: &Scene,
    settings: &RenderSettings,
    say: &dyn Fn(&str),
) -> anyhow::Result<ReferenceImage> {
    let prepared = prepared(ctx, scene, LightingMode::GatherAmbient, say)?;
    let f = RenderSettings {
        lighting: LightingMode::GatherAmbient,
        ambient: [0.0; 3],
        gather_bounces: 1,
        gather_filter: 0,
        ..*settings
    };
    let opts = ReferenceOptions {
        target_error: a.target_error,
        max_seconds: a.max_seconds / 4.0,
        ..Default::default()
    };
    Frame::of(ctx, prepared, f).reference(&[(0, f.width)], &opts, &|s| {
        say(&format!(
            "one-bounce reference: {} spp, relative standard error {:.4}",
            s.spp, s.relative_error
        ))
    })
}

/// What a saved reference was made for: the scene's bundle (the scene
/// file and every model file it names, as `sylva submit` packs it), the
/// image, the reference's budget and this very binary.
pub(super) fn reference_key(a: &CompareArgs) -> anyhow::Result<String> {
    let bundle = sylva_scene::bundle::pack(&a.scene)?;
    let mut h = blake3::Hasher::new();
    h.update(bundle.hash.as_bytes());
    h.update(format!("{}x{} {} {}", a.width, a.height, a.target_error, a.max_seconds).as_bytes());
    let exe = std::env::current_exe().context("this program's own file")?;
    let mut file =
        std::fs::File::open(&exe).with_context(|| format!("{}: cannot read", exe.display()))?;
    std::io::copy(&mut file, &mut h).with_context(|| format!("{}: cannot read", exe.display()))?;
    Ok(h.finalize().to_hex().to_string())
}

/// A saved reference and the key it was made for.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct SavedReference {
    key: String,
    reference: ReferenceImage,
}

/// Writes the reference beside the images, for `--reuse-reference`.
pub(super) fn save_reference(path: &Path, key: &str, r: &ReferenceImage) -> anyhow::Result<()> {
    let bytes = postcard::to_stdvec(&SavedReference { key: key.into(), reference: r.clone() })?;
    std::fs::write(path, bytes).with_context(|| format!("{}: cannot write", path.display()))
}

/// The saved reference if it was made for `key` and has the image's size;
/// otherwise `None` (and the reason, logged), so the reference is rendered.
pub(super) fn load_reference(
    path: &Path,
    key: &str,
    width: u32,
    height: u32,
) -> Option<ReferenceImage> {
    let bytes = std::fs::read(path)
        .map_err(|e| tracing::info!("{}: no saved reference ({e})", path.display()))
        .ok()?;
    let saved: SavedReference = postcard::from_bytes(&bytes)
        .map_err(|e| tracing::warn!("{}: unreadable reference ({e})", path.display()))
        .ok()?;
    let n = (width * height) as usize;
    let r = saved.reference;
    let sized = [
        r.image.pixels.len(),
        r.local.pixels.len(),
        r.coverage.len(),
        r.std_error.len(),
        r.indirect_variance.len(),
    ]
    .iter()
    .all(|&l| l == n)
        && r.image.width == width
        && r.image.height == height;
    if saved.key != key || !sized {
        tracing::warn!(
            "{}: made for another scene, size, budget or build; rendering a new reference",
            path.display()
        );
        return None;
    }
    tracing::info!("{}: reusing the saved reference ({} spp)", path.display(), r.stats.spp);
    Some(r)
}
