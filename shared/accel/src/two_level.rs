//! Two levels: a structure over instances' world bounds, and one per model
//! over its triangles. A ray entering an instance is carried into model
//! space unnormalized, so `t` means the same on both levels.

use super::coverage::{Coverage, OpacityMaps, triangle_coverage};
use super::triangle::{TriangleRecord, intersect};
use super::{Aabb, Accel, AccelKind, Error, Ray};
use glam::{Affine3A, Vec2, Vec3};
use rayon::prelude::*;
use sylva_scene::Scene;
use sylva_scene::model::Model;

/// Where a ray hit the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneHit {
    /// Instance index.
    pub instance: u32,
    /// Triangle index within the instance's model.
    pub triangle: u32,
    /// Ray parameter.
    pub t: f32,
    /// Barycentric u.
    pub u: f32,
    /// Barycentric v.
    pub v: f32,
}

/// The acceleration structures of a scene.
#[derive(Clone, Debug)]
pub struct SceneAccel {
    /// Which kind both levels are.
    pub kind: AccelKind,
    /// Over instances' world bounds.
    pub top: Accel,
    /// One per model, over its triangles.
    pub models: Vec<Accel>,
    /// World to model space, per instance.
    pub to_model: Vec<Affine3A>,
    /// Per model, with a BVH: its triangles in the BVH's slot order.
    pub records: Vec<Vec<TriangleRecord>>,
    /// Per model, with a BVH: the opacity micromaps its records' opacity
    /// words index.
    pub opacity: Vec<OpacityMaps>,
    /// With a BVH, what the top level is built over: pieces of instances.
    pub parts: Vec<InstancePart>,
}

/// Most pieces an instance is split into for the top level. Crowns overlap,
/// so a ray entering a whole tree's box meets several; split into
/// subtrees of its model's BVH, the top level orders and culls the pieces
/// of all trees together, nearest first.
pub const PARTS_PER_INSTANCE: usize = 8;

/// A piece of an instance: one subtree of its model's BVH, placed where
/// the instance is.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct InstancePart {
    /// Instance index.
    pub instance: u32,
    /// The subtree's entry in the model's BVH (as [`super::BvhNode::child`]).
    pub entry: u32,
    /// Its leaf count when the entry is a leaf; 0 otherwise.
    pub count: u32,
    /// Padding (the GPU reads a part as one 16-byte entry).
    pub pad: u32,
}

/// What [`SceneAccel::model_closest`] looks for along a ray in model
/// space: the closest opaque hit in `(t_min, t_max)`, or with `any` the
/// first found; without `alpha` every triangle counts as opaque.
#[derive(Clone, Copy, Debug)]
pub struct ModelQuery<'a> {
    /// The ray, in the model's space.
    pub ray: &'a Ray,
    /// Hits at or before this distance are ignored.
    pub t_min: f32,
    /// Hits at or past this distance are ignored.
    pub t_max: f32,
    /// Stop at the first hit found (shadow rays).
    pub any: bool,
    /// Test alpha-masked triangles' textures.
    pub alpha: bool,
}

impl SceneAccel {
    /// Builds both levels (the models' in parallel).
    pub fn build(scene: &Scene, kind: AccelKind) -> Self {
        let (models, coverage) = scene
            .models
            .par_iter()
            .map(|m| {
                let coverage = triangle_coverage(&m.model);
                let triangles: Vec<[Vec3; 3]> =
                    (0..m.model.triangle_count()).map(|t| m.model.triangle(t)).collect();
                (
                    Accel::build_triangles(
                        kind,
                        &triangle_bounds(&triangles, &coverage),
                        &triangles,
                    ),
                    coverage,
                )
            })
            .unzip();
        Self::around(scene, kind, models, coverage)
    }

    /// Both levels around the models' structures built elsewhere (another
    /// worker's, received over the wire, the costly part of [`Self::build`]):
    /// each is checked against its model first; the triangle records, the
    /// instance parts and the top level are derived here as `build` does.
    pub fn from_models(scene: &Scene, kind: AccelKind, models: Vec<Accel>) -> crate::Result<Self> {
        if models.len() != scene.models.len() {
            return Err(Error::ModelCount { given: models.len(), models: scene.models.len() });
        }
        for (i, (a, m)) in models.iter().zip(&scene.models).enumerate() {
            if a.kind() != kind {
                return Err(Error::WrongKind { model: i, got: a.kind(), want: kind });
            }
            a.check(m.model.triangle_count()).map_err(|e| Error::Model {
                model: i,
                name: m.name.clone(),
                error: Box::new(e),
            })?;
        }
        let coverage = scene.models.par_iter().map(|m| triangle_coverage(&m.model)).collect();
        Ok(Self::around(scene, kind, models, coverage))
    }

