//! Leaf triangles of the wide layouts in packs of four, structure of arrays ([`Tri4`]): the layout
//! tinybvh's BVH8_CPU and Embree's triangle4 leaves use. The four-wide watertight test then loads
//! each coordinate of four triangles with one 16-byte load instead of transposing four 48-byte
//! records (measured with callgrind on breakfast_room: the transposes were a quarter of the leaf
//! test's instructions), and four triangles take 160 bytes instead of 192.
//!
//! A leaf is a run of packs: its triangles fill them in order, the last one's prim index carries
//! [`END`], and the lanes after it (in the leaf's last pack) are never tested. A wide layout names
//! a leaf by its first pack (`PackStore::new` lays out each leaf at the pack index given).
use crate::fast::{WTri, WoopRay};
use crate::{accept, Hit};
use bvhlab_geom::Triangle;

/// Set in the prim index of the last triangle of a leaf (scene indices stay below 2^31).
pub const END: u32 = 1 << 31;

/// Four triangles: `v[vertex][axis][lane]`, then the four scene indices (with [`END`] on a leaf's
/// last). 160 bytes, 32-byte aligned (a pack starts on a half line; any 160 bytes span three).
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tri4 {
    pub v: [[[f32; 4]; 3]; 3],
    pub prim: [u32; 4],
}

impl Tri4 {
    const UNUSED: Tri4 = Tri4 {
        v: [[[f32::NAN; 4]; 3]; 3],
        prim: [0; 4],
    };

    /// Lane `l` as a one-triangle record (for the one-at-a-time tests).
    #[inline(always)]
    pub fn lane(&self, l: usize) -> WTri {
        let v = |i: usize| [self.v[i][0][l], self.v[i][1][l], self.v[i][2][l]];
        WTri {
            v: [v(0), v(1), v(2)],
            prim: self.prim[l] & !END,
            last: self.prim[l] & END,
            pad: 0,
        }
    }
}

/// Packs a leaf of `count` triangles takes (at least one, so that leaves start at distinct packs).
#[inline]
pub fn packs_for(count: u32) -> u32 {
    count.div_ceil(4).max(1)
}

/// The wide layouts' triangle store: every leaf's triangles in packs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PackStore {
    pub packs: Vec<Tri4>,
}

impl PackStore {
    /// `leaves`: `[first slot, count, first pack]`; leaf triangles `prim_indices[first..first +
    /// count]` go to packs from `first pack` on. Slots out of range, an index past the scene (a
    /// malformed layout) or an empty leaf leave NaN triangles that are never hit (an empty leaf's
    /// pack has its first lane marked last, so a traversal tests one lane and stops).
    pub fn new(prim_indices: &[u32], tris: &[Triangle], leaves: &[[u32; 3]]) -> PackStore {
        let total = leaves.iter().map(|l| l[2] as usize + packs_for(l[1]) as usize).max().unwrap_or(0);
        let mut packs = crate::thp::filled(Tri4::UNUSED, total);
        for &[first, count, pack] in leaves {
            let ids = prim_indices.get(first as usize..first as usize + count as usize).unwrap_or_default();
            let base = pack as usize;
            for (j, &p) in ids.iter().enumerate() {
                let q = &mut packs[base + j / 4];
                let l = j % 4;
                if let Some(t) = tris.get(p as usize) {
                    for (i, v) in t.v.iter().enumerate() {
                        for (k, c) in v.to_array().into_iter().enumerate() {
                            q.v[i][k][l] = c;
                        }
                    }
                }
                q.prim[l] = p & !END;
            }
            let last = ids.len().max(1) - 1;
            packs[base + last / 4].prim[last % 4] |= END;
        }
        PackStore { packs }
    }
}

/// Tests a leaf's packs (from `packs[0]` to the lane marked [`END`]) one triangle at a time with
/// `f`: the default of [`TriTest::test_packs`].
#[inline(always)]
pub(crate) fn test_packs_with<R>(
    r: &R,
    packs: &[Tri4],
    best: &mut Hit,
    f: impl Fn(&R, &WTri) -> Option<f32>,
) -> u32 {
    let mut n = 0;
    for q in packs {
        for l in 0..4 {
            let tri = q.lane(l);
            n += 1;
            if let Some(t) = f(r, &tri) {
                accept(t, tri.prim, best);
            }
            if tri.last != 0 {
                return n;
            }
        }
    }
    n
}

