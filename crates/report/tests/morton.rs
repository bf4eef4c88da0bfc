//! Report additions of the Morton family (issue 3) on synthetic rows: scene-parameter sweep plots
//! with measured and predicted drops (Riemersma 2024 eq. 13/14), flags, thesis tables 10 and 25,
//! total build time in the Pareto chart, invalid rows.
use bvhlab_pipeline::ResultRow;
use bvhlab_report::analysis::{self, Flag};
use bvhlab_report::reference;
use bvhlab_report::write_report;
use std::path::Path;

fn base(scene: &str, builder: &str, params: &str) -> ResultRow {
    ResultRow {
        experiment: "t".into(),
        scene: scene.into(),
        scene_name: scene.trim_start_matches("gen:").into(),
        triangles: 20_001,
        builder: builder.into(),
        build_params: params.into(),
        compact: "none".into(),
        method: format!("{builder} {params}"),
        c_t: 3.0,
        c_i: 2.0,
        sah_cost: 50.0,
        valid: true,
        build_seconds: 0.01,
        total_build_seconds: 0.01,
        ..Default::default()
    }
}

fn coded(scene: &str, builder: &str, params: &str, encoder: &str, eparams: &str) -> ResultRow {
    let mut r = base(scene, builder, params);
    r.encoder = Some(encoder.into());
    r.encode_params = Some(eparams.into());
    r.method = format!("{builder} {params} \u{b7} {encoder} {eparams}");
    r.encode_seconds = Some(0.002);
    r.total_build_seconds = 0.012;
    r.code_bits = Some(30);
    r
}

const PLAIN: &str = "bits=10,bounds=scene,grid_bits=0";
const GRID9: &str = "bits=10,bounds=scene,grid_bits=9,grid_frame=cell";
const EMC: &str = "bounds=scene,grid_bits=0";
const EMC9: &str = "bounds=scene,grid_bits=9,grid_frame=cell";

/// Focus cost of a method at e: 100 up to (excluding) its drop, then 100 * 2^(e - drop + 1).
fn cost_at(e: u32, drop: Option<u32>) -> f64 {
    match drop {
        Some(d) if e >= d => 100.0 * 2f64.powi((e - d + 1) as i32),
        _ => 100.0 + 0.1 * e as f64, // slow growth, below the 10 % threshold
    }
}

/// gen:outlier e = 0, 2, ..., 30 with lbvh and ploc on four encoders, plus binned-sah; the city.
/// Synthetic drops: plain Morton at e = 10 (ploc) / 8 (lbvh), its grid-9 variant at 14 / 12; EMC at
/// 20, its grid-9 variant never within the range.
fn outlier_rows() -> Vec<ResultRow> {
    let mut rows = Vec::new();
    for e in (0..=30).step_by(2) {
        let scene = format!("gen:outlier:n=20000,e={e}");
        for (b, p, shift) in [("ploc", "radius=10", 0u32), ("lbvh", "", 2)] {
            for (enc, ep, drop) in [
                ("morton", PLAIN, Some(10 - shift)),
                ("morton", GRID9, Some(14 - shift)),
                ("emc64-var", EMC, Some(20)),
                ("emc64-var", EMC9, None),
            ] {
                let mut r = coded(&scene, b, p, enc, ep);
                r.focus_sah_cost = Some(cost_at(e, drop));
                r.focus_triangles = Some(20_000);
                r.sah_cost = 1e6; // whole-scene cost: dominated by the outlier, never used
                r.duplicate_code_fraction = Some(if drop.is_some_and(|d| e >= d) {
                    0.9
                } else {
                    0.01
                });
                r.rays_kind = Some("primary:256x256".into());
                r.traversal_steps_per_ray = Some(r.focus_sah_cost.unwrap() / 4.0);
                r.intersections_per_ray = Some(3.0);
                rows.push(r);
            }
        }
        let mut r = base(&scene, "binned-sah", "bins=16,leaf=2");
        r.focus_sah_cost = Some(90.0);
        r.rays_kind = Some("primary:256x256".into());
        r.traversal_steps_per_ray = Some(20.0);
        rows.push(r);
    }
    rows
}

