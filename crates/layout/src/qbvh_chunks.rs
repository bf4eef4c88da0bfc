//! Kilian 5.2: quantized BVH in chunks.
//!
//! The input BVH's topology is kept exactly and split by Kilian's breadth-first chunker
//! ([`crate::chunks::chunk_bfs`], arity 2): 1 bit per node slot (1 = inner), `child(i) =
//! 2(rank(i) + 1)` for the first `groups - 1` inner slots of a chunk, `childchunk(i) =
//! first_child_chunk + rank(i) - (groups - 1)` for the later ones (4.2.1, 4.2.2.2).
//!
//! Every chunk is exactly `chunk_bytes` bytes, all chunks in one contiguous `Vec<u64>`
//! (`chunk_bytes / 8` words each, the memory counted is the memory traversal reads):
//!
//! | words | content |
//! |-------|---------|
//! | 0..3  | exact AABB of the chunk's implicit root (6 f32, min xyz then max xyz) |
//! | 3     | `child_chunks_offset` (low 32 bits) \| `leaf_offset` (high 32 bits) |
//! | 4     | `node_info_offset` (low 32 bits) \| 32 bits padding |
//! | 5..   | the bit field, bit i = word i / 64, bit i % 64 |
//!
//! The header is Kilian's 36 bytes (5.2.1.3), padded to 40 so that the bit field is u64-aligned
//! (his "40 bytes of offsets and other data", 6.3): 64-byte chunks hold 3 words = 192 node slots,
//! 128-byte chunks 11 words = 704 (5.2.1.3).
//!
//! Node info lives outside the chunks (5.2.1.1), one entry per node slot in bit order: the
//! quantization key, `bits` per coordinate (min xyz, max xyz), packed as a little-endian bit
//! stream of `6 * bits` bits per node. Kilian also stores the split axis there; we do not: our
//! traversal (like bvh2's) tests both child boxes anyway and visits the nearer *entry* first,
//! which is exact for the ray, so the axis (used only for ordering, 5.1.1) would be dead data.
//!
//! Leaf data (not topology): `offsets` (u32 per leaf in bit order, plus an end entry; the leaf's
//! primitives are `prims[offsets[l]..offsets[l + 1]]`) and `prims` (u32 per triangle).
//!
//! Quantization must be conservative (exact closest hits): Kilian's floor/ceil (alg. 3/4) is not
//! under float rounding (and alg. 4 returns `quantKey`, a typo). One dequantization,
//! `deq_value` (key 0 = frame min and the top key = frame max exactly), is used by build,
//! traversal, validation and SAH; the build picks the largest min key / smallest max key whose
//! *dequantized* value still contains the exact box (estimate, then check and step).
//!
//! Traversal: iterative with a spilling stack, same semantics as `bvhlab_trace::trace` (steps =
//! nodes entered, near entry first, culling with `SLAB_ROBUST`). On x86-64 with popcnt and SSE4.1
//! (detected at run time) a sibling pair is dequantized and slab-tested four lanes at a time with
//! the very same float operations as the portable path (`Grid` + `RayBox::hit`).
use crate::chunks::chunk_bfs;
use crate::{LayoutSpec, Memory};
use bvhlab_bvh::{Bvh, CostParams};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};
use bvhlab_trace::{accept, intersect_triangle, Hit, Ray, RayBox, TraceStats, SLAB_ROBUST};
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "qbvh_chunks",
    "Kilian 5.2 quantized BVH: bit-field topology in fixed-size chunks, `bits` per box coordinate, frame = chunk root or parent box",
    "Kilian 2021 5.2",
    &[
        ParamSpec {
            name: "bits",
            default: "8",
            kind: Kind::UInt { min: 1, max: 16 },
            about: "quantization bits per box coordinate (Kilian 5.2.1.1: 8)",
            in_label: false,
        },
        ParamSpec {
            name: "chunk_bytes",
            default: "64",
            kind: Kind::UInt { min: 48, max: MAX_CHUNK_BYTES },
            about: "bytes per chunk, a multiple of 8: 40-byte header + bit field (Kilian 5.2.1.3: 64 or 128)",
            in_label: false,
        },
        ParamSpec {
            name: "frame",
            default: "chunk",
            kind: Kind::Choice(&["chunk", "parent"]),
            about: "quantization frame: the chunk root's exact box (Kilian's choice) or the parent's box (5.2.3)",
            in_label: false,
        },
    ],
);

/// Chunk header: 36 bytes (box + three u32 offsets) padded to 40 = 5 words.
const HEADER_WORDS: usize = 5;
const MAX_CHUNK_BYTES: u32 = 1 << 16;

/// What a node's quantization key is relative to (Kilian 5.2.1.2, 5.2.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Frame {
    /// The exact box of the chunk's implicit root (stored in the chunk header): Kilian's choice.
    Chunk,
    /// The parent's dequantized box; the chunk root's children use the exact chunk box.
    Parent,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// Quantization bits per coordinate, 1..=16 (Kilian: 8).
    pub bits: u32,
    /// Bytes per chunk: a multiple of 8, at least 48 (40-byte header + one bit-field word).
    pub chunk_bytes: u32,
    pub frame: Frame,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            bits: 8,
            chunk_bytes: 64,
            frame: Frame::Chunk,
        }
    }
}

impl Config {
    pub fn from_spec(spec: &LayoutSpec) -> Result<Config, String> {
        let bits: u32 = spec.get("bits")?;
        if !(1..=16).contains(&bits) {
            return Err(format!("layout `qbvh_chunks`: bits must be in 1..=16, got {bits}"));
        }
        let chunk_bytes: u32 = spec.get("chunk_bytes")?;
        if !chunk_bytes.is_multiple_of(8) || !(48..=MAX_CHUNK_BYTES).contains(&chunk_bytes) {
            return Err(format!(
                "layout `qbvh_chunks`: chunk_bytes must be a multiple of 8 in 48..={MAX_CHUNK_BYTES} \
                 (40-byte header + at least one 64-bit bit-field word), got {chunk_bytes}"
            ));
        }
        let frame = match spec.get::<String>("frame")?.as_str() {
            "chunk" => Frame::Chunk,
            "parent" => Frame::Parent,
            other => {
                return Err(format!(
                    "layout `qbvh_chunks`: frame must be `chunk` or `parent`, got `{other}`"
                ))
            }
        };
        Ok(Config {
            bits,
            chunk_bytes,
            frame,
        })
    }

