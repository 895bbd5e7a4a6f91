//! Models: triangle meshes with texture coordinates and materials (leaf or
//! wood, base colour, alpha-masked texture), and their loading from glTF 2.0.

use crate::error::chain;
use crate::{Error, FileAccess, Result};
use glam::{Mat4, Vec2, Vec3};
use std::path::Path;

/// What a triangle is made of, for the LB medium: leaves make green nodes,
/// wood brown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    /// Leaf blade (alpha-masked in glTF, or anything not named as wood).
    Leaf,
    /// Trunk, branch or stem.
    Wood,
}

/// An RGBA8 image: colour in sRGB, alpha linear, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width × height × 4` bytes.
    pub rgba: Vec<u8>,
}

impl Texture {
    /// The texel nearest to `uv` (wrapping), as linear-alpha RGBA8.
    pub fn texel(&self, uv: Vec2) -> [u8; 4] {
        let x = ((uv.x - uv.x.floor()) * self.width as f32) as u32 % self.width;
        let y = ((uv.y - uv.y.floor()) * self.height as f32) as u32 % self.height;
        let i = 4 * (y * self.width + x) as usize;
        [self.rgba[i], self.rgba[i + 1], self.rgba[i + 2], self.rgba[i + 3]]
    }
}

/// How a surface looks.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name, from the file or the generator.
    pub name: String,
    /// Leaf or wood.
    pub surface: Surface,
    /// Linear RGBA multiplier of the texture (or the colour, without one).
    pub base_color: [f32; 4],
    /// Index into the model's textures.
    pub texture: Option<u32>,
    /// Texels with alpha below this are holes (glTF `MASK`); `None` is opaque.
    pub alpha_cutoff: Option<f32>,
    /// Whether both faces are lit (leaves).
    pub double_sided: bool,
}

impl Material {
    /// An untextured, opaque material.
    pub fn plain(name: &str, surface: Surface, rgb: [f32; 3]) -> Self {
        Self {
            name: name.into(),
            surface,
            base_color: [rgb[0], rgb[1], rgb[2], 1.0],
            texture: None,
            alpha_cutoff: None,
            double_sided: surface == Surface::Leaf,
        }
    }

    /// Whether a point whose texel (of this material's texture, `None`
    /// without one) is `texel` is a hole.
    pub fn is_hole(&self, texel: Option<[u8; 4]>) -> bool {
        let Some(cut) = self.alpha_cutoff else { return false };
        let alpha = texel.map_or(1.0, |t| t[3] as f32 / 255.0);
        alpha * self.base_color[3] < cut
    }
}

/// An indexed triangle model in model space.
#[derive(Clone, Debug, Default)]
pub struct Model {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Texture coordinates, one per position.
    pub uvs: Vec<Vec2>,
    /// Vertex indices, three per triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Material index per triangle.
    pub material: Vec<u32>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Textures the materials refer to.
    pub textures: Vec<Texture>,
}

impl Model {
    /// Bytes its geometry, materials and textures hold in memory.
    pub fn bytes(&self) -> u64 {
        let v = |n: usize, each: usize| (n * each) as u64;
        v(self.positions.len(), 12)
            + v(self.uvs.len(), 8)
            + v(self.triangles.len(), 12)
            + v(self.material.len(), 4)
            + v(self.materials.len(), std::mem::size_of::<Material>())
            + self.textures.iter().map(|t| t.rgba.len() as u64).sum::<u64>()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Adds a material; returns its index.
    pub fn add_material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        self.materials.len() as u32 - 1
    }

