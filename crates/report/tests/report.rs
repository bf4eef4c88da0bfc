use bvhlab_pipeline::ResultRow;
use bvhlab_report::{frame, pareto_front, write_report};
use polars::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;

fn row(scene: &str, builder: &str, params: &str, cost: f64, secs: f64) -> ResultRow {
    let mut keys = BTreeMap::new();
    keys.insert("load".to_string(), format!("{:016x}", scene.len()));
    keys.insert("build".to_string(), format!("{builder}-{params}"));
    ResultRow {
        experiment: "t".into(),
        scene: format!("gen:{scene}"),
        scene_name: scene.into(),
        triangles: 1000,
        builder: builder.into(),
        build_params: params.into(),
        compact: "none".into(),
        method: format!("{builder} {params}"),
        c_t: 3.0,
        c_i: 2.0,
        sah_cost: cost,
        inner_sa_ratio: 10.0,
        leaf_sa_ratio: 4.0,
        refs_per_leaf: 2.0,
        inner_nodes: 499,
        leaves: 500,
        depth: 12,
        bytes: 32_000,
        bytes_per_triangle: 32.0,
        valid: true,
        bvh_hash: "abc".into(),
        build_seconds: secs,
        build_seconds_spread: Some(0.25),
        build_seconds_runs: Some(vec![secs * 0.9, secs, secs * 1.15]),
        keys,
        ..Default::default()
    }
}

fn with_rays(mut r: ResultRow, kind: &str, steps: f64, isects: f64) -> ResultRow {
    r.rays_kind = Some(kind.into());
    r.rays = Some(640_000);
    r.hits = Some(500_000);
    r.traversal_steps_per_ray = Some(steps);
    r.intersections_per_ray = Some(isects);
    r.trace_seconds = Some(0.5);
    r.trace_seconds_spread = Some(0.04);
    r.trace_seconds_runs = Some(vec![0.49, 0.5, 0.51]);
    r.mrays_per_s = Some(1.28);
    r
}

/// 2 scenes x 3 methods, the first scene also with primary and shadow ray rows; a dragon row
/// (same model as the thesis' "Dragon") and a decimated armadillo (different model).
fn synthetic(heatmap: Option<&Path>) -> Vec<ResultRow> {
    let mut rows = Vec::new();
    let methods = [("spatial-median", "leaf=2", 1.0), ("binned-sah", "bins=16,leaf=2", 1.0), ("sweep-sah", "leaf=2", 1.0)];
    for (si, scene) in ["sphere_n1000", "teapot<&>"].iter().enumerate() {
        for (mi, (b, p, _)) in methods.iter().enumerate() {
            // spatial median: fast and bad; binned: middle; sweep: slow and best.
            let cost = 120.0 - 10.0 * mi as f64 + si as f64;
            let secs = [0.001, 0.004, 0.09][mi];
            let base = row(scene, b, p, cost, secs);
            if si == 0 {
                let mut primary = with_rays(base.clone(), "primary:64x64", 20.0 - mi as f64, 3.0 - 0.2 * mi as f64);
                primary.heatmap = heatmap.map(|h| h.display().to_string());
                rows.push(primary);
                rows.push(with_rays(base, "shadow:64x64", 12.0 - mi as f64, 1.5));
            } else {
                rows.push(base);
            }
        }
    }
    let mut dragon = row("stanford_dragon", "sweep-sah", "leaf=2", 140.0, 4.0);
    dragon.scene = "/work/shared/scenes/stanford_dragon.obj.gz".into();
    dragon.triangles = 871_414;
    rows.push(dragon);
    let mut arma = row("armadillo_86k", "sweep-sah", "leaf=2", 80.0, 0.3);
    arma.scene = "/work/shared/scenes/armadillo_86k.obj.gz".into();
    arma.triangles = 86_482;
    rows.push(arma);
    rows
}

fn reference_dir() -> Option<&'static Path> {
    let p = Path::new("/work/shared/reference");
    p.join("frantal_t10_sah_cost.tsv").exists().then_some(p)
}

