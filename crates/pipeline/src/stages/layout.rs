//! The layout stage: the final BVH (or, for octrees, the scene) stored in a memory layout of
//! Kilian 2021 (`bvhlab_layout`), each with its own exact traversal, which measure then traces;
//! or `auto`, the smallest layout within a slowdown limit (the search is in `auto.rs`).
use super::auto::auto_search;
use super::build::final_bvh;
use super::chain::{cost_params, method_version, param, Plan};
use super::load::Load;
use crate::batch::{Batch, SameAsFirst};
use crate::error::{Error, Result};
use crate::run::{Artifact, Files, Node, Runner, Stage, Timing};
use bvhlab_bvh::Bvh;
use bvhlab_geom::stats::median;
use bvhlab_layout::{Layout, LayoutSpec, Memory};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// 3: layout names `qbvh` -> `qbvh_chunks`, `octree1` -> `octree_1bit` (issue 17); an `auto`
///    artifact records the chosen candidate by name. Layout contents are unchanged.
/// 4: bvh2's timed traversal reads child pairs (`bvhlab_trace::pairs`); every layout's slowdown is
///    against bvh2's time, so every layout node is timed again.
/// A change of one layout bumps that layout's own version (`.with_version(2)` on its `METHOD` in
/// `bvhlab_layout`): its layout nodes get new keys, and so do the `auto` nodes (which may choose
/// it), nothing else.
/// 5: timed runs of calls shorter than 10 ms are batched (`crate::batch`): every time is re-measured.
/// 6: bvh2's timed traversal runs in an AVX2 build where the CPU has it; every layout's slowdown is
///    against bvh2's time, so every layout node is timed again.
/// 7: bvh2's timed traversal reads one arena of pairs and triangles by offsets (faster, same hits);
///    every layout's slowdown is against bvh2's time, so every layout node is timed again.
/// 8: the timed layouts' memory (the compressed layouts' arrays and triangles too) is advised for
///    transparent huge pages (`bvhlab_trace::thp`): every layout node is timed again.
/// 9: cwbvh's leaf table advised too and buffers collapsed once filled (changed on main after 8
///    was first used): every layout node is timed again.
pub const LAYOUT_VERSION: u32 = 9;

/// A layout request: a layout with its parameters, or the `auto` search (Kilian 2021 layouts; the
/// chosen one then behaves as if it had been given).
#[derive(Clone, Debug, PartialEq)]
pub enum LayoutRequest {
    Fixed(LayoutSpec),
    Auto(AutoSpec),
}

/// `auto:max_slowdown=X,rays=N,budget=B`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoSpec {
    /// Largest accepted trace-time ratio against bvh2 of the same BVH (bvh2 always qualifies).
    pub max_slowdown: f64,
    /// Random rays the candidates are timed on.
    pub rays: u32,
    /// Time the search may spend, in multiples of one bvh2 trace of those rays (timed at the
    /// start of the search): once spent, no further candidate is built or timed.
    pub budget: f64,
}

pub const AUTO_MAX_SLOWDOWN: f64 = 1.25;
pub const AUTO_RAYS: u32 = 20_000;
pub const AUTO_BUDGET: f64 = 10.0;
/// Seed of the auto search's ray sample (part of its key through `rays`/the candidate list).
pub const AUTO_SEED: u64 = 0xa070_1a70;
/// Timed runs per candidate (each alternated with bvh2); the median is compared.
pub const AUTO_RUNS: usize = 3;

/// The `auto` search space, kept small (every candidate is built and timed per scene): bvh2; qbvh_chunks
/// with chunk_bytes 64/128 x frame chunk/parent x bits 4/6/8; octree_1bit in 16-byte chunks filled
/// breadth-first or densely.
pub fn auto_candidates() -> Vec<String> {
    let mut c = vec!["bvh2".to_string()];
    for chunk in [64, 128] {
        for frame in ["chunk", "parent"] {
            for bits in [4, 6, 8] {
                c.push(format!(
                    "qbvh_chunks:bits={bits},chunk_bytes={chunk},frame={frame}"
                ));
            }
        }
    }
    for fill in ["bfs", "dense"] {
        c.push(format!("octree_1bit:chunk_bytes=16,fill={fill}"));
    }
    c
}

