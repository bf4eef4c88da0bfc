//! Full-sweep SAH over all three axes with the presorted O(n log n) scheme (Frantal 2019 3.3.1,
//! after Wald and Havran 2006 and Ganestam et al. 2015): primitives are sorted once per axis by
//! centroid; the three sorted arrays are kept for the whole build; after a split is chosen on one
//! axis, the other two arrays are stable-partitioned by a per-primitive side flag, so every array
//! stays sorted within each child and no node ever sorts again.
//!
//! The sorted arrays hold bare 4-byte indices and the sweeps gather the boxes by index: 12 bytes per
//! primitive for the three orders instead of 96 for 32-byte records (box + index), which made this
//! builder's peak 220 bytes per triangle on the dragon (issue 19 asks at most 150). The gathers cost
//! little: a node's boxes are read six times (two sweeps on three axes), the first read brings
//! them into cache for the next ones below the top levels, and the loads are independent (the
//! index array streams), so they overlap.
//!
//! Bonsai (thesis 3.3.2) reuses the sweep twice: [`build_local`] builds a mini tree over a subset of
//! the primitives, [`build_weighted`] the top tree over mini-tree roots, each item weighted by its
//! primitive count in the SAH.
use crate::simd_box::BoxA;
use crate::topdown::{build_nodes, Range};
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_params::Method;
use glam::Vec3A;
use std::borrow::Cow;

pub const METHOD: Method = Method::new(
    "sweep-sah",
    "full-sweep SAH over all three axes (thesis 3.3.1)",
    "thesis 3.3.1",
    &[LEAF],
)
// 2: the same trees; the sorted arrays hold indices (121 instead of 220 bytes per triangle of peak
//    on the dragon, another build time): build times and memory re-measured.
.with_version(2);

/// The best full-sweep split of a node: the first `n_left` primitives of the array sorted on `axis`.
#[derive(Clone, Copy, Debug)]
struct SweepSplit {
    axis: usize,
    n_left: usize,
    /// `SA_L * n_L + SA_R * n_R` (half areas scaled by `Sweeper::scale`: see
    /// `BoxA::half_area_scaled`).
    cost: f32,
}

/// Builder state: the items' boxes, the three presorted index arrays and scratch buffers, allocated
/// once per build.
struct Sweeper<'a> {
    boxes: Cow<'a, [Aabb]>,
    /// Item weights for the weighted sweep (Bonsai top tree); empty otherwise.
    weights: &'a [u32],
    /// Item indices sorted by centroid on each axis, stable-partitioned at every split.
    sorted: [Vec<u32>; 3],
    /// Right-sweep half areas: `right_area[i]` is the area of elements `i..` of the current range.
    right_area: Vec<f32>,
    /// Scratch for the stable partition (right part).
    tmp: Vec<u32>,
    /// Side flag per item (thesis 3.3.1).
    is_left: Vec<bool>,
    /// `simd_box::pow2_for_max` of the items: areas are `BoxA::half_area_scaled` by it.
    scale: Vec3A,
}

pub fn build(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    assert_eq!(
        boxes.len(),
        centers.len(),
        "builders need one centre per primitive box"
    );
    assert!(boxes.len() < u32::MAX as usize, "primitive indices are u32");
    let (nodes, prim_indices) = sweep(Cow::Borrowed(boxes), |i| centers[i], &[], cfg);
    Bvh {
        nodes,
        prim_indices,
    }
}

/// The full sweep over `n` items given by accessors (item `i`: centre, box): the node array (leaf
/// `first` indexes the returned order) and the items' order in the leaves. [`build`] is this over
/// all primitives; Bonsai (thesis 3.3.2) calls it per mini-tree primitive set.
#[inline]
pub(crate) fn build_local(
    n: usize,
    center: impl Fn(usize) -> Vec3,
    bounds: impl Fn(usize) -> Aabb,
    cfg: &TopDownConfig,
) -> (Vec<Node>, Vec<u32>) {
    assert!(n < u32::MAX as usize, "primitive indices are u32");
    sweep(Cow::Owned((0..n).map(bounds).collect()), center, &[], cfg)
}

