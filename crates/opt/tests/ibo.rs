//! Insertion-based optimization (Bittner 2013): optimized trees are valid, find the same closest
//! hits as brute force, never cost more than the input with keep_best, are deterministic, fix bad
//! (spatial-median) trees, and survive degenerate inputs.
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{metrics, validate, Aabb, Bvh, CostParams, Node, Vec3};
use bvhlab_geom::{load_scene, Scene};
use bvhlab_opt::ibo::{measure_value, optimize, reinsert_children, IboConfig, Measure};
use bvhlab_opt::search::{find_best, SearchScratch};
use bvhlab_bvh::dyntree::DynTree;
use bvhlab_opt::Stop;
use bvhlab_trace::{brute_force, random_rays, trace};

fn cost(b: &Bvh) -> f64 {
    metrics(b, CostParams::default()).sah_cost
}

fn check_hits(ctx: &str, bvh: &Bvh, scene: &Scene) {
    let (boxes, centers) = scene.boxes_and_centers();
    validate(bvh, &boxes).unwrap_or_else(|e| panic!("{ctx}: invalid: {e}"));
    let b = scene.bounds();
    let radius = centers.iter().map(|c| (*c - b.center()).length()).fold(0.0, f32::max);
    let rays = random_rays(&b, radius, 1500, 3);
    let want = brute_force(&scene.triangles, &rays);
    let got = trace(bvh, &scene.triangles, &rays);
    for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
        let same =
            g.prim == w.prim || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-4 * w.t.abs().max(1e-30));
        assert!(same, "{ctx}: ray {i} got {g:?}, brute force {w:?}");
    }
}

fn build(scene: &Scene, median: bool, leaf: u32) -> Bvh {
    let (boxes, centers) = scene.boxes_and_centers();
    let cfg = TopDownConfig { leaf, cost: CostParams::default() };
    if median {
        bvhlab_builders::spatial_median::build(&boxes, &centers, &cfg)
    } else {
        bvhlab_builders::sweep_sah::build(&boxes, &centers, &cfg)
    }
}

#[test]
fn optimized_trees_are_valid_match_brute_force_and_never_cost_more() {
    for spec in ["gen:sphere:n=2000", "gen:terrain:n=2000", "gen:city:blocks=4", "gen:outlier:e=20,n=1500", "gen:degenerate:n=1500"] {
        let scene = load_scene(spec).unwrap();
        for (median, leaf) in [(false, 1), (true, 1), (false, 4)] {
            let input = build(&scene, median, leaf);
            for measure in [Measure::Comb, Measure::Sum, Measure::Min, Measure::Area, Measure::Random] {
                let cfg = IboConfig { measure, frac: 0.02, max_passes: 40, ..Default::default() };
                let o = optimize(&input, &cfg);
                let ctx = format!("{spec} median={median} leaf={leaf} {}", measure.as_str());
                check_hits(&ctx, &o.bvh, &scene);
                assert!(cost(&o.bvh) <= cost(&input) + 1e-9, "{ctx}: {} > {}", cost(&o.bvh), cost(&input));
                // Trace: pass 0 is the input; the returned pass's recorded cost is the tree's cost.
                assert_eq!(o.trace[0].pass, 0);
                assert!((o.trace[0].sah_cost - cost(&input)).abs() <= 1e-6 * cost(&input));
                let r = &o.trace[o.returned_pass as usize];
                assert!((r.sah_cost - cost(&o.bvh)).abs() <= 1e-6 * cost(&o.bvh), "{ctx}: trace {} vs {}", r.sah_cost, cost(&o.bvh));
                assert!(o.trace.iter().skip(1).all(|r| r.sah_cost >= cost(&o.bvh) - 1e-6 * cost(&o.bvh)), "{ctx}: not the best");
                // Leaves move as units: same leaf count and sizes.
                let leaves = |b: &Bvh| {
                    let mut v: Vec<u32> = b.nodes.iter().filter(|n| n.is_leaf()).map(|n| n.count).collect();
                    v.sort();
                    v
                };
                assert_eq!(leaves(&o.bvh), leaves(&input), "{ctx}");
            }
        }
    }
}

