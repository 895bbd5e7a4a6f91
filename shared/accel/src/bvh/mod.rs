//! A four-wide bounding-volume hierarchy: built as a binary tree with the
//! binned surface area heuristic, then collapsed so each node holds up to
//! four children whose boxes sit side by side per axis, the layout one SIMD
//! box test (CPU lanes, or one `vec4` on the GPU) reads at once. Child boxes
//! are stored in 8 bits per coordinate on a grid over the node (the
//! compressed wide BVH of Ylitie et al. 2017), rounded outward, so a node is
//! 64 bytes: one cache line. Traversal
//! visits hit children nearest first and keeps the others on a stack with
//! their entry distance, so a popped entry beyond the closest hit is
//! dropped without touching its node.

mod spatial;

use crate::{Aabb, Ray};
use bytemuck::{Pod, Zeroable};
use glam::Vec4;
use spatial::Ref;
use std::mem::MaybeUninit;

/// Children per node.
pub const WIDTH: usize = 4;
/// Child reference flag: the child is a leaf, the rest is its first
/// primitive slot.
pub const LEAF: u32 = 1 << 31;
/// Child reference of an unused slot.
pub const EMPTY: u32 = u32::MAX;
/// Deepest binary tree the SAH builds; a deeper node still too big for a
/// leaf's 16-bit count is halved, at most 32 more levels.
pub const MAX_DEPTH: usize = 48;
/// Most stack entries a traversal of any tree can need: each level pushes
/// at most `WIDTH − 1`.
pub const MAX_STACK: usize = (WIDTH - 1) * (MAX_DEPTH + 32) + 1;
/// Most primitives in one leaf (its count has 16 bits).
const MAX_LEAF_COUNT: usize = 0xffff;

/// One node, as the GPU reads it (64 bytes, four 16-byte entries): a grid
/// over the node's children, their boxes in grid cells, and what each
/// child is. Coordinate `q` on axis `a` means `origin[a] + q · 2^e[a]`,
/// which f32 computes exactly (q < 256, a power-of-two step).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, serde::Serialize, serde::Deserialize)]
pub struct BvhNode {
    /// The grid's lower corner.
    pub origin: [f32; 3],
    /// Per axis, byte `a`: the step's biased exponent (the f32 exponent
    /// field of `2^e`).
    pub exponents: u32,
    /// An inner node's index, `LEAF | first slot` for a leaf, or [`EMPTY`].
    pub child: [u32; WIDTH],
    /// Lower corners in cells: per axis, child `i` in byte `i`.
    pub lo: [u32; 3],
    /// Upper corners in cells, as `lo`.
    pub hi: [u32; 3],
    /// Primitives in each leaf child, 16 bits each (children 0 and 1 in
    /// the first word); 0 otherwise.
    pub count: [u32; 2],
}

impl BvhNode {
    /// A node with every child slot empty.
    pub const EMPTY: BvhNode = BvhNode {
        origin: [0.0; 3],
        exponents: 0,
        child: [EMPTY; WIDTH],
        lo: [0; 3],
        hi: [0; 3],
        count: [0; 2],
    };

    /// The grid step on `axis`.
    #[inline(always)]
    pub fn step(&self, axis: usize) -> f32 {
        f32::from_bits(((self.exponents >> (8 * axis)) & 0xff) << 23)
    }

    /// A bit per used child slot.
    #[inline(always)]
    fn valid_mask(&self) -> u32 {
        (0..WIDTH).fold(0, |m, i| m | (((self.child[i] != EMPTY) as u32) << i))
    }

    /// Primitives in child `i` (0 unless a leaf).
    #[inline(always)]
    pub fn leaf_count(&self, i: usize) -> u32 {
        (self.count[i / 2] >> (16 * (i % 2))) & 0xffff
    }

    /// Child `i`'s box.
    pub fn child_box(&self, i: usize) -> Aabb {
        let corner = |q: &[u32; 3]| {
            glam::Vec3::from_array(std::array::from_fn(|a| {
                self.origin[a] + byte(q[a], i) as f32 * self.step(a)
            }))
        };
        Aabb { min: corner(&self.lo), max: corner(&self.hi) }
    }

