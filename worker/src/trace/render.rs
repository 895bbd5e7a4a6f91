//! The strip renderer: one compute dispatch renders columns `[x0, x1)` of
//! the frame and reads them back as linear HDR.

use super::filter::SampleMeans;
use super::gpu_scene::GpuScene;
use super::kernels::{Kernels, Tracer};
use crate::gpu::GpuContext;
use crate::lighting::{self, Kernel};
use bytemuck::{Pod, Zeroable};
use serde::Serialize;
use std::sync::Arc;
use sylva_scene::film::RayCounts;
use sylva_scene::frame::FrameSettings;
use sylva_scene::passes::{Pass, PassImage, PassSet};
use sylva_scene::sequence::View;
use sylva_scene::{LightingMode, Scene};
use wgpu::util::DeviceExt;

/// Bytes one sample of the per-sample kernel writes per pixel: four
/// images of four floats (the path, `local` along it, the first
/// surface's guides and its indirect light; `reference.wgsl`'s
/// `reference_sample`), and two more in the `PASSES` kernels (the first
/// event's split and the camera ray's normal; a dispatch's output then
/// also holds one image of sample 0's depth and ids).
pub fn sample_bytes_per_pixel(passes: bool) -> u64 {
    if passes { 6 * 16 } else { 4 * 16 }
}

/// A pixel's guides in the layout of the direct kernels' guide images
/// (`guides` in render.wgsl), as means: (albedo, depth), (normal, 0),
/// (instance + 1, model + 1, 0, 0), the albedo and normal over the
/// pixel's samples, the depth and ids of its sample 0.
type GuidePixel = [[f32; 4]; 3];

/// Longest path the reference integrator follows.
pub const MAX_BOUNCES: u32 = 16;

/// The per-frame uniform `render.wgsl` reads as `Frame` (the fields are
/// documented there; a test checks the two layouts agree).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct FrameUniform {
    pub cam_position: [f32; 3],
    pub tan_half_fov_y: f32,
    pub cam_forward: [f32; 3],
    pub aspect: f32,
    pub cam_right: [f32; 3],
    pub width: u32,
    pub cam_up: [f32; 3],
    pub height: u32,
    pub sun_towards: [f32; 3],
    pub x0: u32,
    pub sun_radiance: [f32; 3],
    pub strip_width: u32,
    pub sky_zenith: [f32; 3],
    pub spp: u32,
    pub sky_horizon: [f32; 3],
    pub seed: u32,
    pub ground_color: [f32; 3],
    pub has_ground: u32,
    pub ambient: [f32; 3],
    pub lighting: u32,
    pub lb_free: f32,
    pub lb_strength: f32,
    pub epsilon: f32,
    pub max_bounces: u32,
    pub leaf_reflect_front: [f32; 3],
    pub pad0: u32,
    pub leaf_reflect_back: [f32; 3],
    pub pad1: u32,
    pub leaf_transmit_front: [f32; 3],
    pub pad2: u32,
    pub leaf_transmit_back: [f32; 3],
    pub pad3: u32,
    pub bl_sky: [[f32; 4]; 8],
    pub ground_grid: [f32; 4],
    pub ground_dims: [u32; 4],
    pub lb_model: u32,
    pub gather_bounces: u32,
    pub sample_base: u32,
    pub batch_spp: u32,
}

impl FrameUniform {
    /// Puts the camera in.
    fn set_camera(&mut self, c: &sylva_scene::camera::Camera) {
        (self.cam_position, self.cam_forward, self.cam_right, self.cam_up) =
            (c.position.to_array(), c.forward.to_array(), c.right.to_array(), c.up.to_array());
        self.tan_half_fov_y = c.tan_half_fov_y;
    }

    /// Puts the sun's direction in, with the paper model's free-space LB
    /// total for it (`lb_free`, its boundary's sum at unit strength).
    fn set_sun(&mut self, towards: glam::Vec3) -> anyhow::Result<()> {
        self.sun_towards = towards.to_array();
        self.lb_free = sylva_light::lb::Sun::towards(towards.as_dvec3().to_array(), 1.0)?
            .boundary()
            .values
            .iter()
            .sum();
        Ok(())
    }
}

