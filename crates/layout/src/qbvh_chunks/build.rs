//! Construction: chunking, quantization and packing (Kilian 5.2.1).

use super::quant::{write_key, Grid};
use super::{Config, Frame, QbvhChunks, HEADER_WORDS};
use crate::chunks::chunk_bfs;
use bvhlab_bvh::Bvh;
use bvhlab_geom::Aabb;

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
}