/// The watertight test on a leaf's packs: four lanes per SSE pass (inlined into an AVX2 caller it
/// is compiled VEX-encoded: the same operations, so the same hits).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn watertight_packs(r: &WoopRay, packs: &[Tri4], best: &mut Hit) -> u32 {
    let mut n = 0;
    for q in packs {
        // SAFETY: SSE is in the x86-64 baseline.
        let (lanes, end) = unsafe { watertight_pack(r, q, best) };
        n += lanes;
        if end {
            break;
        }
    }
    n
}

/// [`intersect_watertight`] on the four lanes of `q` up to its lane marked [`END`]; hits accepted
/// into `best`. The same f32 operations in the same order per lane as the one-triangle test (so
/// the same hits); a lane that needs the f64 fallback (an edge function 0, |det| out of the trusted
/// range) goes through the one-triangle test. Returns (lanes tested, leaf ended).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn watertight_pack(r: &WoopRay, q: &Tri4, best: &mut Hit) -> (u32, bool) {
    use crate::fast::woop4;
    use std::arch::x86_64::*;
    unsafe {
        // The END bits are the prim indices' sign bits.
        let ends = _mm_movemask_ps(_mm_load_ps(q.prim.as_ptr() as *const f32));
        let lanes = if ends == 0 { 4 } else { ends.trailing_zeros() + 1 };
        // The lanes up to the first marked one (all four when none is), without a branch.
        let valid = (ends ^ ends.wrapping_sub(1)) & 0xf;
        let done = (lanes, ends != 0);
        // Rows picked by the ray's axis order: one load each (the index is an address offset).
        let k = r.k;
        // SAFETY: every `WoopRay` constructor takes `k` from a table of axes (values below 3),
        // and its fields are private to the crate (bounds checks here cost 9 instructions a leaf).
        let row = |i: usize, j: usize| _mm_load_ps(q.v.get_unchecked(i).get_unchecked(k[j]).as_ptr());
        woop4(r, row, valid, |l| q.prim[l] & !END, |l| q.lane(l), best);
        done
    }
}

/// [`watertight_packs`] in its baseline (SSE) build, as a call of its own (the AVX2 walks inline
/// `watertight_packs` instead: `Watertight::test_packs_avx2`).
#[cfg(target_arch = "x86_64")]
#[inline(never)]
pub(crate) fn watertight_packs_sse(r: &WoopRay, packs: &[Tri4], best: &mut Hit) -> u32 {
    watertight_packs(r, packs, best)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bvhlab_geom::Vec3;

    fn tri(i: u32) -> Triangle {
        let o = i as f32;
        Triangle { v: [Vec3::new(o, 0.0, 0.0), Vec3::new(o + 1.0, 0.0, 0.0), Vec3::new(o, 1.0, 0.0)] }
    }

    #[test]
    fn leaves_fill_their_packs_and_mark_their_last_triangle() {
        let tris: Vec<Triangle> = (0..9).map(tri).collect();
        let ids: Vec<u32> = (0..9).rev().collect();
        // Leaf A: slots 0..5 (two packs from 0); leaf B: slots 5..9 (one pack, 2).
        let s = PackStore::new(&ids, &tris, &[[0, 5, 0], [5, 4, 2]]);
        assert_eq!(s.packs.len(), 3);
        assert_eq!(s.packs[0].prim, [8, 7, 6, 5]);
        assert_eq!(s.packs[1].prim[0], 4 | END);
        assert!(s.packs[1].v[0][0][1].is_nan(), "lanes after the leaf's last are unused");
        assert_eq!(s.packs[2].prim, [3, 2, 1, END]);
        assert_eq!(s.packs[0].lane(2).v, tri(6).v.map(|v| v.to_array()));
        assert_eq!(s.packs[2].lane(3).prim, 0);
        assert_eq!(s.packs[2].lane(3).last, END);
        // Lane by lane, a leaf stops at its END mark: 5 tests for leaf A, 4 for B.
        let mut best = Hit::within(f32::INFINITY);
        let none = |_: &(), _: &WTri| None;
        assert_eq!(test_packs_with(&(), &s.packs[0..], &mut best, none), 5);
        assert_eq!(test_packs_with(&(), &s.packs[2..], &mut best, none), 4);
    }
}