/// What a frame is rendered with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RenderSettings {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Rays per pixel.
    pub spp: u32,
    /// Seed of the per-pixel sample hash.
    pub seed: u32,
    /// Lighting method.
    pub lighting: LightingMode,
    /// Constant indirect light of the `ambient` method, linear RGB.
    pub ambient: [f32; 3],
    /// The paper LB model's weight of LB light relative to the sun's: a
    /// non-physical override the grounded model does not read.
    pub lb_strength: f32,
    /// The frame's camera and sun where they differ from the scene's.
    #[serde(skip)]
    pub view: View,
    /// The gather methods: bounces traced before the far end's lattice.
    pub gather_bounces: u32,
    /// The gather methods: radius in pixels of the filter over their
    /// indirect light (0: none).
    pub gather_filter: u32,
    /// Render passes beside the image.
    pub passes: PassSet,
}

impl RenderSettings {
    /// What `frame` asks of a scene whose own lighting method is
    /// `scene_lighting`: the one way a frame's settings become render
    /// settings (flags → [`FrameSettings`] → these), on a worker and in
    /// this process alike. `ambient` stays 0 unless the frame gives it; the
    /// `ambient` method matches it to the LB image before rendering.
    pub fn resolve(frame: &FrameSettings, scene_lighting: LightingMode) -> Self {
        RenderSettings {
            width: frame.width,
            height: frame.height,
            spp: frame.spp,
            seed: frame.seed,
            lighting: frame.lighting_or(scene_lighting),
            ambient: frame.ambient.unwrap_or([0.0; 3]),
            lb_strength: frame.lb_strength,
            view: frame.view,
            gather_bounces: frame.gather_bounces,
            gather_filter: frame.gather_filter,
            passes: frame.passes,
        }
    }

    /// Whether the frame is a gather whose indirect light is filtered.
    pub fn gather_filtered(&self) -> bool {
        matches!(self.lighting, LightingMode::Gather | LightingMode::GatherAmbient)
            && self.gather_filter > 0
    }
}

/// The GPU's ray counters for one strip: 32-bit atomics, as WGSL has them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct GpuRayCounts {
    /// Camera rays.
    pub primary: u32,
    /// Rays towards the sun.
    pub shadow: u32,
    /// Transparent texels a ray passed through and went on.
    pub transparent: u32,
    pad: u32,
}

impl From<GpuRayCounts> for RayCounts {
    fn from(c: GpuRayCounts) -> Self {
        RayCounts {
            primary: c.primary.into(),
            shadow: c.shadow.into(),
            transparent: c.transparent.into(),
        }
    }
}

/// A rendered strip: columns `[x0, x0 + width)` of the frame, linear HDR.
#[derive(Clone, Debug)]
pub struct RenderedStrip {
    /// First column.
    pub x0: u32,
    /// Columns.
    pub width: u32,
    /// Linear RGB, `width × height`, rows from the top.
    pub pixels: Vec<[f32; 3]>,
    /// Per pixel, the fraction of its samples that hit a model (not sky or ground).
    pub coverage: Vec<f32>,
    /// The reference only (empty otherwise): per pixel, what `local` shows
    /// along the same camera samples, so the reference's indirect light is
    /// `pixels − first_light` without another sampling's edge aliasing.
    pub first_light: Vec<[f32; 3]>,
    /// Rays traced.
    pub rays: RayCounts,
    /// The passes the frame asked for beside the image, if any.
    pub passes: Option<PassImage>,
}

/// The render pipeline over one uploaded scene.
pub struct StripRenderer {
    scene: GpuScene,
    /// Its kernels (shared with other scenes of the same specialisation).
    kernels: Arc<Kernels>,
    base: FrameUniform,
    /// The gathers' filter: the depth range of one crown, metres.
    crown_depth: f32,
}

impl StripRenderer {
    /// Builds the pipeline for an uploaded scene.
    pub fn new(tracer: &Tracer, gpu_scene: GpuScene, scene: &Scene) -> anyhow::Result<Self> {
        let kernels = tracer.kernels.get(tracer, gpu_scene.backend, !scene.clouds.is_empty())?;
        Ok(Self::build(gpu_scene, scene, kernels))
    }

