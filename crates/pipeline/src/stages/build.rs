//! The build stage: a builder of the registry over the scene's boxes and centres (and, for the
//! bottom-up builders, the encode stage's sorted codes). Also what the BVH-producing stages share
//! (build, optimize, compact): their artifact, the timed repeats with the determinism check, and
//! the final BVH of a chain.
use super::chain::{method_params, Plan};
use super::compact::Compact;
use super::encode::Encode;
use super::load::Load;
use super::optimize::Optimize;
use super::Ops;
use crate::batch::{Batch, SameAsFirst};
use crate::error::{Error, Result};
use crate::run::{Artifact, Files, Node, Runner, Stage, Timing};
use bvhlab_bvh::{Aabb, Bvh, Metrics, Refs};
use bvhlab_geom::stats::median;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// 2: bottom-up builders (lbvh, aac, ploc) and the reworked (parallel) binned SAH.
/// 3: scale-free costs (issue 15): SAH areas and costs in f64, binned SAH bins in f64 and its
///    "centroids too close" threshold relative to the node box, PLOC/AAC distances of boxes
///    prescaled by a power of two; the SAH leaf test splits on equal costs (as the compaction
///    keeps such subtrees).
/// A change of one builder bumps that builder's own version (`BuilderInfo::version`) instead.
/// 4: the summary keeps the build's peak heap (`BvhSummary::peak_heap_bytes`; issue 19.4).
/// 5: timed runs of calls shorter than 10 ms are batched (`crate::batch`): every time is re-measured.
pub const BUILD_VERSION: u32 = 5;

/// Summary of a BVH-producing stage (`build`, `compact`): metrics, validity, hash and timings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BvhSummary {
    pub metrics: Metrics,
    pub valid: bool,
    pub invalid_reason: Option<String>,
    /// blake3 of `Bvh::canonical_bytes`.
    pub bvh_hash: String,
    /// Seconds of each of the `repeat` runs.
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
    /// Peak heap growth of the first run in bytes (the method's working memory and its output;
    /// process-wide counting allocator, `memtrack`). None for peer libraries, which allocate
    /// outside Rust's allocator.
    pub peak_heap_bytes: Option<u64>,
}

/// Full artifact of a BVH-producing stage (`<key>.bin`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BvhArtifact {
    pub bvh: Bvh,
    pub summary: BvhSummary,
}

/// The BVH-producing stages, in chain order.
pub(crate) const BVH_STAGES: [&str; 3] = ["build", "optimize", "compact"];

/// The chain's final BVH (compact, else optimize, else build): what layout, measure and focus read.
pub(crate) fn final_bvh(rt: &mut Runner, plan: &Plan) -> Result<Arc<BvhArtifact>> {
    bvh_of(rt, plan, plan.final_bvh().stage)
}

/// The BVH artifact of the chain's `stage` node (one of `BVH_STAGES`).
pub(crate) fn bvh_of(rt: &mut Runner, plan: &Plan, stage: &str) -> Result<Arc<BvhArtifact>> {
    match stage {
        "build" => rt.full::<Build>(plan),
        "optimize" => rt.full::<Optimize>(plan),
        "compact" => rt.full::<Compact>(plan),
        s => Err(Error::internal(format!("stage `{s}` has no BVH"))),
    }
}

