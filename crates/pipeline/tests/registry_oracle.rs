//! Every builder the pipeline offers (the registry, so builders added later are covered without
//! touching this file), with and without SAH compaction, on every generated scene type: the BVH passes
//! structural validation and finds the same closest hit as brute force on random rays (thesis 4.4).
//! Builders that take codes run with every encoder and the encoder options (bits, bounds, grid),
//! including the far-outlier scenes where quantization fails (Riemersma 2024).
use bvhlab_builders::SortedCodes;
use bvhlab_bvh::{collapse::collapse, validate_refs, Bvh, CostParams, Refs};
use bvhlab_geom::{load_scene, Scene};
use bvhlab_pipeline::registry::Registry;
use bvhlab_trace::{brute_force, random_rays, trace, Ray};
use std::collections::BTreeMap;

const SCENES: &[&str] = &[
    "gen:sphere:n=3000",
    "gen:terrain:n=3000",
    "gen:hairball:n=500",
    "gen:city:blocks=6",
    "gen:outlier:e=0,n=2000",
    "gen:outlier:e=10,n=2000",
    "gen:outlier:e=20,n=2000",
    "gen:outlier:e=30,n=2000",
    "gen:degenerate:n=2000",
];

/// (encoder, parameters) for the builders that take codes.
const ENCODERS: &[(&str, &[(&str, &str)])] = &[
    ("morton", &[]),
    ("morton", &[("bits", "10")]),
    ("morton", &[("bounds", "concise")]),
    ("emc64-sort", &[]),
    ("emc64-var", &[]),
    ("emc64-var", &[("bounds", "concise"), ("grid_bits", "9")]),
    ("morton", &[("grid_bits", "9")]),
];

fn check(
    ctx: &str,
    refs: Refs,
    bvh: &Bvh,
    scene: &Scene,
    boxes: &[bvhlab_bvh::Aabb],
    rays: &[Ray],
    want: &[bvhlab_trace::Hit],
) {
    validate_refs(bvh, boxes, refs).unwrap_or_else(|e| panic!("{ctx}: invalid: {e}"));
    let got = trace(bvh, &scene.triangles, rays);
    for (i, (g, w)) in got.hits.iter().zip(want).enumerate() {
        let same = g.prim == w.prim
            || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-4 * w.t.abs().max(1e-30));
        assert!(same, "{ctx}: ray {i} got {g:?}, brute force {w:?}");
    }
}