    /// Lower and upper bounds of the four children on `axis`.
    #[inline(always)]
    fn slab(&self, axis: usize) -> (Vec4, Vec4) {
        let (o, s) = (Vec4::splat(self.origin[axis]), Vec4::splat(self.step(axis)));
        (o + bytes(self.lo[axis]) * s, o + bytes(self.hi[axis]) * s)
    }

    /// Puts `b` (a binary node: its box, and its leaf reference if a leaf)
    /// in `slot`; the grid must be set.
    fn set_child(&mut self, slot: usize, b: &Binary) {
        for a in 0..3 {
            let step = self.step(a);
            let cell = |v: f32| (v - self.origin[a]) / step;
            // Rounded outward, then checked against f32's own arithmetic.
            let mut lo = cell(b.bounds.min[a]).floor().clamp(0.0, 255.0) as u32;
            while lo > 0 && self.origin[a] + lo as f32 * step > b.bounds.min[a] {
                lo -= 1;
            }
            let mut hi = cell(b.bounds.max[a]).ceil().clamp(0.0, 255.0) as u32;
            while hi < 255 && self.origin[a] + (hi as f32) * step < b.bounds.max[a] {
                hi += 1;
            }
            self.lo[a] |= lo << (8 * slot);
            self.hi[a] |= hi << (8 * slot);
        }
        self.child[slot] = EMPTY;
        if b.count > 0 {
            self.child[slot] = LEAF | b.first as u32;
            self.count[slot / 2] |= (b.count as u32) << (16 * (slot % 2));
        }
    }

    /// A node whose grid covers `bounds`, children to be set.
    fn over(bounds: Aabb) -> Self {
        let mut n = BvhNode { origin: bounds.min.to_array(), ..BvhNode::EMPTY };
        for a in 0..3 {
            let extent = bounds.max[a] - bounds.min[a];
            // The smallest power-of-two step whose 255 cells reach the top.
            let mut e = if extent > 0.0 { (extent / 255.0).log2().ceil() as i32 } else { -126 };
            e = e.clamp(-126, 127);
            while e < 127
                && bounds.min[a] + 255.0 * f32::from_bits(((e + 127) as u32) << 23) < bounds.max[a]
            {
                e += 1;
            }
            n.exponents |= ((e + 127) as u32) << (8 * a);
        }
        n
    }
}

/// Asks for the cache line at `item` ahead of its use: traversal waits on
/// memory, not arithmetic.
#[inline(always)]
pub fn prefetch<T>(item: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing and cannot fault; SSE is part of x86-64.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
            (item as *const T).cast(),
        );
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = item;
}

/// Byte `i` of `w`.
#[inline(always)]
fn byte(w: u32, i: usize) -> u32 {
    (w >> (8 * i)) & 0xff
}

/// The four bytes of `w` as lanes: widened and converted in four SSE2
/// instructions on x86-64 (with scalar conversions the CPU traversal was
/// about 14 % slower).
#[inline(always)]
fn bytes(w: u32) -> Vec4 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SAFETY: SSE2 is part of x86-64.
        unsafe {
            let zero = _mm_setzero_si128();
            let v = _mm_unpacklo_epi16(_mm_unpacklo_epi8(_mm_cvtsi32_si128(w as i32), zero), zero);
            Vec4::from(_mm_cvtepi32_ps(v))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    Vec4::new(byte(w, 0) as f32, byte(w, 1) as f32, byte(w, 2) as f32, byte(w, 3) as f32)
}

/// A four-wide BVH over primitive indices.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Bvh {
    /// Nodes; the root is node 0. Empty when there is nothing to hit.
    pub nodes: Vec<BvhNode>,
    /// Primitive indices referenced by leaves: each once, or, for a
    /// triangle cut by spatial splits, once per leaf a piece of it is in.
    pub prims: Vec<u32>,
    /// Most stack entries a traversal of this tree can need.
    pub stack_depth: usize,
}

