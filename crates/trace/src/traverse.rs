//! Closest-hit traversal, near child first, counting traversal steps (nodes entered) and
//! ray-triangle intersection tests per ray, plus the brute-force oracle.
//!
//! Both `trace` and `brute_force` use the same triangle test ([`intersect_triangle`]) and the same
//! acceptance rule (closer t wins; on an exact tie in t the lower scene triangle index wins), so a
//! correct BVH gives bit-identical hits to brute force, independent of traversal order.
use crate::Ray;
use bvhlab_bvh::{Bvh, Node};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hit {
    /// Distance along the ray; `f32::INFINITY` when nothing was hit.
    pub t: f32,
    /// Scene triangle index; `u32::MAX` when nothing was hit.
    pub prim: u32,
}

impl Hit {
    pub const NONE: Hit = Hit {
        t: f32::INFINITY,
        prim: u32::MAX,
    };
    /// No hit yet, searching up to `tmax` (a traversal's start).
    pub fn within(tmax: f32) -> Hit {
        Hit {
            t: tmax,
            prim: u32::MAX,
        }
    }
    /// The hit, or [`Hit::NONE`] when the search found nothing (its `t` was only the limit).
    #[inline(always)]
    pub fn found(self) -> Hit {
        if self.is_hit() {
            self
        } else {
            Hit::NONE
        }
    }
    pub fn is_hit(&self) -> bool {
        self.prim != u32::MAX
    }
}

/// Per-ray results and totals of one trace.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TraceStats {
    pub hits: Vec<Hit>,
    /// Traversal steps per ray: nodes (inner or leaf) the ray *entered*, i.e. whose box it
    /// intersects within its current search interval and which were not culled by a closer hit
    /// when popped. A ray missing the root box takes 0 steps; one that hits the root of a one-leaf
    /// BVH takes 1. The thesis (4.4, table 15) does not define the step further; this is the usual
    /// "visited nodes" count. Boxes tested but not entered are not counted.
    pub steps: Vec<u32>,
    /// Ray-triangle intersection tests per ray.
    pub intersections: Vec<u32>,
    pub total_steps: u64,
    pub total_intersections: u64,
    pub hit_count: u64,
}

/// Möller-Trumbore ray-triangle test (Möller and Trumbore 1997). Returns the hit distance `t`
/// (not yet range-checked) or NaN/inf-free `None` on a miss. Degenerate triangles (det == 0) and
/// rays lying in the triangle's plane miss. Comparisons are written so that NaN means "miss".
///
/// Evaluated in f64 (the f32 inputs convert exactly; products of two f32 are exact in f64): in f32
/// the computed t of a ray starting far from a small triangle (a far outlier, a huge scene seen
/// from its edge) is off by several ulps, more than the slab test's margin (`SLAB_ROBUST`), so a
/// traversal could cull the box of a triangle whose computed t is the smallest and disagree with
/// brute force. In f64, t is within about one f32 ulp of the exact distance, inside that margin.
#[inline(always)]
pub fn intersect_triangle(origin: Vec3, dir: Vec3, tri: &Triangle) -> Option<f32> {
    let [v0, v1, v2] = tri.v.map(|v| v.as_dvec3());
    let (origin, dir) = (origin.as_dvec3(), dir.as_dvec3());
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = origin - v0;
    let u = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv_det;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    Some((e2.dot(q) * inv_det) as f32)
}

/// The shared acceptance rule: `t` in (0, best.t], closer wins, exact ties go to the lower index.
/// `best` starts as `(tmax, u32::MAX)`, which makes the range (0, tmax].
#[inline(always)]
pub fn accept(t: f32, prim: u32, best: &mut Hit) {
    if t > 0.0 && (t < best.t || (t == best.t && prim < best.prim)) {
        *best = Hit { t, prim };
    }
}

/// Ray data precomputed once per ray for the slab test (shared with the compressed layouts'
/// traversals, so every layout uses the same conservative box test).
pub struct RayBox {
    pub origin: Vec3,
    pub inv_dir: Vec3,
    /// Some direction component is zero (the ray is parallel to a slab): `hit` tests that axis
    /// by the origin's position instead of the products.
    parallel: bool,
}

/// 1 + 2 * gamma(3) with gamma(n) = n*eps / (1 - n*eps), eps = 2^-24: the factor that makes the
/// slab test conservative under float rounding (Ize 2013, "Robust BVH Ray Traversal").
pub const SLAB_ROBUST: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

