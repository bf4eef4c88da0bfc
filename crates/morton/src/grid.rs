//! Riemersma's occupation grid with mipping (Riemersma 3.2.1, 3.2.2, appendix 8.1).
//!
//! 1. Every primitive gets a `b`-bit cell code (b = `grid_bits`): the first b spatial bits of the
//!    scheme's layout (Morton: x y z x y z ...; EMC-64-sort: the extent-sorted axes repeating;
//!    EMC-64-var: the halving sequence), size bits left out - the grid is about position.
//! 2. The occupied cells are set in a bitmap (the base layer, 2^b bits); mip layers merge 8 bits of
//!    the layer below into 1 (any occupied -> occupied) up to the 8-bit top layer.
//! 3. From the top layer down, the byte holding the primitive's cell's 8 sub-cells tells which of
//!    the 3 splits of that octree level are necessary (a 256 x 8 lookup table, Riemersma fig. 8/9):
//!    a split is necessary iff, inside the part of the byte the primitive is in, both sides of the
//!    split are occupied. Only necessary splits are appended: the "concise cell index".
//! 4. The code inside the cell is the configured scheme's code computed in the cell's own box
//!    (smaller than the frame, so more precision where primitives are); the final code is the
//!    concise index followed by the in-cell code.
//!
//! Choices where the text is silent (see also docs/decisions.md, "Encoding choices"):
//! - Fixed width: the total length is the scheme's length T (3 x bits for Morton, 64 for EMC);
//!   a cell whose concise index has L bits gets the top T - L bits of its in-cell code:
//!   `code = prefix << (T - L) | incell >> L`. The grid redistributes bits, it adds none.
//! - Why this sorts correctly: dropping splits where one side is empty is collapsing the unary
//!   nodes of the binary trie of occupied cells, so the concise indices form a prefix-free code
//!   whose order is the order of the cells along the original curve. For any bit position, the
//!   codes sharing the bits above it either all lie in one cell (the bit is an in-cell split) or
//!   the bit is a split of the trie of cells; every split LBVH/AAC/PLOC see is spatial.
//! - grid_bits not divisible by 3: the cell code is padded with leading zero bits to a multiple
//!   of 3 (the top octree level is partial); the padded splits have one empty side, so the
//!   lookup removes them. grid_bits is clamped to 0..=min(T, 18).
use crate::bounds::{box_diag, diag, Frame};
use crate::emc::LayoutCoder;
use crate::morton::{pow2, quantize};
use bvhlab_geom::{Aabb, Vec3};
use rayon::prelude::*;

/// Largest grid (2^18 cells: a 32 KiB bitmap).
pub const MAX_GRID_BITS: u32 = 18;

/// `NECESSARY[byte][child] = (split bits, count)`: the necessary splits of one octree level for a
/// primitive in sub-cell `child` (3 bits, first split most significant) when the 8 sub-cells'
/// occupancy is `byte` (bit i = sub-cell i occupied).
pub fn necessary_table() -> [[(u8, u8); 8]; 256] {
    let mut t = [[(0u8, 0u8); 8]; 256];
    for (occ, row) in t.iter_mut().enumerate() {
        let occupied = |c: usize| (occ >> c) & 1 == 1;
        for (child, slot) in row.iter_mut().enumerate() {
            let (mut bits, mut len) = (0u8, 0u8);
            // Split k (k = 0, 1, 2) divides the group of sub-cells sharing the child's higher
            // split bits into those with bit (2 - k) = 0 and = 1.
            for k in 0..3 {
                let bit = 2 - k;
                let high_mask = !((1usize << (bit + 1)) - 1) & 7;
                let side = |b: usize| {
                    (0..8usize).any(|c| c & high_mask == child & high_mask && (c >> bit) & 1 == b && occupied(c))
                };
                if side(0) && side(1) {
                    bits = (bits << 1) | ((child >> bit) & 1) as u8;
                    len += 1;
                }
            }
            *slot = (bits, len);
        }
    }
    t
}

/// The occupation grid of one encoding: cell geometry, occupancy mips and concise indices.
pub struct Grid {
    /// Grid bits b.
    pub bits: u32,
    /// Bits per axis of the cell lattice (counts of each axis in the cell letters).
    pub axis_bits: [u32; 3],
    cell_coder: LayoutCoder,
    /// Layer 0 is the base occupancy (bit g = cell g occupied); layer k merges 8 bits of k-1.
    pub layers: Vec<Vec<u64>>,
    /// Per cell: concise index and its length (only meaningful for occupied cells).
    pub concise: Vec<(u32, u8)>,
}