    /// The rest of both levels around the models' structures, given each
    /// triangle's coverage class.
    fn around(
        scene: &Scene,
        kind: AccelKind,
        models: Vec<Accel>,
        coverage: Vec<Vec<Coverage>>,
    ) -> Self {
        let (records, opacity) = scene
            .models
            .par_iter()
            .zip(&models)
            .zip(&coverage)
            .map(|((m, accel), coverage)| match accel {
                Accel::Bvh(b) => {
                    let maps = OpacityMaps::new(&m.model, coverage);
                    let words = &maps.of_triangle;
                    let r =
                        b.prims.iter().map(|&t| record(&m.model, t, words[t as usize])).collect();
                    (r, maps)
                }
                Accel::Kd(_) => (Vec::new(), OpacityMaps::default()),
            })
            .unzip();
        let to_model = scene.instances.iter().map(|i| i.to_world.inverse()).collect();
        let mut parts = Vec::new();
        let top = match kind {
            AccelKind::Bvh => {
                let model_parts: Vec<Vec<(u32, u32, Aabb)>> = models
                    .iter()
                    .map(|a| match a {
                        Accel::Bvh(b) => b.parts(PARTS_PER_INSTANCE),
                        Accel::Kd(_) => unreachable!("one kind for both levels"),
                    })
                    .collect();
                let mut world = Vec::new();
                for (i, inst) in scene.instances.iter().enumerate() {
                    for &(entry, count, b) in &model_parts[inst.model as usize] {
                        parts.push(InstancePart { instance: i as u32, entry, count, pad: 0 });
                        world.push(b.transformed(&inst.to_world));
                    }
                }
                Accel::build(kind, &world)
            }
            AccelKind::Kd => {
                let models: Vec<Aabb> =
                    scene.models.iter().map(|m| model_bounds(&m.model)).collect();
                let world: Vec<Aabb> = scene
                    .instances
                    .iter()
                    .map(|i| models[i.model as usize].transformed(&i.to_world))
                    .collect();
                Accel::build(kind, &world)
            }
        };
        Self { kind, top, models, to_model, records, opacity, parts }
    }

    /// Bytes of all nodes, primitive lists and triangle records.
    pub fn bytes(&self) -> usize {
        self.top.bytes()
            + self.models.iter().map(Accel::bytes).sum::<usize>()
            + self.records.iter().map(|r| size_of_val(r.as_slice())).sum::<usize>()
            + self.opacity.iter().map(|o| size_of_val(o.maps.as_slice())).sum::<usize>()
            + size_of_val(self.parts.as_slice())
    }

    /// The closest opaque hit in `(t_min, t_max)`: hits on transparent
    /// texels are passed through.
    pub fn closest(&self, scene: &Scene, ray: &Ray, t_min: f32, t_max: f32) -> Option<SceneHit> {
        self.closest_with(scene, ray, t_min, t_max, true)
    }

    /// The closest hit with every triangle taken as opaque (fully cut ones
    /// are not in the structures at all): what renderers without an alpha
    /// test, Embree's baseline in `sylva bench trace`, compute.
    pub fn closest_opaque(
        &self,
        scene: &Scene,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
    ) -> Option<SceneHit> {
        self.closest_with(scene, ray, t_min, t_max, false)
    }

    fn closest_with(
        &self,
        scene: &Scene,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        alpha: bool,
    ) -> Option<SceneHit> {
        let mut best: Option<SceneHit> = None;
        self.top_level(ray, t_min, t_max, &mut |inst, start, limit| {
            let m = scene.instances[inst as usize].model as usize;
            let local = self.local_ray(inst, ray);
            let q = ModelQuery { ray: &local, t_min, t_max: limit, any: false, alpha };
            let (tri, t, u, v) = self.model_closest(m, &scene.models[m].model, start, &q)?;
            best = Some(SceneHit { instance: inst, triangle: tri, t, u, v });
            Some(t)
        });
        best
    }

