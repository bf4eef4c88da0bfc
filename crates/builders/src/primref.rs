//! Primitive references for the in-place builders (spatial median, binned SAH): box, centre and
//! index in one 48-byte record, so binning and partitioning stream through memory sequentially
//! instead of gathering boxes and centres by index.
use crate::simd_box::BoxA;
use crate::topdown::Range;
use bvhlab_bvh::{Aabb, Vec3};
use glam::Vec3A;

#[derive(Clone, Copy, Debug)]
pub(crate) struct PrimRef {
    pub min: Vec3A,
    pub max: Vec3A,
    pub c: Vec3,
    pub idx: u32,
}

/// References in input order plus the root range (bounds of all boxes, bounds of all centres).
pub(crate) fn make_refs(boxes: &[Aabb], centers: &[Vec3]) -> (Vec<PrimRef>, Range) {
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
            let r = PrimRef {
                min: b.min.into(),
                max: b.max.into(),
                c,
                idx: i as u32,
            };
            bounds.grow(r.min, r.max);
            cbounds.grow_point(c.into());
            r
        })
        .collect();
    (refs, Range::root(boxes.len(), bounds, cbounds))
}

/// Hoare-style in-place partition of `refs[r.begin..r.end]` (Wald 2007 via thesis 3.1.1): elements
/// with `is_left` first. Every element is classified exactly once, and the children's bounds and
/// centroid bounds are gathered on the way. Returns the two child ranges; either may be empty.
#[inline]
pub(crate) fn partition(
    refs: &mut [PrimRef],
    r: &Range,
    is_left: impl Fn(&PrimRef) -> bool,
) -> (Range, Range) {
    let s = &mut refs[r.begin..r.end];
    let (mut lb, mut lcb, mut rb, mut rcb) = (BoxA::EMPTY, BoxA::EMPTY, BoxA::EMPTY, BoxA::EMPTY);
    let mut i = 0;
    let mut j = s.len();
    loop {
        while i < j && is_left(&s[i]) {
            lb.grow(s[i].min, s[i].max);
            lcb.grow_point(s[i].c.into());
            i += 1;
        }
        while i < j && !is_left(&s[j - 1]) {
            rb.grow(s[j - 1].min, s[j - 1].max);
            rcb.grow_point(s[j - 1].c.into());
            j -= 1;
        }
        if i >= j {
            break;
        }
        // s[i] belongs right, s[j-1] left: swap them into place.
        s.swap(i, j - 1);
        lb.grow(s[i].min, s[i].max);
        lcb.grow_point(s[i].c.into());
        rb.grow(s[j - 1].min, s[j - 1].max);
        rcb.grow_point(s[j - 1].c.into());
        i += 1;
        j -= 1;
    }
    let mid = r.begin + i;
    r.split(mid, (lb, lcb), (rb, rcb))
}

/// [`partition`] when the children's boxes are already known (the binned SAH has them from its
/// bins, exactly: unions of the same boxes): gathers only the centroid bounds, half the min/max
/// work of the loop. `lb` / `rb` are the left and right boxes.
#[inline]
pub(crate) fn partition_known_bounds(
    refs: &mut [PrimRef],
    r: &Range,
    lb: BoxA,
    rb: BoxA,
    is_left: impl Fn(&PrimRef) -> bool,
) -> (Range, Range) {
    let s = &mut refs[r.begin..r.end];
    let (mut lcb, mut rcb) = (BoxA::EMPTY, BoxA::EMPTY);
    let mut i = 0;
    let mut j = s.len();
    loop {
        while i < j && is_left(&s[i]) {
            lcb.grow_point(s[i].c.into());
            i += 1;
        }
        while i < j && !is_left(&s[j - 1]) {
            rcb.grow_point(s[j - 1].c.into());
            j -= 1;
        }
        if i >= j {
            break;
        }
        s.swap(i, j - 1);
        lcb.grow_point(s[i].c.into());
        rcb.grow_point(s[j - 1].c.into());
        i += 1;
        j -= 1;
    }
    let mid = r.begin + i;
    (
        Range {
            begin: r.begin,
            end: mid,
            bounds: lb,
            cbounds: lcb,
        },
        Range {
            begin: mid,
            end: r.end,
            bounds: rb,
            cbounds: rcb,
        },
    )
}

/// Object-median split on `axis`: the lower half by (centre, index) goes left. The index tie-break
/// makes it deterministic and it always separates a range of >= 2 primitives, even when all centres
/// coincide, so it is the builders' fallback that guarantees termination.
pub(crate) fn object_median(refs: &mut [PrimRef], r: &Range, axis: usize) -> (Range, Range) {
    let s = &mut refs[r.begin..r.end];
    debug_assert!(s.len() >= 2);
    let m = s.len() / 2;
    s.select_nth_unstable_by(m, |a, b| {
        a.c[axis].total_cmp(&b.c[axis]).then(a.idx.cmp(&b.idx))
    });
    let bounds = |part: &[PrimRef]| {
        let (mut b, mut cb) = (BoxA::EMPTY, BoxA::EMPTY);
        for p in part {
            b.grow(p.min, p.max);
            cb.grow_point(p.c.into());
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
fn bounds_of(part: &[PrimRef]) -> (BoxA, BoxA) {
    let (mut b, mut cb) = (BoxA::EMPTY, BoxA::EMPTY);
    for p in part {
        b.grow(p.min, p.max);
        cb.grow_point(p.c.into());
    }
    (b, cb)
}

/// [`make_refs`] on all threads; the same references and the same root bounds (min/max merge
/// exactly in any order).
pub(crate) fn make_refs_parallel(boxes: &[Aabb], centers: &[Vec3]) -> (Vec<PrimRef>, Range) {
    use rayon::prelude::*;
    assert_eq!(
        boxes.len(),
        centers.len(),
        "builders need one centre per primitive box"
    );
    assert!(boxes.len() < u32::MAX as usize, "primitive indices are u32");
    let refs: Vec<PrimRef> = boxes
        .par_iter()
        .zip(centers.par_iter())
        .enumerate()
        .map(|(i, (b, &c))| PrimRef {
            min: b.min.into(),
            max: b.max.into(),
            c,
            idx: i as u32,
        })
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
pub(crate) fn partition_parallel(
    refs: &mut [PrimRef],
    r: &Range,
    flags: &mut [bool],
    chunk: usize,
    is_left: impl Fn(&PrimRef) -> bool + Sync,
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
                    a.1.grow(p.min, p.max);
                    a.2.grow_point(p.c.into());
                } else {
                    a.3.grow(p.min, p.max);
                    a.4.grow_point(p.c.into());
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
fn swap_misplaced(s: &mut [PrimRef], flags: &[bool], mid: usize, chunk: usize) {
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
    let mut rights: Vec<(&mut [PrimRef], &[bool])> = Vec::with_capacity(starts.len());
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
