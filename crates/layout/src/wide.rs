//! Wide BVHs `bvh4` and `bvh8` (issue 19 item 2): the binary BVH collapsed into 4- or 8-wide nodes,
//! child boxes stored structure-of-arrays, all children's boxes tested at once with SIMD, children
//! visited nearest first.
//!
//! Collapse (layout parameter `collapse`): by default SAH-optimal, the dynamic programme of Ylitie,
//! Karras and Laine 2017 (section 3.1; `crate::wide_collapse`), which over every binary node and
//! slot count picks the cheapest way to share a wide node's slots among binary subtrees and which
//! subtrees become leaves, under a cost of one unit per wide node entered and one per four-triangle
//! leaf test, each weighted by its box's area. `greedy` is the method of Wald, Benthin and Boulos
//! 2008 ("Getting rid of packets", section 3.1; also Dammertz et al. 2008): a wide node starts with
//! the binary node's two children and repeatedly replaces the inner child of largest surface area
//! by its two children until it has `width` children or only leaves. Measured on the four
//! reference scenes (docs/decisions.md), the optimal collapse has 4-10 % lower wide SAH cost and
//! traces 0-8 % faster (bvh8; bvh4 1-11 %). Leaves: a binary subtree with at most [`LEAF_BLOCK`] (4) triangle
//! references may be one leaf (a binary leaf with more stays as it is; greedy makes every such
//! subtree a leaf, the programme only where that is cheaper):
//! four triangles are one SSE watertight test (`TriTest::test_leaf`), so a ray tests the four for
//! about the price of one and skips the binary levels between them, as tinybvh's BVH8_CPU and
//! Embree's triangle4 leaves do. Triangles are stored in the order the leaves are made (the wide
//! layout's own `prim_indices`), so a combined leaf's triangles are consecutive.
//!
//! Node storage: per node `7 * width` 32-bit words, the storage 32-byte aligned: rows min.x, min.y,
//! min.z, max.x, max.y, max.z (f32 bits, one value per child) and a row of child codes (inner: node
//! index; leaf: `LEAF_BIT |` its first triangle pack; empty slot: [`EMPTY`], with the empty box,
//! which the sign-selected slab test always misses). bvh4: 112 bytes per node; bvh8: 224, which on
//! a 32-byte boundary spans exactly four cache lines (unaligned, mostly five: measured 3-8 % slower on
//! the dragon and the bunny), and whose rows are aligned AVX2 loads. Leaf triangles are stored for
//! the traversal in packs of four, structure of arrays (`bvhlab_trace::packs`, as tinybvh's
//! BVH8_CPU and Embree's triangle4): a leaf runs from its first pack to the triangle marked last,
//! so a leaf visit goes straight to its triangles (one memory access fewer than a leaf table, which
//! on the dragon is a cache miss per leaf); the (first slot, count, first pack) table `leaves`
//! serves validation and the counters only.
//!
//! Timed traversal (AVX2): the leaf test is inlined into the walk; the root box is tested in one
//! SSE pass; a pushed child's prefetch address is picked without a branch; a node with two children
//! hit needs one comparison, and three or more are ordered by counting (`counted_order`) instead of
//! an insertion sort. Callgrind on bvh8, breakfast_room (2x10^6 rays): 1,242 M instructions and
//! 14.7 M mispredicted branches (branch simulation) before these and the packs, 991 M and 6.3 M
//! after (tinybvh's BVH8_CPU: 3.3 mispredictions per ray, bvhlab now 3.2); 818 M and 5.9 M with
//! the leaf test's and the ray setup's AVX2 builds, BMI/POPCNT and the register-held pop loop
//! (409 instructions per ray; tinybvh 268).
//! Tried and dropped: one instantiation of the walk per ray octant (constant plane rows, as tinybvh's
//! BVH8_CPU): the same instructions, and the jump to the octant's walk mispredicted 0.8 times per ray.
//!
//! Box test: one SIMD slab test of all children (AVX2 for 8 wide when the CPU has it, detected at
//! run time; SSE for 4 wide, baseline on x86-64; a scalar loop otherwise), conservative like the
//! binary traversal's (`bvhlab_trace::SLAB_ROBUST`). Leaves use the triangle test given as a type:
//! the watertight f32 test for timing (four at a time), the exact f64 test for counters and the
//! oracle. Children pushed on the stack are prefetched (a ray missing below its nearest child pops
//! them next; the dragon's tree does not fit the caches).
use crate::Memory;
use bvhlab_bvh::{Bvh, CostParams, Node, Refs};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};
use bvhlab_trace::fast::{Exact, Planes, SlabRay, TriTest, Watertight};
use bvhlab_trace::packs::packs_for;
use bvhlab_trace::{Hit, PackStore, Ray, RayBox, Stack, TraceStats, Tri4, SLAB_ROBUST};
use serde::{Deserialize, Serialize};
pub use crate::wide_collapse::CollapseCost;
use crate::wide_collapse::Optimal;

/// How [`WideBvh::build_with`] turns binary nodes into wide ones (layout parameter `collapse`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Collapse {
    /// Wald et al. 2008: the largest-area inner child opened first (module doc).
    Greedy,
    /// Ylitie et al. 2017's dynamic programme with these weights (`wide_collapse`).
    Optimal(CollapseCost),
}

impl Default for Collapse {
    /// `sah`: the programme with a wide node entered and a four-triangle leaf test weighted alike
    /// (measured against 1/0.5, 1/2, 1/4 and leaves of up to 8: docs/decisions.md).
    fn default() -> Self {
        Collapse::Optimal(CollapseCost { c_node: 1.0, c_leaf: 1.0, max_leaf: LEAF_BLOCK, block: 4 })
    }
}

impl Collapse {
    /// The layout parameter `collapse` of `spec` (`sah` or `greedy`).
    pub fn from_spec(spec: &crate::LayoutSpec) -> Result<Collapse, String> {
        match spec.get::<String>("collapse")?.as_str() {
            "sah" => Ok(Collapse::default()),
            "greedy" => Ok(Collapse::Greedy),
            o => Err(format!("layout `{}`: collapse must be `sah` or `greedy` (got `{o}`)", spec.name)),
        }
    }
}

/// The `collapse` parameter of bvh4, bvh8 and cwbvh.
pub const COLLAPSE_PARAM: ParamSpec = ParamSpec {
    name: "collapse",
    default: "sah",
    kind: Kind::Choice(&["sah", "greedy"]),
    about: "sah: SAH-optimal collapse of the binary BVH (Ylitie et al. 2017's dynamic programme); greedy: \
            largest-area child opened first (Wald et al. 2008)",
    in_label: false,
};

pub const METHOD4: Method = Method::new(
    "bvh4",
    "4-wide BVH: SAH-optimal collapse of the binary BVH (or greedy), subtrees of up to 4 triangles one leaf tested four at a time, SoA child boxes, SSE box test, nearest child first",
    "Ylitie et al. 2017 (optimal collapse); Wald et al. 2008 (greedy collapse); Dammertz et al. 2008 (QBVH)",
    &[COLLAPSE_PARAM],
)
// 2: a leaf child's code names its first triangle slot, not an index into `leaves`.
// 3: subtrees of at most LEAF_BLOCK references combined into one leaf; own prim_indices order.
// 4: SAH-optimal collapse by default (parameter `collapse`).
// 5: nodes unchanged; the timed traversal's prefetch is straight-line, and where the CPU has AVX2
//    the leaf test (and bvh4's whole SSE traversal) is compiled for AVX2 (same hits, fewer
//    instructions): times re-measured.
// 6: leaf triangles stored in packs of four, structure of arrays (`bvhlab_trace::packs`); a leaf
//    child's code names its first pack; `leaves` gains the first pack.
// 7: nodes and packs unchanged; the timed traversal runs fewer instructions (watertight set-up once
//    per ray, BMI/POPCNT, origin-minus-vertex leaf test: the same hits): times re-measured.
.with_version(7);

