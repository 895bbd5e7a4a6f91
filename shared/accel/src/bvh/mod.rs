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

mod build;
mod spatial;

use crate::{Aabb, Error, Ray};
use build::Binary;
use bytemuck::{Pod, Zeroable};
use glam::Vec4;
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
            let (lo, hi) = cells(self.origin[a], self.step(a), b.bounds.min[a], b.bounds.max[a]);
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
        let (origin, exponents) = grid(bounds);
        BvhNode { origin, exponents, ..BvhNode::EMPTY }
    }
}

/// A grid of 255 power-of-two steps per axis over `bounds`: its lower
/// corner, and per axis (byte `a`) the step's biased exponent.
pub(crate) fn grid(bounds: Aabb) -> ([f32; 3], u32) {
    let mut exponents = 0;
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
        exponents |= ((e + 127) as u32) << (8 * a);
    }
    (bounds.min.to_array(), exponents)
}

/// The cells of `[min, max]` on one axis of a grid (`origin`, `step`),
/// rounded outward and checked against f32's own arithmetic, so the
/// quantized box holds the exact one.
pub(crate) fn cells(origin: f32, step: f32, min: f32, max: f32) -> (u32, u32) {
    let cell = |v: f32| (v - origin) / step;
    let mut lo = cell(min).floor().clamp(0.0, 255.0) as u32;
    while lo > 0 && origin + lo as f32 * step > min {
        lo -= 1;
    }
    let mut hi = cell(max).ceil().clamp(0.0, 255.0) as u32;
    while hi < 255 && origin + (hi as f32) * step < max {
        hi += 1;
    }
    (lo, hi)
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
pub(crate) fn byte(w: u32, i: usize) -> u32 {
    (w >> (8 * i)) & 0xff
}

/// The four bytes of `w` as lanes: widened and converted in four SSE2
/// instructions on x86-64 (with scalar conversions the CPU traversal was
/// about 14 % slower).
#[inline(always)]
pub(crate) fn bytes(w: u32) -> Vec4 {
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

impl Bvh {
    /// Checks a tree built elsewhere (another worker's) before any walk:
    /// every inner child lies after its parent (so walks end), every leaf
    /// holds primitives inside `prims`, every primitive index is below
    /// `primitives`, grids are finite, and `stack_depth` is what the tree
    /// needs and within [`MAX_STACK`].
    pub fn check(&self, primitives: usize) -> crate::Result<()> {
        if let Some(p) = self.prims.iter().find(|&&p| p as usize >= primitives) {
            return Err(Error::Malformed(format!("primitive {p} of a model with {primitives}")));
        }
        if self.nodes.is_empty() {
            return if self.stack_depth == 0 {
                Ok(())
            } else {
                Err(Error::Malformed("a stack depth for an empty tree".into()))
            };
        }
        let mut need = vec![0usize; self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate().rev() {
            if !n.origin.iter().all(|v| v.is_finite())
                || (0..3).any(|a| !(1..=254).contains(&((n.exponents >> (8 * a)) & 0xff)))
            {
                return Err(Error::Malformed(format!("node {i}: its grid is not finite")));
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
                        return Err(Error::Malformed(format!(
                            "node {i}: a leaf of {count} primitives from slot {first}, of {}",
                            self.prims.len()
                        )));
                    }
                } else if (c as usize) <= i || c as usize >= self.nodes.len() {
                    return Err(Error::Malformed(format!(
                        "node {i}: child {c} is not a later node of {}",
                        self.nodes.len()
                    )));
                } else {
                    deepest = deepest.max(need[c as usize]);
                }
            }
            need[i] = used.max(1) - 1 + deepest;
        }
        let depth = need[0] + 1;
        if depth != self.stack_depth || depth > MAX_STACK {
            return Err(Error::Malformed(format!(
                "stack depth {} where the tree needs {depth} (at most {MAX_STACK})",
                self.stack_depth
            )));
        }
        Ok(())
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

    /// Whether any primitive is hit in `(t_min, t_max)` (see
    /// [`crate::Accel::any_hit`]): the walk ends at the first one.
    pub fn any_hit(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        hit: &mut dyn FnMut(u32, f32) -> Option<f32>,
    ) -> bool {
        let mut found = false;
        self.walk(ray, t_min, t_max, |first, count, limit| {
            let prims = &self.prims[first as usize..(first + count) as usize];
            found = prims.iter().any(|&p| hit(p, limit).is_some_and(|t| t > t_min && t < limit));
            // No box is entered before −∞: every entry left is passed over.
            found.then_some(f32::NEG_INFINITY)
        });
        found
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

#[cfg(test)]
mod tests {
    use super::build::MAX_LEAF;
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
