//! Kensler tree rotations (hill climbing, simulated annealing): valid trees with the same closest
//! hits as brute force, hill climbing never increases the cost and ends in a local optimum,
//! annealing is deterministic for a seed and keep_best returns the cheapest pass, degenerate
//! inputs (1 or 2 primitives, coincident and zero-area triangles) pass through.
use bvhlab_builders::{spatial_median, sweep_sah, TopDownConfig};
use bvhlab_bvh::{metrics, validate, Bvh, CostParams};
use bvhlab_geom::load_scene;
use bvhlab_opt::kensler::{optimize, KenslerConfig};
use bvhlab_opt::Stop;
use bvhlab_trace::{brute_force, random_rays, trace};

const SCENES: &[&str] = &[
    "gen:sphere:n=2000",
    "gen:terrain:n=2000",
    "gen:hairball:n=300",
    "gen:city:blocks=4",
    "gen:degenerate:n=1000",
];

fn hc() -> KenslerConfig {
    KenslerConfig::default()
}

fn sa(seed: u64) -> KenslerConfig {
    // Cold enough to end near a local optimum in 30 passes, hot enough to accept uphill moves.
    KenslerConfig {
        anneal: true,
        t0: 1e-4,
        cooling: 0.7,
        max_passes: 30,
        seed,
        ..KenslerConfig::default()
    }
}

fn cost(b: &Bvh) -> f64 {
    metrics(b, CostParams::default()).sah_cost
}

#[test]
fn valid_and_same_hits_as_brute_force() {
    for spec in SCENES {
        let scene = load_scene(spec).unwrap();
        let (boxes, centers) = scene.boxes_and_centers();
        let rays = random_rays(&scene.bounds(), 0.0, 2000, 11);
        let want = brute_force(&scene.triangles, &rays);
        for leaf in [1, 3] {
            let tcfg = TopDownConfig {
                leaf,
                ..Default::default()
            };
            for (init, bvh) in [
                ("median", spatial_median::build(&boxes, &centers, &tcfg)),
                ("sweep", sweep_sah::build(&boxes, &centers, &tcfg)),
            ] {
                for (mode, cfg) in [("hc", hc()), ("sa", sa(5))] {
                    let ctx = format!("{spec} {init} leaf={leaf} {mode}");
                    let r = optimize(&bvh, &cfg);
                    validate(&r.bvh, &boxes).unwrap_or_else(|e| panic!("{ctx}: {e}"));
                    let got = trace(&r.bvh, &scene.triangles, &rays);
                    for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
                        let same = g.prim == w.prim
                            || (g.is_hit()
                                && w.is_hit()
                                && (g.t - w.t).abs() <= 1e-4 * w.t.abs().max(1e-30));
                        assert!(same, "{ctx}: ray {i} got {g:?}, brute force {w:?}");
                    }
                    // The returned tree's cost is the one the trace reports for the returned pass.
                    let rec = &r.trace[r.returned_pass as usize];
                    assert!(
                        (rec.sah_cost - cost(&r.bvh)).abs() <= 1e-9 * rec.sah_cost.max(1.0),
                        "{ctx}"
                    );
                    assert!(
                        cost(&r.bvh) <= cost(&bvh) * (1.0 + 1e-9),
                        "{ctx}: {} -> {}",
                        cost(&bvh),
                        cost(&r.bvh)
                    );
                }
            }
        }
    }
}

#[test]
fn hill_climbing_is_monotone_and_converges_to_a_local_optimum() {
    for spec in ["gen:sphere:n=3000", "gen:city:blocks=4"] {
        let scene = load_scene(spec).unwrap();
        let (boxes, centers) = scene.boxes_and_centers();
        let bvh = spatial_median::build(
            &boxes,
            &centers,
            &TopDownConfig {
                leaf: 1,
                ..Default::default()
            },
        );
        let r = optimize(&bvh, &hc());
        assert_eq!(r.stop, Stop::Converged, "{spec}");
        assert!((r.trace[0].sah_cost - cost(&bvh)).abs() <= 1e-9 * cost(&bvh));
        for w in r.trace.windows(2) {
            assert!(
                w[1].sah_cost <= w[0].sah_cost * (1.0 + 1e-12),
                "{spec}: pass {} raised the cost",
                w[1].pass
            );
        }
        assert!(r.trace[1].moved > 0);
        assert_eq!(r.trace.last().unwrap().moved, 0);
        assert!(
            cost(&r.bvh) < 0.99 * cost(&bvh),
            "{spec}: {} -> {}",
            cost(&bvh),
            cost(&r.bvh)
        );
        // A local optimum: climbing again from it applies no rotation.
        let again = optimize(&r.bvh, &hc());
        assert_eq!(again.trace.len(), 2);
        assert_eq!(again.trace[1].moved, 0);
        assert_eq!(again.bvh, r.bvh);
        // max_passes caps the climb.
        let capped = optimize(
            &bvh,
            &KenslerConfig {
                max_passes: 1,
                ..hc()
            },
        );
        assert_eq!(capped.stop, Stop::MaxPasses);
        assert_eq!(capped.trace.len(), 2);
    }
}