pub const METHOD8: Method = Method::new(
    "bvh8",
    "8-wide BVH: SAH-optimal collapse of the binary BVH (or greedy), subtrees of up to 4 triangles one leaf tested four at a time, SoA child boxes, AVX2 box test (scalar fallback), nearest child first",
    "Ylitie et al. 2017 (optimal collapse, 8-wide); Wald et al. 2008 (greedy collapse)",
    &[COLLAPSE_PARAM],
)
// 2, 3, 4, 5, 6, 7: as METHOD4.
.with_version(7);

/// Child code of an unused slot.
pub const EMPTY: u32 = u32::MAX;
/// A binary subtree with at most this many triangle references becomes one leaf of the wide
/// tree: four triangles are one SIMD triangle test (`TriTest::test_leaf`), as tinybvh's BVH8_CPU
/// leaves hold four (its `CombineLeafs(4)`) and Embree's hold triangle4 blocks.
pub const LEAF_BLOCK: u32 = 4;

/// References below each binary node (leaves' counts summed), checking on the way that every index
/// is in range and no node is reached twice.
/// Also returns the nodes in pre-order (parents before children).
pub(crate) fn subtree_refs(nodes: &[Node]) -> Result<(Vec<u32>, Vec<usize>), String> {
    let mut refs = vec![0u32; nodes.len()];
    let mut seen = vec![false; nodes.len()];
    let mut order = Vec::with_capacity(nodes.len());
    let mut todo = vec![0usize];
    seen[0] = true;
    while let Some(i) = todo.pop() {
        order.push(i);
        let n = &nodes[i];
        if n.is_leaf() {
            continue;
        }
        for c in [n.first as usize, n.first as usize + 1] {
            match seen.get_mut(c) {
                None => return Err(format!("malformed BVH: node index {c} out of range")),
                Some(s) if *s => return Err(format!("malformed BVH: node {c} reached twice")),
                Some(s) => *s = true,
            }
            todo.push(c);
        }
    }
    for &i in order.iter().rev() {
        let n = &nodes[i];
        refs[i] = if n.is_leaf() { n.count } else { refs[n.first as usize].saturating_add(refs[n.first as usize + 1]) };
    }
    Ok((refs, order))
}
/// Set in a child code that names a leaf (the rest is its first triangle pack).
pub const LEAF_BIT: u32 = 1 << 31;

/// 32 bytes on a 32-byte boundary: the unit of [`WideBvh`]'s node storage (module doc).
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Row32(pub [u32; 8]);

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WideBvh {
    /// 4 or 8.
    pub width: u32,
    /// `7 * width` words per node (see the module doc; [`WideBvh::words`]), node 0 the root; the
    /// last unit may have unused words.
    pub data: Vec<Row32>,
    /// (first slot, count, first pack) per leaf, sorted by first slot (and so by first pack):
    /// triangles `prim_indices[first..first + count]`, stored for the traversal in packs of four
    /// from `first pack` on ([`PackStore`]). Not read by the timed traversal (a leaf code names
    /// its first pack).
    pub leaves: Vec<[u32; 3]>,
    pub prim_indices: Vec<u32>,
    /// Box of the root (tested once per ray, exactly, before the SIMD traversal).
    pub root_bounds: Aabb,
}

impl WideBvh {
    /// The default (SAH-optimal) collapse of `bvh` (module doc). Errors on a malformed input (index out of range or a
    /// node reached twice), which a validated BVH never is.
    pub fn build(bvh: &Bvh, width: usize) -> Result<WideBvh, String> {
        Self::build_with(bvh, width, Collapse::default())
    }

    /// [`Self::build`] with a choice of collapse.
    pub fn build_with(bvh: &Bvh, width: usize, collapse: Collapse) -> Result<WideBvh, String> {
        assert!(width == 4 || width == 8, "width 4 or 8");
        let mut w = WideBvh {
            width: width as u32,
            data: Vec::new(),
            leaves: Vec::new(),
            prim_indices: Vec::with_capacity(bvh.prim_indices.len()),
            root_bounds: Aabb::EMPTY,
        };
        let nodes = &bvh.nodes;
        let Some(root) = nodes.first() else {
            return Ok(w);
        };
        w.root_bounds = root.bounds;
        let (refs, order) = subtree_refs(nodes)?;
        let optimal = match collapse {
            Collapse::Greedy => None,
            Collapse::Optimal(c) => Some(Optimal::plan(nodes, &order, &refs, width, c)),
        };
        drop(order);
        // Greedy: a binary subtree of at most LEAF_BLOCK references is one leaf (module doc); the
        // programme decides for itself.
        let leafish = |k: u32| match &optimal {
            None => nodes[k as usize].is_leaf() || refs[k as usize] <= LEAF_BLOCK,
            Some(o) => o.is_leaf(k),
        };
        let mut work = vec![(w.alloc(), 0u32)];
        let mut kids: Vec<u32> = Vec::with_capacity(width);
        while let Some((wi, bn)) = work.pop() {
            let n = &nodes[bn as usize];
            kids.clear();
            if leafish(bn) {
                kids.push(bn);
            } else if let Some(o) = &optimal {
                o.children(nodes, bn, &mut kids);
            } else {
                kids.extend([n.first, n.first + 1]);
            }
            while optimal.is_none() && kids.len() < width {
                // The inner child of largest surface area (first one on ties: deterministic).
                let mut pick: Option<(usize, f64)> = None;
                for (i, &k) in kids.iter().enumerate() {
                    if !leafish(k) {
                        let a = nodes[k as usize].bounds.area();
                        if pick.is_none_or(|(_, b)| a > b) {
                            pick = Some((i, a));
                        }
                    }
                }
                let Some((i, _)) = pick else { break };
                let l = nodes[kids[i] as usize].first;
                kids[i] = l;
                kids.insert(i + 1, l + 1);
            }
            for (slot, &k) in kids.iter().enumerate() {
                let kn = &nodes[k as usize];
                w.set_box(wi, slot, &kn.bounds);
                let code = if leafish(k) {
                    let first = w.prim_indices.len() as u32;
                    let pack = w.leaves.last().map_or(0u64, |l| l[2] as u64 + packs_for(l[1]) as u64);
                    if first & LEAF_BIT != 0 || pack >= LEAF_BIT as u64 {
                        return Err(format!("leaf slot {first} (pack {pack}) beyond the 2^31 a wide layout addresses"));
                    }
                    w.push_leaf_refs(bvh, k, !kn.is_leaf())?;
                    w.leaves.push([first, w.prim_indices.len() as u32 - first, pack as u32]);
                    LEAF_BIT | pack as u32
                } else {
                    let ni = w.alloc();
                    work.push((ni, k));
                    ni as u32
                };
                w.set_child(wi, slot, code);
            }
        }
        Ok(w)
    }

    /// Appends the references of binary subtree `k` (left to right) to `prim_indices`; in a
    /// combined leaf each triangle once (an SBVH subtree may hold two fragments of one triangle).
    fn push_leaf_refs(&mut self, bvh: &Bvh, k: u32, combined: bool) -> Result<(), String> {
        let start = self.prim_indices.len();
        let mut todo = vec![k];
        while let Some(i) = todo.pop() {
            let n = &bvh.nodes[i as usize];
            if n.is_leaf() {
                let (first, count) = (n.first as usize, n.count as usize);
                let ids = bvh
                    .prim_indices
                    .get(first..first.saturating_add(count))
                    .ok_or_else(|| format!("malformed BVH: leaf {i} slots {first}+{count} out of range"))?;
                for &p in ids {
                    if !combined || !self.prim_indices[start..].contains(&p) {
                        self.prim_indices.push(p);
                    }
                }
            } else {
                todo.extend([n.first + 1, n.first]);
            }
        }
        Ok(())
    }