/// Parses `NAME[:k=v,k=v]` (`bvh2`, `qbvh_chunks:chunk_bytes=128,frame=parent,bits=6`,
/// `octree_1bit:chunk_bytes=16`, `auto:max_slowdown=1.3,rays=20000`) against the standard layout
/// table (`crate::methods::layouts`). Unknown names, parameters and bad values are input errors;
/// defaults are filled in.
pub fn parse_layout(spec: &str) -> Result<LayoutRequest> {
    crate::methods::layouts::parse(crate::methods::layouts::standard_table(), spec)
}

/// One candidate of the auto search as measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutoCandidate {
    pub layout: String,
    pub params: String,
    pub total_bytes: u64,
    pub total_bytes_per_triangle: f64,
    /// Candidate and bvh2 times of the alternated runs.
    pub seconds: Vec<f64>,
    pub bvh2_seconds: Vec<f64>,
    /// median(seconds) / median(bvh2_seconds) (bvh2 itself: 1, the baseline, not timed).
    pub slowdown: f64,
    /// Why the candidate could not be used (build error, invalid, hits differing from bvh2).
    pub error: Option<String>,
    /// Seconds its build (and validation) took inside the search.
    pub build_seconds: f64,
    /// Why it was not built or not timed (None: it was fully measured, or is unusable).
    pub skipped: Option<String>,
}

/// The auto search's decision, stored with the chosen layout (machine dependent: it depends on
/// timings).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AutoChoice {
    pub max_slowdown: f64,
    pub rays: u32,
    pub candidates: Vec<AutoCandidate>,
    /// Index into `candidates`.
    pub chosen: usize,
    /// Human-readable reason (the row's `layout_choice`).
    pub reason: String,
    /// The budget in multiples of the bvh2 trace, that trace's seconds, the budget in seconds and
    /// the seconds the search took (it can overrun by the one step that was running).
    pub budget: f64,
    pub bvh2_trace_seconds: f64,
    pub budget_seconds: f64,
    pub search_seconds: f64,
    /// The budget ran out before every candidate that could have won was measured: the choice
    /// is the best among those measured (`skipped` says which were not).
    pub budget_cut: bool,
    /// Labels of the candidates the budget cut (not built, or built but not timed).
    pub skipped: Vec<String>,
    /// The chosen layout's slowdown in the search exceeds max_slowdown (only possible for the
    /// bvh2 fallback with max_slowdown < 1); the row re-judges it on its own measured slowdown.
    pub over_limit: bool,
}

/// Summary of the layout stage (`layout/<key>.sum`): what a row needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayoutSummary {
    /// Layout name and canonical parameters (with `auto`: the chosen ones).
    pub layout: String,
    pub params: String,
    pub memory: Memory,
    /// Seconds of each of the `repeat` builds.
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
    /// `Layout::sah_cost` with the chain's c_t / c_i.
    pub sah_cost: f64,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    /// Heap growth of the first build (process-wide counting allocator, see `memtrack`).
    pub peak_build_bytes: u64,
    /// blake3 of the encoded layout.
    pub layout_hash: String,
    pub choice: Option<AutoChoice>,
}

/// Full artifact of the layout stage (`layout/<key>.bin`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayoutArtifact {
    pub layout: Layout,
    pub summary: LayoutSummary,
}

pub(crate) struct LayoutStage;

