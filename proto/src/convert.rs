//! The wire form of Sylva's typed values, converted in one place: frames
//! ([`FrameSettings`]), lighting methods, structures and schedules. A value
//! the wire cannot name (an enum number this build does not know) or a
//! frame that fails its checks is refused here, with INVALID_ARGUMENT.

use crate::pb;
use sylva_scene::LightingMode;
use sylva_scene::format::CameraSpec;
use sylva_scene::frame::{Backend, Denoise, FrameSettings, ScheduleKind};
use sylva_scene::passes::{Pass, PassSet};
use sylva_scene::sequence::View;
use tonic::Status;

/// The wire's lighting for a method (`None`: the scene's).
pub fn lighting_to_wire(l: Option<LightingMode>) -> pb::Lighting {
    match l {
        None => pb::Lighting::Scene,
        Some(LightingMode::Local) => pb::Lighting::Local,
        Some(LightingMode::Ambient) => pb::Lighting::Ambient,
        Some(LightingMode::Lb) => pb::Lighting::Lb,
        Some(LightingMode::LbVisualize) => pb::Lighting::LbVisualize,
        Some(LightingMode::Reference) => pb::Lighting::Reference,
        Some(LightingMode::Boulanger) => pb::Lighting::Boulanger,
        Some(LightingMode::Gather) => pb::Lighting::Gather,
        Some(LightingMode::GatherAmbient) => pb::Lighting::GatherAmbient,
    }
}

/// The method a wire lighting number names.
pub fn lighting_from_wire(v: i32) -> Result<Option<LightingMode>, Status> {
    Ok(
        match pb::Lighting::try_from(v).map_err(|_| {
            Status::invalid_argument(format!(
                "lighting {v}: not a lighting method this worker knows"
            ))
        })? {
            pb::Lighting::Scene => None,
            pb::Lighting::Local => Some(LightingMode::Local),
            pb::Lighting::Ambient => Some(LightingMode::Ambient),
            pb::Lighting::Lb => Some(LightingMode::Lb),
            pb::Lighting::LbVisualize => Some(LightingMode::LbVisualize),
            pb::Lighting::Reference => Some(LightingMode::Reference),
            pb::Lighting::Boulanger => Some(LightingMode::Boulanger),
            pb::Lighting::Gather => Some(LightingMode::Gather),
            pb::Lighting::GatherAmbient => Some(LightingMode::GatherAmbient),
        },
    )
}

/// The traversal a wire number names.
pub fn accel_from_wire(v: i32) -> Result<Backend, Status> {
    match pb::Accel::try_from(v) {
        Ok(pb::Accel::Bvh) => Ok(Backend::Bvh),
        Ok(pb::Accel::Kd) => Ok(Backend::Kd),
        Ok(pb::Accel::Auto) => Ok(Backend::Auto),
        Ok(pb::Accel::Rq) => Ok(Backend::Rq),
        Ok(pb::Accel::Cwbvh) => Ok(Backend::Cwbvh),
        Err(_) => Err(Status::invalid_argument(format!(
            "accel {v}: not a traversal this worker knows (auto, rq, bvh, cwbvh, kd)"
        ))),
    }
}

/// The wire's traversal.
pub fn accel_to_wire(a: Backend) -> pb::Accel {
    match a {
        Backend::Auto => pb::Accel::Auto,
        Backend::Rq => pb::Accel::Rq,
        Backend::Bvh => pb::Accel::Bvh,
        Backend::Kd => pb::Accel::Kd,
        Backend::Cwbvh => pb::Accel::Cwbvh,
    }
}

/// The wire's schedule.
pub fn schedule_to_wire(s: ScheduleKind) -> pb::Schedule {
    match s {
        ScheduleKind::Static => pb::Schedule::Static,
        ScheduleKind::Dynamic => pb::Schedule::Dynamic,
    }
}

/// The schedule a wire number names.
pub fn schedule_from_wire(v: i32) -> Result<ScheduleKind, Status> {
    match pb::Schedule::try_from(v) {
        Ok(pb::Schedule::Dynamic) => Ok(ScheduleKind::Dynamic),
        Ok(pb::Schedule::Static) => Ok(ScheduleKind::Static),
        Err(_) => Err(Status::invalid_argument(format!("schedule {v}: static or dynamic"))),
    }
}

impl TryFrom<&pb::FrameSettings> for FrameSettings {
    type Error = Status;

