//! Acceleration structures for ray casting: a kd-tree traversed with the
//! short-stack algorithm and a bounding-volume hierarchy, both built with
//! the surface area heuristic, over any set of bounded primitives. Two levels
//! use them: one over instances' world bounds, one per model over triangles
//! ([`two_level::SceneAccel`]). Triangles whose texels are all opaque or all
//! holes skip the alpha test ([`coverage`]). Node layouts are `#[repr(C)]` and uploaded to
//! the GPU as they are; these CPU traversals are the reference the GPU
//! tracer is tested against.
//!
//! ```
//! use glam::Vec3;
//! use sylva_accel::{Aabb, Bvh, Ray};
//! let boxes = [Aabb::around(&[Vec3::ZERO, Vec3::ONE]), Aabb::around(&[Vec3::splat(3.0), Vec3::splat(4.0)])];
//! let bvh = Bvh::build(&boxes);
//! let ray = Ray::new(Vec3::new(3.5, 3.5, -1.0), Vec3::Z);
//! // Each box stands for a primitive hit where the ray enters it.
//! let hit = bvh.closest(&ray, 0.0, f32::MAX, &mut |p, t_max| {
//!     boxes[p as usize].clip(&ray, 0.0, t_max).map(|(t_in, _)| t_in)
//! });
//! assert_eq!(hit.map(|(p, _)| p), Some(1));
//! ```

mod aabb;
pub mod bvh;
pub mod coverage;
pub mod cwbvh;
mod error;
pub mod kdtree;
pub mod triangle;
pub mod two_level;

pub use aabb::Aabb;
pub use bvh::{Bvh, BvhNode};
pub use error::{Error, Result};
pub use kdtree::{KdNode, KdTree};
pub use two_level::{SceneAccel, SceneHit};

use glam::Vec3;

pub use sylva_scene::frame::AccelKind;

/// Direction components smaller than this are replaced by it (keeping the
/// sign), so slab and split-plane arithmetic never meets 0 × ∞. The GPU
/// tracer does the same.
pub const MIN_DIRECTION: f32 = 1e-20;

/// A ray with its reciprocal direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Direction (not necessarily unit: instance transforms keep `t`).
    pub dir: Vec3,
    /// 1 / dir, per component.
    pub inv_dir: Vec3,
}

impl Ray {
    /// A ray from `origin` along `dir`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        let safe = |d: f32| if d.abs() < MIN_DIRECTION { MIN_DIRECTION.copysign(d) } else { d };
        let dir = Vec3::new(safe(dir.x), safe(dir.y), safe(dir.z));
        Self { origin, dir, inv_dir: dir.recip() }
    }

    /// The point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// A built structure of either kind.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub enum Accel {
    /// kd-tree.
    Kd(KdTree),
    /// BVH.
    Bvh(Bvh),
}

impl Accel {
    /// Builds a structure of `kind` over primitives with `bounds`.
    pub fn build(kind: AccelKind, bounds: &[Aabb]) -> Self {
        match kind {
            AccelKind::Kd => Accel::Kd(KdTree::build(bounds)),
            AccelKind::Bvh => Accel::Bvh(Bvh::build(bounds)),
        }
    }

    /// Builds a structure of `kind` over a model's triangles, with `bounds`
    /// empty for those no ray can hit; the BVH splits triangles at planes
    /// where their boxes overlap ([`Bvh::build_spatial`]).
    pub fn build_triangles(kind: AccelKind, bounds: &[Aabb], triangles: &[[Vec3; 3]]) -> Self {
        match kind {
            AccelKind::Kd => Accel::Kd(KdTree::build(bounds)),
            AccelKind::Bvh => Accel::Bvh(Bvh::build_spatial(bounds, triangles)),
        }
    }

    /// The closest primitive hit along `ray` in `(t_min, t_max)`:
    /// `hit(prim, t_max)` tests one primitive and returns its distance when
    /// it is hit closer than `t_max`.
    pub fn closest(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        hit: &mut dyn FnMut(u32, f32) -> Option<f32>,
    ) -> Option<(u32, f32)> {
        match self {
            Accel::Kd(k) => k.closest(ray, t_min, t_max, hit),
            Accel::Bvh(b) => b.closest(ray, t_min, t_max, hit),
        }
    }