#[test]
fn keep_best_false_returns_last_and_is_valid() {
    let scene = load_scene("gen:hairball:n=400").unwrap();
    let input = build(&scene, false, 1);
    let o = optimize(&input, &IboConfig { keep_best: false, max_passes: 30, frac: 0.05, ..Default::default() });
    check_hits("keep_best=false", &o.bvh, &scene);
    assert_eq!(o.returned_pass as usize, o.trace.len() - 1);
    let last = o.trace.last().unwrap().sah_cost;
    assert!((last - cost(&o.bvh)).abs() <= 1e-6 * last);
}

#[test]
fn deterministic() {
    let scene = load_scene("gen:city:blocks=4").unwrap();
    let input = build(&scene, true, 1);
    for measure in [Measure::Comb, Measure::Random] {
        let cfg = IboConfig { measure, frac: 0.03, ..Default::default() };
        let (a, b) = (optimize(&input, &cfg), optimize(&input, &cfg));
        assert_eq!(a.bvh, b.bvh);
        assert_eq!(a.returned_pass, b.returned_pass);
        let costs = |o: &bvhlab_opt::Optimized| o.trace.iter().map(|r| (r.sah_cost, r.moved, r.phase.clone())).collect::<Vec<_>>();
        assert_eq!(costs(&a), costs(&b));
        // A different seed changes the random phase.
        let c = optimize(&input, &IboConfig { seed: 99, ..cfg });
        if measure == Measure::Random {
            assert_ne!(costs(&a), costs(&c));
        }
    }
}

#[test]
fn spatial_median_gets_much_better_and_terminates() {
    let scene = load_scene("gen:city:blocks=5").unwrap();
    let median = build(&scene, true, 1);
    let sweep = build(&scene, false, 1);
    let o = optimize(&median, &IboConfig::default());
    assert_eq!(o.stop, Stop::Converged);
    let (cm, cs, co) = (cost(&median), cost(&sweep), cost(&o.bvh));
    // Bittner 2013 table 3/5: optimization takes spatial-median trees close to sweep-SAH quality.
    assert!(co < 0.9 * cm, "median {cm} -> {co}");
    assert!(co < 1.1 * cs, "median+ibo {co} vs sweep {cs}");
    // The phase switches to random after p_R passes without improvement, before p_T stops it.
    assert!(o.trace.iter().any(|r| r.phase == "random"));
    let trailing = o.trace.iter().rev().take_while(|r| r.pass > o.returned_pass).count();
    assert_eq!(trailing, 10, "p_T = 10 passes without improvement");
}

#[test]
fn limits_stop_the_run() {
    let scene = load_scene("gen:sphere:n=3000").unwrap();
    let input = build(&scene, true, 1);
    let o = optimize(&input, &IboConfig { max_passes: 3, pt: 1000, ..Default::default() });
    assert_eq!((o.stop, o.trace.len()), (Stop::MaxPasses, 4));
    let o = optimize(&input, &IboConfig { max_seconds: 1e-9, pt: 1000, ..Default::default() });
    assert_eq!((o.stop, o.trace.len()), (Stop::MaxSeconds, 2));
}

/// Boxes along a diagonal, built into a left-deep chain (depth n - 1): the worst case for
/// anything recursive.
fn staircase(n: usize) -> (Bvh, Vec<Aabb>) {
    let boxes: Vec<Aabb> = (0..n).map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0))).collect();
    // Node layout: inner i at 2i (children 2i+1 leaf of prim i, 2i+2 next inner), last leaf at 2(n-1).
    let mut nodes = vec![Node::leaf(Aabb::EMPTY, 0, 1); 2 * n - 1];
    let mut acc = boxes[n - 1];
    nodes[2 * (n - 1)] = Node::leaf(boxes[n - 1], (n - 1) as u32, 1);
    for i in (0..n - 1).rev() {
        acc = acc.union(&boxes[i]);
        nodes[2 * i + 1] = Node::leaf(boxes[i], i as u32, 1);
        nodes[2 * i] = Node::inner(acc, (2 * i + 1) as u32);
    }
    (Bvh { nodes, prim_indices: (0..n as u32).collect() }, boxes)
}