    /// Reads and checks a frame from the wire.
    fn try_from(f: &pb::FrameSettings) -> Result<Self, Status> {
        let ambient = match f.ambient.as_slice() {
            [] => None,
            [r, g, b] => Some([*r, *g, *b]),
            other => {
                return Err(Status::invalid_argument(format!(
                    "ambient: three values or none, not {}",
                    other.len()
                )));
            }
        };
        let frame = FrameSettings {
            width: f.width,
            height: f.height,
            spp: f.spp,
            seed: f.seed,
            lighting: lighting_from_wire(f.lighting)?,
            accel: accel_from_wire(f.accel)?,
            lb_strength: f.lb_strength,
            ambient,
            view: f.view.as_ref().map(View::try_from).transpose()?.unwrap_or_default(),
            gather_bounces: if f.gather_bounces == 0 {
                sylva_scene::frame::DEFAULT_GATHER_BOUNCES
            } else {
                f.gather_bounces
            },
            gather_filter: f.gather_filter.unwrap_or(sylva_scene::frame::DEFAULT_GATHER_FILTER),
            passes: passes_from_wire(&f.passes)?,
            denoise: match pb::Denoise::try_from(f.denoise) {
                Ok(pb::Denoise::Off) => Denoise::Off,
                Ok(pb::Denoise::Frame) => Denoise::Frame,
                Ok(pb::Denoise::Indirect) => Denoise::Indirect,
                Err(_) => {
                    return Err(Status::invalid_argument(format!(
                        "denoise {}: one of off, frame, indirect",
                        f.denoise
                    )));
                }
            },
        };
        frame.check().map_err(|e| Status::invalid_argument(e.to_string()))?;
        Ok(frame)
    }
}

impl From<&FrameSettings> for pb::FrameSettings {
    fn from(f: &FrameSettings) -> Self {
        pb::FrameSettings {
            width: f.width,
            height: f.height,
            spp: f.spp,
            seed: f.seed,
            lighting: lighting_to_wire(f.lighting).into(),
            accel: accel_to_wire(f.accel).into(),
            lb_strength: f.lb_strength,
            ambient: f.ambient.map(|a| a.to_vec()).unwrap_or_default(),
            view: (f.view != View::default()).then(|| pb::FrameView::from(&f.view)),
            gather_bounces: f.gather_bounces,
            gather_filter: Some(f.gather_filter),
            passes: passes_to_wire(f.passes),
            denoise: match f.denoise {
                Denoise::Off => pb::Denoise::Off,
                Denoise::Frame => pb::Denoise::Frame,
                Denoise::Indirect => pb::Denoise::Indirect,
            }
            .into(),
        }
    }
}

/// The passes a frame's wire numbers name.
pub fn passes_from_wire(v: &[i32]) -> Result<PassSet, Status> {
    let mut out = Vec::with_capacity(v.len());
    for &n in v {
        out.push(match pb::Pass::try_from(n) {
            Ok(pb::Pass::Beauty) => Pass::Beauty,
            Ok(pb::Pass::Direct) => Pass::Direct,
            Ok(pb::Pass::Indirect) => Pass::Indirect,
            Ok(pb::Pass::Albedo) => Pass::Albedo,
            Ok(pb::Pass::Normal) => Pass::Normal,
            Ok(pb::Pass::Depth) => Pass::Depth,
            Ok(pb::Pass::Instance) => Pass::Instance,
            Ok(pb::Pass::Species) => Pass::Species,
            Ok(pb::Pass::Sky) => Pass::Sky,
            Err(_) => return Err(Status::invalid_argument(format!("pass {n}: no such pass"))),
        });
    }
    Ok(PassSet::of(out))
}

/// A frame's passes as wire numbers.
pub fn passes_to_wire(set: PassSet) -> Vec<i32> {
    set.extra()
        .map(|p| {
            match p {
                Pass::Beauty => pb::Pass::Beauty,
                Pass::Direct => pb::Pass::Direct,
                Pass::Indirect => pb::Pass::Indirect,
                Pass::Albedo => pb::Pass::Albedo,
                Pass::Normal => pb::Pass::Normal,
                Pass::Depth => pb::Pass::Depth,
                Pass::Instance => pb::Pass::Instance,
                Pass::Species => pb::Pass::Species,
                Pass::Sky => pb::Pass::Sky,
            }
            .into()
        })
        .collect()
}