#[test]
fn full_report() {
    let tmp = tempfile::tempdir().unwrap();
    let heat = tmp.path().join("cache_heat.png");
    std::fs::write(&heat, b"not really a png, copied verbatim").unwrap();
    let rows = synthetic(Some(&heat));
    // BVHLAB_REPORT_KEEP=<dir> keeps the rendered report for a look.
    let out = std::env::var_os("BVHLAB_REPORT_KEEP")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| tmp.path().join("reports/exp"));
    let index = write_report(&out, "exp <1>", &rows, reference_dir()).unwrap();
    assert_eq!(index, out.join("index.html"));
    let html = std::fs::read_to_string(&index).unwrap();

    assert!(html.contains("exp &lt;1&gt;"), "experiment name is escaped");
    assert!(html.contains("teapot&lt;&amp;&gt;"), "scene names are escaped");
    assert!(!html.contains("Problems while making"), "no plot failed:\n{html}");
    for scene in ["sphere_n1000", "teapot", "stanford_dragon"] {
        let png = std::fs::read_dir(out.join("plots"))
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(&format!("pareto_{scene}")) && n.ends_with(".png"))
            .collect::<Vec<_>>();
        assert_eq!(png.len(), 1, "one Pareto plot for {scene}");
        assert!(html.contains(&format!("plots/{}", png[0])), "index shows {}", png[0]);
    }
    // Every plot file referenced exists as PNG (non-empty, PNG magic) and SVG.
    let mut n_imgs = 0;
    for part in html.split("<img src=\"").skip(1) {
        let src = &part[..part.find('"').unwrap()];
        let bytes = std::fs::read(out.join(src)).unwrap_or_else(|e| panic!("{src}: {e}"));
        if src.starts_with("plots/") {
            assert_eq!(&bytes[..4], b"\x89PNG", "{src}");
            let svg = std::fs::read_to_string(out.join(src.replace(".png", ".svg"))).unwrap();
            assert!(svg.contains("<svg"), "{src}");
            n_imgs += 1;
        }
    }
    // 4 scenes x (pareto + sah) + 2 ray sets of scene 1 + reference plots.
    assert!(n_imgs >= 10, "{n_imgs} plots");
    for section in ["Pareto", "SAH cost per method", "Traversal steps and intersections", "Heat maps", "Reference comparison", "Results table"] {
        assert!(html.contains(section), "section {section}");
    }
    // The methods used, with their papers, from the pipeline's method table.
    assert!(html.contains("<td>sweep-sah</td><td>thesis 3.3.1</td>"), "methods section");
    assert!(!html.contains("<td>ploc</td>"), "only the methods the rows use");
    assert!(html.contains("rays_sphere_n1000_primary"), "ray plot per ray set");
    assert!(html.contains("rays_sphere_n1000_shadow"));
    assert!(!html.contains("rays_teapot"), "no ray plot without ray metrics");
    // Heat map copied with a readable name.
    let heat_files: Vec<_> = std::fs::read_dir(out.join("heatmaps")).unwrap().collect();
    assert_eq!(heat_files.len(), 3, "one heat map per primary row");
    assert!(html.contains("heatmaps/sphere_n1000__binned-sah_bins_16_leaf_2__primary_64x64.png"), "{html}");
    assert!(html.contains("href=\"results.csv\"") && html.contains("href=\"results.parquet\""));
    // No absolute links or external assets.
    assert!(!html.contains("src=\"/") && !html.contains("http://") && !html.contains("https://"));

    if reference_dir().is_some() {
        // Dragon is the thesis' Dragon (871,414 triangles): SAH cost compared with FSW.
        let sec = &html[html.find("id=\"reference\"").unwrap()..html.find("id=\"results\"").unwrap()];
        assert!(sec.contains("<td>Dragon</td><td>FSW</td>"), "{sec}");
        assert!(sec.contains("reference_SAH_cost.png"));
        // The decimated armadillo is flagged, never compared.
        assert!(sec.contains("armadillo_86k: 86482 triangles") && sec.contains("different model"));
        assert!(!sec.contains("<td>armadillo_86k</td>"));
        // Generated scenes are never compared even though their names are arbitrary.
        assert!(!sec.contains("<td>sphere_n1000</td>"));
    }

    // Parquet round trip: row count, columns in ResultRow order, keys flattened, types.
    let f = std::fs::File::open(out.join("results.parquet")).unwrap();
    let df = ParquetReader::new(f).finish().unwrap();
    assert_eq!(df.height(), rows.len());
    let names: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).collect();
    assert_eq!(&names[..3], ["experiment", "scene", "scene_name"]);
    assert_eq!(names.last().unwrap(), "key_load", "keys flattened in stage order at the end");
    assert!(names.contains(&"key_build".to_string()));
    assert!(!names.contains(&"keys".to_string()));
    for col in ["traversal_steps_per_ray", "heatmap", "mrays_per_s", "rays_kind"] {
        assert!(names.contains(&col.to_string()), "{col}");
    }
    assert_eq!(df.column("sah_cost").unwrap().dtype(), &DataType::Float64);
    assert_eq!(df.column("triangles").unwrap().dtype(), &DataType::Int64);
    assert_eq!(df.column("valid").unwrap().dtype(), &DataType::Boolean);
    assert_eq!(df.column("rays_kind").unwrap().dtype(), &DataType::String);
    assert_eq!(df.column("traversal_steps_per_ray").unwrap().null_count(), rows.len() - 6);
    let cost = df.column("sah_cost").unwrap().f64().unwrap().get(0).unwrap();
    assert_eq!(cost, rows[0].sah_cost);

    // CSV: header + one line per row, same header as the parquet columns.
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), rows.len() + 1);
    assert_eq!(lines[0], names.join(","));

    // Issue 16: every timed quantity has `X_spread` (and measured ones `X_runs`) beside it, in
    // results.csv and parquet alike; spreads are numbers, runs JSON lists.
    for t in [
        "build_seconds",
        "encode_seconds",
        "optimize_seconds",
        "compact_seconds",
        "trace_seconds",
        "layout_seconds",
        "bvh2_trace_seconds",
        "slowdown",
    ] {
        for col in [format!("{t}_spread"), format!("{t}_runs")] {
            assert!(names.contains(&col), "{col} in parquet");
        }
        let at = names.iter().position(|n| n == t).unwrap();
        assert_eq!(names[at + 1], format!("{t}_spread"), "the spread right after {t}");
    }
    for col in ["total_build_seconds_spread", "mrays_per_s_spread", "auto_search_slowdown", "auto_search_slowdown_spread"] {
        assert!(names.contains(&col.to_string()), "{col}");
    }
    assert_eq!(df.column("build_seconds_spread").unwrap().dtype(), &DataType::Float64);
    assert_eq!(df.column("build_seconds_spread").unwrap().f64().unwrap().get(0), Some(0.25));
    assert_eq!(df.column("trace_seconds_spread").unwrap().null_count(), rows.len() - 6);
    let header: Vec<&str> = lines[0].split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name} in results.csv"));
    let (spread, trace_spread) = (col("build_seconds_spread"), col("trace_seconds_spread"));
    // Row 1 is a primary-ray row; quoted cells (the runs lists) hold commas.
    let mut cells: Vec<String> = vec![String::new()];
    let mut quoted = false;
    for ch in lines[1].chars() {
        match ch {
            '"' => quoted = !quoted,
            ',' if !quoted => cells.push(String::new()),
            _ => cells.last_mut().unwrap().push(ch),
        }
    }
    assert_eq!(cells.len(), header.len());
    assert_eq!(cells[spread], "0.25", "{}", lines[1]);
    assert_eq!(cells[trace_spread], "0.04", "{}", lines[1]);
    assert_eq!(cells[col("trace_seconds_runs")], "[0.49,0.5,0.51]", "runs as a JSON list: {}", lines[1]);
}

