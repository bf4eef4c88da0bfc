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
mod sweeps;

pub use plots::pareto::pareto_front;

use bvhlab_pipeline::ResultRow;
use fsutil::Stems;
use html::{Heatmap, Page, Section};
use plots::bars::{Bar, BarsFigure, Panel};
use plots::pareto::{ParetoFigure, ParetoPoint};
use plots::reference::ReferenceFigure;
use plots::{render, Plot};
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

fn machine_name(m: &str) -> &str {
    if m.is_empty() {
        "unknown CPU"
    } else {
        m
    }
}

/// The notice about machines: one line when every timing comes from one CPU model, a warning box
/// with the per-machine row counts and every mixed row otherwise.
fn machines_notice(rows: &[ResultRow], groups: &[TimingGroup]) -> String {
    use std::fmt::Write;
    let mixed: Vec<&ResultRow> = rows.iter().filter(|r| r.machine_mixed).collect();
    let mut h = String::new();
    if groups.len() <= 1 && mixed.is_empty() {
        if let Some(g) = groups.first() {
            let _ = writeln!(h, "<p class=\"meta\">Timings measured on: {}.</p>", html::escape(machine_name(&g.machine)));
        }
        return h;
    }
    h.push_str("<div class=\"invalid-box\" id=\"machines\"><h2>Timings from more than one CPU model</h2>");
    h.push_str(
        "<p>These rows were computed on different machines (e.g. a sharded Slurm run). Timing plots, \
         Pareto fronts and time ratios are drawn per CPU model (section titles say which); SAH costs, \
         counts and bytes do not depend on the machine and merge all rows. Pin one model with \
         <code>bvhlab slurm --constraint</code> (or <code>--partition</code>) to compare all timings.</p><ul>",
    );
    for g in groups {
        let _ = write!(h, "<li>{}: {} rows</li>", html::escape(machine_name(&g.machine)), g.rows.len());
    }
    h.push_str("</ul>");
    if !mixed.is_empty() {
        let _ = write!(
            h,
            "<p class=\"warn\"><b>{} rows have stages timed on different CPU models</b> (e.g. built on one, \
             traced on another): their trace times are left out of every timing plot and ratio; their build \
             times still appear where the construction stages ran on one model.</p>\
             <table><tr><th>scene</th><th>method</th><th>machines</th></tr>",
            mixed.len()
        );
        for r in &mixed {
            let _ = write!(
                h,
                "<tr class=\"invalid\"><td>{}</td><td>{}</td><td>{}</td></tr>",
                html::escape(&r.scene_name),
                html::escape(&r.method),
                html::escape(&r.machine)
            );
        }
        h.push_str("</table>");
    }
    h.push_str("</div>\n");
    h
}