fn raw(kv: &[(&str, &str)]) -> BTreeMap<String, String> {
    kv.iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// A scene with `n` random rays (seeded) and their brute-force closest hits.
struct Case {
    scene: Scene,
    boxes: Vec<bvhlab_bvh::Aabb>,
    centers: Vec<bvhlab_bvh::Vec3>,
    rays: Vec<Ray>,
    want: Vec<bvhlab_trace::Hit>,
}

fn case(spec: &str, n: usize, seed: u64) -> Case {
    let scene = load_scene(spec).unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    let b = scene.bounds();
    let radius = centers
        .iter()
        .map(|c| (*c - b.center()).length())
        .fold(0.0, f32::max);
    let rays = random_rays(&b, radius, n, seed);
    let want = brute_force(&scene.triangles, &rays);
    Case {
        scene,
        boxes,
        centers,
        rays,
        want,
    }
}

#[test]
fn every_registered_builder_matches_brute_force() {
    let reg = Registry::standard();
    let cost = CostParams::default();
    for spec in SCENES {
        let Case {
            scene,
            boxes,
            centers,
            rays,
            want,
        } = case(spec, 3000, 7);
        for info in &reg.builders {
            if info.codes.is_none() {
                // Builders without a leaf threshold (incremental: one primitive per leaf) run once.
                let has_leaf = info.params.iter().any(|p| p.name == "leaf");
                for leaf in if has_leaf {
                    &["1", "2"][..]
                } else {
                    &["1"][..]
                } {
                    let params = if has_leaf {
                        raw(&[("leaf", leaf)])
                    } else {
                        raw(&[])
                    };
                    let resolved = reg.resolve(info.name, &params, cost).unwrap();
                    let built = info.construct(&scene.triangles, &boxes, &centers, None, &resolved);
                    for (what, bvh) in [
                        ("built", built.clone()),
                        ("collapsed", collapse(&built, cost)),
                    ] {
                        check(
                            &format!("{spec} {} leaf={leaf} {what}", info.name),
                            info.refs,
                            &bvh,
                            &scene,
                            &boxes,
                            &rays,
                            &want,
                        );
                    }
                }
                continue;
            }
            for (enc, params) in ENCODERS {
                let (resolved, encoder) = reg
                    .resolve_chain(info.name, Some(enc), None, &raw(params), cost)
                    .unwrap()
                    .parts();
                let encoder = encoder.expect("code builders have an encoder");
                let e = bvhlab_morton::encode(&boxes, &centers, &encoder.config);
                let codes = SortedCodes {
                    order: &e.order,
                    codes: &e.codes,
                    code_bits: e.code_bits,
                };
                let ctx = format!(
                    "{spec} {} {}",
                    reg.label(&resolved),
                    reg.encoder_label(&encoder)
                );
                // The raw single-primitive-leaf tree and what the build stage stores (+ compaction).
                let raw_tree = (info.run)(&boxes, &centers, Some(&codes), &resolved);
                check(
                    &format!("{ctx} raw"),
                    Refs::Unique,
                    &raw_tree,
                    &scene,
                    &boxes,
                    &rays,
                    &want,
                );
                let built = info.construct(&scene.triangles, &boxes, &centers, Some(&codes), &resolved);
                check(
                    &format!("{ctx} built"),
                    Refs::Unique,
                    &built,
                    &scene,
                    &boxes,
                    &rays,
                    &want,
                );
            }
        }
    }
}

/// Every registered optimizer on a poor (spatial median) and a good (sweep SAH) single-primitive-
/// leaf tree and on a multi-primitive-leaf tree, then compacted: valid, same closest hits as brute
/// force, never a worse tree than its input when `keep_best` is on (the default).
#[test]
fn every_registered_optimizer_matches_brute_force() {
    let reg = Registry::standard();
    let cost = CostParams::default();
    for spec in SCENES {
        let Case {
            scene,
            boxes,
            centers,
            rays,
            want,
        } = case(spec, 2000, 11);
        for (builder, leaf) in [
            ("spatial-median", "1"),
            ("sweep-sah", "1"),
            ("binned-sah", "4"),
            // Repeated references (Stich et al. 2009) through every optimizer and the compaction.
            ("sbvh", "1"),
        ] {
            let r = reg.resolve(builder, &raw(&[("leaf", leaf)]), cost).unwrap();
            let info = reg.get(builder).unwrap();
            let refs = info.refs;
            let built = info.construct(&scene.triangles, &boxes, &centers, None, &r);
            let before = bvhlab_bvh::metrics(&built, cost).sah_cost;
            for info in &reg.optimizers {
                // Bounded so the suite stays fast; convergence is the optimizers' own tests' job.
                let o = reg
                    .resolve_optimizer(info.name, &raw(&[("max_passes", "20")]), cost)
                    .unwrap();
                let out = (info.run)(&built, &o);
                let ctx = format!("{spec} {builder} leaf={leaf} {}", reg.optimizer_label(&o));
                check(&ctx, refs, &out.bvh, &scene, &boxes, &rays, &want);
                check(
                    &format!("{ctx} collapsed"),
                    refs,
                    &collapse(&out.bvh, cost),
                    &scene,
                    &boxes,
                    &rays,
                    &want,
                );
                let after = bvhlab_bvh::metrics(&out.bvh, cost).sah_cost;
                assert!(
                    after <= before * (1.0 + 1e-9),
                    "{ctx}: keep_best returned cost {after} > input {before}"
                );
                assert_eq!(
                    out.trace.first().map(|p| p.pass),
                    Some(0),
                    "{ctx}: trace starts at pass 0"
                );
            }
        }
    }
}
