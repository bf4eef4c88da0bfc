//! Traversal: the portable and the SSE4.1 paths, frame modes and the spilling stack.

use super::quant::{Bytes8, Grid, KeyReader, Packed};
#[cfg(target_arch = "x86_64")]
use super::sse;
use super::{chunk_box, header, rank_bit, Frame, QbvhChunks, HEADER_WORDS};
use bvhlab_geom::{Aabb, Triangle};
use bvhlab_trace::{accept, intersect_triangle, Hit, Ray, RayBox, TraceStats, SLAB_ROBUST};

impl QbvhChunks {
    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        // SSE4.1 (pshufb, blendv, ptest) and popcnt (rank) when the CPU has them, detected once;
        // the portable path (RayBox::hit on dequantized Aabbs) otherwise. Both compute the same
        // floats, so hits and counters are identical.
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("popcnt")
            && std::arch::is_x86_feature_detected!("sse4.1")
        {
            return match (self.bits == 8, self.frame) {
                (true, Frame::Chunk) => self.trace_sse::<Bytes8, ChunkMode>(Bytes8, tris, rays),
                (true, Frame::Parent) => self.trace_sse::<Bytes8, ParentMode>(Bytes8, tris, rays),
                (false, frame) => {
                    let t = sse::PackedTables::new(self.bits);
                    let kr = sse::PackedSse {
                        bits: self.bits,
                        t: &t,
                    };
                    match frame {
                        Frame::Chunk => self.trace_sse::<_, ChunkMode>(kr, tris, rays),
                        Frame::Parent => self.trace_sse::<_, ParentMode>(kr, tris, rays),
                    }
                }
            };
        }
        self.trace_portable(tris, rays)
    }

    /// The portable traversal (also used by tests to check the SSE path gives identical results).
    pub fn trace_portable(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        match (self.bits == 8, self.frame) {
            (true, Frame::Chunk) => self.trace_as::<Bytes8, ChunkMode>(Bytes8, tris, rays),
            (true, Frame::Parent) => self.trace_as::<Bytes8, ParentMode>(Bytes8, tris, rays),
            (false, Frame::Chunk) => {
                self.trace_as::<Packed, ChunkMode>(Packed { bits: self.bits }, tris, rays)
            }
            (false, Frame::Parent) => {
                self.trace_as::<Packed, ParentMode>(Packed { bits: self.bits }, tris, rays)
            }
        }
    }

    fn trace_as<K: KeyReader, M: Mode>(
        &self,
        kr: K,
        tris: &[Triangle],
        rays: &[Ray],
    ) -> TraceStats {
        let max_key = (1u32 << self.bits) - 1;
        bvhlab_trace::trace_with(rays, QStack::<M::C<Aabb>>::new, |stack, ray| {
            let lanes = Scalar {
                rb: RayBox::new(ray),
                max_key,
                inv_max: 1.0 / max_key as f32,
            };
            self.trace_one::<K, M, Scalar>(kr, &lanes, tris, ray, stack)
        })
    }

    #[cfg(target_arch = "x86_64")]
    fn trace_sse<K: KeyReader, M: Mode>(
        &self,
        kr: K,
        tris: &[Triangle],
        rays: &[Ray],
    ) -> TraceStats {
        bvhlab_trace::trace_with(rays, QStack::<M::C<sse::Box2>>::new, |stack, ray| {
            // SAFETY: popcnt and sse4.1 were detected by the caller.
            unsafe { self.trace_one_sse::<K, M>(kr, tris, ray, stack) }
        })
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "popcnt,sse4.1")]
    unsafe fn trace_one_sse<K: KeyReader, M: Mode>(
        &self,
        kr: K,
        tris: &[Triangle],
        ray: &Ray,
        stack: &mut QStack<M::C<sse::Box2>>,
    ) -> (Hit, u32, u32) {
        let lanes = sse::Sse::new(ray, (1u32 << self.bits) - 1);
        self.trace_one::<K, M, sse::Sse>(kr, &lanes, tris, ray, stack)
    }

    #[inline(always)]
    fn leaf(&self, l: usize, tris: &[Triangle], ray: &Ray, best: &mut Hit, tests: &mut u32) {
        let (a, b) = (self.offsets[l] as usize, self.offsets[l + 1] as usize);
        for &p in &self.prims[a..b] {
            *tests += 1;
            if let Some(t) = intersect_triangle(ray.origin, ray.dir, &tris[p as usize]) {
                accept(t, p, best);
            }
        }
    }

    /// Closest hit of one ray, same semantics as `bvhlab_trace::trace`: steps = nodes entered
    /// (the root counts), both child boxes tested, the nearer entry first, popped entries culled
    /// when beyond the closest hit (with the slab test's margin).
    #[inline(always)]
    fn trace_one<K: KeyReader, M: Mode, L: Lanes>(
        &self,
        kr: K,
        lanes: &L,
        tris: &[Triangle],
        ray: &Ray,
        stack: &mut QStack<M::C<L::B>>,
    ) -> (Hit, u32, u32) {
        let mut best = Hit::within(ray.tmax);
        if self.nodes == 0 || ray.tmax.is_nan() || ray.tmax <= 0.0 {
            return (Hit::NONE, 0, 0);
        }
        // The implicit root: its exact box, tested as bvh2 tests its root.
        if self.world.is_empty() || RayBox::new(ray).hit(&self.world, best.t).is_none() {
            return (Hit::NONE, 0, 0);
        }
        let mut steps = 1u32;
        let mut tests = 0u32;
        let (words, keys) = (&self.words[..], &self.keys[..]);
        let finish = |best: Hit, steps, tests| {
            let h = best.found();
            (h, steps, tests)
        };
        if words.is_empty() {
            self.leaf(0, tris, ray, &mut best, &mut tests);
            return finish(best, steps, tests);
        }
        let wpc = self.chunk_bytes as usize / 8;
        let inner_groups = ((wpc - HEADER_WORDS) * 32 - 1) as u32;
        let limit = self.nodes as u32;
        stack.clear();
        // The sibling pair to test: chunk, slot of the first sibling, frame.
        let mut pc = 0usize;
        let mut ps = 0usize;
        let mut grid = lanes.grid_aabb(&self.world);
        // Chunk frame: the grid only changes with the chunk, so it is cached (Kilian 5.2.3: the
        // chunk frame needs no box per stack entry).
        let mut grid_chunk = 0usize;
        loop {
            let g = header(words, pc * wpc).node_offset as usize + ps;
            let (h0, h1, b0, b1) = lanes.test_pair(&grid, kr, keys, g, best.t);
            let mut cur = match (h0, h1) {
                (Some(t0), Some(t1)) => {
                    if t1 < t0 {
                        stack.push(Entry {
                            chunk: pc as u32,
                            slot: ps as u32,
                            t: t0,
                            b: M::carry(b0),
                        });
                        Some((pc, ps + 1, M::carry(b1)))
                    } else {
                        stack.push(Entry {
                            chunk: pc as u32,
                            slot: ps as u32 + 1,
                            t: t1,
                            b: M::carry(b1),
                        });
                        Some((pc, ps, M::carry(b0)))
                    }
                }
                (Some(_), None) => Some((pc, ps, M::carry(b0))),
                (None, Some(_)) => Some((pc, ps + 1, M::carry(b1))),
                (None, None) => stack.pop_within(best.t * SLAB_ROBUST).map(Entry::unpack),
            };
            // Enter nodes until an inner one gives the next pair to test.
            loop {
                let Some((c, s, b)) = cur else {
                    return finish(best, steps, tests);
                };
                steps += 1;
                if steps > limit {
                    return finish(best, steps, tests);
                }
                let base = c * wpc;
                let (r, inner) = rank_bit(&words[base + HEADER_WORDS..base + wpc], s);
                let h = header(words, base);
                if !inner {
                    let l = h.leaf_offset as usize + s - r as usize;
                    self.leaf(l, tris, ray, &mut best, &mut tests);
                    cur = stack.pop_within(best.t * SLAB_ROBUST).map(Entry::unpack);
                    continue;
                }
                if r < inner_groups {
                    pc = c;
                    ps = 2 * (r as usize + 1);
                    if M::PARENT {
                        grid = lanes.grid_box(&M::get(b));
                    } else if c != grid_chunk {
                        grid = lanes.grid_aabb(&chunk_box(words, base));
                        grid_chunk = c;
                    }
                } else {
                    pc = (h.child_chunks + r - inner_groups) as usize;
                    ps = 0;
                    grid = lanes.grid_aabb(&chunk_box(words, pc * wpc));
                    grid_chunk = pc;
                }
                break;
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Traversal helpers.
// ---------------------------------------------------------------------------------------------

/// Frame mode: what a stack entry carries. Chunk mode carries nothing (the frame is in the chunk
/// header); parent mode carries the node's dequantized box (Kilian 5.2.3's "extra stack of
/// AABBs").
pub(super) trait Mode {
    type C<T: Copy + Default + Send>: Copy + Default + Send;
    const PARENT: bool;
    fn carry<T: Copy + Default + Send>(b: T) -> Self::C<T>;
    fn get<T: Copy + Default + Send>(c: Self::C<T>) -> T;
}

struct ChunkMode;
impl Mode for ChunkMode {
    type C<T: Copy + Default + Send> = ();
    const PARENT: bool = false;
    #[inline(always)]
    fn carry<T: Copy + Default + Send>(_: T) {}
    #[inline(always)]
    fn get<T: Copy + Default + Send>(_: ()) -> T {
        T::default()
    }
}

struct ParentMode;
impl Mode for ParentMode {
    type C<T: Copy + Default + Send> = T;
    const PARENT: bool = true;
    #[inline(always)]
    fn carry<T: Copy + Default + Send>(b: T) -> T {
        b
    }
    #[inline(always)]
    fn get<T: Copy + Default + Send>(c: T) -> T {
        c
    }
}

/// How a sibling pair is dequantized and tested against the ray: portable (`Scalar`: `Grid` +
/// `RayBox::hit` on `Aabb`s) or SSE (`sse::Sse`, the same floats four lanes at a time).
pub(super) trait Lanes {
    type G: Copy;
    /// A dequantized child box, as carried in parent mode.
    type B: Copy + Default + Send;
    fn grid_aabb(&self, frame: &Aabb) -> Self::G;
    fn grid_box(&self, frame: &Self::B) -> Self::G;
    /// Entry distances (None = missed) and boxes of the siblings `g`, `g + 1`.
    fn test_pair<K: KeyReader>(
        &self,
        grid: &Self::G,
        kr: K,
        keys: &[u8],
        g: usize,
        tmax: f32,
    ) -> (Option<f32>, Option<f32>, Self::B, Self::B);
}

struct Scalar {
    rb: RayBox,
    max_key: u32,
    inv_max: f32,
}

impl Lanes for Scalar {
    type G = Grid;
    type B = Aabb;
    #[inline(always)]
    fn grid_aabb(&self, frame: &Aabb) -> Grid {
        Grid::new(frame, self.inv_max)
    }
    #[inline(always)]
    fn grid_box(&self, frame: &Aabb) -> Grid {
        Grid::new(frame, self.inv_max)
    }
    #[inline(always)]
    fn test_pair<K: KeyReader>(
        &self,
        grid: &Grid,
        kr: K,
        keys: &[u8],
        g: usize,
        tmax: f32,
    ) -> (Option<f32>, Option<f32>, Aabb, Aabb) {
        let k = kr.pair(keys, g);
        let (b0, b1) = grid.dequantize_pair(&k, self.max_key);
        (self.rb.hit(&b0, tmax), self.rb.hit(&b1, tmax), b0, b1)
    }
}

#[derive(Clone, Copy, Default)]
struct Entry<B> {
    chunk: u32,
    slot: u32,
    t: f32,
    b: B,
}

impl<B: Copy + Default> bvhlab_trace::Pending for Entry<B> {
    fn entry(&self) -> f32 {
        self.t
    }
}

impl<B> Entry<B> {
    #[inline(always)]
    fn unpack(self) -> (usize, usize, B) {
        (self.chunk as usize, self.slot as usize, self.b)
    }
}

/// Pending nodes (the shared fixed-then-spill stack of `bvhlab_trace`).
type QStack<B> = bvhlab_trace::Stack<Entry<B>>;