#[test]
fn predicted_shift_numbers() {
    // Riemersma 3.2.4: mipping with 9 grid bits moves a single-axis drop by 9, a diagonal one by 3.
    assert_eq!(analysis::move_d(512.0, 1.0), 9.0);
    assert_eq!(analysis::move_d(512.0, 3.0), 3.0);
    assert_eq!(analysis::move_d(128.0, 1.0), 7.0);
    assert_eq!(analysis::predicted_drop(10.0, 9, 3.0), 13.0);
    assert_eq!(analysis::predicted_drop(20.0, 12, 3.0), 24.0);
    assert_eq!(analysis::predicted_drop(4.0, 0, 3.0), 4.0);
    // Threshold: strictly more than 10 % above the first value.
    assert_eq!(
        analysis::measured_drop(&[(0.0, 100.0), (2.0, 110.0), (4.0, 110.1)]),
        Some(4.0)
    );
    assert_eq!(analysis::measured_drop(&[(0.0, 100.0), (2.0, 105.0)]), None);
    assert_eq!(analysis::measured_drop(&[(0.0, 100.0)]), None);
    assert_eq!(analysis::measured_drop(&[]), None);
}

#[test]
fn sweeps_and_drops() {
    let mut rows = outlier_rows();
    rows.push(base("gen:city", "lbvh", ""));
    // A scene of another generator with one value only is no sweep; neither are file scenes.
    rows.push(base("gen:sphere:n=100", "lbvh", ""));
    rows.push(base("../shared/scenes/x.obj.gz", "lbvh", ""));
    let sweeps = analysis::find_sweeps(&rows);
    assert_eq!(sweeps.len(), 1, "{sweeps:?}");
    let sw = &sweeps[0];
    assert_eq!(
        (sw.generator.as_str(), sw.param.as_str(), sw.fixed.as_str()),
        ("outlier", "e", "n=20000")
    );
    assert_eq!(sw.points.len(), 16);
    assert_eq!(sw.points[5], (10.0, "gen:outlier:n=20000,e=10".to_string()));
    assert_eq!(analysis::shift_model(sw), Some(3.0));

    let series = analysis::sweep_series(sw, &rows, &analysis::SWEEP_METRICS[0]);
    assert_eq!(series.len(), 9, "8 coded methods + binned-sah");
    let drops = analysis::drops(&series, 3.0);
    assert_eq!(drops.len(), 8, "only methods with an encoder");
    let find = |b: &str, ep: &str| {
        let enc = if ep.starts_with("bits") {
            "morton"
        } else {
            "emc64-var"
        };
        let m = format!("{enc} {ep}");
        drops
            .iter()
            .find(|d| d.builder == b && d.method.ends_with(&m))
            .unwrap_or_else(|| panic!("{b} {m}: {drops:?}"))
    };
    let p = find("ploc radius=10", GRID9);
    assert_eq!(p.measured, Some(14.0));
    assert_eq!(p.reference_drop, Some(10.0));
    assert_eq!(p.predicted, Some(13.0), "10 + log2(2^9)/3");
    assert!(p.reference.as_deref().unwrap().ends_with(PLAIN));
    let l = find("lbvh", GRID9);
    assert_eq!(
        (l.measured, l.reference_drop, l.predicted),
        (Some(12.0), Some(8.0), Some(11.0))
    );
    let plain = find("ploc radius=10", PLAIN);
    assert_eq!(
        (plain.measured, plain.predicted, plain.reference.clone()),
        (Some(10.0), None, None)
    );
    let emc9 = find("ploc radius=10", EMC9);
    assert_eq!(
        (emc9.measured, emc9.reference_drop, emc9.predicted),
        (None, Some(20.0), Some(23.0))
    );

    let tmp = tempfile::tempdir().unwrap();
    let out = std::env::var_os("BVHLAB_REPORT_KEEP_MORTON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| tmp.path().join("r"));
    let index = write_report(&out, "outliers", &rows, None).unwrap();
    let html = std::fs::read_to_string(index).unwrap();
    assert!(!html.contains("Problems while making"), "{html}");
    for stem in [
        "sweep_outlier_e_focus_sah_cost",
        "sweep_outlier_e_steps_primary",
        "sweep_outlier_e_duplicate_code_fraction",
    ] {
        let png = std::fs::read(out.join(format!("plots/{stem}.png")))
            .unwrap_or_else(|e| panic!("{stem}: {e}"));
        assert_eq!(&png[..4], b"\x89PNG");
        let svg = std::fs::read_to_string(out.join(format!("plots/{stem}.svg"))).unwrap();
        assert!(svg.contains("<svg"));
        assert!(
            html.contains(&format!("plots/{stem}.png")),
            "{stem} in index.html"
        );
    }
    // With a focus cost, the whole-scene cost (here 1e6 for every method) is not swept.
    assert!(!out.join("plots/sweep_outlier_e_sah_cost.png").exists());
    let svg =
        std::fs::read_to_string(out.join("plots/sweep_outlier_e_focus_sah_cost.svg")).unwrap();
    assert!(
        svg.contains("predicted 13"),
        "predicted marker label in the plot"
    );
    assert!(svg.contains("binned-sah"), "reference curve in the legend");

    // The drop table: measured vs predicted, with the threshold stated.
    let sec = &html[html.find("id=\"sweeps\"").unwrap()..html.find("id=\"flags\"").unwrap()];
    assert!(sec.contains("more than 10%"), "threshold stated");
    assert!(sec.contains("log2(f)/d"));
    let row = sec
        .split("<tr>")
        .find(|r| r.contains("ploc radius=10") && r.contains(GRID9))
        .expect("ploc grid row");
    // measured 14, e_drop 10, move 3, predicted 13, difference +1.
    let cells: Vec<&str> = row
        .split("<td")
        .skip(1)
        .map(|c| &c[c.find('>').unwrap() + 1..c.find("</td>").unwrap()])
        .collect();
    assert_eq!(
        &cells[2..],
        &["9", "14", cells[4], "10", "3", "13", "+1"],
        "{cells:?}"
    );
    assert!(sec.contains("none up to e = 30"), "EMC grid never drops");
}

fn flag_set(flags: &[Flag]) -> Vec<(String, &'static str, String)> {
    flags
        .iter()
        .map(|f| (f.scene_name.clone(), f.metric, f.method.clone()))
        .collect()
}

#[test]
fn flags_computed() {
    let mut rows = Vec::new();
    // Focus scene: whole-scene costs would flag the wrong method.
    for (m, focus, whole) in [
        ("a", 10.0, 1000.0),
        ("b", 15.0, 10.0),
        ("c", 15.01, 10.0),
        ("d", 40.0, 10.0),
    ] {
        let mut r = base("gen:outlier:e=20", m, "");
        r.focus_sah_cost = Some(focus);
        r.sah_cost = whole;
        rows.push(r.clone());
        // A second ray set of the same chain must not be listed twice.
        r.rays_kind = Some("shadow".into());
        rows.push(r);
    }
    // Plain scene: sah_cost. An invalid chain with the lowest cost is not the best, but is flagged
    // when above the ratio; a NaN cost is always flagged.
    for (m, cost, valid) in [
        ("a", 100.0, true),
        ("b", 150.0, true),
        ("c", 151.0, true),
        ("x", 10.0, false),
        ("y", 200.0, false),
        ("n", f64::NAN, true),
    ] {
        let mut r = base("gen:sphere", m, "");
        r.sah_cost = cost;
        r.valid = valid;
        rows.push(r);
    }
    let flags = analysis::flags(&rows);
    assert_eq!(
        flag_set(&flags),
        vec![
            ("outlier:e=20".into(), "focus_sah_cost", "c ".into()),
            ("outlier:e=20".into(), "focus_sah_cost", "d ".into()),
            ("sphere".into(), "sah_cost", "c ".into()),
            ("sphere".into(), "sah_cost", "y ".into()),
            ("sphere".into(), "sah_cost", "n ".into()),
        ]
    );
    assert_eq!(flags[1].ratio, 4.0);
    assert_eq!(flags[1].best_method, "a ");
    assert_eq!(flags[2].best, 100.0, "the invalid x (10) is not the best");
    assert!(!flags[3].valid);
    assert!(flags[4].ratio.is_nan());

    let tmp = tempfile::tempdir().unwrap();
    let html =
        std::fs::read_to_string(write_report(tmp.path(), "flags", &rows, None).unwrap()).unwrap();
    let sec = &html[html.find("id=\"flags\"").unwrap()..html.find("id=\"heatmaps\"").unwrap()];
    assert!(sec.contains("<td>focus_sah_cost</td><td>d </td>"), "{sec}");
    assert!(sec.contains("<td class=\"n\">4x</td>"));
    assert!(
        sec.contains("<tr class=\"invalid\"><td>sphere</td><td>sah_cost</td><td>y </td>"),
        "invalid flag is red"
    );
    // Invalid rows stand out: a red box at the top listing each invalid chain, linked from the nav.
    let top = &html[..html.find("id=\"pareto\"").unwrap()];
    assert!(
        top.contains("class=\"invalid-box\"") && top.contains("2 invalid results"),
        "{top}"
    );
    assert!(top.contains("href=\"#invalid\""));
    assert!(top.contains("<tr class=\"invalid\"><td>sphere</td><td>x </td>"));
}

#[test]
fn no_flags_no_invalid_box() {
    let rows = vec![base("gen:sphere", "a", ""), base("gen:sphere", "b", "")];
    let tmp = tempfile::tempdir().unwrap();
    let html =
        std::fs::read_to_string(write_report(tmp.path(), "ok", &rows, None).unwrap()).unwrap();
    assert!(!html.contains("class=\"invalid-box\"") && !html.contains("#invalid"));
    assert!(html.contains("No method is flagged"));
    assert!(html.contains("No generated scenes differing in one numeric parameter"));
}

#[test]
fn pareto_charges_encode_time() {
    let mut r = coded("gen:sphere", "ploc", "radius=10", "morton", PLAIN);
    r.build_seconds = 0.010;
    r.encode_seconds = Some(0.004);
    r.total_build_seconds = 0.014;
    r.compact_seconds = 0.0;
    assert_eq!(analysis::total_build_seconds(&r), 0.014);
    // A top-down chain with a separate compaction stage pays for it too.
    let mut t = base("gen:sphere", "binned-sah", "bins=16");
    t.build_seconds = 0.02;
    t.total_build_seconds = 0.02;
    t.compact_seconds = 0.005;
    assert_eq!(analysis::total_build_seconds(&t), 0.025);
    // Rows from before total_build_seconds existed (0) fall back to encode + build.
    let mut old = r.clone();
    old.total_build_seconds = 0.0;
    assert_eq!(analysis::total_build_seconds(&old), 0.014);

    let tmp = tempfile::tempdir().unwrap();
    write_report(tmp.path(), "p", &[r, t], None).unwrap();
    let svg = std::fs::read_to_string(tmp.path().join("plots/pareto_sphere.svg")).unwrap();
    assert!(
        svg.contains("encode + build + compact time"),
        "x axis is the total construction time"
    );
}

fn reference_dir() -> Option<&'static Path> {
    let p = Path::new("/work/shared/reference");
    (p.join("frantal_t10_sah_cost.tsv").exists() && p.join(reference::EMC_TABLE).exists())
        .then_some(p)
}

