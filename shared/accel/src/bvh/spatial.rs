//! Spatial splits for the BVH builder (Stich, Friedrich and Dietrich 2009,
//! "Spatial splits in bounding volume hierarchies"). An object split puts
//! each triangle wholly on one side, so where long triangles (branches,
//! leaf cards across a crown) overlap, both children's boxes cover the
//! overlap and a ray through it walks both. A spatial split cuts the node
//! at a plane instead and clips each triangle that crosses it into a piece
//! per side: the children's boxes no longer overlap, at the price of a
//! triangle referenced by two leaves.

use super::build::sweep;
use crate::Aabb;
use glam::Vec3;

/// A primitive reference: the primitive, and the box of the piece of it
/// this reference stands for (its whole box until a spatial split cuts it).
#[derive(Clone, Copy, Debug)]
pub(super) struct Ref {
    pub prim: u32,
    pub bounds: Aabb,
}

/// Planes per axis a spatial split is chosen among.
const BINS: usize = 16;

/// A spatial split: the plane `pos` on `axis`, and its SAH cost (areas
/// times reference counts, not yet divided by the node's area).
#[derive(Clone, Copy, Debug)]
pub(super) struct SpatialSplit {
    pub cost: f32,
    pub axis: usize,
    pub pos: f32,
}

/// The box of the part of `tri` between `lo` and `hi` on `axis`, inside
/// `within` (the piece a reference already stands for); empty when the
/// triangle does not reach there. Corners computed on an edge are moved
/// outward by a few ulps so rounding never cuts off a sliver of triangle.
pub(super) fn clip(tri: &[Vec3; 3], axis: usize, lo: f32, hi: f32, within: Aabb) -> Aabb {
    let mut b = Aabb::EMPTY;
    for i in 0..3 {
        let (p, q) = (tri[i], tri[(i + 1) % 3]);
        if p[axis] >= lo && p[axis] <= hi {
            b = b.grow(p);
        }
        for plane in [lo, hi] {
            let (a, c) = (p[axis], q[axis]);
            if (a < plane && plane < c) || (c < plane && plane < a) {
                let mut x = p + (q - p) * ((plane - a) / (c - a));
                x[axis] = plane;
                let slack = x.abs() * 4.0 * f32::EPSILON;
                b = b.grow(x - slack).grow(x + slack);
            }
        }
    }
    let mut b = b.intersection(within);
    // The plane itself stays exact: pieces on both sides meet there.
    b.min[axis] = b.min[axis].max(lo);
    b.max[axis] = b.max[axis].min(hi);
    if b.is_empty() { Aabb::EMPTY } else { b }
}

/// The cheapest spatial split of a node with box `bb` over `refs`, by the
/// surface area heuristic over `BINS` planes per axis.
pub(super) fn find(refs: &[Ref], triangles: &[[Vec3; 3]], bb: &Aabb) -> Option<SpatialSplit> {
    let mut best: Option<SpatialSplit> = None;
    for axis in 0..3 {
        let (min, extent) = (bb.min[axis], bb.max[axis] - bb.min[axis]);
        if extent <= 0.0 {
            continue;
        }
        let width = extent / BINS as f32;
        let plane = |i: usize| if i == BINS { bb.max[axis] } else { min + i as f32 * width };
        let bin_of = |x: f32| (((x - min) / width) as usize).min(BINS - 1);
        let mut boxes = [Aabb::EMPTY; BINS];
        let mut entries = [0usize; BINS];
        let mut exits = [0usize; BINS];
        for r in refs {
            let (first, last) = (bin_of(r.bounds.min[axis]), bin_of(r.bounds.max[axis]));
            entries[first] += 1;
            exits[last] += 1;
            if first == last {
                boxes[first] = boxes[first].union(r.bounds);
                continue;
            }
            let tri = &triangles[r.prim as usize];
            for (b, bin) in boxes.iter_mut().enumerate().take(last + 1).skip(first) {
                *bin = bin.union(clip(tri, axis, plane(b), plane(b + 1), r.bounds));
            }
        }
        if let Some(s) = sweep(&boxes, &entries, &exits)
            && best.is_none_or(|b| s.cost < b.cost)
        {
            best = Some(SpatialSplit { cost: s.cost, axis, pos: plane(s.boundary) });
        }
    }
    best
}

