//! The parallel binned SAH (thesis 3.1.2) gives byte-identical trees to the sequential binned SAH
//! for every parameter, speed knob and thread count, and they are valid.
mod common;
use bvhlab_builders::binned_sah::{self, Axes, BinnedOptions, CentroidTermination, ParallelTuning};
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{validate, Aabb, Vec3};
use common::*;

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

fn generated(spec: &str) -> (Vec<Aabb>, Vec<Vec3>) {
    bvhlab_geom::load_scene(spec)
        .expect("generated scene")
        .boxes_and_centers()
}

/// Small scenes with the hard cases: coincident centroids, flat, all points, far outlier, huge
/// coordinates, one and two primitives, and the generators' degenerate mix and city.
fn scenes() -> Vec<(String, Vec<Aabb>, Vec<Vec3>)> {
    let mut v: Vec<(String, Vec<Aabb>, Vec<Vec3>)> = Vec::new();
    for spec in [
        "gen:sphere:n=4000",
        "gen:degenerate:n=3000",
        "gen:city:blocks=8",
        "gen:outlier:n=2000,e=20",
        "gen:outlier:n=2000,e=100",
        "gen:hairball:n=2000",
        "gen:terrain:n=2000",
    ] {
        let (b, c) = generated(spec);
        v.push((spec.into(), b, c));
    }
    let huge: Vec<Aabb> = random_boxes(1500, 0.05, 9)
        .into_iter()
        .map(|b| Aabb::new(b.min * 1e30, b.max * 1e30))
        .collect();
    for (name, boxes) in [
        ("random", random_boxes(3000, 0.05, 1)),
        ("equal-centroids", equal_centroid_boxes(500)),
        ("flat", flat_boxes(2000, 2)),
        ("points", point_boxes(300)),
        ("huge", huge),
        ("one", random_boxes(1, 0.1, 3)),
        ("two", random_boxes(2, 0.1, 4)),
        ("two-equal", point_boxes(2)),
    ] {
        let c = centers_of(&boxes);
        v.push((name.into(), boxes, c));
    }
    v
}

/// Tiny knobs run the horizontal phase (parallel binning and partition) down to single
/// primitives and cut chunks into odd sizes; `vertical_min = 1` means no vertical tasks at all.
const TUNINGS: [ParallelTuning; 4] = [
    ParallelTuning {
        vertical_min: 1,
        min_chunk: 7,
    },
    ParallelTuning {
        vertical_min: 2,
        min_chunk: 1,
    },
    ParallelTuning {
        vertical_min: 100,
        min_chunk: 33,
    },
    ParallelTuning {
        vertical_min: 1000,
        min_chunk: 1024,
    },
];

#[test]
fn parallel_binned_is_byte_identical_to_sequential() {
    let pools = [pool(1), pool(2), pool(3)];
    for (scene, boxes, centers) in scenes() {
        for leaf in [1, 2, 8] {
            let cfg = TopDownConfig {
                leaf,
                ..Default::default()
            };
            for bins in [2, 16, 33] {
                for (term, axes) in [
                    (CentroidTermination::SplitAxis, Axes::Largest),
                    (CentroidTermination::AnyAxis, Axes::Largest),
                    (CentroidTermination::SplitAxis, Axes::All),
                    (CentroidTermination::AnyAxis, Axes::All),
                ] {
                    let opts = BinnedOptions { bins, term, axes };
                    let seq = binned_sah::build_with_options(&boxes, &centers, &opts, &cfg);
                    if axes == Axes::Largest {
                        let legacy =
                            binned_sah::build_with_termination(&boxes, &centers, bins, &cfg, term);
                        assert!(legacy.canonical_bytes() == seq.canonical_bytes());
                    }
                    if let Err(e) = validate(&seq, &boxes) {
                        panic!("sequential on {scene}: {e}");
                    }
                    let want = seq.canonical_bytes();
                    for (pi, p) in pools.iter().enumerate() {
                        let what = format!(
                            "{scene} leaf {leaf} bins {bins} {term:?} {axes:?} threads {}",
                            pi + 1
                        );
                        let par = p.install(|| {
                            binned_sah::build_parallel_with_options(&boxes, &centers, &opts, &cfg)
                        });
                        assert!(par.canonical_bytes() == want, "build_parallel: {what}");
                        for t in TUNINGS {
                            let par = p.install(|| {
                                binned_sah::build_parallel_options_tuned(
                                    &boxes, &centers, &opts, &cfg, t,
                                )
                            });
                            if let Err(e) = validate(&par, &boxes) {
                                panic!("{what} {t:?}: {e}");
                            }
                            assert!(par.canonical_bytes() == want, "{what} {t:?}");
                        }
                    }
                }
            }
        }
    }
}