fn incomplete_notice(missing: &[String]) -> String {
    use std::fmt::Write;
    if missing.is_empty() {
        return String::new();
    }
    let mut h = format!(
        "<div class=\"invalid-box\" id=\"incomplete\"><h2>Incomplete: {} chains missing from the cache</h2>\
         <p>Compute them (resubmit the same <code>bvhlab slurm</code> command, or run <code>bvhlab sweep</code>) \
         and build the report again. Missing:</p><ul>",
        missing.len()
    );
    for m in missing {
        let _ = write!(h, "<li>{}</li>", html::escape(m));
    }
    h.push_str("</ul></div>\n");
    h
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

    let methods = unique(rows.iter().map(|r| r.method.as_str()));
    let method_index = |m: &str| methods.iter().position(|x| *x == m).unwrap_or(0);
    let scenes = unique(rows.iter().map(|r| r.scene.as_str()));
    let mut problems = Vec::new();
    let mut stems = Stems::default();
    let mut plot = |fig: &dyn DynFigure, stem: &str, title: &str, problems: &mut Vec<String>| {
        let stem = stems.unique(stem);
        match fig.render(&plots_dir, &stem, title) {
            Ok(mut p) => {
                p.png = format!("{PLOTS_DIR}/{}", p.png);
                p.svg = format!("{PLOTS_DIR}/{}", p.svg);
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
    let multi = groups.len() > 1;
    let multi_build = build_groups.len() > 1;
    let suffix = |g: &TimingGroup| if multi { format!(" [{}]", machine_name(&g.machine)) } else { String::new() };
    let build_suffix =
        |g: &TimingGroup| if multi_build { format!(" [{}]", machine_name(&g.machine)) } else { String::new() };
    let mut pareto = Vec::new();
    let mut sah = Vec::new();
    let mut rays = Vec::new();
    for scene in &scenes {
        let scene_rows: Vec<&ResultRow> = rows.iter().filter(|r| r.scene == *scene).collect();
        let name = scene_rows[0].scene_name.as_str();
        // One point / bar per chain: ray sets repeat the build metrics, keep the first row.
        let chains = first_per(&scene_rows, |r| r.method.clone());

        // With a focus box (far outlier, huge ground plane) the object's cost is what matters; the
        // whole-scene cost is still in the bar chart below.
        let focus = chains.iter().any(|r| r.focus_sah_cost.is_some_and(f64::is_finite));
        let cost_label = if focus { "focus SAH cost" } else { "SAH cost" };
        // Build time only: grouped by the construction stages' model.
        for g in &build_groups {
        let timed: Vec<&ResultRow> = g.rows.iter().copied().filter(|r| r.scene == *scene).collect();
        let chains = first_per(&timed, |r| r.method.clone());
        if chains.is_empty() {
            continue;
        }
        let fig = ParetoFigure {
            scene: name.to_string(),
            cost_label: cost_label.to_string(),
            time_label: if chains.iter().any(|r| r.optimizer.is_some()) {
                "encode + build + optimize + compact time [s]".to_string()
            } else {
                "encode + build + compact time [s]".to_string()
            },
            points: chains
                .iter()
                .map(|r| ParetoPoint {
                    label: r.method.clone(),
                    method_index: method_index(&r.method),
                    // Encode + build + optimize + compaction: Morton builders pay for their codes
                    // and sort, optimizer chains for their passes.
                    seconds: analysis::total_build_seconds(r),
                    sah_cost: if focus { r.focus_sah_cost.unwrap_or(f64::NAN) } else { r.sah_cost },
                })
                .collect(),
        };
        pareto.extend(plot(
            &fig,
            &format!("pareto_{name}{}", if multi_build { format!("_{}", machine_name(&g.machine)) } else { String::new() }),
            &format!("{name}: build time vs {cost_label}{}", build_suffix(g)),
            &mut problems,
        ));
        }

        let bars = |v: &dyn Fn(&ResultRow) -> Option<f64>, rs: &[&ResultRow]| -> Vec<Bar> {
            rs.iter()
                .filter_map(|r| {
                    v(r).map(|value| Bar { label: r.method.clone(), value, color_index: method_index(&r.method) })
                })
                .collect()
        };
        let fig = BarsFigure {
            caption: format!("{name}: SAH cost per method"),
            panels: {
                let mut p = vec![Panel {
                    title: format!("c_T = {}, c_I = {}", scene_rows[0].c_t, scene_rows[0].c_i),
                    x_desc: "SAH cost".into(),
                    bars: bars(&|r| Some(r.sah_cost), &chains),
                }];
                if focus {
                    p.push(Panel {
                        title: "focus box: object subtree".into(),
                        x_desc: "focus SAH cost".into(),
                        bars: bars(&|r| r.focus_sah_cost, &chains),
                    });
                }
                p
            },
        };
        sah.extend(plot(&fig, &format!("sah_{name}"), &format!("{name}: SAH cost"), &mut problems));

        let kinds = unique(scene_rows.iter().filter_map(|r| r.rays_kind.as_deref()));
        for kind in kinds {
            let kind_rows: Vec<&ResultRow> = scene_rows
                .iter()
                .copied()
                .filter(|r| r.rays_kind.as_deref() == Some(kind))
                .collect();
            let kind_rows = first_per(&kind_rows, |r| r.method.clone());
            let steps = bars(&|r| r.traversal_steps_per_ray, &kind_rows);
            let isects = bars(&|r| r.intersections_per_ray, &kind_rows);
            if steps.is_empty() && isects.is_empty() {
                continue;
            }
            let fig = BarsFigure {
                caption: format!("{name}, {kind} rays"),
                panels: vec![
                    Panel { title: "traversal steps per ray".into(), x_desc: "steps / ray".into(), bars: steps },
                    Panel { title: "intersections per ray".into(), x_desc: "intersections / ray".into(), bars: isects },
                ],
            };
            rays.extend(plot(&fig, &format!("rays_{name}_{kind}"), &format!("{name}: {kind} rays"), &mut problems));
        }
    }

    let sweep_section = sweeps::section(rows, &mut |fig, stem, title, problems| plot(fig, stem, title, problems), &mut problems);

    let heatmaps = copy_heatmaps(out_dir, rows, &mut problems);

    let reference = reference_dir.map(|d| reference::compare(d, rows));
    // Sections whose plots and tables use timings: once per CPU model (mixed rows left out). The
    // optimization section plots construction times only (build_machine); the layout section also
    // trace times (machine).
    let group_rows = |g: &TimingGroup| -> Vec<ResultRow> { g.rows.iter().map(|r| (*r).clone()).collect() };
    let mut optimization_section = Vec::new();
    for (gi, g) in build_groups.iter().enumerate() {
        let owned;
        let rs: &[ResultRow] = if build_groups.len() == 1 && g.rows.len() == rows.len() {
            rows
        } else {
            owned = group_rows(g);
            &owned
        };
        let (tag, stem_tag) = (build_suffix(g), if multi_build { format!("_{}", machine_name(&g.machine)) } else { String::new() });
        let opt = optimization::section(
            rs,
            reference.as_ref().and_then(|r| r.as_ref().ok()),
            &mut |fig, stem, title, problems| plot(fig, &format!("{stem}{stem_tag}"), &format!("{title}{tag}"), problems),
            &mut problems,
        );
        optimization_section.extend(opt.into_iter().map(|s| retitle(s, multi_build, &tag, gi)));
    }
    let mut layouts_section = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        let owned;
        let rs: &[ResultRow] = if groups.len() == 1 && g.rows.len() == rows.len() {
            rows
        } else {
            owned = group_rows(g);
            &owned
        };
        let (tag, stem_tag) = (suffix(g), if multi { format!("_{}", machine_name(&g.machine)) } else { String::new() });
        let lay = layouts::section(
            rs,
            &mut |fig, stem, title, problems| plot(fig, &format!("{stem}{stem_tag}"), &format!("{title}{tag}"), problems),
            &mut problems,
        );
        layouts_section.extend(lay.into_iter().map(|s| retitle(s, multi, &tag, gi)));
    }
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

    let sections = vec![
        Section {
            id: "pareto",
            title: "Build time vs SAH cost (Pareto front)".into(),
            intro: "One point per chain (builder, parameters, encoder, compaction) and scene. The cost \
                    is the SAH cost, or the focus SAH cost for scenes with a focus box (axis label). \
                    Filled, ringed points are on the Pareto front (no other chain is both faster and cheaper); the \
                    line connects them. Time is the whole construction: encode (Morton/EMC codes \
                    and their sort) + build + optimize (ibo, kensler: the label says +ibo ...) + \
                    compaction (medians)."
                .into(),
            plots: pareto,
            extra: String::new(),
        },
        Section {
            id: "sah",
            title: "SAH cost per method".into(),
            intro: "SAH cost of each chain per scene, with the cost constants of the run; for scenes \
                    with a focus box also the focus SAH cost (the smallest subtree holding the focus \
                    triangles, normalized by their own bounds), which the Pareto chart then uses."
                .into(),
            plots: sah,
            extra: String::new(),
        },
        Section {
            id: "rays",
            title: "Traversal steps and intersections per ray".into(),
            intro: "Per scene and ray set, for chains with a measure stage.".into(),
            plots: rays,
            extra: String::new(),
        },
        sweep_section,
    ];
    let mut sections = sections;
    sections.extend(optimization_section);
    sections.extend(layouts_section);
    sections.extend([
        Section {
            id: "flags",
            title: format!("Flags: cost above {}x the best method", analysis::FLAG_RATIO),
            intro: format!(
                "Every (scene, method) whose SAH cost is more than {}x the best valid method's on that \
                 scene, or not a finite number. Scenes with a focus box are compared by focus_sah_cost \
                 (the object's subtree: with a far outlier or a huge ground plane the whole-scene cost \
                 says little), other scenes by sah_cost; the metric column says which.",
                analysis::FLAG_RATIO
            ),
            plots: Vec::new(),
            extra: html::flags_table(&analysis::flags(rows)),
        },
    ]);
    let page = Page {
        experiment,
        generated: html::utc_now(),
        rows,
        sections,
        heatmaps,
        reference,
        reference_plots,
        problems,
        notices: format!("{}{}", incomplete_notice(&options.missing_chains), machines_notice(rows, &groups)),
    };
    let index = out_dir.join("index.html");
    fsutil::write_atomic(&index, html::render(&page).as_bytes())?;
    Ok(index)
}

/// A per-model copy of a section: the model in its title, a distinct anchor.
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

fn first_per<'a>(rows: &[&'a ResultRow], key: impl Fn(&ResultRow) -> String) -> Vec<&'a ResultRow> {
    let mut seen = std::collections::HashSet::new();
    rows.iter().copied().filter(|r| seen.insert(key(r))).collect()
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
                caption: format!("{}: {} ({})", r.scene_name, r.method, kind),
                file: format!("{HEATMAPS_DIR}/{file}"),
            }),
            Err(e) => problems.push(format!("heat map of {} / {}: {e}", r.scene_name, r.method)),
        }
    }
    out
}
