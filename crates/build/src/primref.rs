//! Primitive references for the in-place builders (spatial median, binned SAH): box, centre and
//! index in one 48-byte record, so binning and partitioning stream through memory sequentially
//! instead of gathering boxes and centres by index.
use crate::boxa::BoxA;
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
    (
        refs,
        Range {
            begin: 0,
            end: boxes.len(),
            bounds,
            cbounds,
        },
    )
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
    let (bounds, cbounds) = refs
        .par_chunks(1 << 14)
        .map(bounds_of)
        .reduce(
            || (BoxA::EMPTY, BoxA::EMPTY),
            |a, b| (a.0.union(&b.0), a.1.union(&b.1)),
        );
    let root = Range {
        begin: 0,
        end: refs.len(),
        bounds,
        cbounds,
    };
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
/// parallel, copy the 2M misplaced elements out, and write them back to their partners' slots.
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
    let flags = &*flags;
    // Misplaced elements on each side, gathered in position order (rayon's collect keeps order).
    let (left_part, right_part) = s.split_at_mut(mid);
    let (left_flags, right_flags) = flags.split_at(mid);
    let gather = |part: &[PrimRef], fl: &[bool], want: bool| -> (Vec<usize>, Vec<PrimRef>) {
        let per_chunk: Vec<Vec<PrimRef>> = part
            .par_chunks(chunk)
            .zip(fl.par_chunks(chunk))
            .map(|(ps, fs)| {
                ps.iter()
                    .zip(fs)
                    .filter(|(_, &f)| f == want)
                    .map(|(p, _)| *p)
                    .collect()
            })
            .collect();
        // Rank of each chunk's first misplaced element.
        let mut offsets = Vec::with_capacity(per_chunk.len());
        let mut acc = 0;
        for c in &per_chunk {
            offsets.push(acc);
            acc += c.len();
        }
        (offsets, per_chunk.concat())
    };
    let ((a_off, a_vals), (b_off, b_vals)) = rayon::join(
        || gather(left_part, left_flags, false),
        || gather(right_part, right_flags, true),
    );
    let m = a_vals.len();
    debug_assert_eq!(m, b_vals.len());
    if m > 0 {
        // a_k receives b_{M-1-k}; b_j receives a_{M-1-j}.
        let scatter = |part: &mut [PrimRef], fl: &[bool], want: bool, off: &[usize], src: &[PrimRef]| {
            part.par_chunks_mut(chunk)
                .zip(fl.par_chunks(chunk))
                .zip(off.par_iter())
                .for_each(|((ps, fs), &o)| {
                    let mut k = o;
                    for (p, &f) in ps.iter_mut().zip(fs) {
                        if f == want {
                            *p = src[m - 1 - k];
                            k += 1;
                        }
                    }
                });
        };
        rayon::join(
            || scatter(left_part, left_flags, false, &a_off, &b_vals),
            || scatter(right_part, right_flags, true, &b_off, &a_vals),
        );
    }
    (
        Range {
            begin: r.begin,
            end: r.begin + mid,
            bounds: lb,
            cbounds: lcb,
        },
        Range {
            begin: r.begin + mid,
            end: r.end,
            bounds: rb,
            cbounds: rcb,
        },
    )
}
