//! The report: every result row in a polars DataFrame (results.parquet, results.csv), plots made with
//! plotters (PNG and SVG), and index.html. Polars lives only here so algorithm crates build fast.
pub mod analysis;
pub mod convergence;
pub mod frame;
mod fsutil;
mod html;
pub mod layouts;
mod optimization;
pub mod plots;
pub mod reference;
pub mod sections;
mod sweeps;

pub use plots::pareto::pareto_front;

use bvhlab_pipeline::ResultRow;
use fsutil::Stems;
use plots::reference::ReferenceFigure;
use sections::summary::Chip;
use sections::{Heatmap, Page, Section};
use plots::{render, Plot};
use sweeps::PlotFn;
use std::path::{Path, PathBuf};

const PLOTS_DIR: &str = "plots";
const HEATMAPS_DIR: &str = "heatmaps";

/// Writes `out_dir/{results.parquet, results.csv, plots/*.png, plots/*.svg, heatmaps/*.png,
/// index.html}` and returns the path of index.html. `reference_dir` is ../shared/reference when
/// present (papers' tables as TSV).
///
/// The tables and index.html are required (errors propagate); a plot or heat map that cannot be made
/// (e.g. no fonts for plotters) is listed under "Problems" in index.html instead of failing the run.
pub fn write_report(
    out_dir: &Path,
    experiment: &str,
    rows: &[ResultRow],
    reference_dir: Option<&Path>,
) -> Result<PathBuf, String> {
    write_report_with(out_dir, experiment, rows, reference_dir, &ReportOptions::default())
}

/// What a report says beyond its rows.
#[derive(Clone, Debug, Default)]
pub struct ReportOptions {
    /// Chains of the experiment with a stage missing from the cache (`sweep --report-only`): the
    /// report is incomplete and says so at the top.
    pub missing_chains: Vec<String>,
}

/// Rows whose timings may be compared with each other: one CPU model (issue 12).
pub struct TimingGroup<'a> {
    /// CPU model ("" = not recorded).
    pub machine: String,
    pub rows: Vec<&'a ResultRow>,
}

/// Rows grouped by the CPU model their timings were measured on, in first-appearance order;
/// rows whose stages ran on different models (`machine_mixed`) are in no group.
pub fn timing_groups(rows: &[ResultRow]) -> Vec<TimingGroup<'_>> {
    group_by_machine(rows.iter().filter(|r| !r.machine_mixed), |r| &r.machine)
}

/// Rows grouped by the CPU model of their construction stages (`build_machine`): for build-time
/// plots, which a row traced on another model may still join. Rows whose construction stages ran
/// on different models are in no group.
pub fn build_timing_groups(rows: &[ResultRow]) -> Vec<TimingGroup<'_>> {
    group_by_machine(rows.iter().filter(|r| !r.build_machine.contains(" + ")), |r| &r.build_machine)
}

fn group_by_machine<'a>(
    rows: impl Iterator<Item = &'a ResultRow>,
    key: impl Fn(&ResultRow) -> &String,
) -> Vec<TimingGroup<'a>> {
    let mut groups: Vec<TimingGroup> = Vec::new();
    for r in rows {
        match groups.iter_mut().find(|g| &g.machine == key(r)) {
            Some(g) => g.rows.push(r),
            None => groups.push(TimingGroup { machine: key(r).clone(), rows: vec![r] }),
        }
    }
    groups
}

pub(crate) fn machine_name(m: &str) -> &str {
    if m.is_empty() {
        "unknown CPU"
    } else {
        m
    }
}

/// Rows of the report already in `out_dir` (its results.parquet), if there is a readable one: a
/// sweep compares it with the rows it is about to write (issue 15: `--report-only` on an empty
/// cache replaced a good report with an empty one).
pub fn existing_rows(out_dir: &Path) -> Option<usize> {
    frame::parquet_rows(&out_dir.join("results.parquet"))
}