/// Splits `refs` at the plane: a reference wholly on one side goes there,
/// one across it is clipped into a piece per side while `budget` (more
/// references the whole build may make) lasts, and afterwards goes whole
/// to the side of its centre.
pub(super) fn partition(
    refs: Vec<Ref>,
    triangles: &[[Vec3; 3]],
    split: SpatialSplit,
    budget: &mut usize,
) -> (Vec<Ref>, Vec<Ref>) {
    let (axis, pos) = (split.axis, split.pos);
    let (mut left, mut right) = (Vec::with_capacity(refs.len()), Vec::with_capacity(refs.len()));
    for r in refs {
        if r.bounds.max[axis] <= pos {
            left.push(r);
        } else if r.bounds.min[axis] >= pos {
            right.push(r);
        } else {
            let tri = &triangles[r.prim as usize];
            let l = clip(tri, axis, f32::NEG_INFINITY, pos, r.bounds);
            let h = clip(tri, axis, pos, f32::INFINITY, r.bounds);
            match (l.is_empty(), h.is_empty()) {
                (true, _) => right.push(Ref { prim: r.prim, bounds: h }),
                (_, true) => left.push(Ref { prim: r.prim, bounds: l }),
                _ if *budget > 0 => {
                    *budget -= 1;
                    left.push(Ref { prim: r.prim, bounds: l });
                    right.push(Ref { prim: r.prim, bounds: h });
                }
                _ if r.bounds.centroid()[axis] < pos => left.push(r),
                _ => right.push(r),
            }
        }
    }
    (left, right)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of `tri` at random barycentrics.
    fn points(tri: &[Vec3; 3], n: usize) -> Vec<Vec3> {
        let mut s = 0x9e37_79b9u32;
        let mut r = move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as f32 / u32::MAX as f32
        };
        (0..n)
            .map(|_| {
                let (mut u, mut v) = (r(), r());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v
            })
            .collect()
    }

    fn contains(b: &Aabb, p: Vec3) -> bool {
        p.cmpge(b.min).all() && p.cmple(b.max).all()
    }

    #[test]
    fn the_pieces_on_both_sides_cover_the_whole_triangle_and_no_more() {
        let tri = [Vec3::new(-1.0, 0.0, 0.3), Vec3::new(3.0, 1.0, -0.2), Vec3::new(0.5, 4.0, 2.0)];
        let whole = Aabb::around(&tri);
        for axis in 0..3 {
            for pos in [-0.5f32, 0.0, 0.7, 1.9] {
                let l = clip(&tri, axis, f32::NEG_INFINITY, pos, whole);
                let h = clip(&tri, axis, pos, f32::INFINITY, whole);
                for p in points(&tri, 2000) {
                    assert!(
                        contains(&l, p) || contains(&h, p),
                        "axis {axis} plane {pos}: {p} in neither piece"
                    );
                }
                assert!(l.max[axis] <= pos && h.min[axis] >= pos);
                // A plane across the triangle leaves each piece smaller than
                // the whole on the cut axis.
                if whole.min[axis] < pos && pos < whole.max[axis] {
                    assert!(l.max[axis] < whole.max[axis] && h.min[axis] > whole.min[axis]);
                }
            }
        }
    }

    #[test]
    fn a_triangle_clear_of_the_slab_clips_to_nothing() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        assert!(clip(&tri, 0, 2.0, 3.0, Aabb::around(&tri)).is_empty());
        assert!(clip(&tri, 2, 0.5, 1.0, Aabb::around(&tri)).is_empty());
    }

    #[test]
    fn a_spatial_split_separates_long_crossing_triangles_within_its_budget() {
        // Thin diagonal slivers crossing one another: every object split
        // overlaps; a plane through the middle does not.
        let triangles: Vec<[Vec3; 3]> = (0..64)
            .map(|i| {
                let y = i as f32 * 0.1;
                [
                    Vec3::new(0.0, y, 0.0),
                    Vec3::new(10.0, 6.4 - y, 0.0),
                    Vec3::new(10.0, 6.4 - y + 0.01, 0.01),
                ]
            })
            .collect();
        let refs: Vec<Ref> = triangles
            .iter()
            .enumerate()
            .map(|(i, t)| Ref { prim: i as u32, bounds: Aabb::around(t) })
            .collect();
        let bb = refs.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bounds));
        let split = find(&refs, &triangles, &bb).expect("a split");
        // With budget to spare, the sides meet at the plane and do not overlap.
        let mut budget = 1000;
        let (l, h) = partition(refs.clone(), &triangles, split, &mut budget);
        let side = |v: &[Ref]| v.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bounds));
        let (lb, hb) = (side(&l), side(&h));
        assert!(lb.max[split.axis] <= split.pos && hb.min[split.axis] >= split.pos);
        assert!(l.iter().chain(&h).all(|r| !r.bounds.is_empty()));
        let duplicated = 1000 - budget;
        assert!(duplicated > 0 && l.len() + h.len() == 64 + duplicated);
        // A spent budget sends the rest whole to one side.
        let mut budget = 10;
        let (l, h) = partition(refs, &triangles, split, &mut budget);
        assert_eq!((budget, l.len() + h.len()), (0, 64 + 10));
    }
}