#[test]
fn empty_rows_do_not_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let index = write_report(tmp.path(), "empty", &[], reference_dir()).unwrap();
    let html = std::fs::read_to_string(index).unwrap();
    assert!(html.contains("No results"));
    let df = ParquetReader::new(std::fs::File::open(tmp.path().join("results.parquet")).unwrap())
        .finish()
        .unwrap();
    assert_eq!(df.height(), 0);
    assert!(df.width() > 10, "the schema is there even without rows");
    let csv = std::fs::read_to_string(tmp.path().join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1);
}

#[test]
fn nasty_values_do_not_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rows = vec![
        row("single", "binned-sah", "bins=16", f64::NAN, f64::INFINITY),
        row("zero_time", "binned-sah", "bins=16", 10.0, 0.0),
        row("zero_time", "sweep-sah", "", 9.0, 0.0),
        row("huge_span", "a", "", 1e9, 1e-9),
        row("huge_span", "b", "", 1.0, 1e3),
        with_rays(row("nan_rays", "a", "", 1.0, 1.0), "random:10", f64::NAN, f64::NEG_INFINITY),
    ];
    rows[0].heatmap = Some("/nonexistent/heat.png".into());
    rows[0].method = String::new();
    let index = write_report(tmp.path(), "", &rows, Some(Path::new("/nonexistent"))).unwrap();
    let html = std::fs::read_to_string(index).unwrap();
    assert!(html.contains("heat map of single"), "missing heat map reported");
    assert!(html.contains("Reference tables could not be read"));
    let df = frame::to_dataframe(&rows).unwrap();
    // serde_json has no NaN: non-finite floats become nulls.
    assert_eq!(df.column("sah_cost").unwrap().null_count(), 1);
}

