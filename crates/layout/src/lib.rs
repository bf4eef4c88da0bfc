//! Memory layouts of an acceleration structure, each with its own closest-hit traversal
//! (Kilian 2021, chapters 4 and 5):
//!
//! - `bvh2`: the flat 32-byte-node BVH every other stage produces (the baseline);
//! - `qbvh_chunks`: Kilian 5.2: quantized child boxes (`bits` per coordinate), the topology as a 1-bit
//!   breadth-first bit field in fixed-size chunks (rank/popcount addressing), node info outside
//!   the chunks, an exact box per chunk root; quantization `frame` = parent box or chunk-root box;
//! - `octree`: Kilian 4.1: 32-bit nodes, implicit boxes, primitive references may repeat;
//! - `octree_1bit`: Kilian 4.2: the same octree as a 1-bit breadth-first bit field in chunks;
//! - `bvh4`, `bvh8`: the BVH collapsed into 4-/8-wide nodes (Wald et al. 2008), SoA boxes, SIMD box tests;
//! - `cwbvh`: `bvh8` in Ylitie et al. 2017's compressed 80-byte nodes (8-bit child boxes on a per-node grid).
//!
//! Every layout must find exactly the closest hit brute force finds (conservative boxes, the shared
//! triangle test and tie rule of `bvhlab_trace`). Algorithms here are plain functions over slices:
//! no files, hashing or caching (that is the pipeline's job).
pub mod bvh2;
pub mod chunks;
pub mod cwbvh;
pub mod octree;
pub mod octree_1bit;
pub mod qbvh_chunks;
pub mod wide;
pub mod wide_collapse;

use bvhlab_bvh::{Bvh, CostParams, Refs};
use bvhlab_geom::Triangle;
use bvhlab_params::{fill, unknown, Method, Spelling};
use bvhlab_trace::{Ray, TraceStats};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The layouts as they describe themselves (name, paper reference, typed parameters): the
/// pipeline's method table lists these (and adds `auto`, a search over them). A new layout adds its
/// entry here and its arms to the dispatches below.
pub const METHODS: [&Method; 7] = [
    &bvh2::METHOD,
    &qbvh_chunks::METHOD,
    &octree::METHOD,
    &octree_1bit::METHOD,
    &wide::METHOD4,
    &wide::METHOD8,
    &cwbvh::METHOD,
];

/// Layout names accepted by `build`.
pub const LAYOUTS: [&str; 7] = [
    METHODS[0].name,
    METHODS[1].name,
    METHODS[2].name,
    METHODS[3].name,
    METHODS[4].name,
    METHODS[5].name,
    METHODS[6].name,
];

/// What a layout costs in memory. "Topology" is Kilian's *size of topology* (6.2): everything
/// traversal reads at every step (nodes; chunks + node info), not the leaf arrays
/// (`primitives_list`, `offset_list`/`sizes_list`), which `total_bytes` adds.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Memory {
    pub topology_bytes: u64,
    pub total_bytes: u64,
    /// Nodes of the topology (bvh2/qbvh_chunks: inner + leaves; octrees: all octree nodes including the root).
    pub nodes: u64,
    /// Fixed-size chunks (0 for unchunked layouts).
    pub chunks: u64,
    /// Mean over chunks of used node slots / node slots (0 for unchunked layouts; Kilian fig. 4.16).
    pub chunk_fill: f64,
    /// Primitive references in the leaf arrays (octrees repeat primitives; BVHs: = triangles).
    pub prim_refs: u64,
}

impl Memory {
    /// Topology bits per node (Kilian's "bits per node").
    pub fn topology_bits_per_node(&self) -> f64 {
        if self.nodes == 0 {
            0.0
        } else {
            self.topology_bytes as f64 * 8.0 / self.nodes as f64
        }
    }
}

/// A layout name with its parameters, validated and with every default filled in (canonical: the
/// pipeline keys the layout stage by `name` + `params`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LayoutSpec {
    pub name: String,
    pub params: BTreeMap<String, String>,
}

/// Layouts renamed in issue 17 (old name, new name, source): `qbvh` left the name free for a 4-wide
/// BVH (quad-BVH). An old name is an error that names the new one ([`renamed`]).
pub const RENAMED: [(&str, &str, &str); 2] = [
    ("qbvh", "qbvh_chunks", "Kilian 2021 5.2"),
    ("octree1", "octree_1bit", "Kilian 2021 4.2"),
];

/// The error for an old layout name (`RENAMED`), `None` for any other name.
pub fn renamed(name: &str) -> Option<String> {
    RENAMED
        .iter()
        .find(|(old, _, _)| *old == name)
        .map(|(old, new, source)| format!("layout `{old}` was renamed to `{new}` ({source})"))
}

