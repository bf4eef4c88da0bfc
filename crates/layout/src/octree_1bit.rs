//! Kilian 4.2: the 1-bit octree: the basic octree's topology (same construction, same parameters)
//! stored as one bit per node (1 = interior, 0 = leaf) in breadth-first order, children found by
//! Jacobson's rank (`child(i) = 8 (rank(i) + 1)`, 4.2.1), the bit field cut into fixed-size chunks.
//!
//! Two fills (`fill`):
//! - `bfs` (Kilian 4.2.2, default): each chunk holds the breadth-first subtree below one implicit
//!   root (`crate::chunks::chunk_bfs`), as `child_chunks_offset: u32, leaf_offset: u32` + the bit
//!   field (u64 words); `chunk_bytes` B give `(B - 8) * 8` node slots = `B - 8` sibling groups
//!   (16 B: 64 slots, 32: 192, 64: 448, 128: 960; 4.2.2.5). Nodes are addressed (chunk, slot).
//!   Leaves are numbered chunk by chunk (4.2.2.4): `leaf_offset + i - rank(i)`.
//! - `dense` (Kilian 7.1, second paragraph): ONE breadth-first bit field over the whole octree; the
//!   chunks are milestones of `B * 8 - 32` consecutive bits, each headed by a u32 = number of 1-bits
//!   before it, so every slot is used (16 B: 96 nodes per chunk, 1.33 bits per node) and
//!   `rank(i) = milestone + popcount within the chunk`; `child(i) = 8 (rank(i) + 1)` and leaf
//!   `i - rank(i)` globally. Nodes are addressed by their global bit index.
//!
//! Leaves: `offset_list` (u32 per leaf + end) into `primitives_list` (the basic octree's
//! references, same order inside each leaf, so traversal does the same tests in the same order).
//! The root is implicit: no chunk (no bits) means the root is leaf 0.
use crate::chunks::{chunk_bfs, rank};
use crate::octree::{self, sah_topo, trace_topo, validate_topo, Expand, Octree, Topo};
use crate::{LayoutSpec, Memory};
use bvhlab_bvh::CostParams;
use bvhlab_geom::{Aabb, Triangle};
use bvhlab_params::{Kind, Method, ParamSpec};
use bvhlab_trace::{Ray, TraceStats};
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "octree_1bit",
    "Kilian 4.2 1-bit octree in fixed-size chunks (ignores the BVH)",
    "Kilian 2021 4.2",
    &[
        ParamSpec {
            name: "chunk_bytes",
            default: "16",
            kind: Kind::UInt { min: 16, max: MAX_CHUNK_BYTES },
            about: "bytes per chunk, a multiple of 8 (Kilian 4.2.2.5: 16, 32, 64, 128)",
            in_label: false,
        },
        ParamSpec {
            name: "fill",
            default: "bfs",
            kind: Kind::Choice(&["bfs", "dense"]),
            about: "bfs: a breadth-first subtree per chunk (Kilian 4.2.2); dense: one bit field, chunks as rank milestones (Kilian 7.1)",
            in_label: false,
        },
        octree::PARAMS[0],
        octree::PARAMS[1],
        octree::PARAMS[2],
        octree::PARAMS[3],
    ],
);

