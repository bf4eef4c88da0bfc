//! The "Compressed layouts (Kilian 2021)" section on synthetic rows: cases and labels, family
//! curves, the Pareto front on a hand-made example, findings that agree and differ, and no panic on
//! rows with missing layout fields or a single layout.
use bvhlab_pipeline::ResultRow;
use bvhlab_report::layouts::{self, Metric, Timed, Verdict};
use bvhlab_report::write_report;

struct L {
    layout: &'static str,
    params: &'static str,
    topo: f64,
    total: f64,
    slowdown: f64,
    extra_tests: f64,
}

fn row(scene: &str, l: &L) -> ResultRow {
    let tris = 10_000u64;
    ResultRow {
        experiment: "t".into(),
        scene: format!("gen:{scene}"),
        scene_name: scene.into(),
        triangles: tris,
        builder: "binned-sah".into(),
        build_params: "bins=16,leaf=2".into(),
        compact: "none".into(),
        method: format!("binned-sah bins=16 [{} {}]", l.layout, l.params),
        c_t: 3.0,
        c_i: 2.0,
        sah_cost: 100.0,
        inner_nodes: tris / 2 - 1,
        leaves: tris / 2,
        valid: true,
        rays_kind: Some("random:1000".into()),
        rays: Some(1000),
        trace_seconds: Some(0.1 * l.slowdown),
        intersections_per_ray: Some(10.0 + l.extra_tests),
        traversal_steps_per_ray: Some(30.0),
        layout: Some(l.layout.into()),
        layout_params: Some(l.params.into()),
        topology_bytes: Some((l.topo * tris as f64) as u64),
        total_bytes: Some((l.total * tris as f64) as u64),
        topology_bytes_per_triangle: Some(l.topo),
        total_bytes_per_triangle: Some(l.total),
        topology_bits_per_node: Some(l.topo * 8.0 / 2.0),
        layout_nodes: Some(2 * tris),
        chunks: if l.params.contains("chunk_bytes") { Some(100) } else { Some(0) },
        chunk_fill: if l.params.contains("chunk_bytes") { Some(0.2) } else { Some(0.0) },
        prim_refs: Some(if l.layout.starts_with("octree") { 3 * tris } else { tris }),
        layout_seconds: Some(0.01),
        layout_sah_cost: Some(105.0),
        extra_box_hits_per_ray: Some(l.extra_tests / 2.0),
        extra_tests_per_ray: Some(l.extra_tests),
        bvh2_trace_seconds: Some(0.1),
        slowdown: Some(l.slowdown),
        // Measured rows: 5 runs within 1 %.
        slowdown_spread: Some(0.01),
        trace_seconds_spread: Some(0.01),
        ..Default::default()
    }
}

const fn l(layout: &'static str, params: &'static str, topo: f64, slowdown: f64, extra_tests: f64) -> L {
    L { layout, params, topo, total: topo + 8.0, slowdown, extra_tests }
}

/// Kilian's picture: smaller chunks smaller and faster, chunk frame faster, parent frame fewer
/// tests, octree_1bit close to octree, qbvh_chunks slower than bvh2 but within 1.5x.
const AGREEING: &[L] = &[
    l("bvh2", "", 64.0, 1.0, 0.0),
    l("qbvh_chunks", "bits=8,chunk_bytes=64,frame=chunk", 20.0, 1.3, 0.5),
    l("qbvh_chunks", "bits=8,chunk_bytes=128,frame=chunk", 30.0, 1.5, 0.5),
    l("qbvh_chunks", "bits=8,chunk_bytes=64,frame=parent", 20.0, 1.4, 0.3),
    l("qbvh_chunks", "bits=8,chunk_bytes=128,frame=parent", 30.0, 1.6, 0.3),
    l("octree", "max_depth=24,mult_threshold=2.0,prim_threshold=20", 8.0, 2.0, 0.0),
    l("octree_1bit", "chunk_bytes=16,fill=bfs,max_depth=24,mult_threshold=2.0,prim_threshold=20", 0.5, 2.1, 0.0),
    l("octree_1bit", "chunk_bytes=32,fill=bfs,max_depth=24,mult_threshold=2.0,prim_threshold=20", 0.6, 2.2, 0.0),
];

