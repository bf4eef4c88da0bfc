//! The encode stage's algorithms: per-primitive codes over a quantization frame, then a sort.
//! Plain functions over boxes and centres; nothing here knows about files or caches.
//!
//! Modules are named after the methods: `morton` (plain codes, thesis 2.3.4), `emc` (Extended
//! Morton codes, Vinkler et al. 2017 / thesis 3.7.1), `bounds` (scene / centroid / concise frame,
//! Riemersma 3.3), `grid` (occupation grid with mipping, Riemersma 3.2) and `radix` (parallel
//! stable LSD radix sort).
pub mod bounds;
pub mod emc;
pub mod grid;
pub mod morton;
pub mod radix;

use bounds::Frame;
use bvhlab_geom::{Aabb, Vec3};
use bvhlab_params::{Kind, ParamSpec, Params, Read};
use emc::LayoutCoder;
use rayon::prelude::*;
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

impl AutoFor {
    /// The builder's name: `bits=auto` is stored as `auto:<name>`.
    pub fn name(self) -> &'static str {
        match self {
            AutoFor::Aac => "aac",
            AutoFor::Lbvh => "lbvh",
            AutoFor::Ploc => "ploc",
        }
    }
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

/// [`EncodeConfig::bounds`] as a parameter of every encoder.
pub const BOUNDS: ParamSpec = ParamSpec {
    name: "bounds",
    default: "scene",
    kind: Kind::Choice(&["scene", "centroids", "concise"]),
    about: "quantization frame: scene box, centroid box, or concise bounds (Riemersma eq. 15)",
    in_label: false,
};

/// [`EncodeConfig::grid_bits`] as a parameter of every encoder.
pub const GRID_BITS: ParamSpec = ParamSpec {
    name: "grid_bits",
    default: "0",
    kind: Kind::Choice(&["0", "6", "9", "12"]),
    about: "occupation grid bits (Riemersma 3.2.2; 0 = off)",
    in_label: false,
};

/// [`CellFrame`] as a parameter of every encoder.
pub const GRID_FRAME: ParamSpec = ParamSpec {
    name: "grid_frame",
    default: "cell",
    kind: Kind::Choice(&["cell", "tight"]),
    about: "with grid_bits > 0: the in-cell code quantizes the grid cell (cell, Riemersma 3.2.2) or the \
            bounds of the centroids inside it (tight; bvhlab's extension, not in the papers)",
    in_label: false,
};

/// Every encoder's finish rule: `grid_frame` only means something with a grid, so it is kept out
/// of the key (and the row's encode_params) otherwise, and grid-less encodings keep one spelling.
pub fn grid_frame_needs_grid(_given: &Params, params: &mut Params) -> Result<(), String> {
    if params.word("grid_bits") == "0" {
        if params.word("grid_frame") == "tight" {
            return Err(
                "`grid_frame=tight` needs an occupation grid: set grid_bits to 6, 9 or 12".into(),
            );
        }
        params.remove("grid_frame");
    }
    Ok(())
}

