//! A kd-tree built with a binned surface area heuristic and traversed with
//! the short-stack algorithm of Horn et al. 2007: a stack of five entries;
//! when it underflows, restart from the root past the last leaf's exit.

use super::{Aabb, Error, Ray};
use bytemuck::{Pod, Zeroable};

/// One node, as the GPU reads it (16 bytes). `axis` 0–2 marks an inner
/// node split at `split` on that axis, its below child at the next index and
/// its above child at `above`; `axis == 3` marks a leaf holding
/// `prims[first .. first + count]`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, serde::Serialize, serde::Deserialize)]
pub struct KdNode {
    /// Split coordinate (inner nodes).
    pub split: f32,
    /// Split axis, or [`KdNode::LEAF`].
    pub axis: u32,
    /// Above child (inner) or first primitive slot (leaf).
    pub first: u32,
    /// Primitives in a leaf.
    pub count: u32,
}

impl KdNode {
    /// `axis` value of a leaf.
    pub const LEAF: u32 = 3;
}

/// A kd-tree over primitive indices.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct KdTree {
    /// Nodes; the root is node 0.
    pub nodes: Vec<KdNode>,
    /// Primitive indices referenced by leaves (a primitive may appear in several).
    pub prims: Vec<u32>,
    /// The bounds of everything.
    pub bounds: Aabb,
}

/// Entries of the short stack.
pub const SHORT_STACK: usize = 5;
const BINS: usize = 32;
const TRAVERSAL_COST: f32 = 1.0;
const INTERSECT_COST: f32 = 1.0;
/// Nodes with this many primitives or fewer become leaves.
const LEAF_PRIMS: usize = 4;
const EMPTY_BONUS: f32 = 0.2;

impl KdTree {
    /// Checks a tree built elsewhere (another worker's) before any walk:
    /// every inner node's children lie after it (so walks end), splits are
    /// finite, leaves hold primitives inside `prims`, and every primitive
    /// index is below `primitives`.
    pub fn check(&self, primitives: usize) -> crate::Result<()> {
        if let Some(p) = self.prims.iter().find(|&&p| p as usize >= primitives) {
            return Err(Error::Malformed(format!("primitive {p} of a model with {primitives}")));
        }
        let finite = |v: glam::Vec3| v.is_finite();
        if self.nodes.is_empty()
            || !(finite(self.bounds.min) && finite(self.bounds.max) || self.bounds.is_empty())
        {
            return Err(Error::Malformed("no root, or bounds that are not finite".into()));
        }
        for (i, n) in self.nodes.iter().enumerate() {
            let ok = match n.axis {
                KdNode::LEAF => n.first as usize + n.count as usize <= self.prims.len(),
                0..=2 => {
                    n.split.is_finite()
                        && i + 1 < self.nodes.len()
                        && (n.first as usize) > i + 1
                        && (n.first as usize) < self.nodes.len()
                }
                _ => false,
            };
            if !ok {
                return Err(Error::Malformed(format!(
                    "node {i} (axis {}, first {}, count {}) does not fit a tree of {} nodes and {} slots",
                    n.axis,
                    n.first,
                    n.count,
                    self.nodes.len(),
                    self.prims.len()
                )));
            }
        }
        Ok(())
    }

    /// Builds a kd-tree over primitives with `bounds`; those with empty
    /// bounds can never be hit and are left out.
    pub fn build(bounds: &[Aabb]) -> Self {
        let root = bounds.iter().fold(Aabb::EMPTY, |b, p| b.union(*p));
        let max_depth = (8.0 + 1.3 * (bounds.len().max(1) as f32).log2()).round() as usize;
        let mut tree = KdTree { nodes: Vec::new(), prims: Vec::new(), bounds: root };
        let all: Vec<u32> =
            (0..bounds.len() as u32).filter(|&p| !bounds[p as usize].is_empty()).collect();
        tree.build_node(bounds, all, root, max_depth, 0);
        tree
    }

    fn build_node(
        &mut self,
        bounds: &[Aabb],
        prims: Vec<u32>,
        node_box: Aabb,
        max_depth: usize,
        bad_refines: u32,
    ) {
        let index = self.nodes.len();
        self.nodes.push(KdNode::zeroed());
        let n = prims.len();
        let leaf_cost = INTERSECT_COST * n as f32;
        let split = if n <= LEAF_PRIMS || max_depth == 0 {
            None
        } else {
            best_plane(&prims, bounds, &node_box)
        };
        let Some((cost, axis, split)) = split else {
            return self.make_leaf(index, &prims);
        };
        // Allow a few splits that do not pay off, as pbrt does, before giving up.
        let bad = bad_refines + (cost > leaf_cost) as u32;
        if (cost > 4.0 * leaf_cost && n < 16) || bad >= 1 {
            return self.make_leaf(index, &prims);
        }
        let (mut below, mut above) = (Vec::new(), Vec::new());
        for &p in &prims {
            let b = bounds[p as usize].intersection(node_box);
            let (lo, hi) = (b.min[axis], b.max[axis]);
            let planar = lo == split && hi == split;
            if lo < split || planar {
                below.push(p);
            }
            if hi > split || planar {
                above.push(p);
            }
        }
        let (mut below_box, mut above_box) = (node_box, node_box);
        below_box.max[axis] = split;
        above_box.min[axis] = split;
        self.build_node(bounds, below, below_box, max_depth - 1, bad);
        let above_index = self.nodes.len() as u32;
        self.nodes[index] = KdNode { split, axis: axis as u32, first: above_index, count: 0 };
        self.build_node(bounds, above, above_box, max_depth - 1, bad);
    }