/// Runs a BVH-producing method `repeat` times (only `run` is timed: boxes and centres are shared
/// input preparation; a peer library's run returns the time of its own call, which replaces it), requires every run to give the same tree (except a time-capped optimizer's,
/// which stops wherever the clock says: the first run's tree is kept, and the row says
/// `optimize_stop = max_seconds`), and summarises the first: metrics, validation, hash, times.
pub(crate) fn repeat_bvh(
    ops: &Ops,
    plan: &Plan,
    node: &Node,
    boxes: &[Aabb],
    refs: Refs,
    time_capped: bool,
    mut run: impl FnMut() -> Result<(Bvh, Option<f64>)>,
) -> Result<BvhArtifact> {
    let cost = plan.resolved.cost;
    let mut seconds = Vec::with_capacity(plan.spec.repeat as usize);
    let mut first: Option<(Bvh, blake3::Hash)> = None;
    let mut peak = None;
    let mut batch = if time_capped { Batch::single() } else { Batch::new() };
    // Every call's tree against the first call's (untimed; a short build is called many times),
    // by a streamed digest: the check runs inside the peak-heap window.
    let mut same = SameAsFirst::default();
    let mut check = |bvh: &Bvh| -> Result<()> {
        if time_capped {
            return Ok(());
        }
        let h = crate::codec::digest(bvh).map_err(Error::internal)?;
        same.check(h, |call| {
            Error::internal(format!(
                "{} `{}` is not deterministic: call {call} produced a different BVH than call 1 on {}",
                node.stage,
                node.params.get("builder").or(node.params.get("method")).cloned().unwrap_or_default(),
                plan.spec.scene
            ))
        })
    };
    for i in 0..plan.spec.repeat {
        // Peak heap of the first run only (later runs reuse the memory the first one freed).
        let mark = (i == 0).then(crate::memtrack::reset_peak);
        let (bvh, s) = batch.run_checked(&mut run, &mut check)?;
        seconds.push(s);
        if let Some(m) = mark {
            peak = Some(crate::memtrack::peak_since(m));
        }
        if first.is_none() {
            let h = blake3::hash(&bvh.canonical_bytes());
            first = Some((bvh, h));
        }
    }
    let (bvh, hash) = first.ok_or_else(|| Error::internal("repeat = 0"))?;
    let metrics = (ops.metrics)(&bvh, cost);
    let validation = (ops.validate)(&bvh, boxes, refs);
    let summary = BvhSummary {
        metrics,
        valid: validation.is_ok(),
        invalid_reason: validation.err(),
        bvh_hash: hash.to_hex().to_string(),
        median_seconds: median(&seconds),
        seconds,
        peak_heap_bytes: peak,
    };
    Ok(BvhArtifact { bvh, summary })
}

pub(crate) struct Build;

impl Stage for Build {
    const NAME: &'static str = "build";
    const TIMING: Timing = Timing::Build;
    type Full = BvhArtifact;

    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        let (builder, repeat) = (&plan.resolved.builder, plan.spec.repeat);
        let p = method_params(plan.resolved.key_params(), "builder", builder, repeat, rt.registry.get(builder)?.version);
        let mut inputs = vec![("load", plan.need("load")?.key)];
        if let Some(e) = plan.node("encode") {
            inputs.push(("encode", e.key));
        }
        Ok(Some(Node::new(Self::NAME, rt.versions.build, p, inputs)))
    }


    fn compute(rt: &mut Runner, plan: &Plan, node: &Node) -> Result<(BvhArtifact, Files)> {
        let scene = rt.full::<Load>(plan)?;
        let info = rt.registry.get(&plan.resolved.builder)?.clone();
        // Builders over codes never read centres (the encode stage had its own): 12 bytes per
        // triangle less at the build's peak.
        let (boxes, centers) = if info.codes.is_some() {
            (scene.boxes(), Vec::new())
        } else {
            scene.boxes_and_centers()
        };
        let encoding = match plan.node("encode") {
            Some(_) => Some(rt.full::<Encode>(plan)?),
            None => None,
        };
        let codes = encoding.as_ref().map(|e| bvhlab_builders::SortedCodes {
            order: &e.encoding.order,
            codes: &e.encoding.codes,
            code_bits: e.encoding.code_bits,
        });
        if info.codes.is_some() != codes.is_some() {
            return Err(Error::internal(format!(
                "builder `{}`: codes expected iff it uses codes",
                info.name
            )));
        }
        let (ops, cost) = (rt.ops, plan.resolved.cost);
        // Bottom-up builders include their SAH compaction (thesis: part of AAC / PLOC).
        let mut art = repeat_bvh(&ops, plan, node, &boxes, info.refs, false, || {
            if let Some(peer) = info.peer {
                // The library's own call is timed (not the import); its failure is this peer's.
                return peer
                    .build(&scene.triangles, &boxes, &plan.resolved.params, cost.c_t, cost.c_i)
                    .map(|b| (b.bvh, Some(b.seconds)))
                    .map_err(|e| Error::input(format!("{} on {}: {e}", info.name, plan.spec.scene)));
            }
            let bvh = match info.triangles {
                Some(run) => run(&scene.triangles, &plan.resolved),
                None => (info.run)(&boxes, &centers, codes.as_ref(), &plan.resolved),
            };
            Ok((
                if info.collapse {
                    (ops.collapse)(&bvh, cost)
                } else {
                    bvh
                },
                None,
            ))
        })?;
        if info.peer.is_some() {
            art.summary.peak_heap_bytes = None;
        }
        Ok((art, Files::new()))
    }
}

impl Artifact for BvhArtifact {
    type Sum = BvhSummary;
    fn summary(&self) -> BvhSummary {
    self.summary.clone()
    }
}
