//! Plain Morton codes (thesis 2.3.4): the centroid is quantized into a lattice of 2^k cells per
//! axis over the frame and the three k-bit indices are interleaved x1 y1 z1 x2 y2 z2 ...
//! (x is the most significant bit of each triple). Bit expansion by magic numbers.
use crate::{AutoFor, Bits, BOUNDS, GRID_BITS, GRID_FRAME};
use bvhlab_params::{Kind, Method, ParamSpec};

pub const METHOD: Method = Method::new(
    "morton",
    "Morton code, bits per axis interleaved x y z (thesis 2.3.4)",
    "thesis 2.3.4",
    &[
        ParamSpec {
            name: "bits",
            default: "auto",
            kind: Kind::AutoOrUInt { min: 1, max: 21 },
            about: "bits per axis; auto = the builder's own choice (aac: ceil(log4 n), lbvh: 10, ploc: 20)",
            in_label: false,
        },
        BOUNDS,
        GRID_BITS,
        GRID_FRAME,
    ],
)
.with_finish(crate::grid_frame_needs_grid);

/// Largest number of bits per axis that fits a 64-bit code.
pub const MAX_BITS: u32 = 21;

/// Bits per axis for a configuration and a primitive count, always in 1..=21.
/// `Auto(Aac)`: ceil(log4 n) (Gu et al. 2013, thesis 3.2.1); `Auto(Lbvh)`: 10 (30-bit codes,
/// Karras 2012); `Auto(Ploc)`: 20 (60-bit codes, Meister and Bittner 2018).
pub fn bits_per_axis(bits: Bits, n: usize) -> u32 {
    match bits {
        Bits::Fixed(b) => b.clamp(1, MAX_BITS),
        Bits::Auto(AutoFor::Aac) => {
            // Smallest b with 4^b >= n.
            let mut b = 0u32;
            while b < MAX_BITS && (1u64 << (2 * b)) < n as u64 {
                b += 1;
            }
            b.max(1)
        }
        Bits::Auto(AutoFor::Lbvh) => 10,
        Bits::Auto(AutoFor::Ploc) => 20,
    }
}

/// Spreads the low 21 bits of `v` so that bit i lands at bit 3i (two zeros between bits).
#[inline]
pub fn expand_bits(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Interleaves three quantized coordinates, x most significant within each triple.
#[inline]
pub fn interleave(x: u64, y: u64, z: u64) -> u64 {
    (expand_bits(x) << 2) | (expand_bits(y) << 1) | expand_bits(z)
}

/// Quantizes a normalized coordinate `u` (0..1 over the frame) to `k` bits: floor(u 2^k),
/// clamped to 0..2^k-1 (values outside the frame and NaN land in the border cells / cell 0).
#[inline]
pub fn quantize(u: f64, k: u32) -> u64 {
    if k == 0 {
        return 0;
    }
    let max = if k >= 64 { u64::MAX } else { (1u64 << k) - 1 };
    let v = u * pow2(k);
    // `as` saturates (NaN -> 0); the explicit `>` keeps NaN and negatives at 0.
    if v > 0.0 {
        (v as u64).min(max)
    } else {
        0
    }
}

/// 2^k exactly, for k in 0..=1023.
#[inline]
pub fn pow2(k: u32) -> f64 {
    f64::from_bits(((1023 + k.min(1023)) as u64) << 52)
}

/// Morton code of a point given in normalized frame coordinates (each 0..1), `bits` per axis.
#[inline]
pub fn code(u: [f64; 3], bits: u32) -> u64 {
    interleave(quantize(u[0], bits), quantize(u[1], bits), quantize(u[2], bits))
}

/// The layout string of a `bits`-per-axis Morton code, most significant bit first.
pub fn layout(bits: u32) -> String {
    "xyz".repeat(bits as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expand_matches_loop() {
        for v in [0u64, 1, 2, 3, 0x15_5555, 0x1f_ffff, 0x12_3456, 0x0a_bcde] {
            let mut e = 0u64;
            for i in 0..21 {
                e |= ((v >> i) & 1) << (3 * i);
            }
            assert_eq!(expand_bits(v), e, "v = {v:#x}");
        }
    }

    #[test]
    fn auto_bits() {
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Aac), 0), 1);
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Aac), 1), 1);
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Aac), 16), 2);
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Aac), 17), 3);
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Aac), 871_414), 10);
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Lbvh), 5), 10);
        assert_eq!(bits_per_axis(Bits::Auto(AutoFor::Ploc), 5), 20);
        assert_eq!(bits_per_axis(Bits::Fixed(0), 5), 1);
        assert_eq!(bits_per_axis(Bits::Fixed(40), 5), 21);
    }

    #[test]
    fn quantize_clamps() {
        assert_eq!(quantize(-1.0, 4), 0);
        assert_eq!(quantize(f64::NAN, 4), 0);
        assert_eq!(quantize(1.0, 4), 15);
        assert_eq!(quantize(0.5, 4), 8);
        assert_eq!(quantize(0.999, 64), (0.999 * 2f64.powi(64)) as u64);
        assert_eq!(quantize(2.0, 64), u64::MAX);
    }
}
