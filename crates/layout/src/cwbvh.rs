//! `cwbvh`: the compressed 8-wide node of Ylitie, Karras and Laine 2017 ("Efficient Incoherent Ray
//! Traversal on GPUs Through Compressed Wide BVHs", section 3.1), 80 bytes per node, built from the
//! `bvh8` collapse (`crate::wide`, SAH-optimal or greedy: the same `collapse` parameter) of the
//! binary BVH.
//!
//! A node stores the origin `p` of a grid (its box minimum), per axis the grid step as a power of
//! two (an 8-bit exponent `e`: step 2^(e-127), the smallest with 255 steps covering the box), and
//! per child slot its box in grid steps, 8 bits per coordinate, the lower bound rounded down and the
//! upper rounded up (conservative). Steps are powers of two so that `p + q * step` is exact up to the
//! one rounding of the addition; the build checks every bound with that very f32 expression, so the
//! decoded box contains the child's box bit for bit. Inner children are consecutive nodes from
//! `child_base`, leaf children consecutive entries of `leaves` from `leaf_base`, both in slot order
//! (`imask` says which slots are inner, `meta` gives each used slot its rank among its kind).
//!
//! Differences from the paper, for the CPU and for bvhlab's trees: leaves keep bvhlab's (first,
//! count) ranges (any leaf size, as built; the paper packs up to 3 triangles per leaf slot into
//! `meta`), and child slots are not reordered by octant: the traversal sorts the children hit by
//! entry distance as `bvh8` does. The traversal decodes a node's six rows to f32 (vectorized with
//! AVX2 when the CPU has it) and runs `bvh8`'s box test and walk, so the two layouts differ only in
//! what a node costs to read: 80 bytes against 224.
use crate::wide::{self, Collapse, NodeSource, Simd, View, WideBvh, EMPTY, LEAF_BIT};
use crate::Memory;
use bvhlab_bvh::{Bvh, CostParams, Refs};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use bvhlab_params::Method;
use bvhlab_trace::fast::{TriTest, Watertight};
use bvhlab_trace::{Hit, PackStore, Ray, TraceStats};
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "cwbvh",
    "compressed 8-wide BVH: bvh8's collapse in 80-byte nodes, child boxes quantized to 8 bits on a power-of-two grid per node",
    "Ylitie, Karras and Laine 2017 (CWBVH, section 3.1)",
    &[wide::COLLAPSE_PARAM],
)
// 2: the traversal reads a leaf's triangles up to the store's end mark (its stored nodes are
// unchanged; the bump re-measures its trace times with the current traversal).
// 3: built from bvh8 version 3 (combined leaves).
// 4: built from bvh8 version 4 (SAH-optimal collapse by default).
// 5: nodes unchanged; bvh8 version 5's faster timed traversal (its times re-measured).
// 6: leaves name their first triangle pack (bvh8 version 6).
// 7: nodes unchanged; bvh8 version 7's faster timed traversal and leaf test (times re-measured).
.with_version(7);

/// One compressed node (80 bytes; see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct CwNode {
    /// Origin of the child grid (the node's box minimum).
    pub p: [f32; 3],
    /// Per axis the exponent of the grid step, 2^(e - 140) (see [`K_MIN`]).
    pub e: [u8; 3],
    /// Bit i: slot i holds an inner child.
    pub imask: u8,
    /// Node index of the first inner child.
    pub child_base: u32,
    /// Index in `leaves` of the first leaf child.
    pub leaf_base: u32,
    /// Per slot: 0 unused, else `0x80 | rank` of the child among the node's inner or leaf children.
    pub meta: [u8; 8],
    /// Per axis and slot: lower bound in grid steps (rounded down).
    pub qlo: [[u8; 8]; 3],
    /// Per axis and slot: upper bound in grid steps (rounded up).
    pub qhi: [[u8; 8]; 3],
}

const _: () = assert!(std::mem::size_of::<CwNode>() == 80);

const USED: u8 = 0x80;

/// Smallest and largest step exponent. The paper's step is 2^(e - 127), an f32 exponent field,
/// which cannot step below 2^-126: boxes of a scene near 1e-37 then grow to whole grid steps (SAH
/// x3 measured). bvhlab spends the byte on 2^-140 ..= 2^113 instead: subnormal steps for tiny
/// scenes, and nodes up to 255 * 2^113 = 2.6e36 wide (wider ones are refused with an error; only
/// scenes spanning most of the f32 range have them).
pub const K_MIN: i32 = -140;
pub const K_MAX: i32 = 113;