/// Dragon rows as the pipeline writes them for frantal-morton.toml.
fn dragon(
    builder: &str,
    params: &str,
    encoder: &str,
    eparams: &str,
    cost: f64,
    total: f64,
) -> ResultRow {
    let mut r = coded(
        "/work/shared/scenes/stanford_dragon.obj.gz",
        builder,
        params,
        encoder,
        eparams,
    );
    r.scene_name = "stanford_dragon".into();
    r.triangles = 871_414;
    r.sah_cost = cost;
    r.total_build_seconds = total;
    r
}

#[test]
fn thesis_tables_10_and_25() {
    let Some(dir) = reference_dir() else {
        eprintln!("no reference tables: skipped");
        return;
    };
    let rows = vec![
        // AHQ (thesis 160.0 / table 25: cost 99.8 %, build 113.8 %).
        dragon(
            "aac",
            "delta=20,epsilon=0.1",
            "morton",
            "bits=auto:aac,bounds=scene,grid_bits=0",
            163.0,
            0.80,
        ),
        dragon("aac", "delta=20,epsilon=0.1", "emc64-var", EMC, 158.4, 0.90),
        // ALQ (158.4): 10 % off, not within 3 %.
        dragon(
            "aac",
            "delta=4,epsilon=0.2",
            "morton",
            "bits=auto:aac,bounds=scene,grid_bits=0",
            174.24,
            0.5,
        ),
        // PL1 (154.0); a bits=10 and a grid row of the same builder must not match PL1.
        dragon(
            "ploc",
            "radius=10",
            "morton",
            "bits=10,bounds=scene,grid_bits=0",
            999.0,
            0.1,
        ),
        dragon(
            "ploc",
            "radius=10",
            "morton",
            "bits=auto:ploc,bounds=scene,grid_bits=9",
            998.0,
            0.1,
        ),
        dragon(
            "ploc",
            "radius=10",
            "morton",
            "bits=auto:ploc,bounds=scene,grid_bits=0",
            154.0,
            1.0,
        ),
        // PL2 emc row without its morton row: no ratio.
        dragon("ploc", "radius=25", "emc64-var", EMC, 150.0, 1.0),
    ];
    let rep = reference::compare(dir, &rows).unwrap();
    let get = |metric: &str, abbrev: &str| {
        let v: Vec<_> = rep
            .comparisons
            .iter()
            .filter(|c| c.metric == metric && c.abbrev == abbrev)
            .collect();
        assert!(v.len() <= 1, "{v:?}");
        v.first().map(|c| (*c).clone())
    };
    let ahq = get("SAH cost", "AHQ").expect("AHQ compared");
    assert_eq!(
        (ahq.ours, ahq.paper, ahq.thesis_scene.as_str()),
        (163.0, 160.0, "Dragon")
    );
    assert!((ahq.diff_percent - 1.875).abs() < 1e-9);
    assert!(ahq.within());
    let alq = get("SAH cost", "ALQ").expect("ALQ compared");
    assert!((alq.diff_percent - 10.0).abs() < 1e-9 && !alq.within());
    let pl1 = get("SAH cost", "PL1").expect("PL1 compared");
    assert_eq!(pl1.ours, 154.0, "the bits=auto, no-grid row");
    assert!(get("SAH cost", "PL2").is_none(), "no morton row for PL2");
    // EMC rows never stand in for the Morton columns.
    assert!(rep
        .comparisons
        .iter()
        .filter(|c| c.metric == "SAH cost")
        .all(|c| !c.method.contains("emc64")));

    let cost = get(reference::EMC_COST_LABEL, "AHQ").expect("table 25 cost ratio");
    assert!((cost.ours - 100.0 * 158.4 / 163.0).abs() < 1e-9);
    assert_eq!(cost.paper, 99.8);
    let build = get(reference::EMC_BUILD_LABEL, "AHQ").expect("table 25 build ratio");
    assert!((build.ours - 112.5).abs() < 1e-9, "{}", build.ours);
    assert_eq!(build.paper, 113.8);
    assert!(
        get(reference::EMC_COST_LABEL, "PL1").is_none(),
        "no emc row for PL1"
    );
    assert!(
        get(reference::EMC_COST_LABEL, "PL2").is_none(),
        "no morton row for PL2"
    );

    let tmp = tempfile::tempdir().unwrap();
    let html =
        std::fs::read_to_string(write_report(tmp.path(), "fm", &rows, Some(dir)).unwrap()).unwrap();
    let sec = &html[html.find("id=\"reference\"").unwrap()..html.find("id=\"results\"").unwrap()];
    assert!(sec.contains("within 3%"));
    let ahq_row = sec
        .split("<tr>")
        .find(|r| r.contains("<td>SAH cost</td>") && r.contains("<td>AHQ</td>"))
        .unwrap();
    assert!(
        ahq_row.contains("+1.9%") && ahq_row.contains("\u{2713}"),
        "{ahq_row}"
    );
    let alq_row = sec
        .split("<tr>")
        .find(|r| r.contains("<td>SAH cost</td>") && r.contains("<td>ALQ</td>"))
        .unwrap();
    assert!(!alq_row.contains("\u{2713}"));
    assert!(sec.contains(reference::EMC_BUILD_LABEL));
}