    fn words_per_chunk(&self) -> usize {
        self.chunk_bytes as usize / 8
    }

    /// Sibling groups (pairs) per chunk.
    fn groups(&self) -> usize {
        (self.words_per_chunk() - HEADER_WORDS) * 64 / 2
    }
}

// ---------------------------------------------------------------------------------------------
// Quantization: ONE dequantization function, used by build, traversal, validation and SAH.
// ---------------------------------------------------------------------------------------------

/// A quantization frame per axis: `deq(k) = lo + k * step` for `k < max_key`, `hi` for `k =
/// max_key` (so key 0 is `lo` and the top key `hi` exactly, whatever the rounding). `step` is
/// `(hi - lo) / max_key`, computed without overflow for huge coordinates and 0 for a zero-extent
/// axis (no division by the extent anywhere).
#[derive(Clone, Copy, Debug)]
struct Grid {
    lo: [f32; 3],
    hi: [f32; 3],
    step: [f32; 3],
}

impl Grid {
    #[inline(always)]
    fn new(frame: &Aabb, inv_max: f32) -> Grid {
        let lo = frame.min.to_array();
        let hi = frame.max.to_array();
        let mut step = [0.0; 3];
        for a in 0..3 {
            let d = hi[a] - lo[a];
            step[a] = if d.is_finite() {
                d * inv_max
            } else {
                // Finite except for bits = 1 (inv_max = 1) across the whole f32 range; clamped
                // so that key 0 still gives `lo + 0 * step = lo` (there are no middle keys then).
                (hi[a] * inv_max - lo[a] * inv_max).min(f32::MAX)
            };
        }
        Grid { lo, hi, step }
    }

    #[inline(always)]
    fn deq(&self, a: usize, k: u32, max_key: u32) -> f32 {
        deq_value(self.lo[a], self.step[a], self.hi[a], k, max_key)
    }

    /// Dequantized box of a key (min xyz, max xyz).
    #[inline(always)]
    fn dequantize(&self, k: &[u32], max_key: u32) -> Aabb {
        Aabb {
            min: Vec3::new(
                self.deq(0, k[0], max_key),
                self.deq(1, k[1], max_key),
                self.deq(2, k[2], max_key),
            ),
            max: Vec3::new(
                self.deq(0, k[3], max_key),
                self.deq(1, k[4], max_key),
                self.deq(2, k[5], max_key),
            ),
        }
    }

    /// The boxes of two siblings at once (the same `deq_value` per coordinate, written as one
    /// 12-lane loop so that it vectorizes).
    #[inline(always)]
    fn dequantize_pair(&self, k: &[u32; 12], max_key: u32) -> (Aabb, Aabb) {
        let mut o = [0.0f32; 12];
        for i in 0..12 {
            let a = i % 3;
            o[i] = deq_value(self.lo[a], self.step[a], self.hi[a], k[i], max_key);
        }
        let v = |j: usize| Vec3::new(o[j], o[j + 1], o[j + 2]);
        (Aabb::new(v(0), v(3)), Aabb::new(v(6), v(9)))
    }

    /// Largest key whose dequantized value is still <= `e` (0, i.e. `lo` exactly, when `e` is
    /// below the frame, NaN, or the axis has no extent). Kilian's floor (alg. 3) is not
    /// conservative under rounding; this checks the actual dequantized value and steps.
    fn key_min(&self, a: usize, e: f32, max_key: u32) -> u32 {
        let (lo, hi) = (self.lo[a], self.hi[a]);
        if !(e > lo && hi > lo) {
            return 0;
        }
        if e >= hi {
            return max_key;
        }
        let est = ((e as f64 - lo as f64) / (hi as f64 - lo as f64) * max_key as f64).floor();
        let mut k = if est.is_finite() {
            est.clamp(0.0, max_key as f64) as u32
        } else {
            0
        };
        while k > 0 && self.deq(a, k, max_key) > e {
            k -= 1;
        }
        while k < max_key && self.deq(a, k + 1, max_key) <= e {
            k += 1;
        }
        k
    }

    /// Smallest key whose dequantized value is still >= `e` (`max_key` when `e` is above the
    /// frame, NaN, or the axis has no extent).
    fn key_max(&self, a: usize, e: f32, max_key: u32) -> u32 {
        let (lo, hi) = (self.lo[a], self.hi[a]);
        if !(e < hi && hi > lo) {
            return max_key;
        }
        if e <= lo {
            return 0;
        }
        let est = ((e as f64 - lo as f64) / (hi as f64 - lo as f64) * max_key as f64).ceil();
        let mut k = if est.is_finite() {
            est.clamp(0.0, max_key as f64) as u32
        } else {
            max_key
        };
        while k < max_key && self.deq(a, k, max_key) < e {
            k += 1;
        }
        while k > 0 && self.deq(a, k - 1, max_key) >= e {
            k -= 1;
        }
        k
    }

    /// The tightest conservative key of `b` (a box inside the frame; outside parts are clamped
    /// to the frame, which `validate` then reports).
    fn quantize(&self, b: &Aabb, max_key: u32) -> [u32; 6] {
        let (mn, mx) = (b.min.to_array(), b.max.to_array());
        let mut k = [0u32; 6];
        for a in 0..3 {
            k[a] = self.key_min(a, mn[a], max_key);
            k[a + 3] = self.key_max(a, mx[a], max_key);
        }
        k
    }
}

/// THE dequantization (build, traversal, validation and SAH all go through here): key 0 gives `lo`
/// exactly (`lo + 0 * step`, `step` finite), the top key `hi` exactly; keys are at most 16 bits,
/// so the i32 conversion is exact (and one instruction, unlike u32).
#[inline(always)]
fn deq_value(lo: f32, step: f32, hi: f32, k: u32, max_key: u32) -> f32 {
    let v = lo + (k as i32) as f32 * step;
    if k >= max_key {
        hi
    } else {
        v
    }
}