impl RayBox {
    #[inline(always)]
    pub fn new(ray: &Ray) -> RayBox {
        // A zero direction component would give an infinite inverse, and (bound - origin) * inf
        // is NaN when the origin lies exactly on the slab plane. A huge finite inverse avoids the
        // NaN; the products of such an axis are then ignored (`parallel`): a parallel ray is inside
        // the slab for all t when min <= origin <= max, else never. (The products alone are wrong
        // when the origin lies on the slab's far plane, 0 * huge = 0 ends the interval at t = 0,
        // or a tiny distance from it.)
        let inv = |d: f32| {
            let i = 1.0 / d;
            if i.is_finite() {
                i
            } else {
                f32::MAX.copysign(d)
            }
        };
        RayBox {
            origin: ray.origin,
            inv_dir: Vec3::new(inv(ray.dir.x), inv(ray.dir.y), inv(ray.dir.z)),
            parallel: ray.dir.x == 0.0 || ray.dir.y == 0.0 || ray.dir.z == 0.0,
        }
    }

    /// Entry distance if the ray meets `b` within [0, tmax], else `None`.
    /// Plain `<` min/max (one instruction each) instead of NaN-aware `f32::min`: inputs here are
    /// never NaN (finite inverse, finite or infinite bounds), and a NaN would only make `near <= far`
    /// false, i.e. a miss.
    #[inline(always)]
    pub fn hit(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        use bvhlab_geom::aabb::{fmax as mx, fmin as mn};
        let (o, i) = (self.origin, self.inv_dir);
        let (mut x0, mut x1) = ((b.min.x - o.x) * i.x, (b.max.x - o.x) * i.x);
        let (mut y0, mut y1) = ((b.min.y - o.y) * i.y, (b.max.y - o.y) * i.y);
        let (mut z0, mut z1) = ((b.min.z - o.z) * i.z, (b.max.z - o.z) * i.z);
        if self.parallel {
            // Rare (axis-parallel rays): a zero-direction axis constrains nothing or everything.
            let axis = |lo: f32, hi: f32, o: f32, inv: f32, t0: &mut f32, t1: &mut f32| {
                if inv.abs() == f32::MAX {
                    if !(lo <= o && o <= hi) {
                        return false;
                    }
                    (*t0, *t1) = (f32::NEG_INFINITY, f32::INFINITY);
                }
                true
            };
            if !(axis(b.min.x, b.max.x, o.x, i.x, &mut x0, &mut x1)
                && axis(b.min.y, b.max.y, o.y, i.y, &mut y0, &mut y1)
                && axis(b.min.z, b.max.z, o.z, i.z, &mut z0, &mut z1))
            {
                return None;
            }
        }
        let near = mx(mx(mn(x0, x1), mn(y0, y1)), mx(mn(z0, z1), 0.0));
        let far = mn(mn(mx(x0, x1), mx(y0, y1)), mn(mx(z0, z1), tmax)) * SLAB_ROBUST;
        if near <= far {
            Some(near)
        } else {
            None
        }
    }
}

/// Entries kept in the fixed stack before spilling to a heap vector (only for very deep trees).
const STACK_SIZE: usize = 64;

/// LIFO of pending nodes, by default (node index, entry distance): fixed array first, then a
/// spill vector whose entries are always above the array's, so a BVH deeper than the array never
/// panics. Generic so that every layout's traversal uses the same one.
pub struct Stack<T = (u32, f32)> {
    items: [T; STACK_SIZE],
    len: usize,
    spill: Vec<T>,
}

impl<T: Copy + Default> Default for Stack<T> {
    fn default() -> Self {
        Stack::new()
    }
}

impl<T: Copy + Default> Stack<T> {
    pub fn new() -> Stack<T> {
        Stack {
            items: [T::default(); STACK_SIZE],
            len: 0,
            spill: Vec::new(),
        }
    }
    #[inline(always)]
    pub fn push(&mut self, e: T) {
        if self.len < STACK_SIZE {
            self.items[self.len] = e;
            self.len += 1;
        } else {
            self.spill.push(e);
        }
    }
    #[inline(always)]
    pub fn pop(&mut self) -> Option<T> {
        if let Some(e) = self.spill.pop() {
            return Some(e);
        }
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        Some(self.items[self.len])
    }
    pub fn clear(&mut self) {
        self.len = 0;
        self.spill.clear();
    }
}