#[test]
fn top_down_reference_rows_still_match() {
    let Some(dir) = reference_dir() else { return };
    let mut fsw = dragon("sweep-sah", "leaf=2", "x", "", 140.0, 4.0);
    fsw.encoder = None;
    fsw.encode_params = None;
    let rep = reference::compare(dir, &[fsw.clone()]).unwrap();
    assert!(rep
        .comparisons
        .iter()
        .any(|c| c.abbrev == "FSW" && c.metric == "SAH cost"));
    // A top-down row with an encoder is not the thesis' FSW.
    fsw.encoder = Some("morton".into());
    let rep = reference::compare(dir, &[fsw]).unwrap();
    assert!(rep.comparisons.is_empty());
}

#[test]
fn pareto_uses_focus_cost_with_a_focus_box() {
    let mut a = coded("gen:outlier:e=20", "ploc", "radius=10", "morton", PLAIN);
    a.sah_cost = 1e6;
    a.focus_sah_cost = Some(120.0);
    let mut b = base("gen:outlier:e=20", "binned-sah", "bins=16");
    b.sah_cost = 2e6;
    b.focus_sah_cost = Some(80.0);
    let tmp = tempfile::tempdir().unwrap();
    let html =
        std::fs::read_to_string(write_report(tmp.path(), "p", &[a, b], None).unwrap()).unwrap();
    assert!(html.contains("build time vs focus SAH cost"), "{html}");
    let svg = std::fs::read_to_string(tmp.path().join("plots/pareto_outlier_e_20.svg")).unwrap();
    assert!(svg.contains("focus SAH cost"));
    // The SAH bars get a second panel with the focus cost.
    let bars = std::fs::read_to_string(tmp.path().join("plots/sah_outlier_e_20.svg")).unwrap();
    assert!(bars.contains("focus box: object subtree"));
}