    /// Adds a triangle with its own three vertices.
    pub fn push_triangle(&mut self, v: [Vec3; 3], uv: [Vec2; 3], material: u32) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&v);
        self.uvs.extend_from_slice(&uv);
        self.triangles.push([base, base + 1, base + 2]);
        self.material.push(material);
    }

    /// Adds a quad `a b c d` (counter-clockwise) as two triangles, with
    /// texture coordinates (0,0) (1,0) (1,1) (0,1) at its corners.
    pub fn push_quad(&mut self, q: [Vec3; 4], material: u32) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&q);
        self.uvs.extend_from_slice(&[
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 0.0),
        ]);
        self.triangles.push([base, base + 1, base + 2]);
        self.triangles.push([base, base + 2, base + 3]);
        self.material.extend([material, material]);
    }

    /// Drops materials no triangle uses and textures no material uses,
    /// renumbering the rest in order.
    pub fn drop_unused_materials(&mut self) {
        let mut used = vec![false; self.materials.len()];
        self.material.iter().for_each(|&m| used[m as usize] = true);
        let mut new_index = vec![u32::MAX; self.materials.len()];
        let old = std::mem::take(&mut self.materials);
        for (i, m) in old.into_iter().enumerate().filter(|(i, _)| used[*i]) {
            new_index[i] = self.materials.len() as u32;
            self.materials.push(m);
        }
        self.material.iter_mut().for_each(|m| *m = new_index[*m as usize]);
        let mut tex_index = vec![None; self.textures.len()];
        let old = std::mem::take(&mut self.textures);
        for (i, t) in old.into_iter().enumerate() {
            if self.materials.iter().any(|m| m.texture == Some(i as u32)) {
                tex_index[i] = Some(self.textures.len() as u32);
                self.textures.push(t);
            }
        }
        self.materials
            .iter_mut()
            .for_each(|m| m.texture = m.texture.and_then(|t| tex_index[t as usize]));
    }

    /// Corners of triangle `t`.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Whether triangle `t` is leaf or wood.
    pub fn surface(&self, t: usize) -> Surface {
        self.materials[self.material[t] as usize].surface
    }

    /// Axis-aligned bounds `(min, max)`, or `None` for an empty model.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.triangles.iter().flatten().map(|&i| self.positions[i as usize]);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }

    /// Number of wood triangles.
    pub fn wood_triangles(&self) -> usize {
        (0..self.triangle_count()).filter(|&t| self.surface(t) == Surface::Wood).count()
    }

    /// Whether the texel `uv` of triangle `t`'s material is a hole.
    pub fn is_transparent(&self, t: usize, uv: Vec2) -> bool {
        let m = &self.materials[self.material[t] as usize];
        m.alpha_cutoff.is_some()
            && m.is_hole(m.texture.map(|i| self.textures[i as usize].texel(uv)))
    }
}

/// Names that mark a glTF material as wood rather than leaf.
const WOOD_WORDS: [&str; 6] = ["bark", "wood", "trunk", "branch", "stem", "twig"];

/// The surface class of a glTF material: wood when its name says so,
/// otherwise leaf (alpha-masked foliage and anything unnamed).
pub fn classify_material(name: Option<&str>) -> Surface {
    let name = name.unwrap_or("").to_ascii_lowercase();
    if WOOD_WORDS.iter().any(|w| name.contains(w)) { Surface::Wood } else { Surface::Leaf }
}

/// Loads every triangle of a glTF 2.0 file (`.gltf` or `.glb`) that the
/// user named, reading buffers and images wherever its URIs point.
pub fn load_gltf(path: &Path) -> Result<Model> {
    let folder = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut budget = GltfBudget::UNLIMITED;
    load_gltf_with(path, &FileAccess::Anywhere(folder), &mut budget, None)
}

/// What a glTF file may still add to a scene; the loader counts its
/// triangles and texels from the document and the image headers, before
/// reading vertex data or decoding a texture, and takes them off.
#[derive(Clone, Copy, Debug)]
pub struct GltfBudget {
    /// Triangles left.
    pub triangles: u64,
    /// Texels left.
    pub texture_pixels: u64,
}

impl GltfBudget {
    /// No caps.
    pub const UNLIMITED: GltfBudget = GltfBudget { triangles: u64::MAX, texture_pixels: u64::MAX };
}