    /// Index in `leaves` of the leaf a child code names (None: not a leaf code, or no such leaf).
    pub fn leaf_index(&self, code: u32) -> Option<usize> {
        if code == EMPTY || code & LEAF_BIT == 0 {
            return None;
        }
        self.leaves.binary_search_by_key(&(code & !LEAF_BIT), |l| l[2]).ok()
    }

    /// The triangle store the traversal reads: every leaf's triangles in packs of four.
    pub fn store(&self, tris: &[Triangle]) -> PackStore {
        PackStore::new(&self.prim_indices, tris, &self.leaves)
    }

    /// A copy for the timed path: the node rows in memory advised for huge pages
    /// ([`bvhlab_trace::thp`], as Embree's BVHs are); the same layout otherwise.
    pub fn timed_copy(&self) -> WideBvh {
        WideBvh {
            width: self.width,
            data: bvhlab_trace::thp::copy(&self.data),
            leaves: self.leaves.clone(),
            prim_indices: self.prim_indices.clone(),
            root_bounds: self.root_bounds,
        }
    }

    fn stride(&self) -> usize {
        7 * self.width as usize
    }

    /// The node words, `7 * width` per node (and the unused tail of the last unit).
    pub fn words(&self) -> &[u32] {
        // SAFETY: a `Row32` is 8 u32 with no padding.
        unsafe { std::slice::from_raw_parts(self.data.as_ptr() as *const u32, self.data.len() * 8) }
    }

    /// [`Self::words`], writable.
    pub fn words_mut(&mut self) -> &mut [u32] {
        // SAFETY: as `words`.
        unsafe { std::slice::from_raw_parts_mut(self.data.as_mut_ptr() as *mut u32, self.data.len() * 8) }
    }

    fn alloc(&mut self) -> usize {
        let (wd, idx, s) = (self.width as usize, self.nodes(), self.stride());
        self.data.resize(((idx + 1) * s).div_ceil(8), Row32([0; 8]));
        let words = &mut self.words_mut()[idx * s..(idx + 1) * s];
        for (row, r) in words.chunks_mut(wd).enumerate() {
            r.fill(match row {
                0..=2 => f32::INFINITY.to_bits(),
                3..=5 => f32::NEG_INFINITY.to_bits(),
                _ => EMPTY,
            });
        }
        idx
    }

    pub(crate) fn set_box(&mut self, node: usize, slot: usize, b: &Aabb) {
        let (s, wd) = (self.stride(), self.width as usize);
        let c = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
        let words = self.words_mut();
        for (row, v) in c.iter().enumerate() {
            words[node * s + row * wd + slot] = v.to_bits();
        }
    }

    pub(crate) fn set_child(&mut self, node: usize, slot: usize, code: u32) {
        let (s, wd) = (self.stride(), self.width as usize);
        self.words_mut()[node * s + 6 * wd + slot] = code;
    }

    /// Number of wide nodes.
    pub fn nodes(&self) -> usize {
        self.data.len() * 8 / self.stride()
    }

    /// Child `slot` of `node`: (code, box).
    pub fn child(&self, node: usize, slot: usize) -> (u32, Aabb) {
        let (s, wd) = (self.stride(), self.width as usize);
        let words = self.words();
        let f = |row: usize| f32::from_bits(words[node * s + row * wd + slot]);
        let b = Aabb {
            min: Vec3::new(f(0), f(1), f(2)),
            max: Vec3::new(f(3), f(4), f(5)),
        };
        (words[node * s + 6 * wd + slot], b)
    }

    /// An empty wide BVH of `width` (nodes are added by [`Self::build`] and by cwbvh's decoding).
    pub(crate) fn empty(width: u32, prim_indices: Vec<u32>, root_bounds: Aabb) -> WideBvh {
        WideBvh { width, data: Vec::new(), leaves: Vec::new(), prim_indices, root_bounds }
    }

    /// Appends a node with no children (every slot empty); returns its index.
    pub(crate) fn push_node(&mut self) -> usize {
        self.alloc()
    }

    pub fn memory(&self) -> Memory {
        // No leaf table: a leaf's count is a mark on its last triangle reference (module doc).
        let topology = (self.nodes() * self.stride() * 4) as u64;
        Memory {
            topology_bytes: topology,
            total_bytes: topology + self.prim_indices.len() as u64 * 4,
            nodes: (self.nodes() + self.leaves.len()) as u64,
            chunks: 0,
            chunk_fill: 0.0,
            prim_refs: self.prim_indices.len() as u64,
        }
    }