/// Largest chunk accepted (the rank inside a chunk is linear in its words).
pub const MAX_CHUNK_BYTES: u32 = 4096;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Fill {
    /// Kilian 4.2.2: one breadth-first subtree per chunk.
    Bfs,
    /// Kilian 7.1: one global breadth-first bit field, chunks as rank milestones.
    Dense,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Config {
    pub base: octree::Config,
    pub chunk_bytes: u32,
    pub fill: Fill,
}

impl Config {
    pub fn from_spec(spec: &LayoutSpec) -> Result<Config, String> {
        let base = octree::Config {
            prim_threshold: spec.get("prim_threshold")?,
            mult_threshold: spec.get("mult_threshold")?,
            max_depth: spec.get("max_depth")?,
            overlap: octree::parse_overlap(spec)?,
        };
        let fill = match spec.get::<String>("fill")?.as_str() {
            "bfs" => Fill::Bfs,
            "dense" => Fill::Dense,
            other => {
                return Err(format!(
                    "layout `{}`: fill must be `bfs` or `dense` (got `{other}`)",
                    spec.name
                ))
            }
        };
        let cfg = Config {
            base,
            chunk_bytes: spec.get("chunk_bytes")?,
            fill,
        };
        cfg.check(&spec.name)?;
        Ok(cfg)
    }

    pub fn check(&self, name: &str) -> Result<(), String> {
        self.base.check(name)?;
        let b = self.chunk_bytes;
        if b < 16 || !b.is_multiple_of(8) || b > MAX_CHUNK_BYTES {
            return Err(format!(
                "layout `{name}`: chunk_bytes must be a multiple of 8 in 16..={MAX_CHUNK_BYTES} (16, 32, 64, 128 in Kilian 4.2.2.5; got {b})"
            ));
        }
        Ok(())
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Octree1Bit {
    pub world: Aabb,
    pub margin: f64,
    pub config: Config,
    /// All chunks, `chunk_bytes / 8` words each. bfs: word 0 = child_chunks_offset (low 32 bits)
    /// | leaf_offset (high 32), words 1.. = slot bits. dense: word 0 low 32 bits = 1-bits before
    /// the chunk, the chunk's node bits follow (bit 32 of word 0 onwards).
    pub words: Vec<u64>,
    pub chunks: u64,
    /// Octree nodes including the implicit root.
    pub nodes: u64,
    pub chunk_fill: f64,
    /// Kilian's `offset_list`: leaf l owns `prims[offsets[l]..offsets[l + 1]]`.
    pub offsets: Vec<u32>,
    pub prims: Vec<u32>,
}

impl Octree1Bit {
    pub fn build(tris: &[Triangle], cfg: &Config) -> Result<Octree1Bit, String> {
        Self::build_until(tris, cfg, None)
    }

    /// `build` with the basic octree's deadline (`Octree::build_until`).
    pub fn build_until(
        tris: &[Triangle],
        cfg: &Config,
        deadline: Option<std::time::Instant>,
    ) -> Result<Octree1Bit, String> {
        cfg.check("octree_1bit")?;
        let o = Octree::build_until(tris, &cfg.base, deadline)?;
        Octree1Bit::from_octree(&o, cfg)
    }

    /// The 1-bit form of a basic octree (its nodes must be in breadth-first order, as
    /// `Octree::build` makes them).
    pub fn from_octree(o: &Octree, cfg: &Config) -> Result<Octree1Bit, String> {
        let wpc = (cfg.chunk_bytes / 8) as usize;
        let leaf_prims = |n: usize| {
            let s = (o.nodes[n] >> 1) as usize;
            &o.prims[s..s + o.sizes[n] as usize]
        };
        let mut offsets = vec![0u32];
        let mut prims = Vec::with_capacity(o.prims.len());
        let mut push_leaf = |n: usize, offsets: &mut Vec<u32>| {
            prims.extend_from_slice(leaf_prims(n));
            offsets.push(prims.len() as u32);
        };
        let (words, chunks, fill);
        if o.nodes[0] & 1 == 0 {
            push_leaf(0, &mut offsets);
            (words, chunks, fill) = (Vec::new(), 0u64, 0.0);
        } else {
            match cfg.fill {
                Fill::Bfs => {
                    let groups = cfg.chunk_bytes as usize - 8;
                    let ids: Vec<u32> = (0..o.nodes.len() as u32).collect();
                    let ch = chunk_bfs(0, 8, groups, |n| {
                        let v = o.nodes[n as usize];
                        if v & 1 == 1 {
                            let b = (v >> 1) as usize;
                            Some(&ids[b..b + 8])
                        } else {
                            None
                        }
                    })?;
                    let mut w = vec![0u64; ch.chunks.len() * wpc];
                    let mut leaves = 0u32;
                    for (j, c) in ch.chunks.iter().enumerate() {
                        if c.leaf_offset != leaves {
                            return Err("octree_1bit: chunk leaf offsets out of order".into());
                        }
                        w[j * wpc] = c.first_child_chunk as u64 | (c.leaf_offset as u64) << 32;
                        for (i, &n) in c.slots.iter().enumerate() {
                            if o.nodes[n as usize] & 1 == 1 {
                                w[j * wpc + 1 + i / 64] |= 1u64 << (i % 64);
                            } else {
                                push_leaf(n as usize, &mut offsets);
                                leaves += 1;
                            }
                        }
                    }
                    (words, chunks, fill) = (w, ch.chunks.len() as u64, ch.fill());
                }
                Fill::Dense => {
                    let bpc = cfg.chunk_bytes as usize * 8 - 32;
                    let nbits = o.nodes.len() - 1;
                    let nchunks = nbits.div_ceil(bpc);
                    let mut w = vec![0u64; nchunks * wpc];
                    let mut ones = 0u64;
                    for i in 0..nbits {
                        let (k, l) = (i / bpc, i % bpc);
                        if l == 0 {
                            w[k * wpc] = ones;
                        }
                        let n = i + 1;
                        if o.nodes[n] & 1 == 1 {
                            // Breadth-first node order: node n's children are 8 (rank + 1) bits on.
                            if (o.nodes[n] >> 1) as u64 != 8 * (ones + 1) + 1 {
                                return Err("octree_1bit: octree nodes are not breadth-first".into());
                            }
                            let pos = 32 + l;
                            w[k * wpc + pos / 64] |= 1u64 << (pos % 64);
                            ones += 1;
                        } else {
                            push_leaf(n, &mut offsets);
                        }
                    }
                    let f = nbits as f64 / (nchunks * bpc) as f64;
                    (words, chunks, fill) = (w, nchunks as u64, f);
                }
            }
        }
        if prims.len() != o.prims.len() {
            return Err("octree_1bit: references lost while chunking".into());
        }
        Ok(Octree1Bit {
            world: o.world,
            margin: o.margin,
            config: cfg.clone(),
            words,
            chunks,
            nodes: o.nodes.len() as u64,
            chunk_fill: fill,
            offsets,
            prims,
        })
    }

    pub fn leaves(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Topology = the chunks (Kilian 6.2); total adds `offset_list`, `primitives_list` and the
    /// 24-byte world box.
    pub fn memory(&self) -> Memory {
        let topology = self.chunks * self.config.chunk_bytes as u64;
        Memory {
            topology_bytes: topology,
            total_bytes: topology
                + 4 * self.offsets.len() as u64
                + 4 * self.prims.len() as u64
                + 24,
            nodes: self.nodes,
            chunks: self.chunks,
            chunk_fill: self.chunk_fill,
            prim_refs: self.prims.len() as u64,
        }
    }

    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        match self.config.fill {
            Fill::Bfs => trace_topo(&self.bfs(), &self.world, tris, rays),
            Fill::Dense => trace_topo(&self.dense(), &self.world, tris, rays),
        }
    }

    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        match self.config.fill {
            Fill::Bfs => sah_topo(&self.bfs(), &self.world, cost),
            Fill::Dense => sah_topo(&self.dense(), &self.world, cost),
        }
    }

    /// Decodes every node (checked indexing: a malformed structure is an error, not a panic):
    /// each node reached once, `nodes` nodes, each leaf index used once, every word inside a
    /// chunk; then the reference checks shared with the basic octree.
    pub fn validate(&self, tris: &[Triangle]) -> Result<(), String> {
        let wpc = (self.config.chunk_bytes / 8) as usize;
        if self.words.len() as u64 != self.chunks * wpc as u64 {
            return Err("octree_1bit: word count is not chunks * chunk_bytes / 8".into());
        }
        if self.offsets.first() != Some(&0)
            || self.offsets.windows(2).any(|w| w[0] > w[1])
            || *self.offsets.last().unwrap() as usize != self.prims.len()
        {
            return Err("octree_1bit: offset_list is not a monotone cover of primitives_list".into());
        }
        let leaves = self.leaves();
        let mut leaf_seen = vec![false; leaves];
        let mut count = 0u64;
        let slots = match self.config.fill {
            Fill::Bfs => self.config.chunk_bytes as usize * 8 - 64,
            Fill::Dense => self.config.chunk_bytes as usize * 8 - 32,
        };
        let total_bits = match self.config.fill {
            Fill::Bfs => self.chunks as usize * slots,
            Fill::Dense => self.nodes.saturating_sub(1) as usize,
        };
        if self.config.fill == Fill::Dense && (total_bits.div_ceil(slots) as u64) != self.chunks {
            return Err("octree_1bit: dense chunk count does not match the node count".into());
        }
        if self.config.fill == Fill::Dense {
            // Milestones: each chunk's header = 1-bits before it; no bits beyond the last node.
            let mut ones = 0u64;
            for k in 0..self.chunks as usize {
                if self.words[k * wpc] & 0xffff_ffff != ones {
                    return Err(format!(
                        "octree_1bit: milestone of chunk {k} is not the rank before it"
                    ));
                }
                for l in 0..slots {
                    let i = k * slots + l;
                    let pos = 32 + l;
                    let b = self.words[k * wpc + pos / 64] >> (pos % 64) & 1;
                    if i >= total_bits && b == 1 {
                        return Err("octree_1bit: bits set beyond the last node".into());
                    }
                    ones += b;
                }
            }
        }
        let mut seen = vec![false; total_bits];
        // Explicit stack of nodes (chunk, slot) / global bits; u64::MAX = the root.
        let mut stack = vec![u64::MAX];
        while let Some(n) = stack.pop() {
            count += 1;
            if count > self.nodes {
                return Err("octree_1bit: more nodes reachable than stored".into());
            }
            let (leaf, kids) = match self.config.fill {
                Fill::Bfs => self.check_bfs(n, slots, &mut seen)?,
                Fill::Dense => self.check_dense(n, &mut seen)?,
            };
            if let Some(l) = leaf {
                let s = leaf_seen
                    .get_mut(l)
                    .ok_or_else(|| format!("octree_1bit: leaf index {l} of {leaves}"))?;
                if *s {
                    return Err(format!("octree_1bit: leaf {l} reached twice"));
                }
                *s = true;
            }
            stack.extend(kids);
        }
        if count != self.nodes {
            return Err(format!(
                "octree_1bit: {count} nodes reachable, {} stored",
                self.nodes
            ));
        }
        if leaf_seen.iter().any(|s| !s) {
            return Err("octree_1bit: unreachable leaf".into());
        }
        match self.config.fill {
            Fill::Bfs => validate_topo(
                &self.bfs(),
                &self.world,
                self.margin,
                tris,
                self.prims.len(),
            ),
            Fill::Dense => validate_topo(
                &self.dense(),
                &self.world,
                self.margin,
                tris,
                self.prims.len(),
            ),
        }
    }

    fn word(&self, i: usize) -> Result<u64, String> {
        self.words
            .get(i)
            .copied()
            .ok_or_else(|| format!("octree_1bit: word {i} out of range"))
    }

    /// One node of the bfs fill: (leaf index, children as (chunk << 32 | slot)).
    fn check_bfs(
        &self,
        n: u64,
        slots: usize,
        seen: &mut [bool],
    ) -> Result<(Option<usize>, Vec<u64>), String> {
        let wpc = (self.config.chunk_bytes / 8) as usize;
        let groups = slots / 8;
        let kids = |c: u64, s: u64| (0..8).map(|k| c << 32 | (s + k)).collect::<Vec<_>>();
        if n == u64::MAX {
            return Ok(if self.chunks == 0 {
                (Some(0), vec![])
            } else {
                (None, kids(0, 0))
            });
        }
        let (c, s) = ((n >> 32) as usize, (n & 0xffff_ffff) as usize);
        if c as u64 >= self.chunks || s >= slots {
            return Err(format!("octree_1bit: node (chunk {c}, slot {s}) out of range"));
        }
        let flag = seen
            .get_mut(c * slots + s)
            .ok_or("octree_1bit: slot out of range")?;
        if *flag {
            return Err(format!("octree_1bit: node (chunk {c}, slot {s}) reached twice"));
        }
        *flag = true;
        let base = c * wpc;
        let bits: Vec<u64> = (1..wpc)
            .map(|w| self.word(base + w))
            .collect::<Result<_, _>>()?;
        let hdr = self.word(base)?;
        let r = rank(&bits, s) as u64;
        if crate::chunks::bit(&bits, s) {
            if r < groups as u64 - 1 {
                Ok((None, kids(c as u64, 8 * (r + 1))))
            } else {
                let cc = (hdr & 0xffff_ffff) + r - (groups as u64 - 1);
                Ok((None, kids(cc, 0)))
            }
        } else {
            Ok((Some(((hdr >> 32) + s as u64 - r) as usize), vec![]))
        }
    }

    fn check_dense(&self, n: u64, seen: &mut [bool]) -> Result<(Option<usize>, Vec<u64>), String> {
        let kids = |s: u64| (0..8).map(|k| s + k).collect::<Vec<_>>();
        if n == u64::MAX {
            return Ok(if self.chunks == 0 {
                (Some(0), vec![])
            } else {
                (None, kids(0))
            });
        }
        let i = n as usize;
        let flag = seen
            .get_mut(i)
            .ok_or_else(|| format!("octree_1bit: bit {i} beyond the bit field"))?;
        if *flag {
            return Err(format!("octree_1bit: bit {i} reached twice"));
        }
        *flag = true;
        let d = self.dense();
        let ones = d.rank(i) as u64;
        if d.bit(i) {
            Ok((None, kids(8 * (ones + 1))))
        } else {
            Ok((Some(i - ones as usize), vec![]))
        }
    }

    /// The basic octree with the same construction parameters (same topology).
    pub fn uncompressed(&self, tris: &[Triangle]) -> Option<Octree> {
        Octree::build(tris, &self.config.base).ok()
    }

    fn bfs(&self) -> BfsView<'_> {
        let wpc = (self.config.chunk_bytes / 8) as usize;
        BfsView {
            words: &self.words,
            wpc,
            inner: (wpc * 8 - 8) as u32 - 1,
            chunks: self.chunks as usize,
            offsets: &self.offsets,
            prims: &self.prims,
        }
    }

    fn dense(&self) -> DenseView<'_> {
        let wpc = (self.config.chunk_bytes / 8) as usize;
        DenseView {
            words: &self.words,
            wpc,
            bpc: wpc * 64 - 32,
            chunks: self.chunks as usize,
            offsets: &self.offsets,
            prims: &self.prims,
        }
    }
}

