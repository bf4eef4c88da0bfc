//! Incremental builder (Bittner 2015; thesis 3.5.1): valid trees with one primitive per leaf and
//! 2n - 1 nodes, the same closest hits as brute force, deterministic, coherent pairs clustered as
//! eq. 13 says, the per-batch passes lower the cost, degenerate inputs pass through.
use bvhlab_bvh::{metrics, validate, Aabb, Bvh, CostParams, Vec3};
use bvhlab_geom::load_scene;
use bvhlab_builders::incremental::{build, build_with_stats, IncConfig};
use bvhlab_trace::{brute_force, random_rays, trace};

fn cost(b: &Bvh) -> f64 {
    metrics(b, CostParams::default()).sah_cost
}

fn one_per_leaf(b: &Bvh, n: usize) {
    assert_eq!(b.nodes.len(), 2 * n - 1);
    assert!(b.nodes.iter().all(|d| !d.is_leaf() || d.count == 1));
}

#[test]
fn valid_and_same_hits_as_brute_force() {
    for spec in [
        "gen:sphere:n=2000",
        "gen:terrain:n=2000",
        "gen:hairball:n=300",
        "gen:city:blocks=4",
        "gen:degenerate:n=1000",
    ] {
        let scene = load_scene(spec).unwrap();
        let (boxes, _) = scene.boxes_and_centers();
        let rays = random_rays(&scene.bounds(), 0.0, 2000, 13);
        let want = brute_force(&scene.triangles, &rays);
        for cfg in [
            IncConfig::default(),
            IncConfig {
                batch: 100,
                ofrac: 0.2,
                ..Default::default()
            },
            IncConfig {
                batch: 37,
                ofrac: 0.05,
                coh: 0.0,
                ..Default::default()
            },
            IncConfig {
                batch: 1,
                ofrac: 1.0,
                coh: 3.0,
                ..Default::default()
            },
        ] {
            let ctx = format!("{spec} {cfg:?}");
            let bvh = build(&boxes, &cfg);
            validate(&bvh, &boxes).unwrap_or_else(|e| panic!("{ctx}: {e}"));
            one_per_leaf(&bvh, boxes.len());
            let got = trace(&bvh, &scene.triangles, &rays);
            for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
                let same = g.prim == w.prim
                    || (g.is_hit()
                        && w.is_hit()
                        && (g.t - w.t).abs() <= 1e-4 * w.t.abs().max(1e-30));
                assert!(same, "{ctx}: ray {i} got {g:?}, brute force {w:?}");
            }
        }
    }
}

#[test]
fn deterministic_and_passes_counted() {
    let scene = load_scene("gen:hairball:n=400").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    let n = boxes.len();
    let cfg = IncConfig {
        batch: 50,
        ofrac: 0.1,
        ..Default::default()
    };
    let (a, sa) = build_with_stats(&boxes, &cfg);
    let (b, sb) = build_with_stats(&boxes, &cfg);
    assert_eq!(a, b);
    assert_eq!(sa, sb);
    // One pass per complete batch that is not the end of the input (insertions of coherent pairs
    // count two primitives, so a batch boundary may be crossed by one).
    let full = ((n - 1) / 50) as u64;
    assert!(
        full > 5 && sa.passes + 1 >= full && sa.passes <= full,
        "{} passes for {n}",
        sa.passes
    );
    assert!(sa.updated >= sa.passes && sa.moved <= sa.updated);
}

#[test]
fn batch_passes_lower_the_cost() {
    // Random insertion order (a shuffled sphere) is where greedy insertion goes wrong most.
    let scene = load_scene("gen:sphere:n=3000").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    let mut rng = bvhlab_geom::rng::SplitMix64::new(5);
    let mut shuffled = boxes.clone();
    for i in (1..shuffled.len()).rev() {
        shuffled.swap(i, rng.below(i as u64 + 1) as usize);
    }
    let none = build(
        &shuffled,
        &IncConfig {
            batch: u32::MAX,
            ..Default::default()
        },
    );
    let (some, st) = build_with_stats(
        &shuffled,
        &IncConfig {
            batch: 200,
            ofrac: 0.2,
            ..Default::default()
        },
    );
    assert!(st.passes > 10 && st.moved > 0);
    assert!(
        cost(&some) < 0.98 * cost(&none),
        "{} vs {}",
        cost(&some),
        cost(&none)
    );
}

#[test]
fn coherent_pairs_are_clustered() {
    let scene = load_scene("gen:terrain:n=2000").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    let n = boxes.len();
    let coh = 1.5f32;
    // Greedy non-overlapping scan of eq. 13, written independently.
    let (mut want, mut pairs, mut i) = (0u64, Vec::new(), 0);
    while i + 1 < n {
        let (x, y) = (&boxes[i], &boxes[i + 1]);
        let r = x.union(y).area_f64() / (x.area_f64() + y.area_f64());
        if r < coh as f64 {
            want += 1;
            pairs.push((i as u32, i as u32 + 1));
            i += 2;
        } else {
            i += 1;
        }
    }
    assert!(
        want > 100,
        "terrain should have coherent neighbours ({want})"
    );
    // Without passes every pair stays under its own inner node.
    let (bvh, st) = build_with_stats(
        &boxes,
        &IncConfig {
            batch: u32::MAX,
            coh,
            ..Default::default()
        },
    );
    assert_eq!(st.clusters, want);
    let mut found = 0;
    for d in &bvh.nodes {
        if d.is_leaf() {
            continue;
        }
        let (l, r) = (
            &bvh.nodes[d.first as usize],
            &bvh.nodes[d.first as usize + 1],
        );
        if l.is_leaf() && r.is_leaf() {
            let (a, b) = (
                bvh.prim_indices[l.first as usize],
                bvh.prim_indices[r.first as usize],
            );
            if pairs.binary_search(&(a.min(b), a.max(b))).is_ok() {
                found += 1;
            }
        }
    }
    assert!(found >= want, "{found} of {want} pairs found as siblings");
    // coh = 0 disables clustering.
    assert_eq!(
        build_with_stats(
            &boxes,
            &IncConfig {
                coh: 0.0,
                ..Default::default()
            }
        )
        .1
        .clusters,
        0
    );
}

#[test]
fn degenerate_inputs() {
    assert_eq!(build(&[], &IncConfig::default()), Bvh::default());
    let p = |x: f32| Aabb::new(Vec3::splat(x), Vec3::splat(x));
    for boxes in [
        vec![p(0.0)],
        vec![p(0.0), p(0.0)],
        vec![p(0.0), p(1.0), p(0.0)],
        vec![p(3.0); 1000],
    ] {
        for cfg in [
            IncConfig::default(),
            IncConfig {
                batch: 10,
                ofrac: 0.5,
                ..Default::default()
            },
        ] {
            let bvh = build(&boxes, &cfg);
            validate(&bvh, &boxes).unwrap();
            one_per_leaf(&bvh, boxes.len());
        }
    }
    // Points along a line in sorted order: every insertion goes to the end, the tree is a chain
    // as deep as the input (quadratic search time, so kept small; deep enough to catch recursion).
    let line: Vec<Aabb> = (0..10_000).map(|i| p(i as f32)).collect();
    let bvh = build(
        &line,
        &IncConfig {
            batch: 1000,
            ..Default::default()
        },
    );
    validate(&bvh, &line).unwrap();
    let scene = load_scene("gen:degenerate:n=2000").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    let bvh = build(
        &boxes,
        &IncConfig {
            batch: 50,
            ..Default::default()
        },
    );
    validate(&bvh, &boxes).unwrap();
}
