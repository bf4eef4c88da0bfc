//! Metrics exactly as Frantal 2019 defines them (eq. 4 in 2.2.2, the list in 4.4).
use crate::Bvh;
use bvhlab_params::{Kind, ParamSpec};
use serde::{Deserialize, Serialize};

/// SAH constants: c_T traversal, c_I intersection (thesis 2.2.2; defaults 3 and 2 as in 4.4).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CostParams {
    pub c_t: f32,
    pub c_i: f32,
}

impl Default for CostParams {
    fn default() -> Self {
        Self { c_t: 3.0, c_i: 2.0 }
    }
}

/// `c_t` and `c_i` as parameters of every builder (defaults: [`CostParams::default`]).
pub const COST_PARAMS: [ParamSpec; 2] = [
    ParamSpec {
        name: "c_t",
        default: "3",
        kind: Kind::PositiveFloat,
        about: "SAH traversal cost c_T (thesis 2.2.2)",
        in_label: false,
    },
    ParamSpec {
        name: "c_i",
        default: "2",
        kind: Kind::PositiveFloat,
        about: "SAH intersection cost c_I (thesis 2.2.2)",
        in_label: false,
    },
];

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Eq. 4: (c_T * sum_inner SA + c_I * sum_leaves SA * t) / SA(root).
    pub sah_cost: f64,
    /// Sum of inner-node SA / SA(root) (thesis table 18).
    pub inner_sa_ratio: f64,
    /// Sum of leaf SA * triangle count / SA(root) (thesis table 19).
    pub leaf_sa_ratio: f64,
    /// Triangle references per leaf (thesis table 17).
    pub refs_per_leaf: f64,
    pub inner_nodes: u64,
    pub leaves: u64,
    /// Maximum depth; a single-leaf tree has depth 0.
    pub depth: u32,
    pub bytes: u64,
}

/// Walks the tree from the root (so unreachable nodes, if any, are not counted; `validate` rejects
/// those). Sums are taken in f64: with ~10^6 nodes f32 accumulation loses the first digits.
///
/// A root with zero surface area (a single flat triangle, all-coincident points) makes eq. 4
/// undefined; there every node is taken as equally likely to be hit (each SA ratio counts as 1),
/// the limit of an infinitesimally thick box.
pub fn metrics(bvh: &Bvh, cost: CostParams) -> Metrics {
    let mut m = Metrics { bytes: bvh.bytes(), ..Default::default() };
    if bvh.nodes.is_empty() {
        return m;
    }
    let root_sa = bvh.nodes[0].bounds.area_f64();
    let degenerate = !(root_sa > 0.0);
    let ratio = |sa: f64| if degenerate { 1.0 } else { sa / root_sa };
    let mut inner_sa = 0.0f64;
    let mut leaf_sa = 0.0f64;
    let mut refs = 0u64;
    let mut stack: Vec<(u32, u32)> = vec![(0, 0)];
    while let Some((i, d)) = stack.pop() {
        let n = &bvh.nodes[i as usize];
        m.depth = m.depth.max(d);
        if n.is_leaf() {
            m.leaves += 1;
            refs += n.count as u64;
            leaf_sa += ratio(n.bounds.area_f64()) * n.count as f64;
        } else {
            m.inner_nodes += 1;
            inner_sa += ratio(n.bounds.area_f64());
            // Guard against malformed input (validate reports it): never index out of bounds here.
            if (n.first as usize) + 1 < bvh.nodes.len() && stack.len() < bvh.nodes.len() {
                stack.push((n.first + 1, d + 1));
                stack.push((n.first, d + 1));
            }
        }
    }
    m.inner_sa_ratio = inner_sa;
    m.leaf_sa_ratio = leaf_sa;
    m.sah_cost = cost.c_t as f64 * inner_sa + cost.c_i as f64 * leaf_sa;
    m.refs_per_leaf = if m.leaves > 0 { refs as f64 / m.leaves as f64 } else { 0.0 };
    m
}
