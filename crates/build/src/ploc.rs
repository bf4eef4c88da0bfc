//! Parallel Locally-Ordered Clustering (Meister and Bittner 2018, thesis 3.6).
//!
//! Clusters start as the primitives in code order. Each iteration has three phases separated by
//! barriers (thesis 3.6.1): (a) every cluster finds its approximate nearest neighbour among the `r`
//! clusters on each side, the distance being the surface area of the union of the two boxes;
//! (b) mutual nearest neighbours merge, the lower index performs the merge and the new cluster
//! takes its place, the higher index becomes invalid; (c) the valid clusters are compacted into a
//! second buffer at positions given by an exclusive prefix scan, and the buffers are swapped.
//! Iterations repeat until one cluster is left.
//!
//! Determinism: each phase is a pure function of the previous buffer. The nearest neighbour is the
//! minimum of (distance, index) (equal distances: the smaller index wins, as the paper proposes),
//! which does not depend on evaluation order; new inner-node ids come from the same prefix scan as
//! the compaction (n + merges before this iteration + merges before this cluster in this
//! iteration), never from an atomic counter. So the output is bit-identical at any thread count.
use crate::bottomup::{to_bvh, ClusterTree};
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlocConfig {
    /// Nearest-neighbour search radius r (thesis table 6; PL1/PL2/PL3 = 10/25/100).
    pub radius: u32,
}

/// Clusters per parallel task of the neighbour search. Chunking never changes the result (see the
/// module comment), only the cost: each chunk recomputes the at most r(r+1)/2 distances across its
/// left border, and 2048 clusters keep a chunk's working set (about 50 KB) near L1.
const CHUNK: usize = 2048;

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes, cfg: &PlocConfig) -> Bvh {
    let n = sorted.order.len();
    assert_eq!(sorted.codes.len(), n, "ploc: codes and order differ in length");
    if n == 0 {
        return Bvh::default();
    }
    let (children, root) = cluster(boxes, sorted.order, cfg.radius.max(1) as usize);
    to_bvh(boxes, &ClusterTree { leaf_prims: sorted.order, children: &children, root })
}

