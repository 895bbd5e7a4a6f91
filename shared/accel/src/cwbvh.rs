//! The compressed eight-wide BVH of Ylitie, Karras and Laine (2017,
//! "Efficient incoherent ray traversal on GPUs through compressed wide
//! BVHs"), laid out for a GPU's compute units: 80-byte nodes read as five
//! `vec4<u32>`, children's boxes in 8 bits per coordinate on a grid over
//! the node, and a walk whose stack holds *groups* (what is left of one
//! node's children, in order) instead of single children, so a tree of
//! height h needs at most h entries: short enough for workgroup memory on
//! the GPU. A visited node's hit children are sorted by entry distance (a
//! 19-exchange network over 8 keys in registers) and kept as a list of
//! 3-bit slots: the paper orders them by the ray's octant instead, which
//! on Sylva's forest visits 35 % more nodes and tests 57 % more triangles
//! (docs/tracing.md).
//!
//! It is derived from the four-wide [`Bvh`] (the structure workers build,
//! cache and share): each node opens its largest inner children into
//! grandchildren while eight slots and 32 records allow. The walk here is
//! the reference `shaders/trace/cwbvh.wgsl` is tested against, in the same
//! visiting order, so ties resolve alike.

use crate::bvh::{self, Bvh, EMPTY, LEAF};
use crate::coverage::OpacityMaps;
use crate::triangle::TriangleRecord;
use crate::two_level::{PARTS_PER_INSTANCE, SceneHit};
use crate::{Aabb, Accel, Error, Ray, SceneAccel};
use bytemuck::{Pod, Zeroable};
use glam::{Affine3A, Vec3, Vec4};
use rayon::prelude::*;
use sylva_scene::Scene;

/// Children per node.
pub const WIDTH: usize = 8;
/// Most records (triangles, or instance parts at the top level) one node's
/// leaves hold together: a record group's mask has 32 bits.
pub const MAX_NODE_RECORDS: u32 = 32;
/// Most records in one leaf (a meta byte's 3-bit count).
pub const MAX_LEAF: u32 = 7;
/// Bit 31 of a group's `base`: a list of a node's children still to visit.
pub const LIST: u32 = 1 << 31;
/// Bit 30 of a group's `base`: a node to visit.
pub const VISIT: u32 = 1 << 30;
/// Entries (16 bytes) of one node in the GPU's node buffer.
pub const NODE_ENTRIES: u32 = (size_of::<CwbvhNode>() / 16) as u32;
/// Most stack entries the walk may need (both levels together:
/// [`CwbvhScene::stack_need`]); the GPU's workgroup stack has this many
/// entries per lane.
pub const MAX_STACK: usize = 32;

/// One node (80 bytes): a grid over the node, eight children's boxes in
/// grid cells, and where its inner children (contiguous, in slot order
/// from `child_base`) and its leaves' records (from `record_base`) are.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct CwbvhNode {
    /// The grid's lower corner.
    pub origin: [f32; 3],
    /// Bytes 0–2: per axis, the step's biased exponent (as
    /// [`bvh::BvhNode::exponents`]); byte 3: a bit per slot holding an
    /// inner child.
    pub grid: u32,
    /// The first inner child's node.
    pub child_base: u32,
    /// The first record of the node's leaves.
    pub record_base: u32,
    /// A byte per slot (slots 0–3 in word 0): for a leaf, its records'
    /// count (bits 5–7, 1 to [`MAX_LEAF`]) and offset from `record_base`
    /// (bits 0–4); 0 for an inner child or an empty slot.
    pub meta: [u32; 2],
    /// Lower corners in cells: `lo[2a]` holds axis `a` of slots 0–3 (a
    /// byte each), `lo[2a + 1]` of slots 4–7.
    pub lo: [u32; 6],
    /// Upper corners in cells, as `lo`.
    pub hi: [u32; 6],
}