    /// Thesis eq. 4 over the wide tree: c_T per wide node entered (its box is the union of its
    /// children's), c_I per triangle test, each weighted by its box's area over the root's. A wide
    /// node stands for several binary nodes, so this is below the binary tree's cost; it is the
    /// same model with one node visit per wide node (the SIMD test of all children).
    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        if self.nodes() == 0 {
            return 0.0;
        }
        let root_sa = self.root_bounds.area();
        let degenerate = !(root_sa > 0.0);
        let ratio = |sa: f64| if degenerate { 1.0 } else { sa / root_sa };
        let (inner, leaf) = self.area_sums(ratio, |count| count as f64);
        cost.c_t as f64 * inner + cost.c_i as f64 * leaf
    }

    /// The collapse programme's objective on this tree (`wide_collapse`): `c_node` times each
    /// node's area (the union of its children's boxes; the root's box for the root) plus `c_leaf`
    /// times each leaf's area per started `block` triangles; areas relative to the root's (as the
    /// programme's, `wide_collapse::area_norm`).
    pub fn collapse_cost(&self, w: CollapseCost) -> f64 {
        let ra = self.root_bounds.area();
        let norm = if ra > 0.0 && ra.is_finite() { 1.0 / ra } else { 1.0 };
        let (inner, leaf) = self.area_sums(|a| a * norm, |count| count.div_ceil(w.block).max(1) as f64);
        w.c_node as f64 * inner + w.c_leaf as f64 * leaf
    }

    /// Sums over the tree of `ratio(area)` of every node (the union of its children's boxes; the
    /// root's box for the root) and of `ratio(area) * per_leaf(count)` of every leaf.
    fn area_sums(&self, ratio: impl Fn(f64) -> f64, per_leaf: impl Fn(u32) -> f64) -> (f64, f64) {
        let (mut inner, mut leaf) = (0.0f64, 0.0f64);
        for n in 0..self.nodes() {
            let mut u = Aabb::EMPTY;
            for s in 0..self.width as usize {
                let (code, b) = self.child(n, s);
                if code == EMPTY {
                    continue;
                }
                u = u.union(&b);
                if let Some(l) = self.leaf_index(code) {
                    leaf += ratio(b.area()) * per_leaf(self.leaves[l][1]);
                }
            }
            inner += ratio(if n == 0 { self.root_bounds.area() } else { u.area() });
        }
        (inner, leaf)
    }

    /// Every triangle referenced exactly once; each node and leaf reached once from the root;
    /// child boxes inside the box their parent slot (or the root box) gives; leaf boxes around
    /// their triangles; empty slots carry the empty box.
    pub fn validate(&self, tris: &[Triangle]) -> Result<(), String> {
        self.validate_refs(tris, Refs::Unique)
    }

    /// [`Self::validate`] for a BVH built with `refs`: with `Refs::Split` (SBVH) a triangle may be
    /// referenced from several leaves, each of whose boxes holds a clipped part of it (so it
    /// overlaps the triangle's box rather than containing it), as `bvhlab_bvh::validate_split`.
    pub fn validate_refs(&self, tris: &[Triangle], refs_kind: Refs) -> Result<(), String> {
        self.check(tris, refs_kind, true)
    }

    /// [`Self::validate_refs`] without nesting (child boxes inside their parent slot's box):
    /// instead every slot's box must hold (`Refs::Unique`) or meet (`Refs::Split`) everything its
    /// subtree's leaves hold. For quantized boxes laid on each node's exact box ([`crate::cwbvh`]).
    pub fn validate_unnested(&self, tris: &[Triangle], refs_kind: Refs) -> Result<(), String> {
        self.check(tris, refs_kind, false)
    }

    fn check(&self, tris: &[Triangle], refs_kind: Refs, nested: bool) -> Result<(), String> {
        let split = refs_kind == Refs::Split;
        let wd = self.width as usize;
        if self.nodes() == 0 {
            return if tris.is_empty() && self.prim_indices.is_empty() {
                Ok(())
            } else {
                Err("no nodes but triangles".into())
            };
        }
        let mut seen_node = vec![false; self.nodes()];
        let mut seen_leaf = vec![false; self.leaves.len()];
        let mut refs = vec![0u32; tris.len()];
        let mut slot_used = vec![false; self.prim_indices.len()];
        let mut stack = vec![(0usize, self.root_bounds)];
        seen_node[0] = true;
        let mut order = Vec::with_capacity(self.nodes());
        while let Some((n, parent)) = stack.pop() {
            order.push(n);
            let mut any = false;
            for s in 0..wd {
                let (code, b) = self.child(n, s);
                if code == EMPTY {
                    if !b.is_empty() {
                        return Err(format!("node {n} slot {s}: empty slot with a box"));
                    }
                    continue;
                }
                any = true;
                if nested && !parent.contains(&b) {
                    return Err(format!("node {n} slot {s}: child box outside its parent's"));
                }
                if code & LEAF_BIT == 0 {
                    let c = code as usize;
                    if c >= self.nodes() || std::mem::replace(&mut seen_node[c], true) {
                        return Err(format!("node {n} slot {s}: child {c} out of range or reached twice"));
                    }
                    stack.push((c, b));
                } else {
                    let Some(l) = self.leaf_index(code) else {
                        return Err(format!("node {n} slot {s}: no leaf starts at pack {}", code & !LEAF_BIT));
                    };
                    if std::mem::replace(&mut seen_leaf[l], true) {
                        return Err(format!("node {n} slot {s}: leaf {l} reached twice"));
                    }
                    let [first, count, _] = self.leaves[l];
                    let (first, count) = (first as usize, count as usize);
                    if count == 0 || first + count > self.prim_indices.len() {
                        return Err(format!("leaf {l}: slots {first}+{count} out of range"));
                    }
                    for slot in first..first + count {
                        if std::mem::replace(&mut slot_used[slot], true) {
                            return Err(format!("leaf {l}: slot {slot} shared with another leaf"));
                        }
                        let p = self.prim_indices[slot] as usize;
                        let t = tris.get(p).ok_or_else(|| format!("leaf {l}: triangle {p} out of range"))?;
                        let tb = t.bounds();
                        let inside = if split {
                            (0..3).all(|k| b.min[k] <= tb.max[k] && tb.min[k] <= b.max[k])
                        } else {
                            b.contains(&tb)
                        };
                        if !inside {
                            return Err(format!("leaf {l}: triangle {p} outside the leaf box"));
                        }
                        refs[p] += 1;
                    }
                }
            }
            if !any {
                return Err(format!("node {n} has no child"));
            }
        }
        if let Some(n) = seen_node.iter().position(|s| !s) {
            return Err(format!("node {n} unreachable"));
        }
        if let Some(l) = seen_leaf.iter().position(|s| !s) {
            return Err(format!("leaf {l} unreachable"));
        }
        if let Some(p) = refs.iter().position(|&r| if split { r == 0 } else { r != 1 }) {
            return Err(format!("triangle {p} referenced {} times", refs[p]));
        }
        if !nested {
            self.check_subtrees(tris, split, &order)?;
        }
        Ok(())
    }

    /// Every slot's box against what its subtree's leaves hold (triangle boxes; with `split`, the
    /// parts of them inside their leaf boxes, which the slot box must meet), children before
    /// parents (`order` is the nodes in visiting order, parents first).
    fn check_subtrees(&self, tris: &[Triangle], split: bool, order: &[usize]) -> Result<(), String> {
        let mut reach = vec![Aabb::EMPTY; self.nodes()];
        for &n in order.iter().rev() {
            let mut all = Aabb::EMPTY;
            for s in 0..self.width as usize {
                let (code, b) = self.child(n, s);
                let below = match code {
                    EMPTY => continue,
                    c if c & LEAF_BIT == 0 => reach[c as usize],
                    c => {
                        let [first, count, _] = self.leaf_index(c).map_or([0; 3], |l| self.leaves[l]);
                        let ids = &self.prim_indices[first as usize..(first + count) as usize];
                        ids.iter().fold(Aabb::EMPTY, |u, &p| {
                            let t = tris[p as usize].bounds();
                            let part = if split { Aabb { min: t.min.max(b.min), max: t.max.min(b.max) } } else { t };
                            u.union(&part)
                        })
                    }
                };
                let ok = if split { below.is_empty() || (0..3).all(|k| b.min[k] <= below.max[k] && below.min[k] <= b.max[k]) } else { b.contains(&below) };
                if !ok {
                    return Err(format!("node {n} slot {s}: box does not hold its subtree"));
                }
                all = all.union(&below);
            }
            reach[n] = all;
        }
        Ok(())
    }

    /// Closest hits with counters (exact f64 test, scalar box test: the oracle and the counters;
    /// untimed). Steps = wide nodes and leaves entered; tests = triangle tests.
    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        let store = self.store(tris);
        let plain = self.plain();
        let v = View { src: &plain, leaves: self.leaves.len(), packs: &store.packs, root: self.root_bounds, nodes: self.nodes() };
        match self.width {
            4 => trace_view::<4, _>(&v, rays),
            _ => trace_view::<8, _>(&v, rays),
        }
    }

    /// The timed path: hits only, the watertight f32 test, the SIMD box test.
    pub fn hits(&self, store: &PackStore, rays: &[Ray]) -> Vec<Hit> {
        self.hits_with::<Watertight>(store, rays, Simd::Best)
    }

    /// Hits with the triangle test `T` and the box test `simd` (tests check every combination).
    /// `store` comes from [`WideBvh::store`].
    pub fn hits_with<T: TriTest>(&self, store: &PackStore, rays: &[Ray], simd: Simd) -> Vec<Hit> {
        let plain = self.plain();
        let v = View { src: &plain, leaves: self.leaves.len(), packs: &store.packs, root: self.root_bounds, nodes: self.nodes() };
        match self.width {
            4 => hits_view4::<T, _>(&v, rays, simd.resolve(4)),
            _ => hits_view8::<T, _>(&v, rays, simd.resolve(8)),
        }
    }

    fn plain(&self) -> Plain<'_> {
        // SAFETY: f32 and u32 have the same size and alignment; every bit pattern is a valid f32.
        let words = self.words();
        let f = unsafe { std::slice::from_raw_parts(words.as_ptr() as *const f32, words.len()) };
        Plain { f, data: words }
    }
}

/// Which box test the timed path uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Simd {
    /// AVX2 (with BMI1, BMI2 and POPCNT) when the CPU has it (bvh8: the 8-wide box test; bvh4: the SSE box test and the leaf
    /// test compiled for AVX2), else SSE for bvh4 (x86-64), else scalar.
    Best,
    Avx2,
    Sse,
    Scalar,
}