impl Stage for LayoutStage {
    const NAME: &'static str = "layout";
    const TIMING: Timing = Timing::Trace;
    type Full = LayoutArtifact;

    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        let Some(spec) = &plan.spec.layout else {
            return Ok(None);
        };
        let req = parse_layout(spec)?;
        let load = ("load", plan.need("load")?.key);
        let fin = plan.final_bvh();
        let fin = (fin.stage, fin.key);
        let (mut p, inputs): (BTreeMap<String, String>, _) = match &req {
            LayoutRequest::Fixed(l) => {
                let mut p = l.params.clone();
                p.insert("layout".into(), l.name.clone());
                method_version(&mut p, rt.registry.layout(&l.name)?.version);
                // Octrees are built from the triangles alone: keyed by the scene, so every
                // builder's chain shares one octree node.
                let inputs = if bvhlab_layout::uses_bvh(&l.name) {
                    vec![load, fin]
                } else {
                    vec![load]
                };
                (p, inputs)
            }
            LayoutRequest::Auto(a) => {
                let candidates = auto_candidates();
                let mut p: BTreeMap<String, String> = [
                    param("layout", "auto"),
                    param("max_slowdown", a.max_slowdown),
                    param("rays", a.rays),
                    param("seed", AUTO_SEED),
                    param("runs", AUTO_RUNS),
                    param("budget", a.budget),
                    param("candidates", candidates.join(";")),
                ]
                .into();
                // Versions of the candidate layouts past their first (none: the key as before).
                let bumped: Vec<String> = rt
                    .registry
                    .layouts
                    .iter()
                    .filter(|l| {
                        l.version != 1 && candidates.iter().any(|c| c.split(':').next() == Some(l.name))
                    })
                    .map(|l| format!("{}={}", l.name, l.version))
                    .collect();
                if !bumped.is_empty() {
                    p.insert("method_versions".into(), bumped.join(","));
                }
                (p, vec![load, fin])
            }
        };
        p.extend(cost_params(plan.resolved.cost));
        p.insert("repeat".into(), plan.spec.repeat.to_string());
        plan.layout = Some(req);
        Ok(Some(Node::new(Self::NAME, rt.versions.layout, p, inputs)))
    }


    fn compute(rt: &mut Runner, plan: &Plan, _: &Node) -> Result<(LayoutArtifact, Files)> {
        let req = plan
            .layout
            .clone()
            .ok_or_else(|| Error::internal("chain has no layout stage"))?;
        let scene = rt.full::<Load>(plan)?;
        let tris = &scene.triangles;
        let cost = plan.resolved.cost;
        let needs_bvh = match &req {
            LayoutRequest::Fixed(l) => bvhlab_layout::uses_bvh(&l.name),
            LayoutRequest::Auto(_) => true,
        };
        // Octrees ignore the BVH: do not load (or compute) it for them.
        let input = if needs_bvh {
            Some(final_bvh(rt, plan)?)
        } else {
            None
        };
        let empty = Bvh {
            nodes: Vec::new(),
            prim_indices: Vec::new(),
        };
        let bvh = input.as_ref().map(|a| &a.bvh).unwrap_or(&empty);
        let (spec, choice) = match req {
            LayoutRequest::Fixed(l) => (l, None),
            LayoutRequest::Auto(a) => {
                let (l, c) = auto_search(&rt.ops, plan, a, bvh, &scene, rt.registry.get(&plan.resolved.builder)?.refs)?;
                (l, Some(c))
            }
        };
        let mut seconds = Vec::new();
        let mut first: Option<(bvhlab_layout::Layout, blake3::Hash)> = None;
        let mut peak = 0;
        let mut batch = Batch::new();
        // Every call's layout against the first call's (untimed; a short build is called many times).
        let mut same = SameAsFirst::default();
        let mut check = |l: &bvhlab_layout::Layout| -> Result<()> {
            // Streamed: the check runs inside the peak-heap window.
            let h = crate::codec::digest(l).map_err(Error::internal)?;
            same.check(h, |call| {
                Error::internal(format!(
                    "layout `{}` is not deterministic: call {call} produced a different layout than call 1 on {}",
                    spec.name, plan.spec.scene
                ))
            })
        };
        for run in 0..plan.spec.repeat {
            // Peak heap of the first build only (later builds reuse freed memory the same way).
            let mark = (run == 0).then(crate::memtrack::reset_peak);
            let build = || {
                let l = (rt.ops.layout)(&spec, bvh, tris, None)
                    .map_err(|e| Error::internal(format!("layout `{}` on {}: {e}", spec.name, plan.spec.scene)))?;
                Ok((l, None))
            };
            let (l, s) = batch.run_checked(build, &mut check)?;
            seconds.push(s);
            if let Some(m) = mark {
                peak = crate::memtrack::peak_since(m);
            }
            if first.is_none() {
                let h = blake3::hash(&crate::codec::encode(&l).map_err(Error::internal)?);
                first = Some((l, h));
            }
        }
        let (layout, hash) = first.ok_or_else(|| Error::internal("repeat = 0"))?;
        let validation = layout.validate_refs(tris, rt.registry.get(&plan.resolved.builder)?.refs);
        let summary = LayoutSummary {
            layout: spec.name.clone(),
            params: spec.params_string(),
            memory: layout.memory(),
            median_seconds: median(&seconds),
            seconds,
            sah_cost: layout.sah_cost(cost),
            valid: validation.is_ok(),
            invalid_reason: validation.err(),
            peak_build_bytes: peak,
            layout_hash: hash.to_hex().to_string(),
            choice,
        };
        Ok((LayoutArtifact { layout, summary }, Files::new()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_specs() {
        let LayoutRequest::Fixed(l) = parse_layout("bvh2").unwrap() else {
            panic!()
        };
        assert_eq!((l.name.as_str(), l.params.len()), ("bvh2", 0));
        let LayoutRequest::Fixed(q) =
            parse_layout(" qbvh_chunks: frame=parent , chunk_bytes=128").unwrap()
        else {
            panic!()
        };
        assert_eq!(q.params["frame"], "parent");
        assert_eq!(q.params["chunk_bytes"], "128");
        // Defaults filled in: explicit defaults and omitted ones give the same canonical params.
        let LayoutRequest::Fixed(d) = parse_layout("qbvh_chunks").unwrap() else {
            panic!()
        };
        let all = format!("qbvh_chunks:{}", d.params_string());
        assert_eq!(parse_layout(&all).unwrap(), LayoutRequest::Fixed(d));
        assert_eq!(
            parse_layout("auto").unwrap(),
            LayoutRequest::Auto(AutoSpec {
                max_slowdown: AUTO_MAX_SLOWDOWN,
                rays: AUTO_RAYS,
                budget: AUTO_BUDGET,
            })
        );
        assert_eq!(
            parse_layout("auto:max_slowdown=1.5,rays=500,budget=40").unwrap(),
            LayoutRequest::Auto(AutoSpec {
                max_slowdown: 1.5,
                rays: 500,
                budget: 40.0,
            })
        );
        for (bad, needle) in [
            ("zip", "unknown layout"),
            ("qbvh_chunks:chunk_bytes", "KEY=VALUE"),
            ("qbvh_chunks:chunk_bytes=64,chunk_bytes=128", "twice"),
            ("qbvh_chunks:nope=1", "nope"),
            // Old names (issue 17) name the new one, with or without parameters.
            (
                "qbvh",
                "layout `qbvh` was renamed to `qbvh_chunks` (Kilian 2021 5.2)",
            ),
            ("qbvh:bits=6", "renamed to `qbvh_chunks`"),
            (
                "octree1:fill=dense",
                "layout `octree1` was renamed to `octree_1bit` (Kilian 2021 4.2)",
            ),
            ("bvh2:bits=4", "bits"),
            ("auto:max_slowdown=0", "max_slowdown"),
            ("auto:max_slowdown=nan", "max_slowdown"),
            ("auto:rays=5", "rays"),
            ("auto:budget=0", "`budget` of layout `auto`: expected a finite number > 0"),
            ("auto:budget=inf", "budget"),
            ("auto:chunk_bytes=64", "chunk_bytes"),
        ] {
            let e = parse_layout(bad).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
            assert!(e.message().contains(needle), "{bad}: {e}");
        }
        for c in auto_candidates() {
            assert!(
                matches!(parse_layout(&c), Ok(LayoutRequest::Fixed(_))),
                "{c}"
            );
        }
    }
}

impl Artifact for LayoutArtifact {
    type Sum = LayoutSummary;
    fn summary(&self) -> LayoutSummary {
    self.summary.clone()
    }
}
