//! One result row per (experiment, scene, stage chain + parameters, ray set).
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Flat, serializable result of one chain. The report turns rows into a polars DataFrame column by
/// column through serde_json, so later issues add fields here (Option, so old rows still read) and
/// the report picks them up. Times are medians over `repeat` runs; every timed quantity `X` also has
/// `X_spread` ((max - min) / median over its runs, `stats::spread`) and, where it is measured
/// directly, `X_runs` (every run, run order).
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
    /// Triangle references in the leaves: `triangles` for every builder but `sbvh`, whose spatial
    /// splits reference a triangle from several leaves (Stich et al. 2009). The SAH and `bytes`
    /// count references; `bytes_per_triangle` divides by triangles.
    #[serde(default)]
    pub references: u64,
    pub inner_nodes: u64,
    pub leaves: u64,
    pub depth: u32,
    pub bytes: u64,
    pub bytes_per_triangle: f64,
    pub valid: bool,
    /// Why the chain is not `valid`: the first failing stage and its validation message.
    #[serde(default)]
    pub invalid_reason: Option<String>,
    pub bvh_hash: String,
    pub build_seconds: f64,
    /// (max - min) / median of the build runs (`stats::spread`): the noise of `build_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub build_seconds_spread: Option<f64>,
    /// Seconds of every timed build run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub build_seconds_runs: Option<Vec<f64>>,
    /// Peak heap growth of the build stage's first run (the builder's working arrays and its BVH;
    /// not the scene, its boxes and centres, nor the encode stage's codes), counted by the
    /// pipeline's allocator; None for peer libraries (their allocations are not Rust's).
    #[serde(default)]
    pub build_heap_bytes: Option<u64>,
    /// `build_heap_bytes` per triangle of `triangles` (the kept ones; issue 19.4 asks the builders' peak per triangle).
    #[serde(default)]
    pub build_heap_bytes_per_triangle: Option<f64>,
    /// Encoder of the encode stage (`morton`, `emc64-sort`, `emc64-var`); absent for builders that
    /// take no codes (the top-down ones).
    pub encoder: Option<String>,
    /// Canonical encoder parameters, `k=v` joined by `,` (e.g. `bits=10,bounds=scene,grid_bits=0`);
    /// `bits=auto` is resolved for the builder (e.g. `bits=auto:aac`).
    pub encode_params: Option<String>,
    /// Median seconds of the encode stage (codes + sort).
    pub encode_seconds: Option<f64>,
    /// (max - min) / median of the encode runs (`stats::spread`): the noise of `encode_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub encode_seconds_spread: Option<f64>,
    /// Seconds of every timed encode run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub encode_seconds_runs: Option<Vec<f64>>,
    /// Meaningful bits per code and the fraction of primitives sharing their code with the previous
    /// one in sorted order (precision lost to quantization; Riemersma 2024).
    pub code_bits: Option<u32>,
    pub duplicate_code_fraction: Option<f64>,
    /// encode_seconds + build_seconds (+ optimize_seconds): the whole construction, what thesis
    /// table 11 compares.
    pub total_build_seconds: f64,
    /// Range of the total over its stages' runs relative to the total: sum over the stages of
    /// (max - min) / total_build_seconds, i.e. (largest - smallest total that one run of each
    /// stage can add up to) / total. The stages' runs are not paired (each stage runs its own
    /// repeats, possibly in another process), so there are no per-repeat totals to take a spread
    /// of; no `_runs`. None when a stage has fewer than two runs.
    #[serde(default)]
    pub total_build_seconds_spread: Option<f64>,
    /// SAH cost of the build stage's tree (before optimization and compaction).
    pub build_sah_cost: Option<f64>,
    /// Optimizer of the optimize stage (`ibo`, `kensler-hc`, `kensler-sa`), absent without one.
    pub optimizer: Option<String>,
    /// Canonical optimizer parameters, `k=v` joined by `,`.
    pub optimize_params: Option<String>,
    /// Median seconds of the optimize stage (included in `total_build_seconds`: Bittner 2013's
    /// build_s is build plus optimization).
    pub optimize_seconds: Option<f64>,
    /// (max - min) / median of the optimize runs (`stats::spread`): the noise of `optimize_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub optimize_seconds_spread: Option<f64>,
    /// Seconds of every timed optimize run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub optimize_seconds_runs: Option<Vec<f64>>,
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
    /// (max - min) / median of the compaction runs (`stats::spread`): the noise of `compact_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub compact_seconds_spread: Option<f64>,
    /// Seconds of every timed compaction run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub compact_seconds_runs: Option<Vec<f64>>,
    /// Ray set (`primary:800x800`, `shadow:800x800`, `random:100000`), absent without a measure stage.
    pub rays_kind: Option<String>,
    pub rays: Option<u64>,
    pub hits: Option<u64>,
    pub traversal_steps_per_ray: Option<f64>,
    pub intersections_per_ray: Option<f64>,
    pub trace_seconds: Option<f64>,
    /// (max - min) / median of the trace runs (`stats::spread`): the noise of `trace_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub trace_seconds_spread: Option<f64>,
    /// Seconds of every timed trace run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub trace_seconds_runs: Option<Vec<f64>>,
    pub mrays_per_s: Option<f64>,
    /// Spread of rays / seconds over the trace runs (derived from `trace_seconds_runs`).
    #[serde(default)]
    pub mrays_per_s_spread: Option<f64>,
    /// Peer builders (issue 18): the library and version (`Embree 3.13.5`, `obvhs 0.4.0`); absent for
    /// bvhlab's own builders.
    #[serde(default)]
    pub library: Option<String>,
    /// The peer's own traversal of the same rays (one thread, median of the runs): Mrays/s beside
    /// bvhlab's `mrays_per_s` on the same tree, its median seconds, and the rays where its hit
    /// disagrees with bvhlab's exact one (0 expected).
    #[serde(default)]
    pub peer_mrays_per_s: Option<f64>,
    #[serde(default)]
    pub peer_trace_seconds: Option<f64>,
    #[serde(default)]
    pub peer_hit_mismatches: Option<u64>,
    /// Layout stage (Kilian 2021): `bvh2`, `qbvh_chunks`, `octree`, `octree_1bit`; absent without a layout
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
    /// (max - min) / median of the layout build runs (`stats::spread`): the noise of `layout_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub layout_seconds_spread: Option<f64>,
    /// Seconds of every timed layout build run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub layout_seconds_runs: Option<Vec<f64>>,
    /// SAH cost (thesis eq. 4) evaluated with the boxes the layout's traversal tests (quantized
    /// boxes for qbvh_chunks, implicit octant boxes for octrees).
    pub layout_sah_cost: Option<f64>,
    /// Per ray, extra nodes entered and extra triangle tests against the uncompressed structure of
    /// the same topology (qbvh_chunks against bvh2 of the same BVH, octree_1bit against octree; 0 for those).
    pub extra_box_hits_per_ray: Option<f64>,
    pub extra_tests_per_ray: Option<f64>,
    /// Median seconds of the same rays through bvh2 of the same BVH, timed in the same run
    /// alternately with the layout's trace; `slowdown` = trace_seconds / bvh2_trace_seconds.
    pub bvh2_trace_seconds: Option<f64>,
    /// (max - min) / median of the bvh2 anchor trace runs (`stats::spread`): the noise of `bvh2_trace_seconds`. None
    /// with fewer than two runs (noise not measured).
    #[serde(default)]
    pub bvh2_trace_seconds_spread: Option<f64>,
    /// Seconds of every timed bvh2 anchor trace run, in run order (the stage artifact keeps them too).
    #[serde(default)]
    pub bvh2_trace_seconds_runs: Option<Vec<f64>>,
    /// With layout bvh2 the layout is its own anchor (one timing per run for both sides): 1 exactly.
    pub slowdown: Option<f64>,
    /// Spread of the per-run slowdowns `slowdown_runs` (run i of the layout over run i of bvh2,
    /// timed back to back): (max - min) / median. 0 for layout bvh2.
    #[serde(default)]
    pub slowdown_spread: Option<f64>,
    #[serde(default)]
    pub slowdown_runs: Option<Vec<f64>>,
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
    /// `layout=auto`: the chosen layout's slowdown as the search measured it (its random-ray
    /// sample, `AUTO_RUNS` alternated runs; 1 for bvh2) and the spread of its per-run ratios: the
    /// estimate the choice was made on, beside the row's own `slowdown`.
    #[serde(default)]
    pub auto_search_slowdown: Option<f64>,
    #[serde(default)]
    pub auto_search_slowdown_spread: Option<f64>,
    /// Path of the primary-ray heat map PNG in the cache, when the ray set is primary.
    pub heatmap: Option<String>,
    /// Stage keys (hex) of this chain, stage name -> key, for provenance.
    pub keys: BTreeMap<String, String>,
}

