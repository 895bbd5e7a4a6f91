//! The denoiser: Intel Open Image Denoise 2.x (OIDN), the field's standard
//! (Blender's Cycles uses it), its `RT` filter on its CPU device, guided by
//! the frame's albedo and normal (Cycles' "Denoising Albedo" and "Normal").
//!
//! The library is loaded when a frame first asks to be denoised, not linked:
//! a binary without it runs everything else, and says what is missing where
//! a denoise is asked for. It is found at `$SYLVA_OIDN_LIB` (a path to
//! `libOpenImageDenoise.so.2`; `scripts/install-deps.sh` takes it from
//! PyPI's `pyoidn` wheel and `scripts/env.sh` sets it), else by the system's
//! loader. Its device is made once per process and kept.
//!
//! OIDN's filter is deterministic on one machine: the same frame denoised
//! in one process and through the farm gives the same bits.

use libloading::{Library, Symbol};
use std::ffi::{CStr, CString, c_char, c_void};
use std::sync::{Mutex, OnceLock};

/// Why a frame could not be denoised.
#[derive(Clone, Debug, thiserror::Error)]
pub enum DenoiseError {
    /// The library is not there (or not OIDN 2.x).
    #[error(
        "Open Image Denoise is not available: {0} (scripts/install-deps.sh installs it; or set SYLVA_OIDN_LIB to libOpenImageDenoise.so.2)"
    )]
    Missing(String),
    /// OIDN refused the frame or failed on it.
    #[error("Open Image Denoise failed: {0}")]
    Failed(String),
    /// The images do not fit together.
    #[error("denoise: {0}")]
    Shape(String),
}

/// OIDN's `OIDN_DEVICE_TYPE_CPU`.
const DEVICE_CPU: i32 = 1;
/// OIDN's `OIDN_FORMAT_FLOAT3`.
const FLOAT3: i32 = 3;
/// OIDN's `OIDN_QUALITY_HIGH`: for final frames.
const QUALITY_HIGH: i32 = 6;

type Device = *mut c_void;
type Filter = *mut c_void;

/// The library and its CPU device.
struct Oidn {
    lib: Library,
    device: Device,
}

// The device is used under `OIDN`'s lock only.
unsafe impl Send for Oidn {}

static OIDN: OnceLock<Result<Mutex<Oidn>, DenoiseError>> = OnceLock::new();

/// Where to load OIDN from: `$SYLVA_OIDN_LIB`, else the loader's search.
fn library_path() -> std::ffi::OsString {
    std::env::var_os("SYLVA_OIDN_LIB").unwrap_or_else(|| "libOpenImageDenoise.so.2".into())
}

impl Oidn {
    fn open() -> Result<Self, DenoiseError> {
        let path = library_path();
        // SAFETY: loading a library runs its initialisers; OIDN's are its own.
        let lib = unsafe { Library::new(&path) }
            .map_err(|e| DenoiseError::Missing(format!("{}: {e}", path.to_string_lossy())))?;
        let mut me = Oidn { lib, device: std::ptr::null_mut() };
        // SAFETY: the signatures are OIDN 2.x's (OpenImageDenoise/oidn.h).
        unsafe {
            let new: Symbol<unsafe extern "C" fn(i32) -> Device> = me.symbol(b"oidnNewDevice\0")?;
            me.device = new(DEVICE_CPU);
            if me.device.is_null() {
                return Err(DenoiseError::Failed("no CPU device".into()));
            }
            let commit: Symbol<unsafe extern "C" fn(Device)> = me.symbol(b"oidnCommitDevice\0")?;
            commit(me.device);
        }
        me.check()?;
        Ok(me)
    }

