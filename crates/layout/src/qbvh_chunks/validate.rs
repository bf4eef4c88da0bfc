//! Structural walk, SAH cost and validation.

use super::quant::{Grid, KeyReader, Packed};
use super::{chunk_box, header, rank_bit, Frame, QbvhChunks, HEADER_WORDS};
use bvhlab_bvh::{CostParams, Refs};
use bvhlab_geom::{Aabb, Triangle};

impl QbvhChunks {
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
        self.validate_refs(tris, Refs::Unique)
    }

    /// With `Refs::Split` (SBVH) a triangle may be referenced from several leaves (at most once per
    /// leaf); each such leaf's dequantized box must overlap the triangle's box, the parts together
    /// cover it, and every box contain those parts below it (instead of whole triangle boxes).
    pub fn validate_refs(&self, tris: &[Triangle], refs: Refs) -> Result<(), String> {
        let split = refs == Refs::Split;
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
            if std::mem::replace(s, true) && !split {
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
        let (mut covered, mut last_leaf, mut bad) =
            (vec![Aabb::EMPTY; if split { tris.len() } else { 0 }], vec![None; if split { tris.len() } else { 0 }], None);
        self.walk(|p, b, range| {
            parent.push(p);
            boxes.push(b);
            let mut u = Aabb::EMPTY;
            if let Some((a, e)) = range {
                for &t in &self.prims[a..e] {
                    let tb = tris[t as usize].bounds();
                    if split {
                        let part = Aabb { min: b.min.max(tb.min), max: b.max.min(tb.max) };
                        if part.is_empty() || last_leaf[t as usize] == Some(a) {
                            bad.get_or_insert(t);
                        }
                        last_leaf[t as usize] = Some(a);
                        covered[t as usize].grow(&part);
                        u.grow(&part);
                    } else {
                        u.grow(&tb);
                    }
                }
            }
            below.push(u);
        })?;
        if let Some(t) = bad {
            return Err(format!(
                "qbvh_chunks: triangle {t} referenced twice by one leaf or from a leaf not overlapping it"
            ));
        }
        if split {
            if let Some(t) = (0..tris.len()).find(|&t| !covered[t].contains(&tris[t].bounds())) {
                return Err(format!("qbvh_chunks: the leaves referencing triangle {t} do not cover it"));
            }
        }
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
