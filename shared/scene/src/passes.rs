//! Render passes (AOVs): the images a frame writes beside its beauty image
//! for compositors and denoisers, and the multi-layer OpenEXR that holds
//! them, named as Blender and Nuke read them (docs/passes.md).
//!
//! `direct`, `indirect` and `sky` split the beauty image: their sum is the
//! beauty image to float precision. The guides (`albedo`, `normal`,
//! `depth`, `instance`, `species`) describe the first surface along the
//! camera rays.

use crate::film::HdrImage;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt;

/// One render pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Pass {
    /// The image itself (Blender's `Combined`): always written.
    Beauty,
    /// The sun's light the first surface reflects or transmits.
    Direct,
    /// Every other light the first surface sends towards the camera, and
    /// the light of clouds in front of it.
    Indirect,
    /// The first surface's diffuse albedo (a leaf's reflectance plus its
    /// transmittance on the side seen), mean over the pixel's samples.
    Albedo,
    /// The first surface's geometric normal, world space, turned to face
    /// the camera; mean over the pixel's samples.
    Normal,
    /// Distance along the camera's axis to the first surface of the
    /// pixel's first sample; [`NO_DEPTH`] where it sees the sky.
    Depth,
    /// The instance the pixel's first sample hit, its index in the scene
    /// plus one; 0 for the ground and the sky.
    Instance,
    /// That instance's model (its species), its index in the scene's
    /// sorted model names plus one; 0 for the ground and the sky.
    Species,
    /// The sky seen directly (Blender's `Env`), through any clouds.
    Sky,
}

/// The depth pass where a sample sees no surface: Blender's own.
pub const NO_DEPTH: f32 = 1e10;

/// The view layer the passes belong to in the EXR: Blender's default name.
pub const VIEW_LAYER: &str = "ViewLayer";

impl Pass {
    /// Every pass, in the order of their planes on the wire.
    pub const ALL: [Pass; 9] = [
        Pass::Beauty,
        Pass::Direct,
        Pass::Indirect,
        Pass::Albedo,
        Pass::Normal,
        Pass::Depth,
        Pass::Instance,
        Pass::Species,
        Pass::Sky,
    ];

    /// The name `--passes` takes.
    pub fn name(self) -> &'static str {
        match self {
            Pass::Beauty => "beauty",
            Pass::Direct => "direct",
            Pass::Indirect => "indirect",
            Pass::Albedo => "albedo",
            Pass::Normal => "normal",
            Pass::Depth => "depth",
            Pass::Instance => "instance",
            Pass::Species => "species",
            Pass::Sky => "sky",
        }
    }

    /// The pass's name in the EXR, Blender's where Blender has one
    /// (Combined, DiffCol, Normal, Depth, IndexOB, Env).
    pub fn layer(self) -> &'static str {
        match self {
            Pass::Beauty => "Combined",
            Pass::Direct => "Direct",
            Pass::Indirect => "Indirect",
            Pass::Albedo => "DiffCol",
            Pass::Normal => "Normal",
            Pass::Depth => "Depth",
            Pass::Instance => "IndexOB",
            Pass::Species => "IndexSpecies",
            Pass::Sky => "Env",
        }
    }

    /// The pass's channels, as Blender names them.
    pub fn channels(self) -> &'static [&'static str] {
        match self {
            Pass::Beauty | Pass::Direct | Pass::Indirect | Pass::Albedo | Pass::Sky => {
                &["R", "G", "B"]
            }
            Pass::Normal => &["X", "Y", "Z"],
            Pass::Depth => &["Z"],
            Pass::Instance | Pass::Species => &["X"],
        }
    }

    const fn bit(self) -> u16 {
        1 << self as u16
    }
}

impl fmt::Display for Pass {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A set of passes beside the beauty image. `direct` or `indirect` bring
/// `sky` with them, so that the three always sum to the beauty image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct PassSet(u16);

/// The passes a denoised frame needs: the denoiser's guides.
pub const DENOISE_GUIDES: PassSet = PassSet(Pass::Albedo.bit() | Pass::Normal.bit());

impl PassSet {
    /// No passes: the beauty image alone.
    pub const NONE: PassSet = PassSet(0);

    /// Every pass.
    pub fn all() -> Self {
        Self::of(Pass::ALL)
    }

    /// These passes; any of the light split (direct, indirect, sky) brings
    /// the other two, so the split always adds up to the image.
    pub fn of(passes: impl IntoIterator<Item = Pass>) -> Self {
        let split = Pass::Direct.bit() | Pass::Indirect.bit() | Pass::Sky.bit();
        let mut bits = 0u16;
        for p in passes {
            if p != Pass::Beauty {
                bits |= p.bit();
            }
        }
        if bits & split != 0 {
            bits |= split;
        }
        PassSet(bits)
    }

