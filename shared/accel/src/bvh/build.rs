//! Building the BVH: a binary tree by the binned surface area heuristic
//! (with spatial splits for triangles), collapsed into the wide nodes.

use super::spatial::{self, Ref};
use super::{Bvh, BvhNode, MAX_DEPTH, MAX_LEAF_COUNT, WIDTH};
use crate::Aabb;

/// Bins per axis for the SAH sweep.
const BINS: usize = 16;
/// Most primitives in a leaf.
pub(super) const MAX_LEAF: usize = 4;
/// Cost of a traversal step against one primitive test.
const TRAVERSAL_COST: f32 = 1.0;
/// Spatial splits are weighed only where an object split's children
/// overlap by more than this share of the root's area (Stich et al.'s α).
/// They suggest 1e-5; on the forest's models that made the build 10×
/// slower than without spatial splits for about the same traversal speed
/// as 1e-3, which costs 3.5× (docs/tracing.md, "Spatial splits").
const SPATIAL_OVERLAP: f32 = 1e-3;
/// Extra references spatial splits may make, as a share of the primitives.
const SPATIAL_BUDGET: f32 = 0.3;

/// A node of the binary tree the wide one is collapsed from.
pub(super) struct Binary {
    pub(super) bounds: Aabb,
    /// Left child (right is `first + 1`), or first slot of a leaf.
    pub(super) first: usize,
    /// Primitives of a leaf; 0 for inner nodes.
    pub(super) count: usize,
}

impl Bvh {
    /// Builds a BVH over primitives with `bounds`; those with empty bounds
    /// can never be hit and are left out.
    pub fn build(bounds: &[Aabb]) -> Self {
        Self::build_with(bounds, None)
    }

    /// Builds a BVH over triangles with `bounds` (empty for those no ray
    /// can hit), splitting triangles at planes where that separates
    /// overlapping children (`spatial`): a triangle may then be
    /// referenced by more than one leaf.
    pub fn build_spatial(bounds: &[Aabb], triangles: &[[glam::Vec3; 3]]) -> Self {
        Self::build_with(bounds, Some(triangles))
    }

    fn build_with(bounds: &[Aabb], triangles: Option<&[[glam::Vec3; 3]]>) -> Self {
        let refs: Vec<Ref> = bounds
            .iter()
            .enumerate()
            .filter(|(_, b)| !b.is_empty())
            .map(|(p, &b)| Ref { prim: p as u32, bounds: b })
            .collect();
        if refs.is_empty() {
            return Bvh::default();
        }
        let (binary, prims) = build_binary(refs, triangles);
        let mut bvh =
            Bvh { nodes: Vec::with_capacity(binary.len() / 3 + 1), prims, stack_depth: 0 };
        if binary[0].count > 0 {
            // A single leaf: a root whose one child it is.
            let mut root = BvhNode::over(binary[0].bounds);
            root.set_child(0, &binary[0]);
            bvh.nodes.push(root);
            bvh.stack_depth = 1;
        } else {
            bvh.stack_depth = bvh.collapse(&binary, 0) + 1;
        }
        bvh
    }

    /// Makes the wide node for binary inner node `b`; returns the stack
    /// entries its subtree can need.
    fn collapse(&mut self, binary: &[Binary], b: usize) -> usize {
        let mut kids = vec![binary[b].first, binary[b].first + 1];
        // Open the largest inner child until the node is full.
        while kids.len() < WIDTH {
            let Some(i) =
                (0..kids.len()).filter(|&i| binary[kids[i]].count == 0).max_by(|&i, &j| {
                    binary[kids[i]].bounds.area().total_cmp(&binary[kids[j]].bounds.area())
                })
            else {
                break;
            };
            let k = kids.swap_remove(i);
            kids.extend([binary[k].first, binary[k].first + 1]);
        }
        let index = self.nodes.len();
        let mut node = BvhNode::over(binary[b].bounds);
        for (slot, &k) in kids.iter().enumerate() {
            node.set_child(slot, &binary[k]);
        }
        self.nodes.push(node);
        let mut deepest = 0;
        for (slot, &k) in kids.iter().enumerate() {
            if binary[k].count == 0 {
                self.nodes[index].child[slot] = self.nodes.len() as u32;
                deepest = deepest.max(self.collapse(binary, k));
            }
        }
        kids.len() - 1 + deepest
    }
}

