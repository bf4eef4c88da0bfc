//! Primitive references for the in-place builders (spatial median, binned SAH): box, centre and
//! index in one record, so binning and partitioning stream through memory sequentially instead of
//! gathering boxes and centres by index. When every centre is its box's centre (what the pipeline
//! gives: `Scene::boxes_and_centers`) the record is the 32-byte [`BoxRef`], the centre recomputed
//! from the box with the same f32 operations as `Aabb::center` (so the same bits, the same trees);
//! otherwise the 48-byte [`PrimRef`] carries the given centre. The builders are generic over
//! [`Ref`] and pick one per build ([`with_refs`]).
use crate::simd_box::BoxA;
use crate::topdown::Range;
use bvhlab_bvh::{Aabb, Vec3};
use glam::Vec3A;

/// A primitive reference: box, centre and index.
pub(crate) trait Ref: Copy + Send + Sync + std::fmt::Debug {
    fn new(b: &Aabb, c: Vec3, idx: u32) -> Self;
    fn min(&self) -> Vec3A;
    fn max(&self) -> Vec3A;
    fn c(&self) -> Vec3A;
    /// `self.c()[axis]`, the same bits, read as scalars: indexing a `Vec3A` by a run-time axis
    /// compiles to a match (a spill and a branch per primitive in the binning and partition loops).
    fn c_axis(&self, axis: usize) -> f32;
    fn idx(&self) -> u32;
}

/// 32 bytes: box and index; the centre is the box's (see the module doc).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(crate) struct BoxRef {
    /// x, y, z: the box's minimum; w: the primitive index's bits.
    lo: glam::Vec4,
    /// x, y, z: the box's maximum; w: 0.
    hi: glam::Vec4,
}

impl Ref for BoxRef {
    #[inline(always)]
    fn new(b: &Aabb, _: Vec3, idx: u32) -> Self {
        BoxRef { lo: b.min.extend(f32::from_bits(idx)), hi: b.max.extend(0.0) }
    }
    #[inline(always)]
    fn min(&self) -> Vec3A {
        xyz(self.lo)
    }
    #[inline(always)]
    fn max(&self) -> Vec3A {
        xyz(self.hi)
    }
    /// The box centre, computed as `Aabb::center` does (same f32 operations, so the same bits).
    #[inline(always)]
    fn c(&self) -> Vec3A {
        self.min() * 0.5 + self.max() * 0.5
    }
    /// Lane `axis` of [`BoxRef::c`]: the same two products and sum in scalar f32 (IEEE per lane).
    #[inline(always)]
    fn c_axis(&self, axis: usize) -> f32 {
        let (lo, hi): (&[f32; 4], &[f32; 4]) = (self.lo.as_ref(), self.hi.as_ref());
        lo[axis] * 0.5 + hi[axis] * 0.5
    }
    #[inline(always)]
    fn idx(&self) -> u32 {
        self.lo.w.to_bits()
    }
}

/// 48 bytes: box, any centre and index.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PrimRef {
    min: Vec3A,
    max: Vec3A,
    c: Vec3,
    idx: u32,
}

impl Ref for PrimRef {
    #[inline(always)]
    fn new(b: &Aabb, c: Vec3, idx: u32) -> Self {
        PrimRef { min: b.min.into(), max: b.max.into(), c, idx }
    }
    #[inline(always)]
    fn min(&self) -> Vec3A {
        self.min
    }
    #[inline(always)]
    fn max(&self) -> Vec3A {
        self.max
    }
    #[inline(always)]
    fn c(&self) -> Vec3A {
        self.c.into()
    }
    #[inline(always)]
    fn c_axis(&self, axis: usize) -> f32 {
        let c: &[f32; 3] = self.c.as_ref();
        c[axis]
    }
    #[inline(always)]
    fn idx(&self) -> u32 {
        self.idx
    }
}