/// Above the default vertical threshold (4096 primitives), `build_parallel` itself takes the
/// horizontal path at 2 and 3 threads.
#[test]
fn default_knobs_on_a_larger_scene() {
    let (boxes, centers) = generated("gen:sphere:n=60000");
    let cfg = TopDownConfig::default();
    let term = CentroidTermination::default();
    let seq = binned_sah::build(&boxes, &centers, 16, &cfg);
    assert!(validate(&seq, &boxes).is_ok());
    for threads in [1, 2, 3] {
        let tuning = ParallelTuning::for_size(boxes.len(), threads);
        assert!(
            threads == 1 || tuning.vertical_min < boxes.len(),
            "the root must be split horizontally"
        );
        let par =
            pool(threads).install(|| binned_sah::build_parallel(&boxes, &centers, 16, &cfg, term));
        assert!(
            par.canonical_bytes() == seq.canonical_bytes(),
            "threads {threads}"
        );
    }
}

#[test]
fn parallel_binned_on_empty_input() {
    let p = pool(2);
    let t = ParallelTuning {
        vertical_min: 1,
        min_chunk: 1,
    };
    let bvh = p.install(|| {
        binned_sah::build_parallel_tuned(
            &[],
            &[],
            16,
            &TopDownConfig::default(),
            CentroidTermination::default(),
            t,
        )
    });
    assert!(bvh.nodes.is_empty() && bvh.prim_indices.is_empty());
}

/// Loading drops non-finite triangles, but the builder must still terminate on them. (Identical
/// bytes are not promised here: min/max with NaN depend on the merge order.)
#[test]
fn parallel_binned_terminates_on_non_finite_boxes() {
    let mut boxes = random_boxes(400, 0.05, 12);
    boxes[3] = Aabb::new(Vec3::NAN, Vec3::NAN);
    boxes[50].max.x = f32::INFINITY;
    boxes[200].min.y = f32::NEG_INFINITY;
    let centers = centers_of(&boxes);
    let p = pool(2);
    for leaf in [1, 2] {
        let cfg = TopDownConfig {
            leaf,
            ..Default::default()
        };
        for t in TUNINGS {
            let bvh = p.install(|| {
                binned_sah::build_parallel_tuned(
                    &boxes,
                    &centers,
                    16,
                    &cfg,
                    CentroidTermination::default(),
                    t,
                )
            });
            let mut ids = bvh.prim_indices.clone();
            ids.sort_unstable();
            assert!(
                ids.iter().copied().eq(0..400u32),
                "{t:?}: not a permutation"
            );
        }
    }
}

/// Geometrically spaced primitives make the top of the tree a long chain of large nodes (each
/// split peels off the few farthest ones), deeper than the parallel driver's recursion limit
/// (about 2 log2 n), so its explicit-stack fallback runs; the bytes must not change.
#[test]
fn deep_chain_of_large_nodes_is_byte_identical() {
    let n = 300;
    let boxes: Vec<Aabb> = (0..n)
        .map(|i| {
            let x = 1.3f32.powi(i);
            Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))
        })
        .collect();
    let centers = centers_of(&boxes);
    let term = CentroidTermination::default();
    let t = ParallelTuning {
        vertical_min: 2,
        min_chunk: 1,
    };
    for leaf in [1, 2] {
        let cfg = TopDownConfig {
            leaf,
            ..Default::default()
        };
        let seq = binned_sah::build_with_termination(&boxes, &centers, 16, &cfg, term);
        assert!(validate(&seq, &boxes).is_ok());
        let cost = bvhlab_bvh::CostParams { c_t: 3.0, c_i: 2.0 };
        let depth = bvhlab_bvh::metrics(&seq, cost).depth;
        // The recursion limit for 300 primitives is 2 * 9 levels; inner nodes have >= 2 primitives.
        assert!(depth > 20, "the scene must make a deep tree, depth {depth}");
        for threads in [2, 3] {
            let par = pool(threads)
                .install(|| binned_sah::build_parallel_tuned(&boxes, &centers, 16, &cfg, term, t));
            assert!(
                par.canonical_bytes() == seq.canonical_bytes(),
                "leaf {leaf} threads {threads}"
            );
        }
    }
}