    /// Whether anything opaque lies along the ray in `(t_min, t_max)`:
    /// the first hit found ends the search (shadow rays).
    pub fn occluded(&self, scene: &Scene, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        let mut found = false;
        self.top_level(ray, t_min, t_max, &mut |inst, start, limit| {
            let m = scene.instances[inst as usize].model as usize;
            let local = self.local_ray(inst, ray);
            let q = ModelQuery { ray: &local, t_min, t_max: limit, any: true, alpha: true };
            found |= self.model_closest(m, &scene.models[m].model, start, &q).is_some();
            // An empty interval: nothing more is in reach.
            found.then_some(f32::NEG_INFINITY)
        });
        found
    }

    /// The ray in instance `inst`'s model space (unnormalized: same `t`).
    fn local_ray(&self, inst: u32, ray: &Ray) -> Ray {
        let to_model = &self.to_model[inst as usize];
        Ray::new(to_model.transform_point3(ray.origin), to_model.transform_vector3(ray.dir))
    }

    /// Walks the top level, nearest first: `enter(instance, model entry,
    /// closest so far)` returns a closer hit distance when it finds one.
    fn top_level(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        enter: &mut dyn FnMut(u32, (u32, u32), f32) -> Option<f32>,
    ) {
        match &self.top {
            Accel::Bvh(b) => {
                b.walk(ray, t_min, t_max, |first, count, limit| {
                    let mut closest = limit;
                    for &p in &b.prims[first as usize..(first + count) as usize] {
                        let part = &self.parts[p as usize];
                        if let Some(t) = enter(part.instance, (part.entry, part.count), closest) {
                            closest = t;
                            if t == f32::NEG_INFINITY {
                                break;
                            }
                        }
                    }
                    (closest < limit).then_some(closest)
                });
            }
            Accel::Kd(k) => {
                let mut done = false;
                k.closest(ray, t_min, t_max, &mut |inst, limit| {
                    if done {
                        return None;
                    }
                    let t = enter(inst, (0, 0), limit)?;
                    // -inf: a shadow ray found its blocker; test nothing more.
                    done = t == f32::NEG_INFINITY;
                    (!done).then_some(t)
                });
            }
        }
    }

    /// The closest opaque hit on model `m` that `query` asks for:
    /// `(triangle, t, u, v)`. A BVH is walked from `start` (an
    /// [`InstancePart`]'s entry; `(0, 0)` is the root).
    pub fn model_closest(
        &self,
        m: usize,
        model: &Model,
        start: (u32, u32),
        query: &ModelQuery,
    ) -> Option<(u32, f32, f32, f32)> {
        let ModelQuery { ray, t_min, t_max, any, alpha } = *query;
        let mut found = None;
        match &self.models[m] {
            Accel::Bvh(bvh) => {
                let (records, opacity) = (&self.records[m], &self.opacity[m]);
                let ahead = |first: u32| super::bvh::prefetch(&records[first as usize]);
                bvh.walk_from(start, ray, t_min, t_max, ahead, |first, count, limit| {
                    let mut closest = limit;
                    for r in &records[first as usize..(first + count) as usize] {
                        let Some((t, u, v)) = r.intersect(ray, t_min, closest) else { continue };
                        if alpha && opacity.is_hole(model, r.opacity, r.triangle, u, v) {
                            continue;
                        }
                        closest = t;
                        found = Some((r.triangle, t, u, v));
                        if any {
                            return Some(f32::NEG_INFINITY);
                        }
                    }
                    (closest < limit).then_some(closest)
                });
            }
            Accel::Kd(kd) => {
                kd.closest(ray, t_min, t_max, &mut |tri, limit| {
                    let [a, b, c] = model.triangle(tri as usize);
                    let (t, u, v) = intersect(ray, a, b, c, t_min, limit)?;
                    if alpha && model.is_transparent(tri as usize, uv_at(model, tri, u, v)) {
                        return None;
                    }
                    found = Some((tri, t, u, v));
                    Some(t)
                });
            }
        }
        found
    }
}

/// Triangle `t`'s record, with its opacity word.
fn record(model: &Model, t: u32, opacity: u32) -> TriangleRecord {
    TriangleRecord::new(t, model.triangle(t as usize), opacity, model.material[t as usize])
}

/// Texture coordinates at barycentrics (u, v) of triangle `tri`.
pub fn uv_at(model: &Model, tri: u32, u: f32, v: f32) -> Vec2 {
    let [i, j, k] = model.triangles[tri as usize];
    model.uvs[i as usize] * (1.0 - u - v) + model.uvs[j as usize] * u + model.uvs[k as usize] * v
}

