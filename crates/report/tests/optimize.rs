//! Report additions of the optimization family (issue 4) on synthetic rows: convergence plots from
//! optimize_trace with the 90%-reduction pass, thesis tables 10 (BP0-2, INC), 20 and 38, Bittner
//! 2013 table 2, optimizer chains on the Pareto chart.
use bvhlab_opt::PassRecord;
use bvhlab_pipeline::ResultRow;
use bvhlab_report::analysis::method_key;
use bvhlab_report::convergence;
use bvhlab_report::reference;
use bvhlab_report::write_report;
use std::path::Path;

const DRAGON: &str = "/work/shared/scenes/stanford_dragon.obj.gz";
const CONFERENCE: &str = "/work/shared/scenes/conference.obj.gz";

fn tris(scene: &str) -> u64 {
    if scene == DRAGON {
        871_414
    } else if scene == CONFERENCE {
        331_179
    } else {
        20_000
    }
}

fn name(scene: &str) -> String {
    Path::new(scene)
        .file_name()
        .and_then(|f| f.to_str())
        .map(|f| f.trim_end_matches(".obj.gz").to_string())
        .unwrap_or_default()
        .replace("gen:", "")
}

fn base(
    scene: &str,
    builder: &str,
    params: &str,
    label: &str,
    compact: &str,
    cost: f64,
) -> ResultRow {
    let mut method = label.to_string();
    if compact != "none" {
        method.push_str(&format!(" +{compact}"));
    }
    ResultRow {
        experiment: "t".into(),
        scene: scene.into(),
        scene_name: name(scene),
        triangles: tris(scene),
        builder: builder.into(),
        build_params: params.into(),
        compact: compact.into(),
        method,
        c_t: 3.0,
        c_i: 2.0,
        sah_cost: cost,
        build_sah_cost: Some(cost),
        valid: true,
        build_seconds: 1.0,
        total_build_seconds: 1.0,
        ..Default::default()
    }
}

const IBO: &str = "ibo_frac=0.01,keep_best=true,max_passes=0,max_seconds=0,measure=MEASURE,pr=5,pt=10,\
                   schedule=bittner,seed=1";
/// The thesis' settings and termination (tables 20 and 38).
const IBO_THESIS: &str = "ibo_frac=0.01,keep_best=false,max_passes=0,max_seconds=0,measure=comb,pr=5,pt=10,\
                          schedule=thesis,seed=1";

#[allow(clippy::too_many_arguments)]
/// A chain with an optimizer: costs per pass (pass 0 = the built tree), 0.1 s per pass; the
/// compacted cost is `ocost`.
fn optimized(
    scene: &str,
    builder: &str,
    params: &str,
    label: &str,
    optimizer: &str,
    oparams: &str,
    olabel: &str,
    costs: &[f64],
    ocost: f64,
) -> ResultRow {
    let mut r = base(scene, builder, params, label, "collapse", ocost);
    r.method = format!("{label} +{olabel} +collapse");
    r.build_sah_cost = Some(costs[0]);
    r.optimizer = Some(optimizer.into());
    r.optimize_params = Some(oparams.into());
    let secs = 0.1 * (costs.len() - 1) as f64;
    r.optimize_seconds = Some(secs);
    r.total_build_seconds = 1.0 + secs;
    let best = costs.iter().copied().fold(f64::INFINITY, f64::min);
    r.optimized_sah_cost = Some(best);
    r.optimize_passes = Some(costs.len() as u32 - 1);
    r.optimize_stop = Some("converged".into());
    r.optimize_trace = Some(
        costs
            .iter()
            .enumerate()
            .map(|(i, &c)| PassRecord {
                pass: i as u32,
                seconds: 0.1 * i as f64,
                sah_cost: c,
                moved: if i == 0 { 0 } else { 10 },
                phase: olabel.split(' ').nth(1).unwrap_or("x").to_string(),
            })
            .collect(),
    );
    r
}

fn ibo(
    scene: &str,
    builder: &str,
    params: &str,
    label: &str,
    measure: &str,
    costs: &[f64],
    ocost: f64,
) -> ResultRow {
    let p = IBO.replace("MEASURE", measure);
    optimized(
        scene,
        builder,
        params,
        label,
        "ibo",
        &p,
        &format!("ibo {measure}"),
        costs,
        ocost,
    )
}

/// ibo with the thesis' settings and termination (schedule=thesis, the last tree).
fn ibo_thesis(
    scene: &str,
    builder: &str,
    params: &str,
    label: &str,
    costs: &[f64],
    ocost: f64,
) -> ResultRow {
    optimized(
        scene,
        builder,
        params,
        label,
        "ibo",
        IBO_THESIS,
        "ibo comb schedule=thesis",
        costs,
        ocost,
    )
}