/// The weighted full sweep of the Bonsai top tree (thesis 3.3.2): the items are mini-tree roots with
/// their boxes, centred at the box centres, and the SAH counts each with its primitive count
/// (`SA_L W_L + SA_R W_R`). Items are never grouped into a leaf (a leaf holds exactly one item: an
/// item is a whole subtree), so there is no leaf test. Returns the nodes (leaf `first` indexes the
/// returned order) and the items' order in the leaves.
pub(crate) fn build_weighted(boxes: &[Aabb], weights: &[u32]) -> (Vec<Node>, Vec<u32>) {
    assert_eq!(boxes.len(), weights.len(), "one weight per item");
    assert!(boxes.len() < u32::MAX as usize, "item indices are u32");
    // leaf = 1: single-item leaves, no SAH leaf test (the cost constants are then unused).
    let single = TopDownConfig {
        leaf: 1,
        ..Default::default()
    };
    sweep(Cow::Borrowed(boxes), |i| boxes[i].center(), weights, &single)
}

/// The sweep build over `boxes` (weighted if `weights` is not empty).
fn sweep(
    boxes: Cow<'_, [Aabb]>,
    center: impl Fn(usize) -> Vec3,
    weights: &[u32],
    cfg: &TopDownConfig,
) -> (Vec<Node>, Vec<u32>) {
    let n = boxes.len();
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    let mut root_bounds = BoxA::EMPTY;
    for b in boxes.iter() {
        root_bounds.grow(b.min.into(), b.max.into());
    }
    let mut s = Sweeper::new(boxes, center, weights);
    let root = Range::root(n, root_bounds, BoxA::EMPTY);
    let nodes = if weights.is_empty() {
        build_nodes(n, root, |r| s.split::<false>(r, cfg))
    } else {
        build_nodes(n, root, |r| s.split::<true>(r, cfg))
    };
    // All three arrays hold the same item set in every node range; take the x-sorted one.
    (nodes, std::mem::take(&mut s.sorted[0]))
}

/// How many items ahead the sweeps prefetch the box they will gather (DRAM latency over the
/// time of one step).
const AHEAD: usize = 24;