/// Contradicts claims 1a/1b for octree_1bit (16 B bigger and slower than 32 B) and 2a (parent faster).
const DIFFERING: &[L] = &[
    l("bvh2", "", 64.0, 1.0, 0.0),
    l("qbvh_chunks", "bits=8,chunk_bytes=64,frame=chunk", 20.0, 1.6, 0.5),
    l("qbvh_chunks", "bits=8,chunk_bytes=64,frame=parent", 20.0, 1.2, 0.3),
    l("octree", "max_depth=24,mult_threshold=2.0,prim_threshold=20", 8.0, 2.0, 0.0),
    l("octree_1bit", "chunk_bytes=16,fill=bfs,max_depth=24,mult_threshold=2.0,prim_threshold=20", 0.9, 2.5, 0.0),
    l("octree_1bit", "chunk_bytes=32,fill=bfs,max_depth=24,mult_threshold=2.0,prim_threshold=20", 0.6, 2.2, 0.0),
];

fn rows(scene: &str, ls: &[L]) -> Vec<ResultRow> {
    ls.iter().map(|x| row(scene, x)).collect()
}

fn verdicts(rows: &[ResultRow], id: &str) -> Vec<(String, Verdict)> {
    layouts::findings(rows)
        .into_iter()
        .filter(|f| f.id == id)
        .flat_map(|f| f.cases.into_iter().map(|c| (c.case, c.verdict)))
        .collect()
}

#[test]
fn labels_and_families() {
    let rs = rows("a", AGREEING);
    let cs = layouts::cases(&rs);
    assert_eq!(cs.len(), 1);
    let labels: Vec<&str> = cs[0].points.iter().map(|p| p.label.as_str()).collect();
    // Only the parameters that vary within a layout appear (bits=8 everywhere: not shown).
    assert_eq!(
        labels,
        [
            "bvh2",
            "qbvh_chunks 64B frame=chunk",
            "qbvh_chunks 128B frame=chunk",
            "qbvh_chunks 64B frame=parent",
            "qbvh_chunks 128B frame=parent",
            "octree",
            "octree_1bit 16B",
            "octree_1bit 32B"
        ]
    );
    let fams: Vec<(String, usize)> =
        layouts::families(&cs[0]).into_iter().map(|f| (f.label, f.members.len())).collect();
    assert!(fams.contains(&("bvh2".into(), 1)), "{fams:?}");
    assert!(fams.contains(&("qbvh_chunks frame=chunk (by chunk size)".into(), 2)), "{fams:?}");
    assert!(fams.contains(&("qbvh_chunks frame=parent (by chunk size)".into(), 2)), "{fams:?}");
    assert!(fams.contains(&("qbvh_chunks 64B (by frame)".into(), 2)), "{fams:?}");
    assert!(fams.contains(&("octree_1bit (by chunk size)".into(), 2)), "{fams:?}");
    assert!(fams.contains(&("octree".into(), 1)), "{fams:?}");
}

#[test]
fn pareto_front_hand_made() {
    let rs = rows("a", AGREEING);
    let cs = layouts::cases(&rs);
    // Topology bytes vs slowdown: 128 B qbvh_chunks and parent frames are dominated by qbvh_chunks 64B chunk
    // (same or fewer bytes, faster); octree_1bit 32B by octree_1bit 16B.
    assert_eq!(
        layouts::front(&cs[0], Metric::TopologyBytesPerTriangle, Metric::Slowdown),
        ["octree_1bit 16B", "octree", "qbvh_chunks 64B frame=chunk", "bvh2"]
    );
    // Against extra tests: bvh2/octree/octree_1bit have 0, so the smallest of them (octree_1bit 16B)
    // dominates everything else.
    assert_eq!(layouts::front(&cs[0], Metric::TopologyBytesPerTriangle, Metric::ExtraTestsPerRay), ["octree_1bit 16B"]);
}