/// Loads every triangle of a glTF 2.0 file (`.gltf` or `.glb`) in the
/// default scene, with node transforms applied, texture coordinates,
/// base-colour textures and alpha modes (`BLEND` is treated as a mask at
/// 0.5). Buffers and images are read only where `access` allows, `data:`
/// URIs always; sizes are checked against `budget` first. With `mesh`,
/// only the mesh of that name is read, in its own space (one species of
/// an instanced scene, whose placements the scene file gives).
pub fn load_gltf_with(
    path: &Path,
    access: &FileAccess,
    budget: &mut GltfBudget,
    mesh: Option<&str>,
) -> Result<Model> {
    // The glTF crates assert on some malformed accessors instead of
    // returning errors; a hostile file must cost its scene, not the process.
    let mut b = *budget;
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        load_unguarded(path, access, &mut b, mesh)
    }));
    match r {
        Ok(Ok(m)) => {
            *budget = b;
            Ok(m)
        }
        Ok(Err(e)) => Err(e),
        Err(_) => Err(Error::gltf(
            path.file_name().map(|f| f.to_string_lossy()).unwrap_or_default(),
            "malformed glTF: the loader failed on it",
        )),
    }
}

fn load_unguarded(
    path: &Path,
    access: &FileAccess,
    budget: &mut GltfBudget,
    mesh: Option<&str>,
) -> Result<Model> {
    let shown = shown_name(path, access);
    let bytes = std::fs::read(path)
        .map_err(|e| Error::file(&shown, "cannot load glTF: cannot read the file", e))?;
    let gltf::Gltf { document: doc, blob } = gltf::Gltf::from_slice(&bytes)
        .map_err(|e| Error::gltf(&shown, format!("cannot load glTF: {}", chain(&e))))?;
    drop(bytes);
    let folder = path.parent().unwrap_or(Path::new("."));
    // Every file the document names must be one we may read, before any is.
    let files = files_named(&doc, access, folder, &shown)?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| Error::gltf(&shown, "the glTF file has no scene"))?;
    let only = match mesh {
        Some(name) => Some(doc.meshes().find(|m| m.name() == Some(name)).ok_or_else(|| {
            let name = name.chars().take(64).collect::<String>();
            Error::gltf(&shown, format!("no mesh named {name:?}"))
        })?),
        None => None,
    };
    let triangles = match &only {
        Some(m) => mesh_triangles(m),
        None => scene_triangles(&scene).map_err(|e| e.within(&shown))?,
    };
    check_accessors(&doc).map_err(|e| e.within(&shown))?;
    if triangles > budget.triangles {
        return Err(Error::limit(
            &shown,
            format!(
                "{triangles} triangles is more than the {} this scene may still have",
                budget.triangles
            ),
        ));
    }
    let buffers = gltf::import_buffers(&doc, Some(folder), blob).map_err(|e| {
        Error::gltf(&shown, format!("cannot load glTF buffers: {}", gltf_error(&e)))
    })?;
    let wanted = wanted_images(&doc, only.as_ref());
    let mut texels = 0u64;
    for img in doc.images().filter(|i| wanted[i.index()]) {
        let (w, h) = image_size(&img, &files, &buffers).map_err(|e| {
            let message = format!("image {}: cannot read its size: {}", img.index(), chain(&*e));
            Error::gltf(&shown, message)
        })?;
        texels = texels.saturating_add(u64::from(w) * u64::from(h));
    }
    if texels > budget.texture_pixels {
        return Err(Error::limit(
            &shown,
            format!(
                "{texels} texels of textures is more than the {} this scene may still have",
                budget.texture_pixels
            ),
        ));
    }
    let images = doc
        .images()
        .map(|i| {
            wanted[i.index()]
                .then(|| gltf::image::Data::from_source(i.source(), Some(folder), &buffers))
                .transpose()
                .map_err(|e| {
                    Error::gltf(&shown, format!("cannot load glTF images: {}", gltf_error(&e)))
                })
        })
        .collect::<Result<Vec<_>>>()?;
    budget.triangles -= triangles;
    budget.texture_pixels -= texels;
    let path = Path::new(&shown);
    let mut model = Model::default();
    add_textures_and_materials(&doc, &images, &mut model, &shown);
    // The glTF default material, for primitives that name none.
    let default_material = model.materials.len() as u32;
    model.materials.push(Material {
        name: "default".into(),
        surface: Surface::Leaf,
        base_color: [1.0; 4],
        texture: None,
        alpha_cutoff: None,
        double_sided: false,
    });
    match &only {
        Some(m) => {
            add_mesh(m, Mat4::IDENTITY, &buffers, &mut model, path, default_material)?;
            model.drop_unused_materials();
        }
        None => {
            for node in scene.nodes() {
                add_node(&node, Mat4::IDENTITY, &buffers, &mut model, path, default_material)?;
            }
        }
    }
    if model.triangles.is_empty() {
        return Err(Error::gltf(path.display(), "the glTF scene has no triangles"));
    }
    Ok(model)
}