#[inline(always)]
fn leaf_refs<'a>(offsets: &[u32], prims: &'a [u32], l: usize) -> &'a [u32] {
    match (offsets.get(l), offsets.get(l + 1)) {
        (Some(&s), Some(&e)) => prims.get(s as usize..e as usize).unwrap_or(&[]),
        _ => &[],
    }
}

/// The bfs fill as a traversable topology; nodes are (chunk << 32 | slot), the root u64::MAX.
struct BfsView<'a> {
    words: &'a [u64],
    wpc: usize,
    /// n = groups - 1: the first n 1-bits of a chunk have their children in it (4.2.2.3).
    inner: u32,
    chunks: usize,
    offsets: &'a [u32],
    prims: &'a [u32],
}

impl Topo for BfsView<'_> {
    type N = u64;
    #[inline(always)]
    fn root(&self) -> u64 {
        u64::MAX
    }
    #[inline(always)]
    fn expand(&self, n: u64) -> Expand<'_, u64> {
        if n == u64::MAX {
            return if self.chunks == 0 {
                Expand::Leaf(leaf_refs(self.offsets, self.prims, 0))
            } else {
                Expand::Interior(0)
            };
        }
        let (c, s) = ((n >> 32) as usize, (n & 0xffff_ffff) as usize);
        let chunk = &self.words[c * self.wpc..(c + 1) * self.wpc];
        let bits = &chunk[1..];
        let r = rank(bits, s);
        if bits[s / 64] >> (s % 64) & 1 == 1 {
            if r < self.inner {
                Expand::Interior((c as u64) << 32 | (8 * (r as u64 + 1)))
            } else {
                let cc = (chunk[0] & 0xffff_ffff) + (r - self.inner) as u64;
                Expand::Interior(cc << 32)
            }
        } else {
            let l = (chunk[0] >> 32) as usize + s - r as usize;
            Expand::Leaf(leaf_refs(self.offsets, self.prims, l))
        }
    }
    #[inline(always)]
    fn child(&self, base: u64, k: usize) -> u64 {
        base + k as u64
    }
}