#[test]
fn findings_agree_and_differ() {
    let mut rs = rows("good", AGREEING);
    rs.extend(rows("bad", DIFFERING));
    let v = |id| verdicts(&rs, id);
    assert_eq!(v("1a"), [("good".to_string(), Verdict::Agrees), ("bad".to_string(), Verdict::Differs)]);
    assert_eq!(v("1b"), [("good".to_string(), Verdict::Agrees), ("bad".to_string(), Verdict::Differs)]);
    // qbvh_chunks chunk sizes: one case per frame on the agreeing scene, none on the other (one size).
    assert_eq!(
        v("1c"),
        [("good (frame=chunk)".to_string(), Verdict::Agrees), ("good (frame=parent)".to_string(), Verdict::Agrees)]
    );
    assert_eq!(v("1d").len(), 2);
    let frame_fast = v("2a");
    assert_eq!(frame_fast.iter().filter(|c| c.1 == Verdict::Agrees).count(), 2, "{frame_fast:?}");
    assert_eq!(frame_fast.iter().filter(|c| c.1 == Verdict::Differs).count(), 1, "{frame_fast:?}");
    assert!(frame_fast.iter().any(|c| c.0.starts_with("bad") && c.1 == Verdict::Differs));
    // Parent frame: fewer tests everywhere.
    assert!(v("2b").iter().all(|c| c.1 == Verdict::Agrees));
    // octree_1bit / octree: 2.1/2.0 = 1.05 agrees, 2.5/2.0 = 1.25 differs.
    assert_eq!(v("3"), [("good".to_string(), Verdict::Agrees), ("bad".to_string(), Verdict::Differs)]);
    // qbvh_chunks 64B/chunk/8bit slower than bvh2 in both; best within 1.5x in both (bad: parent 1.2).
    assert!(v("4a").iter().all(|c| c.1 == Verdict::Agrees));
    assert!(v("4b").iter().all(|c| c.1 == Verdict::Agrees));
    // Topology 20/64 = 0.31 <= 0.5.
    assert!(v("5").iter().all(|c| c.1 == Verdict::Agrees));
    // octree_1bit 16B bits/node = topo * 4: 2.0 (agrees) and 3.6 (differs).
    assert_eq!(
        v("6"),
        [("good (octree_1bit 16B)".to_string(), Verdict::Agrees), ("bad (octree_1bit 16B)".to_string(), Verdict::Differs)]
    );

    // The page says so.
    let dir = tempfile::tempdir().unwrap();
    let index = write_report(dir.path(), "layouts", &rs, None).unwrap();
    let html = std::fs::read_to_string(index).unwrap();
    assert!(html.contains("Compressed layouts (Kilian 2021)"));
    assert!(html.contains("<td>1a</td><td>bad</td><td><span class=\"warn\">differs</span></td>"), "{html}");
    assert!(html.contains("<td>1a</td><td>good</td><td><span>agrees</span></td>"));
    assert!(html.contains("Kilian (stated)"));
    assert!(html.contains("58.67 (5.2.1, best case)"), "qbvh_chunks 64 B stated bits per node");
    assert!(html.contains("2 (4.2.2, best case)"), "octree_1bit 16 B stated bits per node");
}