    /// Parses `--passes`: names separated by commas, or `all`.
    pub fn parse(s: &str) -> Result<Self> {
        let mut out = Vec::new();
        for name in s.split(',').map(str::trim).filter(|n| !n.is_empty()) {
            if name == "all" {
                return Ok(Self::all());
            }
            match Pass::ALL.iter().find(|p| p.name() == name) {
                Some(&p) => out.push(p),
                None => {
                    let valid: Vec<_> = Pass::ALL.iter().map(|p| p.name()).collect();
                    return Err(Error::Invalid(format!(
                        "pass {name:?}: one of {}, or all",
                        valid.join(", ")
                    )));
                }
            }
        }
        Ok(Self::of(out))
    }

    /// This set and `other`'s passes.
    pub fn with(self, other: PassSet) -> Self {
        PassSet(self.0 | other.0)
    }

    /// Whether there is any pass beside beauty.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Whether `p` is in the set (beauty always is).
    pub fn contains(self, p: Pass) -> bool {
        p == Pass::Beauty || self.0 & p.bit() != 0
    }

    /// The passes beside beauty, in wire order.
    pub fn extra(self) -> impl Iterator<Item = Pass> {
        Pass::ALL.into_iter().filter(move |&p| p != Pass::Beauty && self.contains(p))
    }

    /// Floats per pixel of the passes beside beauty.
    pub fn floats_per_pixel(self) -> usize {
        self.extra().map(|p| p.channels().len()).sum()
    }

    /// Whether any guide (albedo, normal, depth, ids) is asked for.
    pub fn wants_guides(self) -> bool {
        [Pass::Albedo, Pass::Normal, Pass::Depth, Pass::Instance, Pass::Species]
            .iter()
            .any(|&p| self.contains(p))
    }

    /// Whether the light split (direct, indirect, sky) is asked for.
    pub fn wants_split(self) -> bool {
        self.contains(Pass::Sky)
    }

    /// The light split of this set alone, without its guides: what later
    /// batches of a progressive render add to the first's.
    pub fn split_only(self) -> Self {
        PassSet(self.0 & (Pass::Direct.bit() | Pass::Indirect.bit() | Pass::Sky.bit()))
    }
}

impl fmt::Display for PassSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<_> = std::iter::once("beauty").chain(self.extra().map(Pass::name)).collect();
        f.write_str(&names.join(","))
    }
}

/// A frame's (or a strip's) passes beside beauty: one plane per pass of
/// `set`, in wire order, each `width × height × channels` floats with the
/// channels interleaved, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct PassImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Which passes.
    pub set: PassSet,
    /// The planes, in `set.extra()` order.
    pub planes: Vec<Vec<f32>>,
}

impl PassImage {
    /// Zeroed planes.
    pub fn new(width: u32, height: u32, set: PassSet) -> Self {
        let n = width as usize * height as usize;
        let planes = set.extra().map(|p| vec![0.0; n * p.channels().len()]).collect();
        Self { width, height, set, planes }
    }

    /// The plane of pass `p`, if the set has it.
    pub fn plane(&self, p: Pass) -> Option<&[f32]> {
        self.set.extra().position(|q| q == p).map(|i| self.planes[i].as_slice())
    }

    /// The plane of pass `p` to fill, if the set has it.
    pub fn plane_mut(&mut self, p: Pass) -> Option<&mut Vec<f32>> {
        self.set.extra().position(|q| q == p).map(|i| &mut self.planes[i])
    }

    /// The planes as the wire carries them: little-endian f32, one plane
    /// after another.
    pub fn to_bytes(&self) -> Vec<u8> {
        self.planes.iter().flatten().flat_map(|v| v.to_le_bytes()).collect()
    }

