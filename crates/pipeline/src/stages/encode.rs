//! The encode stage: Morton / EMC codes of the primitives and their sorted order (thesis 2.3.4,
//! 3.7.1; Riemersma 2024), for the builders that take codes (lbvh, aac, ploc).
use super::chain::{method_params, Plan};
use super::load::Load;
use crate::batch::{Batch, SameAsFirst};
use crate::error::{Error, Result};
use crate::run::{Artifact, Files, Node, Runner, Stage, Timing};
use bvhlab_geom::stats::median;
use bvhlab_morton::Encoding;
use serde::{Deserialize, Serialize};

/// 3: EMC size of boxes spanning more than the f32 range (issue 15).
/// 4: timed runs of calls shorter than 10 ms are batched (`crate::batch`): every time is re-measured.
pub const ENCODE_VERSION: u32 = 4;

/// Summary of the encode stage (`encode/<key>.sum`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodeSummary {
    pub code_bits: u32,
    pub duplicate_fraction: f64,
    /// Bit layout, most significant bit first (`Encoding::layout`).
    pub layout: String,
    /// Seconds of each of the `repeat` runs of `encode()` (codes + sort).
    pub seconds: Vec<f64>,
    pub median_seconds: f64,
}

/// Full artifact of the encode stage (`encode/<key>.bin`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EncodeArtifact {
    pub encoding: Encoding,
    pub summary: EncodeSummary,
}

pub(crate) struct Encode;

impl Stage for Encode {
    const NAME: &'static str = "encode";
    const TIMING: Timing = Timing::Build;
    type Full = EncodeArtifact;

    /// Encoder parameters are canonical with `bits=auto` resolved for the builder, so chains
    /// whose codes are identical (e.g. emc64-var for aac and ploc) share the encode node.
    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        let Some(e) = &plan.encoder else {
            return Ok(None);
        };
        let version = rt.registry.encoder(&e.encoder)?.version;
        let p = method_params(e.params.clone(), "encoder", &e.encoder, plan.spec.repeat, version);
        let inputs = vec![("load", plan.need("load")?.key)];
        Ok(Some(Node::new(Self::NAME, rt.versions.encode, p, inputs)))
    }


    fn compute(rt: &mut Runner, plan: &Plan, _: &Node) -> Result<(EncodeArtifact, Files)> {
        let enc = plan
            .encoder
            .clone()
            .ok_or_else(|| Error::internal("chain has no encoder"))?;
        let scene = rt.full::<Load>(plan)?;
        let (boxes, centers) = scene.boxes_and_centers();
        let mut seconds = Vec::new();
        let mut batch = Batch::new();
        // Every call's codes against the first call's (untimed; a short encode is called many times).
        let mut same = SameAsFirst::default();
        let mut check = |e: &Encoding| {
            same.check(e.clone(), |call| {
                Error::internal(format!(
                    "encoder `{}` is not deterministic: call {call} produced different codes than call 1 on {}",
                    enc.encoder, plan.spec.scene
                ))
            })
        };
        for _ in 0..plan.spec.repeat {
            // Only encode() is timed (codes + sort); boxes and centres are shared preparation.
            let (_, s) = batch.run_checked(
                || Ok(((rt.ops.encode)(&boxes, &centers, &enc.config, enc.cell_frame), None)),
                &mut check,
            )?;
            seconds.push(s);
        }
        let encoding = same.into_first().ok_or_else(|| Error::internal("repeat = 0"))?;
        if encoding.order.len() != boxes.len() || encoding.codes.len() != boxes.len() {
            return Err(Error::internal(format!(
                "encoder `{}` returned {} codes for {} primitives",
                enc.encoder,
                encoding.codes.len(),
                boxes.len()
            )));
        }
        let summary = EncodeSummary {
            code_bits: encoding.code_bits,
            duplicate_fraction: encoding.duplicate_fraction(),
            layout: encoding.layout.clone(),
            median_seconds: median(&seconds),
            seconds,
        };
        Ok((EncodeArtifact { encoding, summary }, Files::new()))
    }
}

impl Artifact for EncodeArtifact {
    type Sum = EncodeSummary;
    fn summary(&self) -> EncodeSummary {
    self.summary.clone()
    }
}
