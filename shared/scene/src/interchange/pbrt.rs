//! A scene as a pbrt-v4 scene, so the field's reference renderer can
//! render the same forest: object instancing (one object per model, one
//! `ObjectInstance` per placement), binary PLY meshes with texture
//! coordinates, leaves as `diffusetransmission` with the same ρ_r and ρ_t
//! the tracer uses (per texel, baked from the texture and the leaf optics),
//! their alpha as a linear float texture, the sun as a `distant` light of
//! irradiance π × its radiance scale (docs/lighting.md), and the sky as an
//! `infinite` light from an equal-area image of the same gradient.

use crate::color::srgb8_to_linear;
use crate::model::{Material, Model, Surface};
use crate::{Error, Result, Scene};
use glam::{Mat4, Vec3};
use std::fmt::Write as _;
use std::path::Path;

/// What a pbrt export wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PbrtSummary {
    /// Objects (one per model).
    pub objects: usize,
    /// `ObjectInstance` placements.
    pub instances: usize,
    /// PLY files (one per model and material).
    pub meshes: usize,
    /// Images written beside the scene (textures, alpha masks, the sky).
    pub images: usize,
    /// Triangles in the meshes (each model once).
    pub triangles: u64,
    /// The folder holding the meshes and images.
    pub folder: String,
}

/// Image size of the sky's equal-area map.
const SKY_SIZE: u32 = 64;
/// Samples per pixel and path depth the written scene asks for: enough for
/// a converged reference of a forest at a few hundred pixels.
const PIXEL_SAMPLES: u32 = 1024;
const MAX_DEPTH: u32 = 16;
/// Image size written (Sylva's default frame).
const RESOLUTION: (u32, u32) = (896, 448);

/// Writes `scene` as the pbrt-v4 file `out`, its meshes and images in the
/// folder `<out without extension>_files` beside it.
pub fn export_pbrt(scene: &Scene, out: &Path) -> Result<PbrtSummary> {
    let stem = out
        .file_stem()
        .ok_or_else(|| Error::Invalid("the output needs a file name".into()))?
        .to_string_lossy()
        .into_owned();
    let dir_name = format!("{stem}_files");
    let dir = out.with_file_name(&dir_name);
    std::fs::create_dir_all(&dir).map_err(|e| Error::file(dir.display(), "cannot create", e))?;
    let mut s = String::new();
    let mut summary = PbrtSummary {
        objects: 0,
        instances: 0,
        meshes: 0,
        images: 0,
        triangles: 0,
        folder: dir.display().to_string(),
    };
    let _ = writeln!(s, "# exported by Sylva {}", env!("CARGO_PKG_VERSION"));

    // pbrt's camera space is left-handed; Sylva's world is right-handed.
    let c = &scene.camera;
    let at = c.position + c.forward;
    let _ = writeln!(s, "Scale -1 1 1");
    let _ = writeln!(s, "LookAt {} {} {}", v3(c.position), v3(at), v3(c.up));
    // pbrt's fov is the shorter image axis's: the vertical one here.
    let fov = 2.0 * c.tan_half_fov_y.atan().to_degrees();
    let _ = writeln!(s, "Camera \"perspective\" \"float fov\" [ {fov} ]");
    let _ = writeln!(
        s,
        "Film \"rgb\" \"integer xresolution\" [ {} ] \"integer yresolution\" [ {} ] \"string filename\" [ \"{stem}.exr\" ]",
        RESOLUTION.0, RESOLUTION.1
    );
    let _ = writeln!(s, "Sampler \"zsobol\" \"integer pixelsamples\" [ {PIXEL_SAMPLES} ]");
    let _ = writeln!(s, "Integrator \"volpath\" \"integer maxdepth\" [ {MAX_DEPTH} ]");
    let _ = writeln!(s, "WorldBegin");

    // The sun: a surface facing it receives π × its radiance scale.
    let e = scene.sun.radiance.map(|v| std::f32::consts::PI * v);
    let _ = writeln!(
        s,
        "LightSource \"distant\" \"point3 from\" [ {} ] \"point3 to\" [ 0 0 0 ] \"rgb L\" [ {} ]",
        v3(scene.sun.towards),
        rgb(e)
    );
    // The sky: pbrt's infinite light takes an equal-area map whose +z is up.
    let sky = dir.join("sky.exr");
    write_sky(scene, &sky)?;
    summary.images += 1;
    let _ = writeln!(
        s,
        "AttributeBegin\n  Rotate -90 1 0 0\n  LightSource \"infinite\" \"string filename\" [ \"{dir_name}/sky.exr\" ]\nAttributeEnd"
    );

    if let Some(g) = &scene.ground {
        let h = 1.0e4;
        let _ = writeln!(
            s,
            "AttributeBegin\n  Material \"diffuse\" \"rgb reflectance\" [ {} ]\n  Shape \"bilinearmesh\" \"point3 P\" [ {} 0 {} {} 0 {} {} 0 {} {} 0 {} ]\nAttributeEnd",
            rgb(g.color),
            -h,
            -h,
            h,
            -h,
            -h,
            h,
            h,
            h
        );
    }

    for (mi, m) in scene.models.iter().enumerate() {
        let name = format!("model{mi}-{}", sanitize(&m.name));
        let _ = writeln!(s, "ObjectBegin \"{name}\"");
        for (k, mat) in m.model.materials.iter().enumerate() {
            let tris: Vec<[u32; 3]> = m
                .model
                .triangles
                .iter()
                .zip(&m.model.material)
                .filter(|(_, t)| **t as usize == k)
                .map(|(t, _)| *t)
                .collect();
            if tris.is_empty() {
                continue;
            }
            let ply = format!("{name}-{k}.ply");
            write_ply(&m.model, &tris, &dir.join(&ply))?;
            summary.meshes += 1;
            summary.triangles += tris.len() as u64;
            let _ = writeln!(s, "  AttributeBegin");
            let files = Files { dir: &dir, dir_name: &dir_name, summary: &mut summary };
            let alpha = material(scene, &m.model, mat, &format!("{name}-{k}"), files, &mut s)?;
            let alpha = alpha.map(|t| format!(" \"texture alpha\" \"{t}\"")).unwrap_or_default();
            let _ = writeln!(
                s,
                "    Shape \"plymesh\" \"string filename\" [ \"{dir_name}/{ply}\" ]{alpha}"
            );
            let _ = writeln!(s, "  AttributeEnd");
        }
        let _ = writeln!(s, "ObjectEnd");
        summary.objects += 1;
        for inst in scene.instances.iter().filter(|i| i.model as usize == mi) {
            let m = Mat4::from(inst.to_world).to_cols_array();
            let nums: Vec<String> = m.iter().map(|v| v.to_string()).collect();
            let _ = writeln!(
                s,
                "AttributeBegin\n  ConcatTransform [ {} ]\n  ObjectInstance \"{name}\"\nAttributeEnd",
                nums.join(" ")
            );
            summary.instances += 1;
        }
    }
    std::fs::write(out, s).map_err(|e| Error::file(out.display(), "cannot write", e))?;
    Ok(summary)
}

