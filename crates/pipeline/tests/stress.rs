//! Stress suite (issue 6): every registered builder (every encoder variant for code builders),
//! the SAH compaction, every optimizer and every layout on the scenes on which BVH libraries are
//! known to break (crates/geom/src/gen.rs: far outliers, huge primitives at the scene edge, flat
//! extents, slivers, zero-area and duplicated triangles, one shared centroid, 1e-30 and 1e30
//! coordinates, non-finite input, one triangle, a 10^5-step staircase). Each method yields a valid
//! structure with the brute-force closest hit on every ray, or a clear error; never a panic.
//! Deep inputs run on a thread with a 2 MB stack: no recursion a deep tree can overflow.
mod methods;

use bvhlab_bvh::{Aabb, Bvh, Node};
use bvhlab_geom::load_scene;
use methods::{run_all, stress_rays, Input, Opts, Tally};

const SCENES: &[&str] = &[
    "gen:outlier:e=30,n=300",
    "gen:outlier:e=100,n=300",
    "gen:huge-edge:n=400",
    "gen:huge-edge:n=300,huge=20,size=1e20",
    "gen:flat:n=400",
    "gen:slivers:n=400",
    "gen:slivers:n=200,width=0",
    "gen:dups:n=400",
    "gen:dups:n=200,copies=200",
    "gen:same-centroid:n=400",
    "gen:degenerate:n=400",
    "gen:scale:n=400,s=1e-30",
    "gen:scale:n=400,s=1e-15",
    "gen:scale:n=400,s=1e30",
    "gen:scale:n=300,s=1e37",
    "gen:nonfinite:n=440,bad=40",
    "gen:single",
    "gen:single:seed=3",
    "gen:staircase:n=1000",
];

const RAYS: usize = 400;

/// Runs `f` on a thread with a 2 MB stack (the deep-tree proof) and propagates its panic.
fn small_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(2 << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap_or_else(|e| std::panic::resume_unwind(e))
}