impl Simd {
    pub(crate) fn resolve(self, width: u32) -> Simd {
        #[cfg(target_arch = "x86_64")]
        {
            // With the BMI1, BMI2 and POPCNT that every AVX2 CPU has (x86-64-v3): the AVX2 walks
            // are compiled with them (shorter bit twiddling, a popcount for the child order).
            let avx2 = std::is_x86_feature_detected!("avx2")
                && std::is_x86_feature_detected!("bmi1")
                && std::is_x86_feature_detected!("bmi2")
                && std::is_x86_feature_detected!("popcnt");
            match (self, width) {
                (Simd::Best | Simd::Avx2, 8 | 4) if avx2 => Simd::Avx2,
                (Simd::Best | Simd::Sse | Simd::Avx2, 4) => Simd::Sse,
                _ => Simd::Scalar,
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (self, width);
            Simd::Scalar
        }
    }
}

/// Where the traversal reads a wide node: its six box rows (`W` floats each) and which slots hold
/// a child; and a child slot's code. [`WideBvh`] hands out its rows in place; the compressed
/// [`crate::cwbvh`] node decodes them into `buf` first.
pub(crate) trait NodeSource<const W: usize> {
    type Buf;
    fn buf() -> Self::Buf;
    /// Box rows and used-slot mask of node `n` (None: out of range, a malformed layout).
    fn node<'a>(&'a self, n: usize, buf: &'a mut Self::Buf) -> Option<(&'a [f32], u32)>;
    /// Child code of `slot` of node `n` (inner: node index; leaf: `LEAF_BIT | ` the source's leaf
    /// number).
    ///
    /// # Safety
    /// `self.node(n, ..)` returned Some (so `n` is in range) and `slot < W`: the traversal reads
    /// codes in its loop without bounds checks (they were 3 % of its instructions).
    unsafe fn code(&self, n: usize, slot: usize) -> u32;
    /// First triangle pack of the leaf a leaf code names (None: no such leaf).
    fn first(&self, code: u32) -> Option<usize>;
    /// Where inner child `code`'s node starts in memory (for a prefetch; None: nothing to fetch).
    fn addr(&self, code: u32) -> Option<*const u8>;
    /// Bytes of one node (what a prefetch of it covers).
    const NODE_BYTES: usize;
    /// Every node starts on a 32-byte boundary (as every triangle pack does).
    const ALIGN32: bool = false;
    /// Where child `code`'s node or first triangle pack starts, for a prefetch (None: nothing to
    /// fetch).
    #[inline(always)]
    fn prefetch_addr(&self, code: u32, packs: &[Tri4]) -> Option<*const u8> {
        if code & LEAF_BIT != 0 {
            self.first(code).and_then(|f| packs.get(f)).map(|t| t as *const Tri4 as *const u8)
        } else {
            self.addr(code)
        }
    }
}

/// The traversal's view of a wide BVH: its nodes and its leaves' triangle packs.
#[derive(Clone, Copy)]
pub(crate) struct View<'a, N> {
    pub src: &'a N,
    /// Number of leaves (bounds the steps of a ray in a malformed layout).
    pub leaves: usize,
    pub packs: &'a [Tri4],
    pub root: Aabb,
    pub nodes: usize,
}

/// [`WideBvh`]'s rows in place: `data` as f32 (the box rows) and the codes row.
pub(crate) struct Plain<'a> {
    f: &'a [f32],
    data: &'a [u32],
}

impl<const W: usize> NodeSource<W> for Plain<'_> {
    type Buf = ();
    fn buf() {}
    #[inline(always)]
    fn node<'a>(&'a self, n: usize, _: &'a mut ()) -> Option<(&'a [f32], u32)> {
        // Unused slots hold the empty box, which every box test misses (`Parallel` skips it), so
        // no per-node mask is stored or computed.
        let base = n * 7 * W;
        Some((self.f.get(base..base + 7 * W)?.get(..6 * W)?, (1u32 << W) - 1))
    }
    #[inline(always)]
    unsafe fn code(&self, n: usize, slot: usize) -> u32 {
        debug_assert!(slot < W && n * 7 * W + 6 * W + slot < self.data.len());
        // SAFETY: `node(n)` returned Some, so words n * 7W .. (n + 1) * 7W exist; slot < W.
        unsafe { *self.data.get_unchecked(n * 7 * W + 6 * W + slot) }
    }
    #[inline(always)]
    fn first(&self, code: u32) -> Option<usize> {
        Some((code & !LEAF_BIT) as usize)
    }
    #[inline(always)]
    fn addr(&self, code: u32) -> Option<*const u8> {
        self.data.get(code as usize * 7 * W).map(|w| w as *const u32 as *const u8)
    }
    const NODE_BYTES: usize = 28 * W;
    /// `Row32` storage and a multiple of 32 bytes per node.
    const ALIGN32: bool = true;
    /// Without a branch on the kind of child (it was 8 % of the traversal's mispredicted branches,
    /// callgrind's branch simulation on breakfast_room) nor bounds checks: a prefetch of an
    /// address past the arrays (a malformed code) is only a hint and never faults.
    #[inline(always)]
    fn prefetch_addr(&self, code: u32, packs: &[Tri4]) -> Option<*const u8> {
        let i = (code & !LEAF_BIT) as usize;
        let leaf = (packs.as_ptr() as *const u8).wrapping_add(i.wrapping_mul(std::mem::size_of::<Tri4>()));
        let node = (self.data.as_ptr() as *const u8).wrapping_add(i.wrapping_mul(28 * W));
        Some(if code & LEAF_BIT != 0 { leaf } else { node })
    }
}

/// All children's slab tests of one node at once: entry distances into `dist`, a bit per child hit.
trait WideBox<const W: usize> {
    /// # Safety
    /// `rows` points at a node's six box rows of `W` floats each; the SIMD impls need their CPU feature.
    unsafe fn test(rows: *const f32, r: &SlabRay, tmax: f32, dist: &mut [f32; W]) -> u32;
    /// The test needs AVX2 (so the leaves may use their AVX2 build too).
    const AVX2: bool = false;
    /// The slots of `mask` (the children hit) by descending entry distance, ties by ascending
    /// slot, into `out`; returns how many. By insertion here.
    ///
    /// # Safety
    /// The SIMD impls need their CPU feature.
    #[inline(always)]
    unsafe fn order(dist: &[f32; W], mask: u32, out: &mut [u8; W]) -> usize {
        insertion_order(dist, mask, out)
    }
}

/// [`WideBox::order`] by insertion: slots in ascending order, each placed after every slot with a
/// larger or equal entry.
#[inline(always)]
fn insertion_order<const W: usize>(dist: &[f32; W], mask: u32, out: &mut [u8; W]) -> usize {
    let (mut n, mut m) = (0, mask);
    while m != 0 {
        let i = m.trailing_zeros() as usize;
        m &= m - 1;
        let mut j = n;
        while j > 0 && dist[out[j - 1] as usize] < dist[i] {
            out[j] = out[j - 1];
            j -= 1;
        }
        out[j] = i as u8;
        n += 1;
    }
    n
}

/// Bits set in each byte value (a table: `count_ones` without the popcnt feature is a dozen
/// instructions).
const POPCOUNT8: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = (i as u32).count_ones() as u8;
        i += 1;
    }
    t
};

