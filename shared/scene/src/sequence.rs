//! Sequences of frames: a sun sweep (the sun's path between two positions,
//! as over a time of day), a camera path (keyframes), or both. A sequence
//! becomes one [`View`] per frame; every other frame setting (size,
//! samples, lighting) is the job's. The scene file's `sequence` or the
//! command line's `--frames`/`--sun-from`/`--sun-to`/`--camera-path` give it.

use crate::camera::Camera;
use crate::format::{CameraSpec, default_fov, y_up};
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Most frames one job may have.
pub const MAX_FRAMES: u32 = 10_000;
/// Largest coordinate a view may name (as a scene's camera).
const MAX_COORDINATE: f32 = 1e6;

/// Where one frame's camera and sun are, where they differ from the scene's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct View {
    /// The camera; `None`: the scene's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraSpec>,
    /// A unit vector towards the sun; `None`: the scene's sun.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun_towards: Option<[f32; 3]>,
}

impl View {
    /// Checks that the camera can be built and the sun is a direction.
    pub fn check(&self) -> crate::Result<()> {
        if let Some(c) = &self.camera {
            camera_of(c)?;
        }
        if let Some(s) = self.sun_towards {
            let v = Vec3::from(s);
            if !v.is_finite()
                || v.abs().max_element() > MAX_COORDINATE
                || v.length_squared() < 1e-12
            {
                return Err(crate::Error::Invalid(format!(
                    "sun_towards {s:?}: a finite, non-zero vector"
                )));
            }
        }
        Ok(())
    }

    /// The view's camera, if it sets one (checked by [`View::check`]).
    pub fn camera(&self) -> Option<crate::Result<Camera>> {
        self.camera.as_ref().map(camera_of)
    }

    /// The view's sun as a unit vector, if it sets one.
    pub fn sun(&self) -> Option<Vec3> {
        self.sun_towards.map(|s| Vec3::from(s).normalize())
    }

    /// Bits of the sun direction: equal keys, equal LB light.
    pub fn sun_key(&self) -> Option<[u32; 3]> {
        self.sun().map(|v| v.to_array().map(f32::to_bits))
    }
}

/// A camera as the renderer uses it, with the reason when it cannot be.
pub fn camera_of(c: &CameraSpec) -> crate::Result<Camera> {
    for (name, v) in [("position", c.position), ("look_at", c.look_at), ("up", c.up)] {
        if !v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE) {
            return Err(crate::Error::Invalid(format!(
                "camera {name} {v:?}: finite values within ±{MAX_COORDINATE}"
            )));
        }
    }
    Camera::look_at(c.position.into(), c.look_at.into(), c.up.into(), c.fov_y_deg)
        .map_err(crate::Error::Camera)
}

/// The sun's place in the sky.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SunAngles {
    /// Degrees above the horizon.
    pub elevation_deg: f32,
    /// Degrees from +x towards +z.
    pub azimuth_deg: f32,
}

impl SunAngles {
    /// The unit vector towards the sun (as the scene file's angles give it).
    pub fn towards(&self) -> [f32; 3] {
        let (e, a) = (self.elevation_deg.to_radians(), self.azimuth_deg.to_radians());
        [e.cos() * a.cos(), e.sin(), e.cos() * a.sin()]
    }

    fn check(&self, name: &str) -> crate::Result<()> {
        if !(self.elevation_deg.is_finite() && self.elevation_deg.abs() <= 90.0) {
            return Err(crate::Error::Invalid(format!(
                "sequence.sun.{name}.elevation_deg {}: valid range [-90, 90]",
                self.elevation_deg
            )));
        }
        if !(self.azimuth_deg.is_finite() && self.azimuth_deg.abs() <= 3600.0) {
            return Err(crate::Error::Invalid(format!(
                "sequence.sun.{name}.azimuth_deg {}: valid range [-3600, 3600]",
                self.azimuth_deg
            )));
        }
        Ok(())
    }
}

/// The sun moving from one place to another over the sequence: elevation
/// and azimuth each change linearly with the frame, as over a time of day.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SunSweep {
    /// Where the sun is in the first frame.
    pub from: SunAngles,
    /// Where it is in the last.
    pub to: SunAngles,
}

/// A camera keyframe: the camera at one frame of the sequence (the scene
/// file's camera and its defaults, plus the frame; serde cannot flatten a
/// struct that denies unknown fields, so the fields stand again here).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraKey {
    /// The frame (from 0) this camera is reached at.
    pub frame: u32,
    /// Eye position.
    pub position: [f32; 3],
    /// Point looked at.
    pub look_at: [f32; 3],
    /// Up direction.
    #[serde(default = "y_up")]
    pub up: [f32; 3],
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    pub fov_y_deg: f32,
}