/// What a walk does next, one stack entry (8 bytes): visit a node (`base`
/// = [`VISIT`] | the node), go on through a visited node's hit children
/// (`base` = [`LIST`] | the node; `bits`: their slots nearest first, 3 bits
/// each from bit 0, and how many in bits 24–27), or test records (`base`
/// the first, `bits` a mask from it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Group {
    /// A node with [`VISIT`] or [`LIST`], or a record.
    pub base: u32,
    /// See the type's description.
    pub bits: u32,
}

impl Group {
    /// Nothing to do.
    pub const EMPTY: Group = Group { base: 0, bits: 0 };
    /// A tree's root.
    pub const ROOT: Group = Group { base: VISIT, bits: 0 };

    /// Whether anything is left to do.
    #[inline(always)]
    pub fn has_work(self) -> bool {
        self.base & (LIST | VISIT) != 0 || self.bits != 0
    }
}

/// A child's sort key: its entry distance's bits (a non-negative float's
/// order is its bits' order; the sign of −0 cleared) with its slot in the
/// three lowest, so keys are distinct and a sort is the same everywhere.
#[inline(always)]
pub fn sort_key(near: f32, slot: u32) -> u32 {
    (near.to_bits() & 0x7fff_fff8) | slot
}

impl CwbvhNode {
    /// The grid step on `axis`.
    #[inline(always)]
    pub fn step(&self, axis: usize) -> f32 {
        f32::from_bits(((self.grid >> (8 * axis)) & 0xff) << 23)
    }

    /// A bit per slot holding an inner child.
    #[inline(always)]
    pub fn imask(&self) -> u32 {
        self.grid >> 24
    }

    /// Slot `s`'s meta byte.
    #[inline(always)]
    pub fn meta(&self, s: usize) -> u32 {
        bvh::byte(self.meta[s / 4], s % 4)
    }

    /// Slot `s`'s box (meaningful for a used slot).
    pub fn child_box(&self, s: usize) -> Aabb {
        let corner = |q: &[u32; 6]| {
            Vec3::from_array(std::array::from_fn(|a| {
                self.origin[a] + bvh::byte(q[2 * a + s / 4], s % 4) as f32 * self.step(a)
            }))
        };
        Aabb { min: corner(&self.lo), max: corner(&self.hi) }
    }

    /// Per slot, the sort key of a used child whose box the ray crosses
    /// within `(t_min, t_max)`, `u32::MAX` otherwise: two four-lane tests,
    /// the arithmetic of the GPU's.
    #[inline(always)]
    pub fn keys(&self, ray: &Ray, t_min: f32, t_max: f32) -> [u32; WIDTH] {
        let mut keys = [u32::MAX; WIDTH];
        let used = self.imask() | self.leaf_mask();
        for half in 0..2 {
            let slab = |a: usize| {
                let (o, s) = (Vec4::splat(self.origin[a]), Vec4::splat(self.step(a)));
                let (oa, ia) = (Vec4::splat(ray.origin[a]), Vec4::splat(ray.inv_dir[a]));
                let lo = ((o + bvh::bytes(self.lo[2 * a + half]) * s) - oa) * ia;
                let hi = ((o + bvh::bytes(self.hi[2 * a + half]) * s) - oa) * ia;
                (lo.min(hi), lo.max(hi))
            };
            let (x0, x1) = slab(0);
            let (y0, y1) = slab(1);
            let (z0, z1) = slab(2);
            let near = x0.max(y0).max(z0.max(Vec4::splat(t_min)));
            let far = x1.min(y1).min(z1.min(Vec4::splat(t_max)));
            let hit = near.cmple(far).bitmask();
            for (i, &d) in near.to_array().iter().enumerate() {
                let s = 4 * half + i;
                if hit >> i & 1 != 0 && used >> s & 1 != 0 {
                    keys[s] = sort_key(d, s as u32);
                }
            }
        }
        keys
    }

    /// A bit per slot holding a leaf.
    #[inline(always)]
    pub fn leaf_mask(&self) -> u32 {
        (0..WIDTH).fold(0, |m, s| m | ((self.meta(s) != 0) as u32) << s)
    }