/// Geometric approach from `start` to `end`: pass i has covered 1 - q^i of the reduction.
fn decay(start: f64, end: f64, q: f64, passes: usize) -> Vec<f64> {
    (0..=passes)
        .map(|i| end + (start - end) * q.powi(i as i32))
        .collect()
}

fn rows() -> Vec<ResultRow> {
    let mut rows = Vec::new();
    for scene in [DRAGON, CONFERENCE] {
        let conf = scene == CONFERENCE;
        // Table 10 methods (no optimizer): FSW, BIN, INC, BP0-2.
        rows.push(base(
            scene,
            "sweep-sah",
            "leaf=2",
            "sweep-sah",
            "none",
            if conf { 92.6 } else { 138.2 },
        ));
        rows.push(base(
            scene,
            "binned-sah",
            "bins=16,centroid_stop=any-axis,leaf=2",
            "binned-sah bins=16",
            "none",
            if conf { 136.1 } else { 144.8 },
        ));
        let mut inc = base(
            scene,
            "incremental",
            "batch=8000,coh=1.5,ofrac=0.01",
            "incremental",
            "collapse",
            if conf { 84.1 } else { 197.5 },
        );
        inc.build_sah_cost = Some(if conf { 100.0 } else { 230.0 });
        rows.push(inc);
        rows.push(base(
            scene,
            "bonsai",
            "leaf=2,n=512,prune=false",
            "bonsai n=512",
            "none",
            if conf { 109.1 } else { 143.7 },
        ));
        rows.push(base(
            scene,
            "bonsai",
            "leaf=2,n=512,prune=true,t=0.1",
            "bonsai n=512 prune t=0.1",
            "none",
            if conf { 95.7 } else { 142.1 },
        ));
        // BP2 on the dragon 5% off the thesis: must be flagged.
        rows.push(base(
            scene,
            "bonsai",
            "leaf=2,n=4096,prune=true,t=0.01",
            "bonsai n=4096 prune t=0.01",
            "none",
            if conf { 94.8 } else { 141.4 * 1.05 },
        ));
        // The SAH-built initial tree (Bittner's "SAH build"): cost 145.4 leaf=1, 138.1 compacted.
        let mut sah = base(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            "collapse",
            if conf { 93.0 } else { 138.1 },
        );
        sah.build_sah_cost = Some(if conf { 99.0 } else { 145.4 });
        rows.push(sah);
        let (s0, fin) = if conf { (99.0, 86.0) } else { (145.4, 144.0) };
        // comb converges fast (q = 0.5), random slowly (q = 0.8); sum in between.
        rows.push(ibo(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            "comb",
            &decay(s0, fin, 0.5, 12),
            if conf { 80.0 } else { 137.0 },
        ));
        // The same with the thesis' termination: what tables 20 and 38 compare (not Bittner's).
        rows.push(ibo_thesis(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            &decay(s0, fin, 0.5, 30),
            if conf { 80.2 } else { 136.9 },
        ));
        rows.push(ibo(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            "random",
            &decay(s0, fin, 0.8, 30),
            if conf { 80.5 } else { 137.9 },
        ));
        rows.push(ibo(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            "sum",
            &decay(s0, fin, 0.7, 20),
            if conf { 81.0 } else { 138.0 },
        ));
        rows.push(optimized(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            "kensler-hc",
            "keep_best=true,max_passes=0,max_seconds=0,seed=1",
            "kensler-hc",
            &decay(s0, s0 - 0.5, 0.5, 5),
            138.0,
        ));
        rows.push(optimized(
            scene,
            "sweep-sah",
            "leaf=1",
            "sweep-sah leaf=1",
            "kensler-sa",
            "cooling=0.9,keep_best=true,max_passes=100,max_seconds=60,seed=1,t0=0.01",
            "kensler-sa",
            // A hot annealing schedule climbing far above its start: clipped in the plot.
            &[s0, 3.0 * s0, 2.0 * s0, s0],
            138.1,
        ));
        // A spatial-median initial tree: much higher start (log y in the plot).
        rows.push(ibo(
            scene,
            "spatial-median",
            "leaf=1",
            "spatial-median leaf=1",
            "comb",
            &decay(700.0, fin + 1.0, 0.6, 25),
            81.0,
        ));
        // Thesis 5.2: BIN (leaf 2) and INC with ibo + collapse.
        rows.push(ibo_thesis(
            scene,
            "binned-sah",
            "bins=16,centroid_stop=any-axis,leaf=2",
            "binned-sah bins=16",
            &[140.0, 120.0, 110.0],
            if conf { 107.2 } else { 140.4 },
        ));
        rows.push(ibo_thesis(
            scene,
            "incremental",
            "batch=8000,coh=1.5,ofrac=0.01",
            "incremental",
            &[230.0, 170.0, 150.0],
            if conf { 80.0 } else { 139.7 },
        ));
    }
    rows
}

