//! The chain definition: the stages in chain order, the plan of a chain (its nodes and keys,
//! computed up front), and the result row assembled from the stages' summaries.
//!
//! Adding a stage: its file in `stages/` (a `Stage`: version, node declaration, artifacts and
//! compute function; its `mod` line in `stages/mod.rs`), and here its entry in `stages()`, its
//! `Versions` field and its summary read in `row()` (with its columns in `row.rs`).
use super::build::{Build, BUILD_VERSION, BVH_STAGES};
use super::compact::{check_compact, Compact, COMPACT_VERSION};
use super::encode::{Encode, ENCODE_VERSION};
use super::focus::{Focus, FOCUS_VERSION};
use super::layout::{LayoutRequest, LayoutStage, AUTO_BUDGET, LAYOUT_VERSION};
use super::load::{precision_warning, Load, LOAD_VERSION};
use super::measure::{paired_ratios, Measure, MEASURE_VERSION};
use super::optimize::{optimize_info, Optimize, OPTIMIZE_VERSION};
use super::{scene_name, ChainSpec};
use crate::error::{Error, Result};
use crate::key::params_string;
use crate::registry::{fmt_f32, Resolved, ResolvedEncoder, ResolvedOptimizer};
use crate::run::{Node, Runner, Stage, Sum, Timing};
use crate::ResultRow;
use bvhlab_bvh::CostParams;
use bvhlab_geom::stats::spread;
use std::collections::BTreeMap;

/// Stage implementation versions (each stage's `*_VERSION`, in its file); injectable so tests can
/// simulate a version bump.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Versions {
    pub load: u32,
    pub encode: u32,
    pub build: u32,
    pub compact: u32,
    pub optimize: u32,
    pub measure: u32,
    pub focus: u32,
    pub layout: u32,
}

impl Default for Versions {
    fn default() -> Self {
        Versions {
            load: LOAD_VERSION,
            encode: ENCODE_VERSION,
            build: BUILD_VERSION,
            compact: COMPACT_VERSION,
            optimize: OPTIMIZE_VERSION,
            measure: MEASURE_VERSION,
            focus: FOCUS_VERSION,
            layout: LAYOUT_VERSION,
        }
    }
}

/// A chain with its methods resolved and its nodes planned (keys computed, nothing run).
pub(crate) struct Plan {
    pub spec: ChainSpec,
    pub resolved: Resolved,
    /// Encoder of a code-using builder.
    pub encoder: Option<ResolvedEncoder>,
    pub optimizer: Option<ResolvedOptimizer>,
    /// The layout request (set when the layout stage is planned).
    pub layout: Option<LayoutRequest>,
    /// The chain's nodes in chain order (absent stages skipped).
    pub nodes: Vec<Node>,
}

impl Plan {
    pub fn node(&self, stage: &str) -> Option<&Node> {
        self.nodes.iter().find(|n| n.stage == stage)
    }
    pub fn need(&self, stage: &str) -> Result<&Node> {
        self.node(stage)
            .ok_or_else(|| Error::internal(format!("chain has no {stage} stage")))
    }
    /// The node whose BVH is final so far (compact, else optimize, else build): what layout,
    /// measure and focus read.
    pub fn final_bvh(&self) -> &Node {
        self.nodes
            .iter()
            .rev()
            .find(|n| BVH_STAGES.contains(&n.stage))
            .expect("a chain plans its build before what reads it")
    }
}

/// A stage as the chain definition lists it.
pub(crate) struct StageDef {
    pub name: &'static str,
    pub timing: Timing,
    pub declare: fn(&mut Runner, &mut Plan) -> Result<Option<Node>>,
    pub ensure: fn(&mut Runner, &Plan) -> Result<()>,
}

fn def<S: Stage>() -> StageDef {
    StageDef {
        name: S::NAME,
        timing: S::TIMING,
        declare: S::declare,
        ensure: S::ensure,
    }
}

/// Every stage in chain order: a stage's inputs are stages before it.
pub(crate) fn stages() -> [StageDef; 8] {
    [
        def::<Load>(),
        def::<Encode>(),
        def::<Build>(),
        def::<Optimize>(),
        def::<Compact>(),
        def::<LayoutStage>(),
        def::<Measure>(),
        def::<Focus>(),
    ]
}

