//! The default pass budgets (issue 15): an optimizer whose own termination never fires still stops,
//! deterministically, and says so (`Stop::PassBudget`); `budget = off` removes the bound.
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{validate, Bvh};
use bvhlab_geom::load_scene;
use bvhlab_opt::{ibo, kensler, Stop};

fn sah_tree(spec: &str) -> (Bvh, Vec<bvhlab_bvh::Aabb>) {
    let s = load_scene(spec).unwrap();
    let (b, c) = s.boxes_and_centers();
    let cfg = TopDownConfig { leaf: 1, ..Default::default() };
    (bvhlab_builders::spatial_median::build(&b, &c, &cfg), b)
}

#[test]
fn ibo_stops_at_its_pass_budget() {
    let (bvh, boxes) = sah_tree("gen:sphere:n=300");
    let inner = bvh.nodes.iter().filter(|n| !n.is_leaf()).count();
    // p_T out of reach: without a budget only max_passes could end this run.
    let cfg = ibo::IboConfig { pt: 1 << 20, pr: 5, ..Default::default() };
    let k = ((cfg.frac as f64 * inner as f64).round() as usize).clamp(1, inner - 1);
    let budget = ibo::pass_budget(inner, k);
    assert!(budget >= 100 && budget as u64 >= ibo::BUDGET_UPDATES_PER_NODE * inner as u64 / k as u64);
    let r = ibo::optimize(&bvh, &cfg);
    assert_eq!(r.stop, Stop::PassBudget);
    assert_eq!(r.stop.as_str(), "pass_budget");
    assert_eq!(r.trace.last().unwrap().pass, budget);
    assert!(validate(&r.bvh, &boxes).is_ok());
    // Deterministic: the same budget, the same tree.
    assert_eq!(ibo::optimize(&bvh, &cfg).bvh.canonical_bytes(), r.bvh.canonical_bytes());
    // budget off: the run goes past it (stopped here by max_passes instead).
    let off = ibo::IboConfig { budget: false, max_passes: budget + 7, ..cfg };
    let r = ibo::optimize(&bvh, &off);
    assert_eq!(r.stop, Stop::MaxPasses);
    assert_eq!(r.trace.last().unwrap().pass, budget + 7);
}

#[test]
fn annealing_stops_at_its_pass_budget() {
    let (bvh, boxes) = sah_tree("gen:sphere:n=300");
    // Cooling so slow that the schedule would run for ~10^5 passes.
    let cfg = kensler::KenslerConfig { anneal: true, t0: 1e-5, cooling: 0.9999, ..Default::default() };
    let budget = kensler::pass_budget(bvh.nodes.len());
    let r = kensler::optimize(&bvh, &cfg);
    assert_eq!(r.stop, Stop::PassBudget);
    assert_eq!(r.trace.last().unwrap().pass, budget);
    assert!(validate(&r.bvh, &boxes).is_ok());
    let off = kensler::KenslerConfig { budget: false, max_passes: budget + 3, ..cfg };
    assert_eq!(kensler::optimize(&bvh, &off).stop, Stop::MaxPasses);
}