    /// The list of this node's (`index`) hit children, nearest first, as
    /// a group; empty when none is hit.
    #[inline(always)]
    pub fn visit(&self, index: u32, ray: &Ray, t_min: f32, t_max: f32) -> Group {
        let mut keys = self.keys(ray, t_min, t_max);
        keys.sort_unstable();
        let mut list = 0;
        let mut count = 0;
        for k in keys.into_iter().take_while(|&k| k != u32::MAX) {
            list |= (k & 7) << (3 * count);
            count += 1;
        }
        if count == 0 {
            Group::EMPTY
        } else {
            Group { base: LIST | index, bits: list | count << 24 }
        }
    }

    /// What slot `s` holds, as a group: a node to visit, or a leaf's records.
    #[inline(always)]
    pub fn child(&self, s: u32) -> Group {
        let imask = self.imask();
        if imask >> s & 1 != 0 {
            Group {
                base: VISIT | (self.child_base + (imask & ((1 << s) - 1)).count_ones()),
                bits: 0,
            }
        } else {
            let m = self.meta(s as usize);
            Group { base: self.record_base, bits: (((1u64 << (m >> 5)) - 1) << (m & 31)) as u32 }
        }
    }
}

/// An eight-wide compressed BVH over the records of a [`Bvh`].
#[derive(Clone, Debug, Default)]
pub struct Cwbvh {
    /// Nodes; the root is node 0. Empty when there is nothing to hit.
    pub nodes: Vec<CwbvhNode>,
    /// Per record of this tree, the source BVH's primitive slot it is:
    /// node `n`'s leaves hold records `n.record_base ..` of it.
    pub order: Vec<u32>,
    /// Height in nodes: a walk of this tree pushes at most this many stack
    /// entries.
    pub height: usize,
}

/// A child while a node is put together.
#[derive(Clone, Debug)]
enum Kid {
    /// An inner node of the source BVH.
    Inner(u32, Aabb),
    /// Source slots `first..first + count`.
    Leaf(u32, u32, Aabb),
    /// A node made here: what it holds, and its box.
    Made(Vec<Kid>, Aabb),
}

impl Kid {
    fn bounds(&self) -> Aabb {
        match self {
            Kid::Inner(_, b) | Kid::Leaf(_, _, b) | Kid::Made(_, b) => *b,
        }
    }

    /// Records it puts in the node when it is a leaf there.
    fn records(&self) -> u32 {
        match self {
            Kid::Leaf(_, n, _) => *n,
            _ => 0,
        }
    }
}

/// The children of source node `n`; leaves too big for one meta byte are
/// cut into pieces under a node of their own.
fn kids_of(src: &Bvh, n: u32) -> Vec<Kid> {
    let node = &src.nodes[n as usize];
    (0..bvh::WIDTH)
        .filter(|&i| node.child[i] != EMPTY)
        .map(|i| {
            let (c, b) = (node.child[i], node.child_box(i));
            if c & LEAF == 0 {
                return Kid::Inner(c, b);
            }
            let (first, count) = (c & !LEAF, node.leaf_count(i));
            if count <= MAX_LEAF {
                return Kid::Leaf(first, count, b);
            }
            let pieces = (0..count.div_ceil(MAX_LEAF))
                .map(|k| {
                    let at = k * MAX_LEAF;
                    Kid::Leaf(first + at, MAX_LEAF.min(count - at), b)
                })
                .collect();
            Kid::Made(pieces, b)
        })
        .collect()
}

impl Cwbvh {
    /// The eight-wide tree of `src`, its records in [`Cwbvh::order`].
    pub fn from_bvh(src: &Bvh) -> Self {
        let mut w = Cwbvh::default();
        if src.nodes.is_empty() {
            return w;
        }
        let kids = kids_of(src, 0);
        let bounds = kids.iter().fold(Aabb::EMPTY, |b, k| b.union(k.bounds()));
        w.nodes.push(CwbvhNode::zeroed());
        w.height = w.fill(src, 0, bounds, kids);
        w
    }

