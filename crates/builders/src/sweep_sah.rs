//! Full-sweep SAH over all three axes with the presorted O(n log n) scheme (Frantal 2019 3.3.1,
//! after Wald and Havran 2006 and Ganestam et al. 2015): primitives are sorted once per axis by
//! centroid; the three sorted arrays are kept for the whole build; after a split is chosen on one
//! axis, the other two arrays are stable-partitioned by a per-primitive side flag, so every array
//! stays sorted within each child and no node ever sorts again.
//!
//! Each sorted array holds 32-byte records (box + index) rather than bare indices, so the sweeps and
//! partitions stream through memory instead of gathering boxes by index.
//!
//! Bonsai (thesis 3.3.2) reuses the sweep twice: [`build_local`] builds a mini tree over a subset of
//! the primitives, [`build_weighted`] the top tree over mini-tree roots, each item weighted by its
//! primitive count in the SAH (the record's spare word holds the weight, so the plain build's records
//! and loops are unchanged).
use crate::simd_box::BoxA;
use crate::topdown::{build_nodes, Range};
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_params::Method;
use glam::Vec3A;

pub const METHOD: Method = Method::new(
    "sweep-sah",
    "full-sweep SAH over all three axes (thesis 3.3.1)",
    "thesis 3.3.1",
    &[LEAF],
);

#[derive(Clone, Copy, Debug)]
#[repr(C)]
struct SweepRef {
    min: Vec3,
    idx: u32,
    max: Vec3,
    /// Item weight for the weighted sweep (Bonsai top tree); 0 and unused otherwise.
    w: u32,
}

impl SweepRef {
    #[inline(always)]
    fn min(&self) -> Vec3A {
        self.min.into()
    }
    #[inline(always)]
    fn max(&self) -> Vec3A {
        self.max.into()
    }
}

/// The best full-sweep split of a node: the first `n_left` primitives of the array sorted on `axis`.
#[derive(Clone, Copy, Debug)]
struct SweepSplit {
    axis: usize,
    n_left: usize,
    /// `SA_L * n_L + SA_R * n_R` (half areas scaled by `Sweeper::scale`: see
    /// `BoxA::half_area_scaled`).
    cost: f32,
}

/// Builder state: the three presorted arrays and scratch buffers, allocated once per build.
struct Sweeper {
    sorted: [Vec<SweepRef>; 3],
    /// Right-sweep half areas: `right_area[i]` is the area of elements `i..` of the current range.
    right_area: Vec<f32>,
    /// Scratch for the stable partition (right part).
    tmp: Vec<SweepRef>,
    /// Side flag per primitive index (thesis 3.3.1).
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
    let (nodes, prim_indices) = build_local(boxes.len(), |i| centers[i], |i| boxes[i], cfg);
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
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    let mut s = Sweeper::new(n, center, &bounds, |_| 0);
    let mut root_bounds = BoxA::EMPTY;
    for i in 0..n {
        let b = bounds(i);
        root_bounds.grow(b.min.into(), b.max.into());
    }
    let root = Range::root(n, root_bounds, BoxA::EMPTY);
    let nodes = build_nodes(n, root, |r| s.split::<false>(r, cfg));
    // All three arrays hold the same primitive set in every node range; take the x-sorted one.
    (nodes, s.sorted[0].iter().map(|p| p.idx).collect())
}

/// The weighted full sweep of the Bonsai top tree (thesis 3.3.2): the items are mini-tree roots with
/// their boxes, centred at the box centres, and the SAH counts each with its primitive count
/// (`SA_L W_L + SA_R W_R`). Items are never grouped into a leaf (a leaf holds exactly one item: an
/// item is a whole subtree), so there is no leaf test. Returns the nodes (leaf `first` indexes the
/// returned order) and the items' order in the leaves.
pub(crate) fn build_weighted(boxes: &[Aabb], weights: &[u32]) -> (Vec<Node>, Vec<u32>) {
    assert_eq!(boxes.len(), weights.len(), "one weight per item");
    let n = boxes.len();
    assert!(n < u32::MAX as usize, "item indices are u32");
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    let mut s = Sweeper::new(n, |i| boxes[i].center(), |i| boxes[i], |i| weights[i]);
    let mut root_bounds = BoxA::EMPTY;
    for b in boxes {
        root_bounds.grow(b.min.into(), b.max.into());
    }
    let root = Range::root(n, root_bounds, BoxA::EMPTY);
    // leaf = 1: single-item leaves, no SAH leaf test (the cost constants are then unused).
    let single = TopDownConfig {
        leaf: 1,
        ..Default::default()
    };
    let nodes = build_nodes(n, root, |r| s.split::<true>(r, &single));
    (nodes, s.sorted[0].iter().map(|p| p.idx).collect())
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

impl Sweeper {
    #[inline]
    fn new(
        n: usize,
        center: impl Fn(usize) -> Vec3,
        bounds: impl Fn(usize) -> Aabb,
        weight: impl Fn(usize) -> u32,
    ) -> Self {
        let mut keys: Vec<u64> = Vec::with_capacity(n);
        let sorted = std::array::from_fn(|axis| {
            keys.clear();
            keys.extend((0..n).map(|i| sort_key(center(i)[axis], i as u32)));
            keys.sort_unstable();
            keys.iter()
                .map(|&k| {
                    let i = k as u32;
                    let b = bounds(i as usize);
                    SweepRef {
                        min: b.min,
                        idx: i,
                        max: b.max,
                        w: weight(i as usize),
                    }
                })
                .collect()
        });
        let first: &Vec<SweepRef> = &sorted[0];
        let m = first
            .iter()
            .map(|p| p.min.abs().max(p.max.abs()).max_element())
            .filter(|m| m.is_finite())
            .fold(0.0f32, f32::max);
        let scale = Vec3A::splat(crate::simd_box::pow2_for_max(m));
        Sweeper {
            sorted,
            right_area: vec![0.0; n],
            tmp: Vec::with_capacity(n),
            is_left: vec![false; n],
            scale,
        }
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
                acc.grow(a[i].min(), a[i].max());
                right_area[i] = acc.half_area_scaled(self.scale);
            }
            let mut acc = BoxA::EMPTY;
            // Weighted: integer prefix sums (exact), converted per candidate.
            let total: u64 = if WEIGHTED {
                a.iter().map(|p| p.w as u64).sum()
            } else {
                0
            };
            let mut w_l: u64 = 0;
            for i in 0..n - 1 {
                acc.grow(a[i].min(), a[i].max());
                let cost = if WEIGHTED {
                    w_l += a[i].w as u64;
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
        let chosen = &self.sorted[best.axis];
        let (mut lb, mut rb) = (BoxA::EMPTY, BoxA::EMPTY);
        for p in &chosen[r.begin..mid] {
            self.is_left[p.idx as usize] = true;
            lb.grow(p.min(), p.max());
        }
        for p in &chosen[mid..r.end] {
            self.is_left[p.idx as usize] = false;
            rb.grow(p.min(), p.max());
        }
        // Stable partition of the other two arrays: lefts compact in place (writes never pass
        // reads), rights go through scratch and are copied back behind them.
        for axis in (0..3).filter(|&a| a != best.axis) {
            let arr = &mut self.sorted[axis][r.begin..r.end];
            self.tmp.clear();
            let mut l = 0;
            for i in 0..n {
                let p = arr[i];
                if self.is_left[p.idx as usize] {
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