// ---------------------------------------------------------------------------------------------
// Node info bit stream.
// ---------------------------------------------------------------------------------------------

fn write_key(keys: &mut [u8], bits: u32, node: usize, k: &[u32; 6]) {
    for (c, &v) in k.iter().enumerate() {
        let p = (node * 6 + c) * bits as usize;
        for b in 0..bits as usize {
            if v >> b & 1 == 1 {
                let q = p + b;
                keys[q / 8] |= 1 << (q % 8);
            }
        }
    }
}

/// Reads the 12 key coordinates of two sibling nodes `g`, `g + 1`.
trait KeyReader: Copy + Send + Sync {
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12];
    /// The pair as SSE key vectors (see `sse::from_u32`).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn pair_sse(&self, keys: &[u8], g: usize) -> [std::arch::x86_64::__m128i; 4] {
        sse::from_u32(&self.pair(keys, g))
    }
}

/// bits = 8: one byte per coordinate, the two siblings' keys are 12 consecutive bytes.
#[derive(Clone, Copy)]
struct Bytes8;

impl KeyReader for Bytes8 {
    #[inline(always)]
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12] {
        let s: &[u8; 12] = keys[6 * g..6 * g + 12].try_into().unwrap();
        s.map(|b| b as u32)
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn pair_sse(&self, keys: &[u8], g: usize) -> [std::arch::x86_64::__m128i; 4] {
        sse::from_bytes(keys[6 * g..6 * g + 12].try_into().unwrap())
    }
}

/// Any `bits`: each coordinate spans at most 16 bits, read as a little-endian u32 window that
/// starts at the coordinate's byte (shift <= 7), clamped to the stream end (then the shift grows
/// but `shift + bits <= 32` still holds because the coordinate ends inside the stream).
#[derive(Clone, Copy)]
struct Packed {
    bits: u32,
}

impl Packed {
    #[inline(always)]
    fn get(&self, keys: &[u8], p: usize) -> u32 {
        let mask = (1u32 << self.bits) - 1;
        if keys.len() >= 4 {
            let start = (p >> 3).min(keys.len() - 4);
            let w = u32::from_le_bytes(keys[start..start + 4].try_into().unwrap());
            (w >> (p - 8 * start)) & mask
        } else {
            let mut w = 0u32;
            for (i, &b) in keys.iter().enumerate() {
                w |= (b as u32) << (8 * i);
            }
            (w >> p) & mask
        }
    }
}

impl KeyReader for Packed {
    #[inline(always)]
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12] {
        // Three coordinates (3 * bits <= 48 bits) plus a shift <= 7 fit one unaligned u64
        // window: four window reads per pair; the stream's last bytes are read coordinate by
        // coordinate.
        let b = self.bits as usize;
        let mask = (1u64 << b) - 1;
        let mut out = [0u32; 12];
        for h in 0..4 {
            let p = (6 * g + 3 * h) * b;
            let byte = p >> 3;
            if byte + 8 <= keys.len() {
                let w = u64::from_le_bytes(keys[byte..byte + 8].try_into().unwrap()) >> (p & 7);
                out[3 * h] = (w & mask) as u32;
                out[3 * h + 1] = (w >> b & mask) as u32;
                out[3 * h + 2] = (w >> (2 * b) & mask) as u32;
            } else {
                for c in 0..3 {
                    out[3 * h + c] = self.get(keys, p + c * b);
                }
            }
        }
        out
    }
}

// ---------------------------------------------------------------------------------------------
// The layout.
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QbvhChunks {
    pub bits: u32,
    pub chunk_bytes: u32,
    pub frame: Frame,
    /// The exact root box (the root is implicit; tested first, as bvh2 tests its root).
    pub world: Aabb,
    /// All chunks, `chunk_bytes / 8` words each.
    pub words: Vec<u64>,
    /// Node info: `6 * bits` bits per node slot, in chunk order then bit order.
    pub keys: Vec<u8>,
    /// Per leaf (bit order) the start in `prims`, plus an end entry.
    pub offsets: Vec<u32>,
    pub prims: Vec<u32>,
    /// Nodes of the tree (slots + the implicit root; 0 for an empty BVH).
    pub nodes: u64,
    /// Mean chunk fill (Kilian fig. 4.16/5.4), from the chunker.
    pub fill: f64,
}

/// Per-chunk header fields.
#[derive(Clone, Copy)]
struct Header {
    child_chunks: u32,
    leaf_offset: u32,
    node_offset: u32,
}

#[inline(always)]
fn chunk_box(words: &[u64], base: usize) -> Aabb {
    let h: &[u64; 3] = words[base..base + 3].try_into().unwrap();
    let lo = |w: u64| f32::from_bits(w as u32);
    let hi = |w: u64| f32::from_bits((w >> 32) as u32);
    Aabb {
        min: Vec3::new(lo(h[0]), hi(h[0]), lo(h[1])),
        max: Vec3::new(hi(h[1]), lo(h[2]), hi(h[2])),
    }
}

#[inline(always)]
fn header(words: &[u64], base: usize) -> Header {
    let (a, b) = (words[base + 3], words[base + 4]);
    Header {
        child_chunks: a as u32,
        leaf_offset: (a >> 32) as u32,
        node_offset: b as u32,
    }
}

/// 1-bits strictly before bit `i` of a chunk's bit field, and bit `i` itself. Short bit fields
/// (chunks up to 72 bytes) are ranked without a data-dependent loop.
#[inline(always)]
fn rank_bit(bf: &[u64], i: usize) -> (u32, bool) {
    let (w, b) = (i >> 6, i & 63);
    let x = bf[w];
    let mut r = (x & ((1u64 << b) - 1)).count_ones();
    if bf.len() <= 4 {
        for (j, y) in bf.iter().enumerate() {
            r += (y & if j < w { !0 } else { 0 }).count_ones();
        }
    } else {
        for y in &bf[..w] {
            r += y.count_ones();
        }
    }
    (r, x >> b & 1 == 1)
}