    /// Whether any primitive is hit along `ray` in `(t_min, t_max)`, as
    /// [`Accel::closest`] would find one, but ending at the first hit
    /// found instead of the closest: occlusion, not shading. `hit` is
    /// called as for [`Accel::closest`].
    pub fn any_hit(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        hit: &mut dyn FnMut(u32, f32) -> Option<f32>,
    ) -> bool {
        match self {
            Accel::Bvh(b) => b.any_hit(ray, t_min, t_max, hit),
            // A kd-tree visits its cells in order along the ray: after the
            // first hit, its own cell ends the walk; primitives met before
            // that are passed over untested.
            Accel::Kd(k) => {
                let mut found = false;
                k.closest(ray, t_min, t_max, &mut |p, limit| {
                    if found {
                        return None;
                    }
                    let t = hit(p, limit).filter(|&t| t > t_min && t < limit)?;
                    found = true;
                    Some(t)
                });
                found
            }
        }
    }

    /// Checks a structure built elsewhere over `primitives` primitives
    /// before any walk ([`Bvh::check`], [`KdTree::check`]).
    pub fn check(&self, primitives: usize) -> crate::Result<()> {
        match self {
            Accel::Kd(k) => k.check(primitives),
            Accel::Bvh(b) => b.check(primitives),
        }
    }

    /// The kind it is.
    pub fn kind(&self) -> AccelKind {
        match self {
            Accel::Kd(_) => AccelKind::Kd,
            Accel::Bvh(_) => AccelKind::Bvh,
        }
    }