#[test]
fn degenerate_inputs() {
    // A 10^4-deep chain.
    let (chain, boxes) = staircase(10_000);
    validate(&chain, &boxes).unwrap();
    let o = optimize(&chain, &IboConfig { max_passes: 5, ..Default::default() });
    validate(&o.bvh, &boxes).unwrap();
    assert!(cost(&o.bvh) < cost(&chain));
    // 1 and 2 primitives, and all-coincident boxes.
    for spec in ["gen:sphere:n=1", "gen:sphere:n=2", "gen:degenerate:n=50"] {
        let scene = load_scene(spec).unwrap();
        let (bx, _) = scene.boxes_and_centers();
        for median in [false, true] {
            let input = build(&scene, median, 1);
            let o = optimize(&input, &IboConfig::default());
            validate(&o.bvh, &bx).unwrap_or_else(|e| panic!("{spec}: {e}"));
        }
    }
    let p = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let n = 300;
    let (mut coincident, _) = staircase(n);
    for node in coincident.nodes.iter_mut() {
        node.bounds = p;
    }
    let o = optimize(&coincident, &IboConfig::default());
    validate(&o.bvh, &vec![p; n]).unwrap();
    let point = Aabb::new(Vec3::ONE, Vec3::ONE);
    for node in coincident.nodes.iter_mut() {
        node.bounds = point;
    }
    let o = optimize(&coincident, &IboConfig::default());
    validate(&o.bvh, &vec![point; n]).unwrap();
}

#[test]
fn reinsert_children_keeps_the_tree_consistent() {
    let scene = load_scene("gen:terrain:n=500").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    let mut t = DynTree::from_bvh(&build(&scene, true, 1));
    let mut scratch = SearchScratch::new();
    let before = t.sah_cost(CostParams::default());
    let inner = t.inner_nodes();
    // Root (no parent): nothing to do. Every other node, including the root's children.
    let root = t.root;
    assert!(!reinsert_children(&mut t, root, &mut scratch));
    let mut moved = 0;
    for &n in &inner {
        let c0 = t.sah_cost(CostParams::default());
        let m = reinsert_children(&mut t, n, &mut scratch);
        moved += m as u32;
        t.check().unwrap();
        if !m {
            // Not moved: the same tree (N and P may have swapped roles).
            assert!((t.sah_cost(CostParams::default()) - c0).abs() <= 1e-9 * c0);
        }
    }
    assert!(moved > 0);
    validate(&t.to_bvh(), &boxes).unwrap();
    // One sweep may raise the cost a little (Bittner 3.5: the second child is inserted while the
    // first is already placed), but not by much.
    assert!(t.sah_cost(CostParams::default()) < 1.05 * before, "{} vs {before}", t.sah_cost(CostParams::default()));
    // Measures: comb = sum * min * area; leaves 0.
    for &n in inner.iter().take(50) {
        let (s, m, a, c) = (
            measure_value(&t, n, Measure::Sum) as f64,
            measure_value(&t, n, Measure::Min) as f64,
            measure_value(&t, n, Measure::Area) as f64,
            measure_value(&t, n, Measure::Comb) as f64,
        );
        assert!(s >= 1.0 - 1e-6 && m >= s - 1e-6, "{s} {m}");
        assert!((c - s * m * a).abs() <= 1e-3 * c.max(1e-30));
    }
    // find_best on a box already in the tree: merging with that very leaf costs SA(leaf) only.
    let leaf = (0..t.nodes.len() as u32).find(|&i| t.is_leaf(i)).unwrap();
    let b = *t.bounds(leaf);
    let (_, c) = find_best(&t, &b, &mut scratch);
    assert!(c <= b.area() * (1.0 + 1e-6));
}

