//! Without any font, plotters cannot draw text: the report must still be written (tables and
//! index.html), with the failed plots listed as problems, not a panic. Own test binary because
//! fontconfig reads its configuration once per process.
use bvhlab_pipeline::ResultRow;
use bvhlab_report::write_report;

#[test]
fn report_without_fonts() {
    let tmp = tempfile::tempdir().unwrap();
    let conf = tmp.path().join("fonts.conf");
    // A valid fontconfig file with no font directories: no fonts at all.
    std::fs::write(&conf, "<?xml version=\"1.0\"?>\n<fontconfig></fontconfig>\n").unwrap();
    std::env::set_var("FONTCONFIG_FILE", &conf);
    std::env::set_var("FONTCONFIG_PATH", tmp.path());

    let rows = vec![ResultRow {
        scene: "gen:sphere".into(),
        scene_name: "sphere".into(),
        method: "binned-sah".into(),
        sah_cost: 10.0,
        build_seconds: 0.1,
        triangles: 10,
        valid: true,
        ..Default::default()
    }];
    let out = tmp.path().join("r");
    let index = write_report(&out, "nofonts", &rows, None).unwrap();
    let html = std::fs::read_to_string(index).unwrap();
    assert!(out.join("results.parquet").exists() && out.join("results.csv").exists());
    assert!(html.contains("<td>sphere</td>"), "results table is there");
    // Either fontconfig still found a font (then plots exist) or the failures are listed.
    let plotted = out.join("plots/pareto_sphere.png").exists();
    assert!(plotted || html.contains("Problems while making this report"), "{html}");
    eprintln!("plots drawn without fontconfig fonts: {plotted}");
}