/// A sequence of frames, as the scene file's `sequence` gives it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequenceSpec {
    /// Frames.
    pub frames: u32,
    /// The sun's path; absent: the scene's sun in every frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun: Option<SunSweep>,
    /// Camera keyframes in frame order; between keys, position and target
    /// follow a Catmull–Rom spline through them, up and field of view
    /// change linearly; before the first and after the last the camera
    /// holds. Absent or empty: the scene's camera in every frame.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub camera: Vec<CameraKey>,
}

impl SequenceSpec {
    /// One view per frame, or why the sequence cannot be rendered.
    pub fn views(&self) -> crate::Result<Vec<View>> {
        if self.frames == 0 || self.frames > MAX_FRAMES {
            return Err(crate::Error::Invalid(format!(
                "sequence.frames {}: valid range [1, {MAX_FRAMES}]",
                self.frames
            )));
        }
        if let Some(s) = &self.sun {
            s.from.check("from")?;
            s.to.check("to")?;
        }
        for (i, k) in self.camera.iter().enumerate() {
            if k.frame >= self.frames {
                return Err(crate::Error::Invalid(format!(
                    "sequence.camera[{i}].frame {}: the sequence has frames 0 to {}",
                    k.frame,
                    self.frames - 1
                )));
            }
            if i > 0 && k.frame <= self.camera[i - 1].frame {
                return Err(crate::Error::Invalid(format!(
                    "sequence.camera[{i}].frame {}: keyframes must come in increasing frame order",
                    k.frame
                )));
            }
            camera_of(&k.pose()).map_err(|e| e.within(format!("sequence.camera[{i}]")))?;
        }
        let last = (self.frames - 1).max(1) as f32;
        let views: Vec<View> = (0..self.frames)
            .map(|f| View {
                camera: (!self.camera.is_empty()).then(|| camera_at(&self.camera, f)),
                sun_towards: self.sun.map(|s| {
                    let t = f as f32 / last;
                    SunAngles {
                        elevation_deg: s.from.elevation_deg
                            + t * (s.to.elevation_deg - s.from.elevation_deg),
                        azimuth_deg: s.from.azimuth_deg
                            + t * (s.to.azimuth_deg - s.from.azimuth_deg),
                    }
                    .towards()
                }),
            })
            .collect();
        // An interpolated camera may still be degenerate (a spline through
        // the target): say which frame.
        for (f, v) in views.iter().enumerate() {
            v.check().map_err(|e| e.within(format!("sequence frame {f}")))?;
        }
        Ok(views)
    }
}

impl CameraKey {
    /// The key's camera.
    pub fn pose(&self) -> CameraSpec {
        CameraSpec {
            position: self.position,
            look_at: self.look_at,
            up: self.up,
            fov_y_deg: self.fov_y_deg,
        }
    }
}

/// The camera at `frame` on the path through `keys` (sorted, not empty).
fn camera_at(keys: &[CameraKey], frame: u32) -> CameraSpec {
    let n = keys.len();
    let Some(k) = keys.windows(2).position(|w| w[0].frame <= frame && frame <= w[1].frame) else {
        return if frame < keys[0].frame { keys[0].pose() } else { keys[n - 1].pose() };
    };
    let (a, b) = (&keys[k], &keys[k + 1]);
    let t = (frame - a.frame) as f32 / (b.frame - a.frame) as f32;
    // Beyond the ends, a phantom key mirrors the neighbour, so the path
    // leaves its first key and reaches its last one moving straight.
    let spline = |f: fn(&CameraKey) -> [f32; 3]| {
        let (p1, p2) = (Vec3::from(f(a)), Vec3::from(f(b)));
        let p0 = if k > 0 { Vec3::from(f(&keys[k - 1])) } else { 2.0 * p1 - p2 };
        let p3 = if k + 2 < n { Vec3::from(f(&keys[k + 2])) } else { 2.0 * p2 - p1 };
        catmull_rom(p0, p1, p2, p3, t).to_array()
    };
    let up = Vec3::from(a.up).lerp(Vec3::from(b.up), t);
    CameraSpec {
        position: spline(|k| k.position),
        look_at: spline(|k| k.look_at),
        up: if up.length_squared() > 1e-12 { up.to_array() } else { a.up },
        fov_y_deg: a.fov_y_deg + t * (b.fov_y_deg - a.fov_y_deg),
    }
}

