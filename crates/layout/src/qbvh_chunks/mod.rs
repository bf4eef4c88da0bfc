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
use crate::{LayoutSpec, Memory};
use bvhlab_geom::{Aabb, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};
use serde::{Deserialize, Serialize};

mod build;
mod quant;
#[cfg(target_arch = "x86_64")]
mod sse;
mod traverse;
mod validate;


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
}

#[cfg(test)]
mod tests;