/// A pending node on a [`Stack`] with the distance at which the ray enters it.
pub trait Pending: Copy + Default {
    fn entry(&self) -> f32;
}

impl Pending for (u32, f32) {
    fn entry(&self) -> f32 {
        self.1
    }
}

/// (child, count, entry): a pending child of the pair layout ([`crate::pairs`]).
impl Pending for (u32, u32, f32) {
    fn entry(&self) -> f32 {
        self.2
    }
}

impl<T: Pending> Stack<T> {
    /// Pops until an entry at most `limit` away (the closest hit so far with its margin) and
    /// returns it; None when no pending node can hold a closer hit.
    #[inline(always)]
    pub fn pop_within(&mut self, limit: f32) -> Option<T> {
        if !self.spill.is_empty() {
            while let Some(e) = self.pop() {
                if e.entry() <= limit {
                    return Some(e);
                }
            }
            return None;
        }
        // Only the array: its length in a register through the loop and stored once (most
        // entries popped are culled: breakfast_room's bvh8 culls 7 of 10).
        let mut n = self.len;
        while n > 0 {
            n -= 1;
            // SAFETY: `len` never exceeds STACK_SIZE (`push` spills past it), and n < len.
            let e = unsafe { *self.items.get_unchecked(n) };
            if e.entry() <= limit {
                self.len = n;
                return Some(e);
            }
        }
        self.len = 0;
        None
    }
}

/// Closest hit of one ray: (hit, traversal steps, intersection tests).
///
/// Near child first by box entry distance (both child boxes are tested at an inner node anyway,
/// so ordering by the actual entry costs nothing extra and is exact for this ray, unlike the
/// split-axis sign heuristic). The far child is pushed with its entry distance and skipped when
/// popped if a hit closer than that entry was found meanwhile. Malformed indices are skipped,
/// never panicked on.
#[inline]
fn trace_one(
    nodes: &[Node],
    prims: &[u32],
    tris: &[Triangle],
    ray: &Ray,
    stack: &mut Stack,
) -> (Hit, u32, u32) {
    let mut best = Hit::within(ray.tmax);
    let mut steps = 0u32;
    let mut tests = 0u32;
    let Some(root) = nodes.first() else {
        return (Hit::NONE, 0, 0);
    };
    if ray.tmax.is_nan() || ray.tmax <= 0.0 {
        return (Hit::NONE, 0, 0);
    }
    let rb = RayBox::new(ray);
    // The slab test sees the empty box (min = +inf, max = -inf) as an infinite interval; only the
    // root can be empty in a valid BVH (every leaf box contains its triangles), so check it here.
    if root.bounds.is_empty() || rb.hit(&root.bounds, best.t).is_none() {
        return (Hit::NONE, 0, 0);
    }
    stack.clear();
    let mut cur = 0u32;
    loop {
        steps += 1;
        // A valid tree enters each node at most once per ray; more means a cycle in a malformed
        // BVH, which must not hang the trace.
        if steps as usize > nodes.len() {
            break;
        }
        let node = &nodes[cur as usize];
        let mut next = None;
        if node.count > 0 {
            let first = node.first as usize;
            let end = first.saturating_add(node.count as usize).min(prims.len());
            for &p in prims.get(first..end).unwrap_or(&[]) {
                if let Some(tri) = tris.get(p as usize) {
                    tests += 1;
                    if let Some(t) = intersect_triangle(ray.origin, ray.dir, tri) {
                        accept(t, p, &mut best);
                    }
                }
            }
        } else {
            let l = node.first;
            let r = l.wrapping_add(1);
            if let (Some(ln), Some(rn)) = (nodes.get(l as usize), nodes.get(r as usize)) {
                let hl = rb.hit(&ln.bounds, best.t);
                let hr = rb.hit(&rn.bounds, best.t);
                next = match (hl, hr) {
                    (Some(tl), Some(tr)) => {
                        if tr < tl {
                            stack.push((l, tl));
                            Some(r)
                        } else {
                            stack.push((r, tr));
                            Some(l)
                        }
                    }
                    (Some(_), None) => Some(l),
                    (None, Some(_)) => Some(r),
                    (None, None) => None,
                };
            }
        }
        match next {
            Some(n) => cur = n,
            None => {
                // Pop until a node whose entry is not beyond the closest hit so far.
                loop {
                    match stack.pop() {
                        None => {
                            let hit = best.found();
                            return (hit, steps, tests);
                        }
                        // Same robustness margin as the child test (`hit` scales `far`, which
                        // includes tmax = best.t): a flat box's entry can round one ulp above an
                        // equal-t hit, and a tie with a lower triangle index must still be found.
                        Some((n, entry)) if entry <= best.t * SLAB_ROBUST => {
                            cur = n;
                            break;
                        }
                        Some(_) => {}
                    }
                }
            }
        }
    }
    let hit = best.found();
    (hit, steps, tests)
}