/// A glTF file's name in messages: inside a bundle, as the bundle names it
/// (its folder is ours), so no path outside the job shows.
pub(crate) fn shown_name(path: &Path, access: &FileAccess) -> String {
    match access {
        FileAccess::Inside(base) => path
            .strip_prefix(base.canonicalize().unwrap_or_else(|_| base.clone()))
            .or_else(|_| path.strip_prefix(base))
            .unwrap_or(path),
        FileAccess::Anywhere(_) => path,
    }
    .display()
    .to_string()
}

/// The files the document's buffers and images name, each checked against
/// what the scene may read before any is read.
pub(crate) fn files_named(
    doc: &gltf::Document,
    access: &FileAccess,
    folder: &Path,
    shown: &str,
) -> Result<std::collections::HashMap<String, std::path::PathBuf>> {
    let mut files = std::collections::HashMap::new();
    let uris = doc.buffers().filter_map(|b| match b.source() {
        gltf::buffer::Source::Uri(u) => Some(u),
        gltf::buffer::Source::Bin => None,
    });
    let image_uris = doc.images().filter_map(|i| match i.source() {
        gltf::image::Source::Uri { uri, .. } => Some(uri),
        gltf::image::Source::View { .. } => None,
    });
    for uri in uris.chain(image_uris) {
        if let Some(p) = access.resolve_uri(folder, uri).map_err(|e| e.within(shown))? {
            files.insert(uri.to_string(), p);
        }
    }
    Ok(files)
}

/// The images the read triangles can show: all of them, or the base
/// colours of the named mesh's materials.
fn wanted_images(doc: &gltf::Document, only: Option<&gltf::Mesh>) -> Vec<bool> {
    match only {
        None => vec![true; doc.images().len()],
        Some(m) => {
            let mut w = vec![false; doc.images().len()];
            for p in m.primitives() {
                if let Some(t) = p.material().pbr_metallic_roughness().base_color_texture() {
                    w[t.texture().source().index()] = true;
                }
            }
            w
        }
    }
}

/// The document's images decoded to RGBA8 as the model's textures, and its
/// materials, after the glTF ones the default for primitives naming none
/// is added by the caller.
fn add_textures_and_materials(
    doc: &gltf::Document,
    images: &[Option<gltf::image::Data>],
    model: &mut Model,
    shown: &str,
) {
    // glTF images decoded to RGBA8, as the textures of this model.
    let mut texture_of_image = vec![None; images.len()];
    for (i, img) in images.iter().enumerate().filter_map(|(i, d)| Some((i, d.as_ref()?))) {
        if let Some(t) = to_rgba8(img) {
            model.textures.push(t);
            texture_of_image[i] = Some(model.textures.len() as u32 - 1);
        } else {
            tracing::warn!(image = i, format = ?img.format, "unsupported texture format; ignored");
        }
    }
    for m in doc.materials() {
        let pbr = m.pbr_metallic_roughness();
        let texture = pbr
            .base_color_texture()
            .and_then(|t| texture_of_image.get(t.texture().source().index()).copied().flatten());
        let alpha_cutoff = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => None,
            gltf::material::AlphaMode::Mask => Some(m.alpha_cutoff().unwrap_or(0.5)),
            gltf::material::AlphaMode::Blend => Some(0.5),
        };
        let image = pbr
            .base_color_texture()
            .and_then(|t| images.get(t.texture().source().index())?.as_ref());
        if let (Some(_), Some(img)) = (alpha_cutoff, image)
            && matches!(
                img.format,
                gltf::image::Format::R8G8B8
                    | gltf::image::Format::R8
                    | gltf::image::Format::R16G16B16
                    | gltf::image::Format::R32G32B32FLOAT
            )
        {
            tracing::warn!(
                file = %shown,
                material = m.name().unwrap_or("?"),
                "the material is alpha-masked but its base-colour texture has no alpha channel, so the mask cuts nothing: the leaves render as solid cards"
            );
        }
        model.materials.push(Material {
            name: m.name().unwrap_or("").to_string(),
            surface: classify_material(m.name()),
            base_color: pbr.base_color_factor(),
            texture,
            alpha_cutoff,
            double_sided: m.double_sided(),
        });
    }
}