/// Where a material's textures go: the folder, its name as the pbrt file
/// writes it, and the summary that counts them.
struct Files<'a> {
    dir: &'a Path,
    dir_name: &'a str,
    summary: &'a mut PbrtSummary,
}

/// Writes a material's directives to `s` (and its textures to `files`);
/// the alpha texture's name, if the material is alpha-masked.
fn material(
    scene: &Scene,
    model: &Model,
    mat: &Material,
    name: &str,
    files: Files,
    s: &mut String,
) -> Result<Option<String>> {
    let Files { dir, dir_name, summary } = files;
    let base = [mat.base_color[0], mat.base_color[1], mat.base_color[2]];
    let texture = mat.texture.and_then(|t| model.textures.get(t as usize));
    let optics = &scene.file.leaf_optics;
    // Per side as the tracer's voxelizer averages them: pbrt's diffuse
    // transmitter has one reflectance and one transmittance.
    let leaf = |albedo: [f32; 3]| -> ([f32; 3], [f32; 3]) {
        let k: [[f32; 4]; 3] = std::array::from_fn(|c| optics.coefficients(albedo, c));
        (
            std::array::from_fn(|c| 0.5 * (k[c][0] + k[c][1])),
            std::array::from_fn(|c| 0.5 * (k[c][2] + k[c][3])),
        )
    };
    match (mat.surface, texture) {
        (Surface::Wood, None) => {
            let _ = writeln!(s, "    Material \"diffuse\" \"rgb reflectance\" [ {} ]", rgb(base));
        }
        (Surface::Leaf, None) => {
            let (r, t) = leaf(base);
            let _ = writeln!(
                s,
                "    Material \"diffusetransmission\" \"rgb reflectance\" [ {} ] \"rgb transmittance\" [ {} ]",
                rgb(r),
                rgb(t)
            );
        }
        (surface, Some(tex)) => {
            // Each texel's linear albedo through the same optics the tracer uses.
            let (w, h) = (tex.width, tex.height);
            let mut refl = image::RgbImage::new(w, h);
            let mut trans = image::RgbImage::new(w, h);
            for (i, px) in tex.rgba.as_chunks::<4>().0.iter().enumerate() {
                let albedo: [f32; 3] = std::array::from_fn(|c| base[c] * srgb8_to_linear(px[c]));
                let (r, t) =
                    if surface == Surface::Leaf { leaf(albedo) } else { (albedo, [0.0; 3]) };
                let (x, y) = (i as u32 % w, i as u32 / w);
                refl.put_pixel(x, y, image::Rgb(r.map(linear_to_srgb8)));
                trans.put_pixel(x, y, image::Rgb(t.map(linear_to_srgb8)));
            }
            let (rf, tf) = (format!("{name}-reflectance.png"), format!("{name}-transmittance.png"));
            refl.save(dir.join(&rf))?;
            let _ = writeln!(
                s,
                "    Texture \"{name}-r\" \"spectrum\" \"imagemap\" \"string filename\" [ \"{dir_name}/{rf}\" ] \"string filter\" [ \"point\" ]"
            );
            summary.images += 1;
            if surface == Surface::Leaf {
                trans.save(dir.join(&tf))?;
                summary.images += 1;
                let _ = writeln!(
                    s,
                    "    Texture \"{name}-t\" \"spectrum\" \"imagemap\" \"string filename\" [ \"{dir_name}/{tf}\" ] \"string filter\" [ \"point\" ]"
                );
                let _ = writeln!(
                    s,
                    "    Material \"diffusetransmission\" \"texture reflectance\" \"{name}-r\" \"texture transmittance\" \"{name}-t\""
                );
            } else {
                let _ =
                    writeln!(s, "    Material \"diffuse\" \"texture reflectance\" \"{name}-r\"");
            }
            if let Some(cut) = mat.alpha_cutoff {
                // pbrt cuts where alpha is 0: the mask, thresholded as the tracer does.
                let mask = image::GrayImage::from_fn(w, h, |x, y| {
                    let a = tex.rgba[4 * (y * w + x) as usize + 3] as f32 / 255.0;
                    image::Luma([if a >= cut { 255 } else { 0 }])
                });
                let af = format!("{name}-alpha.png");
                mask.save(dir.join(&af))?;
                summary.images += 1;
                let _ = writeln!(
                    s,
                    "    Texture \"{name}-a\" \"float\" \"imagemap\" \"string filename\" [ \"{dir_name}/{af}\" ] \"string encoding\" [ \"linear\" ] \"string filter\" [ \"point\" ]"
                );
                return Ok(Some(format!("{name}-a")));
            }
        }
    }
    Ok(None)
}