impl QbvhChunks {
    pub fn build(bvh: &Bvh, cfg: &Config) -> Result<QbvhChunks, String> {
        let max_key = (1u32 << cfg.bits) - 1;
        let inv_max = 1.0 / max_key as f32;
        let wpc = cfg.words_per_chunk();
        let groups = cfg.groups();
        let mut q = QbvhChunks {
            bits: cfg.bits,
            chunk_bytes: cfg.chunk_bytes,
            frame: cfg.frame,
            world: Aabb::EMPTY,
            words: Vec::new(),
            keys: Vec::new(),
            offsets: vec![0],
            prims: Vec::new(),
            nodes: 0,
            fill: 0.0,
        };
        let n = bvh.nodes.len();
        if n == 0 {
            return Ok(q);
        }
        // Children table, and a walk from the root that rejects malformed input (out-of-range
        // children or primitives, nodes reached twice) instead of looping or panicking.
        let mut kids = vec![[0u32; 2]; n];
        let mut seen = vec![false; n];
        let mut stack = vec![0u32];
        seen[0] = true;
        let mut reached = 0u64;
        while let Some(i) = stack.pop() {
            reached += 1;
            let nd = &bvh.nodes[i as usize];
            if nd.is_leaf() {
                if nd.first as u64 + nd.count as u64 > bvh.prim_indices.len() as u64 {
                    return Err(format!("qbvh_chunks: leaf {i} references primitives out of range"));
                }
                continue;
            }
            let l = nd.first as usize;
            if l + 1 >= n {
                return Err(format!("qbvh_chunks: node {i} has children out of range"));
            }
            for c in [l, l + 1] {
                if seen[c] {
                    return Err(format!("qbvh_chunks: node {c} is reached twice"));
                }
                seen[c] = true;
                stack.push(c as u32);
            }
            kids[i as usize] = [l as u32, l as u32 + 1];
        }
        q.nodes = reached;
        q.world = bvh.nodes[0].bounds;
        let ch = chunk_bfs(0, 2, groups, |i| {
            if bvh.nodes[i as usize].is_leaf() {
                None
            } else {
                Some(&kids[i as usize][..])
            }
        })?;
        q.fill = ch.fill();
        let slots = ch.used_slots() as usize;
        if slots as u64 + 1 != reached {
            return Err("qbvh_chunks: chunker lost nodes".into());
        }
        q.words = vec![0u64; ch.chunks.len() * wpc];
        q.keys = vec![0u8; (slots * 6 * cfg.bits as usize).div_ceil(8)];
        let mut pair_grid: Vec<Grid> = Vec::new();
        for (ci, plan) in ch.chunks.iter().enumerate() {
            let base = ci * wpc;
            let root_box = bvh.nodes[plan.root as usize].bounds;
            let (mn, mx) = (root_box.min.to_array(), root_box.max.to_array());
            let pack = |a: f32, b: f32| a.to_bits() as u64 | (b.to_bits() as u64) << 32;
            q.words[base] = pack(mn[0], mn[1]);
            q.words[base + 1] = pack(mn[2], mx[0]);
            q.words[base + 2] = pack(mx[1], mx[2]);
            q.words[base + 3] = plan.first_child_chunk as u64 | (plan.leaf_offset as u64) << 32;
            q.words[base + 4] = plan.node_offset as u64;
            // Frames of the sibling pairs: pair 0 (the implicit root's children) uses the exact
            // chunk box; pair r + 1 belongs to the r-th inner slot (r < groups - 1), which
            // precedes it in bit order, so one pass in slot order has every frame ready.
            let root_grid = Grid::new(&root_box, inv_max);
            pair_grid.clear();
            pair_grid.resize(plan.slots.len() / 2, root_grid);
            let mut rank = 0usize;
            for (s, &node) in plan.slots.iter().enumerate() {
                let nd = &bvh.nodes[node as usize];
                let grid = pair_grid[s / 2];
                let key = grid.quantize(&nd.bounds, max_key);
                write_key(&mut q.keys, cfg.bits, plan.node_offset as usize + s, &key);
                if nd.is_leaf() {
                    q.offsets.pop();
                    q.offsets.push(q.prims.len() as u32);
                    let (f, c) = (nd.first as usize, nd.count as usize);
                    q.prims.extend_from_slice(&bvh.prim_indices[f..f + c]);
                    q.offsets.push(q.prims.len() as u32);
                } else {
                    q.words[base + HEADER_WORDS + s / 64] |= 1u64 << (s % 64);
                    if rank < groups - 1 {
                        pair_grid[rank + 1] = match cfg.frame {
                            Frame::Chunk => root_grid,
                            Frame::Parent => Grid::new(&grid.dequantize(&key, max_key), inv_max),
                        };
                    }
                    rank += 1;
                }
            }
        }
        if ch.chunks.is_empty() {
            // Leaf root: no chunks, one leaf.
            let nd = &bvh.nodes[0];
            let (f, c) = (nd.first as usize, nd.count as usize);
            q.prims.extend_from_slice(&bvh.prim_indices[f..f + c]);
            q.offsets.push(q.prims.len() as u32);
        }
        Ok(q)
    }

    pub fn chunks(&self) -> u64 {
        (self.words.len() / (self.chunk_bytes as usize / 8)) as u64
    }

    pub fn memory(&self) -> Memory {
        // Chunks + node info + the 24-byte exact root box.
        let topology = self.words.len() as u64 * 8 + self.keys.len() as u64 + 24;
        Memory {
            topology_bytes: topology,
            total_bytes: topology + 4 * (self.offsets.len() + self.prims.len()) as u64,
            nodes: self.nodes,
            chunks: self.chunks(),
            chunk_fill: self.fill,
            prim_refs: self.prims.len() as u64,
        }
    }

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
        let mut best = Hit {
            t: ray.tmax,
            prim: u32::MAX,
        };
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
            let h = if best.prim == u32::MAX {
                Hit::NONE
            } else {
                best
            };
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
                (None, None) => stack.pop_within(best.t * SLAB_ROBUST),
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
                    cur = stack.pop_within(best.t * SLAB_ROBUST);
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

