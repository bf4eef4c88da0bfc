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