    /// Fills node `index` (its box `bounds`) with `kids`, opening the
    /// largest inner ones into their children while the node has room,
    /// then its inner children after it; returns its height.
    fn fill(&mut self, src: &Bvh, index: usize, bounds: Aabb, mut kids: Vec<Kid>) -> usize {
        // Open the largest inner child whose children fit.
        loop {
            let records: u32 = kids.iter().map(Kid::records).sum();
            let mut open: Option<(usize, Vec<Kid>)> = None;
            let mut order: Vec<usize> =
                (0..kids.len()).filter(|&i| matches!(kids[i], Kid::Inner(..))).collect();
            order.sort_by(|&i, &j| kids[j].bounds().area().total_cmp(&kids[i].bounds().area()));
            for i in order {
                let Kid::Inner(n, _) = kids[i] else { unreachable!() };
                let grand = kids_of(src, n);
                let more: u32 = grand.iter().map(Kid::records).sum();
                if kids.len() - 1 + grand.len() <= WIDTH && records + more <= MAX_NODE_RECORDS {
                    open = Some((i, grand));
                    break;
                }
            }
            let Some((i, grand)) = open else { break };
            kids.swap_remove(i);
            kids.extend(grand);
        }
        // Leaves while their records fit; the rest (and leaves that do
        // not fit) take the other slots, shared among made nodes when
        // there are more than slots.
        let mut records = 0;
        let (mut placed, mut rest) = (Vec::with_capacity(WIDTH), Vec::new());
        for k in kids {
            match k {
                Kid::Leaf(_, n, _) if records + n <= MAX_NODE_RECORDS => {
                    records += n;
                    placed.push(k);
                }
                k => rest.push(k),
            }
        }
        if placed.len() + rest.len() > WIDTH {
            let groups = rest.len().min(WIDTH / 2);
            rest.extend(placed.drain(WIDTH - groups..));
            let share = rest.len().div_ceil(groups);
            while !rest.is_empty() {
                let chunk: Vec<Kid> = rest.drain(..share.min(rest.len())).collect();
                let b = chunk.iter().fold(Aabb::EMPTY, |b, k| b.union(k.bounds()));
                placed.push(Kid::Made(chunk, b));
            }
        } else {
            placed.extend(rest.into_iter().map(|k| match k {
                Kid::Leaf(_, _, b) => Kid::Made(vec![k], b),
                k => k,
            }));
        }
        let (origin, exponents) = bvh::grid(bounds);
        let mut node = CwbvhNode { origin, grid: exponents, ..CwbvhNode::zeroed() };
        node.record_base = self.order.len() as u32;
        let mut inner = Vec::new();
        let mut imask = 0;
        let mut offset = 0;
        // Slots in the kids' order: the walk sorts by distance, not slot.
        for (s, k) in placed.iter().enumerate() {
            let b = k.bounds();
            for (a, &o) in origin.iter().enumerate() {
                let (lo, hi) = bvh::cells(o, node.step(a), b.min[a], b.max[a]);
                node.lo[2 * a + s / 4] |= lo << (8 * (s % 4));
                node.hi[2 * a + s / 4] |= hi << (8 * (s % 4));
            }
            match k {
                Kid::Leaf(first, count, _) => {
                    debug_assert!(offset + count <= MAX_NODE_RECORDS);
                    node.meta[s / 4] |= (count << 5 | offset) << (8 * (s % 4));
                    self.order.extend(*first..first + count);
                    offset += count;
                }
                _ => {
                    imask |= 1 << s;
                    inner.push(k.clone());
                }
            }
        }
        node.grid |= imask << 24;
        node.child_base = self.nodes.len() as u32;
        self.nodes[index] = node;
        let first = self.nodes.len();
        self.nodes.extend(std::iter::repeat_n(CwbvhNode::zeroed(), inner.len()));
        let mut tallest = 0;
        for (k, kid) in inner.into_iter().enumerate() {
            let (b, kids) = match kid {
                Kid::Inner(n, b) => (b, kids_of(src, n)),
                Kid::Made(kids, b) => (b, kids),
                Kid::Leaf(..) => unreachable!("leaves are placed in the node"),
            };
            tallest = tallest.max(self.fill(src, first + k, b, kids));
        }
        tallest + 1
    }