    /// Walks the stored tree from the root (iteratively) and reports every node: (parent id,
    /// dequantized box, leaf primitive range or None for inner nodes). Ids are in visit order
    /// (parents before children). Errors on structural inconsistencies.
    fn walk(
        &self,
        mut visit: impl FnMut(usize, Aabb, Option<(usize, usize)>),
    ) -> Result<(), String> {
        if self.nodes == 0 {
            return Ok(());
        }
        let wpc = self.chunk_bytes as usize / 8;
        if self.bits == 0
            || self.bits > 16
            || wpc <= HEADER_WORDS
            || !self.words.len().is_multiple_of(wpc)
        {
            return Err("qbvh_chunks: bad parameters or chunk array length".into());
        }
        let nchunks = self.words.len() / wpc;
        let expect_keys =
            (self.nodes.saturating_sub(1) as usize * 6 * self.bits as usize).div_ceil(8);
        if self.keys.len() != expect_keys {
            return Err(format!(
                "qbvh_chunks: node info has {} bytes, expected {expect_keys}",
                self.keys.len()
            ));
        }
        let cap = (wpc - HEADER_WORDS) * 64;
        let inner_groups = (cap / 2 - 1) as u32;
        let max_key = (1u32 << self.bits) - 1;
        let inv_max = 1.0 / max_key as f32;
        let leaves = self
            .offsets
            .len()
            .checked_sub(1)
            .ok_or("qbvh_chunks: empty offset list")?;
        let leaf_range = |l: usize| -> Result<(usize, usize), String> {
            if l >= leaves {
                return Err(format!("qbvh_chunks: leaf {l} out of range ({leaves} leaves)"));
            }
            let (a, b) = (self.offsets[l] as usize, self.offsets[l + 1] as usize);
            if a >= b || b > self.prims.len() {
                return Err(format!("qbvh_chunks: leaf {l} has a bad primitive range {a}..{b}"));
            }
            Ok((a, b))
        };
        if nchunks == 0 {
            if leaves != 1 || self.nodes != 1 {
                return Err("qbvh_chunks: a leaf root needs exactly one leaf and one node".into());
            }
            visit(usize::MAX, self.world, Some(leaf_range(0)?));
            return Ok(());
        }
        visit(usize::MAX, self.world, None);
        let slots = (self.nodes - 1) as usize;
        let kr = Packed { bits: self.bits };
        let mut chunk_seen = vec![false; nchunks];
        let mut slot_seen = vec![false; slots];
        let mut leaf_seen = vec![false; leaves];
        // Pending pairs: (chunk, first slot, frame box, parent id).
        let mut todo: Vec<(usize, usize, Aabb, usize)> = vec![(0, 0, self.world, 0)];
        chunk_seen[0] = true;
        let mut next_id = 1usize;
        let mut count = 1u64;
        while let Some((c, s, frame, parent)) = todo.pop() {
            let base = c * wpc;
            let h = header(&self.words, base);
            let bf = &self.words[base + HEADER_WORDS..base + wpc];
            if s + 1 >= cap {
                return Err(format!("qbvh_chunks: chunk {c} slot {s} beyond the bit field"));
            }
            let g = h.node_offset as usize + s;
            if g + 1 >= slots {
                return Err(format!("qbvh_chunks: node info index {g} out of range"));
            }
            let grid = Grid::new(&frame, inv_max);
            let k = kr.pair(&self.keys, g);
            for j in 0..2 {
                if std::mem::replace(&mut slot_seen[g + j], true) {
                    return Err(format!("qbvh_chunks: node slot {} reached twice", g + j));
                }
                let id = next_id;
                next_id += 1;
                count += 1;
                let b = grid.dequantize(&k[6 * j..6 * j + 6], max_key);
                let (r, inner) = rank_bit(bf, s + j);
                if !inner {
                    let l = h.leaf_offset as usize + s + j - r as usize;
                    let range = leaf_range(l)?;
                    if std::mem::replace(&mut leaf_seen[l], true) {
                        return Err(format!("qbvh_chunks: leaf {l} reached twice"));
                    }
                    visit(parent, b, Some(range));
                    continue;
                }
                visit(parent, b, None);
                if r < inner_groups {
                    let f = match self.frame {
                        Frame::Chunk => chunk_box(&self.words, base),
                        Frame::Parent => b,
                    };
                    todo.push((c, 2 * (r as usize + 1), f, id));
                } else {
                    let cc = (h.child_chunks + r - inner_groups) as usize;
                    if cc >= nchunks || std::mem::replace(&mut chunk_seen[cc], true) {
                        return Err(format!("qbvh_chunks: child chunk {cc} out of range or shared"));
                    }
                    todo.push((cc, 0, chunk_box(&self.words, cc * wpc), id));
                }
            }
        }
        if count != self.nodes {
            return Err(format!(
                "qbvh_chunks: {count} nodes reached, {} stored",
                self.nodes
            ));
        }
        if slot_seen.iter().any(|s| !s) || chunk_seen.iter().any(|s| !s) {
            return Err("qbvh_chunks: unreachable chunks or node slots".into());
        }
        if leaf_seen.iter().any(|s| !s) {
            return Err("qbvh_chunks: unreachable leaves".into());
        }
        Ok(())
    }

    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        if self.nodes == 0 {
            return 0.0;
        }
        // Thesis eq. 4 with the boxes traversal tests (same normalisation as bvh metrics).
        let root_sa = self.world.area_f64();
        let degenerate = root_sa.is_nan() || root_sa <= 0.0;
        let ratio = |sa: f64| if degenerate { 1.0 } else { sa / root_sa };
        let (mut inner, mut leaf) = (0.0f64, 0.0f64);
        let r = self.walk(|_, b, range| match range {
            Some((a, e)) => leaf += ratio(b.area_f64()) * (e - a) as f64,
            None => inner += ratio(b.area_f64()),
        });
        if r.is_err() {
            return f64::NAN;
        }
        cost.c_t as f64 * inner + cost.c_i as f64 * leaf
    }

    pub fn validate(&self, tris: &[Triangle]) -> Result<(), String> {
        if self.offsets.first() != Some(&0) || self.offsets.windows(2).any(|w| w[0] > w[1]) {
            return Err("qbvh_chunks: offset list does not start at 0 or decreases".into());
        }
        if self.nodes > 0 && self.offsets.last().map(|&x| x as usize) != Some(self.prims.len()) {
            return Err("qbvh_chunks: offset list does not end at the primitive count".into());
        }
        let mut seen = vec![false; tris.len()];
        for &p in &self.prims {
            let s = seen
                .get_mut(p as usize)
                .ok_or_else(|| format!("qbvh_chunks: primitive {p} out of range"))?;
            if std::mem::replace(s, true) {
                return Err(format!("qbvh_chunks: triangle {p} referenced twice"));
            }
        }
        if let Some(t) = seen.iter().position(|s| !s) {
            return Err(format!("qbvh_chunks: triangle {t} not referenced"));
        }
        // Decode the tree, then check bottom-up that every dequantized box contains the exact
        // boxes of all triangles below it.
        let mut parent = Vec::new();
        let mut boxes = Vec::new();
        let mut below = Vec::new();
        self.walk(|p, b, range| {
            parent.push(p);
            boxes.push(b);
            let mut u = Aabb::EMPTY;
            if let Some((a, e)) = range {
                for &t in &self.prims[a..e] {
                    u.grow(&tris[t as usize].bounds());
                }
            }
            below.push(u);
        })?;
        for id in (0..boxes.len()).rev() {
            let u = below[id];
            if !u.is_empty() && !boxes[id].contains(&u) {
                return Err(format!(
                    "qbvh_chunks: node {id}: dequantized box {:?} does not contain its triangles {:?}",
                    boxes[id], u
                ));
            }
            if id > 0 {
                let p = parent[id];
                below[p] = below[p].union(&u);
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Traversal helpers.
// ---------------------------------------------------------------------------------------------

/// Frame mode: what a stack entry carries. Chunk mode carries nothing (the frame is in the chunk
/// header); parent mode carries the node's dequantized box (Kilian 5.2.3's "extra stack of
/// AABBs").
trait Mode {
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
trait Lanes {
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

/// SSE4.1 version of the pair test. Lane layout of every vector: (x, y, z, x); the duplicated x
/// lane does not change a min/max reduction. Every lane computes exactly the scalar float
/// operations of `deq_value`, `Grid::new` and `RayBox::hit` (mulps/addps are the same IEEE
/// operations, minps/maxps are the same `a < b ? a : b` selections, and the reduction order does
/// not matter without NaNs, which cannot occur with finite boxes and the finite inverse
/// direction), so both paths give bit-identical hits, steps and tests. Rays with a zero direction
/// component call `RayBox::hit` itself (it tests such an axis by the origin's position).
#[cfg(target_arch = "x86_64")]
mod sse {
    use super::{Aabb, KeyReader, Ray, SLAB_ROBUST};
    use std::arch::x86_64::*;

    #[derive(Clone, Copy)]
    pub struct G {
        lo: __m128,
        step: __m128,
        hi: __m128,
    }

    #[derive(Clone, Copy)]
    pub struct Box2 {
        min: __m128,
        max: __m128,
    }

    impl Box2 {
        #[inline(always)]
        unsafe fn aabb(&self) -> Aabb {
            let (mut a, mut b) = ([0.0f32; 4], [0.0f32; 4]);
            _mm_storeu_ps(a.as_mut_ptr(), self.min);
            _mm_storeu_ps(b.as_mut_ptr(), self.max);
            Aabb::new(
                bvhlab_geom::Vec3::new(a[0], a[1], a[2]),
                bvhlab_geom::Vec3::new(b[0], b[1], b[2]),
            )
        }
    }

    impl Default for Box2 {
        #[inline(always)]
        fn default() -> Self {
            // SAFETY: SSE is baseline on x86_64.
            unsafe {
                Box2 {
                    min: _mm_setzero_ps(),
                    max: _mm_setzero_ps(),
                }
            }
        }
    }

    pub struct Sse {
        /// A direction component is zero: `RayBox::hit` treats that axis specially (by the
        /// origin's position), so such rays use it on the dequantized boxes.
        parallel: bool,
        rb: bvhlab_trace::RayBox,
        o: __m128,
        inv: __m128,
        max_key: __m128i,
        inv_max: __m128,
    }

    #[inline(always)]
    unsafe fn xyzx(x: f32, y: f32, z: f32) -> __m128 {
        _mm_setr_ps(x, y, z, x)
    }

    impl Sse {
        #[inline(always)]
        pub unsafe fn new(ray: &Ray, max_key: u32) -> Sse {
            let rb = bvhlab_trace::RayBox::new(ray);
            Sse {
                parallel: ray.dir.x == 0.0 || ray.dir.y == 0.0 || ray.dir.z == 0.0,
                o: xyzx(rb.origin.x, rb.origin.y, rb.origin.z),
                inv: xyzx(rb.inv_dir.x, rb.inv_dir.y, rb.inv_dir.z),
                max_key: _mm_set1_epi32(max_key as i32),
                inv_max: _mm_set1_ps(1.0 / max_key as f32),
                rb,
            }
        }

        /// `Grid::new`, four lanes.
        #[inline(always)]
        unsafe fn grid(&self, lo: __m128, hi: __m128) -> G {
            let d = _mm_sub_ps(hi, lo);
            let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), d);
            let finite = _mm_cmplt_ps(abs, _mm_set1_ps(f32::INFINITY));
            let far = _mm_min_ps(
                _mm_sub_ps(_mm_mul_ps(hi, self.inv_max), _mm_mul_ps(lo, self.inv_max)),
                _mm_set1_ps(f32::MAX),
            );
            let step = _mm_blendv_ps(far, _mm_mul_ps(d, self.inv_max), finite);
            G { lo, step, hi }
        }

        /// `deq_value`, four lanes.
        #[inline(always)]
        unsafe fn deq(&self, g: &G, k: __m128i) -> __m128 {
            let v = _mm_add_ps(g.lo, _mm_mul_ps(_mm_cvtepi32_ps(k), g.step));
            let top = _mm_castsi128_ps(_mm_cmpeq_epi32(k, self.max_key));
            _mm_blendv_ps(v, g.hi, top)
        }
    }

    impl super::Lanes for Sse {
        type G = G;
        type B = Box2;
        #[inline(always)]
        fn grid_aabb(&self, f: &Aabb) -> G {
            unsafe {
                self.grid(
                    xyzx(f.min.x, f.min.y, f.min.z),
                    xyzx(f.max.x, f.max.y, f.max.z),
                )
            }
        }
        #[inline(always)]
        fn grid_box(&self, f: &Box2) -> G {
            unsafe { self.grid(f.min, f.max) }
        }
        #[inline(always)]
        fn test_pair<K: KeyReader>(
            &self,
            g: &G,
            kr: K,
            keys: &[u8],
            i: usize,
            tmax: f32,
        ) -> (Option<f32>, Option<f32>, Box2, Box2) {
            unsafe {
                let [k0n, k0x, k1n, k1x] = kr.pair_sse(keys, i);
                let b0 = Box2 {
                    min: self.deq(g, k0n),
                    max: self.deq(g, k0x),
                };
                let b1 = Box2 {
                    min: self.deq(g, k1n),
                    max: self.deq(g, k1x),
                };
                if self.parallel {
                    let (a0, a1) = (b0.aabb(), b1.aabb());
                    return (self.rb.hit(&a0, tmax), self.rb.hit(&a1, tmax), b0, b1);
                }
                // RayBox::hit for both boxes.
                let slab = |b: &Box2| {
                    let t0 = _mm_mul_ps(_mm_sub_ps(b.min, self.o), self.inv);
                    let t1 = _mm_mul_ps(_mm_sub_ps(b.max, self.o), self.inv);
                    (_mm_min_ps(t0, t1), _mm_max_ps(t0, t1))
                };
                let (n0, f0) = slab(&b0);
                let (n1, f1) = slab(&b1);
                // Lanes (box0, box1): near = max(x, y, z, 0), far = min(x, y, z, tmax).
                let nl = _mm_unpacklo_ps(n0, n1); // x0 x1 y0 y1
                let nh = _mm_unpackhi_ps(n0, n1); // z0 z1 x0 x1
                let near = _mm_max_ps(
                    _mm_max_ps(nl, _mm_movehl_ps(nl, nl)),
                    _mm_max_ps(nh, _mm_setzero_ps()),
                );
                let fl = _mm_unpacklo_ps(f0, f1);
                let fh = _mm_unpackhi_ps(f0, f1);
                let far = _mm_mul_ps(
                    _mm_min_ps(
                        _mm_min_ps(fl, _mm_movehl_ps(fl, fl)),
                        _mm_min_ps(fh, _mm_set1_ps(tmax)),
                    ),
                    _mm_set1_ps(SLAB_ROBUST),
                );
                let m = _mm_movemask_ps(_mm_cmple_ps(near, far));
                let mut t = [0.0f32; 4];
                _mm_storeu_ps(t.as_mut_ptr(), near);
                (
                    (m & 1 != 0).then_some(t[0]),
                    (m & 2 != 0).then_some(t[1]),
                    b0,
                    b1,
                )
            }
        }
    }

    /// (min, max, min, max) key vectors of a sibling pair, lanes (x, y, z, x), from the 12
    /// coordinates in stream order.
    #[inline(always)]
    pub unsafe fn from_u32(k: &[u32; 12]) -> [__m128i; 4] {
        let v =
            |j: usize| _mm_setr_epi32(k[j] as i32, k[j + 1] as i32, k[j + 2] as i32, k[j] as i32);
        [v(0), v(3), v(6), v(9)]
    }

    /// Byte shuffles and per-lane multipliers that turn an unaligned u64 window of the key stream
    /// into one key vector (lanes x, y, z, x of three consecutive coordinates): lane j takes the 3
    /// bytes holding its coordinate, `* 2^(7 - r)` then `>> 7` shifts each lane right by its own
    /// residual r (SSE4.1 has no per-lane variable shift), then the mask. Indexed by [half of a
    /// byte the pair starts at (odd bits only)][vector h = coordinates 3h..3h + 3 of the pair].
    pub struct PackedTables {
        shuf: [[__m128i; 4]; 2],
        mul: [[__m128i; 4]; 2],
        mask: __m128i,
    }

    impl PackedTables {
        pub fn new(bits: u32) -> PackedTables {
            let b = bits as usize;
            let mut shuf = [[[0x80u8; 16]; 4]; 2];
            let mut mul = [[[0u32; 4]; 4]; 2];
            for (par, (sh, mu)) in shuf.iter_mut().zip(mul.iter_mut()).enumerate() {
                for h in 0..4 {
                    let p = 4 * par + 3 * h * b; // window starts at byte p >> 3
                    for (j, c) in [0usize, 1, 2, 0].into_iter().enumerate() {
                        let off = (p & 7) + c * b;
                        for q in 0..3 {
                            sh[h][4 * j + q] = ((off >> 3) + q) as u8;
                        }
                        mu[h][j] = 1 << (7 - (off & 7));
                    }
                }
            }
            // SAFETY: plain SSE2 loads of local arrays.
            unsafe {
                let ld = |a: &[u8; 16]| _mm_loadu_si128(a.as_ptr() as *const __m128i);
                let ldm = |a: &[u32; 4]| _mm_loadu_si128(a.as_ptr() as *const __m128i);
                PackedTables {
                    shuf: [0, 1].map(|i| std::array::from_fn(|h| ld(&shuf[i][h]))),
                    mul: [0, 1].map(|i| std::array::from_fn(|h| ldm(&mul[i][h]))),
                    mask: _mm_set1_epi32(((1u32 << bits) - 1) as i32),
                }
            }
        }
    }

    /// `Packed` with the SSE key path.
    #[derive(Clone, Copy)]
    pub struct PackedSse<'a> {
        pub bits: u32,
        pub t: &'a PackedTables,
    }

    // SAFETY: the tables are plain data, only read.
    unsafe impl Send for PackedTables {}
    unsafe impl Sync for PackedTables {}

    impl KeyReader for PackedSse<'_> {
        #[inline(always)]
        fn pair(&self, keys: &[u8], g: usize) -> [u32; 12] {
            super::Packed { bits: self.bits }.pair(keys, g)
        }
        #[inline(always)]
        unsafe fn pair_sse(&self, keys: &[u8], g: usize) -> [__m128i; 4] {
            let b = self.bits as usize;
            let p0 = 6 * g * b; // g is even: p0 % 8 is 0 or 4
            let par = (p0 >> 2) & 1;
            let t = self.t;
            #[inline(always)]
            unsafe fn one(
                t: &PackedTables,
                keys: &[u8],
                p: usize,
                par: usize,
                h: usize,
            ) -> __m128i {
                let byte = p >> 3;
                let w = if byte + 8 <= keys.len() {
                    u64::from_le_bytes(keys[byte..byte + 8].try_into().unwrap())
                } else {
                    let mut a = [0u8; 8];
                    let tail = &keys[byte.min(keys.len())..];
                    a[..tail.len()].copy_from_slice(tail);
                    u64::from_le_bytes(a)
                };
                let v = _mm_shuffle_epi8(_mm_cvtsi64_si128(w as i64), t.shuf[par][h]);
                let v = _mm_srli_epi32(_mm_mullo_epi32(v, t.mul[par][h]), 7);
                _mm_and_si128(v, t.mask)
            }
            [
                one(t, keys, p0, par, 0),
                one(t, keys, p0 + 3 * b, par, 1),
                one(t, keys, p0 + 6 * b, par, 2),
                one(t, keys, p0 + 9 * b, par, 3),
            ]
        }
    }

    /// The same from 12 key bytes (bits = 8), with one byte shuffle per vector.
    #[inline(always)]
    pub unsafe fn from_bytes(b: &[u8; 12]) -> [__m128i; 4] {
        let lo = u64::from_le_bytes(b[..8].try_into().unwrap());
        let hi = u32::from_le_bytes(b[8..].try_into().unwrap());
        let x = _mm_set_epi64x(hi as i64, lo as i64);
        let z = -128i8; // pshufb: high bit set = zero byte
        let sh = |j: i8| _mm_setr_epi8(j, z, z, z, j + 1, z, z, z, j + 2, z, z, z, j, z, z, z);
        [
            _mm_shuffle_epi8(x, sh(0)),
            _mm_shuffle_epi8(x, sh(3)),
            _mm_shuffle_epi8(x, sh(6)),
            _mm_shuffle_epi8(x, sh(9)),
        ]
    }
}

#[derive(Clone, Copy, Default)]
struct Entry<B> {
    chunk: u32,
    slot: u32,
    t: f32,
    b: B,
}

const STACK_SIZE: usize = 64;

/// LIFO of pending nodes: fixed array first, then a spill vector above it (deep trees never
/// overflow, as in `bvhlab_trace::Stack`).
struct QStack<B> {
    items: [Entry<B>; STACK_SIZE],
    len: usize,
    spill: Vec<Entry<B>>,
}

impl<B: Copy + Default> QStack<B> {
    fn new() -> Self {
        QStack {
            items: [Entry::default(); STACK_SIZE],
            len: 0,
            spill: Vec::new(),
        }
    }
    #[inline(always)]
    fn clear(&mut self) {
        self.len = 0;
        self.spill.clear();
    }
    #[inline(always)]
    fn push(&mut self, e: Entry<B>) {
        if self.len < STACK_SIZE {
            self.items[self.len] = e;
            self.len += 1;
        } else {
            self.spill.push(e);
        }
    }
    #[inline(always)]
    fn pop(&mut self) -> Option<Entry<B>> {
        if let Some(e) = self.spill.pop() {
            return Some(e);
        }
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        Some(self.items[self.len])
    }
    /// Pops until an entry whose entry distance is within `limit` (closer hits cull the rest).
    #[inline(always)]
    fn pop_within(&mut self, limit: f32) -> Option<(usize, usize, B)> {
        while let Some(e) = self.pop() {
            if e.t <= limit {
                return Some((e.chunk as usize, e.slot as usize, e.b));
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dequantize_hits_the_frame_ends_and_keys_are_conservative() {
        for bits in [1u32, 2, 4, 8, 12, 16] {
            let m = (1u32 << bits) - 1;
            let inv = 1.0 / m as f32;
            for f in [
                Aabb::new(Vec3::new(-1.0, 0.0, 1e6), Vec3::new(3.0, 0.0, 1e6 + 0.125)),
                Aabb::new(Vec3::splat(-3.0e38), Vec3::splat(3.0e38)),
                Aabb::new(Vec3::splat(1e-30), Vec3::splat(2e-30)),
            ] {
                let g = Grid::new(&f, inv);
                for a in 0..3 {
                    assert_eq!(g.deq(a, 0, m), f.min[a]);
                    assert_eq!(g.deq(a, m, m), f.max[a]);
                }
                for i in 0..=100 {
                    let s = i as f32 / 100.0;
                    let e = f.min * (1.0 - s) + f.max * s;
                    let e = e.clamp(f.min, f.max);
                    let b = Aabb::new(e, e);
                    let k = g.quantize(&b, m);
                    assert!(g.dequantize(&k, m).contains(&b), "bits {bits} {f:?} {e}");
                }
            }
        }
    }

    #[test]
    fn packed_reader_matches_writer() {
        for bits in 1..=16u32 {
            let n = 7;
            let mut keys = vec![0u8; (n * 6 * bits as usize).div_ceil(8)];
            let m = (1u32 << bits) - 1;
            let key = |i: usize| {
                std::array::from_fn::<u32, 6, _>(|c| {
                    ((i * 31 + c * 7) as u32).wrapping_mul(2654435761u32) >> 7 & m
                })
            };
            for i in 0..n {
                write_key(&mut keys, bits, i, &key(i));
            }
            let kr = Packed { bits };
            for i in 0..n - 1 {
                let p = kr.pair(&keys, i);
                assert_eq!(&p[..6], &key(i)[..]);
                assert_eq!(&p[6..], &key(i + 1)[..]);
                if bits == 8 {
                    assert_eq!(Bytes8.pair(&keys, i), p);
                }
            }
        }
    }
}