/// Prefetches the box of item `order[k]`, if `k` is in range.
#[inline(always)]
fn prefetch(boxes: &[Aabb], order: &[u32], k: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(&i) = order.get(k) {
        if let Some(b) = boxes.get(i as usize) {
            // SAFETY: a prefetch has no architectural effect; the address is in bounds anyway.
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((b as *const Aabb).cast())
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (boxes, order, k);
}

/// Sort key (centroid, index) as one u64: the f32 bits are mapped to an order-preserving u32
/// (total order: -0 < +0, NaNs at the ends), the index breaks ties, so the order is deterministic.
#[inline]
fn sort_key(c: f32, idx: u32) -> u64 {
    let b = c.to_bits();
    let ordered = if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    };
    ((ordered as u64) << 32) | idx as u64
}

impl<'a> Sweeper<'a> {
    #[inline]
    fn new(boxes: Cow<'a, [Aabb]>, center: impl Fn(usize) -> Vec3, weights: &'a [u32]) -> Self {
        let n = boxes.len();
        let mut keys: Vec<u64> = Vec::with_capacity(n);
        let sorted = std::array::from_fn(|axis| {
            keys.clear();
            keys.extend((0..n).map(|i| sort_key(center(i)[axis], i as u32)));
            keys.sort_unstable();
            keys.iter().map(|&k| k as u32).collect()
        });
        drop(keys);
        let m = boxes
            .iter()
            .map(|b| b.min.abs().max(b.max.abs()).max_element())
            .filter(|m| m.is_finite())
            .fold(0.0f32, f32::max);
        let scale = Vec3A::splat(crate::simd_box::pow2_for_max(m));
        Sweeper {
            boxes,
            weights,
            sorted,
            right_area: vec![0.0; n],
            tmp: Vec::with_capacity(n),
            is_left: vec![false; n],
            scale,
        }
    }

    /// Item `i`'s box as SIMD vectors.
    #[inline(always)]
    fn bounds(&self, i: u32) -> (Vec3A, Vec3A) {
        let b = &self.boxes[i as usize];
        (b.min.into(), b.max.into())
    }

    /// Evaluates all `n - 1` candidates on all three axes (thesis 3.3.1 with eq. 2 costs). Ties go
    /// to the lowest axis, then the lowest position. `WEIGHTED`: an item counts `w` times (thesis
    /// 3.3.2, the Bonsai top tree); otherwise once.
    fn find_split<const WEIGHTED: bool>(&mut self, r: &Range) -> SweepSplit {
        let n = r.len();
        // Fallback if every cost is NaN (non-finite input): a valid median split on x.
        let mut best = SweepSplit {
            axis: 0,
            n_left: n / 2,
            cost: f32::INFINITY,
        };
        for axis in 0..3 {
            let a = &self.sorted[axis][r.begin..r.end];
            let right_area = &mut self.right_area[..n];
            let mut acc = BoxA::EMPTY;
            for i in (1..n).rev() {
                prefetch(&self.boxes, a, i.wrapping_sub(AHEAD));
                let b = &self.boxes[a[i] as usize];
                acc.grow(b.min.into(), b.max.into());
                right_area[i] = acc.half_area_scaled(self.scale);
            }
            let mut acc = BoxA::EMPTY;
            // Weighted: integer prefix sums (exact), converted per candidate.
            let total: u64 = if WEIGHTED {
                a.iter().map(|&p| self.weights[p as usize] as u64).sum()
            } else {
                0
            };
            let mut w_l: u64 = 0;
            for i in 0..n - 1 {
                prefetch(&self.boxes, a, i + AHEAD);
                let b = &self.boxes[a[i] as usize];
                acc.grow(b.min.into(), b.max.into());
                let cost = if WEIGHTED {
                    w_l += self.weights[a[i] as usize] as u64;
                    acc.half_area_scaled(self.scale) * w_l as f32 + right_area[i + 1] * (total - w_l) as f32
                } else {
                    let n_l = (i + 1) as f32;
                    acc.half_area_scaled(self.scale) * n_l + right_area[i + 1] * (n as f32 - n_l)
                };
                if cost < best.cost {
                    best = SweepSplit {
                        axis,
                        n_left: i + 1,
                        cost,
                    };
                }
            }
        }
        best
    }

    /// The split decision for one node: `None` makes a leaf.
    fn split<const WEIGHTED: bool>(
        &mut self,
        r: &Range,
        cfg: &TopDownConfig,
    ) -> Option<(Range, Range)> {
        let n = r.len();
        if n <= cfg.max_leaf() {
            return None;
        }
        // The weighted sweep only runs with single-item leaves (no leaf test below).
        debug_assert!(!WEIGHTED || cfg.forced_single());
        let best = self.find_split::<WEIGHTED>(r);
        let node_area = r.bounds.half_area_scaled(self.scale) as f64;
        if !cfg.forced_single() && cfg.sah_prefers_leaf(n, node_area, best.cost as f64) {
            return None;
        }
        let mid = r.begin + best.n_left;
        // Flag sides from the chosen axis' array, which is already partitioned (it is sorted).
        let (mut lb, mut rb) = (BoxA::EMPTY, BoxA::EMPTY);
        let chosen = &self.sorted[best.axis][..r.end];
        for k in r.begin..r.end {
            prefetch(&self.boxes, chosen, k + AHEAD);
            let p = chosen[k];
            let (min, max) = self.bounds(p);
            let left = k < mid;
            self.is_left[p as usize] = left;
            if left {
                lb.grow(min, max);
            } else {
                rb.grow(min, max);
            }
        }
        // Stable partition of the other two arrays: lefts compact in place (writes never pass
        // reads), rights go through scratch and are copied back behind them.
        for axis in (0..3).filter(|&a| a != best.axis) {
            let arr = &mut self.sorted[axis][r.begin..r.end];
            self.tmp.clear();
            let mut l = 0;
            for i in 0..n {
                let p = arr[i];
                if self.is_left[p as usize] {
                    arr[l] = p;
                    l += 1;
                } else {
                    self.tmp.push(p);
                }
            }
            debug_assert_eq!(l, best.n_left);
            arr[l..].copy_from_slice(&self.tmp);
        }
        Some(r.split(mid, (lb, BoxA::EMPTY), (rb, BoxA::EMPTY)))
    }
}