#[test]
fn pareto_front_is_exposed() {
    let pts = [(0.001, 120.0), (0.004, 110.0), (0.09, 100.0), (0.1, 105.0), (0.002, 130.0)];
    assert_eq!(pareto_front(&pts), vec![0, 1, 2]);
}

/// Issue 12: rows timed on two CPU models get one Pareto plot per model, mixed rows are left out
/// of timing plots and listed; one model gives one plot per scene and a one-line note.
#[test]
fn timings_from_two_machines_are_plotted_per_machine() {
    let mk = |params: &str, cost: f64, secs: f64, machine: &str, mixed: bool| {
        let mut r = row("sphere", "binned-sah", params, cost, secs);
        r.machine = machine.into();
        r.machine_mixed = mixed;
        // A mixed row here was built on the first model and traced on the second.
        r.build_machine = machine.split(" + ").next().unwrap().into();
        r
    };
    let dir = tempfile::tempdir().unwrap();
    let single: Vec<ResultRow> = vec![mk("bins=4", 110.0, 0.01, "CPU A", false), mk("bins=16", 100.0, 0.02, "CPU A", false)];
    write_report(&dir.path().join("one"), "t", &single, None).unwrap();
    let html = std::fs::read_to_string(dir.path().join("one/index.html")).unwrap();
    assert!(html.contains("Timings measured on: CPU A."), "one model: one line");
    assert!(!html.contains("more than one CPU model"));
    let paretos = |d: &str| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir.path().join(d).join("plots"))
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().to_string())
            .filter(|n| n.starts_with("pareto_") && n.ends_with(".png"))
            .collect();
        v.sort();
        v
    };
    assert_eq!(paretos("one").len(), 1);

    let mut rows = single.clone();
    rows.push(mk("bins=8", 105.0, 0.5, "CPU B", false));
    rows.push(mk("bins=32", 99.0, 0.03, "CPU B", false));
    rows.push(mk("bins=64", 98.0, 0.04, "CPU A + CPU B", true));
    write_report(&dir.path().join("two"), "t", &rows, None).unwrap();
    let html = std::fs::read_to_string(dir.path().join("two/index.html")).unwrap();
    assert!(html.contains("Timings from more than one CPU model"), "warning box");
    assert!(html.contains("CPU A: 2 rows") && html.contains("CPU B: 2 rows"), "per-model counts");
    assert!(html.contains("1 rows have stages timed on different CPU models"), "mixed rows counted");
    assert!(html.contains("binned-sah bins=64"), "the mixed row is listed");
    let p = paretos("two");
    assert_eq!(p.len(), 2, "one Pareto plot per CPU model: {p:?}");
    assert!(p.iter().any(|n| n.contains("CPU_A") || n.contains("CPU A")), "{p:?}");
    // The SAH bar chart still merges every row (machine independent): one per scene.
    let sah = std::fs::read_dir(dir.path().join("two/plots"))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("sah_") && e.file_name().to_string_lossy().ends_with(".png"))
        .count();
    assert_eq!(sah, 1);
    // Groups: mixed rows belong to none for trace times, but keep their build time with the model
    // that built them.
    let g = bvhlab_report::timing_groups(&rows);
    assert_eq!(g.iter().map(|g| (g.machine.as_str(), g.rows.len())).collect::<Vec<_>>(), vec![("CPU A", 2), ("CPU B", 2)]);
    let g = bvhlab_report::build_timing_groups(&rows);
    assert_eq!(g.iter().map(|g| (g.machine.as_str(), g.rows.len())).collect::<Vec<_>>(), vec![("CPU A", 3), ("CPU B", 2)]);
}