    /// The uploaded scene it traces.
    pub fn scene(&self) -> &GpuScene {
        &self.scene
    }

    /// Its kernels.
    pub fn kernels(&self) -> &Kernels {
        &self.kernels
    }

    fn build(gpu_scene: GpuScene, scene: &Scene, kernels: Arc<Kernels>) -> Self {
        let mut base = FrameUniform {
            sun_radiance: scene.sun.radiance,
            sky_zenith: scene.sky.zenith,
            sky_horizon: scene.sky.horizon,
            ground_color: scene.ground.as_ref().map_or([0.0; 3], |g| g.color),
            has_ground: scene.ground.is_some() as u32,
            epsilon: ray_offset(scene),
            max_bounces: MAX_BOUNCES,
            leaf_reflect_front: scene.file.leaf_optics.reflect_front,
            leaf_reflect_back: scene.file.leaf_optics.reflect_back,
            leaf_transmit_front: scene.file.leaf_optics.transmit_front,
            leaf_transmit_back: scene.file.leaf_optics.transmit_back,
            bl_sky: lighting::boulanger::sky_per_direction(scene),
            ground_grid: gpu_scene.ground.0,
            ground_dims: gpu_scene.ground.1,
            lb_model: match scene.file.lb_model {
                sylva_scene::LbModel::Grounded => 0,
                sylva_scene::LbModel::Paper => 1,
            },
            ..FrameUniform::zeroed()
        };
        base.set_camera(&scene.camera);
        base.set_sun(scene.sun.towards).expect("the scene checked its sun");
        let crown_depth = super::filter::crown_depth(scene);
        Self { scene: gpu_scene, kernels, base, crown_depth }
    }

    /// Bytes of scene data on the GPU.
    pub fn scene_bytes(&self) -> u64 {
        self.scene.bytes
    }