/// A node with at most this many references, below the root, is built as
/// a subtree of its own once the levels above are split, the subtrees in
/// parallel. A count, not a share of the machine: the tree is the same on
/// every machine.
const SUBTREE_REFS: usize = 4096;

/// The binary SAH tree over `refs`, and the primitive slots its leaves
/// index (each leaf's contiguous). With `triangles`, spatial splits are
/// tried where an object split's children would overlap.
///
/// The levels above [`SUBTREE_REFS`] references are split breadth first,
/// so the budget of extra references goes to them first, where a split
/// saves most; what budget is left is shared among the subtrees below in
/// proportion to their references, and they are built in parallel.
fn build_binary(refs: Vec<Ref>, triangles: Option<&[[glam::Vec3; 3]]>) -> (Vec<Binary>, Vec<u32>) {
    use rayon::prelude::*;
    let budget = (refs.len() as f32 * SPATIAL_BUDGET) as usize;
    let root_area = refs.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bounds)).area();
    let top = grow(refs, triangles, budget, root_area, 0, SUBTREE_REFS);
    let waiting: usize = top.deferred.iter().map(|d| d.refs.len()).sum();
    let left = top.budget;
    let homes: Vec<usize> = top.deferred.iter().map(|d| d.node).collect();
    let subtrees: Vec<Part> = top
        .deferred
        .into_par_iter()
        .map(|d| {
            let share = (left as u128 * d.refs.len() as u128 / waiting.max(1) as u128) as usize;
            grow(d.refs, triangles, share, root_area, d.depth, 0)
        })
        .collect();
    let (mut nodes, mut prims) = (top.nodes, top.prims);
    nodes.reserve(subtrees.iter().map(|p| p.nodes.len()).sum());
    for (home, sub) in homes.into_iter().zip(subtrees) {
        // The subtree's root takes its place in the tree above; its other
        // nodes go after the nodes so far, its leaves' slots after theirs.
        let (base, slots) = (nodes.len(), prims.len());
        let place = |i: usize| if i == 0 { home } else { base + i - 1 };
        for (i, mut b) in sub.nodes.into_iter().enumerate() {
            b.first = if b.count > 0 { b.first + slots } else { place(b.first) };
            if i == 0 {
                nodes[home] = b;
            } else {
                nodes.push(b);
            }
        }
        prims.extend(sub.prims);
    }
    (nodes, prims)
}

/// A node left for later: its references and depth.
struct Deferred {
    node: usize,
    refs: Vec<Ref>,
    depth: usize,
}

/// A binary tree built by [`grow`], with the nodes it left for later.
struct Part {
    nodes: Vec<Binary>,
    prims: Vec<u32>,
    deferred: Vec<Deferred>,
    /// Extra references spatial splits may still make.
    budget: usize,
}