    /// Up to `max` groups that together hold every record, each with its
    /// box: the root's children, then the largest inner one opened into
    /// its children while the count allows. Each is one child: a node to
    /// visit or a leaf's records.
    pub fn parts(&self, max: usize) -> Vec<(Group, Aabb)> {
        let Some(root) = self.nodes.first() else { return Vec::new() };
        let entries = |n: &CwbvhNode| {
            let used = n.imask() | n.leaf_mask();
            (0..WIDTH as u32)
                .filter(|&s| used >> s & 1 != 0)
                .map(|s| (n.child(s), n.child_box(s as usize)))
                .collect::<Vec<_>>()
        };
        let mut parts = entries(root);
        loop {
            let open = (0..parts.len())
                .filter(|&i| parts[i].0.base & VISIT != 0)
                .max_by(|&i, &j| parts[i].1.area().total_cmp(&parts[j].1.area()));
            let Some(i) = open else { break };
            let kids = entries(&self.nodes[(parts[i].0.base & !VISIT) as usize]);
            if parts.len() - 1 + kids.len() > max {
                break;
            }
            parts.swap_remove(i);
            parts.extend(kids);
        }
        parts
    }

    /// Visits the records a ray reaches before its closest hit, from
    /// `start` ([`Group::ROOT`] for the whole tree), in the GPU's order:
    /// `record(index, closest so far)` returns a closer hit distance when
    /// it finds one, `-∞` to end the walk. Returns the closest distance.
    pub fn walk(
        &self,
        start: Group,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        mut record: impl FnMut(u32, f32) -> Option<f32>,
    ) -> f32 {
        let mut closest = t_max;
        if self.nodes.is_empty() {
            return closest;
        }
        let mut stack = [Group::EMPTY; MAX_STACK];
        let mut sp = 0;
        let mut g = start;
        loop {
            if g.base & LIST != 0 {
                // The list's next child; the rest wait.
                let count = g.bits >> 24;
                if count > 1 {
                    stack[sp] =
                        Group { base: g.base, bits: (g.bits >> 3 & 0x1f_ffff) | (count - 1) << 24 };
                    sp += 1;
                }
                g = self.nodes[(g.base & !LIST) as usize].child(g.bits & 7);
            }
            if g.base & VISIT != 0 {
                let i = g.base & !VISIT;
                g = self.nodes[i as usize].visit(i, ray, t_min, closest);
            } else {
                while g.bits != 0 {
                    let k = g.bits.trailing_zeros();
                    g.bits &= g.bits - 1;
                    if let Some(t) = record(g.base + k, closest) {
                        if t == f32::NEG_INFINITY {
                            return t;
                        }
                        closest = t;
                    }
                }
            }
            if !g.has_work() {
                if sp == 0 {
                    return closest;
                }
                sp -= 1;
                g = stack[sp];
            }
        }
    }
}

/// A piece of an instance at the top level: where in its model's tree a
/// walk starts (one child of a node, by slot).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct CwbvhPart {
    /// Instance index.
    pub instance: u32,
    /// The start group in the instance's model's tree.
    pub start: Group,
    /// Padding (the GPU reads a part as one 16-byte entry).
    pub pad: u32,
}

/// Both levels of a scene as eight-wide trees, derived from its four-wide
/// [`SceneAccel`]: one per model over its triangle records, one over
/// instance parts (pieces of instances: [`crate::two_level::PARTS_PER_INSTANCE`]
/// subtrees each, as the four-wide top level has).
#[derive(Clone, Debug)]
pub struct CwbvhScene {
    /// Over the parts' world boxes; its records are `parts`.
    pub top: Cwbvh,
    /// The top level's records, in its order.
    pub parts: Vec<CwbvhPart>,
    /// One per model; its records are that model's `records`.
    pub models: Vec<Cwbvh>,
    /// Per model, its triangle records in its tree's order.
    pub records: Vec<Vec<TriangleRecord>>,
    /// Per model, the opacity micromaps its records' words index.
    pub opacity: Vec<OpacityMaps>,
    /// World to model space, per instance.
    pub to_model: Vec<Affine3A>,
}