    /// A function of the library, or `Missing` naming it.
    unsafe fn symbol<T>(&self, name: &[u8]) -> Result<Symbol<'_, T>, DenoiseError> {
        // SAFETY: the caller gives the symbol's true type.
        unsafe { self.lib.get(name) }.map_err(|e| {
            let n = String::from_utf8_lossy(&name[..name.len() - 1]).into_owned();
            DenoiseError::Missing(format!("{n}: {e} (not Open Image Denoise 2.x?)"))
        })
    }

    /// The device's last error, if any.
    fn check(&self) -> Result<(), DenoiseError> {
        // SAFETY: oidnGetDeviceError(OIDNDevice, const char**) -> OIDNError.
        unsafe {
            let get: Symbol<unsafe extern "C" fn(Device, *mut *const c_char) -> i32> =
                self.symbol(b"oidnGetDeviceError\0")?;
            let mut message: *const c_char = std::ptr::null();
            let code = get(self.device, &mut message);
            if code == 0 {
                return Ok(());
            }
            let text = if message.is_null() {
                format!("error {code}")
            } else {
                CStr::from_ptr(message).to_string_lossy().into_owned()
            };
            Err(DenoiseError::Failed(text))
        }
    }

    /// Runs the `RT` filter over `color` (linear HDR, RGB) with its guides,
    /// into `out`; all `width × height × 3` floats.
    fn run(
        &self,
        (width, height): (usize, usize),
        color: &[f32],
        albedo: Option<&[f32]>,
        normal: Option<&[f32]>,
        out: &mut [f32],
    ) -> Result<(), DenoiseError> {
        type SetImage = unsafe extern "C" fn(
            Filter,
            *const c_char,
            *mut c_void,
            i32,
            usize,
            usize,
            usize,
            usize,
            usize,
        );
        // SAFETY: OIDN 2.x's signatures; every image holds width × height
        // × 3 floats (checked by `denoise`), which OIDN reads or writes
        // only while `oidnExecuteFilter` runs, before the borrows end.
        unsafe {
            let new: Symbol<unsafe extern "C" fn(Device, *const c_char) -> Filter> =
                self.symbol(b"oidnNewFilter\0")?;
            let set: Symbol<SetImage> = self.symbol(b"oidnSetSharedFilterImage\0")?;
            let set_bool: Symbol<unsafe extern "C" fn(Filter, *const c_char, bool)> =
                self.symbol(b"oidnSetFilterBool\0")?;
            let set_int: Symbol<unsafe extern "C" fn(Filter, *const c_char, i32)> =
                self.symbol(b"oidnSetFilterInt\0")?;
            let commit: Symbol<unsafe extern "C" fn(Filter)> =
                self.symbol(b"oidnCommitFilter\0")?;
            let execute: Symbol<unsafe extern "C" fn(Filter)> =
                self.symbol(b"oidnExecuteFilter\0")?;
            let release: Symbol<unsafe extern "C" fn(Filter)> =
                self.symbol(b"oidnReleaseFilter\0")?;
            let name = |s: &str| CString::new(s).expect("no NUL");
            let filter = new(self.device, name("RT").as_ptr());
            if filter.is_null() {
                self.check()?;
                return Err(DenoiseError::Failed("no RT filter".into()));
            }
            let image = |key: &str, data: *mut f32| {
                set(filter, name(key).as_ptr(), data.cast(), FLOAT3, width, height, 0, 0, 0);
            };
            image("color", color.as_ptr().cast_mut());
            if let Some(a) = albedo {
                image("albedo", a.as_ptr().cast_mut());
            }
            if let (Some(n), Some(_)) = (normal, albedo) {
                image("normal", n.as_ptr().cast_mut());
            }
            image("output", out.as_mut_ptr());
            set_bool(filter, name("hdr").as_ptr(), true);
            set_int(filter, name("quality").as_ptr(), QUALITY_HIGH);
            commit(filter);
            let committed = self.check();
            if committed.is_ok() {
                execute(filter);
            }
            release(filter);
            committed.and_then(|()| self.check())
        }
    }
}

impl Drop for Oidn {
    fn drop(&mut self) {
        // SAFETY: the device was made by oidnNewDevice and is released once.
        unsafe {
            if let Ok(release) = self.symbol::<unsafe extern "C" fn(Device)>(b"oidnReleaseDevice\0")
            {
                release(self.device);
            }
        }
    }
}

