//! Extended Morton codes (Vinkler, Bittner, Havran 2017), as thesis 3.7.1 describes them:
//! - size s = diagonal of the primitive's box / diagonal of the frame, quantized linearly like a
//!   fourth coordinate (thesis: "interleave 4 quantized coordinates (x, y, z, s)");
//! - EMC-64-sort: 64 bits, the size bit is every 4th bit (x y z s x y z s ...), the three axes
//!   ordered by the frame extent, largest first (16 bits per axis, 16 size bits);
//! - EMC-64-var: 64 bits, the size bit is every 7th bit (bits 7, 14, ..., 63 counted from the
//!   most significant one, so 9 size bits and 55 spatial bits); every other bit goes to the
//!   currently largest axis of an auxiliary box that starts as the frame and is halved along the
//!   chosen axis after each spatial bit (so the per-axis bit counts vary with the scene's shape).
//!
//! Riemersma 2.4.3 phrases the size bit as "is the primitive's diagonal larger than the diagonal of
//! the current cell"; with linear quantization of s this holds exactly for every size bit down to
//! (and including) the first 1 bit of a primitive, after which the linear code keeps refining the
//! size while the threshold reading would write only 1s.
//!
//! Codes are made by a generic layout coder: any string of axis letters (x, y, z, s) becomes a
//! code by quantizing each letter's value to as many bits as the letter occurs and depositing the
//! bits in layout order, through one 256-entry table per (letter, value byte).
use crate::{BOUNDS, GRID_BITS, GRID_FRAME};
use bvhlab_params::Method;

pub const EMC64_SORT: Method = Method::new(
    "emc64-sort",
    "Extended Morton code, 64 bits, size bit every 4th bit, axes by extent (Vinkler 2017; thesis 3.7.1)",
    "Vinkler 2017; thesis 3.7.1",
    &[BOUNDS, GRID_BITS, GRID_FRAME],
)
.with_finish(crate::grid_frame_needs_grid);

pub const EMC64_VAR: Method = Method::new(
    "emc64-var",
    "Extended Morton code, 64 bits, size bit every 7th bit, others on the largest axis (thesis 3.7.1)",
    "thesis 3.7.1",
    &[BOUNDS, GRID_BITS, GRID_FRAME],
)
.with_finish(crate::grid_frame_needs_grid);

/// Letter values in layouts.
pub const X: u8 = 0;
pub const Y: u8 = 1;
pub const Z: u8 = 2;
pub const S: u8 = 3;

/// Length of both EMC variants.
pub const EMC_BITS: u32 = 64;

/// Axes ordered by extent, largest first; ties keep x before y before z.
pub fn axes_by_extent(ext: [f64; 3]) -> [u8; 3] {
    let mut order = [X, Y, Z];
    // Stable: equal (or NaN) extents keep the x, y, z order.
    order.sort_by(|&a, &b| ext[b as usize].partial_cmp(&ext[a as usize]).unwrap_or(std::cmp::Ordering::Equal));
    order
}

/// Index of the largest entry; ties (and NaN) go to the lower axis.
#[inline]
pub fn largest_axis(e: [f64; 3]) -> u8 {
    if e[0] >= e[1] && e[0] >= e[2] {
        X
    } else if e[1] >= e[2] {
        Y
    } else {
        Z
    }
}

/// EMC-64-sort layout: (a0 a1 a2 s) x 16 with a0 the axis of largest frame extent.
pub fn sort_layout(ext: [f64; 3]) -> Vec<u8> {
    let o = axes_by_extent(ext);
    (0..EMC_BITS as usize).map(|i| if (i + 1) % 4 == 0 { S } else { o[i % 4] }).collect()
}

/// The spatial-only axis sequence of EMC-64-sort (used by the occupation grid's cell codes).
pub fn sort_axes(ext: [f64; 3], len: usize) -> Vec<u8> {
    let o = axes_by_extent(ext);
    (0..len).map(|i| o[i % 3]).collect()
}

/// EMC-64-var layout: size bit at every 7th position, the others on the largest axis of a box
/// that starts with extent `ext` and is halved along each chosen axis.
pub fn var_layout(ext: [f64; 3]) -> Vec<u8> {
    let mut aux = ext;
    (0..EMC_BITS as usize)
        .map(|i| {
            if (i + 1) % 7 == 0 {
                S
            } else {
                let a = largest_axis(aux);
                aux[a as usize] *= 0.5;
                a
            }
        })
        .collect()
}