/// Validates a chain and computes every key without running anything.
pub(crate) fn plan(rt: &mut Runner, spec: &ChainSpec) -> Result<Plan> {
    if spec.repeat == 0 {
        return Err(Error::input("repeat must be at least 1"));
    }
    check_compact(&spec.compact)?;
    let chain = rt.registry.resolve_chain(
        &spec.build,
        spec.encode.as_deref(),
        spec.optimize.as_deref(),
        &spec.params,
        spec.cost,
    )?;
    let mut plan = Plan {
        spec: spec.clone(),
        resolved: chain.build,
        encoder: chain.encoder,
        optimizer: chain.optimizer,
        layout: None,
        nodes: Vec::new(),
    };
    for s in stages() {
        if let Some(n) = (s.declare)(rt, &mut plan)? {
            plan.nodes.push(n);
        }
    }
    Ok(plan)
}

pub(crate) fn param(k: &str, v: impl ToString) -> (String, String) {
    (k.to_string(), v.to_string())
}

/// The cost constants as key parameters (shortest round-trip floats).
pub(crate) fn cost_params(cost: CostParams) -> [(String, String); 2] {
    [
        param("c_t", fmt_f32(cost.c_t)),
        param("c_i", fmt_f32(cost.c_i)),
    ]
}

/// A method's own version (builder, encoder, optimizer, layout) in its stage's key parameters.
/// Version 1, every method's first, adds nothing: keys written before methods had versions stay
/// valid. From 2 on the key has `method_version`, so bumping one method recomputes its nodes and
/// what is downstream of them, and nothing else.
pub(crate) fn method_version(params: &mut BTreeMap<String, String>, version: u32) {
    if version != 1 {
        params.insert("method_version".into(), version.to_string());
    }
}

/// The parameters of a method's stage (build, encode, optimize): the method's own, its name under
/// `kind`, the repeat count and (from 2 on) its version.
pub(crate) fn method_params(
    mut params: BTreeMap<String, String>,
    kind: &str,
    name: &str,
    repeat: u32,
    version: u32,
) -> BTreeMap<String, String> {
    params.insert(kind.into(), name.into());
    params.insert("repeat".into(), repeat.to_string());
    method_version(&mut params, version);
    params
}

/// The summary of `S` if the chain has that stage.
fn summary_if<S: Stage>(rt: &mut Runner, plan: &Plan) -> Result<Option<Sum<S>>> {
    match plan.node(S::NAME) {
        Some(_) => rt.summary::<S>(plan).map(Some),
        None => Ok(None),
    }
}