/// Splits `refs` breadth first from depth `depth` into a tree whose root
/// is node 0, leaving every node below the root with at most `defer`
/// references unsplit, for later (none when `defer` is 0).
fn grow(
    refs: Vec<Ref>,
    triangles: Option<&[[glam::Vec3; 3]]>,
    mut budget: usize,
    root_area: f32,
    depth: usize,
    defer: usize,
) -> Part {
    let mut prims = Vec::with_capacity(refs.len());
    let mut nodes = Vec::with_capacity(2 * refs.len());
    nodes.push(Binary { bounds: Aabb::EMPTY, first: 0, count: 0 });
    let mut deferred = Vec::new();
    let mut todo = std::collections::VecDeque::from([(0usize, refs, depth)]);
    while let Some((node, refs, depth)) = todo.pop_front() {
        if node > 0 && refs.len() <= defer {
            deferred.push(Deferred { node, refs, depth });
            continue;
        }
        let bb = refs.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bounds));
        nodes[node].bounds = bb;
        let split = if refs.len() <= 1 {
            Err(refs)
        } else if depth + 1 >= MAX_DEPTH {
            // Past the SAH's depth, only what a leaf cannot count is split.
            if refs.len() > MAX_LEAF_COUNT { Ok(halve(refs)) } else { Err(refs) }
        } else {
            best_split(refs, &bb, root_area, triangles, &mut budget)
        };
        match split {
            Err(leaf) => {
                nodes[node].first = prims.len();
                nodes[node].count = leaf.len();
                prims.extend(leaf.iter().map(|r| r.prim));
            }
            Ok((left_refs, right_refs)) => {
                let left = nodes.len();
                nodes.push(Binary { bounds: Aabb::EMPTY, first: 0, count: 0 });
                nodes.push(Binary { bounds: Aabb::EMPTY, first: 0, count: 0 });
                nodes[node].first = left;
                nodes[node].count = 0;
                todo.push_back((left, left_refs, depth + 1));
                todo.push_back((left + 1, right_refs, depth + 1));
            }
        }
    }
    Part { nodes, prims, deferred, budget }
}

/// The references split in list order, half on each side.
fn halve(mut refs: Vec<Ref>) -> (Vec<Ref>, Vec<Ref>) {
    let right = refs.split_off(refs.len() / 2);
    (refs, right)
}

/// The binned-SAH split of a node with box `bb` over `refs`: the two sides,
/// or the references back when a leaf is cheaper. With `triangles`, a
/// spatial split is weighed too where the best object split's children
/// overlap by more than `SPATIAL_OVERLAP` of the root's area, while the
/// build's `budget` of extra references lasts. A node too big for a leaf
/// that no split separates (all centroids in one bin) is halved in list
/// order.
fn best_split(
    mut refs: Vec<Ref>,
    bb: &Aabb,
    root_area: f32,
    triangles: Option<&[[glam::Vec3; 3]]>,
    budget: &mut usize,
) -> Result<(Vec<Ref>, Vec<Ref>), Vec<Ref>> {
    let count = refs.len();
    let object = object_split(&refs);
    let spatial = match (triangles, &object) {
        (Some(triangles), Some(o))
            if *budget > 0 && o.left.intersection(o.right).area() > SPATIAL_OVERLAP * root_area =>
        {
            spatial::find(&refs, triangles, bb).filter(|s| s.cost < o.cost).map(|s| (s, triangles))
        }
        _ => None,
    };
    let Some(cost) = spatial.map(|(s, _)| s.cost).or(object.map(|o| o.cost)) else {
        return if count > MAX_LEAF { Ok(halve(refs)) } else { Err(refs) };
    };
    let cost = TRAVERSAL_COST + cost / bb.area().max(f32::MIN_POSITIVE);
    if cost >= count as f32 && count <= MAX_LEAF {
        return Err(refs);
    }
    if let Some((s, triangles)) = spatial {
        let (left, right) = spatial::partition(refs, triangles, s, budget);
        if !left.is_empty() && !right.is_empty() {
            return Ok((left, right));
        }
        refs = left.into_iter().chain(right).collect();
    }
    let Some(o) = object else {
        return if count > MAX_LEAF { Ok(halve(refs)) } else { Err(refs) };
    };
    let mut mid = 0;
    for i in 0..refs.len() {
        if o.bin_of(&refs[i]) < o.boundary {
            refs.swap(i, mid);
            mid += 1;
        }
    }
    if mid > 0 && mid < count {
        let right = refs.split_off(mid);
        Ok((refs, right))
    } else if count > MAX_LEAF {
        Ok(halve(refs))
    } else {
        Err(refs)
    }
}

