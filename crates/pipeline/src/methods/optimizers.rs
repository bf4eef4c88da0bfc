//! Optimizers (the optimize stage, after the build and before the compaction): one registration
//! line each (the [`Method`](super::Method) comes from `crates/opt/src/`).
use super::{MethodInfo, MethodKind};
use crate::registry::ResolvedOptimizer;
use bvhlab_bvh::Bvh;
use bvhlab_opt::{ibo, kensler};

/// Runs an optimizer on a built BVH with its resolved parameters.
pub type OptimizeFn = fn(&Bvh, &ResolvedOptimizer) -> bvhlab_opt::Optimized;

/// What the pipeline needs to run an optimizer.
#[derive(Clone)]
pub struct Optimizer {
    pub run: OptimizeFn,
}

impl MethodKind for Optimizer {
    const WHAT: &'static str = "optimizer";
}

pub type OptimizerInfo = MethodInfo<Optimizer>;

/// The standard optimizers: one line each (the order of `bvhlab methods`).
#[rustfmt::skip]
pub fn standard() -> Vec<OptimizerInfo> {
    vec![
        optimizer(&ibo::METHOD, |bvh, r| ibo::optimize(bvh, &r.ibo_config())),
        optimizer(&kensler::HILL_CLIMBING, |bvh, r| kensler::optimize(bvh, &r.kensler_config(false))),
        optimizer(&kensler::ANNEALING, |bvh, r| kensler::optimize(bvh, &r.kensler_config(true))),
    ]
}

fn optimizer(m: &super::Method, run: OptimizeFn) -> OptimizerInfo {
    MethodInfo::new(m, Optimizer { run })
}

#[cfg(test)]
mod tests {
    use crate::registry::tests::raw;
    use crate::registry::Registry;
    use bvhlab_bvh::CostParams;

    #[test]
    fn ibo_schedule_and_spatial_median_frame() {
        let r = Registry::standard();
        let cost = CostParams::default();
        let bittner = r.resolve_optimizer("ibo", &raw(&[]), cost).unwrap();
        assert_eq!(bittner.params["schedule"], "bittner");
        assert_eq!(bittner.params["keep_best"], "true");
        assert_eq!(
            bittner.ibo_config().schedule,
            bvhlab_opt::ibo::Schedule::Bittner
        );
        assert_eq!(r.optimizer_label(&bittner), "ibo comb");
        // The thesis schedule returns the last tree unless keep_best is given.
        let thesis = r
            .resolve_optimizer("ibo", &raw(&[("schedule", "thesis")]), cost)
            .unwrap();
        assert_eq!(thesis.params["keep_best"], "false");
        // ... and counts k over all nodes (thesis 3.4.3) unless ibo_nodes is given.
        assert_eq!(thesis.params["ibo_nodes"], "all");
        assert!(thesis.ibo_config().frac_of_all);
        assert!(!bittner.ibo_config().frac_of_all);
        let ibo = |kv: &[(&str, &str)]| r.resolve_optimizer("ibo", &raw(kv), cost).unwrap();
        let inner = ibo(&[("schedule", "thesis"), ("ibo_nodes", "inner")]);
        assert!(!inner.ibo_config().frac_of_all);
        let cfg = thesis.ibo_config();
        assert_eq!(
            (cfg.schedule, cfg.keep_best),
            (bvhlab_opt::ibo::Schedule::Thesis, false)
        );
        assert_eq!(r.optimizer_label(&thesis), "ibo comb schedule=thesis");
        let best = ibo(&[("schedule", "thesis"), ("keep_best", "true")]);
        assert!(best.ibo_config().keep_best);
        assert_eq!(
            r.optimizer_label(&best),
            "ibo comb schedule=thesis keep_best=true"
        );
        assert!(r
            .resolve_optimizer("ibo", &raw(&[("schedule", "frantal")]), cost)
            .is_err());
        // The spatial median's frame: centroids by default, node on request, in the key.
        let c = r.resolve("spatial-median", &raw(&[]), cost).unwrap();
        assert_eq!(c.key_params()["frame"], "centroids");
        let n = r
            .resolve("spatial-median", &raw(&[("frame", "node")]), cost)
            .unwrap();
        assert_eq!(n.key_params()["frame"], "node");
        assert_eq!(r.label(&n), "spatial-median frame=node");
        assert!(r
            .resolve("sweep-sah", &raw(&[("frame", "node")]), cost)
            .is_err());
    }
}