#[test]
fn measures_stay_finite_above_degenerate_leaves() {
    // Zero-area boxes (points): eq. 10 would divide by zero; the measure ignores such children.
    let p = |x: f32| Aabb::new(Vec3::splat(x), Vec3::splat(x));
    let q = Aabb::new(Vec3::ZERO, Vec3::splat(2.0));
    let nodes = vec![
        Node::inner(q.union(&p(5.0)), 1),
        Node::inner(q.union(&p(3.0)), 3),
        Node::leaf(p(5.0), 2, 1),
        Node::leaf(q, 0, 1),
        Node::leaf(p(3.0), 1, 1),
    ];
    let t = DynTree::from_bvh(&Bvh { nodes, prim_indices: vec![0, 1, 2] });
    t.check().unwrap();
    for m in [Measure::Sum, Measure::Min, Measure::Area, Measure::Comb] {
        for n in [0, 1] {
            assert!(measure_value(&t, n, m).is_finite(), "{m:?} node {n}");
        }
    }
    // Node 1 = (q, point at 3): SA(N) / SA(q).
    let want = t.bounds(1).area() / q.area();
    assert!((measure_value(&t, 1, Measure::Min) - want).abs() <= 1e-5 * want);
}

/// The thesis' termination (Frantal 3.4.3), replayed from a run's trace: the cost is checked every
/// p_T passes against the previous check; the first check without improvement switches to random
/// sampling, checked every p_R passes; its first check without improvement ends the run, which
/// returns the last tree.
#[test]
fn thesis_schedule_checks_every_pt_passes_and_returns_the_last_tree() {
    use bvhlab_opt::ibo::Schedule;
    let scene = load_scene("gen:city:blocks=5").unwrap();
    let median = build(&scene, true, 1);
    for (pt, pr) in [(10, 5), (3, 2), (4, 0)] {
        let cfg = IboConfig { schedule: Schedule::Thesis, keep_best: false, pt, pr, ..Default::default() };
        let o = optimize(&median, &cfg);
        let ctx = format!("pt={pt} pr={pr}");
        assert_eq!(o.stop, Stop::Converged, "{ctx}");
        let last = o.trace.len() as u32 - 1;
        assert_eq!(o.returned_pass, last, "{ctx}: the last tree");
        assert!((o.trace[last as usize].sah_cost - cost(&o.bvh)).abs() <= 1e-6 * cost(&o.bvh), "{ctx}");
        check_hits(&ctx, &o.bvh, &scene);
        // Replay: where must the stage switch and the run end, given the recorded costs?
        let (mut prev, mut random, mut since, mut end, mut switch) = (o.trace[0].sah_cost, false, 0, None, None);
        for r in &o.trace[1..] {
            since += 1;
            if since == if random { pr } else { pt } {
                since = 0;
                let improved = r.sah_cost < prev;
                prev = r.sah_cost;
                if !improved {
                    if random || pr == 0 {
                        end = Some(r.pass);
                        break;
                    }
                    random = true;
                    switch = Some(r.pass);
                }
            }
        }
        assert_eq!(end, Some(last), "{ctx}: stops at the first check without improvement of the last stage");
        let first_random = o.trace.iter().find(|r| r.phase == "random").map(|r| r.pass);
        assert_eq!(first_random, switch.map(|p| p + 1), "{ctx}: random sampling after the measure stage");
        if pr == 0 {
            assert_eq!(first_random, None, "{ctx}");
        } else {
            // The measure stage lasts a multiple of p_T passes, the random stage one of p_R.
            let s = switch.unwrap();
            assert_eq!((s % pt, (last - s) % pr), (0, 0), "{ctx}");
        }
        // The input's cost was improved at the first check (the spatial median is a bad start).
        assert!(o.trace[pt as usize].sah_cost < o.trace[0].sah_cost, "{ctx}");
    }
    // keep_best applies to the thesis schedule too: the best pass's tree, never costlier than the last.
    let cfg = IboConfig { schedule: Schedule::Thesis, keep_best: true, ..Default::default() };
    let (best, lastt) = (optimize(&median, &cfg), optimize(&median, &IboConfig { keep_best: false, ..cfg }));
    let costs = |o: &bvhlab_opt::Optimized| o.trace.iter().map(|r| r.sah_cost).collect::<Vec<_>>();
    assert_eq!(costs(&best), costs(&lastt));
    assert!(cost(&best.bvh) <= cost(&lastt.bvh));
}