#[test]
fn annealing_is_deterministic_and_keep_best_returns_the_cheapest_pass() {
    let scene = load_scene("gen:terrain:n=2000").unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    let bvh = sweep_sah::build(
        &boxes,
        &centers,
        &TopDownConfig {
            leaf: 1,
            ..Default::default()
        },
    );
    let a = optimize(&bvh, &sa(7));
    let b = optimize(&bvh, &sa(7));
    assert_eq!(a.bvh, b.bvh);
    let strip =
        |t: &[bvhlab_opt::PassRecord]| t.iter().map(|p| (p.sah_cost, p.moved)).collect::<Vec<_>>();
    assert_eq!(strip(&a.trace), strip(&b.trace));
    assert_eq!(a.stop, Stop::MaxPasses);
    assert_eq!(a.trace.len(), 31);
    let c = optimize(&bvh, &sa(8));
    assert_ne!(strip(&a.trace), strip(&c.trace), "the seed should matter");
    // Hot start: early passes accept uphill rotations and raise the cost above the input's.
    let hot = KenslerConfig {
        t0: 0.01,
        cooling: 0.8,
        max_passes: 20,
        ..sa(3)
    };
    let h = optimize(&bvh, &hot);
    assert!(
        h.trace[1].sah_cost > h.trace[0].sah_cost,
        "t0=0.01 should accept uphill moves"
    );
    let min = h
        .trace
        .iter()
        .map(|p| p.sah_cost)
        .fold(f64::INFINITY, f64::min);
    assert_eq!(h.trace[h.returned_pass as usize].sah_cost, min);
    assert!((cost(&h.bvh) - min).abs() <= 1e-9 * min);
    let last = optimize(
        &bvh,
        &KenslerConfig {
            keep_best: false,
            ..hot
        },
    );
    assert_eq!(last.returned_pass, 20);
    assert!((cost(&last.bvh) - last.trace[20].sah_cost).abs() <= 1e-9 * min);
    // Annealing ends when the temperature is negligible.
    let short = optimize(
        &bvh,
        &KenslerConfig {
            t0: 1e-8,
            cooling: 0.1,
            max_passes: 0,
            ..sa(1)
        },
    );
    assert_eq!(short.stop, Stop::Converged);
    assert!(short.trace.len() <= 3);
}

#[test]
fn degenerate_inputs() {
    for spec in [
        "gen:degenerate:n=1",
        "gen:degenerate:n=2",
        "gen:degenerate:n=3",
        "gen:degenerate:n=500",
    ] {
        let scene = load_scene(spec).unwrap();
        let (boxes, centers) = scene.boxes_and_centers();
        let bvh = spatial_median::build(
            &boxes,
            &centers,
            &TopDownConfig {
                leaf: 1,
                ..Default::default()
            },
        );
        for cfg in [
            hc(),
            sa(2),
            KenslerConfig {
                t0: 1.0,
                cooling: 0.5,
                ..sa(2)
            },
        ] {
            let r = optimize(&bvh, &cfg);
            validate(&r.bvh, &boxes).unwrap_or_else(|e| panic!("{spec}: {e}"));
            assert!(r.stop != Stop::MaxSeconds);
        }
    }
    // Empty tree.
    let r = optimize(&Bvh::default(), &hc());
    assert_eq!(r.bvh, Bvh::default());
    // A zero-area root (every box the same point) and a deep chain (depth n) do not overflow.
    for (n, step) in [(2_000u32, 0.0f32), (50_000, 1.0)] {
        let boxes: Vec<_> = (0..n)
            .map(|i| {
                let p = bvhlab_bvh::Vec3::new(0.0, 0.0, i as f32 * step);
                bvhlab_bvh::Aabb::new(p, p + bvhlab_bvh::Vec3::new(0.0, step, step))
            })
            .collect();
        let bvh = chain(&boxes);
        for cfg in [
            KenslerConfig {
                max_passes: 5,
                ..hc()
            },
            KenslerConfig {
                max_passes: 3,
                ..sa(4)
            },
        ] {
            let r = optimize(&bvh, &cfg);
            validate(&r.bvh, &boxes).unwrap();
            assert!(cost(&r.bvh) <= cost(&bvh) * (1.0 + 1e-9));
        }
    }
}

/// ((((p0, p1), p2), p3) ...): a tree as deep as the primitive count.
fn chain(boxes: &[bvhlab_bvh::Aabb]) -> Bvh {
    use bvhlab_bvh::dyntree::{DNode, DynTree, NONE};
    let n = boxes.len();
    let mut nodes: Vec<DNode> = boxes
        .iter()
        .enumerate()
        .map(|(i, b)| DNode::leaf(*b, i as u32, 1))
        .collect();
    let mut parent = vec![NONE; 2 * n - 1];
    let mut top = 0u32;
    for i in 1..n as u32 {
        let id = nodes.len() as u32;
        nodes.push(DNode::inner(
            nodes[top as usize].bounds.union(&boxes[i as usize]),
            top,
            i,
        ));
        parent[top as usize] = id;
        parent[i as usize] = id;
        top = id;
    }
    let t = DynTree {
        nodes,
        parent,
        prims: (0..n as u32).collect(),
        root: top,
    };
    t.check().unwrap();
    t.to_bvh()
}
