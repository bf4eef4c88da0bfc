//! One result row per (experiment, scene, stage chain + parameters, ray set).
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Flat, serializable result of one chain. The report turns rows into a polars DataFrame column by
/// column through serde_json, so later issues add fields here (Option, so old rows still read) and
/// the report picks them up. Times are medians over `repeat` runs.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ResultRow {
    pub experiment: String,
    /// Scene spec as given (`gen:sphere:n=1000` or a path).
    pub scene: String,
    /// Short scene name for plots (file stem or generator name with parameters).
    pub scene_name: String,
    pub triangles: u64,
    pub dropped_triangles: u64,
    /// `Scene::precision_loss` (f32 spacing at the largest coordinate over the median edge).
    #[serde(default)]
    pub precision_loss: Option<f64>,
    /// Set when `precision_loss` exceeds `stages::PRECISION_LOSS_WARN` (issue 15).
    #[serde(default)]
    pub precision_warning: Option<String>,
    /// Builder name (`binned-sah`, ...).
    pub builder: String,
    /// Canonical builder parameters, `k=v` joined by `,` in key order (e.g. `bins=16,leaf=2`).
    pub build_params: String,
    /// Compaction applied after the build (`none` or `collapse`).
    pub compact: String,
    /// Display label of the whole chain, e.g. `binned-sah bins=16 +collapse`.
    pub method: String,
    pub c_t: f64,
    pub c_i: f64,
    pub sah_cost: f64,
    pub inner_sa_ratio: f64,
    pub leaf_sa_ratio: f64,
    pub refs_per_leaf: f64,
    pub inner_nodes: u64,
    pub leaves: u64,
    pub depth: u32,
    pub bytes: u64,
    pub bytes_per_triangle: f64,
    pub valid: bool,
    pub bvh_hash: String,
    pub build_seconds: f64,
    /// Encoder of the encode stage (`morton`, `emc64-sort`, `emc64-var`); absent for builders that
    /// take no codes (the top-down ones).
    pub encoder: Option<String>,
    /// Canonical encoder parameters, `k=v` joined by `,` (e.g. `bits=10,bounds=scene,grid_bits=0`);
    /// `bits=auto` is resolved for the builder (e.g. `bits=auto:aac`).
    pub encode_params: Option<String>,
    /// Median seconds of the encode stage (codes + sort).
    pub encode_seconds: Option<f64>,
    /// Meaningful bits per code and the fraction of primitives sharing their code with the previous
    /// one in sorted order (precision lost to quantization; Riemersma 2024).
    pub code_bits: Option<u32>,
    pub duplicate_code_fraction: Option<f64>,
    /// encode_seconds + build_seconds (+ optimize_seconds): the whole construction, what thesis
    /// table 11 compares.
    pub total_build_seconds: f64,
    /// SAH cost of the build stage's tree (before optimization and compaction).
    pub build_sah_cost: Option<f64>,
    /// Optimizer of the optimize stage (`ibo`, `kensler-hc`, `kensler-sa`), absent without one.
    pub optimizer: Option<String>,
    /// Canonical optimizer parameters, `k=v` joined by `,`.
    pub optimize_params: Option<String>,
    /// Median seconds of the optimize stage (included in `total_build_seconds`: Bittner 2013's
    /// build_s is build plus optimization).
    pub optimize_seconds: Option<f64>,
    /// SAH cost right after the optimizer, before compaction (Bittner 2013's "cost"; `sah_cost` is
    /// then its "ocost" when the chain compacts).
    pub optimized_sah_cost: Option<f64>,
    /// Optimization passes run (pass 0, the input, not counted).
    pub optimize_passes: Option<u32>,
    /// Why the optimizer stopped: `converged`, `max_passes` or `max_seconds` (the last is not
    /// reproducible bit for bit).
    pub optimize_stop: Option<String>,
    /// Pass-by-pass trace (pass, seconds, sah_cost, moved, phase) for the convergence plots.
    pub optimize_trace: Option<Vec<bvhlab_opt::PassRecord>>,
    /// Worker threads the stages ran with (rayon pool size); timings depend on it, results do not.
    pub threads: u32,
    /// CPU model the row's timed stages (encode, build, optimize, compact, layout, measure) ran on,
    /// from their manifests. When they ran on different models (a sharded run on a mixed cluster),
    /// the models joined by " + " and `machine_mixed` is set: the row's times must not be added or
    /// compared as if measured on one machine. Empty: unknown (manifests older than issue 12).
    pub machine: String,
    pub machine_mixed: bool,
    /// CPU model(s) of the construction stages alone (encode, build, optimize, compact; joined by
    /// " + " when they differ): what build-time plots and the Pareto front group by, so a row traced
    /// on another model keeps its build time.
    pub build_machine: String,
    /// Focus-box metrics (experiment `[focus]`, for scenes whose interesting part is dwarfed by an
    /// outlier or a huge ground plane): the triangles whose centroid lies inside the focus box, and
    /// the SAH cost (thesis eq. 4, same c_t/c_i) of the smallest subtree holding all of them,
    /// normalized by the surface area of those triangles' own bounds.
    pub focus_triangles: Option<u64>,
    pub focus_sah_cost: Option<f64>,
    /// Median seconds of the compaction stage (0 when none).
    pub compact_seconds: f64,
    /// Ray set (`primary:800x800`, `shadow:800x800`, `random:100000`), absent without a measure stage.
    pub rays_kind: Option<String>,
    pub rays: Option<u64>,
    pub hits: Option<u64>,
    pub traversal_steps_per_ray: Option<f64>,
    pub intersections_per_ray: Option<f64>,
    pub trace_seconds: Option<f64>,
    pub mrays_per_s: Option<f64>,
    /// Layout stage (Kilian 2021): `bvh2`, `qbvh`, `octree`, `octree1`; absent without a layout
    /// stage (the measure stage then traces the flat BVH, i.e. bvh2). With `layout=auto` this is the
    /// layout the search picked and `layout_choice` says why.
    pub layout: Option<String>,
    /// Canonical layout parameters, `k=v` joined by `,` (e.g. `bits=8,chunk_bytes=64,frame=chunk`).
    pub layout_params: Option<String>,
    /// Bytes traversal reads at every step (Kilian 6.2 "size of topology": nodes, or chunks plus
    /// node info), and with the leaf arrays (primitive and offset lists).
    pub topology_bytes: Option<u64>,
    pub total_bytes: Option<u64>,
    pub topology_bytes_per_triangle: Option<f64>,
    pub total_bytes_per_triangle: Option<f64>,
    /// topology_bytes * 8 / layout_nodes.
    pub topology_bits_per_node: Option<f64>,
    /// Nodes of the layout's tree (octrees: octree nodes, not BVH nodes).
    pub layout_nodes: Option<u64>,
    /// Fixed-size chunks and their mean fill (used node slots / slots; Kilian fig. 4.16).
    pub chunks: Option<u64>,
    pub chunk_fill: Option<f64>,
    /// Primitive references in the leaf arrays (octrees repeat primitives).
    pub prim_refs: Option<u64>,
    /// Peak heap growth while building the layout (bytes, counting allocator).
    pub peak_build_bytes: Option<u64>,
    /// Median seconds of the layout build.
    pub layout_seconds: Option<f64>,
    /// SAH cost (thesis eq. 4) evaluated with the boxes the layout's traversal tests (quantized
    /// boxes for qbvh, implicit octant boxes for octrees).
    pub layout_sah_cost: Option<f64>,
    /// Per ray, extra nodes entered and extra triangle tests against the uncompressed structure of
    /// the same topology (qbvh against bvh2 of the same BVH, octree1 against octree; 0 for those).
    pub extra_box_hits_per_ray: Option<f64>,
    pub extra_tests_per_ray: Option<f64>,
    /// Median seconds of the same rays through bvh2 of the same BVH, timed in the same run
    /// alternately with the layout's trace; `slowdown` = trace_seconds / bvh2_trace_seconds.
    pub bvh2_trace_seconds: Option<f64>,
    pub slowdown: Option<f64>,
    /// `layout=auto`: the candidates measured and why this one was picked.
    pub layout_choice: Option<String>,
    /// `layout=auto`: the search's time budget ran out before every candidate that could have
    /// won was measured (the choice is the best of those measured).
    pub auto_budget_cut: Option<bool>,
    /// `layout=auto`: the limit the choice was made under.
    pub auto_max_slowdown: Option<f64>,
    /// `layout=auto`: this row's `slowdown` (or, without rays, the search's) exceeds
    /// `auto_max_slowdown`: the choice does not hold here.
    pub auto_over_limit: Option<bool>,
    /// Path of the primary-ray heat map PNG in the cache, when the ray set is primary.
    pub heatmap: Option<String>,
    /// Stage keys (hex) of this chain, stage name -> key, for provenance.
    pub keys: BTreeMap<String, String>,
}