/// `write_report` with options (an incomplete report's missing chains).
pub fn write_report_with(
    out_dir: &Path,
    experiment: &str,
    rows: &[ResultRow],
    reference_dir: Option<&Path>,
    options: &ReportOptions,
) -> Result<PathBuf, String> {
    let plots_dir = out_dir.join(PLOTS_DIR);
    std::fs::create_dir_all(&plots_dir).map_err(|e| format!("{}: {e}", plots_dir.display()))?;
    // A run killed while writing left `.tmp-<pid>-*` files; they are never renamed into place.
    let stale = fsutil::remove_stale_temps(out_dir);
    if stale > 0 {
        eprintln!("note: removed {stale} temporary file(s) of a killed report writer from {}", out_dir.display());
    }

    let mut df = frame::to_dataframe(rows)?;
    frame::write_parquet(&mut df, &out_dir.join("results.parquet"))?;
    frame::write_csv(&mut df, &out_dir.join("results.csv"))?;

    let mut problems = Vec::new();
    let mut stems = Stems::default();
    let mut plot = |fig: &dyn DynFigure, stem: &str, title: &str, problems: &mut Vec<String>| {
        let stem = stems.unique(stem);
        match fig.render(&plots_dir, &stem, title) {
            Ok(mut p) => {
                p.png = format!("{PLOTS_DIR}/{}", p.png);
                p.svg = format!("{PLOTS_DIR}/{}", p.svg);
                if p.label_overlaps > 0 || p.labels_outside > 0 {
                    problems.push(format!(
                        "plot '{title}': {} overlapping label pair(s), {} label(s) outside the plot",
                        p.label_overlaps, p.labels_outside
                    ));
                }
                Some(p)
            }
            Err(e) => {
                problems.push(e);
                None
            }
        }
    };

    // Timings compare only within one CPU model (issue 12): with several, every timing plot is
    // drawn per model and mixed rows are left out of them.
    let groups = timing_groups(rows);
    let build_groups = build_timing_groups(rows);
    let multi_build = build_groups.len() > 1;
    let (pareto, sah, rays) = sections::charts::per_scene(rows, &build_groups, multi_build, &mut plot, &mut problems);

    let sweep_section = sweeps::section(rows, &mut |fig, stem, title, problems| plot(fig, stem, title, problems), &mut problems);

    let heatmaps = copy_heatmaps(out_dir, rows, &mut problems);

    let reference = reference_dir.map(|d| reference::compare(d, rows));
    // Sections whose plots and tables use timings: once per CPU model (mixed rows left out). The
    // optimization section plots construction times only (build_machine); the layout section also
    // trace times (machine).
    let reference_ok = reference.as_ref().and_then(|r| r.as_ref().ok());
    let optimization_section = per_group(rows, &build_groups, &mut plot, &mut problems, &mut |rs, plot, problems| {
        optimization::section(rs, reference_ok, plot, problems)
    });
    let layouts_section = per_group(rows, &groups, &mut plot, &mut problems, &mut layouts::section);
    let mut reference_plots = Vec::new();
    if let Some(Ok(rep)) = &reference {
        for metric in unique(rep.comparisons.iter().map(|c| c.metric.as_str())) {
            let items: Vec<_> = rep.comparisons.iter().filter(|c| c.metric == metric).cloned().collect();
            let source = items[0].source.clone();
            let fig = ReferenceFigure { metric: metric.to_string(), source: source.clone(), items };
            reference_plots.extend(plot(
                &fig,
                &format!("reference_{metric}"),
                &format!("{metric}: ours vs {source}"),
                &mut problems,
            ));
        }
    }

    let mut pareto_section = Section::new(
        "pareto",
        "Build time vs SAH cost (Pareto front)",
        "One point per build chain (builder, parameters, encoder, optimizer, compaction) and scene; the \
         layouts of a build share its point and are charted in the layouts section. The cost is the SAH cost, \
         or the focus SAH cost for scenes with a focus box (axis label). Filled, ringed points are on the \
         Pareto front (no other chain is both faster and cheaper); the line connects them and they are named \
         where the name fits; every other point carries a number from the key under the chart. Time is the \
         whole construction: encode (Morton/EMC codes and their sort) + build + optimize + compaction (medians).",
        pareto,
    );
    pareto_section.open = true;
    let mut sections = vec![
        pareto_section,
        Section::new(
            "sah",
            "SAH cost per method",
            "SAH cost of each build chain per scene, with the cost constants of the run; for scenes with a \
             focus box also the focus SAH cost (the smallest subtree holding the focus triangles, normalized \
             by their own bounds), which the Pareto chart then uses.",
            sah,
        ),
        Section::new("rays", "Traversal steps and intersections per ray", "Per scene and ray set, for chains with a measure stage.", rays),
        sweep_section,
    ];
    if rows.iter().any(|r| r.library.is_some()) {
        let mut peers = Section::new(
            "peers",
            "bvhlab vs production libraries",
            "Embree 3 and obvhs run as builders inside the sweep (crates/peers): same boxes, same cost model,              same rays and oracle; their trees are imported into bvhlab's BVH, and their points are the              triangles on the Pareto charts.",
            Vec::new(),
        );
        peers.extra = sections::peers::table(rows);
        sections.push(peers);
    }
    sections.extend(optimization_section);
    sections.extend(layouts_section);
    let cost_flags = analysis::flags(rows);
    let mut flags_section = Section::new(
        "flags",
        format!("Flags: cost above {}x the best method", analysis::FLAG_RATIO),
        format!(
            "Every (scene, method) whose SAH cost is more than {}x the best valid method's on that \
             scene, or not a finite number. Scenes with a focus box are compared by focus_sah_cost \
             (the object's subtree: with a far outlier or a huge ground plane the whole-scene cost \
             says little), other scenes by sah_cost; the metric column says which.",
            analysis::FLAG_RATIO
        ),
        Vec::new(),
    );
    flags_section.extra = sections::tables::flags_table(&cost_flags);
    sections.push(flags_section);
    let mut noise_section = Section::new(
        "noise",
        "Timing noise",
        format!(
            "Every timed quantity is the median of the experiment's repeats, each run at least 10 ms of calls (a \
             shorter call is warmed up and repeated within the run; times are per call); its spread is (slowest - \
             fastest) / median (results.csv: <name>_spread, <name>_runs). Rows whose construction, trace or slowdown spread \
             exceeds {} are listed: their times are a property of the machine's load as much as of the method. \
             Verdicts on times elsewhere in this report read \"within noise\" unless the difference exceeds the \
             spreads. Re-run on a quiet machine, with more repeats or on one thread (`--threads 1`: on a 2-core machine \
             two threads were most of the noise) to resolve them.",
            analysis::NOISY_SPREAD
        ),
        Vec::new(),
    );
    noise_section.extra = sections::tables::noise_table(rows);
    sections.push(noise_section);

    // A re-run whose plots changed names (fewer scenes, small multiples) leaves the old files
    // behind; nothing links them, so they only mislead someone browsing plots/.
    let keep: std::collections::HashSet<String> = sections
        .iter()
        .flat_map(|s| s.plots.iter())
        .chain(reference_plots.iter())
        .flat_map(|p| [p.png.clone(), p.svg.clone()])
        .collect();
    if let Ok(dir) = std::fs::read_dir(&plots_dir) {
        for e in dir.flatten() {
            let name = format!("{PLOTS_DIR}/{}", e.file_name().to_string_lossy());
            let ours = name.ends_with(".png") || name.ends_with(".svg");
            if ours && !keep.contains(&name) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    let chips = summary_chips(rows, &problems, &cost_flags, options, &groups);
    let summary = sections::summary::render(&sections::summary::scene_lines(rows), &chips, reference.as_ref());
    let page = Page {
        experiment,
        generated: html::utc_now(),
        rows,
        summary,
        sections,
        heatmaps,
        reference,
        reference_plots,
        problems,
        notices: maud::html! {
            (sections::notices::incomplete(&options.missing_chains))
            (sections::notices::machines(rows, &groups))
        },
    };
    let index = out_dir.join("index.html");
    bvhlab_pipeline::atomic::write_atomic(&index, sections::render(&page).as_bytes())?;
    Ok(index)
}

/// The flags of the first screen, each linking to where it is explained.
fn summary_chips(
    rows: &[ResultRow],
    problems: &[String],
    cost_flags: &[analysis::Flag],
    options: &ReportOptions,
    groups: &[TimingGroup],
) -> Vec<Chip> {
    let mut chips = Vec::new();
    let plural = |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
    let invalid = sections::tables::invalid_chains(rows).len();
    if invalid > 0 {
        chips.push(Chip::new("bad", plural(invalid, "invalid chain", "invalid chains"), "#invalid"));
    }
    if !options.missing_chains.is_empty() {
        chips.push(Chip::new("bad", plural(options.missing_chains.len(), "chain missing", "chains missing"), "#incomplete"));
    }
    if !problems.is_empty() {
        chips.push(Chip::new("bad", plural(problems.len(), "report problem", "report problems"), "#problems"));
    }
    let precision = rows.iter().filter_map(|r| r.precision_warning.as_ref()).collect::<std::collections::BTreeSet<_>>().len();
    if precision > 0 {
        chips.push(Chip::new("note", plural(precision, "precision warning", "precision warnings"), "#precision"));
    }
    if !cost_flags.is_empty() {
        chips.push(Chip::new(
            "note",
            format!("{} above {}x the best cost", plural(cost_flags.len(), "method", "methods"), analysis::FLAG_RATIO),
            "#flags",
        ));
    }
    let noisy = sections::tables::noisy_rows(rows).len();
    if noisy > 0 {
        chips.push(Chip::new(
            "note",
            format!("{} with timing spread above {}", plural(noisy, "noisy timing", "noisy timings"), analysis::NOISY_SPREAD),
            "#noise",
        ));
    }
    let verdicts: Vec<layouts::Verdict> =
        layouts::findings(rows).iter().flat_map(|f| f.cases.iter().map(|c| c.verdict)).collect();
    let count = |v: layouts::Verdict| verdicts.iter().filter(|x| **x == v).count();
    let (na, wn) = (count(layouts::Verdict::NotApplicable), count(layouts::Verdict::WithinNoise));
    if na > 0 {
        chips.push(Chip::new("note", plural(na, "verdict not applicable (degenerate case)", "verdicts not applicable (degenerate cases)"), "#layouts"));
    }
    if wn > 0 {
        chips.push(Chip::new("note", plural(wn, "timing verdict within noise", "timing verdicts within noise"), "#layouts"));
    }
    let over = rows.iter().filter(|r| r.auto_over_limit == Some(true)).count();
    if over > 0 {
        chips.push(Chip::new("bad", plural(over, "auto layout over its slowdown limit", "auto layouts over their slowdown limit"), "#layouts"));
    }
    if groups.len() > 1 || rows.iter().any(|r| r.machine_mixed) {
        chips.push(Chip::new("note", "timings from several CPU models", "#machines"));
    }
    chips
}

/// A per-model copy of a section: the model in its title, a distinct anchor.
/// A section written once per timing group (`groups`: CPU models), from that group's rows (the
/// whole table when one group holds every row); with several groups, plot stems, plot titles and
/// section titles carry the model.
fn per_group(
    rows: &[ResultRow],
    groups: &[TimingGroup],
    plot: &mut PlotFn,
    problems: &mut Vec<String>,
    section: &mut dyn FnMut(&[ResultRow], &mut PlotFn, &mut Vec<String>) -> Option<Section>,
) -> Vec<Section> {
    let multi = groups.len() > 1;
    let mut out = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        let owned: Vec<ResultRow>;
        let rs: &[ResultRow] = if groups.len() == 1 && g.rows.len() == rows.len() {
            rows
        } else {
            owned = g.rows.iter().map(|r| (*r).clone()).collect();
            &owned
        };
        let (tag, stem_tag) = if multi {
            (format!(" [{}]", machine_name(&g.machine)), format!("_{}", machine_name(&g.machine)))
        } else {
            (String::new(), String::new())
        };
        let s = section(
            rs,
            &mut |fig, stem, title, problems| plot(fig, &format!("{stem}{stem_tag}"), &format!("{title}{tag}"), problems),
            problems,
        );
        out.extend(s.into_iter().map(|s| retitle(s, multi, &tag, gi)));
    }
    out
}

fn retitle(mut s: Section, multi: bool, tag: &str, gi: usize) -> Section {
    if multi {
        s.title.push_str(tag);
        // Anchors must be unique; a report process lives briefly, so leaking a few ids is fine.
        s.id = Box::leak(format!("{}-m{gi}", s.id).into_boxed_str());
    }
    s
}

/// Object-safe wrapper so one closure can render every figure type.
pub(crate) trait DynFigure {
    fn render(&self, dir: &Path, stem: &str, title: &str) -> Result<Plot, String>;
}

impl<F: plots::Figure> DynFigure for F {
    fn render(&self, dir: &Path, stem: &str, title: &str) -> Result<Plot, String> {
        render(self, dir, stem, title)
    }
}

/// Distinct values in first-appearance order (deterministic plot and legend order).
fn unique<'a>(it: impl Iterator<Item = &'a str>) -> Vec<&'a str> {
    let mut out: Vec<&str> = Vec::new();
    for s in it {
        if !out.contains(&s) {
            out.push(s);
        }
    }
    out
}