    /// Planes from the wire for a `width × height` strip of `set`, checked:
    /// the right number of bytes, and each value what its pass can hold.
    pub fn from_bytes(width: u32, height: u32, set: PassSet, bytes: &[u8]) -> Result<Self> {
        let n = width as usize * height as usize;
        let due = n * set.floats_per_pixel() * 4;
        if bytes.len() != due {
            return Err(Error::Invalid(format!(
                "passes {set}: {} bytes where {due} were due for {width}×{height}",
                bytes.len()
            )));
        }
        let mut values = bytes.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap()));
        let planes = set
            .extra()
            .map(|p| (&mut values).take(n * p.channels().len()).collect::<Vec<_>>())
            .collect();
        let image = Self { width, height, set, planes };
        image.check()?;
        Ok(image)
    }

    /// Checks every value against what its pass can hold.
    pub fn check(&self) -> Result<()> {
        let n = self.width as usize * self.height as usize;
        for (p, plane) in self.set.extra().zip(&self.planes) {
            if plane.len() != n * p.channels().len() {
                return Err(Error::Invalid(format!(
                    "pass {p}: {} values for {n} pixels",
                    plane.len()
                )));
            }
            let ok = |v: f32| match p {
                Pass::Normal => v.is_finite() && (-1.0001..=1.0001).contains(&v),
                Pass::Instance | Pass::Species => {
                    v.is_finite() && v >= 0.0 && v.fract() == 0.0 && v <= 16_777_216.0
                }
                Pass::Depth => v.is_finite() && v >= 0.0,
                Pass::Albedo => v.is_finite() && v >= 0.0,
                // The light split may round a hair below zero where one
                // part is the image less the others (the reference's).
                Pass::Beauty | Pass::Direct | Pass::Indirect | Pass::Sky => v.is_finite(),
            };
            if let Some(v) = plane.iter().find(|v| !ok(**v)) {
                return Err(Error::Invalid(format!("pass {p} has a value {v} it cannot hold")));
            }
        }
        Ok(())
    }

    /// Columns `[x0, x0 + width)` of the planes, as a strip's: what
    /// [`PassImage::paste_strip`] puts back.
    pub fn columns(&self, x0: u32, width: u32) -> Result<PassImage> {
        if x0 + width > self.width {
            return Err(Error::Invalid(format!(
                "columns {x0}..{} of a frame {} wide",
                x0 + width,
                self.width
            )));
        }
        let mut out = PassImage::new(width, self.height, self.set);
        for ((p, dst), src) in self.set.extra().zip(&mut out.planes).zip(&self.planes) {
            let c = p.channels().len();
            let (w, sw) = (self.width as usize * c, width as usize * c);
            for y in 0..self.height as usize {
                let at = y * w + x0 as usize * c;
                dst[y * sw..(y + 1) * sw].copy_from_slice(&src[at..at + sw]);
            }
        }
        Ok(out)
    }

    /// Copies a strip's planes into columns `[x0, x0 + strip.width)`.
    pub fn paste_strip(&mut self, x0: u32, strip: &PassImage) -> Result<()> {
        if strip.set != self.set || strip.height != self.height || x0 + strip.width > self.width {
            return Err(Error::Invalid(format!(
                "a strip's passes ({}, {}×{} at {x0}) do not fit the frame's ({}, {}×{})",
                strip.set, strip.width, strip.height, self.set, self.width, self.height
            )));
        }
        for ((p, dst), src) in self.set.extra().zip(&mut self.planes).zip(&strip.planes) {
            let c = p.channels().len();
            let (w, sw) = (self.width as usize * c, strip.width as usize * c);
            for y in 0..self.height as usize {
                let at = y * w + x0 as usize * c;
                dst[at..at + sw].copy_from_slice(&src[y * sw..(y + 1) * sw]);
            }
        }
        Ok(())
    }
}

impl PassImage {
    /// Adds the planes of `strip` (whose set is `self.set`, or its split
    /// alone) times `weight` into columns `[x0, x0 + strip.width)`: how
    /// batches of a progressive render sum into their mean.
    pub fn add_strip(&mut self, x0: u32, strip: &PassImage, weight: f32) -> Result<()> {
        if strip.height != self.height || x0 + strip.width > self.width {
            return Err(Error::Invalid(format!(
                "a strip's passes do not fit the frame's ({}×{})",
                self.width, self.height
            )));
        }
        let (width, height) = (self.width as usize, self.height as usize);
        for (p, src) in strip.set.extra().zip(&strip.planes) {
            let Some(dst) = self.plane_mut(p) else {
                return Err(Error::Invalid(format!("pass {p} is not the frame's")));
            };
            let c = p.channels().len();
            let (w, sw) = (width * c, strip.width as usize * c);
            for y in 0..height {
                let at = y * w + x0 as usize * c;
                for (d, s) in dst[at..at + sw].iter_mut().zip(&src[y * sw..(y + 1) * sw]) {
                    *d += weight * s;
                }
            }
        }
        Ok(())
    }
}

/// The layer of a denoised frame's noisy image, as Cycles names it.
pub const NOISY_LAYER: &str = "Noisy Image";