fn run_scene(spec: &str, rays: usize, opts: Opts, tally: &mut Tally) {
    let scene = load_scene(spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
    if spec.starts_with("gen:nonfinite") {
        assert_eq!(scene.dropped_triangles, 40, "{spec}");
        assert_eq!(scene.triangles.len(), 400, "{spec}");
    }
    let rays = stress_rays(&scene.triangles, rays, 0x5eed);
    let want = bvhlab_trace::brute_force(&scene.triangles, &rays);
    let input = Input::new(&scene, &rays);
    // Slow methods are named (time since the previous report = this method's build + checks).
    let mut last = std::time::Instant::now();
    run_all(&input, opts, &mut |label, o| {
        let dt = last.elapsed().as_secs_f64();
        if dt > 1.0 {
            eprintln!("  slow: {spec} | {label}: {dt:.1} s");
        }
        tally.add(spec, label, o, &want);
        last = std::time::Instant::now();
    });
}

#[test]
fn every_method_on_every_stress_scene() {
    let t0 = std::time::Instant::now();
    let tally = small_stack(|| {
        let mut tally = Tally::default();
        for spec in SCENES {
            run_scene(spec, RAYS, Opts::FULL, &mut tally);
        }
        tally
    });
    eprintln!("stress matrix ({:.1} s): {}", t0.elapsed().as_secs_f64(), tally.summary());
    assert!(tally.failures.is_empty(), "{}", tally.summary());
    // The matrix really ran: every scene had hits to compare (not only misses).
    assert!(tally.rays_checked > 0);
}

/// A 10^5-step staircase: builders (default encoder), compaction and layouts on a 2 MB stack, few
/// rays. The incremental builder inserts along the stair and grows a tree about as deep as the
/// scene; its insertion search is then quadratic (146 s at n = 10^5 in debug), so it runs on a
/// 2*10^4-step staircase, still far deeper than any recursion a 2 MB stack holds. The hand-made
/// caterpillar below is the deepest tree of all.
#[test]
fn deep_staircase_on_a_small_stack() {
    let t0 = std::time::Instant::now();
    let tally = small_stack(|| {
        let mut tally = Tally::default();
        let opts = Opts {
            all_encoders: false,
            variants: false,
            optimizers: false,
            max_passes: 1,
            layouts: true,
            collapse: true,
            skip_builders: &["incremental"],
        };
        run_scene("gen:staircase:n=100000", 64, opts, &mut tally);
        let reg = bvhlab_pipeline::Registry::standard();
        let others: Vec<&'static str> =
            reg.builders.iter().map(|b| b.name).filter(|&n| n != "incremental").collect();
        let inc_only = Opts {
            skip_builders: Vec::leak(others),
            ..opts
        };
        run_scene("gen:staircase:n=20000", 64, inc_only, &mut tally);
        // The input is deep indeed.
        let scene = load_scene("gen:staircase:n=20000").unwrap();
        let (boxes, centers) = scene.boxes_and_centers();
        let cost = bvhlab_bvh::CostParams::default();
        let r = reg.resolve("incremental", &Default::default(), cost).unwrap();
        let bvh = reg.get("incremental").unwrap().construct(&scene.triangles, &boxes, &centers, None, &r);
        let d = depth(&bvh);
        eprintln!("incremental on staircase:n=20000: depth {d}");
        assert!(d > 2000, "depth {d}");
        tally
    });
    eprintln!("deep staircase ({:.1} s): {}", t0.elapsed().as_secs_f64(), tally.summary());
    assert!(tally.failures.is_empty(), "{}", tally.summary());
}

/// A caterpillar BVH (every inner node has one leaf child: depth n - 1) over the staircase, the
/// deepest tree a BVH can be: validation, traversal, compaction, every optimizer (one pass) and
/// every BVH layout on a 2 MB stack.
#[test]
fn caterpillar_tree_on_a_small_stack() {
    let n = std::env::var("STRESS_CATERPILLAR_N")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000u32);
    let tally = small_stack(move || {
        let scene = load_scene(&format!("gen:staircase:n={n}")).unwrap();
        let bvh = caterpillar(&scene.triangles);
        let rays = stress_rays(&scene.triangles, 32, 9);
        let want = bvhlab_trace::brute_force(&scene.triangles, &rays);
        let input = Input::new(&scene, &rays);
        let mut tally = Tally::default();
        let ctx = format!("caterpillar n={n}");
        let cost = bvhlab_bvh::CostParams::default();
        let reg = bvhlab_pipeline::Registry::standard();
        let check = |label: &str, b: &Bvh, tally: &mut Tally| {
            let o = match bvhlab_bvh::validate(b, &input.boxes) {
                Err(e) => methods::Outcome::Invalid(e),
                Ok(()) => methods::Outcome::Hits(bvhlab_trace::trace(b, input.tris, input.rays).hits),
            };
            tally.add(&ctx, label, o, &want);
        };
        check("caterpillar", &bvh, &mut tally);
        check("caterpillar +collapse", &bvhlab_bvh::collapse::collapse(&bvh, cost), &mut tally);
        for info in &reg.optimizers {
            let o = reg
                .resolve_optimizer(info.name, &methods::raw(&[("max_passes", "1")]), cost)
                .unwrap();
            let out = (info.run)(&bvh, &o);
            check(&reg.optimizer_label(&o), &out.bvh, &mut tally);
        }
        for name in bvhlab_layout::LAYOUTS {
            if !bvhlab_layout::uses_bvh(name) {
                continue;
            }
            let spec = bvhlab_layout::LayoutSpec::parse(name, &Default::default()).unwrap();
            let o = methods::layout_outcome(&spec, &bvh, &input);
            tally.add(&ctx, &format!("layout {name}"), o, &want);
        }
        tally
    });
    eprintln!("caterpillar: {}", tally.summary());
    assert!(tally.failures.is_empty(), "{}", tally.summary());
}

/// Node k (inner, at index 2k) has leaf k (index 2k + 1) and node k + 1 (index 2k + 2) as
/// children; the last inner node has the last two leaves.
fn caterpillar(tris: &[bvhlab_geom::Triangle]) -> Bvh {
    let n = tris.len();
    assert!(n >= 2);
    let boxes: Vec<Aabb> = tris.iter().map(|t| t.bounds()).collect();
    // suffix[k] = union of boxes k..n
    let mut suffix = vec![Aabb::EMPTY; n + 1];
    for k in (0..n).rev() {
        suffix[k] = suffix[k + 1].union(&boxes[k]);
    }
    let mut nodes = Vec::with_capacity(2 * n - 1);
    for k in 0..n - 1 {
        nodes.push(Node::inner(suffix[k], 2 * k as u32 + 1));
        nodes.push(Node::leaf(boxes[k], k as u32, 1));
        if k == n - 2 {
            nodes.push(Node::leaf(boxes[n - 1], n as u32 - 1, 1));
        }
    }
    Bvh {
        nodes,
        prim_indices: (0..n as u32).collect(),
    }
}

/// Maximum leaf depth (root = 0), iteratively.
fn depth(bvh: &Bvh) -> usize {
    let mut max = 0;
    let mut stack = vec![(0usize, 0usize)];
    while let Some((n, d)) = stack.pop() {
        max = max.max(d);
        let node = &bvh.nodes[n];
        if !node.is_leaf() {
            stack.push((node.first as usize, d + 1));
            stack.push((node.first as usize + 1, d + 1));
        }
    }
    max
}