/// Three values from the wire, or why not.
fn three(v: &[f32], name: &str) -> Result<[f32; 3], Status> {
    <[f32; 3]>::try_from(v)
        .map_err(|_| Status::invalid_argument(format!("{name}: three values, not {}", v.len())))
}

impl TryFrom<&pb::FrameView> for View {
    type Error = Status;

    /// Reads and checks a frame's view from the wire.
    fn try_from(v: &pb::FrameView) -> Result<Self, Status> {
        let camera = match &v.camera {
            None => None,
            Some(c) => Some(CameraSpec {
                position: three(&c.position, "camera.position")?,
                look_at: three(&c.look_at, "camera.look_at")?,
                up: three(&c.up, "camera.up")?,
                fov_y_deg: c.fov_y_deg,
            }),
        };
        let sun_towards = if v.sun_towards.is_empty() {
            None
        } else {
            Some(three(&v.sun_towards, "sun_towards")?)
        };
        let view = View { camera, sun_towards };
        view.check().map_err(Status::invalid_argument)?;
        Ok(view)
    }
}

impl From<&View> for pb::FrameView {
    fn from(v: &View) -> Self {
        pb::FrameView {
            camera: v.camera.map(|c| pb::CameraPose {
                position: c.position.to_vec(),
                look_at: c.look_at.to_vec(),
                up: c.up.to_vec(),
                fov_y_deg: c.fov_y_deg,
            }),
            sun_towards: v.sun_towards.map(|s| s.to_vec()).unwrap_or_default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_round_trip_and_unknown_enums_are_refused() {
        for lighting in [None, Some(LightingMode::Boulanger), Some(LightingMode::GatherAmbient)] {
            let f = FrameSettings {
                lighting,
                accel: Backend::Kd,
                ambient: Some([0.1, 0.2, 0.3]),
                gather_bounces: 2,
                gather_filter: 0,
                ..Default::default()
            };
            assert_eq!(FrameSettings::try_from(&pb::FrameSettings::from(&f)).unwrap(), f);
        }
        let mut wire = pb::FrameSettings::from(&FrameSettings::default());
        wire.lighting = 99;
        let e = FrameSettings::try_from(&wire).unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        assert!(e.message().contains("lighting 99"), "{}", e.message());
        let mut wire = pb::FrameSettings::from(&FrameSettings::default());
        wire.accel = 7;
        assert!(FrameSettings::try_from(&wire).unwrap_err().message().contains("accel 7"));
        let camera = CameraSpec {
            position: [1.0, 2.0, 3.0],
            look_at: [0.0; 3],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 30.0,
        };
        let f = FrameSettings {
            view: View { camera: Some(camera), sun_towards: Some([0.0, 1.0, 0.0]) },
            ..Default::default()
        };
        assert_eq!(FrameSettings::try_from(&pb::FrameSettings::from(&f)).unwrap(), f);
        let mut wire = pb::FrameSettings::from(&f);
        wire.view.as_mut().unwrap().sun_towards = vec![1.0, 2.0];
        assert!(
            FrameSettings::try_from(&wire)
                .unwrap_err()
                .message()
                .contains("sun_towards: three values")
        );
        wire.view.as_mut().unwrap().sun_towards = vec![f32::NAN, 1.0, 0.0];
        assert!(FrameSettings::try_from(&wire).unwrap_err().message().contains("sun_towards"));
        wire.view.as_mut().unwrap().sun_towards = Vec::new();
        wire.view.as_mut().unwrap().camera.as_mut().unwrap().look_at = vec![1.0, 2.0, 3.0];
        assert!(FrameSettings::try_from(&wire).unwrap_err().message().contains("look_at"));
        // A sender that never heard of the gather's depth gets the default.
        let mut wire = pb::FrameSettings::from(&FrameSettings::default());
        wire.gather_bounces = 0;
        assert_eq!(FrameSettings::try_from(&wire).unwrap().gather_bounces, 1);
        wire.gather_bounces = 9;
        assert!(FrameSettings::try_from(&wire).unwrap_err().message().contains("gather_bounces"));
        let mut wire = pb::FrameSettings::from(&FrameSettings::default());
        wire.spp = 0;
        assert!(FrameSettings::try_from(&wire).unwrap_err().message().contains("spp 0"));
    }
}