/// The channel name of pass `p`'s channel `c` in the multi-layer EXR:
/// `ViewLayer.Combined.R`, as Blender writes and reads it (Nuke shows the
/// layer as `ViewLayer_Combined`).
pub fn exr_channel(p: Pass, c: &str) -> String {
    format!("{VIEW_LAYER}.{}.{c}", p.layer())
}

/// A frame and its passes as one multi-layer OpenEXR (32-bit floats,
/// lossless ZIP): beauty as `ViewLayer.Combined.RGBA`, each pass as its own
/// layer, and a denoised frame's noisy image as `ViewLayer.Noisy Image`
/// (Cycles' name). Combined's alpha is 1: the film is opaque (the sky is in
/// the image), as Cycles writes Combined without a transparent film.
pub fn encode_layers(
    beauty: &HdrImage,
    passes: &PassImage,
    noisy: Option<&HdrImage>,
) -> Result<Vec<u8>> {
    use exr::prelude::*;
    let n = beauty.pixels.len();
    if passes.width != beauty.width || passes.height != beauty.height {
        return Err(crate::Error::Invalid(format!(
            "passes {}×{} for a frame {}×{}",
            passes.width, passes.height, beauty.width, beauty.height
        )));
    }
    let mut list: Vec<AnyChannel<FlatSamples>> = Vec::new();
    for (c, name) in Pass::Beauty.channels().iter().enumerate() {
        let v = beauty.pixels.iter().map(|p| p[c]).collect();
        list.push(AnyChannel::new(exr_channel(Pass::Beauty, name).as_str(), FlatSamples::F32(v)));
    }
    let opaque = FlatSamples::F32(vec![1.0; n]);
    list.push(AnyChannel::new(exr_channel(Pass::Beauty, "A").as_str(), opaque));
    if let Some(noisy) = noisy {
        if noisy.pixels.len() != n {
            return Err(crate::Error::Invalid("the noisy image is not the frame's size".into()));
        }
        for (c, name) in ["R", "G", "B"].iter().enumerate() {
            let v = noisy.pixels.iter().map(|p| p[c]).collect();
            let channel = format!("{VIEW_LAYER}.{NOISY_LAYER}.{name}");
            list.push(AnyChannel::new(channel.as_str(), FlatSamples::F32(v)));
        }
    }
    for (p, plane) in passes.set.extra().zip(&passes.planes) {
        let k = p.channels().len();
        for (c, name) in p.channels().iter().enumerate() {
            let v = (0..n).map(|i| plane[i * k + c]).collect();
            list.push(AnyChannel::new(exr_channel(p, name).as_str(), FlatSamples::F32(v)));
        }
    }
    let mut attributes = LayerAttributes::default();
    // Blender's own multi-layer files carry this; its reader takes dotted
    // channel names as layers either way.
    attributes.other.insert(
        Text::from("BlenderMultiChannel"),
        AttributeValue::Text(Text::from("Blender V2.55.1 and newer")),
    );
    let layer = Layer::new(
        (beauty.width as usize, beauty.height as usize),
        attributes,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut out)
        .map_err(|error| crate::Error::Exr { context: "writing the EXR".into(), error })?;
    Ok(out.into_inner())
}

/// A multi-layer EXR's channels by name, each `width × height` floats.
pub struct ExrLayers {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Channel names and values.
    pub channels: Vec<(String, Vec<f32>)>,
}