#[test]
fn missing_fields_single_layout_and_auto() {
    // Only a layout name: every number missing.
    let bare = ResultRow {
        experiment: "t".into(),
        scene: "gen:x".into(),
        scene_name: "x".into(),
        method: "m".into(),
        layout: Some("qbvh_chunks".into()),
        ..Default::default()
    };
    // A single layout with numbers.
    let single = row("y", &AGREEING[0]);
    // An auto row.
    let mut auto = row("y", &AGREEING[1]);
    auto.layout_choice = Some("qbvh_chunks 64B: smallest within max_slowdown 1.5 (1.3x)".into());
    let rs = vec![bare, single, auto];
    assert!(layouts::findings(&rs).iter().all(|f| f.cases.is_empty()));
    let cs = layouts::cases(&rs);
    assert_eq!(cs.len(), 2);
    assert_eq!(cs[1].points.len(), 1);
    assert_eq!(cs[1].auto.len(), 1);
    assert!(layouts::front(&cs[0], Metric::TotalBytesPerTriangle, Metric::TraceSeconds).is_empty());
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(write_report(dir.path(), "layouts", &rs, None).unwrap()).unwrap();
    assert!(html.contains("Compressed layouts (Kilian 2021)"));
    assert!(html.contains("smallest within max_slowdown 1.5"));
    assert!(html.contains("no data for this claim"));

    // Without layout rows there is no section.
    let mut plain = row("z", &AGREEING[0]);
    plain.layout = None;
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(write_report(dir.path(), "plain", &[plain], None).unwrap()).unwrap();
    assert!(!html.contains("Compressed layouts"));
}

/// Issue 15: an auto choice above its limit in its own row, or cut short by the budget, is
/// flagged in the layouts section (it used to be listed like any other).
#[test]
fn auto_over_limit_and_budget_cut_are_flagged() {
    let mut ok = row("y", &AGREEING[1]);
    ok.layout_choice = Some("qbvh_chunks: within".into());
    ok.auto_max_slowdown = Some(1.5);
    ok.auto_budget_cut = Some(false);
    ok.auto_over_limit = Some(false);
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(write_report(dir.path(), "l", &[ok.clone()], None).unwrap()).unwrap();
    assert!(!html.contains("exceed their max_slowdown"), "no warning without a flagged row");
    assert!(!html.contains("ran out of their time budget"));
    let mut over = row("z", &AGREEING[1]);
    over.slowdown = Some(1.8);
    over.layout_choice = Some("qbvh_chunks: within on the search's rays".into());
    over.auto_max_slowdown = Some(1.5);
    over.auto_budget_cut = Some(true);
    over.auto_over_limit = Some(true);
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(write_report(dir.path(), "l", &[ok, over], None).unwrap()).unwrap();
    assert!(html.contains("Warning: 1 layout=auto choice(s) exceed their max_slowdown"), "{html}");
    assert!(html.contains("at slowdown 1.8") && html.contains("max_slowdown 1.5"), "{html}");
    assert!(html.contains("1 layout=auto search(es) ran out of their time budget"), "{html}");
    assert!(html.contains("over limit</b>"), "{html}");
}

/// Issue 16, the noise rule: a time verdict only beyond max(spread_a + spread_b, TIE_PERCENT).
#[test]
fn noise_rule() {
    let t = |value: f64, spread: f64| Timed { value, spread: Some(spread) };
    // 10 % apart: resolved with 2 % + 3 % of noise, not with 6 % + 5 %.
    assert_eq!(layouts::beyond_noise(t(1.1, 0.02), t(1.0, 0.03)), Some(1.1 / 1.0));
    assert_eq!(layouts::beyond_noise(t(1.1, 0.06), t(1.0, 0.05)), None);
    assert_eq!(layouts::faster(t(1.0, 0.02), t(1.1, 0.03)), Verdict::Agrees);
    assert_eq!(layouts::faster(t(1.1, 0.02), t(1.0, 0.03)), Verdict::Differs);
    assert_eq!(layouts::faster(t(1.1, 0.06), t(1.0, 0.05)), Verdict::WithinNoise);
    // The floor: 1.5 % apart with no measured spread at all is within noise.
    assert_eq!(layouts::faster(t(1.0, 0.0), t(1.015, 0.0)), Verdict::WithinNoise);
    // One run (no spread): noise not measured, nothing resolved however far apart.
    let one = Timed { value: 5.0, spread: None };
    assert_eq!(layouts::faster(t(1.0, 0.01), one), Verdict::WithinNoise);
    assert_eq!(layouts::at_most(one, 1.5), Verdict::WithinNoise);
    // Limits are exact: 1.71 +- 20 % against 1.5 is within noise, 1.71 +- 5 % is over.
    assert_eq!(layouts::at_most(t(1.71, 0.2), 1.5), Verdict::WithinNoise);
    assert_eq!(layouts::at_most(t(1.71, 0.05), 1.5), Verdict::Differs);
    assert_eq!(layouts::at_most(t(1.2, 0.05), 1.5), Verdict::Agrees);
    // Ratios carry the sum of the spreads.
    assert_eq!(t(2.0, 0.01).ratio(t(1.0, 0.02)), t(2.0, 0.03));

    // In the findings: the same rows with a wide spread read "within noise", never agree/differ.
    let mut rs = rows("noisy", DIFFERING);
    for r in &mut rs {
        r.slowdown_spread = Some(0.7);
    }
    for id in ["1b", "2a", "3", "4a", "4b"] {
        let v = verdicts(&rs, id);
        assert!(!v.is_empty() && v.iter().all(|c| c.1 == Verdict::WithinNoise), "{id}: {v:?}");
    }
    // Memory claims are not timings: unchanged.
    assert_eq!(verdicts(&rs, "1a"), [("noisy".to_string(), Verdict::Differs)]);
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(write_report(dir.path(), "l", &rs, None).unwrap()).unwrap();
    assert!(html.contains("<th>within noise</th>") && html.contains("<th>not applicable</th>"), "{html}");
    assert!(html.contains("<span>within noise</span>"), "{html}");
}

