//! The binary BVH in child-pair nodes for the timed path: one 64-byte, cache-line-aligned record
//! per inner node holding both children's boxes (SoA, so one SSE pass tests both) and where each
//! child leads. A visit then reads one cache line and no parent box: the flat layout's 32-byte
//! nodes put a node's two children side by side, but at an odd index, so half of the pairs
//! straddled two lines, and a child's box and its own children's indices sat in different lines.
//! This is the two-wide node of Aila and Laine 2009 ("Understanding the efficiency of ray
//! traversal on GPUs": both child boxes stored in the parent) on the CPU.
//!
//! Built from a [`Node`] array before timing; a malformed tree (index out of range, a node reached
//! twice) gives no pair layout, and the caller keeps the flat traversal.
use crate::fast::{TriTest, WTri};
use crate::{Hit, Ray, Stack, SLAB_ROBUST};
use bvhlab_bvh::Node;

/// Both children of an inner node: per axis `[left min, right min, left max, right max]`, then per
/// child its target: a leaf's first slot and triangle count (count > 0), or an inner child's pair
/// index (count 0).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pair {
    pub axis: [[f32; 4]; 3],
    pub child: [u32; 2],
    pub count: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<Pair>() == 64);

/// A binary BVH as [`Pair`]s, pair 0 holding the root's children; depth first, left subtree
/// first, a pair's two inner children's pairs allocated together (as the flat layout's siblings).
/// Never empty: built only by [`Pairs::new`], which the traversal's unchecked indexing relies on.
#[derive(Clone, Debug, PartialEq)]
pub struct Pairs {
    /// Private: the traversal follows the indices unchecked, trusting `Pairs::new`.
    pairs: Vec<Pair>,
}

impl Pairs {
    /// None for a tree whose root is a leaf (nothing to pair) or that is malformed: an index out of
    /// range, a node reached twice, or a child box that is empty or inverted on some axis (the
    /// flat test always misses such a box, the pair test's min / max of the two planes would not).
    pub fn new(nodes: &[Node]) -> Option<Pairs> {
        let root = nodes.first()?;
        if root.is_leaf() {
            return None;
        }
        let mut seen = vec![false; nodes.len()];
        seen[0] = true;
        let mut pairs: Vec<Pair> = Vec::with_capacity(nodes.len() / 2);
        // (inner node, the pair slot its children go to); depth first, left subtree first.
        let mut todo = vec![(0usize, 0usize)];
        pairs.push(Pair::default());
        while let Some((n, slot)) = todo.pop() {
            let l = nodes[n].first as usize;
            let kids = [l, l.checked_add(1)?];
            let mut pair = Pair::default();
            let mut inner = [None, None];
            for (side, &c) in kids.iter().enumerate() {
                let node = nodes.get(c)?;
                if std::mem::replace(&mut seen[c], true) {
                    return None;
                }
                let b = node.bounds;
                if !(b.min.x <= b.max.x && b.min.y <= b.max.y && b.min.z <= b.max.z) {
                    return None;
                }
                for (a, (lo, hi)) in [(b.min.x, b.max.x), (b.min.y, b.max.y), (b.min.z, b.max.z)]
                    .into_iter()
                    .enumerate()
                {
                    pair.axis[a][side] = lo;
                    pair.axis[a][side + 2] = hi;
                }
                if node.is_leaf() {
                    pair.child[side] = node.first;
                    pair.count[side] = node.count;
                } else {
                    pair.child[side] = pairs.len() as u32;
                    inner[side] = Some((c, pairs.len()));
                    pairs.push(Pair::default());
                }
            }
            pairs[slot] = pair;
            // Right pushed first so the left subtree is laid out (and popped) first.
            todo.extend(inner.into_iter().rev().flatten());
        }
        Some(Pairs { pairs })
    }

    pub fn pairs(&self) -> &[Pair] {
        &self.pairs
    }
}

/// Bytes per offset unit of an [`Arena`]: a [`Pair`] is 4 units, a [`WTri`] 3.
const UNIT: usize = 16;
const _: () = assert!(std::mem::size_of::<Pair>() == 4 * UNIT && std::mem::size_of::<WTri>() == 3 * UNIT);