/// A binary little-endian PLY of `tris` over the model's vertices (each
/// vertex used, once), with texture coordinates.
fn write_ply(model: &Model, tris: &[[u32; 3]], path: &Path) -> Result<()> {
    let mut remap = vec![u32::MAX; model.positions.len()];
    let mut verts: Vec<u32> = Vec::new();
    let faces: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| {
            t.map(|v| {
                if remap[v as usize] == u32::MAX {
                    remap[v as usize] = verts.len() as u32;
                    verts.push(v);
                }
                remap[v as usize]
            })
        })
        .collect();
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float u\nproperty float v\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        verts.len(),
        faces.len()
    )
    .into_bytes();
    for &v in &verts {
        let p = model.positions[v as usize];
        let uv = model.uvs.get(v as usize).copied().unwrap_or_default();
        for f in [p.x, p.y, p.z, uv.x, uv.y] {
            out.extend_from_slice(&f.to_le_bytes());
        }
    }
    for f in &faces {
        out.push(3);
        for i in f {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    std::fs::write(path, out).map_err(|e| Error::file(path.display(), "cannot write", e))
}

/// The sky gradient (docs/lighting.md: horizon to zenith by the square root
/// of the elevation's sine, nothing below the horizon where the ground is)
/// on pbrt's equal-area octahedral map, whose +z is up. On that map a
/// texel's height z = ±(1 − r²), with r = 1 − |1 − |u| − |v|| (Clarberg 2008).
fn write_sky(scene: &Scene, path: &Path) -> Result<()> {
    let (zen, hor) = (scene.sky.zenith, scene.sky.horizon);
    let ground = scene.ground.is_some();
    let img = image::Rgb32FImage::from_fn(SKY_SIZE, SKY_SIZE, |x, y| {
        let u = 2.0 * (x as f32 + 0.5) / SKY_SIZE as f32 - 1.0;
        let v = 2.0 * (y as f32 + 0.5) / SKY_SIZE as f32 - 1.0;
        let signed = 1.0 - (u.abs() + v.abs());
        let r = 1.0 - signed.abs();
        let z = (1.0 - r * r).copysign(signed);
        if z < 0.0 && ground {
            return image::Rgb([0.0; 3]);
        }
        let t = z.max(0.0).sqrt();
        image::Rgb(std::array::from_fn(|c| hor[c] + (zen[c] - hor[c]) * t))
    });
    image::DynamicImage::ImageRgb32F(img)
        .save_with_format(path, image::ImageFormat::OpenExr)
        .map_err(|error| Error::Image {
            context: format!("{}: cannot write", path.display()),
            error,
        })
}

fn linear_to_srgb8(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}

fn v3(v: Vec3) -> String {
    format!("{} {} {}", v.x, v.y, v.z)
}

fn rgb(c: [f32; 3]) -> String {
    format!("{} {} {}", c[0], c[1], c[2])
}

/// A name safe inside pbrt's quoted strings and file names.
fn sanitize(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '_' })
        .take(64)
        .collect()
}