/// Whether every centre is bit for bit its box's centre (`Aabb::center`), so [`BoxRef`] serves.
/// `parallel`: checked on the thread pool (the parallel builders); else on the calling thread, so
/// a single-thread build stays on one thread.
pub(crate) fn centres_are_box_centres(boxes: &[Aabb], centers: &[Vec3], parallel: bool) -> bool {
    use rayon::prelude::*;
    let same = |(b, c): (&Aabb, &Vec3)| b.center().to_array().map(f32::to_bits) == c.to_array().map(f32::to_bits);
    boxes.len() == centers.len()
        && if parallel {
            boxes.par_iter().zip(centers.par_iter()).with_min_len(1 << 14).all(same)
        } else {
            boxes.iter().zip(centers).all(same)
        }
}

/// Runs a builder generic over [`Ref`] with the smallest reference that holds the input
/// (`parallel`: see [`centres_are_box_centres`]).
macro_rules! with_refs {
    ($boxes:expr, $centers:expr, $parallel:expr, $f:ident($($arg:expr),*)) => {
        if $crate::primref::centres_are_box_centres($boxes, $centers, $parallel) {
            $f::<$crate::primref::BoxRef>($($arg),*)
        } else {
            $f::<$crate::primref::PrimRef>($($arg),*)
        }
    };
}
pub(crate) use with_refs;

/// The x, y, z lanes of `v` with w cleared (w holds an index's bits: kept out of arithmetic, where
/// it would be a denormal or NaN).
#[inline(always)]
fn xyz(v: glam::Vec4) -> Vec3A {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{__m128, _mm_and_ps, _mm_castsi128_ps, _mm_set_epi32};
        // SAFETY: SSE2 is part of x86_64.
        #[allow(unused_unsafe)]
        unsafe {
            let m = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
            Vec3A::from(_mm_and_ps(__m128::from(v), m))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Vec3A::new(v.x, v.y, v.z)
    }
}

/// References in input order plus the root range (bounds of all boxes, bounds of all centres).
pub(crate) fn make_refs<R: Ref>(boxes: &[Aabb], centers: &[Vec3]) -> (Vec<R>, Range) {
    assert_eq!(
        boxes.len(),
        centers.len(),
        "builders need one centre per primitive box"
    );
    assert!(boxes.len() < u32::MAX as usize, "primitive indices are u32");
    let mut bounds = BoxA::EMPTY;
    let mut cbounds = BoxA::EMPTY;
    let refs = boxes
        .iter()
        .zip(centers)
        .enumerate()
        .map(|(i, (b, &c))| {
            let r = R::new(b, c, i as u32);
            bounds.grow(r.min(), r.max());
            cbounds.grow_point(c.into());
            r
        })
        .collect();
    (refs, Range::root(boxes.len(), bounds, cbounds))
}

/// Hoare-style in-place partition of `refs[r.begin..r.end]` (Wald 2007 via thesis 3.1.1): elements
/// with `is_left` first ([`hoare_blocks`]), then the children's bounds and centroid bounds.
/// Returns the two child ranges; either may be empty.
#[inline]
pub(crate) fn partition<R: Ref>(
    refs: &mut [R],
    r: &Range,
    is_left: impl Fn(&R) -> bool,
) -> (Range, Range) {
    let s = &mut refs[r.begin..r.end];
    let mid = hoare_blocks(s, &is_left);
    // Each side's bounds in a pass of their own (min / max: exact in any order).
    let bounds = |part: &[R]| {
        part.iter().fold((BoxA::EMPTY, BoxA::EMPTY), |(mut b, mut cb), p| {
            b.grow(p.min(), p.max());
            cb.grow_point(p.c());
            (b, cb)
        })
    };
    let (left, right) = (bounds(&s[..mid]), bounds(&s[mid..]));
    r.split(r.begin + mid, left, right)
}