    /// Bytes of its nodes and primitive lists.
    pub fn bytes(&self) -> usize {
        match self {
            Accel::Kd(k) => k.nodes.len() * size_of::<KdNode>() + k.prims.len() * 4,
            Accel::Bvh(b) => b.nodes.len() * size_of::<BvhNode>() + b.prims.len() * 4,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::triangle::intersect;
    use super::*;
    use sylva_scene::rng::SplitMix64;

    fn soup(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut rng = SplitMix64::new(seed);
        let mut tris = Vec::new();
        for i in 0..n {
            let c =
                Vec3::new(rng.range(-10.0, 10.0), rng.range(-10.0, 10.0), rng.range(-10.0, 10.0));
            let mut d =
                || Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            let (a, b) = (d(), d());
            let mut t = [c, c + a, c + b];
            if i % 7 == 0 {
                // Axis-aligned, on round coordinates: the planes a kd-tree splits on.
                let y = c.y.round();
                t = [
                    Vec3::new(c.x, y, c.z),
                    Vec3::new(c.x + 1.0, y, c.z),
                    Vec3::new(c.x, y, c.z + 1.0),
                ];
            }
            tris.push(t);
        }
        tris
    }

    /// `tris` and `n` long slivers across them, as branches cross a crown.
    fn with_slivers(mut tris: Vec<[Vec3; 3]>, n: usize, seed: u64) -> Vec<[Vec3; 3]> {
        let mut rng = SplitMix64::new(seed);
        for _ in 0..n {
            let a =
                Vec3::new(rng.range(-10.0, 10.0), rng.range(-10.0, 10.0), rng.range(-10.0, 10.0));
            let b =
                Vec3::new(rng.range(-10.0, 10.0), rng.range(-10.0, 10.0), rng.range(-10.0, 10.0));
            tris.push([a, b, b + Vec3::splat(0.3)]);
        }
        tris
    }

    fn brute(tris: &[[Vec3; 3]], ray: &Ray) -> Option<(u32, f32)> {
        brute_where(tris, ray, |_| true)
    }

    /// The closest hit among the primitives `keep` admits.
    fn brute_where(
        tris: &[[Vec3; 3]],
        ray: &Ray,
        keep: impl Fn(u32) -> bool,
    ) -> Option<(u32, f32)> {
        let mut best = None;
        let mut closest = f32::INFINITY;
        for (i, t) in tris.iter().enumerate().filter(|(i, _)| keep(*i as u32)) {
            if let Some((d, _, _)) = intersect(ray, t[0], t[1], t[2], 0.0, closest) {
                closest = d;
                best = Some((i as u32, d));
            }
        }
        best
    }

    fn rays(n: usize, seed: u64) -> Vec<Ray> {
        let mut rng = SplitMix64::new(seed);
        (0..n)
            .map(|i| {
                let o = Vec3::new(
                    rng.range(-15.0, 15.0),
                    rng.range(-15.0, 15.0),
                    rng.range(-15.0, 15.0),
                );
                let mut d =
                    Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
                // Some rays parallel to an axis plane, some along an axis.
                if i % 5 == 0 {
                    d.y = 0.0;
                }
                if i % 11 == 0 {
                    d = Vec3::X * if i % 2 == 0 { 1.0 } else { -1.0 };
                }
                Ray::new(o, d)
            })
            .collect()
    }

    /// Equal, or a tie: two triangles hit at exactly the same distance.
    fn assert_same_hit(
        got: Option<(u32, f32)>,
        want: Option<(u32, f32)>,
        tris: &[[Vec3; 3]],
        r: &Ray,
        kind: AccelKind,
    ) {
        assert_eq!(got.map(|h| h.1), want.map(|h| h.1), "{kind:?} ray {r:?}");
        if let (Some(g), Some(w)) = (got, want)
            && g.0 != w.0
        {
            let t = &tris[g.0 as usize];
            assert_eq!(
                intersect(r, t[0], t[1], t[2], 0.0, f32::INFINITY).map(|h| h.0),
                Some(w.1),
                "{kind:?} ray {r:?}"
            );
        }
    }

    fn check(kind: AccelKind, tris: &[[Vec3; 3]], rays: &[Ray]) {
        let bounds: Vec<Aabb> = tris.iter().map(|t| Aabb::around(t)).collect();
        check_accel(&Accel::build(kind, &bounds), tris, rays);
        check_accel(&Accel::build_triangles(kind, &bounds, tris), tris, rays);
    }

    fn check_accel(accel: &Accel, tris: &[[Vec3; 3]], rays: &[Ray]) {
        let kind = accel.kind();
        let mut hits = 0;
        for r in rays {
            let want = brute(tris, r);
            let got = accel.closest(r, 0.0, f32::INFINITY, &mut |p, limit| {
                let t = &tris[p as usize];
                intersect(r, t[0], t[1], t[2], 0.0, limit).map(|h| h.0)
            });
            assert_same_hit(got, want, tris, r, kind);
            hits += got.is_some() as usize;
            // Occlusion: any hit at all, and none once every primitive
            // hit is refused by the caller (as a leaf refuses its own card).
            let test = |p: u32, limit: f32| {
                let t = &tris[p as usize];
                intersect(r, t[0], t[1], t[2], 0.0, limit).map(|h| h.0)
            };
            assert_eq!(
                accel.any_hit(r, 0.0, f32::INFINITY, &mut |p, l| test(p, l)),
                want.is_some()
            );
            let odd = brute_where(tris, r, |p| p % 2 == 1).is_some();
            let got = accel.any_hit(r, 0.0, f32::INFINITY, &mut |p, l| {
                if p % 2 == 1 { test(p, l) } else { None }
            });
            assert_eq!(got, odd, "{kind:?} ray {r:?}");
        }
        assert!(hits > rays.len() / 20, "too few hits ({hits}) to mean anything");
    }

    #[test]
    fn both_structures_find_the_closest_hit_brute_force_finds() {
        let tris = soup(3000, 1);
        let rs = rays(20_000, 2);
        check(AccelKind::Bvh, &tris, &rs);
        check(AccelKind::Kd, &tris, &rs);
    }

    #[test]
    fn spatial_splits_cut_long_crossing_triangles_and_find_the_same_hits() {
        // A soup with long slivers across it, as branches cross a crown.
        let tris = with_slivers(soup(2000, 6), 300, 7);
        let bounds: Vec<Aabb> = tris.iter().map(|t| Aabb::around(t)).collect();
        let Accel::Bvh(bvh) = Accel::build_triangles(AccelKind::Bvh, &bounds, &tris) else {
            unreachable!()
        };
        assert!(
            bvh.prims.len() > tris.len(),
            "no triangle was split ({} references)",
            bvh.prims.len()
        );
        bvh.check(tris.len()).unwrap();
        check(AccelKind::Bvh, &tris, &rays(20_000, 8));
    }

    #[test]
    fn a_bvh_is_the_same_tree_on_any_number_of_threads() {
        // Big enough that subtrees are built apart from the levels above
        // them, with slivers that spend the spatial splits' budget.
        let tris = with_slivers(soup(30_000, 11), 3000, 12);
        let bounds: Vec<Aabb> = tris.iter().map(|t| Aabb::around(t)).collect();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            match pool.install(|| Accel::build_triangles(AccelKind::Bvh, &bounds, &tris)) {
                Accel::Bvh(b) => b,
                Accel::Kd(_) => unreachable!(),
            }
        };
        let (one, four) = (on(1), on(4));
        assert!(one.prims.len() > tris.len(), "no triangle was split");
        assert_eq!(
            (one.nodes.as_slice(), one.prims.as_slice()),
            (four.nodes.as_slice(), four.prims.as_slice())
        );
        assert_eq!(one.stack_depth, four.stack_depth);
        one.check(tris.len()).unwrap();
        check_accel(&Accel::Bvh(one), &tris, &rays(5_000, 13));
    }

    #[test]
    fn rays_lying_in_kd_split_planes_are_traversed() {
        let tris = soup(2000, 3);
        let bounds: Vec<Aabb> = tris.iter().map(|t| Aabb::around(t)).collect();
        let Accel::Kd(kd) = Accel::build(AccelKind::Kd, &bounds) else { unreachable!() };
        let mut rng = SplitMix64::new(4);
        let mut rs = Vec::new();
        for n in kd.nodes.iter().filter(|n| n.axis != KdNode::LEAF).take(400) {
            let a = n.axis as usize;
            let mut o =
                Vec3::new(rng.range(-15.0, 15.0), rng.range(-15.0, 15.0), rng.range(-15.0, 15.0));
            o[a] = n.split;
            let mut d = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            d[a] = 0.0;
            rs.push(Ray::new(o, d));
            rs.push(Ray::new(o, -d));
        }
        assert!(rs.len() > 100);
        let expected: Vec<_> = rs.iter().map(|r| brute(&tris, r)).collect();
        for kind in [AccelKind::Kd, AccelKind::Bvh] {
            let accel = Accel::build(kind, &bounds);
            for (r, want) in rs.iter().zip(&expected) {
                let got = accel.closest(r, 0.0, f32::INFINITY, &mut |p, limit| {
                    let t = &tris[p as usize];
                    intersect(r, t[0], t[1], t[2], 0.0, limit).map(|h| h.0)
                });
                assert_same_hit(got, *want, &tris, r, kind);
            }
        }
    }

    #[test]
    fn short_stack_restarts_give_the_same_answers_on_deep_trees() {
        // Many small triangles along a line make deep trees and many restarts.
        let tris: Vec<[Vec3; 3]> = (0..4000)
            .map(|i| {
                let x = i as f32 * 0.01;
                [Vec3::new(x, -0.5, -0.5), Vec3::new(x, 0.5, -0.5), Vec3::new(x, 0.0, 0.5)]
            })
            .collect();
        let mut rng = SplitMix64::new(5);
        let rs: Vec<Ray> = (0..3000)
            .map(|_| {
                Ray::new(
                    Vec3::new(-1.0, rng.range(-0.6, 0.6), rng.range(-0.6, 0.6)),
                    Vec3::new(1.0, rng.range(-0.02, 0.02), rng.range(-0.02, 0.02)),
                )
            })
            .collect();
        check(AccelKind::Kd, &tris, &rs);
    }
}
