//! Prepared data a farm shares, so that N workers pre-process a scene once
//! instead of N times: the models' acceleration structures (the costly
//! part of both levels) and the scene's LB light for one sun, serialized
//! with postcard and named by the BLAKE3 hash of the bytes.
//!
//! What arrives comes from another worker and is checked before use, as a
//! bundle is: its size as it arrives (by the caller), its hash, then every
//! structure against its model (`SceneAccel::from_models`: walks end, leaves
//! and indices stay in range) and every LB grid's shape and values. Data
//! that passes can at worst light a frame wrongly, as a bad strip can; it
//! cannot stop this worker or read outside its buffers.

use crate::lighting::lb::SceneLb;
use serde::{Deserialize, Serialize};
use sylva_accel::{Accel, AccelKind, SceneAccel};
use sylva_scene::Scene;

/// The layout's version: data of another version is refused, not misread.
const FORMAT: u32 = 3;

/// What goes over the wire, borrowed for encoding.
#[derive(Serialize)]
struct Outgoing<'a> {
    format: u32,
    models: &'a [Accel],
    lb: Option<&'a SceneLb>,
    choice: Option<&'a SharedChoice>,
}

/// The same fields, owned, as they are decoded.
#[derive(Deserialize)]
struct Incoming {
    format: u32,
    models: Vec<Accel>,
    lb: Option<SceneLb>,
    choice: Option<SharedChoice>,
}

/// `--accel auto`'s choice as the preparing worker measured it: workers
/// with the same adapter take it instead of measuring again, so a farm of
/// alike GPUs traces every strip of a frame alike.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SharedChoice {
    /// The adapter it was measured on (`GpuContext::adapter_name`).
    pub adapter: String,
    /// What it chose.
    pub backend: sylva_scene::frame::Backend,
    /// Why (the measurement).
    pub why: String,
}

/// What prepared data holds, checked.
pub struct Imported {
    /// Both levels, built around the received model structures.
    pub accel: Option<SceneAccel>,
    /// The LB light.
    pub lb: Option<SceneLb>,
    /// The preparing worker's `auto` choice, if it made one.
    pub choice: Option<SharedChoice>,
}

/// Prepared data as one worker exports it.
pub struct Exported {
    /// The serialized data.
    pub bytes: Vec<u8>,
    /// BLAKE3 of `bytes`, hex.
    pub hash: String,
}

/// Serializes a scene's model structures (none for ray queries: each
/// device builds its own) and, when given, its LB light.
pub fn export(
    accel: Option<&SceneAccel>,
    lb: Option<&SceneLb>,
    choice: Option<&SharedChoice>,
) -> anyhow::Result<Exported> {
    let models = accel.map_or(&[][..], |a| a.models.as_slice());
    let bytes = postcard::to_stdvec(&Outgoing { format: FORMAT, models, lb, choice })?;
    let hash = blake3::hash(&bytes).to_hex().to_string();
    Ok(Exported { bytes, hash })
}

/// Why prepared data was refused: another worker's (or the disk's) bytes
/// that do not hold together for this scene.
#[derive(Debug, thiserror::Error)]
pub enum Refused {
    /// Bytes that are not what their hash says.
    #[error("the prepared data's bytes do not match its hash")]
    Hash,
    /// Bytes that do not decode.
    #[error("the prepared data cannot be read: {0}")]
    Unreadable(postcard::Error),
    /// Another format version.
    #[error("prepared data of format {0} where this worker reads {FORMAT}")]
    Format(u32),
    /// No LB light where the frame's lighting needs it.
    #[error("the prepared data holds no LB light, which this frame's lighting needs")]
    NoLb,
    /// Structures where ray queries need none.
    #[error("the prepared data holds structures where none was asked for")]
    UnaskedStructures,
    /// Structures that do not fit the scene's models.
    #[error("{0}")]
    Structures(sylva_accel::Error),
    /// LB light that does not fit the scene.
    #[error("{0}")]
    Lb(String),
}

/// Reads prepared data for `scene`: its hash must be `hash`, its
/// structures of `kind` (none when `None`) and fit the scene's models, and
/// its LB light (which it must hold when `want_lb`) fit the scene.
pub fn import(
    bytes: &[u8],
    hash: &str,
    scene: &Scene,
    kind: Option<AccelKind>,
    want_lb: bool,
) -> Result<Imported, Refused> {
    if blake3::hash(bytes).to_hex().as_str() != hash {
        return Err(Refused::Hash);
    }
    let d: Incoming = postcard::from_bytes(bytes).map_err(Refused::Unreadable)?;
    if d.format != FORMAT {
        return Err(Refused::Format(d.format));
    }
    let lb = match (d.lb, want_lb) {
        (Some(lb), true) => {
            check_lb(&lb, scene)?;
            Some(lb)
        }
        (None, true) => return Err(Refused::NoLb),
        (_, false) => None,
    };
    let accel = match kind {
        Some(kind) => {
            Some(SceneAccel::from_models(scene, kind, d.models).map_err(Refused::Structures)?)
        }
        None if d.models.is_empty() => None,
        None => return Err(Refused::UnaskedStructures),
    };
    // Another worker's words: bounded before they are kept and shown.
    let choice = d.choice.map(|c| SharedChoice {
        adapter: c.adapter.chars().take(256).collect(),
        why: c.why.chars().take(1024).collect(),
        ..c
    });
    Ok(Imported { accel, lb, choice })
}

/// Checks LB light received for `scene`: one entry per model and per
/// instance, every grid's values as many as its nodes, finite and not
/// negative, and grid frames with finite corners and positive cells.
fn check_lb(lb: &SceneLb, scene: &Scene) -> Result<(), Refused> {
    let (models, instances) = (scene.models.len(), scene.instances.len());
    if lb.grids.len() != models || lb.light.len() != models || lb.scales.len() != instances {
        return Err(Refused::Lb(format!(
            "LB light for {} models ({} reports) and {} instances, in a scene of {models} models and {instances} instances",
            lb.grids.len(),
            lb.light.len(),
            lb.scales.len()
        )));
    }
    let light = |v: &[f32]| v.iter().all(|x| x.is_finite() && *x >= 0.0);
    if !light(&lb.scales) {
        return Err(Refused::Lb("LB instance scales that are not finite and positive".into()));
    }
    for (i, g) in lb.grids.iter().enumerate() {
        let Some(g) = g else { continue };
        let nodes = g
            .dims
            .nx
            .checked_mul(g.dims.ny)
            .and_then(|n| n.checked_mul(g.dims.nz))
            .and_then(|n| n.checked_mul(3));
        let framed = g.frame.origin.iter().all(|v| v.is_finite())
            && g.frame.cell.is_finite()
            && g.frame.cell > 0.0;
        if nodes != Some(g.rgb.len())
            || g.dims.nx < 3
            || g.dims.ny < 3
            || g.dims.nz < 3
            || !framed
            || !light(&g.rgb)
        {
            return Err(Refused::Lb(format!(
                "model {i}'s LB grid: its shape, frame or values do not hold together"
            )));
        }
    }
    if let Some(ground) = &lb.ground {
        let framed = ground.origin.iter().all(|v| v.is_finite())
            && ground.cell.is_finite()
            && ground.cell > 0.0;
        let nodes = ground.nx.checked_mul(ground.nz).and_then(|n| n.checked_mul(3));
        if nodes != Some(ground.rgb.len()) || !framed || !light(&ground.rgb) {
            return Err(Refused::Lb(
                "the ground's LB light: its shape, frame or values do not hold together".into(),
            ));
        }
    }
    Ok(())
}