struct Scalar;
impl<const W: usize> WideBox<W> for Scalar {
    #[inline(always)]
    unsafe fn test(rows: *const f32, r: &SlabRay, tmax: f32, dist: &mut [f32; W]) -> u32 {
        let rows = unsafe { std::slice::from_raw_parts(rows, 6 * W) };
        let Planes { near, far } = r.planes();
        let mut mask = 0;
        for (c, d) in dist.iter_mut().enumerate() {
            let t = |k: usize, a: usize| (rows[k * W + c] - r.origin[a]) * r.inv[a];
            let mx = |a: f32, b: f32| if a > b { a } else { b };
            let mn = |a: f32, b: f32| if a < b { a } else { b };
            let near = mx(mx(t(near[0], 0), t(near[1], 1)), mx(t(near[2], 2), 0.0));
            let far = mn(mn(t(far[0], 0), t(far[1], 1)), mn(t(far[2], 2), tmax)) * SLAB_ROBUST;
            *d = near;
            mask |= ((near <= far) as u32) << c;
        }
        mask
    }
}

#[cfg(target_arch = "x86_64")]
struct Sse4;
#[cfg(target_arch = "x86_64")]
impl WideBox<4> for Sse4 {
    #[inline(always)]
    unsafe fn order(dist: &[f32; 4], mask: u32, out: &mut [u8; 4]) -> usize {
        unsafe { sse4_order(dist, mask, out) }
    }
    #[inline(always)]
    unsafe fn test(rows: *const f32, r: &SlabRay, tmax: f32, dist: &mut [f32; 4]) -> u32 {
        unsafe { sse4_test(rows, r, r.planes(), tmax, dist) }
    }
}

/// [`WideBox::order`] for 4 wide by counting, as [`Avx8`]'s: one 4-wide comparison per child hit.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn sse4_order(dist: &[f32; 4], mask: u32, out: &mut [u8; 4]) -> usize {
    use std::arch::x86_64::*;
    unsafe {
        let d4 = _mm_loadu_ps(dist.as_ptr());
        counted_order::<4, false>(dist, mask, out, |d| {
            let b = _mm_set1_ps(d);
            (_mm_movemask_ps(_mm_cmpgt_ps(d4, b)) as u32, _mm_movemask_ps(_mm_cmpeq_ps(d4, b)) as u32)
        })
    }
}

/// The slots of `mask` by descending entry, ties by ascending slot, each placed at the number of
/// children hit before it: `cmp(d)` gives the lanes whose entry is greater than `d` and equal to it.
/// `POPCNT`: the caller is compiled with the popcnt instruction (else a table counts).
#[inline(always)]
fn counted_order<const W: usize, const POPCNT: bool>(
    dist: &[f32; W],
    mask: u32,
    out: &mut [u8; W],
    cmp: impl Fn(f32) -> (u32, u32),
) -> usize {
    let count = |b: u32| if POPCNT { b.count_ones() } else { POPCOUNT8[(b & 0xff) as usize] as u32 };
    let mut m = mask;
    while m != 0 {
        let i = m.trailing_zeros() as usize;
        m &= m - 1;
        let (gt, eq) = cmp(dist[i]);
        let rank = count((gt | (eq & ((1 << i) - 1))) & mask);
        // A rank is below the count of children hit (no NaN entry among them), so below W.
        out[rank as usize % W] = i as u8;
    }
    count(mask) as usize
}

/// The 4-wide SSE box test with the plane rows given.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn sse4_test(rows: *const f32, r: &SlabRay, p: Planes, tmax: f32, dist: &mut [f32; 4]) -> u32 {
    use std::arch::x86_64::*;
    let Planes { near, far } = p;
    unsafe {
        let t = |k: usize, a: usize| {
            _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(rows.add(k * 4)), _mm_set1_ps(r.origin[a])), _mm_set1_ps(r.inv[a]))
        };
        let near = _mm_max_ps(_mm_max_ps(t(near[0], 0), t(near[1], 1)), _mm_max_ps(t(near[2], 2), _mm_setzero_ps()));
        let far = _mm_mul_ps(
            _mm_min_ps(_mm_min_ps(t(far[0], 0), t(far[1], 1)), _mm_min_ps(t(far[2], 2), _mm_set1_ps(tmax))),
            _mm_set1_ps(SLAB_ROBUST),
        );
        _mm_storeu_ps(dist.as_mut_ptr(), near);
        _mm_movemask_ps(_mm_cmple_ps(near, far)) as u32
    }
}

/// [`Sse4`] where the CPU has AVX2 (only instantiated in [`chunk_avx4`]): the same box test, and the
/// leaves take the leaf test's AVX2 build.
#[cfg(target_arch = "x86_64")]
struct Sse4Vex;
#[cfg(target_arch = "x86_64")]
impl WideBox<4> for Sse4Vex {
    const AVX2: bool = true;
    #[inline(always)]
    unsafe fn order(dist: &[f32; 4], mask: u32, out: &mut [u8; 4]) -> usize {
        unsafe { sse4_order(dist, mask, out) }
    }
    #[inline(always)]
    unsafe fn test(rows: *const f32, r: &SlabRay, tmax: f32, dist: &mut [f32; 4]) -> u32 {
        unsafe { Sse4::test(rows, r, tmax, dist) }
    }
}

#[cfg(target_arch = "x86_64")]
struct Avx8;
#[cfg(target_arch = "x86_64")]
impl WideBox<8> for Avx8 {
    const AVX2: bool = true;
    /// Each child's place by counting, with one 8-wide comparison, the children hit that come
    /// before it (a larger entry, or an equal one in a lower slot): the same order as the
    /// insertion sort without its data-dependent inner loop (18 % of the traversal's mispredicted
    /// branches, callgrind's branch simulation on breakfast_room). Hit lanes have no NaN entry
    /// (their `near <= far` held).
    #[inline(always)]
    unsafe fn order(dist: &[f32; 8], mask: u32, out: &mut [u8; 8]) -> usize {
        use std::arch::x86_64::*;
        unsafe {
            let d8 = _mm256_loadu_ps(dist.as_ptr());
            counted_order::<8, true>(dist, mask, out, |d| {
                let b = _mm256_set1_ps(d);
                let gt = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(d8, b)) as u32;
                (gt, _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(d8, b)) as u32)
            })
        }
    }
    #[inline(always)]
    unsafe fn test(rows: *const f32, r: &SlabRay, tmax: f32, dist: &mut [f32; 8]) -> u32 {
        use std::arch::x86_64::*;
        // The rows of the ray's planes (loop-invariant: computed once per ray in the walk).
        let Planes { near, far } = r.planes();
        unsafe {
            // (origin - plane) * -inverse: the same bits as (plane - origin) * inverse (both
            // factors negated exactly), with the row the subtrahend, which AVX reads from memory.
            let t = |k: usize, a: usize| {
                _mm256_mul_ps(
                    _mm256_sub_ps(_mm256_set1_ps(r.origin[a]), _mm256_loadu_ps(rows.add(k * 8))),
                    _mm256_set1_ps(-r.inv[a]),
                )
            };
            let near = _mm256_max_ps(
                _mm256_max_ps(t(near[0], 0), t(near[1], 1)),
                _mm256_max_ps(t(near[2], 2), _mm256_setzero_ps()),
            );
            let far = _mm256_mul_ps(
                _mm256_min_ps(
                    _mm256_min_ps(t(far[0], 0), t(far[1], 1)),
                    _mm256_min_ps(t(far[2], 2), _mm256_set1_ps(tmax)),
                ),
                _mm256_set1_ps(SLAB_ROBUST),
            );
            _mm256_storeu_ps(dist.as_mut_ptr(), near);
            _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32
        }
    }
}

/// Parallel rays (a zero direction component): every child through `RayBox::hit`, which is exact
/// for them. `RayBox` sees an empty box as unbounded, so empty boxes (unused slots of `bvh4`/`bvh8`)
/// are skipped here; cwbvh's unused slots are dropped by its used-slot mask.
struct Parallel;