/// The uniform Catmull–Rom spline through `p1` (t = 0) and `p2` (t = 1).
fn catmull_rom(p0: Vec3, p1: Vec3, p2: Vec3, p3: Vec3, t: f32) -> Vec3 {
    let (t2, t3) = (t * t, t * t * t);
    0.5 * ((2.0 * p1)
        + (p2 - p0) * t
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(frame: u32, x: f32) -> CameraKey {
        CameraKey {
            frame,
            position: [x, 2.0, -10.0],
            look_at: [0.0, 2.0, 0.0],
            up: y_up(),
            fov_y_deg: 40.0 + frame as f32,
        }
    }

    #[test]
    fn the_path_passes_through_its_keys_and_holds_beyond_them() {
        let s = SequenceSpec {
            frames: 12,
            sun: None,
            camera: vec![key(2, -4.0), key(6, 0.0), key(10, 4.0)],
        };
        let v = s.views().unwrap();
        assert_eq!(v.len(), 12);
        for k in &s.camera {
            assert_eq!(
                v[k.frame as usize].camera.unwrap().position,
                k.position,
                "frame {}",
                k.frame
            );
        }
        assert_eq!(v[0].camera.unwrap().position, [-4.0, 2.0, -10.0]);
        assert_eq!(v[11].camera.unwrap().position, [4.0, 2.0, -10.0]);
        // Evenly spaced collinear keys: the spline moves evenly between them.
        assert!((v[4].camera.unwrap().position[0] + 2.0).abs() < 1e-5, "{:?}", v[4].camera);
        assert!((v[4].camera.unwrap().fov_y_deg - 44.0).abs() < 1e-5);
        assert!(v.iter().all(|v| v.sun_towards.is_none()));
    }

    #[test]
    fn the_sun_sweeps_from_one_place_to_the_other() {
        let sweep = SunSweep {
            from: SunAngles { elevation_deg: 10.0, azimuth_deg: 90.0 },
            to: SunAngles { elevation_deg: 50.0, azimuth_deg: 270.0 },
        };
        let v = SequenceSpec { frames: 5, sun: Some(sweep), camera: Vec::new() }.views().unwrap();
        let elevation = |v: &View| v.sun_towards.unwrap()[1].asin().to_degrees();
        let want = [10.0, 20.0, 30.0, 40.0, 50.0];
        for (v, w) in v.iter().zip(want) {
            assert!((elevation(v) - w).abs() < 1e-3, "{} vs {w}", elevation(v));
            assert!(v.camera.is_none());
        }
        // Azimuth 180° at the middle frame: towards −x.
        assert!(v[2].sun_towards.unwrap()[0] < -0.8);
    }

    #[test]
    fn bad_sequences_say_what_is_wrong() {
        let ok = || SequenceSpec { frames: 4, sun: None, camera: vec![key(0, -1.0), key(3, 1.0)] };
        let cases = [
            (SequenceSpec { frames: 0, ..ok() }, "sequence.frames 0"),
            (SequenceSpec { frames: MAX_FRAMES + 1, ..ok() }, "sequence.frames"),
            (
                SequenceSpec { camera: vec![key(3, 1.0), key(1, 0.0)], ..ok() },
                "increasing frame order",
            ),
            (SequenceSpec { camera: vec![key(9, 1.0)], ..ok() }, "camera[0].frame 9"),
            (
                SequenceSpec {
                    camera: vec![CameraKey { look_at: [0.0, 2.0, -10.0], ..key(0, 0.0) }],
                    ..ok()
                },
                "camera[0]: camera: camera position and look_at",
            ),
            (
                SequenceSpec {
                    camera: vec![CameraKey { position: [f32::NAN, 0.0, 0.0], ..key(0, 0.0) }],
                    ..ok()
                },
                "camera position",
            ),
            (
                SequenceSpec {
                    sun: Some(SunSweep {
                        from: SunAngles { elevation_deg: 95.0, azimuth_deg: 0.0 },
                        to: SunAngles { elevation_deg: 10.0, azimuth_deg: 0.0 },
                    }),
                    ..ok()
                },
                "sequence.sun.from.elevation_deg 95",
            ),
        ];
        for (s, want) in cases {
            let e = s.views().unwrap_err().to_string();
            assert!(e.contains(want), "{want}: {e}");
        }
        assert!(
            View { camera: None, sun_towards: Some([0.0; 3]) }
                .check()
                .unwrap_err()
                .to_string()
                .contains("non-zero")
        );
    }
}