/// The timed path's memory: the [`Pairs`] and then the leaf triangles in one 64-byte-aligned
/// allocation, every child named by its offset from the start in 16-byte units (a pair's or a
/// leaf's first triangle's alike). A visit then asks for both children's memory at `base + 16 *
/// child` without choosing between two arrays by the child's kind (that choice was 18 of a
/// visit's 63 instructions, callgrind on the dragon), and follows a child without scaling its
/// index. Leaf ranges are checked once here, so the walk reads them unchecked.
#[derive(Clone, Debug)]
pub struct Arena {
    /// Pairs first, then the triangles' bytes (the last line padded).
    lines: Vec<Pair>,
    pairs: usize,
    tris: usize,
}

impl Arena {
    /// None when a leaf's range leaves `tris` or the offsets would not fit 32 bits (more than
    /// 64 GiB of pairs and triangles): the caller keeps the flat traversal.
    pub fn new(p: &Pairs, tris: &[WTri]) -> Option<Arena> {
        let np = p.pairs.len();
        let tri_lines = (tris.len() * 3).div_ceil(4);
        let units = (np + tri_lines).checked_mul(4)?;
        u32::try_from(units).ok()?;
        let tri0 = 4 * np;
        let mut lines = crate::thp::with_capacity(np + tri_lines);
        for pair in &p.pairs {
            let mut q = *pair;
            for side in 0..2 {
                let (c, n) = (pair.child[side] as usize, pair.count[side] as usize);
                q.child[side] = if n > 0 {
                    if c.checked_add(n)? > tris.len() {
                        return None;
                    }
                    (tri0 + 3 * c) as u32
                } else {
                    // `Pairs::new` checked the pair indices.
                    (4 * c) as u32
                };
            }
            lines.push(q);
        }
        lines.resize(np + tri_lines, Pair::default());
        // SAFETY: the `tri_lines` lines after the pairs hold at least `3 * tris.len()` units, i.e.
        // `tris.len()` triangles' bytes; they start 64-byte aligned (WTri needs 16), and the two
        // buffers do not overlap.
        unsafe {
            std::ptr::copy_nonoverlapping(tris.as_ptr(), lines.as_mut_ptr().add(np) as *mut WTri, tris.len());
        }
        crate::thp::settle(&lines);
        Some(Arena { lines, pairs: np, tris: tris.len() })
    }

    /// The triangles, in slot order (the store's copy).
    pub fn tris(&self) -> &[WTri] {
        // SAFETY: `new` copied `self.tris` triangles to the lines after the pairs.
        unsafe { std::slice::from_raw_parts(self.lines.as_ptr().add(self.pairs) as *const WTri, self.tris) }
    }

    /// The pairs with their children as offsets (in 16-byte units from the first pair: a pair's
    /// offset is 4 times its index, a leaf's `4 * pairs + 3 * slot`).
    pub fn pairs(&self) -> &[Pair] {
        &self.lines[..self.pairs]
    }
}