/// The dense fill: nodes are global bit indices, the root u64::MAX.
struct DenseView<'a> {
    words: &'a [u64],
    wpc: usize,
    /// Node bits per chunk.
    bpc: usize,
    chunks: usize,
    offsets: &'a [u32],
    prims: &'a [u32],
}

impl DenseView<'_> {
    /// 1-bits before global bit i: the chunk's milestone + a popcount inside the chunk.
    #[inline(always)]
    fn rank(&self, i: usize) -> u32 {
        let (k, l) = (i / self.bpc, i % self.bpc);
        let chunk = &self.words[k * self.wpc..(k + 1) * self.wpc];
        let w0 = chunk[0] >> 32;
        let r = chunk[0] as u32;
        if l < 32 {
            r + (w0 & ((1u64 << l) - 1)).count_ones()
        } else {
            r + w0.count_ones() + rank(&chunk[1..], l - 32)
        }
    }
    #[inline(always)]
    fn bit(&self, i: usize) -> bool {
        let (k, l) = (i / self.bpc, i % self.bpc);
        let pos = 32 + l;
        self.words[k * self.wpc + pos / 64] >> (pos % 64) & 1 == 1
    }
}

impl Topo for DenseView<'_> {
    type N = u64;
    #[inline(always)]
    fn root(&self) -> u64 {
        u64::MAX
    }
    #[inline(always)]
    fn expand(&self, n: u64) -> Expand<'_, u64> {
        if n == u64::MAX {
            return if self.chunks == 0 {
                Expand::Leaf(leaf_refs(self.offsets, self.prims, 0))
            } else {
                Expand::Interior(0)
            };
        }
        let i = n as usize;
        let r = self.rank(i) as usize;
        if self.bit(i) {
            Expand::Interior(8 * (r as u64 + 1))
        } else {
            Expand::Leaf(leaf_refs(self.offsets, self.prims, i - r))
        }
    }
    #[inline(always)]
    fn child(&self, base: u64, k: usize) -> u64 {
        base + k as u64
    }
}