/// [`partition`] when the children's boxes are already known (the binned SAH has them from its
/// bins, exactly: unions of the same boxes): gathers only the centroid bounds, half the min/max
/// work of the loop. `lb` / `rb` are the left and right boxes.
#[inline(always)]
pub(crate) fn partition_known_bounds<R: Ref>(
    refs: &mut [R],
    r: &Range,
    lb: BoxA,
    rb: BoxA,
    is_left: impl Fn(&R) -> bool,
) -> (Range, Range) {
    let s = &mut refs[r.begin..r.end];
    let mid = hoare_blocks(s, &is_left);
    // The centroid bounds of each side in a pass of their own (min / max: exact in any order),
    // on elements just partitioned, mostly in cache (measured faster than growing them
    // branch-free in the blocks' classification).
    let cbounds = |part: &[R]| {
        part.iter().fold(BoxA::EMPTY, |mut b, p| {
            b.grow_point(p.c());
            b
        })
    };
    let (lcb, rcb) = (cbounds(&s[..mid]), cbounds(&s[mid..]));
    r.split(r.begin + mid, (lb, lcb), (rb, rcb))
}

/// [`partition_known_bounds`] where the children's centroid bounds are known too (from the bins):
/// the partition alone.
#[inline(always)]
pub(crate) fn partition_known_all<R: Ref>(
    refs: &mut [R],
    r: &Range,
    left: (BoxA, BoxA),
    right: (BoxA, BoxA),
    is_left: impl Fn(&R) -> bool,
) -> (Range, Range) {
    let mid = hoare_blocks(&mut refs[r.begin..r.end], &is_left);
    r.split(r.begin + mid, left, right)
}

/// Elements per block of [`hoare_blocks`].
const BLOCK: usize = 128;
const _: () = assert!(BLOCK.is_power_of_two() && 2 * BLOCK <= 256);

/// Hoare's partition (elements with `is_left` first; returns how many) with the classification
/// taken out of the branches (Edelkamp and Weiss 2016, "BlockQuicksort: avoiding branch
/// mispredictions in quicksort"): a block of `BLOCK` elements at each end is classified without
/// branching into a list of offsets of the misplaced ones, and the lists are swapped pairwise. The
/// k-th misplaced element from the left still meets the k-th misplaced one from the right, as in
/// the plain scan, so the permutation is Hoare's exactly (and `partition_parallel`'s, which
/// reproduces it): the same trees. On a random split half the plain scan's branches mispredicted
/// (the profile's hottest spots in the binned build).
#[inline(always)]
fn hoare_blocks<R>(s: &mut [R], is_left: &impl Fn(&R) -> bool) -> usize {
    let (mut l, mut r) = (0usize, s.len());
    // Pending offsets (from `l` / back from `r - 1`) of misplaced elements of the current blocks;
    // `2 * BLOCK` long for the rest below.
    let (mut off_l, mut off_r) = ([0u8; 2 * BLOCK], [0u8; 2 * BLOCK]);
    let (mut start_l, mut num_l, mut start_r, mut num_r) = (0usize, 0usize, 0usize, 0usize);
    // Two whole blocks fit between the ends, so a swap never crosses them.
    while r - l >= 2 * BLOCK {
        if num_l == 0 {
            start_l = 0;
            for (i, x) in s[l..l + BLOCK].iter().enumerate() {
                // (num_l <= i < BLOCK: the mask only spares the bounds check.)
                off_l[num_l & (BLOCK - 1)] = i as u8;
                num_l += !is_left(x) as usize;
            }
        }
        if num_r == 0 {
            start_r = 0;
            for (i, x) in s[r - BLOCK..r].iter().rev().enumerate() {
                off_r[num_r & (BLOCK - 1)] = i as u8;
                num_r += is_left(x) as usize;
            }
        }
        let m = num_l.min(num_r);
        for k in 0..m {
            let (a, b) = (off_l[(start_l + k) & (BLOCK - 1)], off_r[(start_r + k) & (BLOCK - 1)]);
            s.swap(l + a as usize, r - 1 - b as usize);
        }
        (num_l, num_r, start_l, start_r) = (num_l - m, num_r - m, start_l + m, start_r + m);
        if num_l == 0 {
            l += BLOCK;
        }
        if num_r == 0 {
            r -= BLOCK;
        }
    }
    // The rest, fewer than two blocks (and a block whose misplaced elements were still pending:
    // classified again, as the plain scan would find them next), also without branching (most
    // nodes are this small): the misplaced elements from the left and the left-bound ones from the
    // right, in Hoare's meeting order; the k-th pair is swapped while they have not crossed.
    const MASK: usize = 2 * BLOCK - 1;
    let rest = &mut s[l..r];
    let mut left = [false; 2 * BLOCK];
    let mut n_mis = 0;
    for (i, x) in rest.iter().enumerate() {
        let is = is_left(x);
        left[i & MASK] = is;
        off_l[n_mis & MASK] = i as u8;
        n_mis += !is as usize;
    }
    let mut n_left = 0;
    for i in (0..rest.len()).rev() {
        off_r[n_left & MASK] = i as u8;
        n_left += left[i & MASK] as usize;
    }
    for k in 0..n_mis.min(n_left) {
        let (a, b) = (off_l[k & MASK] as usize, off_r[k & MASK] as usize);
        if a > b {
            break;
        }
        rest.swap(a, b);
    }
    l + n_left
}