/// `a < b ? a : b`: one `minps` (Rust's `f32::min` adds NaN handling the hot loop does not need).
#[inline(always)]
fn mn(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}
#[inline(always)]
fn mx(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Cluster boxes as six coordinate arrays (min x y z, max x y z), so the distance kernel runs over
/// consecutive clusters in SIMD lanes.
#[derive(Clone, Default)]
struct Boxes {
    c: [Vec<f32>; 6],
}

impl Boxes {
    fn with_len(n: usize) -> Boxes {
        Boxes { c: std::array::from_fn(|_| vec![0.0; n]) }
    }
}

/// Power-of-two factor that brings every coordinate into [-1, 1] when the scene is so large that
/// union areas could overflow f32 (|x| > 2^32); 1 otherwise. Scaling by a power of two is exact,
/// so distances keep their order (up to underflow of tiny extents, which only adds ties).
fn area_scale(boxes: &[Aabb]) -> f32 {
    let m = boxes
        .par_iter()
        .with_min_len(CHUNK)
        .map(|b| b.min.abs().max(b.max.abs()).max_element())
        .filter(|m| m.is_finite())
        .reduce(|| 0.0f32, f32::max);
    if m <= 4294967296.0 {
        return 1.0;
    }
    let e = m.log2().ceil() as i32; // m <= 2^e, e <= 128
    // 2^-126 is the smallest normal power of two; it leaves |x| <= 4, still far from overflow.
    2f32.powi(-(e.min(126)))
}

/// The merges of PLOC over primitives in code order: returns `children` of a cluster tree whose
/// leaf `k` is the k-th primitive in code order and whose inner node `n + m` is the m-th merge,
/// and the root id.
fn cluster(boxes: &[Aabb], order: &[u32], r: usize) -> (Vec<[u32; 2]>, u32) {
    let n = order.len();
    let mut children = vec![[0u32; 2]; n.saturating_sub(1)];
    if n < 2 {
        return (children, 0);
    }
    let s = area_scale(boxes);
    // The two cluster buffers (boxes and node ids), swapped after every iteration.
    let mut cur = Boxes::with_len(n);
    {
        let [a, b, c, d, e, f] = &mut cur.c;
        (a, b, c, d, e, f, order).into_par_iter().with_min_len(CHUNK).for_each(|(a, b, c, d, e, f, &p)| {
            let bx = &boxes[p as usize];
            (*a, *b, *c) = (bx.min.x * s, bx.min.y * s, bx.min.z * s);
            (*d, *e, *f) = (bx.max.x * s, bx.max.y * s, bx.max.z * s);
        });
    }
    let mut cur_id: Vec<u32> = (0..n as u32).collect();
    let mut next = cur.clone();
    let mut next_id = cur_id.clone();
    let mut nn = vec![0u32; n];
    // Per-chunk (kept clusters, merges).
    let mut counts: Vec<(usize, usize)> = Vec::with_capacity(n.div_ceil(CHUNK));
    let mut merged = 0usize; // merges done so far = next free inner-node slot
    let mut c = n;
    while c > 1 {
        let cl: [&[f32]; 6] = std::array::from_fn(|a| &cur.c[a][..c]);
        let ids = &cur_id[..c];
        // (a) Nearest neighbours.
        nn[..c].par_chunks_mut(CHUNK).enumerate().for_each(|(k, out)| nearest(&cl, k * CHUNK, out, r));
        let nn = &nn[..c];
        // (b) + (c): per chunk the clusters it keeps and the merges it performs, their exclusive
        // prefix sums (positions in the new buffer, inner-node ids), then the writes.
        counts.clear();
        nn.par_chunks(CHUNK)
            .enumerate()
            .map(|(k, part)| {
                let (mut keep, mut merge) = (0, 0);
                for (o, &j) in part.iter().enumerate() {
                    let i = (k * CHUNK + o) as u32;
                    let mutual = nn[j as usize] == i;
                    keep += (!mutual || i < j) as usize;
                    merge += (mutual && i < j) as usize;
                }
                (keep, merge)
            })
            .collect_into_vec(&mut counts);
        // Split the output buffers into the disjoint slices each chunk writes (no unsafe needed).
        let (mut keep_at, mut merge_at) = (0usize, merged);
        let mut tasks = Vec::with_capacity(counts.len());
        {
            let mut dst: [&mut [f32]; 6] = next.c.each_mut().map(|v| &mut v[..]);
            let mut dst_id = &mut next_id[..];
            let mut ch = &mut children[merged..];
            for (k, &(keep, merge)) in counts.iter().enumerate() {
                let part: [&mut [f32]; 6] = std::array::from_fn(|a| {
                    let (x, rest) = std::mem::take(&mut dst[a]).split_at_mut(keep);
                    dst[a] = rest;
                    x
                });
                let (b, rest) = std::mem::take(&mut dst_id).split_at_mut(keep);
                dst_id = rest;
                let (m, rest) = std::mem::take(&mut ch).split_at_mut(merge);
                ch = rest;
                tasks.push((k, part, b, m, merge_at));
                keep_at += keep;
                merge_at += merge;
            }
        }
        tasks.into_par_iter().for_each(|(k, dst, dst_id, ch, first_merge)| {
            let (mut w, mut m) = (0usize, 0usize);
            for i in k * CHUNK..(k * CHUNK + CHUNK).min(c) {
                let j = nn[i] as usize;
                if nn[j] as usize != i {
                    for a in 0..6 {
                        dst[a][w] = cl[a][i];
                    }
                    dst_id[w] = ids[i];
                    w += 1;
                } else if i < j {
                    // The lower index merges; the new cluster takes its place (thesis 3.6.1).
                    for a in 0..3 {
                        dst[a][w] = mn(cl[a][i], cl[a][j]);
                        dst[a + 3][w] = mx(cl[a + 3][i], cl[a + 3][j]);
                    }
                    dst_id[w] = (n + first_merge + m) as u32;
                    ch[m] = [ids[i], ids[j]];
                    w += 1;
                    m += 1;
                }
            }
            debug_assert_eq!((w, m), (dst_id.len(), ch.len()));
        });
        // Mutual pairs always exist (the pair minimizing (distance, lower index, higher index) over
        // all candidate pairs is one), so every iteration makes progress.
        debug_assert!(merge_at > merged);
        merged = merge_at;
        c = keep_at;
        std::mem::swap(&mut cur, &mut next);
        std::mem::swap(&mut cur_id, &mut next_id);
    }
    debug_assert_eq!(merged, n - 1);
    (children, cur_id[0])
}

/// Nearest neighbours of clusters `base .. base + out.len()` among the `r` clusters on each side.
///
/// Every pair distance is computed once and updates both ends: for each offset k = 1..=r, pairs
/// (i, i + k) over consecutive i (SIMD lanes). The best right neighbour of i takes a candidate only
/// when strictly closer (offsets grow, so equal distances keep the smaller index); the best left
/// neighbour of j = i + k takes it when closer or equal (offsets grow, so the index i shrinks).
/// Then a left candidate wins ties against a right one: overall, equal distances go to the smaller
/// index (Meister and Bittner 2018), whatever the chunking. Pairs with an end left of `base` are
/// recomputed here (at most r(r+1)/2) so that chunks are independent.
fn nearest(cl: &[&[f32]; 6], base: usize, out: &mut [u32], r: usize) {
    let c = cl[0].len();
    let lo = base.saturating_sub(r);
    let hi = base + out.len(); // exclusive
    let top = (hi + r).min(c); // candidates up to top - 1
    // Best right neighbour (distance, index) of i in lo..hi; best left neighbour of j in lo..top.
    let mut rd = vec![f32::INFINITY; hi - lo];
    let mut rj = vec![0u32; hi - lo];
    let mut ld = vec![f32::INFINITY; top - lo];
    let mut lj = vec![0u32; top - lo];
    for k in 1..=r.min(c - 1 - lo) {
        let m = hi.min(c - k) - lo; // pairs (i, i + k) for i in lo..lo + m
        let a: [&[f32]; 6] = std::array::from_fn(|x| &cl[x][lo..lo + m]);
        let b: [&[f32]; 6] = std::array::from_fn(|x| &cl[x][lo + k..lo + k + m]);
        pass(a, b, &mut rd[..m], &mut rj[..m], &mut ld[k..k + m], &mut lj[k..k + m], lo as u32, k as u32);
    }
    for (x, o) in out.iter_mut().enumerate() {
        let i = base + x - lo;
        *o = if ld[i] <= rd[i] { lj[i] } else { rj[i] };
    }
}

/// One offset of [`nearest`]: distances of the pairs (a[t], b[t]) = (i0 + t, i0 + t + k), written
/// without branches so that it vectorizes.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pass(a: [&[f32]; 6], b: [&[f32]; 6], rd: &mut [f32], rj: &mut [u32], ld: &mut [f32], lj: &mut [u32], i0: u32, k: u32) {
    let m = rd.len();
    let a: [&[f32]; 6] = a.map(|s| &s[..m]);
    let b: [&[f32]; 6] = b.map(|s| &s[..m]);
    let (rj, ld, lj) = (&mut rj[..m], &mut ld[..m], &mut lj[..m]);
    for t in 0..m {
        let ex = mx(a[3][t], b[3][t]) - mn(a[0][t], b[0][t]);
        let ey = mx(a[4][t], b[4][t]) - mn(a[1][t], b[1][t]);
        let ez = mx(a[5][t], b[5][t]) - mn(a[2][t], b[2][t]);
        // Half the surface area of the union. Clamping to f32::MAX maps NaN and infinity (only
        // from non-finite input boxes) to one finite value: distances stay totally ordered, so
        // mutual pairs still exist, and every candidate beats the initial infinity.
        let d = mn(ex * ey + ey * ez + ez * ex, f32::MAX);
        let i = i0 + t as u32;
        let closer = d < rd[t];
        rd[t] = if closer { d } else { rd[t] };
        rj[t] = if closer { i + k } else { rj[t] };
        let closer = d <= ld[t];
        ld[t] = if closer { d } else { ld[t] };
        lj[t] = if closer { i } else { lj[t] };
    }
}