impl CwbvhScene {
    /// The wide trees of a four-wide `accel` (an error for a kd-tree).
    pub fn from_accel(scene: &Scene, accel: &SceneAccel) -> crate::Result<Self> {
        let wide = |a: &Accel| match a {
            Accel::Bvh(b) => Ok(Cwbvh::from_bvh(b)),
            Accel::Kd(_) => {
                Err(Error::Malformed("a compressed wide BVH is made from a BVH".into()))
            }
        };
        let models: Vec<Cwbvh> = accel.models.par_iter().map(wide).collect::<crate::Result<_>>()?;
        let records = models
            .iter()
            .zip(&accel.records)
            .map(|(w, r)| w.order.iter().map(|&slot| r[slot as usize]).collect())
            .collect();
        let model_parts: Vec<Vec<(Group, Aabb)>> =
            models.iter().map(|w| w.parts(PARTS_PER_INSTANCE)).collect();
        let (mut parts, mut world) = (Vec::new(), Vec::new());
        for (i, inst) in scene.instances.iter().enumerate() {
            for &(start, b) in &model_parts[inst.model as usize] {
                parts.push(CwbvhPart { instance: i as u32, start, pad: 0 });
                world.push(b.transformed(&inst.to_world));
            }
        }
        let top_bvh = Bvh::build(&world);
        let top = Cwbvh::from_bvh(&top_bvh);
        let parts =
            top.order.iter().map(|&slot| parts[top_bvh.prims[slot as usize] as usize]).collect();
        let opacity = accel.opacity.clone();
        Ok(Self { top, parts, models, records, opacity, to_model: accel.to_model.clone() })
    }

    /// Stack entries the walk of both levels can need: each tree's height
    /// (a bound on its pushes), one for an instance's entry, and one spare.
    pub fn stack_need(&self) -> usize {
        self.top.height + 2 + self.models.iter().map(|m| m.height).max().unwrap_or(0)
    }

    /// Bytes of all nodes, records, parts and opacity micromaps.
    pub fn bytes(&self) -> usize {
        size_of_val(self.top.nodes.as_slice())
            + size_of_val(self.parts.as_slice())
            + self.models.iter().map(|m| size_of_val(m.nodes.as_slice())).sum::<usize>()
            + self.records.iter().map(|r| size_of_val(r.as_slice())).sum::<usize>()
            + self.opacity.iter().map(|o| size_of_val(o.maps.as_slice())).sum::<usize>()
    }

    /// The closest opaque hit in `(t_min, t_max)`, as the GPU's walk finds it.
    pub fn closest(&self, scene: &Scene, ray: &Ray, t_min: f32, t_max: f32) -> Option<SceneHit> {
        self.trace(scene, ray, t_min, t_max, false)
    }

    /// Whether anything opaque lies along the ray in `(t_min, t_max)`.
    pub fn occluded(&self, scene: &Scene, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        self.trace(scene, ray, t_min, t_max, true).is_some()
    }