/// Deepest node hierarchy read: glTF forbids cycles, and a file with one
/// shows up as a hierarchy deeper than this.
const MAX_NODE_DEPTH: usize = 64;
/// Most node placements (a node counts once per path that reaches it).
const MAX_NODE_PLACEMENTS: u64 = 1 << 20;

/// Triangles the scene's nodes would place (a mesh counts once per node
/// path that reaches it), from accessor counts alone; refuses cycles and
/// graphs whose shared children multiply past [`MAX_NODE_PLACEMENTS`].
fn scene_triangles(scene: &gltf::Scene) -> Result<u64> {
    let mut stack: Vec<(gltf::Node, usize)> = scene.nodes().map(|n| (n, 0)).collect();
    let (mut triangles, mut placements) = (0u64, 0u64);
    while let Some((node, depth)) = stack.pop() {
        if depth >= MAX_NODE_DEPTH {
            return Err(Error::Invalid(format!(
                "the node hierarchy is deeper than {MAX_NODE_DEPTH} (a node that is its own descendant?)"
            )));
        }
        placements += 1;
        if placements > MAX_NODE_PLACEMENTS {
            return Err(Error::Invalid(format!(
                "the nodes place meshes more than {MAX_NODE_PLACEMENTS} times"
            )));
        }
        if let Some(m) = node.mesh() {
            triangles = triangles.saturating_add(mesh_triangles(&m));
        }
        stack.extend(node.children().map(|c| (c, depth + 1)));
    }
    Ok(triangles)
}

/// Triangles of one mesh, from its accessor counts.
fn mesh_triangles(m: &gltf::Mesh) -> u64 {
    m.primitives()
        .filter(|p| p.mode() == gltf::mesh::Mode::Triangles)
        .map(|p| {
            p.indices()
                .or_else(|| p.get(&gltf::Semantic::Positions))
                .map_or(0, |a| a.count() as u64 / 3)
        })
        .fold(0u64, u64::saturating_add)
}