impl LayoutSpec {
    /// Parses `name` or `name:k=v,k=v` (as the examples and benchmarks take it) with [`Self::parse`].
    pub fn from_spec(spec: &str) -> Result<LayoutSpec, String> {
        let (name, rest) = spec.split_once(':').unwrap_or((spec, ""));
        let mut kv = BTreeMap::new();
        for p in rest.split(',').filter(|p| !p.is_empty()) {
            let (k, v) = p.split_once('=').ok_or_else(|| format!("`{p}` in `{spec}` is not k=v"))?;
            kv.insert(k.to_string(), v.to_string());
        }
        LayoutSpec::parse(name, &kv)
    }

    /// Validates `name` and `params` against [`METHODS`] (unknown names and bad values are errors
    /// naming the valid choices) and fills in defaults. Values keep their spelling (trimmed): the
    /// layout stage has been keyed by them as written (`mult_threshold=2.0`).
    pub fn parse(name: &str, given: &BTreeMap<String, String>) -> Result<LayoutSpec, String> {
        if let Some(e) = renamed(name) {
            return Err(e);
        }
        let method = METHODS.iter().find(|m| m.name == name).ok_or_else(|| {
            format!("unknown layout `{name}`; valid: {}, auto", LAYOUTS.join(", "))
        })?;
        if let Some(k) = unknown(&[method.params], given) {
            return Err(format!(
                "unknown parameter `{k}` for layout `{name}`; valid parameters: {}",
                bvhlab_params::names(method.params)
            ));
        }
        let params = fill(method.params, given, None, Spelling::AsGiven).map_err(|e| {
            format!(
                "bad value `{}` for `{}` of layout `{name}`: expected {}",
                e.given, e.param, e.want
            )
        })?;
        LayoutSpec::checked(name, params)
    }

    /// A spec from parameters already checked against the layout's [`Method`] and filled in, after
    /// the checks a parameter's range cannot say (e.g. a chunk size a multiple of 8).
    pub fn checked(name: &str, params: BTreeMap<String, String>) -> Result<LayoutSpec, String> {
        let spec = LayoutSpec {
            name: name.to_string(),
            params,
        };
        match name {
            "qbvh_chunks" => qbvh_chunks::Config::from_spec(&spec).map(|_| ())?,
            "octree" => octree::Config::from_spec(&spec).map(|_| ())?,
            "octree_1bit" => octree_1bit::Config::from_spec(&spec).map(|_| ())?,
            _ => {}
        }
        Ok(spec)
    }

    /// Typed parameter (after `parse`, every parameter of the schema is present).
    pub fn get<T: std::str::FromStr>(&self, key: &str) -> Result<T, String> {
        let v = self
            .params
            .get(key)
            .ok_or_else(|| format!("layout `{}`: missing parameter `{key}`", self.name))?;
        v.parse::<T>()
            .map_err(|_| format!("layout `{}`: bad value `{v}` for `{key}`", self.name))
    }

    /// `k=v` joined by `,` in key order.
    pub fn params_string(&self) -> String {
        self.params
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(",")
    }
}

/// A built layout (the layout stage's artifact).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Layout {
    Bvh2(bvh2::Bvh2),
    QbvhChunks(qbvh_chunks::QbvhChunks),
    Octree(octree::Octree),
    Octree1Bit(octree_1bit::Octree1Bit),
    /// `bvh4` or `bvh8` (by its width).
    Wide(wide::WideBvh),
    Cw(cwbvh::CwBvh),
}

/// Start of the error of a build given up at its deadline (`build_until`).
pub const DEADLINE_REACHED: &str = "deadline reached";

/// Builds `spec` for a scene. BVH layouts store `bvh` (its topology is kept exactly); octrees are
/// built from the triangles alone and ignore `bvh`.
pub fn build(spec: &LayoutSpec, bvh: &Bvh, tris: &[Triangle]) -> Result<Layout, String> {
    build_until(spec, bvh, tris, None)
}