/// Copies each row's heat map PNG (a cache path) into `out_dir/heatmaps/` under a readable name, so
/// the report stays valid when the cache is cleaned. Missing files are reported, not fatal.
fn copy_heatmaps(out_dir: &Path, rows: &[ResultRow], problems: &mut Vec<String>) -> Vec<Heatmap> {
    let mut out = Vec::new();
    let mut stems = Stems::default();
    let mut done = std::collections::HashSet::new();
    let dir = out_dir.join(HEATMAPS_DIR);
    for r in rows {
        let Some(src) = r.heatmap.as_deref() else { continue };
        if !done.insert((r.scene.clone(), r.method.clone(), src.to_string())) {
            continue;
        }
        if let Err(e) = std::fs::create_dir_all(&dir) {
            problems.push(format!("{}: {e}", dir.display()));
            return out;
        }
        let kind = r.rays_kind.as_deref().unwrap_or("rays");
        let stem = stems.unique(&format!("{}__{}__{}", r.scene_name, r.method, kind));
        let file = format!("{stem}.png");
        match fsutil::copy_atomic(Path::new(src), &dir.join(&file)) {
            Ok(()) => out.push(Heatmap {
                scene: r.scene_name.clone(),
                caption: format!("{}: {} ({})", r.scene_name, r.method, kind),
                file: format!("{HEATMAPS_DIR}/{file}"),
            }),
            Err(e) => problems.push(format!("heat map of {} / {}: {e}", r.scene_name, r.method)),
        }
    }
    out
}
