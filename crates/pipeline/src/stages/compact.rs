//! The compact stage: the SAH compaction (`bvhlab_bvh::collapse`, thesis 3.4.4, Bittner 3.6) of
//! the built or optimized BVH (after the optimizer, as Bittner 2013 3.6 orders them).
use super::build::{bvh_of, repeat_bvh, BvhArtifact};
use super::chain::{cost_params, param, Plan};
use super::load::Load;
use crate::error::{Error, Result};
use crate::run::{Files, Node, Runner, Stage, Timing};
use std::collections::BTreeMap;

/// 2: areas of boxes spanning more than the f32 range (issue 15).
/// 3: the summary keeps the peak heap (`BvhSummary::peak_heap_bytes`).
/// 4: timed runs of calls shorter than 10 ms are batched (`crate::batch`): every time is re-measured.
pub const COMPACT_VERSION: u32 = 4;

pub const COMPACT_METHODS: [&str; 2] = ["none", "collapse"];

pub fn check_compact(name: &str) -> Result<()> {
    if COMPACT_METHODS.contains(&name) {
        Ok(())
    } else {
        Err(Error::input(format!(
            "unknown compaction `{name}`; valid: {}",
            COMPACT_METHODS.join(", ")
        )))
    }
}

pub(crate) struct Compact;

impl Stage for Compact {
    const NAME: &'static str = "compact";
    const TIMING: Timing = Timing::Build;
    type Full = BvhArtifact;

    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        if plan.spec.compact == "none" {
            return Ok(None);
        }
        let mut p: BTreeMap<String, String> = cost_params(plan.resolved.cost).into();
        p.extend([
            param("method", &plan.spec.compact),
            param("repeat", plan.spec.repeat),
        ]);
        let input = plan.final_bvh();
        let inputs = vec![(input.stage, input.key)];
        Ok(Some(Node::new(Self::NAME, rt.versions.compact, p, inputs)))
    }


    fn compute(rt: &mut Runner, plan: &Plan, node: &Node) -> Result<(BvhArtifact, Files)> {
        let scene = rt.full::<Load>(plan)?;
        let (boxes, _) = scene.boxes_and_centers();
        // Its one input: the optimized BVH, else the built one.
        let input = bvh_of(rt, plan, node.inputs[0].0)?;
        let (ops, cost) = (rt.ops, plan.resolved.cost);
        let art = repeat_bvh(&ops, plan, node, &boxes, rt.registry.get(&plan.resolved.builder)?.refs, false, || {
            Ok(((ops.collapse)(&input.bvh, cost), None))
        })?;
        Ok((art, Files::new()))
    }
}