/// Rays per rayon task: large enough to amortize scheduling, small enough to balance 2+ cores.
const CHUNK: usize = 1024;

/// Traces every ray (in parallel with rayon; results are per-ray so independent of thread count).
pub fn trace(bvh: &Bvh, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
    trace_with(rays, Stack::new, |stack, ray| {
        trace_one(&bvh.nodes, &bvh.prim_indices, tris, ray, stack)
    })
}

/// Runs a per-ray closest-hit function over all rays in parallel and gathers the counters; every
/// layout's traversal (crates/layout) goes through here, so all of them are measured the same way.
/// `init` makes the per-task scratch (a traversal stack); `one` returns (hit, steps, tests).
pub fn trace_with<S, I, F>(rays: &[Ray], init: I, one: F) -> TraceStats
where
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, &Ray) -> (Hit, u32, u32) + Sync + Send,
{
    let n = rays.len();
    let mut hits = vec![Hit::NONE; n];
    let mut steps = vec![0u32; n];
    let mut intersections = vec![0u32; n];
    hits.par_chunks_mut(CHUNK)
        .zip(steps.par_chunks_mut(CHUNK))
        .zip(intersections.par_chunks_mut(CHUNK))
        .zip(rays.par_chunks(CHUNK))
        .for_each_init(&init, |scratch, (((h, s), x), r)| {
            for i in 0..r.len() {
                let (hit, st, it) = one(scratch, &r[i]);
                h[i] = hit;
                s[i] = st;
                x[i] = it;
            }
        });
    let total_steps = steps.iter().map(|&s| s as u64).sum();
    let total_intersections = intersections.iter().map(|&s| s as u64).sum();
    let hit_count = hits.iter().filter(|h| h.is_hit()).count() as u64;
    TraceStats {
        hits,
        steps,
        intersections,
        total_steps,
        total_intersections,
        hit_count,
    }
}

/// Closest hit of one ray against every triangle, with the traversal's test and acceptance rule.
pub fn brute_force_one(tris: &[Triangle], ray: &Ray) -> Hit {
    let mut best = Hit::within(ray.tmax);
    if ray.tmax.is_nan() || ray.tmax <= 0.0 {
        return Hit::NONE;
    }
    for (i, tri) in tris.iter().enumerate() {
        if let Some(t) = intersect_triangle(ray.origin, ray.dir, tri) {
            accept(t, i as u32, &mut best);
        }
    }
    best.found()
}

/// The oracle: closest hit of each ray against every triangle.
pub fn brute_force(tris: &[Triangle], rays: &[Ray]) -> Vec<Hit> {
    rays.par_iter()
        .with_min_len(16)
        .map(|r| brute_force_one(tris, r))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stack is a LIFO across the array / spill boundary: random pushes and pops (runs longer
    /// than the array, so entries spill and come back several times) match a plain vector.
    #[test]
    fn stack_is_lifo_across_spills() {
        let mut s: Stack<(u32, f32)> = Stack::new();
        let mut model: Vec<(u32, f32)> = Vec::new();
        let mut x = 12345u64;
        let mut next = 0u32;
        let mut deepest = 0;
        for _ in 0..20_000 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            // Pushes win 55 % of steps in phases: the depth wanders far past STACK_SIZE and back.
            let phase = (next / 3000) % 2 == 0;
            let push = ((x >> 33) % 100) < if phase { 70 } else { 35 };
            if push {
                let e = (next, next as f32);
                next += 1;
                s.push(e);
                model.push(e);
                deepest = deepest.max(model.len());
            } else {
                assert_eq!(s.pop(), model.pop());
            }
        }
        assert!(next > 3 * STACK_SIZE as u32);
        // Deep enough that entries went to the spill vector and came back.
        assert!(deepest > 4 * STACK_SIZE, "deepest {deepest}");
        while let Some(e) = model.pop() {
            assert_eq!(s.pop(), Some(e));
        }
        assert_eq!(s.pop(), None);
        s.push((1, 1.0));
        s.clear();
        assert_eq!(s.pop(), None);
    }
}
