//! Structural validation: the invariants every builder, optimizer and layout must keep.
use crate::Bvh;
use bvhlab_geom::Aabb;
use serde::{Deserialize, Serialize};

/// How often a BVH may reference a triangle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Refs {
    /// Exactly once (every builder but the SBVH): [`validate`].
    #[default]
    Unique,
    /// At least once, in several leaves whose boxes each hold a clipped part of it (spatial splits,
    /// Stich et al. 2009): [`validate_split`].
    Split,
}

/// [`validate`] or [`validate_split`] as `refs` says.
pub fn validate_refs(bvh: &Bvh, prim_boxes: &[Aabb], refs: Refs) -> Result<(), String> {
    match refs {
        Refs::Unique => validate(bvh, prim_boxes),
        Refs::Split => validate_split(bvh, prim_boxes),
    }
}

/// Validation of a BVH whose leaves may hold clipped references (SBVH): every node reachable once,
/// children inside parents, every index slot in one leaf, and for the triangles: each referenced at
/// least once and at most once per leaf, each leaf box overlapping the boxes of its triangles, and
/// the leaf boxes of a triangle's references together covering its whole box (what spatial splits
/// must keep so that rays still find it; the oracle checks the triangles themselves).
pub fn validate_split(bvh: &Bvh, prim_boxes: &[Aabb]) -> Result<(), String> {
    if bvh.prim_indices.len() < prim_boxes.len() && !bvh.nodes.is_empty() {
        return Err(references_error(bvh, prim_boxes));
    }
    // Union of (leaf box ∩ triangle box) over the triangle's references; the leaf that saw it last.
    let mut covered = vec![Aabb::EMPTY; prim_boxes.len()];
    let mut last_leaf = vec![usize::MAX; prim_boxes.len()];
    walk(bvh, prim_boxes, |i, leaf, p| {
        if std::mem::replace(&mut last_leaf[p], i) == i {
            return Err(format!("leaf {i} references primitive {p} twice"));
        }
        let pb = &prim_boxes[p];
        let part = Aabb { min: leaf.min.max(pb.min), max: leaf.max.min(pb.max) };
        if part.is_empty() {
            return Err(format!("leaf {i} box does not overlap primitive {p}"));
        }
        covered[p].grow(&part);
        Ok(())
    })?;
    if let Some(p) = last_leaf.iter().position(|&l| l == usize::MAX) {
        return Err(format!("primitive {p} not referenced"));
    }
    if let Some(p) = (0..prim_boxes.len()).find(|&p| !covered[p].contains(&prim_boxes[p])) {
        return Err(format!("the leaves referencing primitive {p} do not cover its box"));
    }
    Ok(())
}

/// Checks that every one of `prim_boxes.len()` primitives is referenced exactly once, every node is
/// reachable from the root exactly once (acyclic, no sharing, no orphans), children's boxes lie
/// inside their parent's, and every leaf's box contains its primitives' boxes.
/// Returns a description of the first violation.
pub fn validate(bvh: &Bvh, prim_boxes: &[Aabb]) -> Result<(), String> {
    if bvh.prim_indices.len() != prim_boxes.len() && !bvh.nodes.is_empty() {
        return Err(references_error(bvh, prim_boxes));
    }
    let mut seen = vec![false; prim_boxes.len()];
    walk(bvh, prim_boxes, |i, leaf, p| {
        if std::mem::replace(&mut seen[p], true) {
            return Err(format!("primitive {p} referenced twice"));
        }
        if !leaf.contains(&prim_boxes[p]) {
            return Err(format!("leaf {i} box does not contain primitive {p}"));
        }
        Ok(())
    })?;
    if let Some(p) = seen.iter().position(|s| !s) {
        return Err(format!("primitive {p} not referenced"));
    }
    Ok(())
}

fn references_error(bvh: &Bvh, prim_boxes: &[Aabb]) -> String {
    format!(
        "index array holds {} references for {} primitives",
        bvh.prim_indices.len(),
        prim_boxes.len()
    )
}

/// The structure both validations share: every node reached exactly once from the root, inner
/// children in range and inside their parent, leaf ranges inside the index array, every index slot
/// in one leaf, every reference in range; `reference(leaf, leaf box, primitive)` checks the rest.
fn walk(
    bvh: &Bvh,
    prim_boxes: &[Aabb],
    mut reference: impl FnMut(usize, &Aabb, usize) -> Result<(), String>,
) -> Result<(), String> {
    let n_nodes = bvh.nodes.len();
    if n_nodes == 0 {
        return if prim_boxes.is_empty() { Ok(()) } else { Err("no nodes".into()) };
    }
    let mut visited = vec![false; n_nodes];
    let mut slot_used = vec![false; bvh.prim_indices.len()];
    let mut stack = vec![0usize];
    let mut reached = 0usize;
    while let Some(i) = stack.pop() {
        if std::mem::replace(&mut visited[i], true) {
            return Err(format!("node {i} reached twice (cycle or shared child)"));
        }
        reached += 1;
        let n = &bvh.nodes[i];
        if n.is_leaf() {
            let (a, b) = (n.first as usize, n.first as usize + n.count as usize);
            if b > bvh.prim_indices.len() {
                return Err(format!("leaf {i} range {a}..{b} exceeds index array"));
            }
            for s in a..b {
                if std::mem::replace(&mut slot_used[s], true) {
                    return Err(format!("index slot {s} used by two leaves"));
                }
                let p = bvh.prim_indices[s] as usize;
                if p >= prim_boxes.len() {
                    return Err(format!("leaf {i} references primitive {p} out of range"));
                }
                reference(i, &n.bounds, p)?;
            }
        } else {
            let l = n.first as usize;
            if l == 0 || l + 1 >= n_nodes {
                return Err(format!("inner node {i} has invalid children index {l}"));
            }
            for c in [l, l + 1] {
                if !n.bounds.contains(&bvh.nodes[c].bounds) {
                    return Err(format!("child {c} box is not inside parent {i}"));
                }
                stack.push(c);
            }
        }
    }
    if reached != n_nodes {
        return Err(format!("{} of {} nodes unreachable from the root", n_nodes - reached, n_nodes));
    }
    Ok(())
}