    fn trace(
        &self,
        scene: &Scene,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        any: bool,
    ) -> Option<SceneHit> {
        let mut best = None;
        self.top.walk(Group::ROOT, ray, t_min, t_max, |p, limit| {
            let part = self.parts[p as usize];
            let inst = part.instance;
            let m = scene.instances[inst as usize].model as usize;
            let model = &scene.models[m].model;
            let to_model = &self.to_model[inst as usize];
            let local = Ray::new(
                to_model.transform_point3(ray.origin),
                to_model.transform_vector3(ray.dir),
            );
            let records = &self.records[m];
            let mut found = None;
            self.models[m].walk(part.start, &local, t_min, limit, |k, lim| {
                let r = &records[k as usize];
                let (t, u, v) = r.intersect(&local, t_min, lim)?;
                if self.opacity[m].is_hole(model, r.opacity, r.triangle, u, v) {
                    return None;
                }
                found = Some(SceneHit { instance: inst, triangle: r.triangle, t, u, v });
                Some(if any { f32::NEG_INFINITY } else { t })
            });
            let h = found?;
            best = Some(h);
            Some(if any { f32::NEG_INFINITY } else { h.t })
        });
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_scene::rng::SplitMix64;

    fn boxes(n: usize, rng: &mut SplitMix64) -> Vec<Aabb> {
        (0..n)
            .map(|_| {
                let p = Vec3::new(
                    rng.range(-10.0, 10.0),
                    rng.range(-10.0, 10.0),
                    rng.range(-10.0, 10.0),
                );
                let s = Vec3::new(rng.range(0.01, 1.0), rng.range(0.01, 1.0), rng.range(0.01, 1.0));
                Aabb::around(&[p, p + s])
            })
            .collect()
    }

    /// Every record slot appears once, inside every ancestor's box, and
    /// nodes keep their limits.
    #[test]
    fn every_record_is_in_one_leaf_inside_its_ancestors_boxes() {
        let mut rng = SplitMix64::new(5);
        for n in [1, 2, 9, 40, 3000] {
            let b = boxes(n, &mut rng);
            let src = Bvh::build(&b);
            let w = Cwbvh::from_bvh(&src);
            let mut seen = vec![0; src.prims.len()];
            fn visit(
                w: &Cwbvh,
                n: usize,
                inside: &[Aabb],
                src: &Bvh,
                b: &[Aabb],
                seen: &mut [u32],
            ) {
                let node = &w.nodes[n];
                let mut inner = 0;
                let mut records = 0;
                for s in 0..WIDTH {
                    let cb = node.child_box(s);
                    let mut chain = inside.to_vec();
                    chain.push(cb);
                    if node.imask() >> s & 1 != 0 {
                        visit(w, (node.child_base + inner) as usize, &chain, src, b, seen);
                        inner += 1;
                    } else if node.meta(s) != 0 {
                        let m = node.meta(s);
                        records += m >> 5;
                        for r in 0..m >> 5 {
                            let slot = w.order[(node.record_base + (m & 31) + r) as usize];
                            seen[slot as usize] += 1;
                            let pb = b[src.prims[slot as usize] as usize];
                            for a in &chain {
                                assert_eq!(a.union(pb), *a, "a record leaves an ancestor's box");
                            }
                        }
                    }
                }
                assert!(records <= MAX_NODE_RECORDS);
            }
            visit(&w, 0, &[], &src, &b, &mut seen);
            assert!(seen.iter().all(|&s| s == 1), "n = {n}");
            assert!(w.height <= MAX_STACK);
        }
    }

    /// Closest hits of the walk agree with the four-wide BVH's (boxes as
    /// primitives, hit where the ray enters them).
    #[test]
    fn the_walk_finds_the_closest_hit_of_the_four_wide_tree() {
        let mut rng = SplitMix64::new(9);
        let b = boxes(2000, &mut rng);
        let src = Bvh::build(&b);
        let w = Cwbvh::from_bvh(&src);
        let hit = |p: u32, ray: &Ray, lim: f32| b[p as usize].clip(ray, 0.0, lim).map(|(t, _)| t);
        for _ in 0..2000 {
            let o =
                Vec3::new(rng.range(-15.0, 15.0), rng.range(-15.0, 15.0), rng.range(-15.0, 15.0));
            let d = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            let ray = Ray::new(o, d);
            let want =
                src.closest(&ray, 0.0, f32::MAX, &mut |p, lim| hit(p, &ray, lim)).map(|h| h.1);
            let mut got = None;
            w.walk(Group::ROOT, &ray, 0.0, f32::MAX, |r, lim| {
                let t = hit(src.prims[w.order[r as usize] as usize], &ray, lim)?;
                (t < lim && t > 0.0).then(|| {
                    got = Some(t);
                    t
                })
            });
            assert_eq!(got, want, "{ray:?}");
        }
    }

    /// Leaves the four-wide tree could not split (coincident boxes) are
    /// cut to fit; every record is still reached.
    #[test]
    fn oversized_leaves_are_cut_to_fit() {
        let b = vec![Aabb::around(&[Vec3::ZERO, Vec3::ONE]); 300];
        let src = Bvh::build(&b);
        let w = Cwbvh::from_bvh(&src);
        let mut seen = vec![false; src.prims.len()];
        let ray = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z);
        w.walk(Group::ROOT, &ray, 0.0, f32::MAX, |r, _| {
            seen[w.order[r as usize] as usize] = true;
            None
        });
        assert!(
            seen.iter().all(|&s| s),
            "{} of {}",
            seen.iter().filter(|&&s| s).count(),
            seen.len()
        );
        assert!(w.height <= MAX_STACK, "height {}", w.height);
    }