    fn make_leaf(&mut self, index: usize, prims: &[u32]) {
        self.nodes[index] = KdNode {
            split: 0.0,
            axis: KdNode::LEAF,
            first: self.prims.len() as u32,
            count: prims.len() as u32,
        };
        self.prims.extend_from_slice(prims);
    }

    /// The closest primitive hit in `(t_min, t_max)`; see [`super::Accel::closest`].
    pub fn closest(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        hit: &mut dyn FnMut(u32, f32) -> Option<f32>,
    ) -> Option<(u32, f32)> {
        let (scene_min, scene_max) = self.bounds.clip(ray, t_min, t_max)?;
        let mut best: Option<(u32, f32)> = None;
        let mut closest = t_max;
        // Ring buffer: pushing onto a full stack drops the oldest entry.
        let mut stack = [(0u32, 0.0f32, 0.0f32); SHORT_STACK];
        let (mut top, mut depth) = (0usize, 0usize);
        let (mut node, mut lo, mut hi) = (0u32, scene_min, scene_max);
        loop {
            // Descend to a leaf.
            loop {
                let n = &self.nodes[node as usize];
                if n.axis == KdNode::LEAF {
                    break;
                }
                let a = n.axis as usize;
                let (o, d) = (ray.origin[a], ray.dir[a]);
                let t_split = (n.split - o) * ray.inv_dir[a];
                let below_first = o < n.split || (o == n.split && d <= 0.0);
                let (first, second) =
                    if below_first { (node + 1, n.first) } else { (n.first, node + 1) };
                if t_split > hi || t_split <= 0.0 {
                    node = first;
                } else if t_split < lo {
                    node = second;
                } else {
                    stack[top] = (second, t_split, hi);
                    top = (top + 1) % SHORT_STACK;
                    depth = (depth + 1).min(SHORT_STACK);
                    node = first;
                    hi = t_split;
                }
            }
            let n = &self.nodes[node as usize];
            for &p in &self.prims[n.first as usize..(n.first + n.count) as usize] {
                if let Some(t) = hit(p, closest)
                    && t < closest
                    && t > t_min
                {
                    closest = t;
                    best = Some((p, t));
                }
            }
            if closest <= hi {
                return best;
            }
            if depth == 0 {
                // Short stack empty: restart from the root past this leaf.
                if hi >= scene_max {
                    return best;
                }
                node = 0;
                lo = hi;
                hi = scene_max;
            } else {
                top = (top + SHORT_STACK - 1) % SHORT_STACK;
                depth -= 1;
                (node, lo, hi) = stack[top];
            }
        }
    }
}

/// The cheapest split plane by the binned SAH: (cost, axis, position).
fn best_plane(prims: &[u32], bounds: &[Aabb], node_box: &Aabb) -> Option<(f32, usize, f32)> {
    let extent = node_box.max - node_box.min;
    let area = node_box.area();
    if area <= 0.0 {
        return None;
    }
    let mut best: Option<(f32, usize, f32)> = None;
    for axis in 0..3 {
        let width = extent[axis];
        if width <= 0.0 {
            continue;
        }
        let scale = BINS as f32 / width;
        // starts[i]: primitives whose lower edge falls in bin i; ends likewise.
        let mut starts = [0usize; BINS];
        let mut ends = [0usize; BINS];
        for &p in prims {
            let b = bounds[p as usize].intersection(*node_box);
            let s = (((b.min[axis] - node_box.min[axis]) * scale) as usize).min(BINS - 1);
            let e = (((b.max[axis] - node_box.min[axis]) * scale) as usize).min(BINS - 1);
            starts[s] += 1;
            ends[e] += 1;
        }
        let (o1, o2) = ((axis + 1) % 3, (axis + 2) % 3);
        let cap = 2.0 * extent[o1] * extent[o2];
        let ring = 2.0 * (extent[o1] + extent[o2]);
        let (mut below, mut above) = (0usize, prims.len());
        for i in 1..BINS {
            // Plane between bin i-1 and bin i.
            below += starts[i - 1];
            above -= ends[i - 1];
            let pos = node_box.min[axis] + width * i as f32 / BINS as f32;
            let (wb, wa) = (pos - node_box.min[axis], node_box.max[axis] - pos);
            let (pb, pa) = ((cap + ring * wb) / area, (cap + ring * wa) / area);
            let bonus = if below == 0 || above == 0 { EMPTY_BONUS } else { 0.0 };
            let cost = TRAVERSAL_COST
                + INTERSECT_COST * (1.0 - bonus) * (pb * below as f32 + pa * above as f32);
            if best.is_none_or(|b| cost < b.0) {
                best = Some((cost, axis, pos));
            }
        }
    }
    best
}