/// Runs (or reads from the cache) every stage of the chain and assembles its result row.
pub(crate) fn row(rt: &mut Runner, plan: &Plan, experiment: &str) -> Result<ResultRow> {
    let spec = &plan.spec;
    let scene = rt.summary::<Load>(plan)?;
    let encode = summary_if::<Encode>(rt, plan)?;
    let build = rt.summary::<Build>(plan)?;
    let optimized = summary_if::<Optimize>(rt, plan)?;
    let opt_info = optimize_info(rt, plan)?;
    let compact = summary_if::<Compact>(rt, plan)?;
    let layout = summary_if::<LayoutStage>(rt, plan)?;
    let measure = summary_if::<Measure>(rt, plan)?;
    let focus = summary_if::<Focus>(rt, plan)?;
    let fin = compact.as_ref().or(optimized.as_ref()).unwrap_or(&build);
    let m = &fin.metrics;
    let (machine, machine_mixed, build_machine) = timing_machine(rt, plan);
    let keys: BTreeMap<String, String> = plan
        .nodes
        .iter()
        .map(|n| (n.stage.to_string(), n.key.hex()))
        .collect();
    let mut method = rt.registry.label(&plan.resolved);
    if let Some(e) = &plan.encoder {
        method.push_str(&format!(" \u{b7} {}", rt.registry.encoder_label(e)));
    }
    if let Some(o) = &plan.optimizer {
        method.push_str(&format!(" +{}", rt.registry.optimizer_label(o)));
    }
    if spec.compact != "none" {
        method.push_str(&format!(" +{}", spec.compact));
    }
    // `auto` keeps its request in the label (scene independent, so plots group its rows); the
    // layout it picked per scene is in `layout` / `layout_params`.
    match &plan.layout {
        Some(LayoutRequest::Fixed(l)) if l.params.is_empty() => {
            method.push_str(&format!(" @{}", l.name))
        }
        Some(LayoutRequest::Fixed(l)) => {
            method.push_str(&format!(" @{} {}", l.name, l.params_string()))
        }
        Some(LayoutRequest::Auto(a)) => {
            method.push_str(&format!(
                " @auto max_slowdown={},rays={}",
                a.max_slowdown, a.rays
            ));
            // Only a non-default budget shows: labels of earlier reports stay the same.
            if a.budget != AUTO_BUDGET {
                method.push_str(&format!(",budget={}", a.budget));
            }
        }
        None => {}
    }
    let per_ray = |total: u64, rays: u64| {
        if rays == 0 {
            0.0
        } else {
            total as f64 / rays as f64
        }
    };
    let mut row = ResultRow {
        experiment: experiment.to_string(),
        scene: spec.scene.clone(),
        scene_name: scene_name(&spec.scene),
        triangles: scene.triangles,
        dropped_triangles: scene.dropped_triangles,
        precision_loss: Some(scene.precision_loss),
        precision_warning: precision_warning(&spec.scene, scene.precision_loss),
        builder: plan.resolved.builder.clone(),
        build_params: params_string(&plan.resolved.params),
        compact: spec.compact.clone(),
        method,
        c_t: plan.resolved.cost.c_t as f64,
        c_i: plan.resolved.cost.c_i as f64,
        sah_cost: m.sah_cost,
        inner_sa_ratio: m.inner_sa_ratio,
        leaf_sa_ratio: m.leaf_sa_ratio,
        refs_per_leaf: m.refs_per_leaf,
        // Exact: refs_per_leaf is references / leaves in f64 (both far below 2^53).
        references: (m.refs_per_leaf * m.leaves as f64).round() as u64,
        inner_nodes: m.inner_nodes,
        leaves: m.leaves,
        depth: m.depth,
        bytes: m.bytes,
        bytes_per_triangle: m.bytes as f64 / scene.triangles.max(1) as f64,
        valid: build.valid
            && optimized.as_ref().is_none_or(|o| o.valid)
            && fin.valid
            && layout.as_ref().is_none_or(|l| l.valid),
        invalid_reason: [
            ("build", build.invalid_reason.as_ref()),
            ("optimize", optimized.as_ref().and_then(|o| o.invalid_reason.as_ref())),
            ("compact", fin.invalid_reason.as_ref()),
            ("layout", layout.as_ref().and_then(|l| l.invalid_reason.as_ref())),
        ]
        .into_iter()
        .find_map(|(stage, r)| r.map(|r| format!("{stage}: {r}"))),
        bvh_hash: fin.bvh_hash.clone(),
        build_seconds: build.median_seconds,
        encoder: plan.encoder.as_ref().map(|e| e.encoder.clone()),
        encode_params: plan.encoder.as_ref().map(|e| params_string(&e.params)),
        encode_seconds: encode.as_ref().map(|e| e.median_seconds),
        code_bits: encode.as_ref().map(|e| e.code_bits),
        duplicate_code_fraction: encode.as_ref().map(|e| e.duplicate_fraction),
        total_build_seconds: encode.as_ref().map(|e| e.median_seconds).unwrap_or(0.0)
            + build.median_seconds
            + optimized.as_ref().map(|o| o.median_seconds).unwrap_or(0.0),
        build_sah_cost: Some(build.metrics.sah_cost),
        optimizer: plan.optimizer.as_ref().map(|o| o.optimizer.clone()),
        optimize_params: plan.optimizer.as_ref().map(|o| params_string(&o.params)),
        optimize_seconds: optimized.as_ref().map(|o| o.median_seconds),
        optimized_sah_cost: optimized.as_ref().map(|o| o.metrics.sah_cost),
        optimize_passes: opt_info
            .as_ref()
            .map(|i| i.trace.len().saturating_sub(1) as u32),
        optimize_stop: opt_info.as_ref().map(|i| i.stop.clone()),
        optimize_trace: opt_info.map(|i| i.trace),
        threads: rayon::current_num_threads() as u32,
        machine,
        machine_mixed,
        build_machine,
        focus_triangles: focus.as_ref().map(|f| f.triangles),
        focus_sah_cost: focus.as_ref().and_then(|f| f.sah_cost),
        compact_seconds: compact.as_ref().map(|c| c.median_seconds).unwrap_or(0.0),
        rays_kind: measure.as_ref().map(|x| x.rays_kind.clone()),
        rays: measure.as_ref().map(|x| x.rays),
        hits: measure.as_ref().map(|x| x.hits),
        traversal_steps_per_ray: measure.as_ref().map(|x| per_ray(x.total_steps, x.rays)),
        intersections_per_ray: measure
            .as_ref()
            .map(|x| per_ray(x.total_intersections, x.rays)),
        trace_seconds: measure.as_ref().map(|x| x.median_seconds),
        mrays_per_s: measure.as_ref().map(|x| {
            if x.median_seconds > 0.0 {
                x.rays as f64 / x.median_seconds / 1e6
            } else {
                0.0
            }
        }),
        library: rt.registry.get(&plan.resolved.builder).ok().and_then(|b| b.peer).map(|p| p.library()),
        peer_mrays_per_s: measure.as_ref().and_then(|x| x.peer.as_ref()).map(|p| {
            let rays = measure.as_ref().map_or(0, |x| x.rays) as f64;
            if p.median_seconds > 0.0 {
                rays / p.median_seconds / 1e6
            } else {
                0.0
            }
        }),
        peer_trace_seconds: measure.as_ref().and_then(|x| x.peer.as_ref()).map(|p| p.median_seconds),
        peer_hit_mismatches: measure.as_ref().and_then(|x| x.peer.as_ref()).map(|p| p.hit_mismatches),
        heatmap: measure
            .as_ref()
            .and_then(|x| x.heatmap.as_ref())
            .map(|h| rt.store.root().join(h).to_string_lossy().to_string()),
        layout: layout.as_ref().map(|l| l.layout.clone()),
        layout_params: layout.as_ref().map(|l| l.params.clone()),
        topology_bytes: layout.as_ref().map(|l| l.memory.topology_bytes),
        total_bytes: layout.as_ref().map(|l| l.memory.total_bytes),
        topology_bytes_per_triangle: layout
            .as_ref()
            .map(|l| l.memory.topology_bytes as f64 / scene.triangles.max(1) as f64),
        total_bytes_per_triangle: layout
            .as_ref()
            .map(|l| l.memory.total_bytes as f64 / scene.triangles.max(1) as f64),
        topology_bits_per_node: layout.as_ref().map(|l| l.memory.topology_bits_per_node()),
        layout_nodes: layout.as_ref().map(|l| l.memory.nodes),
        chunks: layout.as_ref().map(|l| l.memory.chunks),
        chunk_fill: layout.as_ref().map(|l| l.memory.chunk_fill),
        prim_refs: layout.as_ref().map(|l| l.memory.prim_refs),
        peak_build_bytes: layout.as_ref().map(|l| l.peak_build_bytes),
        layout_seconds: layout.as_ref().map(|l| l.median_seconds),
        layout_sah_cost: layout.as_ref().map(|l| l.sah_cost),
        extra_box_hits_per_ray: measure.as_ref().and_then(|x| x.extra_box_hits_per_ray),
        extra_tests_per_ray: measure.as_ref().and_then(|x| x.extra_tests_per_ray),
        bvh2_trace_seconds: measure.as_ref().and_then(|x| x.bvh2_median_seconds),
        slowdown: measure.as_ref().and_then(|x| {
            x.bvh2_median_seconds
                .filter(|&b| b > 0.0)
                .map(|b| x.median_seconds / b)
        }),
        layout_choice: layout
            .as_ref()
            .and_then(|l| l.choice.as_ref().map(|c| c.reason.clone())),
        auto_budget_cut: layout
            .as_ref()
            .and_then(|l| l.choice.as_ref().map(|c| c.budget_cut)),
        auto_max_slowdown: layout
            .as_ref()
            .and_then(|l| l.choice.as_ref().map(|c| c.max_slowdown)),
        ..Default::default()
    };
    row.keys = keys;
    // Issue 16: every timed quantity keeps its runs and their spread beside the median.
    let runs = |v: &[f64]| Some(v.to_vec());
    row.build_seconds_spread = spread(&build.seconds);
    row.build_seconds_runs = runs(&build.seconds);
    row.build_heap_bytes = build.peak_heap_bytes;
    row.build_heap_bytes_per_triangle =
        build.peak_heap_bytes.map(|b| b as f64 / row.triangles.max(1) as f64);
    if let Some(e) = &encode {
        row.encode_seconds_spread = spread(&e.seconds);
        row.encode_seconds_runs = runs(&e.seconds);
    }
    if let Some(o) = &optimized {
        row.optimize_seconds_spread = spread(&o.seconds);
        row.optimize_seconds_runs = runs(&o.seconds);
    }
    if let Some(c) = &compact {
        row.compact_seconds_spread = spread(&c.seconds);
        row.compact_seconds_runs = runs(&c.seconds);
    }
    row.total_build_seconds_spread = {
        let stages: Vec<&[f64]> = [
            encode.as_ref().map(|e| e.seconds.as_slice()),
            Some(build.seconds.as_slice()),
            optimized.as_ref().map(|o| o.seconds.as_slice()),
        ]
        .into_iter()
        .flatten()
        .collect();
        let range = |v: &[f64]| {
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                - v.iter().copied().fold(f64::INFINITY, f64::min)
        };
        (stages.iter().all(|v| spread(v).is_some()) && row.total_build_seconds > 0.0)
            .then(|| stages.iter().map(|v| range(v)).sum::<f64>() / row.total_build_seconds)
    };
    if let Some(x) = &measure {
        row.trace_seconds_spread = spread(&x.seconds);
        row.trace_seconds_runs = runs(&x.seconds);
        let mrays: Vec<f64> = x
            .seconds
            .iter()
            .filter(|&&t| t > 0.0)
            .map(|t| x.rays as f64 / t / 1e6)
            .collect();
        row.mrays_per_s_spread = (mrays.len() == x.seconds.len())
            .then(|| spread(&mrays))
            .flatten();
        if let Some(b) = &x.bvh2_seconds {
            row.bvh2_trace_seconds_spread = spread(b);
            row.bvh2_trace_seconds_runs = runs(b);
            let r = paired_ratios(&x.seconds, b);
            if !r.is_empty() {
                row.slowdown_spread = spread(&r);
                row.slowdown_runs = Some(r);
            }
        }
    }
    if let Some(l) = &layout {
        row.layout_seconds_spread = spread(&l.seconds);
        row.layout_seconds_runs = runs(&l.seconds);
        if let Some(c) = &l.choice {
            let chosen = &c.candidates[c.chosen];
            row.auto_search_slowdown = Some(chosen.slowdown);
            row.auto_search_slowdown_spread = if chosen.layout == "bvh2" {
                Some(0.0)
            } else {
                spread(&paired_ratios(&chosen.seconds, &chosen.bvh2_seconds))
            };
        }
    }
    // The choice was judged on the search's random rays; this row's slowdown is measured
    // again on the chain's own rays (often primary, where compressed layouts lose more) and
    // under other machine load. Either one above the limit is flagged, never silent.
    row.auto_over_limit = layout
        .as_ref()
        .and_then(|l| l.choice.as_ref())
        .map(|c| c.over_limit || row.slowdown.is_some_and(|s| s > c.max_slowdown));
    Ok(row)
}