/// Issue 16: every label a figure places is free of every other and inside its plot, on a scene
/// with many chains piled up at the front (the found case: labels on top of each other there).
#[test]
fn dense_plots_have_no_overlapping_labels() {
    use bvhlab_report::plots::{bars, pareto, render};
    let dir = tempfile::tempdir().unwrap();
    let mut points = Vec::new();
    for i in 0..40 {
        // Half of them on one cost (the front's flat end), times close together.
        let cost = if i % 2 == 0 { 7.0 } else { 7.0 + (i as f64) * 0.7 };
        points.push(pareto::ParetoPoint {
            label: format!("binned-sah bins={} leaf=2 +ibo comb +collapse variant {i}", 4 + i),
            method_index: i,
            seconds: 1e-3 * (1.0 + 0.05 * i as f64),
            sah_cost: cost,
            seconds_range: Some((0.9e-3 * (1.0 + 0.05 * i as f64), 1.3e-3 * (1.0 + 0.05 * i as f64))),
            peer: false,
        });
    }
    // Identical points (layouts of one build used to stack on the build's point).
    for i in 0..4 {
        points.push(pareto::ParetoPoint { label: format!("same {i}"), method_index: 0, seconds: 2e-3, sah_cost: 9.0, seconds_range: None, peer: false });
    }
    let fig = pareto::ParetoFigure {
        scene: "dense".into(),
        cost_label: "SAH cost".into(),
        time_label: "time [s]".into(),
        points,
    };
    let p = render(&fig, dir.path(), "pareto_dense", "dense").unwrap();
    assert!(p.labels >= 20, "labels placed: {}", p.labels);
    assert_eq!((p.label_overlaps, p.labels_outside), (0, 0), "pareto labels");

    let bars = bars::BarsFigure {
        shared_labels: false,
        caption: "dense bars".into(),
        panels: vec![bars::Panel {
            title: "t".into(),
            x_desc: "SAH cost".into(),
            bars: (0..60)
                .map(|i| bars::Bar {
                    label: format!("{} @qbvh_chunks bits=8,chunk_bytes=64,frame=parent,fill=dense {i}", "x".repeat(i % 30)),
                    value: if i == 7 { f64::NAN } else { 1.0 + i as f64 },
                    color_index: i,
                })
                .collect(),
        }],
    };
    let p = render(&bars, dir.path(), "bars_dense", "bars").unwrap();
    assert_eq!(p.labels, 120, "every bar has its name and value");
    assert_eq!((p.label_overlaps, p.labels_outside), (0, 0), "bar labels");
}

/// A re-run removes plot files no section links any more (renamed or dropped plots), and keeps
/// the ones it wrote.
#[test]
fn stale_plot_files_are_removed() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rep");
    std::fs::create_dir_all(out.join("plots")).unwrap();
    std::fs::write(out.join("plots/pareto_gone_scene.png"), b"old").unwrap();
    std::fs::write(out.join("plots/notes.txt"), b"not ours").unwrap();
    write_report(&out, "exp", &synthetic(None), None).unwrap();
    assert!(!out.join("plots/pareto_gone_scene.png").exists(), "stale plot removed");
    assert!(out.join("plots/notes.txt").exists(), "only .png/.svg are touched");
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    let linked = std::fs::read_dir(out.join("plots"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".png"))
        .collect::<Vec<_>>();
    assert!(!linked.is_empty());
    for n in linked {
        assert!(html.contains(&format!("plots/{n}")), "{n} is linked");
    }
}