/// Closest hits with counters: the exact f64 triangle test, the scalar box test (the oracle).
pub(crate) fn trace_view<const W: usize, N: NodeSource<W> + Sync>(v: &View<N>, rays: &[Ray]) -> TraceStats {
    bvhlab_trace::trace_with(rays, Stack::new, |stack, ray| v.one::<W, Exact, Scalar, true>(ray, stack))
}

/// The timed path of an 8-wide node source: hits only, the AVX2 box test when `simd` says so.
pub(crate) fn hits_view8<T: TriTest, N: NodeSource<8> + Sync>(v: &View<N>, rays: &[Ray], simd: Simd) -> Vec<Hit> {
    par_hits(rays, |r, h, stack| match simd {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Simd::resolve` picks Avx2 only when the CPU has AVX2, BMI1, BMI2 and POPCNT.
        Simd::Avx2 => unsafe { chunk_avx8::<T, N>(v, r, h, stack) },
        _ => chunk::<8, T, N, Scalar>(v, r, h, stack),
    })
}

/// The timed path of a 4-wide node source: hits only, the SSE box test when `simd` says so
/// (compiled for AVX2 with `Simd::Avx2`).
pub(crate) fn hits_view4<T: TriTest, N: NodeSource<4> + Sync>(v: &View<N>, rays: &[Ray], simd: Simd) -> Vec<Hit> {
    par_hits(rays, |r, h, stack| match simd {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Simd::resolve` picks Avx2 only when the CPU has AVX2, BMI1, BMI2 and POPCNT.
        Simd::Avx2 => unsafe { chunk_avx4::<T, N>(v, r, h, stack) },
        #[cfg(target_arch = "x86_64")]
        Simd::Sse => chunk::<4, T, N, Sse4>(v, r, h, stack),
        _ => chunk::<4, T, N, Scalar>(v, r, h, stack),
    })
}

/// Rays traced in parallel in chunks of 1024 (one stack per worker), hits in ray order.
fn par_hits(rays: &[Ray], f: impl Fn(&[Ray], &mut [Hit], &mut Stack) + Sync) -> Vec<Hit> {
    use rayon::prelude::*;
    let mut hits = vec![Hit::NONE; rays.len()];
    hits.par_chunks_mut(1024)
        .zip(rays.par_chunks(1024))
        .for_each_init(Stack::new, |stack, (h, r)| f(r, h, stack));
    hits
}

#[inline(always)]
fn chunk<const W: usize, T: TriTest, N: NodeSource<W>, B: WideBox<W>>(v: &View<N>, rays: &[Ray], hits: &mut [Hit], stack: &mut Stack) {
    for (h, r) in hits.iter_mut().zip(rays) {
        *h = v.one::<W, T, B, false>(r, stack).0;
    }
}

/// The 8-wide chunk compiled with AVX2 so the box test's intrinsics (and a compressed node's
/// decoding) inline and vectorize.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt")]
unsafe fn chunk_avx8<T: TriTest, N: NodeSource<8>>(v: &View<N>, rays: &[Ray], hits: &mut [Hit], stack: &mut Stack) {
    if v.nodes == 0 || v.root.is_empty() {
        return hits.fill(Hit::NONE);
    }
    for (h, r) in hits.iter_mut().zip(rays) {
        *h = v.one_checked::<8, T, Avx8>(r, stack);
    }
}

/// The 4-wide chunk compiled for AVX2: the same SSE box test (VEX-encoded) and the leaf test's
/// AVX2 build ([`Sse4Vex`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt")]
unsafe fn chunk_avx4<T: TriTest, N: NodeSource<4>>(v: &View<N>, rays: &[Ray], hits: &mut [Hit], stack: &mut Stack) {
    if v.nodes == 0 || v.root.is_empty() {
        return hits.fill(Hit::NONE);
    }
    for (h, r) in hits.iter_mut().zip(rays) {
        *h = v.one_checked::<4, T, Sse4Vex>(r, stack);
    }
}

