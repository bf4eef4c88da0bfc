//! LBVH: Karras 2012 binary radix tree over sorted codes (thesis 2.3.4).
//!
//! With `n` sorted keys, internal node `i` (of `n - 1`) covers a key range that starts or ends at
//! key `i`; its direction, the far end of the range and its split are found from the common-prefix
//! length `delta` alone (Karras 2012 section 3, figure 4), so every internal node is computed
//! independently (here with rayon) and the output does not depend on the thread count.
use crate::bottomup::{finish, ClusterTree};
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh, CostParams};
use bvhlab_params::Method;

pub const METHOD: Method = Method::new(
    "lbvh",
    "LBVH: binary radix tree over sorted codes (Karras 2012; thesis 2.3.4), then SAH compaction",
    "Karras 2012; thesis 2.3.4",
    &[],
)
// 2: the same trees; the compaction reads the cluster tree (`build_compacted`, less memory, another
//    build time): build times re-measured.
.with_version(2);
use rayon::prelude::*;

/// Rayon grain: one internal node is a few dozen instructions.
const GRAIN: usize = 4096;

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes) -> Bvh {
    build_in(boxes, sorted, None)
}

/// [`build`] followed by the SAH compaction (`bvhlab_bvh::collapse`), the same bytes, without the
/// uncompacted layout in memory.
pub fn build_compacted(boxes: &[Aabb], sorted: &SortedCodes, cost: CostParams) -> Bvh {
    build_in(boxes, sorted, Some(cost))
}

fn build_in(boxes: &[Aabb], sorted: &SortedCodes, cost: Option<CostParams>) -> Bvh {
    let n = sorted.len("lbvh");
    if n == 0 {
        return Bvh::default();
    }
    // Karras' construction is only a tree over sorted keys.
    debug_assert!(
        sorted.codes.windows(2).all(|w| w[0] <= w[1]),
        "lbvh: codes not sorted"
    );
    let children = radix_tree(sorted.codes);
    // Leaf i is the i-th key (primitive order[i]); internal node i has id n + i; the root is
    // internal node 0 (Karras 2012 section 3), or leaf 0 when there is only one primitive.
    let root = if n == 1 { 0 } else { n as u32 };
    let tree = ClusterTree { leaf_prims: sorted.order, children: &children, root };
    finish(boxes, &tree, cost)
}

/// Children of the `n - 1` internal nodes of the binary radix tree over `codes` (non-decreasing),
/// in cluster-tree ids: leaf `k` is `k`, internal node `k` is `n + k`.
pub(crate) fn radix_tree(codes: &[u64]) -> Vec<[u32; 2]> {
    let n = codes.len();
    if n < 2 {
        return Vec::new();
    }
    (0..n - 1)
        .into_par_iter()
        .with_min_len(GRAIN)
        .map(|i| internal_node(codes, i))
        .collect()
}

/// Length of the longest common prefix of keys `i` and `j`, or -1 when `j` is outside the array.
/// Equal codes are made distinct by appending the key position (Karras 2012 section 4): their
/// prefix is 64 bits plus the common prefix of the two indices. Any constant offset is harmless
/// (only comparisons of `delta` values matter), so the unused high bits of short codes need no care.
#[inline(always)]
fn delta(codes: &[u64], i: usize, j: i64) -> i32 {
    if j < 0 || j >= codes.len() as i64 {
        return -1;
    }
    let (a, b) = (codes[i], codes[j as usize]);
    if a != b {
        (a ^ b).leading_zeros() as i32
    } else {
        64 + ((i as u64) ^ (j as u64)).leading_zeros() as i32
    }
}

/// Karras 2012 figure 4 for internal node `i` (0 <= i < n - 1, n >= 2).
fn internal_node(codes: &[u64], i: usize) -> [u32; 2] {
    let n = codes.len();
    let ii = i as i64;
    // Direction of the range: towards the neighbour sharing the longer prefix.
    let d: i64 = if delta(codes, i, ii + 1) > delta(codes, i, ii - 1) {
        1
    } else {
        -1
    };
    // Upper bound for the range length by exponential search: every key in the range shares more
    // than `delta_min` bits with key i.
    let delta_min = delta(codes, i, ii - d);
    let mut l_max: i64 = 2;
    while delta(codes, i, ii + l_max * d) > delta_min {
        l_max *= 2;
    }
    // The other end by binary search.
    let mut l: i64 = 0;
    let mut t = l_max / 2;
    while t >= 1 {
        if delta(codes, i, ii + (l + t) * d) > delta_min {
            l += t;
        }
        t /= 2;
    }
    let j = ii + l * d;
    // Split: the last key sharing more than `delta_node` bits with key i, by binary search.
    let delta_node = delta(codes, i, j);
    let mut s: i64 = 0;
    let mut t = l;
    loop {
        t = (t + 1) / 2; // ceil(t / 2)
        if delta(codes, i, ii + (s + t) * d) > delta_node {
            s += t;
        }
        if t <= 1 {
            break;
        }
    }
    let gamma = ii + s * d + d.min(0);
    let (lo, hi) = (ii.min(j), ii.max(j));
    let left = if lo == gamma { gamma } else { n as i64 + gamma };
    let right = if hi == gamma + 1 {
        gamma + 1
    } else {
        n as i64 + gamma + 1
    };
    [left as u32, right as u32]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every internal node and leaf has exactly one parent, except the root (internal node 0), and
    /// each node's leaves are a contiguous key range: checked by walking from the root.
    fn check(codes: &[u64]) {
        let n = codes.len();
        let ch = radix_tree(codes);
        assert_eq!(ch.len(), n.saturating_sub(1));
        if n < 2 {
            return;
        }
        let mut seen = vec![0u32; 2 * n - 1];
        // (id) -> leaf range
        let mut stack = vec![n as u32];
        let mut leaves = Vec::new();
        while let Some(id) = stack.pop() {
            seen[id as usize] += 1;
            assert!(
                seen[id as usize] == 1,
                "node {id} reached twice in {codes:?}"
            );
            if (id as usize) < n {
                leaves.push(id);
            } else {
                let [l, r] = ch[id as usize - n];
                stack.push(r);
                stack.push(l);
            }
        }
        // Depth-first left-to-right visits the leaves in key order: the tree respects the sort.
        assert_eq!(leaves, (0..n as u32).collect::<Vec<_>>(), "{codes:?}");
    }

    #[test]
    fn radix_tree_is_a_tree_in_key_order() {
        check(&[]);
        check(&[5]);
        check(&[1, 2]);
        check(&[7, 7]);
        check(&[1, 2, 4, 5, 19, 24, 25, 30]); // Karras 2012 figure 3
        check(&[3; 17]);
        check(&[0, 0, 0, 1, 1, 8, 8, 8, 8, 9, u64::MAX >> 4, u64::MAX >> 4]);
        let mut r = bvhlab_geom::rng::SplitMix64(9);
        for len in [3usize, 10, 100, 1000] {
            let mut c: Vec<u64> = (0..len).map(|_| r.next_u64() % 64).collect();
            c.sort_unstable();
            check(&c);
        }
    }

    #[test]
    fn karras_figure_3_root_split() {
        // Keys 00001 00010 00100 00101 10011 11000 11001 11110: the root splits between 3 and 4.
        let ch = radix_tree(&[1, 2, 4, 5, 19, 24, 25, 30]);
        assert_eq!(ch[0], [8 + 3, 8 + 4]);
    }
}