    /// Renders columns `[x0, x1)` of the frame.
    pub fn render_strip(
        &self,
        ctx: &GpuContext,
        f: &RenderSettings,
        x0: u32,
        x1: u32,
    ) -> anyhow::Result<RenderedStrip> {
        anyhow::ensure!(
            x0 < x1 && x1 <= f.width,
            "strip [{x0}, {x1}) is not inside a frame {} wide",
            f.width
        );
        let strip_width = x1 - x0;
        let method = lighting::method(f.lighting);
        // A frame of a sequence: its own camera and sun (the LB light it
        // reads was prepared for that sun: the worker keys it so).
        let mut base = self.base;
        if let Some(c) = f.view.camera() {
            base.set_camera(&c.map_err(anyhow::Error::msg)?);
        }
        if let Some(towards) = f.view.sun() {
            base.set_sun(towards)?;
        }
        // The gathers' filter reads `radius` columns beyond the strip on
        // each side (the same samples whichever strip renders them), so a
        // frame is the same however it is cut.
        let radius = if f.gather_filtered() { f.gather_filter } else { 0 };
        let (a0, a1) = (x0.saturating_sub(radius), (x1 + radius).min(f.width));
        let uniform = FrameUniform {
            aspect: f.width as f32 / f.height as f32,
            width: f.width,
            height: f.height,
            x0: a0,
            strip_width: a1 - a0,
            spp: f.spp,
            seed: f.seed,
            ambient: f.ambient,
            lighting: method.code,
            lb_strength: f.lb_strength,
            gather_bounces: f.gather_bounces,
            batch_spp: 1,
            ..base
        };
        let with_passes = !f.passes.is_empty();
        ctx.checked("rendering a strip", || {
            if method.kernel != Kernel::Reference {
                let n = (strip_width * f.height) as usize;
                // The image, then the split's three and the guides' three.
                let images = if with_passes { 7 } else { 1 };
                let (px, counts) = self.dispatch(
                    ctx,
                    method.kernel,
                    with_passes,
                    &uniform,
                    images * n as u64 * 16,
                    1,
                )?;
                let rgb = |k: usize| px[k * n..(k + 1) * n].iter().map(|p| [p[0], p[1], p[2]]);
                let passes = with_passes.then(|| {
                    // The kernel sums albedo and normal over the samples.
                    let spp = f.spp as f32;
                    let wanted = if f.passes.wants_guides() { n } else { 0 };
                    let guides: Vec<GuidePixel> = (0..wanted)
                        .map(|i| {
                            let [a, nrm, ids] = std::array::from_fn(|k| px[(4 + k) * n + i]);
                            let mean =
                                |v: [f32; 4], w: f32| [v[0] / spp, v[1] / spp, v[2] / spp, w];
                            [mean(a, a[3]), mean(nrm, 0.0), ids]
                        })
                        .collect();
                    let split = || (rgb(1).collect(), rgb(2).collect(), rgb(3).collect());
                    passes(f, strip_width, split, &guides)
                });
                return Ok(RenderedStrip {
                    x0,
                    width: strip_width,
                    pixels: rgb(0).collect(),
                    coverage: px[..n].iter().map(|p| p[3]).collect(),
                    first_light: Vec::new(),
                    rays: counts.into(),
                    passes,
                });
            }
            let (mut means, guides, rays) = self.sample_means(
                ctx,
                method.kernel,
                with_passes,
                f.passes.wants_guides(),
                &uniform,
            )?;
            if radius > 0 {
                super::filter::filter_indirect(
                    &mut means,
                    (a1 - a0) as usize,
                    radius as usize,
                    self.crown_depth,
                );
            }
            // The strip's own columns.
            let aw = (a1 - a0) as usize;
            fn crop<T: Copy>(image: &[T], aw: usize, cols: std::ops::Range<usize>) -> Vec<T> {
                image.chunks_exact(aw).flat_map(|row| row[cols.clone()].iter().copied()).collect()
            }
            let cols = (x0 - a0) as usize..(x1 - a0) as usize;
            let crop4 = |image: &[[f32; 4]]| crop(image, aw, cols.clone());
            let (px, first) = (crop4(&means.paths), crop4(&means.first));
            let pixels: Vec<[f32; 3]> = px.iter().map(|p| [p[0], p[1], p[2]]).collect();
            // The passes over the strip's own columns.
            let passes = with_passes.then(|| {
                let split = || {
                    let (direct, sky) =
                        (crop(&means.direct, aw, cols.clone()), crop(&means.sky, aw, cols.clone()));
                    // The rest of each path's light is indirect: the split is
                    // exact per sample, so its means split the image.
                    let indirect = (0..pixels.len())
                        .map(|i| std::array::from_fn(|c| pixels[i][c] - direct[i][c] - sky[i][c]))
                        .collect();
                    (direct, indirect, sky)
                };
                passes(f, strip_width, split, &crop(&guides, aw, cols.clone()))
            });
            Ok(RenderedStrip {
                x0,
                width: strip_width,
                pixels,
                coverage: px.iter().map(|p| p[3]).collect(),
                first_light: first.iter().map(|p| [p[0], p[1], p[2]]).collect(),
                rays,
                passes,
            })
        })
    }