/// Object-median split on `axis`: the lower half by (centre, index) goes left. The index tie-break
/// makes it deterministic and it always separates a range of >= 2 primitives, even when all centres
/// coincide, so it is the builders' fallback that guarantees termination.
pub(crate) fn object_median<R: Ref>(refs: &mut [R], r: &Range, axis: usize) -> (Range, Range) {
    let s = &mut refs[r.begin..r.end];
    debug_assert!(s.len() >= 2);
    let m = s.len() / 2;
    s.select_nth_unstable_by(m, |a, b| {
        a.c_axis(axis).total_cmp(&b.c_axis(axis)).then(a.idx().cmp(&b.idx()))
    });
    let bounds = |part: &[R]| {
        let (mut b, mut cb) = (BoxA::EMPTY, BoxA::EMPTY);
        for p in part {
            b.grow(p.min(), p.max());
            cb.grow_point(p.c());
        }
        (b, cb)
    };
    let (lb, lcb) = bounds(&s[..m]);
    let (rb, rcb) = bounds(&s[m..]);
    let mid = r.begin + m;
    r.split(mid, (lb, lcb), (rb, rcb))
}

/// Bounds and centroid bounds of a slice of references.
#[inline]
pub(crate) fn bounds_of<R: Ref>(part: &[R]) -> (BoxA, BoxA) {
    let (mut b, mut cb) = (BoxA::EMPTY, BoxA::EMPTY);
    for p in part {
        b.grow(p.min(), p.max());
        cb.grow_point(p.c());
    }
    (b, cb)
}

/// [`make_refs`] on all threads; the same references and the same root bounds (min/max merge
/// exactly in any order).
pub(crate) fn make_refs_parallel<R: Ref>(boxes: &[Aabb], centers: &[Vec3]) -> (Vec<R>, Range) {
    use rayon::prelude::*;
    assert_eq!(
        boxes.len(),
        centers.len(),
        "builders need one centre per primitive box"
    );
    assert!(boxes.len() < u32::MAX as usize, "primitive indices are u32");
    let refs: Vec<R> = boxes
        .par_iter()
        .zip(centers.par_iter())
        .enumerate()
        .map(|(i, (b, &c))| R::new(b, c, i as u32))
        .collect();
    let (bounds, cbounds) = refs.par_chunks(1 << 14).map(bounds_of).reduce(
        || (BoxA::EMPTY, BoxA::EMPTY),
        |a, b| (a.0.union(&b.0), a.1.union(&b.1)),
    );
    let root = Range::root(refs.len(), bounds, cbounds);
    (refs, root)
}