fn get_bit(words: &[u64], i: usize) -> bool {
    (words[i / 64] >> (i % 64)) & 1 == 1
}

fn get_byte(words: &[u64], node: usize) -> usize {
    let i = node * 8;
    ((words[i / 64] >> (i % 64)) & 0xff) as usize
}

impl Grid {
    /// Builds the grid over `frame` for cells along `cell_letters` (axis letters, b of them).
    pub fn build(centers: &[Vec3], frame: &Frame, cell_letters: &[u8]) -> Grid {
        let bits = cell_letters.len() as u32;
        assert!(bits <= MAX_GRID_BITS);
        let mut axis_bits = [0u32; 3];
        for &l in cell_letters {
            axis_bits[l as usize] += 1;
        }
        let cell_coder = LayoutCoder::new(cell_letters.to_vec());
        let padded = 3 * bits.div_ceil(3);
        let words = ((1usize << padded) / 64).max(1);
        let mut grid = Grid { bits, axis_bits, cell_coder, layers: Vec::new(), concise: Vec::new() };

        // Base layer: OR of per-chunk bitmaps (order-independent, so deterministic).
        let base = centers
            .par_chunks(1 << 14)
            .map(|chunk| {
                let mut w = vec![0u64; words];
                for &c in chunk {
                    let g = grid.cell(frame.normalize(c)).0 as usize;
                    w[g / 64] |= 1u64 << (g % 64);
                }
                w
            })
            .reduce(
                || vec![0u64; words],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(&b) {
                        *x |= y;
                    }
                    a
                },
            );
        // Mip layers: bit i of layer k = any of bits 8i..8i+8 of layer k-1; the last layer kept
        // has 8 bits (the root's byte).
        let mut layers = vec![base];
        for k in 1..(padded / 3) {
            let below = &layers[k as usize - 1];
            let nbits = 1usize << (padded - 3 * k);
            let mut w = vec![0u64; (nbits / 64).max(1)];
            for i in 0..nbits {
                if get_byte(below, i) != 0 {
                    w[i / 64] |= 1u64 << (i % 64);
                }
            }
            layers.push(w);
        }
        grid.layers = layers;

        // Concise indices, walking the mips from the top (appendix 8.1.2).
        let table = necessary_table();
        let levels = padded / 3;
        grid.concise = (0..1usize << bits)
            .map(|g| {
                if !get_bit(&grid.layers[0], g) {
                    return (0, 0);
                }
                let (mut prefix, mut len) = (0u32, 0u8);
                for k in (1..=levels).rev() {
                    let node = g >> (3 * k);
                    let byte = get_byte(&grid.layers[k as usize - 1], node);
                    let child = (g >> (3 * (k - 1))) & 7;
                    let (b, l) = table[byte][child];
                    prefix = (prefix << l) | b as u32;
                    len += l;
                }
                (prefix, len)
            })
            .collect();
        grid
    }

    /// Cell code of a normalized point and the point's normalized coordinates inside the cell.
    #[inline]
    pub fn cell(&self, u: [f64; 3]) -> (u64, [f64; 3]) {
        let mut q = [0u64; 4];
        let mut t = [0f64; 3];
        for a in 0..3 {
            let m = self.axis_bits[a];
            q[a] = quantize(u[a], m);
            t[a] = u[a] * pow2(m) - q[a] as f64;
        }
        (self.cell_coder.deposit(q), t)
    }

    /// Number of occupied cells.
    pub fn occupied(&self) -> usize {
        self.layers[0].iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Longest concise index over occupied cells.
    pub fn max_concise_len(&self) -> u32 {
        (0..self.concise.len())
            .filter(|&g| get_bit(&self.layers[0], g))
            .map(|g| self.concise[g].1 as u32)
            .max()
            .unwrap_or(0)
    }

    /// Extents of a cell, for the in-cell coder.
    pub fn cell_extent(&self, frame: &Frame) -> [f64; 3] {
        [0, 1, 2].map(|a| frame.ext[a] / pow2(self.axis_bits[a]))
    }
}

#[inline]
fn shl(v: u64, s: u32) -> u64 {
    v.checked_shl(s).unwrap_or(0)
}

