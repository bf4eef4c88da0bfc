//! Breadth-first 1-bit topology in fixed-size chunks (Kilian 4.2.1-4.2.2, shared by the 1-bit
//! octree, arity 8, and the quantized BVH, arity 2).
//!
//! Each chunk stores the nodes below one *implicit root* (an inner node of the tree that is not
//! itself in the chunk) in breadth-first order, one bit per node (1 = inner, 0 = leaf), sibling
//! groups of `arity` nodes kept together. A chunk has room for `groups` sibling groups; the root's
//! children take the first, and the first `groups - 1` inner nodes (1-bits) of the chunk, in bit
//! order, get their children in the same chunk: `child(i) = arity * (rank(i) + 1)` (4.2.1). Every
//! later 1-bit has its children in another chunk, the `rank(i) - (groups - 1)`-th child chunk of
//! this chunk (4.2.2.2: `childchunk(i) = offset_chunk + rank(i) - n` with n = groups - 1). Chunks are
//! listed breadth-first (4.2.2, fig. 4.11), so the child chunks of one chunk are consecutive.
use serde::{Deserialize, Serialize};

/// One chunk before bit packing.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChunkPlan {
    /// Tree node id of the implicit root.
    pub root: u32,
    /// Tree node ids of the chunk's slots, breadth-first (a multiple of `arity`, at most
    /// `arity * groups`). Bit i of the chunk is 1 iff `slots[i]` is an inner node.
    pub slots: Vec<u32>,
    /// Index (in `Chunking::chunks`) of this chunk's first child chunk; its child chunks are
    /// consecutive, one per 1-bit whose children are outside this chunk, in bit order.
    pub first_child_chunk: u32,
    /// Number of child chunks.
    pub child_chunks: u32,
    /// Leaves (0-bits) in all earlier chunks (Kilian 4.2.2.4's leaf node offset).
    pub leaf_offset: u32,
    /// Slots in all earlier chunks (Kilian 5.2.1.2's node info offset).
    pub node_offset: u32,
}

#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Chunking {
    pub arity: u32,
    pub groups: u32,
    /// Breadth-first over chunks; empty when the root is a leaf.
    pub chunks: Vec<ChunkPlan>,
}

impl Chunking {
    /// Mean over chunks of used slots / slots (Kilian fig. 4.16 right); 0 without chunks.
    pub fn fill(&self) -> f64 {
        if self.chunks.is_empty() {
            return 0.0;
        }
        let cap = (self.arity * self.groups) as f64;
        self.chunks
            .iter()
            .map(|c| c.slots.len() as f64 / cap)
            .sum::<f64>()
            / self.chunks.len() as f64
    }
    /// Total used slots (= tree nodes minus the root).
    pub fn used_slots(&self) -> u64 {
        self.chunks.iter().map(|c| c.slots.len() as u64).sum()
    }
}

/// Splits a tree into breadth-first chunks. `children(n)` returns the `arity` children of an inner
/// node, `None` for a leaf. Iterative (no recursion), so any depth works.
pub fn chunk_bfs<'a>(
    root: u32,
    arity: usize,
    groups: usize,
    children: impl Fn(u32) -> Option<&'a [u32]>,
) -> Result<Chunking, String> {
    if arity < 2 || groups < 1 {
        return Err(format!("chunks need arity >= 2 and at least one sibling group (arity {arity}, groups {groups})"));
    }
    let mut out = Chunking {
        arity: arity as u32,
        groups: groups as u32,
        chunks: Vec::new(),
    };
    if children(root).is_none() {
        return Ok(out);
    }
    // FIFO of implicit chunk roots: chunks are created in the order their roots are discovered,
    // which lists them breadth-first and keeps each chunk's children consecutive.
    let mut roots = std::collections::VecDeque::from([root]);
    let (mut leaves, mut nodes) = (0u32, 0u32);
    while let Some(r) = roots.pop_front() {
        let kids = children(r).ok_or("chunk root is a leaf")?;
        if kids.len() != arity {
            return Err(format!(
                "node {r} has {} children, expected {arity}",
                kids.len()
            ));
        }
        let mut slots: Vec<u32> = kids.to_vec();
        let mut used_groups = 1usize;
        let mut outside = Vec::new();
        let mut i = 0;
        while i < slots.len() {
            let n = slots[i];
            if let Some(k) = children(n) {
                if k.len() != arity {
                    return Err(format!(
                        "node {n} has {} children, expected {arity}",
                        k.len()
                    ));
                }
                if used_groups < groups {
                    slots.extend_from_slice(k);
                    used_groups += 1;
                } else {
                    outside.push(n);
                }
            }
            i += 1;
        }
        let first_child_chunk = (out.chunks.len() + roots.len() + 1) as u32;
        let leaf_count = slots.iter().filter(|&&n| children(n).is_none()).count() as u32;
        out.chunks.push(ChunkPlan {
            root: r,
            first_child_chunk,
            child_chunks: outside.len() as u32,
            leaf_offset: leaves,
            node_offset: nodes,
            slots,
        });
        leaves += leaf_count;
        nodes += out.chunks.last().map(|c| c.slots.len() as u32).unwrap_or(0);
        roots.extend(outside);
    }
    Ok(out)
}