impl<N> View<'_, N> {
    /// Asks for the memory of a child pushed on the stack: a ray that misses everything below
    /// its nearest child pops it next, and its node (or leaf triangles) is then already on the
    /// way instead of one more cache miss in line (the dragon's tree does not fit the caches).
    #[inline(always)]
    fn prefetch<const W: usize>(&self, code: u32) where N: NodeSource<W> {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            // A leaf: its first pack (one four-wide test); a node: all of it. The larger of the two
            // either way (one line more for the smaller, instead of a branch on the kind).
            let bytes = if N::NODE_BYTES > std::mem::size_of::<Tri4>() { N::NODE_BYTES } else { std::mem::size_of::<Tri4>() };
            if let Some(p) = self.src.prefetch_addr(code, self.packs) {
                // Every cache line the object touches: one per 64 bytes from its first byte, and
                // the line of its last byte (the object need not start a line) where that is
                // another. `bytes` is a
                // constant of the instantiation, so this unrolls into a few instructions (a loop
                // over the lines cost 20 instructions per ray, measured with callgrind).
                let mut o = 0;
                while o < bytes {
                    // SAFETY: prefetching never faults (no memory is read through these addresses).
                    unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(o) as *const i8) };
                    o += 64;
                }
                // Starting on a 32-byte boundary, an object of 64k + 32 bytes ends in the line of
                // its last 64-byte step.
                if !(N::ALIGN32 && bytes % 64 == 32) {
                    // SAFETY: as above.
                    unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(bytes - 1) as *const i8) };
                }
            }
        }
    }

    #[inline(always)]
    fn one<const W: usize, T: TriTest, B: WideBox<W>, const STATS: bool>(
        &self,
        ray: &Ray,
        stack: &mut Stack,
    ) -> (Hit, u32, u32)
    where
        N: NodeSource<W>,
    {
        if self.nodes == 0 || ray.tmax.is_nan() || ray.tmax <= 0.0 {
            return (Hit::NONE, 0, 0);
        }
        if self.root.is_empty() {
            return (Hit::NONE, 0, 0);
        }
        let sr = SlabRay::new(ray);
        self.one_slab::<W, T, B, STATS>(ray, &sr, stack)
    }

    /// [`Self::one`] (hits only) where the caller has checked once that the tree has a root with a
    /// non-empty box.
    #[inline(always)]
    fn one_checked<const W: usize, T: TriTest, B: WideBox<W>>(&self, ray: &Ray, stack: &mut Stack) -> Hit
    where
        N: NodeSource<W>,
    {
        if !(ray.tmax > 0.0) {
            return Hit::NONE;
        }
        self.one_slab::<W, T, B, false>(ray, &SlabRay::new(ray), stack).0
    }

    /// [`Self::one`] after its checks, with the ray's slab data.
    #[inline(always)]
    fn one_slab<const W: usize, T: TriTest, B: WideBox<W>, const STATS: bool>(
        &self,
        ray: &Ray,
        sr: &SlabRay,
        stack: &mut Stack,
    ) -> (Hit, u32, u32)
    where
        N: NodeSource<W>,
    {
        if sr.parallel {
            let rb = RayBox::new(ray);
            if rb.hit(&self.root, ray.tmax).is_none() {
                return (Hit::NONE, 0, 0);
            }
            self.walk::<W, T, Parallel, STATS>(ray, sr, Some(&rb), stack)
        } else {
            // The same test as `RayBox::hit` for a ray with no zero component, without its divisions.
            if !sr.enters(&self.root, ray.tmax) {
                return (Hit::NONE, 0, 0);
            }
            self.walk::<W, T, B, STATS>(ray, sr, None, stack)
        }
    }

    /// Nearest child first: the children hit are sorted by entry distance, the nearest entered,
    /// the rest pushed farthest first; a popped entry beyond the closest hit is culled (with the
    /// binary traversal's margin, so the exact test finds brute force's hits, ties included).
    #[inline(always)]
    fn walk<const W: usize, T: TriTest, B: BoxSel<W>, const STATS: bool>(
        &self,
        ray: &Ray,
        sr: &SlabRay,
        rb: Option<&RayBox>,
        stack: &mut Stack,
    ) -> (Hit, u32, u32)
    where
        N: NodeSource<W>,
    {
        let mut best = Hit::within(ray.tmax);
        let (mut steps, mut tests) = (0u32, 0u32);
        // Prepared up front: almost every ray that enters the root reaches a leaf (breakfast_room:
        // 97 %), and prepared at the first leaf the ray's data were reloaded and rebroadcast at
        // every leaf.
        let tr = if B::AVX2 {
            // SAFETY: `B::AVX2` holds only for the AVX2 box tests, which run only after
            // `Simd::resolve` found AVX2.
            unsafe { T::prepare_avx2(ray, &sr.inv) }
        } else {
            T::prepare(ray, &sr.inv)
        };
        stack.clear();
        let mut cur = 0u32;
        let mut budget = self.nodes + self.leaves;
        let mut buf = N::buf();
        loop {
            if budget == 0 {
                break;
            }
            budget -= 1;
            if STATS {
                steps += 1;
            }
            if cur & LEAF_BIT == 0 {
                let node = cur as usize;
                let Some((rows, used)) = self.src.node(node, &mut buf) else { break };
                let mut dist = [0f32; W];
                let mask = B::sel(rows, sr, rb, best.t, &mut dist) & used;
                // SAFETY: `node` was just read (`self.src.node` returned Some) and every slot
                // index comes from `mask`, whose bits are below W.
                let code = |i: usize| unsafe { self.src.code(node, i) };
                // (No count_ones: popcnt is not in the x86-64 baseline nor implied by AVX2.)
                match mask {
                    0 => {}
                    m if m & (m - 1) == 0 => {
                        cur = code(m.trailing_zeros() as usize);
                        continue;
                    }
                    // Two children (the commonest case after one): one comparison instead of
                    // the insertion sort, in the sort's order (the nearer entered; on a tie the
                    // higher slot, which the sort puts last).
                    m if (m & (m - 1)) & (m & (m - 1)).wrapping_sub(1) == 0 => {
                        let (a, b) = (m.trailing_zeros() as usize, (m & (m - 1)).trailing_zeros() as usize);
                        let (near, far) = if dist[a] < dist[b] { (a, b) } else { (b, a) };
                        let f = code(far);
                        self.prefetch::<W>(f);
                        stack.push((f, dist[far]));
                        cur = code(near);
                        continue;
                    }
                    _ => {
                        // By descending entry: the nearest ends up last, and is entered.
                        let mut ord = [0u8; W];
                        let n = B::order(&dist, mask, &mut ord);
                        for &i in &ord[..n - 1] {
                            let c = code(i as usize);
                            self.prefetch::<W>(c);
                            stack.push((c, dist[i as usize]));
                        }
                        cur = code(ord[n - 1] as usize);
                        continue;
                    }
                }
            } else if let Some(first) = self.src.first(cur) {
                // The leaf's triangles: from its first pack to the lane marked last.
                let leaf = self.packs.get(first..).unwrap_or_default();
                let n = if B::AVX2 {
                    // SAFETY: `B::AVX2` holds only for the AVX2 box test, which runs only after
                    // `Simd::resolve` found AVX2.
                    unsafe { T::test_packs_avx2(&tr, leaf, &mut best) }
                } else {
                    T::test_packs(&tr, leaf, &mut best)
                };
                if STATS {
                    tests += n;
                }
            }
            match stack.pop_within(best.t * SLAB_ROBUST) {
                Some((n, _)) => cur = n,
                None => break,
            }
        }
        let hit = best.found();
        (hit, steps, tests)
    }
}

/// A box test over a node given its rows (the traversal masks the slots not in use).
trait BoxSel<const W: usize> {
    fn sel(rows: &[f32], sr: &SlabRay, rb: Option<&RayBox>, tmax: f32, dist: &mut [f32; W]) -> u32;
    /// See [`WideBox::order`].
    #[inline(always)]
    fn order(dist: &[f32; W], mask: u32, out: &mut [u8; W]) -> usize {
        insertion_order(dist, mask, out)
    }
    /// See [`WideBox::AVX2`].
    const AVX2: bool = false;
}

impl<const W: usize, B: WideBox<W>> BoxSel<W> for B {
    const AVX2: bool = B::AVX2;
    #[inline(always)]
    fn order(dist: &[f32; W], mask: u32, out: &mut [u8; W]) -> usize {
        // SAFETY: as `sel`: a SIMD `B` runs only after its CPU feature was found.
        unsafe { B::order(dist, mask, out) }
    }
    #[inline(always)]
    fn sel(rows: &[f32], sr: &SlabRay, _: Option<&RayBox>, tmax: f32, dist: &mut [f32; W]) -> u32 {
        debug_assert!(rows.len() >= 6 * W);
        // SAFETY: rows holds at least 6 * W floats (a node's slice); the CPU feature of a SIMD `B`
        // was checked before its instantiation was called (`Simd::resolve`).
        unsafe { B::test(rows.as_ptr(), sr, tmax, dist) }
    }
}

impl<const W: usize> BoxSel<W> for Parallel {
    fn sel(rows: &[f32], _: &SlabRay, rb: Option<&RayBox>, tmax: f32, dist: &mut [f32; W]) -> u32 {
        // Always given for parallel rays (`one`).
        let Some(rb) = rb else { return 0 };
        let mut mask = 0;
        for c in 0..W {
            let f = |row: usize| rows[row * W + c];
            let b = Aabb {
                min: Vec3::new(f(0), f(1), f(2)),
                max: Vec3::new(f(3), f(4), f(5)),
            };
            if b.is_empty() {
                continue;
            }
            if let Some(t) = rb.hit(&b, tmax) {
                dist[c] = t;
                mask |= 1 << c;
            }
        }
        mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The counted orderings of the children hit (AVX2 8-wide, SSE 4-wide) are the insertion
    /// sort's, ties included (equal entries are common: rays starting inside several boxes enter
    /// them all at 0).
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn counted_order_equals_the_insertion_sort() {
        if !std::is_x86_feature_detected!("avx2") {
            return;
        }
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..100_000 {
            let r = next();
            // Few distinct values, so that ties are frequent.
            let dist: [f32; 8] = std::array::from_fn(|i| [0.0, 0.5, 1.0, 2.5, f32::INFINITY][((r >> (3 * i)) % 5) as usize]);
            let mask = (next() & 0xff) as u32;
            let (mut a, mut b) = ([0u8; 8], [0u8; 8]);
            let n = insertion_order(&dist, mask, &mut a);
            // SAFETY: AVX2 was detected.
            let m = unsafe { <Avx8 as WideBox<8>>::order(&dist, mask, &mut b) };
            assert_eq!((n, &a[..n]), (m, &b[..m]), "{dist:?} {mask:#b}");
            let (d4, m4) = ([dist[0], dist[1], dist[2], dist[3]], mask & 0xf);
            let (mut a4, mut b4) = ([0u8; 4], [0u8; 4]);
            let n = insertion_order(&d4, m4, &mut a4);
            // SAFETY: SSE is in the x86-64 baseline.
            let m = unsafe { sse4_order(&d4, m4, &mut b4) };
            assert_eq!((n, &a4[..n]), (m, &b4[..m]), "{d4:?} {m4:#b}");
        }
    }
}
