//! The optimize stage: an optimizer of the registry (ibo, Kensler rotations) on the built BVH,
//! before the compaction (Bittner 2013 3.6). Keeps the pass-by-pass trace beside the BVH.
use super::build::{repeat_bvh, Build, BvhArtifact};
use super::chain::{cost_params, method_params, Plan};
use super::load::Load;
use crate::error::{Error, Result};
use crate::run::{Files, Node, Runner, Stage, Timing};
use serde::{Deserialize, Serialize};

/// 2: f64 areas in the insertion search and the measures (issue 15).
/// 3: the summary keeps the peak heap (`BvhSummary::peak_heap_bytes`).
/// A change of one optimizer bumps that optimizer's own version (`OptimizerInfo::version`).
/// 4: timed runs of calls shorter than 10 ms are batched (`crate::batch`; a time-capped optimizer
///    keeps one call per run): every time is re-measured.
pub const OPTIMIZE_VERSION: u32 = 4;

/// What the optimize stage keeps beside its BVH (`optimize/<key>.opt`): the pass-by-pass trace the
/// report draws convergence curves from, and why the optimizer stopped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OptimizeInfo {
    /// Trace of the first timed run (later runs repeat the same tree; only their times differ).
    pub trace: Vec<bvhlab_opt::PassRecord>,
    /// `converged`, `max_passes` or `max_seconds`.
    pub stop: String,
    /// Pass whose tree was returned (the best one with `keep_best`).
    pub returned_pass: u32,
}

pub(crate) struct Optimize;

impl Stage for Optimize {
    const NAME: &'static str = "optimize";
    const TIMING: Timing = Timing::Build;
    type Full = BvhArtifact;

    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        let Some(o) = &plan.optimizer else {
            return Ok(None);
        };
        let version = rt.registry.optimizer(&o.optimizer)?.version;
        let mut p = method_params(o.params.clone(), "optimizer", &o.optimizer, plan.spec.repeat, version);
        p.extend(cost_params(o.cost));
        let inputs = vec![("build", plan.need("build")?.key)];
        Ok(Some(Node::new(Self::NAME, rt.versions.optimize, p, inputs)))
    }


    fn compute(rt: &mut Runner, plan: &Plan, node: &Node) -> Result<(BvhArtifact, Files)> {
        let scene = rt.full::<Load>(plan)?;
        let (boxes, _) = scene.boxes_and_centers();
        let built = rt.full::<Build>(plan)?;
        let o = plan
            .optimizer
            .clone()
            .ok_or_else(|| Error::internal("chain has no optimizer"))?;
        let run = rt.registry.optimizer(&o.optimizer)?.run;
        let mut info: Option<OptimizeInfo> = None;
        let art = repeat_bvh(&rt.ops, plan, node, &boxes, rt.registry.get(&plan.resolved.builder)?.refs, o.time_capped(), || {
            let out = run(&built.bvh, &o);
            info.get_or_insert(OptimizeInfo {
                trace: out.trace,
                stop: out.stop.as_str().to_string(),
                returned_pass: out.returned_pass,
            });
            Ok((out.bvh, None))
        })?;
        let info = info.ok_or_else(|| Error::internal("repeat = 0"))?;
        let mut files = Files::new();
        files.insert(
            "opt".into(),
            rt.store.put(Self::NAME, &node.key, "opt", &info)?,
        );
        rt.remember_part(node, "opt", info);
        Ok((art, files))
    }

    fn ensure(rt: &mut Runner, plan: &Plan) -> Result<()> {
        rt.summary::<Self>(plan)?;
        optimize_info(rt, plan).map(drop)
    }
}

/// The optimize stage's trace and stop reason (read from `.opt`; recomputes the stage when that
/// file is missing or corrupt).
pub(crate) fn optimize_info(rt: &mut Runner, plan: &Plan) -> Result<Option<OptimizeInfo>> {
    let Some(node) = plan.node(Optimize::NAME).cloned() else {
        return Ok(None);
    };
    if let Some(i) = rt.part::<OptimizeInfo>(&node, "opt") {
        return Ok(Some(i));
    }
    // Artifact present but its trace unreadable: drop the in-memory copy and recompute the stage.
    rt.drop_full(&node);
    let path = rt.store.path(Optimize::NAME, &node.key, "bin");
    if path.exists() {
        rt.store.quarantine(&path);
    }
    rt.full::<Optimize>(plan)?;
    rt.part::<OptimizeInfo>(&node, "opt")
        .map(Some)
        .ok_or_else(|| Error::internal("optimize stage produced no trace"))
}