/// The spatial-only halving sequence of EMC-64-var (for the occupation grid's cell codes).
pub fn var_axes(ext: [f64; 3], len: usize) -> Vec<u8> {
    let mut aux = ext;
    (0..len)
        .map(|_| {
            let a = largest_axis(aux);
            aux[a as usize] *= 0.5;
            a
        })
        .collect()
}

/// Layout letters as a string, one char per bit, most significant first.
pub fn layout_string(letters: &[u8]) -> String {
    letters.iter().map(|&l| ['x', 'y', 'z', 's'][l as usize]).collect()
}

/// Makes codes with an arbitrary layout (at most 64 letters).
#[derive(Clone, Debug)]
pub struct LayoutCoder {
    pub letters: Vec<u8>,
    /// Bits per letter (x, y, z, s).
    pub counts: [u32; 4],
    /// (letter, byte index of its quantized value, deposit table).
    tables: Vec<(u8, u8, Box<[u64; 256]>)>,
}

impl LayoutCoder {
    pub fn new(letters: Vec<u8>) -> Self {
        assert!(letters.len() <= 64, "a layout has at most 64 bits");
        let total = letters.len() as u32;
        let mut counts = [0u32; 4];
        for &l in &letters {
            counts[l as usize] += 1;
        }
        // deposit[letter][value bit] = code bit position.
        let mut deposit: [Vec<u32>; 4] = Default::default();
        for (c, d) in deposit.iter_mut().enumerate() {
            *d = vec![0; counts[c] as usize];
        }
        let mut seen = [0u32; 4];
        for (p, &l) in letters.iter().enumerate() {
            let c = l as usize;
            // The j-th occurrence (from the most significant end) carries value bit counts-1-j.
            let vbit = counts[c] - 1 - seen[c];
            deposit[c][vbit as usize] = total - 1 - p as u32;
            seen[c] += 1;
        }
        let mut tables = Vec::new();
        for c in 0..4 {
            let nbytes = counts[c].div_ceil(8);
            for b in 0..nbytes {
                let mut t = Box::new([0u64; 256]);
                for (v, slot) in t.iter_mut().enumerate() {
                    let mut out = 0u64;
                    for i in 0..8 {
                        let vbit = 8 * b + i;
                        if vbit < counts[c] && (v >> i) & 1 == 1 {
                            out |= 1u64 << deposit[c][vbit as usize];
                        }
                    }
                    *slot = out;
                }
                tables.push((c as u8, b as u8, t));
            }
        }
        LayoutCoder { letters, counts, tables }
    }

    pub fn bits(&self) -> u32 {
        self.letters.len() as u32
    }

    /// Code from already quantized values (x, y, z, s), each with `counts[letter]` bits.
    #[inline]
    pub fn deposit(&self, q: [u64; 4]) -> u64 {
        let mut code = 0u64;
        for (c, b, t) in &self.tables {
            code |= t[((q[*c as usize] >> (8 * *b as u32)) & 0xff) as usize];
        }
        code
    }

    /// Code of a point in normalized frame coordinates `u` (0..1) with normalized size `s`.
    #[inline]
    pub fn code(&self, u: [f64; 3], s: f64) -> u64 {
        use crate::morton::quantize;
        self.deposit([
            quantize(u[0], self.counts[0]),
            quantize(u[1], self.counts[1]),
            quantize(u[2], self.counts[2]),
            quantize(s, self.counts[3]),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_coder_reproduces_morton() {
        let c = LayoutCoder::new((0..30).map(|i| [X, Y, Z][i % 3]).collect());
        for (x, y, z) in [(0u64, 0, 0), (1023, 0, 5), (5, 600, 1023), (341, 682, 17)] {
            assert_eq!(c.deposit([x, y, z, 0]), crate::morton::interleave(x, y, z));
        }
    }

    #[test]
    fn var_layout_flat_scene() {
        // A 4 x 1 x 0 slab: the first two spatial bits go to x, then x and y alternate, z never.
        let l = var_layout([4.0, 1.0, 0.0]);
        assert_eq!(&layout_string(&l)[..7], "xxxyxys");
        assert!(!l.contains(&Z));
    }
}