fn reference_dir() -> Option<&'static Path> {
    let p = Path::new("/work/shared/reference");
    (p.join(reference::IBO_COST_TABLE).exists() && p.join(reference::BITTNER_TABLE).exists())
        .then_some(p)
}

#[test]
fn optimizer_is_part_of_the_method_identity() {
    let r = rows();
    let keys: Vec<String> = r
        .iter()
        .filter(|x| x.scene == DRAGON)
        .map(method_key)
        .collect();
    let mut dedup = keys.clone();
    dedup.sort();
    dedup.dedup();
    assert_eq!(
        dedup.len(),
        keys.len(),
        "every chain of a scene has its own key: {keys:?}"
    );
}

#[test]
fn convergence_groups_and_ninety_percent_pass() {
    let rows = rows();
    let groups = convergence::groups(&rows);
    // Per scene: sweep-sah leaf=1, spatial-median, binned-sah, incremental.
    assert_eq!(groups.len(), 8);
    let g = &groups[0];
    assert_eq!(
        (g.scene.as_str(), g.initial.as_str()),
        (DRAGON, "sweep-sah leaf=1")
    );
    let labels: Vec<&str> = g.curves.iter().map(|c| c.label.as_str()).collect();
    assert_eq!(
        labels,
        [
            "ibo comb",
            "ibo comb schedule=thesis",
            "ibo random",
            "ibo sum",
            "kensler-hc",
            "kensler-sa"
        ]
    );
    // Baseline: the same initial tree without optimizer (cost as built, compacted).
    assert_eq!(g.baseline.map(|b| (b.0, b.1)), Some((145.4, Some(138.1))));
    // 1 - q^i >= 0.9: comb (q = 0.5) at pass 4, random (q = 0.8) at pass 11, sum (0.7) at 7.
    let pass = |l: &str| {
        g.curves
            .iter()
            .find(|c| c.label == l)
            .unwrap()
            .pass90
            .map(|p| p.0)
    };
    assert_eq!(pass("ibo comb"), Some(4));
    assert_eq!(pass("ibo random"), Some(11));
    assert_eq!(pass("ibo sum"), Some(7));
    // Annealing that returns its start (keep_best): no reduction, no pass.
    assert_eq!(pass("kensler-sa"), None);
    let comb = &g.curves[0];
    assert_eq!(comb.ocost, Some(137.0));
    assert!((comb.reduction_percent() - 100.0 * (145.4 - comb.final_cost) / 145.4).abs() < 1e-12);
}

#[test]
fn thesis_tables_and_bittner() {
    let Some(dir) = reference_dir() else {
        eprintln!("no reference tables: skipped");
        return;
    };
    let rows = rows();
    let rep = reference::compare(dir, &rows).unwrap();
    let get = |metric: &str, scene: &str, abbrev: &str| {
        rep.comparisons
            .iter()
            .find(|c| c.metric == metric && c.scene_name == scene && c.abbrev == abbrev)
            .unwrap_or_else(|| panic!("{metric} {scene} {abbrev} missing: {:#?}", rep.comparisons))
    };
    // Table 10: FSW is the leaf=2 chain without optimizer, never an ibo chain.
    let fsw = get("SAH cost", "stanford_dragon", "FSW");
    assert_eq!((fsw.ours, fsw.method.as_str()), (138.2, "sweep-sah"));
    for (abbrev, paper) in [
        ("BP0", 143.7),
        ("BP1", 142.1),
        ("BP2", 141.4),
        ("INC", 197.5),
    ] {
        let c = get("SAH cost", "stanford_dragon", abbrev);
        assert_eq!(c.paper, paper, "{abbrev}");
        assert_eq!(c.within(), abbrev != "BP2", "{abbrev}: {c:?}");
    }
    assert_eq!(get("SAH cost", "conference", "BP1").paper, 95.7);
    assert_eq!(get("SAH cost", "conference", "INC").ours, 84.1);
    // Table 38: cost after ibo + compaction; table 20: / the table-10 chain, in percent.
    let c = get(reference::IBO_COST_LABEL, "conference", "FSW");
    // The schedule=thesis row, not the Bittner-terminated one (80.0).
    assert_eq!((c.ours, c.paper), (80.2, 79.9));
    assert!(c.within());
    assert!(c.method.contains("schedule=thesis"), "{}", c.method);
    let c = get(reference::IBO_RELATIVE_LABEL, "conference", "FSW");
    assert!((c.ours - 100.0 * 80.2 / 92.6).abs() < 1e-9, "{c:?}");
    assert_eq!(c.paper, 86.3);
    assert!(c.method.ends_with("/ sweep-sah"), "{}", c.method);
    let c = get(reference::IBO_RELATIVE_LABEL, "stanford_dragon", "INC");
    assert!((c.ours - 100.0 * 139.7 / 197.5).abs() < 1e-9);
    assert_eq!(
        get(reference::IBO_COST_LABEL, "stanford_dragon", "BIN").paper,
        140.4
    );
    // No table 20/38 cells for the ibo random / kensler chains.
    assert_eq!(
        rep.comparisons
            .iter()
            .filter(|c| c.metric == reference::IBO_COST_LABEL)
            .count(),
        6,
        "FSW, BIN, INC on two scenes"
    );
    // Bittner 2013 table 2: dragon only (871k), cost before and ocost after compaction.
    let b: Vec<_> = rep
        .bittner
        .iter()
        .map(|b| (b.scene_name.as_str(), b.paper_method.as_str()))
        .collect();
    assert_eq!(
        b,
        [
            ("stanford_dragon", "SAH build"),
            ("stanford_dragon", "IBO random"),
            ("stanford_dragon", "IBO combined"),
            ("stanford_dragon", "Kensler hill climbing"),
            ("stanford_dragon", "Kensler annealing"),
        ]
    );
    let sah = &rep.bittner[0];
    assert_eq!(&sah.ours[..3], &[145.4, 138.1, 0.0]);
    let comb = &rep.bittner[2];
    assert!(
        (comb.ours[0] - 144.0).abs() < 0.01 && comb.ours[1] == 137.0,
        "{comb:?}"
    );
    assert_eq!(comb.paper, [145.4, 138.1, 1.21, 13.18]);
    let c = get(
        reference::BITTNER_OCOST_LABEL,
        "stanford_dragon",
        "IBO combined",
    );
    assert_eq!(c.source, reference::BITTNER);
}