/// Bounds of each triangle; empty for triangles no ray can hit.
pub fn triangle_bounds(triangles: &[[Vec3; 3]], coverage: &[Coverage]) -> Vec<Aabb> {
    triangles
        .iter()
        .zip(coverage)
        .map(|(t, &c)| if c == Coverage::Cut { Aabb::EMPTY } else { Aabb::around(t) })
        .collect()
}

/// Bounds of a whole model.
pub fn model_bounds(model: &Model) -> Aabb {
    model.bounds().map_or(Aabb { min: Vec3::ZERO, max: Vec3::ZERO }, |(min, max)| Aabb { min, max })
}

/// Three instances of one small birch, moved, turned and sheared: the
/// unit tests' scene.
#[cfg(test)]
pub(crate) fn test_scene() -> Scene {
    let text = r#"{
        "models": { "birch": { "tree": { "species": "paper_birch", "triangles": 6000, "seed": 2 } } },
        "instances": [ { "model": "birch", "position": [0, 0, 0] },
                       { "model": "birch", "position": [6, 0, 1], "rotate_y_deg": 70, "scale": 0.6 },
                       { "model": "birch", "matrix": [0.8,0,0,0, 0,1.3,0,0, 0,0,0.8,0, -5,0,3,1] } ],
        "camera": { "position": [0, 5, -30], "look_at": [0, 5, 0] },
        "sun": { "elevation_deg": 40, "azimuth_deg": 30 }
    }"#;
    let file = sylva_scene::parse(text, "t.json").unwrap();
    Scene::build(file, std::path::Path::new("."), "t.json").unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_scene::rng::SplitMix64;

    /// Every instance's every triangle, in world space, with the alpha test.
    fn brute(scene: &Scene, ray: &Ray) -> Option<SceneHit> {
        let mut best: Option<SceneHit> = None;
        for (i, inst) in scene.instances.iter().enumerate() {
            let m = &scene.models[inst.model as usize].model;
            for t in 0..m.triangle_count() {
                let [a, b, c] = m.triangle(t).map(|p| inst.to_world.transform_point3(p));
                let limit = best.map_or(f32::INFINITY, |h| h.t);
                if let Some((d, u, v)) = intersect(ray, a, b, c, 1e-4, limit)
                    && !m.is_transparent(t, uv_at(m, t as u32, u, v))
                {
                    best = Some(SceneHit { instance: i as u32, triangle: t as u32, t: d, u, v });
                }
            }
        }
        best
    }

    #[test]
    fn instances_are_hit_where_their_transforms_put_them() {
        let s = test_scene();
        let mut rng = SplitMix64::new(8);
        for kind in [AccelKind::Bvh, AccelKind::Kd] {
            let accel = SceneAccel::build(&s, kind);
            // Straight at each trunk's base: the instance there is hit.
            for (i, p) in [[0.0, 0.5, 0.0], [6.0, 0.5, 1.0], [-5.0, 0.5, 3.0]].iter().enumerate() {
                let ray = Ray::new(Vec3::new(p[0], p[1], -20.0), Vec3::Z);
                let hit = accel.closest(&s, &ray, 1e-4, f32::INFINITY).expect("trunk hit");
                assert_eq!(hit.instance, i as u32, "{kind:?}");
            }
            let (mut hits, mut agree, mut close) = (0, 0, 0);
            for _ in 0..1500 {
                let o = Vec3::new(rng.range(-12.0, 12.0), rng.range(0.0, 24.0), -15.0);
                let target =
                    Vec3::new(rng.range(-8.0, 8.0), rng.range(0.0, 20.0), rng.range(-3.0, 5.0));
                let ray = Ray::new(o, target - o);
                let (got, want) = (accel.closest(&s, &ray, 1e-4, f32::INFINITY), brute(&s, &ray));
                assert_eq!(got.is_some(), want.is_some(), "{kind:?} {ray:?}");
                if let (Some(g), Some(w)) = (got, want) {
                    hits += 1;
                    // World-space triangles and model-space rays round
                    // differently; the hit distance must agree closely.
                    assert!((g.t - w.t).abs() <= 1e-4 * w.t.max(1.0), "{kind:?} {g:?} vs {w:?}");
                    agree += ((g.instance, g.triangle) == (w.instance, w.triangle)) as u32;
                    close += 1;
                }
            }
            assert!(hits > 50, "{kind:?}: only {hits} hits");
            assert!(agree as f32 >= 0.97 * close as f32, "{kind:?}: {agree}/{close} same triangle");
        }
    }
}