/// CPU model a node was computed on (its manifest's; "" if unknown).
fn node_cpu_model(rt: &mut Runner, node: &Node) -> String {
    if let Some(m) = rt.cpu_models.get(&(node.stage, node.key)) {
        return m.clone();
    }
    let m = rt
        .store
        .read_manifest(node.stage, &node.key)
        .map(|m| m.machine.cpu_model)
        .unwrap_or_default();
    rt.cpu_models.insert((node.stage, node.key), m.clone());
    m
}

/// The row's `machine`, `machine_mixed` and `build_machine` from the timed nodes of the chain
/// (unknown models are compatible with any: caches written before models were recorded are
/// not flagged).
fn timing_machine(rt: &mut Runner, plan: &Plan) -> (String, bool, String) {
    let defs = stages();
    let timed = |t: Timing| {
        let defs = &defs;
        plan.nodes
            .iter()
            .filter(move |n| defs.iter().any(|s| s.name == n.stage && s.timing == t))
    };
    let build: Vec<&Node> = timed(Timing::Build).collect();
    let trace: Vec<&Node> = timed(Timing::Trace).collect();
    let mut models: Vec<String> = Vec::new();
    let mut build_models = 0;
    for (i, n) in build.iter().chain(&trace).enumerate() {
        let m = node_cpu_model(rt, n);
        if !m.is_empty() && !models.contains(&m) {
            models.push(m);
        }
        if i + 1 == build.len() {
            build_models = models.len();
        }
    }
    (
        models.join(" + "),
        models.len() > 1,
        models[..build_models].join(" + "),
    )
}