    /// Parts cover every record once.
    #[test]
    fn parts_cover_every_record_once() {
        let mut rng = SplitMix64::new(3);
        let b = boxes(500, &mut rng);
        let w = Cwbvh::from_bvh(&Bvh::build(&b));
        let parts = w.parts(8);
        assert!(parts.len() > 1 && parts.len() <= 8);
        let mut seen = vec![0; w.order.len()];
        for (g, _) in &parts {
            // Counted by structure: every child of every node under it.
            let mut stack = vec![*g];
            while let Some(g) = stack.pop() {
                if g.base & VISIT != 0 {
                    let n = &w.nodes[(g.base & !VISIT) as usize];
                    let used = n.imask() | n.leaf_mask();
                    stack.extend(
                        (0..WIDTH as u32).filter(|&s| used >> s & 1 != 0).map(|s| n.child(s)),
                    );
                } else {
                    let mut m = g.bits;
                    while m != 0 {
                        seen[(g.base + m.trailing_zeros()) as usize] += 1;
                        m &= m - 1;
                    }
                }
            }
        }
        assert!(seen.iter().all(|&s| s == 1));
    }

    /// Both levels walked as the GPU walks them agree with the four-wide
    /// scene's walk: the same instance and triangle on every ray but the
    /// few where two hits tie.
    #[test]
    fn the_scene_walk_agrees_with_the_four_wide_scene() {
        let scene = crate::two_level::test_scene();
        let four = SceneAccel::build(&scene, crate::AccelKind::Bvh);
        let wide = CwbvhScene::from_accel(&scene, &four).unwrap();
        assert!(wide.stack_need() <= MAX_STACK, "{}", wide.stack_need());
        let mut rng = SplitMix64::new(8);
        let (mut hits, mut same, mut blocked) = (0, 0, 0);
        for _ in 0..10_000 {
            let o = Vec3::new(rng.range(-12.0, 12.0), rng.range(0.0, 24.0), -15.0);
            let target =
                Vec3::new(rng.range(-8.0, 8.0), rng.range(0.0, 20.0), rng.range(-3.0, 5.0));
            let ray = Ray::new(o, target - o);
            let (got, want) = (
                wide.closest(&scene, &ray, 1e-4, f32::MAX),
                four.closest(&scene, &ray, 1e-4, f32::MAX),
            );
            assert_eq!(got.is_some(), want.is_some(), "{ray:?}");
            assert_eq!(wide.occluded(&scene, &ray, 1e-4, f32::MAX), want.is_some());
            if let (Some(g), Some(w)) = (got, want) {
                hits += 1;
                assert_eq!(g.t, w.t, "{ray:?}");
                same += ((g.instance, g.triangle) == (w.instance, w.triangle)) as u32;
                let shadow = Ray::new(ray.at(g.t), Vec3::new(0.4, 0.8, 0.3));
                let b = wide.occluded(&scene, &shadow, 1e-3, f32::MAX);
                assert_eq!(b, four.occluded(&scene, &shadow, 1e-3, f32::MAX), "{shadow:?}");
                blocked += b as u32;
            }
        }
        assert!(hits > 400, "{hits} hits");
        assert!(blocked > 50, "{blocked} shadow rays blocked");
        assert!(same * 1000 >= hits * 999, "{same} of {hits} the same triangle");
    }
}