    /// The per-sample kernel over the columns `uniform` names, every
    /// sample of the frame: each pixel's mean of its four images and, with
    /// `passes`, the light split and, where `guides` asks, the guides
    /// (empty otherwise: a progressive reference's later batches want the
    /// split alone). As many samples per dispatch as the adapter binds.
    fn sample_means(
        &self,
        ctx: &GpuContext,
        kernel: Kernel,
        passes: bool,
        guides: bool,
        uniform: &FrameUniform,
    ) -> anyhow::Result<(SampleMeans, Vec<GuidePixel>, RayCounts)> {
        let n = (uniform.strip_width * uniform.height) as usize;
        let sample_bytes = n as u64 * sample_bytes_per_pixel(passes);
        // With passes, one image more per dispatch: sample 0's depth and ids.
        let once = if passes { n as u64 * 16 } else { 0 };
        let spp = uniform.spp;
        let batch = (ctx.limits.max_storage_buffer_binding_size.saturating_sub(once) / sample_bytes)
            .min(spp as u64) as u32;
        anyhow::ensure!(
            batch >= 1,
            "a strip of {}×{} needs {} bytes of output per sample, more than the adapter binds",
            uniform.strip_width,
            uniform.height,
            sample_bytes
        );
        let mut sums = vec![[0.0f32; 4]; 4 * n];
        // With passes: per pixel, the sums of the first event's sun light
        // and of the sky it saw.
        let (mut direct, mut sky) = (vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n]);
        // With passes: per pixel, the sum of its samples' normals, and
        // sample 0's (depth, instance + 1, model + 1, 0).
        let wanted = if passes && guides { n } else { 0 };
        let mut normals = vec![[0.0f32; 3]; wanted];
        let mut first_ids = Vec::new();
        // Per pixel and channel, Σ (surface indirect)² over its samples:
        // the spread of its indirect light, which the gathers' filter weighs.
        let mut ind_sq = vec![[0.0f64; 3]; n];
        let mut rays = RayCounts::default();
        for base in (0..spp).step_by(batch as usize) {
            let batch_spp = batch.min(spp - base);
            let u = FrameUniform { sample_base: base, batch_spp, ..*uniform };
            let bytes = batch_spp as u64 * sample_bytes + once;
            let (all, counts) = self.dispatch(ctx, kernel, passes, &u, bytes, batch_spp)?;
            // Four (six) images, each `batch_spp` slots of `n` pixels.
            let slots = n * batch_spp as usize;
            let indirect = &all[3 * slots..4 * slots];
            if passes {
                for slot in all[4 * slots..5 * slots].chunks_exact(n) {
                    for ((d, s), v) in direct.iter_mut().zip(&mut sky).zip(slot) {
                        let to = if v[3] > 0.5 { s } else { d };
                        for c in 0..3 {
                            to[c] += v[c];
                        }
                    }
                }
                let normal_slots = if wanted > 0 { &all[5 * slots..6 * slots] } else { &[] };
                for slot in normal_slots.chunks_exact(n) {
                    for (a, v) in normals.iter_mut().zip(slot) {
                        for c in 0..3 {
                            a[c] += v[c];
                        }
                    }
                }
                if base == 0 && wanted > 0 {
                    first_ids = all[6 * slots..6 * slots + n].to_vec();
                }
            }
            for slot in indirect.chunks_exact(n) {
                for (a, v) in ind_sq.iter_mut().zip(slot) {
                    for c in 0..3 {
                        a[c] += (v[c] as f64).powi(2);
                    }
                }
            }
            for (image, sum) in all[..4 * slots].chunks_exact(slots).zip(sums.chunks_exact_mut(n)) {
                for slot in image.chunks_exact(n) {
                    for (a, v) in sum.iter_mut().zip(slot) {
                        for c in 0..4 {
                            a[c] += v[c];
                        }
                    }
                }
            }
            rays.add(&RayCounts::from(counts));
        }
        let mut mean = sums.into_iter().map(|a| a.map(|v| v / spp as f32));
        let mut take = || (&mut mean).take(n).collect::<Vec<_>>();
        let (paths, first, guide, surface_indirect) = (take(), take(), take(), take());
        // The variance of each pixel's mean indirect light, from its samples' spread.
        let k = spp as f64;
        let indirect_variance = ind_sq
            .iter()
            .zip(&surface_indirect)
            .map(|(sq, s)| {
                std::array::from_fn(|c| {
                    let mean = s[c] as f64;
                    if spp < 2 {
                        0.0
                    } else {
                        ((sq[c] / k - mean * mean).max(0.0) / (k - 1.0)) as f32
                    }
                })
            })
            .collect();
        let mean3 = |v: Vec<[f32; 3]>| -> Vec<[f32; 3]> {
            if passes {
                v.into_iter().map(|p| p.map(|x| x / spp as f32)).collect()
            } else {
                Vec::new()
            }
        };
        let (direct, sky) = (mean3(direct), mean3(sky));
        // The guides: the albedo is the third image's (the first surface's,
        // as a diffuse field sees it), the normal its own.
        let guides = (0..wanted)
            .map(|i| {
                let (a, nrm, ids) = (guide[i], normals[i].map(|v| v / spp as f32), first_ids[i]);
                [
                    [a[0], a[1], a[2], ids[0]],
                    [nrm[0], nrm[1], nrm[2], 0.0],
                    [ids[1], ids[2], 0.0, 0.0],
                ]
            })
            .collect();
        Ok((
            SampleMeans { paths, first, guide, surface_indirect, indirect_variance, direct, sky },
            guides,
            rays,
        ))
    }

    /// One dispatch of the method's kernel (writing the passes or not)
    /// with `uniform`, `depth` samples deep (the per-sample kernel's z),
    /// into `bytes` of output: what it wrote and the rays it counted.
    fn dispatch(
        &self,
        ctx: &GpuContext,
        kernel: Kernel,
        passes: bool,
        uniform: &FrameUniform,
        bytes: u64,
        depth: u32,
    ) -> anyhow::Result<(Vec<[f32; 4]>, GpuRayCounts)> {
        let pipeline = self.kernels.render(ctx, kernel, passes)?;
        let device = &ctx.device;
        let ubuf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("frame"),
            contents: bytemuck::bytes_of(uniform),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        anyhow::ensure!(
            bytes <= ctx.limits.max_storage_buffer_binding_size,
            "a strip of {}×{} at {} samples needs {bytes} bytes of output, more than the adapter binds",
            uniform.strip_width,
            uniform.height,
            uniform.spp
        );
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("strip"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let counters = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("ray counters"),
            contents: bytemuck::bytes_of(&GpuRayCounts::default()),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        });
        let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &self.kernels.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: ubuf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: out.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: counters.as_entire_binding() },
            ],
        });
        let mut enc = device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &self.scene.bind_group, &[]);
            pass.set_bind_group(1, &bg, &[]);
            pass.dispatch_workgroups(
                uniform.strip_width.div_ceil(8),
                uniform.height.div_ceil(8),
                depth,
            );
        }
        ctx.queue.submit([enc.finish()]);
        let raw = ctx.read_back(&out, bytes)?;
        let counts: GpuRayCounts =
            *bytemuck::from_bytes(&ctx.read_back(&counters, size_of::<GpuRayCounts>() as u64)?);
        Ok((bytemuck::cast_slice(&raw).to_vec(), counts))
    }
}