/// Number of 1-bits strictly before bit `i` of a bit field stored as little-endian u64 words
/// (bit i = word i / 64, bit i % 64): Jacobson's rank, by popcount.
#[inline]
pub fn rank(words: &[u64], i: usize) -> u32 {
    let (w, b) = (i / 64, i % 64);
    let mut r = 0;
    for x in &words[..w] {
        r += x.count_ones();
    }
    if b > 0 {
        r += (words[w] & ((1u64 << b) - 1)).count_ones();
    }
    r
}

#[inline]
pub fn bit(words: &[u64], i: usize) -> bool {
    words[i / 64] >> (i % 64) & 1 == 1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Kilian fig. 4.8: a binary tree whose breadth-first bits are 1 1 0 1 0 1 1 0 0 0 0 0 (fig. 4.9).
    fn fig48() -> Vec<Option<[u32; 2]>> {
        // 0 = root; layer 1: 1, 2; layer 2: 3 4 (of 1), 5 6 (of 2); layer 3: 7 8 (of 4), 9 10 (of 6);
        // layer 4: 11 12 (of 7).
        let mut c = vec![None; 13];
        c[0] = Some([1, 2]);
        c[1] = Some([3, 4]);
        c[2] = Some([5, 6]);
        c[4] = Some([7, 8]);
        c[6] = Some([9, 10]);
        c[7] = Some([11, 12]);
        c
    }

    #[test]
    fn kilian_figure_4_13_chunks() {
        let t = fig48();
        let ch = chunk_bfs(0, 2, 3, |n| t[n as usize].as_ref().map(|a| &a[..])).unwrap();
        // Fig. 4.14: chunk 1 = bits 1 1 0 1 0 1 (B2 B4 - C2 - C3), chunk 2 = 1 0 0 0, chunk 3 = 0 0.
        let bits: Vec<Vec<u8>> = ch
            .chunks
            .iter()
            .map(|c| {
                c.slots
                    .iter()
                    .map(|&n| t[n as usize].is_some() as u8)
                    .collect()
            })
            .collect();
        assert_eq!(
            bits,
            vec![vec![1, 1, 0, 1, 0, 1], vec![1, 0, 0, 0], vec![0, 0]]
        );
        assert_eq!(ch.chunks[0].first_child_chunk, 1);
        assert_eq!(ch.chunks[0].child_chunks, 2);
        assert_eq!(ch.chunks[1].root, 4);
        assert_eq!(ch.chunks[2].root, 6);
        assert_eq!(ch.chunks[1].leaf_offset, 2);
        assert_eq!(ch.chunks[2].node_offset, 10);
        assert_eq!(ch.used_slots(), 12);
        assert!(
            (ch.fill() - 2.0 / 3.0).abs() < 1e-12,
            "Kilian: 'on average, each chunk is only 2/3 filled'"
        );
    }

    #[test]
    fn leaf_root_has_no_chunks_and_rank_counts() {
        let ch = chunk_bfs(0, 8, 2, |_| None).unwrap();
        assert!(ch.chunks.is_empty());
        let w = [0b1011u64, u64::MAX];
        assert_eq!(rank(&w, 0), 0);
        assert_eq!(rank(&w, 2), 2);
        assert_eq!(rank(&w, 64), 3);
        assert_eq!(rank(&w, 70), 9);
        assert!(bit(&w, 3) && !bit(&w, 2));
    }
}