/// Issue 16, bvh2 against itself: the pipeline makes it exactly 1 (tests/layout_stage.rs); were a
/// self-comparison ever timed twice, a noisy ratio (the 5.1 once seen) must not read as a
/// slowdown when its spread covers it.
#[test]
fn self_comparison_is_not_a_slowdown() {
    let noisy = Timed { value: 5.1, spread: Some(4.5) };
    assert_eq!(layouts::beyond_noise(noisy, Timed::exact(1.0)), None);
    assert_eq!(layouts::at_most(noisy, 1.5), Verdict::WithinNoise);
    assert_eq!(layouts::at_most(Timed::exact(1.0), 1.0), Verdict::WithinNoise);
}

/// Issue 16, the degenerate rule: a one-node structure (a collapsed octree with 0 bits per node)
/// or an empty scene is "not applicable", not an agreement with "<= 2 bits per node".
#[test]
fn degenerate_cases_are_not_applicable() {
    let mut rs = rows("one", AGREEING);
    for r in rs.iter_mut().filter(|r| r.layout.as_deref().is_some_and(|l| l.starts_with("octree"))) {
        r.layout_nodes = Some(1);
        r.topology_bits_per_node = Some(0.0);
        r.topology_bytes = Some(0);
        r.topology_bytes_per_triangle = Some(0.0);
    }
    assert!(layouts::degenerate(&rs[5]) && !layouts::degenerate(&rs[1]));
    for id in ["1a", "1b", "3", "6"] {
        let v = verdicts(&rs, id);
        assert!(!v.is_empty() && v.iter().all(|c| c.1 == Verdict::NotApplicable), "{id}: {v:?}");
    }
    // The qbvh_chunks claims are not about the octree: unchanged.
    assert!(verdicts(&rs, "4a").iter().all(|c| c.1 == Verdict::Agrees));
    // An empty scene: nothing applies.
    let mut empty = rows("empty", AGREEING);
    for r in &mut empty {
        r.triangles = 0;
        r.inner_nodes = 0;
        r.leaves = 1;
    }
    assert!(empty.iter().all(layouts::degenerate));
    for f in layouts::findings(&empty) {
        assert!(f.cases.iter().all(|c| c.verdict == Verdict::NotApplicable), "{}: {:?}", f.id, f.cases);
    }
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(write_report(dir.path(), "l", &rs, None).unwrap()).unwrap();
    assert!(html.contains("<span>not applicable</span>") && html.contains("degenerate: 10000 triangles"), "{html}");
}