/// `build`, given up with an error starting with [`DEADLINE_REACHED`] once `deadline` has passed.
/// Only octree builds check it (between levels): their time is not bounded by the input size;
/// bvh2 and qbvh_chunks builds are one linear pass over the BVH.
pub fn build_until(
    spec: &LayoutSpec,
    bvh: &Bvh,
    tris: &[Triangle],
    deadline: Option<std::time::Instant>,
) -> Result<Layout, String> {
    Ok(match spec.name.as_str() {
        "bvh2" => Layout::Bvh2(bvh2::Bvh2::build(bvh)),
        "bvh4" => Layout::Wide(wide::WideBvh::build_with(bvh, 4, wide::Collapse::from_spec(spec)?)?),
        "bvh8" => Layout::Wide(wide::WideBvh::build_with(bvh, 8, wide::Collapse::from_spec(spec)?)?),
        "cwbvh" => Layout::Cw(cwbvh::CwBvh::build_with(bvh, wide::Collapse::from_spec(spec)?)?),
        "qbvh_chunks" => Layout::QbvhChunks(qbvh_chunks::QbvhChunks::build(bvh, &qbvh_chunks::Config::from_spec(spec)?)?),
        "octree" => Layout::Octree(octree::Octree::build_until(
            tris,
            &octree::Config::from_spec(spec)?,
            deadline,
        )?),
        "octree_1bit" => Layout::Octree1Bit(octree_1bit::Octree1Bit::build_until(
            tris,
            &octree_1bit::Config::from_spec(spec)?,
            deadline,
        )?),
        other => {
            return Err(format!(
                "unknown layout `{other}`; valid: {}",
                LAYOUTS.join(", ")
            ))
        }
    })
}

/// Whether a layout's structure depends on the input BVH (octrees are built from the scene alone,
/// so the pipeline keys them by the scene only).
pub fn uses_bvh(name: &str) -> bool {
    matches!(name, "bvh2" | "qbvh_chunks" | "bvh4" | "bvh8" | "cwbvh")
}

impl Layout {
    pub fn name(&self) -> &'static str {
        match self {
            Layout::Bvh2(_) => "bvh2",
            Layout::QbvhChunks(_) => "qbvh_chunks",
            Layout::Octree(_) => "octree",
            Layout::Octree1Bit(_) => "octree_1bit",
            Layout::Wide(w) if w.width == 4 => "bvh4",
            Layout::Wide(_) => "bvh8",
            Layout::Cw(_) => "cwbvh",
        }
    }

    pub fn memory(&self) -> Memory {
        match self {
            Layout::Bvh2(l) => l.memory(),
            Layout::QbvhChunks(l) => l.memory(),
            Layout::Octree(l) => l.memory(),
            Layout::Octree1Bit(l) => l.memory(),
            Layout::Wide(l) => l.memory(),
            Layout::Cw(l) => l.memory(),
        }
    }

    /// Closest hits of all rays with this layout's own traversal. `steps` = nodes entered (boxes
    /// hit and not culled), `intersections` = ray-triangle tests (repeated references count).
    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        match self {
            Layout::Bvh2(l) => l.trace(tris, rays),
            Layout::QbvhChunks(l) => l.trace(tris, rays),
            Layout::Octree(l) => l.trace(tris, rays),
            Layout::Octree1Bit(l) => l.trace(tris, rays),
            Layout::Wide(l) => l.trace(tris, rays),
            Layout::Cw(l) => l.trace(tris, rays),
        }
    }

    /// The layout prepared for timing (triangles copied into leaf-slot order outside the timed
    /// region): bvh2, bvh4 and bvh8 trace with their fast paths (watertight f32 test, no counters);
    /// the compressed layouts with their own exact traversals (counters included). Every one reads
    /// memory advised for huge pages (`bvhlab_trace::thp`): copies made here where needed.
    pub fn timed<'a>(&'a self, tris: &[Triangle]) -> Timed<'a> {
        match self {
            Layout::Bvh2(l) => Timed::Bvh2(bvhlab_trace::FastBvh2::new(&l.bvh, tris)),
            Layout::Wide(w) => Timed::Wide(w.timed_copy(), w.store(tris)),
            Layout::Cw(c) => Timed::Cw(c.timed_copy(), c.store(tris)),
            other => Timed::Exact(Box::new(other.timed_copy()), bvhlab_trace::thp::copy(tris)),
        }
    }

    /// The compressed layouts (traced exactly) with their arrays copied to memory advised for huge
    /// pages (`bvhlab_trace::thp`), as the fast paths' are, so their slowdown against bvh2 measures
    /// the layout and not the page size. Other layouts: a plain clone (not used for timing).
    fn timed_copy(&self) -> Layout {
        use bvhlab_trace::thp::copy;
        match self {
            // Every field named (no `..l.clone()`, which would copy the large arrays once more).
            Layout::QbvhChunks(l) => Layout::QbvhChunks(qbvh_chunks::QbvhChunks {
                bits: l.bits,
                chunk_bytes: l.chunk_bytes,
                frame: l.frame,
                world: l.world,
                words: copy(&l.words),
                keys: copy(&l.keys),
                offsets: copy(&l.offsets),
                prims: copy(&l.prims),
                nodes: l.nodes,
                fill: l.fill,
            }),
            Layout::Octree(l) => Layout::Octree(octree::Octree {
                world: l.world,
                margin: l.margin,
                nodes: copy(&l.nodes),
                sizes: copy(&l.sizes),
                prims: copy(&l.prims),
                config: l.config.clone(),
            }),
            Layout::Octree1Bit(l) => Layout::Octree1Bit(octree_1bit::Octree1Bit {
                world: l.world,
                margin: l.margin,
                config: l.config.clone(),
                words: copy(&l.words),
                chunks: l.chunks,
                nodes: l.nodes,
                chunk_fill: l.chunk_fill,
                offsets: copy(&l.offsets),
                prims: copy(&l.prims),
            }),
            other => other.clone(),
        }
    }

    /// SAH cost (thesis eq. 4) of the boxes traversal actually tests: quantized boxes for qbvh_chunks,
    /// implicit octant boxes for octrees (leaf cost counts repeated references).
    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        match self {
            Layout::Bvh2(l) => l.sah_cost(cost),
            Layout::QbvhChunks(l) => l.sah_cost(cost),
            Layout::Octree(l) => l.sah_cost(cost),
            Layout::Octree1Bit(l) => l.sah_cost(cost),
            Layout::Wide(l) => l.sah_cost(cost),
            Layout::Cw(l) => l.sah_cost(cost),
        }
    }

    /// Structural check: BVH layouts reference every triangle exactly once and their (quantized)
    /// boxes contain their children and triangles; octrees reference every triangle at least once
    /// and only from leaves whose implicit box overlaps the triangle's box.
    pub fn validate(&self, tris: &[Triangle]) -> Result<(), String> {
        self.validate_refs(tris, Refs::Unique)
    }

    /// [`Layout::validate`] for a BVH built with `refs`: with `Refs::Split` (SBVH, Stich et al.
    /// 2009) the BVH layouts may reference a triangle from several leaves whose boxes each hold a
    /// clipped part of it (`bvhlab_bvh::validate_split`'s rules); octrees are built from the scene
    /// and check their own rules either way.
    pub fn validate_refs(&self, tris: &[Triangle], refs: Refs) -> Result<(), String> {
        match self {
            Layout::Bvh2(l) => l.validate_refs(tris, refs),
            Layout::QbvhChunks(l) => l.validate_refs(tris, refs),
            Layout::Octree(l) => l.validate(tris),
            Layout::Octree1Bit(l) => l.validate(tris),
            Layout::Wide(l) => l.validate_refs(tris, refs),
            Layout::Cw(l) => l.validate_refs(tris, refs),
        }
    }

    /// The uncompressed layout with the same topology, against which extra box hits and extra
    /// triangle tests are counted: qbvh_chunks -> bvh2 of the same BVH, octree_1bit -> octree with the same
    /// construction parameters. `None` when `self` is already uncompressed (bvh2, octree).
    pub fn uncompressed(&self, bvh: &Bvh, tris: &[Triangle]) -> Option<Layout> {
        match self {
            Layout::Bvh2(_) | Layout::Octree(_) | Layout::Wide(_) => None,
            Layout::Cw(l) => Some(Layout::Wide(wide::WideBvh::build_with(bvh, 8, l.collapse).ok()?)),
            Layout::QbvhChunks(_) => Some(Layout::Bvh2(bvh2::Bvh2::build(bvh))),
            Layout::Octree1Bit(l) => l.uncompressed(tris).map(Layout::Octree),
        }
    }
}