/// Whether OIDN can be loaded here (it is then kept for the process).
pub fn available() -> Result<(), DenoiseError> {
    oidn().map(|_| ())
}

fn oidn() -> Result<&'static Mutex<Oidn>, DenoiseError> {
    OIDN.get_or_init(|| Oidn::open().map(Mutex::new)).as_ref().map_err(Clone::clone)
}

/// A frame to denoise: linear HDR RGB and its guides, each `width × height`
/// pixels of three floats, rows from the top.
pub struct Noisy<'a> {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The image.
    pub color: &'a [[f32; 3]],
    /// The first surface's albedo (the `albedo` pass), if rendered.
    pub albedo: Option<&'a [f32]>,
    /// The first surface's normal (the `normal` pass), used with an albedo.
    pub normal: Option<&'a [f32]>,
}

/// `frame` denoised by OIDN's `RT` filter (HDR, high quality, on the CPU).
pub fn denoise(frame: &Noisy<'_>) -> Result<Vec<[f32; 3]>, DenoiseError> {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let n = w * h;
    if frame.color.len() != n {
        return Err(DenoiseError::Shape(format!("{} pixels for {w}×{h}", frame.color.len())));
    }
    for (name, g) in [("albedo", frame.albedo), ("normal", frame.normal)] {
        if let Some(g) = g
            && g.len() != 3 * n
        {
            return Err(DenoiseError::Shape(format!("{name}: {} floats for {w}×{h}", g.len())));
        }
    }
    if frame.color.iter().flatten().any(|v| !v.is_finite()) {
        return Err(DenoiseError::Shape("the image has values that are not finite".into()));
    }
    let mut out = vec![[0.0f32; 3]; n];
    let oidn = oidn()?;
    let oidn = oidn.lock().unwrap_or_else(|p| p.into_inner());
    oidn.run(
        (w, h),
        frame.color.as_flattened(),
        frame.albedo,
        frame.normal,
        out.as_flattened_mut(),
    )?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth image, the same with noise of a known spread, and the
    /// denoised one: closer to the smooth one by far. Needs the library
    /// (`scripts/env.sh` sets `SYLVA_OIDN_LIB`).
    #[test]
    fn noise_comes_out_and_the_picture_stays() {
        let (w, h) = (96u32, 64u32);
        let truth: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
                [0.2 + 0.6 * x, 0.3 + 0.4 * y, 0.5]
            })
            .collect();
        // A fixed sequence of noise (a linear congruential generator).
        let mut s = 12345u32;
        let mut noise = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (s >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        let noisy: Vec<[f32; 3]> =
            truth.iter().map(|p| p.map(|v| (v + 0.4 * v * noise()).max(0.0))).collect();
        let albedo: Vec<f32> = vec![0.8; 3 * truth.len()];
        let normal: Vec<f32> = (0..truth.len()).flat_map(|_| [0.0, 0.0, 1.0]).collect();
        let frame = Noisy {
            width: w,
            height: h,
            color: &noisy,
            albedo: Some(&albedo),
            normal: Some(&normal),
        };
        let out = denoise(&frame).expect("OIDN loads (scripts/env.sh sets SYLVA_OIDN_LIB)");
        let rms = |a: &[[f32; 3]]| {
            let e: f64 = a
                .iter()
                .zip(&truth)
                .flat_map(|(p, t)| (0..3).map(move |c| ((p[c] - t[c]) as f64).powi(2)))
                .sum();
            (e / (3 * a.len()) as f64).sqrt()
        };
        let (before, after) = (rms(&noisy), rms(&out));
        assert!(after < before / 4.0, "rms {before:.4} → {after:.4}");
        // The same input, the same bits.
        assert_eq!(denoise(&frame).unwrap(), out);
        // Shapes that do not fit are refused before OIDN sees them.
        let short = Noisy { color: &noisy[1..], ..frame };
        assert!(matches!(denoise(&short), Err(DenoiseError::Shape(_))));
    }
}