/// Closest hit of one ray whose origin and direction are finite with no zero direction component
/// (the caller routes every other ray through the flat traversal), the root's box already
/// entered. Same hits as the flat traversal with `T`: the same boxes with the same products (the
/// near and far planes taken by min and max of the two products instead of by the direction's
/// sign, which for finite products and non-inverted boxes is the same pair of values), the same
/// culling margin and [`crate::accept`]'s order-free choice between equal distances. Leaves of
/// four or more triangles go through `T::test_leaf` (four at once), smaller ones one triangle at a
/// time inline (a call per leaf cost more than it saved). `AVX2`: the caller is compiled for AVX2
/// (and the CPU has it), so the leaf test takes its AVX2 build.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn pairs_one<T: TriTest, const AVX2: bool>(
    arena: &Arena,
    ray: &Ray,
    inv: [f32; 3],
    stack: &mut Stack<(u32, u32, f32)>,
) -> Hit {
    use std::arch::x86_64::*;
    let base = arena.lines.as_ptr() as *const u8;
    // SAFETY (for the callers below): every offset stored in the arena was checked by `Arena::new`.
    let at = |off: u32| unsafe { base.add(off as usize * UNIT) };
    let mut best = Hit::within(ray.tmax);
    let mut tr: Option<T::Ray> = None;
    stack.clear();
    let o = ray.origin.to_array();
    // SAFETY: SSE is in the x86-64 baseline, and AVX2 where `AVX2` says so (the caller's
    // contract); every offset followed was checked by `Pairs::new` and `Arena::new`.
    unsafe {
        let (ox, oy, oz) = (_mm_set1_ps(o[0]), _mm_set1_ps(o[1]), _mm_set1_ps(o[2]));
        let (ix, iy, iz) = (
            _mm_set1_ps(inv[0]),
            _mm_set1_ps(inv[1]),
            _mm_set1_ps(inv[2]),
        );
        let robust = _mm_set1_ps(SLAB_ROBUST);
        // (child, count): count > 0 a leaf's triangles, else a pair; the offset of either.
        let (mut child, mut count) = (0u32, 0u32);
        loop {
            if count > 0 {
                let tr = &*tr.get_or_insert_with(|| {
                    if AVX2 {
                        T::prepare_avx2(ray, &inv)
                    } else {
                        T::prepare(ray, &inv)
                    }
                });
                let leaf = std::slice::from_raw_parts(at(child) as *const WTri, count as usize);
                if leaf.len() >= 4 {
                    if AVX2 {
                        T::test_leaf_avx2(tr, leaf, &mut best);
                    } else {
                        T::test_leaf(tr, leaf, &mut best);
                    }
                } else {
                    // Small leaves (most of the thesis' trees) inline, one triangle at a time.
                    for tri in leaf {
                        if let Some(t) = T::test(tr, tri) {
                            crate::accept(t, tri.prim, &mut best);
                        }
                    }
                }
            } else {
                let p = &*(at(child) as *const Pair);
                // Both children's memory asked for before the box test needs this pair's boxes:
                // the near child is read next, and its line is then on the way during the test
                // and the branches after it; the far one is popped next by most rays that reach a
                // pair with both children hit (prefetching it alone when pushed: +6-10 % on the
                // dragon and the bunny; both, here: +30 % and +50 %).
                for side in 0..2 {
                    _mm_prefetch::<_MM_HINT_T0>(at(p.child[side]) as *const i8);
                }
                let slab = |row: &[f32; 4], o: __m128, i: __m128| {
                    let t = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(row.as_ptr()), o), i);
                    let s = _mm_shuffle_ps::<0b01_00_11_10>(t, t);
                    (_mm_min_ps(t, s), _mm_max_ps(t, s))
                };
                let (nx, fx) = slab(&p.axis[0], ox, ix);
                let (ny, fy) = slab(&p.axis[1], oy, iy);
                let (nz, fz) = slab(&p.axis[2], oz, iz);
                let near = _mm_max_ps(_mm_max_ps(nx, ny), _mm_max_ps(nz, _mm_setzero_ps()));
                let far = _mm_mul_ps(
                    _mm_min_ps(_mm_min_ps(fx, fy), _mm_min_ps(fz, _mm_set1_ps(best.t))),
                    robust,
                );
                let mask = _mm_movemask_ps(_mm_cmple_ps(near, far)) & 3;
                if mask != 0 {
                    let mut d = [0f32; 4];
                    _mm_storeu_ps(d.as_mut_ptr(), near);
                    let side = if mask == 3 {
                        // Near child first; the other waits with its entry distance.
                        let first = (d[1] < d[0]) as usize;
                        let (c, n) = (p.child[1 - first], p.count[1 - first]);
                        // Its memory was asked for at the start of this visit.
                        stack.push((c, n, d[1 - first]));
                        first
                    } else {
                        (mask >> 1) as usize
                    };
                    child = p.child[side];
                    count = p.count[side];
                    continue;
                }
            }
            match stack.pop_within(best.t * SLAB_ROBUST) {
                Some((c, n, _)) => (child, count) = (c, n),
                None => break,
            }
        }
    }
    best.found()
}
