//! The focus stage: the SAH cost of the smallest subtree of the final BVH holding the triangles of
//! a focus box (for scenes whose interesting part is dwarfed by an outlier or a ground plane).
use super::build::final_bvh;
use super::chain::{cost_params, Plan};
use super::load::Load;
use crate::error::{Error, Result};
use crate::run::{Artifact, Files, Node, Runner, Stage, Timing};
use bvhlab_bvh::Aabb;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

pub const FOCUS_VERSION: u32 = 1;

/// Result of the focus stage (`focus/<key>.sum`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FocusSummary {
    /// Triangles whose centroid lies in the focus box.
    pub triangles: u64,
    /// `bvhlab_bvh::focus::focus_cost`; None when no triangle is in focus.
    pub sah_cost: Option<f64>,
}

/// Parses `minx,miny,minz,maxx,maxy,maxz` (the CLI's `--focus`).
pub fn parse_focus(s: &str) -> Result<Aabb> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            Error::input(format!(
                "bad focus box `{s}`: expected six numbers minx,miny,minz,maxx,maxy,maxz"
            ))
        })?;
    if v.len() != 6 {
        return Err(Error::input(format!(
            "bad focus box `{s}`: expected six numbers minx,miny,minz,maxx,maxy,maxz, got {}",
            v.len()
        )));
    }
    focus_box([v[0], v[1], v[2]], [v[3], v[4], v[5]])
        .map_err(|why| Error::input(format!("bad focus box `{s}`: {why}")))
}

/// A focus box from its corners: finite, `min <= max` on every axis (a flat box is allowed).
pub fn focus_box(min: [f32; 3], max: [f32; 3]) -> Result<Aabb, String> {
    if min.iter().chain(max.iter()).any(|x| !x.is_finite()) {
        return Err("corners must be finite".into());
    }
    if (0..3).any(|i| min[i] > max[i]) {
        return Err(format!(
            "min {min:?} must not exceed max {max:?} on any axis"
        ));
    }
    Ok(Aabb::new(
        bvhlab_geom::Vec3::from(min),
        bvhlab_geom::Vec3::from(max),
    ))
}

/// Canonical text of a focus box for keys: `min=x,y,z;max=x,y,z` (shortest round-trip floats).
pub fn focus_canonical(b: &Aabb) -> String {
    let v = |v: bvhlab_geom::Vec3| format!("{},{},{}", v.x + 0.0, v.y + 0.0, v.z + 0.0);
    format!("min={};max={}", v(b.min), v(b.max))
}

pub(crate) struct Focus;

impl Stage for Focus {
    const NAME: &'static str = "focus";
    const TIMING: Timing = Timing::None;
    const FULL: bool = false;
    type Full = FocusSummary;

    fn declare(rt: &mut Runner, plan: &mut Plan) -> Result<Option<Node>> {
        let Some(b) = plan.spec.focus else {
            return Ok(None);
        };
        let mut p: BTreeMap<String, String> = cost_params(plan.resolved.cost).into();
        p.insert("box".into(), focus_canonical(&b));
        let fin = plan.final_bvh();
        let inputs = vec![("load", plan.need("load")?.key), (fin.stage, fin.key)];
        Ok(Some(Node::new(Self::NAME, rt.versions.focus, p, inputs)))
    }


    fn compute(rt: &mut Runner, plan: &Plan, _: &Node) -> Result<(FocusSummary, Files)> {
        let focus_box = plan
            .spec
            .focus
            .ok_or_else(|| Error::internal("chain has no focus box"))?;
        let scene = rt.full::<Load>(plan)?;
        let input = final_bvh(rt, plan)?;
        let (boxes, centers) = scene.boxes_and_centers();
        // A triangle is in focus when its centroid (box centre, as the builders see it) is inside.
        let in_focus: Vec<bool> = centers
            .iter()
            .map(|c| focus_box.min.cmple(*c).all() && c.cmple(focus_box.max).all())
            .collect();
        let result =
            bvhlab_bvh::focus::focus_cost(&input.bvh, &in_focus, &boxes, plan.resolved.cost);
        let f = FocusSummary {
            triangles: in_focus.iter().filter(|&&x| x).count() as u64,
            sah_cost: result.map(|(_, c)| c),
        };
        Ok((f, Files::new()))
    }
}

impl Artifact for FocusSummary {
    type Sum = FocusSummary;
    fn summary(&self) -> FocusSummary {
    self.clone()
    }
}