#[inline]
fn shr(v: u64, s: u32) -> u64 {
    v.checked_shr(s).unwrap_or(0)
}

/// Per-cell affine map of in-cell coordinates onto the tight bounds of the cell's centroids
/// (`CellFrame::Tight`): `t' = (t - min) * inv`.
#[derive(Clone, Copy, Debug)]
pub struct TightCell {
    pub min: [f64; 3],
    pub inv: [f64; 3],
}

/// Tight centroid bounds of every cell, in in-cell coordinates (an extension, not in Riemersma:
/// see `CellFrame::Tight`). Min/max reductions, so deterministic at any thread count.
pub fn tight_cells(centers: &[Vec3], frame: &Frame, grid: &Grid) -> Vec<TightCell> {
    let cells = 1usize << grid.bits;
    let empty = || {
        vec![
            [f64::INFINITY, f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
            cells
        ]
    };
    let b = centers
        .par_chunks(1 << 14)
        .fold(empty, |mut acc, chunk| {
            for &c in chunk {
                let (g, t) = grid.cell(frame.normalize(c));
                let e = &mut acc[g as usize];
                for a in 0..3 {
                    // NaN never wins a comparison, so it cannot poison the bounds.
                    if t[a] < e[a] {
                        e[a] = t[a];
                    }
                    if t[a] > e[3 + a] {
                        e[3 + a] = t[a];
                    }
                }
            }
            acc
        })
        .reduce(empty, |mut a, b| {
            for (x, y) in a.iter_mut().zip(&b) {
                for k in 0..3 {
                    x[k] = x[k].min(y[k]);
                    x[3 + k] = x[3 + k].max(y[3 + k]);
                }
            }
            a
        });
    b.iter()
        .map(|e| {
            let mut tc = TightCell { min: [0.0; 3], inv: [0.0; 3] };
            for a in 0..3 {
                let ext = e[3 + a] - e[a];
                if e[a].is_finite() && ext > 0.0 && ext.is_finite() {
                    tc.min[a] = e[a];
                    tc.inv[a] = 1.0 / ext;
                }
            }
            tc
        })
        .collect()
}

/// Codes of all primitives: concise index, then the top `total - L` bits of the in-cell code
/// `incell(t, s)` (a `total`-bit code of the in-cell coordinates `t` and the size `s` normalized
/// by the cell diagonal). With `tight`, `t` is first mapped onto the cell's tight bounds.
pub fn codes<F>(
    boxes: &[Aabb],
    centers: &[Vec3],
    frame: &Frame,
    grid: &Grid,
    total: u32,
    tight: Option<&[TightCell]>,
    incell: F,
) -> Vec<u64>
where
    F: Fn([f64; 3], f64) -> u64 + Sync,
{
    let cell_diag = diag(grid.cell_extent(frame));
    centers
        .par_iter()
        .zip(boxes.par_iter())
        .map(|(&c, b)| {
            let (g, mut t) = grid.cell(frame.normalize(c));
            if let Some(tc) = tight {
                let tc = &tc[g as usize];
                t = [0, 1, 2].map(|a| (t[a] - tc.min[a]) * tc.inv[a]);
            }
            let (prefix, len) = grid.concise[g as usize];
            let len = len as u32;
            let s = if cell_diag > 0.0 && cell_diag.is_finite() { box_diag(b) / cell_diag } else { 0.0 };
            shl(prefix as u64, total - len) | shr(incell(t, s), len)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_table() {
        let t = necessary_table();
        // All 8 sub-cells occupied: every split is necessary, the index is the child itself.
        for (c, &e) in t[0xff].iter().enumerate() {
            assert_eq!(e, (c as u8, 3));
        }
        // Only one sub-cell occupied: nothing is necessary.
        assert_eq!(t[1 << 5][5], (0, 0));
        // Sub-cells 0 and 7 (opposite corners): only the first split.
        assert_eq!(t[0b1000_0001][0], (0, 1));
        assert_eq!(t[0b1000_0001][7], (1, 1));
        // Sub-cells 4, 6, 7: first split unnecessary (all have bit 2 set); second necessary; third
        // only on the side (bit 1 = 1) where both 6 and 7 are occupied.
        assert_eq!(t[0b1101_0000][4], (0, 1));
        assert_eq!(t[0b1101_0000][6], (0b10, 2));
        assert_eq!(t[0b1101_0000][7], (0b11, 2));
    }
}