/// Bins per axis for the SAH sweep.
const BINS: usize = 16;
/// Most primitives in a leaf.
const MAX_LEAF: usize = 4;
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
struct Binary {
    bounds: Aabb,
    /// Left child (right is `first + 1`), or first slot of a leaf.
    first: usize,
    /// Primitives of a leaf; 0 for inner nodes.
    count: usize,
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

    /// Checks a tree built elsewhere (another worker's) before any walk:
    /// every inner child lies after its parent (so walks end), every leaf
    /// holds primitives inside `prims`, every primitive index is below
    /// `primitives`, grids are finite, and `stack_depth` is what the tree
    /// needs and within [`MAX_STACK`].
    pub fn check(&self, primitives: usize) -> Result<(), String> {
        if let Some(p) = self.prims.iter().find(|&&p| p as usize >= primitives) {
            return Err(format!("primitive {p} of a model with {primitives}"));
        }
        if self.nodes.is_empty() {
            return if self.stack_depth == 0 {
                Ok(())
            } else {
                Err("a stack depth for an empty tree".into())
            };
        }
        let mut need = vec![0usize; self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate().rev() {
            if !n.origin.iter().all(|v| v.is_finite())
                || (0..3).any(|a| !(1..=254).contains(&((n.exponents >> (8 * a)) & 0xff)))
            {
                return Err(format!("node {i}: its grid is not finite"));
            }
            let (mut used, mut deepest) = (0, 0);
            for slot in 0..WIDTH {
                let c = n.child[slot];
                if c == EMPTY {
                    continue;
                }
                used += 1;
                if c & LEAF != 0 {
                    let (first, count) = ((c & !LEAF) as usize, n.leaf_count(slot) as usize);
                    if count == 0 || first + count > self.prims.len() {
                        return Err(format!(
                            "node {i}: a leaf of {count} primitives from slot {first}, of {}",
                            self.prims.len()
                        ));
                    }
                } else if (c as usize) <= i || c as usize >= self.nodes.len() {
                    return Err(format!(
                        "node {i}: child {c} is not a later node of {}",
                        self.nodes.len()
                    ));
                } else {
                    deepest = deepest.max(need[c as usize]);
                }
            }
            need[i] = used.max(1) - 1 + deepest;
        }
        let depth = need[0] + 1;
        if depth != self.stack_depth || depth > MAX_STACK {
            return Err(format!(
                "stack depth {} where the tree needs {depth} (at most {MAX_STACK})",
                self.stack_depth
            ));
        }
        Ok(())
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

    /// The closest primitive hit in `(t_min, t_max)`; see [`crate::Accel::closest`].
    pub fn closest(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        hit: &mut dyn FnMut(u32, f32) -> Option<f32>,
    ) -> Option<(u32, f32)> {
        let mut best = None;
        self.walk(ray, t_min, t_max, |first, count, limit| {
            let mut closest = limit;
            for &p in &self.prims[first as usize..(first + count) as usize] {
                if let Some(t) = hit(p, closest)
                    && t < closest
                    && t > t_min
                {
                    closest = t;
                    best = Some((p, t));
                }
            }
            (closest < limit).then_some(closest)
        });
        best
    }

    /// Up to `max` entries that together hold every primitive, each with
    /// its box: the root's children, then the largest inner entry opened
    /// into its children while the count allows. `(reference, leaf count,
    /// box)`, the reference as in [`BvhNode::child`].
    pub fn parts(&self, max: usize) -> Vec<(u32, u32, Aabb)> {
        let Some(root) = self.nodes.first() else { return Vec::new() };
        let entries = |n: &BvhNode| {
            (0..WIDTH)
                .filter(|&i| n.child[i] != EMPTY)
                .map(|i| (n.child[i], n.leaf_count(i), n.child_box(i)))
                .collect::<Vec<_>>()
        };
        let mut parts = entries(root);
        loop {
            let open = (0..parts.len())
                .filter(|&i| parts[i].0 & LEAF == 0)
                .max_by(|&i, &j| parts[i].2.area().total_cmp(&parts[j].2.area()));
            let Some(i) = open else { break };
            let kids = entries(&self.nodes[parts[i].0 as usize]);
            if parts.len() - 1 + kids.len() > max {
                break;
            }
            parts.swap_remove(i);
            parts.extend(kids);
        }
        parts
    }

    /// Visits, nearest first, every leaf a ray reaches before its closest
    /// hit: `leaf(first slot, count, closest so far)` returns a closer hit
    /// distance when it finds one. Returns the closest distance.
    #[inline]
    pub fn walk(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        leaf: impl FnMut(u32, u32, f32) -> Option<f32>,
    ) -> f32 {
        self.walk_from((0, 0), ray, t_min, t_max, |_| {}, leaf)
    }

    /// As [`Bvh::walk`], from one entry (`(reference, leaf count)` of a
    /// [`Bvh::parts`] entry) instead of the root; `ahead(first slot)` hears
    /// of each leaf the ray will visit, when its parent is visited, to
    /// fetch what the leaf holds early.
    #[inline]
    pub fn walk_from(
        &self,
        start: (u32, u32),
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        ahead: impl Fn(u32),
        mut leaf: impl FnMut(u32, u32, f32) -> Option<f32>,
    ) -> f32 {
        let mut closest = t_max;
        if self.nodes.is_empty() {
            return closest;
        }
        // (child reference, leaf count, entry distance); entries above `sp`
        // are never read, so the array is not cleared per call.
        let mut stack = [MaybeUninit::<(u32, u32, f32)>::uninit(); MAX_STACK];
        let mut sp = 0;
        let (mut cur, mut count) = start;
        loop {
            if cur & LEAF != 0 {
                if let Some(t) = leaf(cur & !LEAF, count, closest) {
                    closest = t;
                }
            } else {
                let n = &self.nodes[cur as usize];
                let (near, mut mask) = child_entries(n, ray, t_min, closest);
                // Empty slots hold infinite boxes; the mask drops them too.
                mask &= n.valid_mask();
                if mask != 0 {
                    // Hit children, sorted nearest first.
                    let near = near.to_array();
                    let mut order = [(0u32, 0u32, 0.0f32); WIDTH];
                    let mut hits = 0;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        let d = near[i];
                        let mut j = hits;
                        while j > 0 && order[j - 1].2 > d {
                            order[j] = order[j - 1];
                            j -= 1;
                        }
                        order[j] = (n.child[i], n.leaf_count(i), d);
                        hits += 1;
                        if n.child[i] & LEAF == 0 {
                            prefetch(&self.nodes[n.child[i] as usize]);
                        } else {
                            ahead(n.child[i] & !LEAF);
                        }
                    }
                    for k in (1..hits).rev() {
                        stack[sp] = MaybeUninit::new(order[k]);
                        sp += 1;
                    }
                    (cur, count) = (order[0].0, order[0].1);
                    continue;
                }
            }
            // Pop the next entry still in reach.
            loop {
                if sp == 0 {
                    return closest;
                }
                sp -= 1;
                // SAFETY: entries below the old `sp` were written by the push above.
                let (c, k, d) = unsafe { stack[sp].assume_init() };
                if d <= closest {
                    (cur, count) = (c, k);
                    break;
                }
            }
        }
    }
}

/// Entry distances of a node's children along the ray, and a bit per
/// child that is hit: one 4-lane SIMD test (glam's `Vec4` is SSE on x86).
#[inline(always)]
fn child_entries(n: &BvhNode, ray: &Ray, t_min: f32, t_max: f32) -> (Vec4, u32) {
    let (o, inv) = (ray.origin, ray.inv_dir);
    let slab = |axis: usize| {
        let (oa, ia) = (Vec4::splat(o[axis]), Vec4::splat(inv[axis]));
        let (lo, hi) = n.slab(axis);
        let a = (lo - oa) * ia;
        let b = (hi - oa) * ia;
        (a.min(b), a.max(b))
    };
    let (x0, x1) = slab(0);
    let (y0, y1) = slab(1);
    let (z0, z1) = slab(2);
    let near = x0.max(y0).max(z0.max(Vec4::splat(t_min)));
    let far = x1.min(y1).min(z1.min(Vec4::splat(t_max)));
    (near, near.cmple(far).bitmask())
}

/// The binary SAH tree over `refs`, and the primitive slots its leaves
/// index (each leaf's contiguous). With `triangles`, spatial splits are
/// tried where an object split's children would overlap.
fn build_binary(refs: Vec<Ref>, triangles: Option<&[[glam::Vec3; 3]]>) -> (Vec<Binary>, Vec<u32>) {
    let mut budget = (refs.len() as f32 * SPATIAL_BUDGET) as usize;
    let mut prims = Vec::with_capacity(refs.len());
    let mut nodes = Vec::with_capacity(2 * refs.len());
    nodes.push(Binary { bounds: Aabb::EMPTY, first: 0, count: 0 });
    let mut root_area = None;
    // (node, its references, depth), breadth first: the budget of extra
    // references goes to the upper levels, where a split saves most.
    let mut todo = std::collections::VecDeque::from([(0usize, refs, 0usize)]);
    while let Some((node, refs, depth)) = todo.pop_front() {
        let bb = refs.iter().fold(Aabb::EMPTY, |b, r| b.union(r.bounds));
        let root_area = *root_area.get_or_insert(bb.area());
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
    (nodes, prims)
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Boxes along x, some far out and some tiny, so grids of very
    /// different steps are exercised.
    fn boxes(n: usize) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let x = if i % 7 == 0 { 1000.0 + i as f32 * 0.001 } else { i as f32 };
                let size = if i % 3 == 0 { 1e-4 } else { 0.5 };
                Aabb::around(&[Vec3::new(x, -3.0, 0.25), Vec3::new(x + size, 1.0 + size, 1.0)])
            })
            .collect()
    }

    /// The primitives under inner node `node`.
    fn under(bvh: &Bvh, node: u32) -> Vec<u32> {
        let n = &bvh.nodes[node as usize];
        (0..WIDTH)
            .filter(|&i| n.child[i] != EMPTY)
            .flat_map(|i| {
                let c = n.child[i];
                if c & LEAF != 0 {
                    bvh.prims[(c & !LEAF) as usize..][..n.leaf_count(i) as usize].to_vec()
                } else {
                    under(bvh, c)
                }
            })
            .collect()
    }

    /// Every primitive is in exactly one leaf and inside every ancestor's
    /// (quantized) box, and the stack bound holds.
    #[test]
    fn every_primitive_is_in_one_leaf_inside_its_ancestors_boxes() {
        for n in [1, 2, 3, 5, 17, 1000] {
            let b = boxes(n);
            let bvh = Bvh::build(&b);
            let mut seen = vec![0; n];
            for node in &bvh.nodes {
                for i in 0..WIDTH {
                    let c = node.child[i];
                    if c == EMPTY {
                        continue;
                    }
                    let bx = node.child_box(i);
                    if c & LEAF != 0 {
                        for &p in &bvh.prims[(c & !LEAF) as usize..][..node.leaf_count(i) as usize]
                        {
                            seen[p as usize] += 1;
                            assert_eq!(bx.union(b[p as usize]), bx);
                        }
                    } else {
                        for p in under(&bvh, c) {
                            assert_eq!(
                                bx.union(b[p as usize]),
                                bx,
                                "a primitive leaves an ancestor's box"
                            );
                        }
                    }
                }
            }
            assert!(seen.iter().all(|&s| s == 1), "n = {n}: {seen:?}");
            assert!(bvh.stack_depth <= MAX_STACK);
        }
    }

    /// Boxes with the same centre can't be split by SAH; leaves still stay small.
    #[test]
    fn coincident_primitives_still_make_small_leaves() {
        let b = vec![Aabb::around(&[Vec3::ZERO, Vec3::ONE]); 100];
        let bvh = Bvh::build(&b);
        assert!(
            bvh.nodes
                .iter()
                .flat_map(|n| (0..WIDTH).map(|i| n.leaf_count(i)))
                .all(|c| c as usize <= MAX_LEAF)
        );
        let mut empty = b.clone();
        empty[3] = Aabb::EMPTY;
        assert_eq!(Bvh::build(&empty).prims.len(), 99);
        assert!(Bvh::build(&[Aabb::EMPTY]).nodes.is_empty());
    }
}