impl ResultRow {
    /// The row with every timing zeroed (medians, spreads, runs, rays per second, slowdowns, the
    /// auto search's estimate), keeping which ones are present and how many runs they have: what
    /// must be equal when a stage is recomputed, or run in another process or on another machine.
    pub fn untimed(&self) -> ResultRow {
        let z = |v: Option<f64>| v.map(|_| 0.0);
        let zr = |v: &Option<Vec<f64>>| v.as_ref().map(|v| vec![0.0; v.len()]);
        ResultRow {
            build_seconds: 0.0,
            build_seconds_spread: z(self.build_seconds_spread),
            build_seconds_runs: zr(&self.build_seconds_runs),
            // A measurement like the times (what else the process allocates meanwhile counts).
            build_heap_bytes: self.build_heap_bytes.map(|_| 0),
            build_heap_bytes_per_triangle: z(self.build_heap_bytes_per_triangle),
            encode_seconds: z(self.encode_seconds),
            encode_seconds_spread: z(self.encode_seconds_spread),
            encode_seconds_runs: zr(&self.encode_seconds_runs),
            total_build_seconds: 0.0,
            total_build_seconds_spread: z(self.total_build_seconds_spread),
            optimize_seconds: z(self.optimize_seconds),
            optimize_seconds_spread: z(self.optimize_seconds_spread),
            optimize_seconds_runs: zr(&self.optimize_seconds_runs),
            compact_seconds: 0.0,
            compact_seconds_spread: z(self.compact_seconds_spread),
            compact_seconds_runs: zr(&self.compact_seconds_runs),
            trace_seconds: z(self.trace_seconds),
            trace_seconds_spread: z(self.trace_seconds_spread),
            trace_seconds_runs: zr(&self.trace_seconds_runs),
            mrays_per_s: z(self.mrays_per_s),
            mrays_per_s_spread: z(self.mrays_per_s_spread),
            peer_mrays_per_s: z(self.peer_mrays_per_s),
            peer_trace_seconds: z(self.peer_trace_seconds),
            layout_seconds: z(self.layout_seconds),
            layout_seconds_spread: z(self.layout_seconds_spread),
            layout_seconds_runs: zr(&self.layout_seconds_runs),
            bvh2_trace_seconds: z(self.bvh2_trace_seconds),
            bvh2_trace_seconds_spread: z(self.bvh2_trace_seconds_spread),
            bvh2_trace_seconds_runs: zr(&self.bvh2_trace_seconds_runs),
            slowdown: z(self.slowdown),
            slowdown_spread: z(self.slowdown_spread),
            slowdown_runs: zr(&self.slowdown_runs),
            auto_search_slowdown: z(self.auto_search_slowdown),
            auto_search_slowdown_spread: z(self.auto_search_slowdown_spread),
            ..self.clone()
        }
    }
}