impl ExrLayers {
    /// Reads every channel of an EXR's first part.
    pub fn read(bytes: &[u8]) -> Result<Self> {
        use exr::prelude::*;
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(bytes))
            .map_err(|error| crate::Error::Exr {
                context: "not an OpenEXR file Sylva can read".into(),
                error,
            })?;
        let size = image.layer_data.size;
        let channels = image
            .layer_data
            .channel_data
            .list
            .iter()
            .map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect()))
            .collect();
        Ok(Self { width: size.0 as u32, height: size.1 as u32, channels })
    }

    /// The channel named `name`.
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.channels.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_slice())
    }

    /// The beauty image: `ViewLayer.Combined`, or a plain `R`, `G`, `B` file.
    pub fn beauty(&self) -> Result<HdrImage> {
        let get = |c: &str| {
            self.channel(&exr_channel(Pass::Beauty, c))
                .or_else(|| self.channel(c))
                .ok_or_else(|| Error::Invalid(format!("the EXR has no {c} channel")))
        };
        let (r, g, b) = (get("R")?, get("G")?, get("B")?);
        Ok(HdrImage {
            width: self.width,
            height: self.height,
            pixels: (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect(),
        })
    }

    /// The passes of `set` (each of whose channels the file must have).
    pub fn passes(&self, set: PassSet) -> Result<PassImage> {
        let n = self.width as usize * self.height as usize;
        let mut image = PassImage::new(self.width, self.height, set);
        for (p, plane) in set.extra().zip(&mut image.planes) {
            let k = p.channels().len();
            for (c, name) in p.channels().iter().enumerate() {
                let full = exr_channel(p, name);
                let v = self
                    .channel(&full)
                    .ok_or_else(|| Error::Invalid(format!("the EXR has no {full}")))?;
                for i in 0..n {
                    plane[i * k + c] = v[i];
                }
            }
        }
        Ok(image)
    }

    /// Which of Sylva's passes the file holds.
    pub fn pass_set(&self) -> PassSet {
        PassSet::of(
            Pass::ALL.into_iter().filter(|&p| {
                p.channels().iter().all(|c| self.channel(&exr_channel(p, c)).is_some())
            }),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_one_part_of_the_split_brings_the_other_two() {
        let s = PassSet::parse("beauty,direct").unwrap();
        assert_eq!(s.to_string(), "beauty,direct,indirect,sky");
        assert_eq!(PassSet::parse("sky").unwrap(), s);
        assert_eq!(
            PassSet::parse("indirect,albedo").unwrap().to_string(),
            "beauty,direct,indirect,albedo,sky"
        );
        assert_eq!(PassSet::parse("all").unwrap(), PassSet::all());
        assert_eq!(PassSet::parse("beauty").unwrap(), PassSet::NONE);
        assert!(
            PassSet::parse("diffuse").unwrap_err().to_string().contains("one of beauty, direct")
        );
        assert_eq!(PassSet::all().floats_per_pixel(), 3 + 3 + 3 + 3 + 1 + 1 + 1 + 3);
    }

    #[test]
    fn columns_cut_out_what_a_pasted_strip_put_in() {
        let set = PassSet::parse("depth,normal,instance").unwrap();
        let mut strip = PassImage::new(2, 3, set);
        for (k, plane) in strip.planes.iter_mut().enumerate() {
            plane.iter_mut().enumerate().for_each(|(i, v)| *v = (10 * k + i) as f32);
        }
        let mut frame = PassImage::new(6, 3, set);
        frame.paste_strip(2, &strip).unwrap();
        assert_eq!(frame.columns(2, 2).unwrap(), strip);
        assert!(frame.columns(5, 2).is_err(), "past the frame's edge");
    }

    #[test]
    fn strips_paste_into_place_and_the_exr_reads_back_bit_for_bit() {
        let set = PassSet::parse("depth,normal,instance").unwrap();
        let mut frame = PassImage::new(5, 2, set);
        let mut strip = PassImage::new(2, 2, set);
        for (k, plane) in strip.planes.iter_mut().enumerate() {
            for (i, v) in plane.iter_mut().enumerate() {
                *v = if k == 2 { (i + 1) as f32 } else { 0.05 * i as f32 };
            }
        }
        frame.paste_strip(3, &strip).unwrap();
        let normal = frame.plane(Pass::Normal).unwrap();
        // Row 1, column 3: the strip's row 1, column 0 (three channels).
        assert_eq!(&normal[(5 + 3) * 3..(5 + 3) * 3 + 3], &strip.planes[0][6..9]);
        assert!(frame.paste_strip(4, &strip).is_err(), "past the frame's edge");
        let back = PassImage::from_bytes(2, 2, set, &strip.to_bytes()).unwrap();
        assert_eq!(back, strip);
        assert!(PassImage::from_bytes(2, 2, set, &strip.to_bytes()[4..]).is_err());
        let mut bad = strip.clone();
        bad.planes[2][0] = 1.5;
        assert!(
            PassImage::from_bytes(2, 2, set, &bad.to_bytes())
                .unwrap_err()
                .to_string()
                .contains("instance")
        );

        let mut beauty = HdrImage::new(5, 2);
        beauty.pixels[7] = [1.0, 2.0, 3.5];
        let exr = encode_layers(&beauty, &frame, None).unwrap();
        let read = ExrLayers::read(&exr).unwrap();
        assert_eq!(read.beauty().unwrap(), beauty);
        assert_eq!(read.pass_set(), set);
        assert_eq!(read.passes(set).unwrap(), frame);
        assert!(read.channel("ViewLayer.IndexOB.X").is_some());
        assert!(read.channel("ViewLayer.Depth.Z").is_some());
    }
}