impl EncodeConfig {
    /// From an encoder's canonical parameters; `bits=auto` is for the builder `auto`.
    pub fn from_params(scheme: Scheme, p: &Params, auto: AutoFor) -> EncodeConfig {
        let bits = match p.get("bits").map(String::as_str) {
            // EMC codes have no bits parameter (always 64 bits); the field is not read for them,
            // and a constant keeps the config (and so the output) independent of the builder.
            None => Bits::Fixed(10),
            Some(b) if b.starts_with("auto") => Bits::Auto(auto),
            Some(b) => Bits::Fixed(b.parse().unwrap_or(10)),
        };
        let bounds = match p.word("bounds") {
            "centroids" => BoundsMode::Centroids,
            "concise" => BoundsMode::Concise,
            _ => BoundsMode::Scene,
        };
        EncodeConfig {
            scheme,
            bits,
            bounds,
            grid_bits: p.typed("grid_bits"),
        }
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

/// A code generator over a box given in normalized coordinates: plain Morton (magic numbers) or a
/// layout (EMC).
enum Coder {
    Morton { bits: u32 },
    Layout(LayoutCoder),
}

impl Coder {
    /// The scheme's coder for a box with extents `ext` (EMC layouts depend on the box's shape).
    fn new(cfg: &EncodeConfig, n: usize, ext: [f64; 3]) -> Coder {
        match cfg.scheme {
            Scheme::Morton => Coder::Morton { bits: morton::bits_per_axis(cfg.bits, n) },
            Scheme::Emc64Sort => Coder::Layout(LayoutCoder::new(emc::sort_layout(ext))),
            Scheme::Emc64Var => Coder::Layout(LayoutCoder::new(emc::var_layout(ext))),
        }
    }

    fn bits(&self) -> u32 {
        match self {
            Coder::Morton { bits } => 3 * bits,
            Coder::Layout(l) => l.bits(),
        }
    }

    fn layout(&self) -> String {
        match self {
            Coder::Morton { bits } => morton::layout(*bits),
            Coder::Layout(l) => emc::layout_string(&l.letters),
        }
    }

    /// Code of normalized coordinates `u` and normalized size `s`.
    #[inline]
    fn code(&self, u: [f64; 3], s: f64) -> u64 {
        match self {
            Coder::Morton { bits } => morton::code(u, *bits),
            Coder::Layout(l) => l.code(u, s),
        }
    }

    fn has_size(&self) -> bool {
        matches!(self, Coder::Layout(l) if l.counts[3] > 0)
    }
}

/// The scheme's spatial axis sequence (no size bits) over a box with extents `ext`: the order in
/// which the occupation grid splits its cells.
fn spatial_axes(scheme: Scheme, ext: [f64; 3], len: usize) -> Vec<u8> {
    match scheme {
        Scheme::Morton => (0..len).map(|i| [emc::X, emc::Y, emc::Z][i % 3]).collect(),
        Scheme::Emc64Sort => emc::sort_axes(ext, len),
        Scheme::Emc64Var => emc::var_axes(ext, len),
    }
}

/// Which box the occupation grid's in-cell code quantizes (only with `grid_bits > 0`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum CellFrame {
    /// The grid cell itself (Riemersma 3.2.2: "the cells' bounds are smaller than the bounds of
    /// the scene"). What `encode` does.
    Lattice,
    /// EXTENSION (not in the papers): the bounds of the centroids inside the cell, so a dense
    /// object far from an outlier gets the whole in-cell code however far the outlier is.
    Tight,
}

impl CellFrame {
    /// From an encoder's canonical parameters (`grid_frame`).
    pub fn from_params(p: &Params) -> CellFrame {
        match p.word("grid_frame") {
            "tight" => CellFrame::Tight,
            _ => CellFrame::Lattice,
        }
    }
}

/// Computes the codes of every primitive (in parallel) and sorts them with the parallel radix
/// sort; ties are ordered by primitive index. Never panics on degenerate input (empty input,
/// coincident centroids, zero or huge extents); `boxes` and `centers` must have equal length.
pub fn encode(boxes: &[Aabb], centers: &[Vec3], cfg: &EncodeConfig) -> Encoding {
    encode_cells(boxes, centers, cfg, CellFrame::Lattice)
}

/// `encode` with a choice of the occupation grid's in-cell frame (`encode` = `CellFrame::Lattice`).
pub fn encode_cells(boxes: &[Aabb], centers: &[Vec3], cfg: &EncodeConfig, cell_frame: CellFrame) -> Encoding {
    assert_eq!(boxes.len(), centers.len(), "encode: one centre per box");
    let n = boxes.len();
    let frame_box = bounds::frame(boxes, centers, cfg.bounds);
    let frame = Frame::new(&frame_box);
    let coder = Coder::new(cfg, n, frame.ext);
    let total = coder.bits();
    let grid_bits = cfg.grid_bits.min(total).min(grid::MAX_GRID_BITS);

    let (codes, layout) = if grid_bits == 0 {
        let codes: Vec<u64> = if coder.has_size() {
            let fd = frame.diag;
            centers
                .par_iter()
                .zip(boxes.par_iter())
                .map(|(&c, b)| coder.code(frame.normalize(c), bounds::size(b, fd)))
                .collect()
        } else {
            centers.par_iter().map(|&c| coder.code(frame.normalize(c), 0.0)).collect()
        };
        (codes, coder.layout())
    } else {
        let letters = spatial_axes(cfg.scheme, frame.ext, grid_bits as usize);
        let grid = grid::Grid::build(centers, &frame, &letters);
        // The in-cell code is the scheme's code over the cell's own box (EMC layouts follow the
        // cell's shape).
        let incell = Coder::new(cfg, n, grid.cell_extent(&frame));
        debug_assert_eq!(incell.bits(), total);
        let tight = match cell_frame {
            CellFrame::Lattice => None,
            CellFrame::Tight => Some(grid::tight_cells(centers, &frame, &grid)),
        };
        let codes = grid::codes(boxes, centers, &frame, &grid, total, tight.as_deref(), |t, s| incell.code(t, s));
        let lmax = grid.max_concise_len() as usize;
        let mut layout = "g".repeat(lmax);
        layout.extend(incell.layout().chars().take(total as usize - lmax));
        (codes, layout)
    };
    let (codes, order) = radix::sort_with_index(codes);
    Encoding { order, codes, code_bits: total, frame: frame_box, layout }
}
