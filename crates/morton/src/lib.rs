//! The encode stage's algorithms: per-primitive codes over a quantization frame, then a sort.
//! Plain functions over boxes and centres; nothing here knows about files or caches.
//!
//! SKELETON (lead): the API below is fixed; the bodies are a simple reference version that the
//! encoder work replaces (EMC layouts, concise bounds, occupation grid, parallel radix sort).
use bvhlab_geom::{Aabb, Vec3};
use serde::{Deserialize, Serialize};

/// Which code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Scheme {
    /// Plain Morton code, `bits` per axis interleaved x y z (thesis 2.3.4).
    Morton,
    /// EMC-64-sort (Vinkler et al. 2017, thesis 3.7.1): size bit every 4th bit, axis order by extent.
    Emc64Sort,
    /// EMC-64-var (thesis 3.7.1): size bit every 7th bit, each other bit on the currently largest axis.
    Emc64Var,
}

/// The box the codes quantize (Riemersma 3.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum BoundsMode {
    /// Union of the primitive boxes (the usual choice).
    Scene,
    /// Bounds of the centroids.
    Centroids,
    /// Riemersma eq. 15: scene bounds shrunk by the per-axis minimum gap to the centroid bounds.
    Concise,
}

/// Who `bits=auto` is for: each method's paper picks its own code length.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum AutoFor {
    /// ceil(log4 n) bits per axis (Gu et al. 2013, thesis 3.2.1).
    Aac,
    /// 30-bit codes (10 per axis; Karras 2012).
    Lbvh,
    /// 60-bit codes (20 per axis; Meister and Bittner 2018).
    Ploc,
}

/// Bits per axis of a plain Morton code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Bits {
    Fixed(u32),
    Auto(AutoFor),
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodeConfig {
    pub scheme: Scheme,
    /// Only for `Scheme::Morton` (1..=21 per axis); EMC codes are always 64 bits.
    pub bits: Bits,
    pub bounds: BoundsMode,
    /// Riemersma's occupation grid ("mipping", 3.2.2) with this many grid bits (0 = off; 6, 9, 12).
    pub grid_bits: u32,
}

impl Default for EncodeConfig {
    fn default() -> Self {
        EncodeConfig { scheme: Scheme::Morton, bits: Bits::Fixed(10), bounds: BoundsMode::Scene, grid_bits: 0 }
    }
}

/// Output of the encode stage: the primitive order sorted by code (ties by primitive index, so the
/// result is deterministic) and the codes in that order.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Encoding {
    /// Primitive (scene triangle) indices sorted by code; `codes[i]` is the code of `order[i]`.
    pub order: Vec<u32>,
    pub codes: Vec<u64>,
    /// Number of meaningful bits; the most significant one is bit `code_bits - 1`. AAC's constraint
    /// tree walks the bits from there downwards.
    pub code_bits: u32,
    /// The quantization frame (after the bounds mode).
    pub frame: Aabb,
    /// The bit layout, most significant bit first, one char per bit: `x`, `y`, `z`, `s` (size) or
    /// `g` (occupation-grid cell prefix, variable per cell). For reports and tests.
    pub layout: String,
}

impl Encoding {
    /// Fraction of primitives whose code equals the previous one in sorted order: the precision the
    /// code lost on this scene (0 = every primitive has its own code).
    pub fn duplicate_fraction(&self) -> f64 {
        if self.codes.len() < 2 {
            return 0.0;
        }
        let d = self.codes.windows(2).filter(|w| w[0] == w[1]).count();
        d as f64 / self.codes.len() as f64
    }
}

/// Computes the codes of every primitive and sorts them.
pub fn encode(boxes: &[Aabb], centers: &[Vec3], cfg: &EncodeConfig) -> Encoding {
    assert_eq!(boxes.len(), centers.len());
    let n = boxes.len();
    let bits = match cfg.bits {
        Bits::Fixed(b) => b.clamp(1, 21),
        Bits::Auto(AutoFor::Aac) => {
            // ceil(log4 n)
            let mut b = 1;
            while (1u64 << (2 * b)) < n as u64 {
                b += 1;
            }
            b.min(21)
        }
        Bits::Auto(AutoFor::Lbvh) => 10,
        Bits::Auto(AutoFor::Ploc) => 20,
    };
    let mut frame = Aabb::EMPTY;
    for b in boxes {
        frame.grow(b);
    }
    let ext = (frame.max - frame.min).max(Vec3::splat(f32::MIN_POSITIVE));
    let scale = ((1u64 << bits) as f32) / ext;
    let max = ((1u64 << bits) - 1) as f32;
    let codes: Vec<u64> = centers
        .iter()
        .map(|c| {
            let q = ((*c - frame.min) * scale).clamp(Vec3::ZERO, Vec3::splat(max));
            let (x, y, z) = (q.x as u64, q.y as u64, q.z as u64);
            let mut code = 0u64;
            for i in (0..bits).rev() {
                code = (code << 3) | (((x >> i) & 1) << 2) | (((y >> i) & 1) << 1) | ((z >> i) & 1);
            }
            code
        })
        .collect();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by_key(|&i| (codes[i as usize], i));
    let sorted = order.iter().map(|&i| codes[i as usize]).collect();
    Encoding { order, codes: sorted, code_bits: 3 * bits, frame, layout: "xyz".repeat(bits as usize) }
}