/// Checks every accessor a triangle primitive reads — the type and
/// component type the reader expects, a count of at least one, a stride
/// and offsets inside its view — since the glTF reader asserts rather
/// than erring on these.
pub(crate) fn check_accessors(doc: &gltf::Document) -> Result<()> {
    use gltf::accessor::{DataType as D, Dimensions as N};
    for m in doc.meshes() {
        let mesh = m.name().unwrap_or("?");
        for p in m.primitives().filter(|p| p.mode() == gltf::mesh::Mode::Triangles) {
            let uses = [
                (p.get(&gltf::Semantic::Positions), "POSITION", &[N::Vec3][..], &[D::F32][..]),
                (p.indices(), "indices", &[N::Scalar][..], &[D::U8, D::U16, D::U32][..]),
                (
                    p.get(&gltf::Semantic::TexCoords(0)),
                    "TEXCOORD_0",
                    &[N::Vec2][..],
                    &[D::F32, D::U8, D::U16][..],
                ),
            ];
            for (acc, what, dims, types) in uses {
                let Some(a) = acc else { continue };
                let bad = |m: String| {
                    Err(Error::Invalid(format!(
                        "mesh {mesh:?}: {what} accessor {}: {m}",
                        a.index()
                    )))
                };
                if !dims.contains(&a.dimensions()) || !types.contains(&a.data_type()) {
                    return bad(format!(
                        "{:?} of {:?} cannot be read as {what}",
                        a.dimensions(),
                        a.data_type()
                    ));
                }
                if a.count() == 0 || a.count() > 1 << 28 {
                    return bad(format!("count {} outside [1, 2^28]", a.count()));
                }
                if a.sparse().is_some() {
                    return bad("sparse accessors are not read".into());
                }
                let Some(view) = a.view() else { return bad("no buffer view".into()) };
                let element = a.size();
                let stride = view.stride().unwrap_or(element);
                if stride < element {
                    return bad(format!(
                        "stride {stride} is less than the element's {element} bytes"
                    ));
                }
                let end_of_first = (a.offset() as u64).checked_add(element as u64);
                let span = (a.count() as u64 - 1)
                    .checked_mul(stride as u64)
                    .zip(end_of_first)
                    .and_then(|(v, e)| v.checked_add(e));
                if span.is_none_or(|s| s > view.length() as u64)
                    || (view.offset() as u64)
                        .checked_add(view.length() as u64)
                        .is_none_or(|end| end > view.buffer().length() as u64)
                {
                    return bad("runs past its buffer view or the view past its buffer".into());
                }
            }
        }
    }
    Ok(())
}

/// Width and height of a glTF image from its header, without decoding it.
fn image_size(
    img: &gltf::Image,
    files: &std::collections::HashMap<String, std::path::PathBuf>,
    buffers: &[gltf::buffer::Data],
) -> std::result::Result<(u32, u32), Box<dyn std::error::Error + Send + Sync>> {
    let reader = match img.source() {
        gltf::image::Source::Uri { uri, .. } => match files.get(uri) {
            Some(p) => image::ImageReader::new(std::io::BufReader::new(std::fs::File::open(p)?))
                .with_guessed_format()?
                .into_dimensions()?,
            None => {
                use base64::Engine as _;
                // A data: URI; the bytes are base64 after the comma.
                let b64 = uri
                    .split_once(";base64,")
                    .map(|(_, d)| d)
                    .ok_or("a data: URI that is not base64")?;
                let bytes = base64::engine::general_purpose::STANDARD.decode(b64)?;
                image::ImageReader::new(std::io::Cursor::new(bytes))
                    .with_guessed_format()?
                    .into_dimensions()?
            }
        },
        gltf::image::Source::View { view, .. } => {
            let data = buffers.get(view.buffer().index()).ok_or("no such buffer")?;
            let bytes = data
                .0
                .get(view.offset()..view.offset() + view.length())
                .ok_or("buffer view runs past its buffer")?;
            image::ImageReader::new(std::io::Cursor::new(bytes))
                .with_guessed_format()?
                .into_dimensions()?
        }
    };
    Ok(reader)
}

/// A glTF loading error, in words that name no path outside the scene.
fn gltf_error(e: &gltf::Error) -> String {
    match e {
        gltf::Error::Io(_) => "a file it names cannot be read".into(),
        gltf::Error::BufferLength { buffer, expected, actual } => {
            format!("buffer {buffer} holds {actual} bytes where it declares {expected}")
        }
        other => other.to_string(),
    }
}

fn to_rgba8(img: &gltf::image::Data) -> Option<Texture> {
    use gltf::image::Format;
    let px = (img.width * img.height) as usize;
    let rgba = match img.format {
        Format::R8G8B8A8 => img.pixels.clone(),
        Format::R8G8B8 => {
            img.pixels.as_chunks::<3>().0.iter().flat_map(|c| [c[0], c[1], c[2], 255]).collect()
        }
        Format::R8G8 => {
            img.pixels.as_chunks::<2>().0.iter().flat_map(|c| [c[0], c[0], c[0], c[1]]).collect()
        }
        Format::R8 => img.pixels.iter().flat_map(|&c| [c, c, c, 255]).collect(),
        _ => return None,
    };
    (rgba.len() == 4 * px && px > 0).then_some(Texture {
        width: img.width,
        height: img.height,
        rgba,
    })
}