impl CwNode {
    /// 2^(e - 140) as 2^(e - 126) (a normal f32 for e <= 253) times 2^-14 (exact, subnormal
    /// below 2^-126).
    #[inline(always)]
    fn step(&self, axis: usize) -> f32 {
        f32::from_bits((self.e[axis] as u32 + 1) << 23) * (1.0 / 16384.0)
    }

    /// The decoded box rows (min x, y, z, max x, y, z; 8 slots each), as traversal tests them.
    #[inline(always)]
    fn decode(&self, rows: &mut [f32; 48]) {
        for a in 0..3 {
            let (p, s) = (self.p[a], self.step(a));
            for c in 0..8 {
                rows[a * 8 + c] = p + self.qlo[a][c] as f32 * s;
                rows[(3 + a) * 8 + c] = p + self.qhi[a][c] as f32 * s;
            }
        }
    }

    /// Bit i set when slot i is used (bit 7 of `meta[i]`).
    #[inline(always)]
    fn used(&self) -> u32 {
        let m = (u64::from_le_bytes(self.meta) >> 7) & 0x0101_0101_0101_0101;
        (m.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u32
    }

    #[inline(always)]
    fn code(&self, slot: usize) -> u32 {
        let rank = (self.meta[slot] & !USED) as u32;
        if self.imask & (1 << slot) != 0 {
            self.child_base + rank
        } else {
            LEAF_BIT | (self.leaf_base + rank)
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CwBvh {
    /// Node 0 is the root; every node's inner children are consecutive (breadth-first order).
    pub nodes: Vec<CwNode>,
    /// (first slot, count, first pack) per leaf, as `bvh8`'s ([`WideBvh::leaves`]): triangles
    /// `prim_indices[first..first + count]`, in the traversal's store from pack `first pack` on.
    pub leaves: Vec<[u32; 3]>,
    pub prim_indices: Vec<u32>,
    /// Exact box of the root (tested once per ray before the traversal).
    pub root_bounds: Aabb,
    /// The collapse the nodes come from (`bvh8`'s with the same parameter).
    pub collapse: Collapse,
}

/// Exponent `k` of the smallest power-of-two step with `255 * 2^k >= extent`, within
/// [`K_MIN`]..=[`K_MAX`] (a flat axis gets the smallest step; a wider extent is refused later).
fn step_exponent(extent: f64) -> i32 {
    if !(extent > 0.0) {
        return K_MIN;
    }
    let mut k = ((extent / 255.0).log2().ceil() as i32).clamp(K_MIN, K_MAX);
    while k < K_MAX && 255.0 * 2f64.powi(k) < extent {
        k += 1;
    }
    while k > K_MIN && 255.0 * 2f64.powi(k - 1) >= extent {
        k -= 1;
    }
    k
}

/// The 8-bit grid bounds of `[lo, hi]` on the grid `p + q * s`, checked with the traversal's own
/// f32 expression: `p + qlo * s <= lo` and `p + qhi * s >= hi`.
fn quantize(p: f32, s: f32, lo: f32, hi: f32) -> Result<(u8, u8), String> {
    let dec = |q: u32| p + q as f32 * s;
    let mut ql = (((lo as f64 - p as f64) / s as f64).floor().clamp(0.0, 255.0)) as u32;
    while ql > 0 && dec(ql) > lo {
        ql -= 1;
    }
    let mut qh = (((hi as f64 - p as f64) / s as f64).ceil().clamp(0.0, 255.0)) as u32;
    while qh < 255 && dec(qh) < hi {
        qh += 1;
    }
    if dec(ql) > lo || dec(qh) < hi {
        return Err(format!(
            "cwbvh: cannot quantize [{lo}, {hi}] on the grid {p} + q * {s} (a node wider than 255 * 2^{K_MAX})"
        ));
    }
    Ok((ql as u8, qh as u8))
}

impl CwBvh {
    /// `bvh8`'s collapse of `bvh`, compressed (module doc).
    pub fn build(bvh: &Bvh) -> Result<CwBvh, String> {
        Self::build_with(bvh, Collapse::default())
    }

    /// [`Self::build`] with a choice of collapse.
    pub fn build_with(bvh: &Bvh, collapse: Collapse) -> Result<CwBvh, String> {
        let w = WideBvh::build_with(bvh, 8, collapse)?;
        let mut out = CwBvh {
            nodes: Vec::with_capacity(w.nodes()),
            leaves: Vec::with_capacity(w.leaves.len()),
            prim_indices: w.prim_indices.clone(),
            root_bounds: w.root_bounds,
            collapse,
        };
        if w.nodes() == 0 {
            return Ok(out);
        }
        // Breadth first: a node's inner children get consecutive indices when it is written.
        let mut queue = std::collections::VecDeque::from([0usize]);
        out.nodes.push(CwNode::default());
        let mut index = 0usize;
        while let Some(wn) = queue.pop_front() {
            let kids: Vec<(u32, Aabb)> = (0..8).map(|s| w.child(wn, s)).filter(|(c, _)| *c != EMPTY).collect();
            let bounds = kids.iter().fold(Aabb::EMPTY, |b, (_, k)| b.union(k));
            let mut node = CwNode {
                p: bounds.min.to_array(),
                child_base: out.nodes.len() as u32,
                leaf_base: out.leaves.len() as u32,
                ..CwNode::default()
            };
            let mut steps = [0f32; 3];
            for a in 0..3 {
                let k = step_exponent(bounds.max[a] as f64 - bounds.min[a] as f64);
                node.e[a] = (k - K_MIN) as u8;
                steps[a] = node.step(a);
                debug_assert_eq!(steps[a] as f64, 2f64.powi(k));
            }
            let (mut inner, mut leaves) = (0u8, 0u8);
            for (slot, (code, b)) in kids.iter().enumerate() {
                for a in 0..3 {
                    let (lo, hi) = quantize(node.p[a], steps[a], b.min[a], b.max[a])?;
                    node.qlo[a][slot] = lo;
                    node.qhi[a][slot] = hi;
                }
                if code & LEAF_BIT == 0 {
                    node.imask |= 1 << slot;
                    node.meta[slot] = USED | inner;
                    inner += 1;
                    out.nodes.push(CwNode::default());
                    queue.push_back(*code as usize);
                } else {
                    node.meta[slot] = USED | leaves;
                    leaves += 1;
                    let l = w.leaf_index(*code).ok_or("cwbvh: a bvh8 leaf code without its leaf")?;
                    out.leaves.push(w.leaves[l]);
                }
            }
            out.nodes[index] = node;
            index += 1;
        }
        Ok(out)
    }

    /// The same tree with its decoded (quantized) boxes as a plain `bvh8` (same node and leaf
    /// indices): what SAH cost and validation read.
    pub fn decoded(&self) -> WideBvh {
        let mut w = WideBvh::empty(8, self.prim_indices.clone(), self.root_bounds);
        // bvh8 names a leaf by its first pack; an out-of-range leaf number keeps a code no leaf
        // starts at, which validation reports.
        let leaf = |c: u32| match self.leaves.get((c & !LEAF_BIT) as usize) {
            Some(l) => LEAF_BIT | l[2],
            None => LEAF_BIT | (LEAF_BIT - 1),
        };
        for n in &self.nodes {
            let i = w.push_node();
            let mut rows = [0f32; 48];
            n.decode(&mut rows);
            let used = n.used();
            for slot in (0..8).filter(|s| used & (1 << s) != 0) {
                let f = |row: usize| rows[row * 8 + slot];
                w.set_box(i, slot, &Aabb { min: Vec3::new(f(0), f(1), f(2)), max: Vec3::new(f(3), f(4), f(5)) });
                let c = n.code(slot);
                w.set_child(i, slot, if c & LEAF_BIT != 0 { leaf(c) } else { c });
            }
        }
        w.leaves = self.leaves.clone();
        w.leaves.sort_unstable();
        w
    }

    /// The triangle store the traversal reads (the `bvh8` one of the same BVH is the same store).
    pub fn store(&self, tris: &[Triangle]) -> PackStore {
        PackStore::new(&self.prim_indices, tris, &self.leaves)
    }

    /// A copy for the timed path: the nodes in memory advised for huge pages (as
    /// [`WideBvh::timed_copy`]); the same layout otherwise.
    pub fn timed_copy(&self) -> CwBvh {
        CwBvh {
            nodes: bvhlab_trace::thp::copy(&self.nodes),
            // Read by the timed walk (a leaf's first pack).
            leaves: bvhlab_trace::thp::copy(&self.leaves),
            prim_indices: self.prim_indices.clone(),
            root_bounds: self.root_bounds,
            collapse: self.collapse,
        }
    }

    pub fn memory(&self) -> Memory {
        let topology = (self.nodes.len() * std::mem::size_of::<CwNode>() + self.leaves.len() * 8) as u64;
        Memory {
            topology_bytes: topology,
            total_bytes: topology + self.prim_indices.len() as u64 * 4,
            nodes: (self.nodes.len() + self.leaves.len()) as u64,
            chunks: 0,
            chunk_fill: 0.0,
            prim_refs: self.prim_indices.len() as u64,
        }
    }

    /// SAH cost with the quantized boxes (the decoded `bvh8`'s, thesis eq. 4 per wide node).
    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        self.decoded().sah_cost(cost)
    }

    /// The decoded tree's structure (each node and leaf reached once, triangles referenced as
    /// `refs` says, leaf boxes around their triangles) and every inner slot's box around all the
    /// triangles below it. Quantized boxes need not nest (a child's grid is laid on its exact box,
    /// not on the rounded-up box its parent stores), so nesting is not required.
    pub fn validate_refs(&self, tris: &[Triangle], refs: Refs) -> Result<(), String> {
        self.decoded().validate_unnested(tris, refs)
    }

    fn view<'a>(&'a self, store: &'a PackStore) -> View<'a, Self> {
        View { src: self, leaves: self.leaves.len(), packs: &store.packs, root: self.root_bounds, nodes: self.nodes.len() }
    }

    /// Closest hits with counters (exact f64 triangle test, scalar box test; untimed).
    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        let store = self.store(tris);
        wide::trace_view::<8, _>(&self.view(&store), rays)
    }

    /// The timed path: hits only, the watertight f32 test, AVX2 box tests where the CPU has them.
    pub fn hits(&self, store: &PackStore, rays: &[Ray]) -> Vec<Hit> {
        self.hits_with::<Watertight>(store, rays, Simd::Best)
    }

    pub fn hits_with<T: TriTest>(&self, store: &PackStore, rays: &[Ray], simd: Simd) -> Vec<Hit> {
        wide::hits_view8::<T, _>(&self.view(store), rays, simd.resolve(8))
    }
}

impl NodeSource<8> for CwBvh {
    type Buf = [f32; 48];
    fn buf() -> [f32; 48] {
        [0.0; 48]
    }
    #[inline(always)]
    fn node<'a>(&'a self, n: usize, buf: &'a mut [f32; 48]) -> Option<(&'a [f32], u32)> {
        let node = self.nodes.get(n)?;
        node.decode(buf);
        Some((&buf[..], node.used()))
    }
    #[inline(always)]
    unsafe fn code(&self, n: usize, slot: usize) -> u32 {
        debug_assert!(n < self.nodes.len() && slot < 8);
        // SAFETY: the caller read node `n` (`node` returned Some); `CwNode::code` indexes `meta`
        // with `slot < 8`.
        unsafe { self.nodes.get_unchecked(n) }.code(slot)
    }
    #[inline(always)]
    fn first(&self, code: u32) -> Option<usize> {
        self.leaves.get((code & !LEAF_BIT) as usize).map(|l| l[2] as usize)
    }
    #[inline(always)]
    fn addr(&self, code: u32) -> Option<*const u8> {
        self.nodes.get(code as usize).map(|n| n as *const CwNode as *const u8)
    }
    const NODE_BYTES: usize = std::mem::size_of::<CwNode>();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_cover_the_extent_with_the_smallest_power_of_two() {
        for extent in [1e-40f64, 1e-30, 1e-3, 0.5, 1.0, 255.0, 256.0, 1e6, 1e36] {
            let k = step_exponent(extent);
            assert!(255.0 * 2f64.powi(k) >= extent, "{extent}");
            assert!(k == K_MIN || 255.0 * 2f64.powi(k - 1) < extent, "{extent}");
            let n = CwNode { e: [(k - K_MIN) as u8; 3], ..CwNode::default() };
            assert_eq!(n.step(0) as f64, 2f64.powi(k), "{extent}");
        }
        assert_eq!(step_exponent(0.0), K_MIN);
        assert_eq!(step_exponent(6e38), K_MAX);
    }

    #[test]
    fn quantized_bounds_contain_the_box_in_f32() {
        let (p, s) = (-3.7f32, 2f32.powi(-4));
        for (lo, hi) in [(-3.7f32, -3.7f32), (-3.7, 12.2), (0.1, 0.1000001), (12.0, 12.2)] {
            let (ql, qh) = quantize(p, s, lo, hi).unwrap();
            assert!(p + ql as f32 * s <= lo && p + qh as f32 * s >= hi, "{lo} {hi}");
            assert!(ql <= qh);
        }
    }

    #[test]
    fn used_mask_reads_bit_seven_of_each_meta_byte() {
        let mut n = CwNode::default();
        n.meta = [USED, 0, USED | 3, 0, 0, 0, 0, USED | 1];
        assert_eq!(n.used(), 0b1000_0101);
    }
}