/// How far secondary rays start off the surface they leave: a millimetre,
/// or more where the scene's coordinates are large enough for f32 to need it.
fn ray_offset(scene: &Scene) -> f32 {
    let extent = scene
        .instances
        .iter()
        .map(|i| i.to_world.translation.abs().max_element())
        .fold(0.0, f32::max);
    (1e-5 * extent).max(1e-3)
}

/// A strip's passes (`width` columns of the frame's height): the light
/// split (`split` gives direct, indirect and sky, called only when asked)
/// and the guides, from the kernel's guide images.
fn passes(
    f: &RenderSettings,
    width: u32,
    split: impl FnOnce() -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 3]>),
    guides: &[GuidePixel],
) -> PassImage {
    let mut image = PassImage::new(width, f.height, f.passes);
    let mut put = |p: Pass, v: &mut dyn Iterator<Item = f32>| {
        if let Some(plane) = image.plane_mut(p) {
            plane.iter_mut().zip(v).for_each(|(d, s)| *d = s);
        }
    };
    if f.passes.wants_split() {
        let (direct, indirect, sky) = split();
        put(Pass::Direct, &mut direct.iter().flatten().copied());
        put(Pass::Indirect, &mut indirect.iter().flatten().copied());
        put(Pass::Sky, &mut sky.iter().flatten().copied());
    }
    if f.passes.wants_guides() {
        let mean = |k: usize| guides.iter().flat_map(move |g| [0, 1, 2].map(|c| g[k][c]));
        put(Pass::Albedo, &mut mean(0));
        put(Pass::Normal, &mut mean(1));
        put(Pass::Depth, &mut guides.iter().map(|g| g[0][3]));
        put(Pass::Instance, &mut guides.iter().map(|g| g[2][0]));
        put(Pass::Species, &mut guides.iter().map(|g| g[2][1]));
    }
    image
}