fn add_node(
    node: &gltf::Node,
    parent: Mat4,
    buffers: &[gltf::buffer::Data],
    model: &mut Model,
    path: &Path,
    default_material: u32,
) -> Result<()> {
    let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
    if let Some(m) = node.mesh() {
        add_mesh(&m, world, buffers, model, path, default_material)?;
    }
    for child in node.children() {
        add_node(&child, world, buffers, model, path, default_material)?;
    }
    Ok(())
}

/// Adds the triangle primitives of `m`, placed by `world`.
fn add_mesh(
    m: &gltf::Mesh,
    world: Mat4,
    buffers: &[gltf::buffer::Data],
    model: &mut Model,
    path: &Path,
    default_material: u32,
) -> Result<()> {
    {
        for prim in m.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                tracing::warn!(mesh = m.name(), mode = ?prim.mode(), "skipping a non-triangle primitive");
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else { continue };
            let base = model.positions.len() as u32;
            for p in pos {
                let v = world.transform_point3(Vec3::from(p));
                if !v.is_finite() {
                    return Err(Error::gltf(
                        path.display(),
                        format!(
                            "mesh {:?} has a non-finite vertex position",
                            m.name().unwrap_or("?")
                        ),
                    ));
                }
                model.positions.push(v);
            }
            let count = model.positions.len() as u32 - base;
            match reader.read_tex_coords(0) {
                Some(uv) => model.uvs.extend(uv.into_f32().map(Vec2::from)),
                None => model.uvs.extend(std::iter::repeat_n(Vec2::ZERO, count as usize)),
            }
            if model.uvs.len() != model.positions.len() {
                return Err(Error::gltf(
                    path.display(),
                    format!(
                        "mesh {:?} has {} texture coordinates for {count} vertices",
                        m.name().unwrap_or("?"),
                        model.uvs.len() - base as usize
                    ),
                ));
            }
            let indices: Vec<u32> = match reader.read_indices() {
                Some(ix) => ix.into_u32().collect(),
                None => (0..count).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i >= count) {
                return Err(Error::gltf(
                    path.display(),
                    format!("mesh {:?} indexes vertex {bad} of {count}", m.name().unwrap_or("?")),
                ));
            }
            let material = prim.material().index().map_or(default_material, |i| i as u32);
            for t in indices.as_chunks::<3>().0 {
                model.triangles.push([base + t[0], base + t[1], base + t[2]]);
                model.material.push(material);
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fern() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/fern_02.glb")
    }

    #[test]
    fn fern_loads_with_its_alpha_masked_texture() {
        let m = load_gltf(&fern()).unwrap();
        assert_eq!(m.triangle_count(), 6232);
        assert_eq!(m.uvs.len(), m.positions.len());
        let leaf = &m.materials[0];
        assert_eq!(leaf.name, "fern_02");
        assert_eq!(leaf.alpha_cutoff, Some(0.5));
        assert!(leaf.double_sided);
        let tex = &m.textures[leaf.texture.expect("fern has a base-colour texture") as usize];
        assert!(tex.width >= 256 && tex.height >= 256);
        // This file's base-colour image is a three-channel JPEG, so by the
        // glTF rules its mask cuts nothing: alpha is 1 everywhere.
        assert!(tex.rgba.as_chunks::<4>().0.iter().all(|p| p[3] == 255));
        assert!(!m.is_transparent(0, Vec2::new(0.01, 0.01)));
        assert!(m.material.iter().all(|&i| i == 0));
    }

    #[test]
    fn missing_and_broken_files_name_the_file() {
        let err = format!("{:#}", load_gltf(Path::new("/nonexistent/tree.glb")).unwrap_err());
        assert!(err.contains("/nonexistent/tree.glb: cannot load glTF"), "{err}");
    }
}