/// [`partition`] on all threads (thesis 3.1.2, horizontal phase), producing exactly the same
/// permutation as the sequential Hoare partition, so the parallel builders give identical trees.
///
/// The Hoare loop swaps the k-th right-bound element it meets from the left with the k-th left-bound
/// element it meets from the right; both scans stop at `mid` = number of left elements. So with
/// `a_0 < a_1 < ..` the positions below `mid` holding right elements and `b_0 < b_1 < ..` the
/// positions from `mid` on holding left elements (M of each), it swaps `a_k` with `b_{M-1-k}`.
/// That needs only per-chunk counts and prefix sums: classify (and gather child bounds) in
/// parallel, then swap the pairs in parallel blocks (see [`swap_misplaced`]).
/// (The thesis describes a stable variant with a double-length array; reproducing the sequential
/// builder's permutation instead keeps its trees and SAH costs unchanged and moves only the M
/// misplaced pairs.) `flags` is scratch of the range's length; `chunk` only affects speed.
pub(crate) fn partition_parallel<R: Ref>(
    refs: &mut [R],
    r: &Range,
    flags: &mut [bool],
    chunk: usize,
    is_left: impl Fn(&R) -> bool + Sync,
) -> (Range, Range) {
    use rayon::prelude::*;
    let chunk = chunk.max(1);
    let s = &mut refs[r.begin..r.end];
    let flags = &mut flags[..s.len()];
    // Pass 1: classify, count left elements, child bounds (min/max: exact in any merge order).
    type Acc = (usize, BoxA, BoxA, BoxA, BoxA);
    let empty: Acc = (0, BoxA::EMPTY, BoxA::EMPTY, BoxA::EMPTY, BoxA::EMPTY);
    let (n_left, lb, lcb, rb, rcb) = s
        .par_chunks(chunk)
        .zip(flags.par_chunks_mut(chunk))
        .map(|(ps, fs)| {
            let mut a = empty;
            for (p, f) in ps.iter().zip(fs.iter_mut()) {
                *f = is_left(p);
                if *f {
                    a.0 += 1;
                    a.1.grow(p.min(), p.max());
                    a.2.grow_point(p.c());
                } else {
                    a.3.grow(p.min(), p.max());
                    a.4.grow_point(p.c());
                }
            }
            a
        })
        .reduce(
            || empty,
            |a, b| {
                (
                    a.0 + b.0,
                    a.1.union(&b.1),
                    a.2.union(&b.2),
                    a.3.union(&b.3),
                    a.4.union(&b.4),
                )
            },
        );
    let mid = n_left;
    swap_misplaced(&mut s[..], flags, mid, chunk);
    r.split(r.begin + mid, (lb, lcb), (rb, rcb))
}