#[test]
fn report_has_convergence_plots_and_tables() {
    let dir = tempfile::tempdir().unwrap();
    // BVHLAB_TEST_REPORT=DIR keeps a copy to look at.
    let out = std::env::var_os("BVHLAB_TEST_REPORT").map_or(dir.path().join("rep"), Into::into);
    let rows = rows();
    let index = write_report(&out, "opt", &rows, reference_dir()).unwrap();
    let html = std::fs::read_to_string(&index).unwrap();
    let no_fonts = html.contains("fonts missing");
    assert!(html.contains("id=\"optimization\""));
    let sec = &html[html.find("id=\"optimization\"").unwrap()..html.find("id=\"flags\"").unwrap()];
    if !no_fonts {
        for stem in [
            "convergence_stanford_dragon_sweep-sah_leaf_1",
            "convergence_conference_spatial-median_leaf_1",
        ] {
            for ext in ["png", "svg"] {
                let p = out.join("plots").join(format!("{stem}.{ext}"));
                assert!(p.exists(), "{} missing", p.display());
            }
        }
        assert_eq!(
            sec.matches("<figure>").count(),
            8,
            "one figure per (scene, initial tree)"
        );
        let svg = std::fs::read_to_string(
            out.join("plots/convergence_stanford_dragon_sweep-sah_leaf_1.svg"),
        )
        .unwrap();
        for label in [
            "ibo comb",
            "ibo random",
            "kensler-sa",
            "optimizer time",
            "pass",
            "90%",
            "higher values drawn at the top",
        ] {
            assert!(svg.contains(label), "{label} in the convergence plot");
        }
        // The speed-vs-quality chart labels optimizer chains and counts their time.
        let pareto = std::fs::read_to_string(out.join("plots/pareto_conference.svg")).unwrap();
        assert!(pareto.contains("+ibo comb +collapse"));
        assert!(pareto.contains("build + optimize"));
    }
    // Convergence table: comb's 90% pass (4) and the (none) baseline row.
    assert!(
        sec.contains("<td>ibo comb</td><td class=\"n\">12</td><td>converged</td>"),
        "{sec}"
    );
    assert!(sec.contains("(none)"));
    if reference_dir().is_some() {
        assert!(sec.contains("Thesis tables 38 and 20"));
        assert!(sec.contains("Bittner 2013 table 2"));
        assert!(sec.contains("Kensler annealing"));
        // BP2 dragon 5% off: flagged in the reference table.
        let refsec =
            &html[html.find("id=\"reference\"").unwrap()..html.find("id=\"results\"").unwrap()];
        assert!(refsec.contains("|diff| &gt; 3%"));
        assert!(refsec.contains("BP2"));
    }
}

#[test]
fn no_optimization_section_without_optimizers() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<ResultRow> = rows()
        .into_iter()
        .filter(|r| r.optimizer.is_none())
        .collect();
    let index = write_report(&dir.path().join("r"), "plain", &rows, None).unwrap();
    let html = std::fs::read_to_string(index).unwrap();
    assert!(!html.contains("id=\"optimization\""));
}