/// The best object split: references binned by their boxes' centres.
#[derive(Clone, Copy)]
struct ObjectSplit {
    /// Areas times counts of both sides (not yet divided by the node's area).
    cost: f32,
    axis: usize,
    /// References in bins below this go left.
    boundary: usize,
    /// The centres' lower corner on `axis`, and bins per unit length.
    min: f32,
    scale: f32,
    /// The two sides' boxes.
    left: Aabb,
    right: Aabb,
}

impl ObjectSplit {
    fn bin_of(&self, r: &Ref) -> usize {
        (((r.bounds.centroid()[self.axis] - self.min) * self.scale) as usize).min(BINS - 1)
    }
}

/// The cheapest object split of `refs` by the binned surface area
/// heuristic; `None` when every centre lies in one bin.
fn object_split(refs: &[Ref]) -> Option<ObjectSplit> {
    let cb = refs.iter().fold(Aabb::EMPTY, |b, r| b.grow(r.bounds.centroid()));
    let extent = cb.max - cb.min;
    let mut best: Option<ObjectSplit> = None;
    for axis in 0..3 {
        if extent[axis] <= 0.0 {
            continue;
        }
        let mut split = ObjectSplit {
            cost: 0.0,
            axis,
            boundary: 0,
            min: cb.min[axis],
            scale: BINS as f32 / extent[axis],
            left: Aabb::EMPTY,
            right: Aabb::EMPTY,
        };
        let mut counts = [0usize; BINS];
        let mut boxes = [Aabb::EMPTY; BINS];
        for r in refs {
            let b = split.bin_of(r);
            counts[b] += 1;
            boxes[b] = boxes[b].union(r.bounds);
        }
        if let Some(sweep) = sweep(&boxes, &counts, &counts)
            && best.is_none_or(|b| sweep.cost < b.cost)
        {
            (split.cost, split.boundary, split.left, split.right) =
                (sweep.cost, sweep.boundary, sweep.left, sweep.right);
            best = Some(split);
        }
    }
    best
}

/// The cheapest boundary between bins by the surface area heuristic.
pub(super) struct Sweep {
    /// Areas times counts of both sides (not yet divided by the node's area).
    pub cost: f32,
    /// Bins below it are the left side.
    pub boundary: usize,
    pub left: Aabb,
    pub right: Aabb,
}

/// Sweeps the boundaries between `boxes`' bins: references counted left
/// of a boundary by `entries` (the bins where they start), right of it by
/// `exits` (where they end): the same counts for an object split, which
/// puts each reference in one bin. `None` when every boundary leaves a
/// side empty.
pub(super) fn sweep<const N: usize>(
    boxes: &[Aabb; N],
    entries: &[usize; N],
    exits: &[usize; N],
) -> Option<Sweep> {
    let mut left_box = [Aabb::EMPTY; N];
    let mut left_count = [0usize; N];
    let (mut acc, mut n) = (Aabb::EMPTY, 0);
    for i in 0..N - 1 {
        acc = acc.union(boxes[i]);
        n += entries[i];
        left_box[i] = acc;
        left_count[i] = n;
    }
    let mut best: Option<Sweep> = None;
    let (mut acc, mut n) = (Aabb::EMPTY, 0);
    for i in (1..N).rev() {
        acc = acc.union(boxes[i]);
        n += exits[i];
        let l = left_count[i - 1];
        if l == 0 || n == 0 {
            continue;
        }
        let cost = left_box[i - 1].area() * l as f32 + acc.area() * n as f32;
        if best.as_ref().is_none_or(|b| cost < b.cost) {
            best = Some(Sweep { cost, boundary: i, left: left_box[i - 1], right: acc });
        }
    }
    best
}
