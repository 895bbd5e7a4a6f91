//! A bounding-volume hierarchy built with the binned surface area heuristic
//! and traversed nearest child first with a stack.

use super::{Aabb, Ray};
use bytemuck::{Pod, Zeroable};

/// One node, as the GPU reads it (32 bytes). Inner nodes have `count == 0`
/// and children at `first` and `first + 1`; leaves hold `prims[first ..
/// first + count]`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct BvhNode {
    /// Lower corner of the node's box.
    pub min: [f32; 3],
    /// Left child (inner) or first primitive slot (leaf).
    pub first: u32,
    /// Upper corner.
    pub max: [f32; 3],
    /// Primitives in a leaf; 0 for inner nodes.
    pub count: u32,
}

/// A BVH over primitive indices.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// Nodes; the root is node 0.
    pub nodes: Vec<BvhNode>,
    /// Primitive indices referenced by leaves.
    pub prims: Vec<u32>,
}

/// Bins per axis for the SAH sweep.
const BINS: usize = 16;
/// Most primitives in a leaf.
const MAX_LEAF: usize = 4;
/// Cost of a traversal step against one primitive test.
const TRAVERSAL_COST: f32 = 1.0;
/// Deepest traversal stack the GPU allows.
pub const MAX_DEPTH: usize = 48;

impl Bvh {
    /// Builds a BVH over primitives with `bounds`.
    pub fn build(bounds: &[Aabb]) -> Self {
        let mut bvh = Bvh { nodes: Vec::with_capacity(2 * bounds.len().max(1)), prims: (0..bounds.len() as u32).collect() };
        let centroids: Vec<glam::Vec3> = bounds.iter().map(Aabb::centroid).collect();
        bvh.nodes.push(BvhNode::zeroed());
        // (node, first, count, depth)
        let mut todo = vec![(0usize, 0usize, bounds.len(), 0usize)];
        while let Some((node, first, count, depth)) = todo.pop() {
            let slice = &mut bvh.prims[first..first + count];
            let bb = slice.iter().fold(Aabb::EMPTY, |b, &p| b.union(bounds[p as usize]));
            let split = if count <= 1 || depth + 1 >= MAX_DEPTH { None } else { best_split(slice, bounds, &centroids, &bb, count) };
            bvh.nodes[node].min = bb.min.to_array();
            bvh.nodes[node].max = bb.max.to_array();
            let Some(mid) = split else {
                bvh.nodes[node].first = first as u32;
                bvh.nodes[node].count = count as u32;
                continue;
            };
            let left = bvh.nodes.len();
            bvh.nodes.push(BvhNode::zeroed());
            bvh.nodes.push(BvhNode::zeroed());
            bvh.nodes[node].first = left as u32;
            bvh.nodes[node].count = 0;
            todo.push((left + 1, first + mid, count - mid, depth + 1));
            todo.push((left, first, mid, depth + 1));
        }
        bvh
    }

    /// The closest primitive hit in `(t_min, t_max)`; see [`super::Accel::closest`].
    pub fn closest(&self, ray: &Ray, t_min: f32, t_max: f32, hit: &mut dyn FnMut(u32, f32) -> Option<f32>) -> Option<(u32, f32)> {
        let mut best: Option<(u32, f32)> = None;
        let mut closest = t_max;
        let mut stack = [0u32; MAX_DEPTH];
        let mut sp = 0;
        let mut node = 0u32;
        if self.nodes.is_empty() || node_box(&self.nodes[0]).clip(ray, t_min, closest).is_none() {
            return None;
        }
        loop {
            let n = &self.nodes[node as usize];
            if n.count > 0 {
                for &p in &self.prims[n.first as usize..(n.first + n.count) as usize] {
                    if let Some(t) = hit(p, closest)
                        && t < closest
                        && t > t_min
                    {
                        closest = t;
                        best = Some((p, t));
                    }
                }
            } else {
                let (a, b) = (n.first, n.first + 1);
                let ta = node_box(&self.nodes[a as usize]).clip(ray, t_min, closest).map(|r| r.0);
                let tb = node_box(&self.nodes[b as usize]).clip(ray, t_min, closest).map(|r| r.0);
                match (ta, tb) {
                    (Some(x), Some(y)) => {
                        // Nearest first; the farther waits on the stack.
                        let (near, far) = if x <= y { (a, b) } else { (b, a) };
                        stack[sp] = far;
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = a;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = b;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next node still in reach.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                node = stack[sp];
                if node_box(&self.nodes[node as usize]).clip(ray, t_min, closest).is_some() {
                    break;
                }
            }
        }
    }
}

fn node_box(n: &BvhNode) -> Aabb {
    Aabb { min: n.min.into(), max: n.max.into() }
}

/// Partitions `prims` at the binned-SAH split; returns the count on the
/// left, or `None` when a leaf is cheaper.
fn best_split(prims: &mut [u32], bounds: &[Aabb], centroids: &[glam::Vec3], bb: &Aabb, count: usize) -> Option<usize> {
    let cb = prims.iter().fold(Aabb::EMPTY, |b, &p| b.grow(centroids[p as usize]));
    let extent = cb.max - cb.min;
    let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, bin boundary)
    for axis in 0..3 {
        if extent[axis] <= 0.0 {
            continue;
        }
        let scale = BINS as f32 / extent[axis];
        let bin_of = |p: u32| (((centroids[p as usize][axis] - cb.min[axis]) * scale) as usize).min(BINS - 1);
        let mut counts = [0usize; BINS];
        let mut boxes = [Aabb::EMPTY; BINS];
        for &p in prims.iter() {
            let b = bin_of(p);
            counts[b] += 1;
            boxes[b] = boxes[b].union(bounds[p as usize]);
        }
        // Sweep: area and count left of each boundary, then right.
        let mut left_area = [0.0f32; BINS];
        let mut left_count = [0usize; BINS];
        let (mut acc, mut n) = (Aabb::EMPTY, 0);
        for i in 0..BINS - 1 {
            acc = acc.union(boxes[i]);
            n += counts[i];
            left_area[i] = acc.area();
            left_count[i] = n;
        }
        let (mut acc, mut n) = (Aabb::EMPTY, 0);
        for i in (1..BINS).rev() {
            acc = acc.union(boxes[i]);
            n += counts[i];
            let l = left_count[i - 1];
            if l == 0 || n == 0 {
                continue;
            }
            let cost = left_area[i - 1] * l as f32 + acc.area() * n as f32;
            if best.is_none_or(|b| cost < b.0) {
                best = Some((cost, axis, i));
            }
        }
    }
    let leaf_cost = count as f32;
    let (cost, axis, boundary) = best?;
    let cost = TRAVERSAL_COST + cost / bb.area().max(f32::MIN_POSITIVE);
    if cost >= leaf_cost && count <= MAX_LEAF {
        return None;
    }
    let scale = BINS as f32 / extent[axis];
    let mut mid = 0;
    for i in 0..prims.len() {
        let b = (((centroids[prims[i] as usize][axis] - cb.min[axis]) * scale) as usize).min(BINS - 1);
        if b < boundary {
            prims.swap(i, mid);
            mid += 1;
        }
    }
    (mid > 0 && mid < count).then_some(mid)
}