/// The swap step of [`partition_parallel`]: swaps `a_k` with `b_{M-1-k}` (see there) for all k.
/// Each chunk of `[0, mid)` holds the misplaced ranks `[o, o + c)`; their partners are the ranks
/// `[M - o - c, M - o)` from `mid` on, which occupy one contiguous stretch of positions. These
/// stretches tile the right part in reverse chunk order, so both sides split into disjoint slices
/// and every chunk swaps its pairs independently (no scratch copies, no unsafe).
fn swap_misplaced<R: Ref>(s: &mut [R], flags: &[bool], mid: usize, chunk: usize) {
    use rayon::prelude::*;
    let (lp, rp) = s.split_at_mut(mid);
    let (lf, rf) = flags.split_at(mid);
    let count = |f: &[bool], want: bool| f.iter().filter(|&&x| x == want).count();
    let (lcounts, rcounts): (Vec<usize>, Vec<usize>) = rayon::join(
        || lf.par_chunks(chunk).map(|f| count(f, false)).collect(),
        || rf.par_chunks(chunk).map(|f| count(f, true)).collect(),
    );
    let m: usize = lcounts.iter().sum();
    debug_assert_eq!(m, rcounts.iter().sum::<usize>());
    if m == 0 {
        return;
    }
    // rpre[i]: number of left-bound elements of the right part before its chunk i.
    let mut rpre = Vec::with_capacity(rcounts.len() + 1);
    rpre.push(0);
    for c in &rcounts {
        rpre.push(rpre.last().unwrap() + c);
    }
    // Position (in the right part) of the left-bound element of rank q; rank m is the end.
    let position = |q: usize| -> usize {
        if q >= m {
            return rp.len();
        }
        let i = rpre.partition_point(|&x| x <= q) - 1;
        let base = i * chunk;
        let mut need = q - rpre[i];
        for (j, &f) in rf[base..].iter().enumerate() {
            if f {
                if need == 0 {
                    return base + j;
                }
                need -= 1;
            }
        }
        unreachable!("rank {q} below the total {m}")
    };
    // Left chunk c (misplaced ranks [o, o + cnt)) pairs with right positions [start_c, end_c).
    let mut lo = Vec::with_capacity(lcounts.len());
    let mut acc = 0;
    for &c in &lcounts {
        lo.push(acc);
        acc += c;
    }
    let starts: Vec<usize> = lo
        .par_iter()
        .zip(lcounts.par_iter())
        .map(|(&o, &c)| position(m - o - c))
        .collect();
    // Carve the right part from its end: chunk 0 owns the highest ranks.
    let mut rights: Vec<(&mut [R], &[bool])> = Vec::with_capacity(starts.len());
    let mut rest = rp;
    for &st in &starts {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(st);
        let len = tail.len();
        rights.push((tail, &rf[st..st + len]));
        rest = head;
    }
    lp.par_chunks_mut(chunk)
        .zip(lf.par_chunks(chunk))
        .zip(rights.into_par_iter())
        .for_each(|((ls, lfl), (rs, rfl))| {
            // Misplaced ascending on the left meet left-bound descending on the right (Hoare).
            let mut j = rs.len();
            for (i, &f) in lfl.iter().enumerate() {
                if !f {
                    loop {
                        j -= 1;
                        if rfl[j] {
                            break;
                        }
                    }
                    std::mem::swap(&mut ls[i], &mut rs[j]);
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use bvhlab_geom::rng::SplitMix64;

    /// The plain Hoare scan (what `hoare_blocks` must reproduce).
    fn hoare_plain(s: &mut [(bool, u32)]) -> usize {
        let (mut i, mut j) = (0, s.len());
        loop {
            while i < j && s[i].0 {
                i += 1;
            }
            while i < j && !s[j - 1].0 {
                j -= 1;
            }
            if i >= j {
                return i;
            }
            s.swap(i, j - 1);
            i += 1;
            j -= 1;
        }
    }

    /// The block partition gives Hoare's permutation exactly (the builders' trees depend on it,
    /// and the parallel partition reproduces Hoare's): every length around the block sizes, left
    /// fractions from none to all, runs of one side (one block's list empty while the other's is
    /// full) and random sides.
    #[test]
    fn block_partition_is_hoares_permutation() {
        let mut rng = SplitMix64::new(3);
        let lens = [0, 1, 2, 127, 128, 129, 255, 256, 257, 383, 384, 511, 512, 1000, 4099, 20000];
        for &n in &lens {
            for p in [0.0, 0.02, 0.3, 0.5, 0.7, 0.98, 1.0] {
                for runs in [false, true] {
                    let v: Vec<(bool, u32)> = (0..n as u32)
                        .map(|i| {
                            let left = if runs { (i / 300) % 3 != 0 } else { rng.f64() < p };
                            (left, i)
                        })
                        .collect();
                    let (mut a, mut b) = (v.clone(), v);
                    let ma = hoare_plain(&mut a);
                    let mb = hoare_blocks(&mut b, &|x: &(bool, u32)| x.0);
                    assert_eq!((ma, &a), (mb, &b), "n = {n}, p = {p}, runs = {runs}");
                    assert!(a[..ma].iter().all(|x| x.0) && a[ma..].iter().all(|x| !x.0));
                }
            }
        }
    }
}