/// A layout ready for the timed path ([`Layout::timed`]).
pub enum Timed<'a> {
    Bvh2(bvhlab_trace::FastBvh2<'a>),
    /// The node rows copied to memory advised for huge pages ([`wide::WideBvh::timed_copy`]).
    Wide(wide::WideBvh, bvhlab_trace::PackStore),
    Cw(cwbvh::CwBvh, bvhlab_trace::PackStore),
    /// A compressed layout's advised copy and the triangles' (its exact test reads them).
    Exact(Box<Layout>, Vec<Triangle>),
}

impl Timed<'_> {
    /// Closest hits of `rays` (what is timed). The exact traversals read the copy of the
    /// triangles made by [`Layout::timed`] (`tris` is the same triangles; kept for callers).
    pub fn hits(&self, tris: &[Triangle], rays: &[Ray]) -> Vec<bvhlab_trace::Hit> {
        match self {
            Timed::Bvh2(f) => f.hits(rays),
            Timed::Wide(w, store) => w.hits(store, rays),
            Timed::Cw(c, store) => c.hits(store, rays),
            Timed::Exact(l, own) => {
                // `own` is `Layout::timed`'s copy of the caller's triangles: the same ones.
                debug_assert!(own.len() == tris.len() && own.first() == tris.first() && own.last() == tris.last());
                l.trace(own, rays).hits
            }
        }
    }
}
