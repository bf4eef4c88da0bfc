//! The first screen (issue 16): per scene, the Pareto fronts of build time vs SAH cost and of
//! memory vs trace time, the best of each measure, the agreement with the papers, and every flag,
//! each linking to its section. It must fit a 1400x900 viewport, so fronts list at most
//! `SHOWN` names and the rest as a count.
use crate::analysis::{method_key, total_build_seconds};
use crate::plots::fmt_num;
use crate::reference::{ReferenceReport, WITHIN_PERCENT};
use bvhlab_pipeline::ResultRow;
use maud::{html, Markup};

const SHOWN: usize = 3;

/// A flag on the first screen: text, the section it links to, and how bad it is.
pub struct Chip {
    pub text: String,
    pub href: String,
    /// "bad" (results not trustworthy), "note" (look before trusting), "good".
    pub class: &'static str,
}

impl Chip {
    pub fn new(class: &'static str, text: impl Into<String>, href: impl Into<String>) -> Chip {
        Chip { text: text.into(), href: href.into(), class }
    }
}

/// A row's chain without its layout (` @qbvh_chunks ...`): layouts of one build share the build.
pub fn build_label(r: &ResultRow) -> &str {
    r.method.split(" @").next().unwrap_or(&r.method)
}

/// Short names for rows with a layout: the build, the layout and only those layout parameters
/// that vary among `rows` of that layout (the full names run to 100 characters).
fn short_names(rows: &[&ResultRow]) -> Vec<String> {
    use crate::analysis::parse_params;
    rows.iter()
        .map(|r| {
            let Some(l) = &r.layout else { return r.method.clone() };
            let mine = parse_params(r.layout_params.as_deref().unwrap_or(""));
            let same: Vec<_> = rows.iter().filter(|q| q.layout.as_ref() == Some(l)).collect();
            let varying: Vec<String> = mine
                .iter()
                .filter(|(k, v)| {
                    same.iter().any(|q| parse_params(q.layout_params.as_deref().unwrap_or("")).get(*k) != Some(v))
                })
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            let auto = if r.method.contains(" @auto") { " (auto)" } else { "" };
            format!("{} @{l}{auto}{}{}", build_label(r), if varying.is_empty() { "" } else { " " }, varying.join(","))
        })
        .collect()
}

/// Seconds as a short reading: ms below one second.
fn seconds(v: f64) -> String {
    if v < 1.0 {
        format!("{} ms", fmt_num(v * 1e3))
    } else {
        format!("{} s", fmt_num(v))
    }
}

struct Best {
    name: String,
    value: f64,
}

/// Per scene, the best of `list` by `value` (lowest, or highest with `max`), computed on a DataFrame
/// (`scene`, `id`, `v`) with `frame::group_best`: the index into the scene's list and the value.
fn scene_bests<'a>(
    picks: &[ScenePick<'a>],
    list: impl for<'p> Fn(&'p ScenePick<'a>) -> &'p [&'a ResultRow],
    value: impl Fn(&ScenePick<'a>, &ResultRow) -> Option<f64>,
    max: bool,
) -> Vec<Option<(usize, f64)>> {
    let (mut scene, mut id, mut v) = (Vec::new(), Vec::new(), Vec::new());
    for p in picks {
        for (i, r) in list(p).iter().enumerate() {
            scene.push(p.key);
            id.push(i as u32);
            v.push(value(p, r).unwrap_or(f64::NAN));
        }
    }
    let bests = polars::df!("scene" => scene, "id" => id, "v" => v)
        .and_then(|df| crate::frame::group_best(&df, "scene", "id", "v", max))
        .unwrap_or_else(|e| panic!("best per scene on the results frame: {e}"));
    picks
        .iter()
        .map(|p| bests.iter().find(|(s, _, _)| s == p.key).map(|&(_, i, x)| (i as usize, x)))
        .collect()
}

pub struct SceneLine {
    pub scene: String,
    pub triangles: u64,
    pub cost_label: &'static str,
    pub build_front: Vec<String>,
    pub trace_front: Vec<String>,
    pub rays: Option<String>,
    best_cost: Option<Best>,
    fastest_build: Option<Best>,
    fastest_trace: Option<Best>,
    smallest: Option<Best>,
}

/// The ray set the trace front uses: random rays if traced (they do not favour one view), else
/// the set traced by the most rows.
fn trace_kind(rows: &[&ResultRow]) -> Option<String> {
    let mut kinds: Vec<(String, usize)> = Vec::new();
    for r in rows.iter().filter(|r| r.trace_seconds.is_some()) {
        let k = r.rays_kind.clone().unwrap_or_default();
        match kinds.iter_mut().find(|(x, _)| *x == k) {
            Some((_, n)) => *n += 1,
            None => kinds.push((k, 1)),
        }
    }
    kinds.iter().find(|(k, _)| k.starts_with("random")).or_else(|| kinds.iter().max_by_key(|(_, n)| *n)).map(|(k, _)| k.clone())
}

/// One scene's rows as the summary compares them: the builds (one row per build chain), those
/// timed on the reference machine, and the rows traced with the front's ray set.
struct ScenePick<'a> {
    key: &'a str,
    srows: Vec<&'a ResultRow>,
    builds: Vec<&'a ResultRow>,
    focus: bool,
    timed: Vec<&'a ResultRow>,
    rays: Option<String>,
    traced: Vec<&'a ResultRow>,
}

/// Points of every scene as a DataFrame (`scene`, `id` = index into that scene's list, `x`, `y`)
/// and their per-scene Pareto fronts computed on it (`frame::front_ids`); a scene without a front
/// point gets an empty list.
fn scene_fronts<'a>(
    picks: &[ScenePick<'a>],
    list: impl for<'p> Fn(&'p ScenePick<'a>) -> &'p [&'a ResultRow],
    xy: impl Fn(&ScenePick<'a>, &ResultRow) -> (f64, f64),
) -> Vec<Vec<usize>> {
    let (mut scene, mut id, mut x, mut y) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for p in picks {
        for (i, r) in list(p).iter().enumerate() {
            let (px, py) = xy(p, r);
            scene.push(p.key);
            id.push(i as u32);
            x.push(px);
            y.push(py);
        }
    }
    let fronts = polars::df!("scene" => scene, "id" => id, "x" => x, "y" => y)
        .and_then(|df| crate::frame::front_ids(&df, "scene", "id", "x", "y"))
        .unwrap_or_else(|e| panic!("Pareto fronts on the results frame: {e}"));
    picks
        .iter()
        .map(|p| {
            fronts
                .iter()
                .find(|(s, _)| s == p.key)
                .map(|(_, ids)| ids.iter().map(|&i| i as usize).collect())
                .unwrap_or_default()
        })
        .collect()
}

/// One line per scene. Timings are compared only within `machine` (the first CPU model of the
/// rows; with several, the machines notice says so).
pub fn scene_lines(rows: &[ResultRow]) -> Vec<SceneLine> {
    let machine = rows.iter().find(|r| !r.machine_mixed).map(|r| r.build_machine.clone()).unwrap_or_default();
    let mut scenes: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
    }
    let picks: Vec<ScenePick> = scenes
        .iter()
        .map(|s| {
            let srows: Vec<&ResultRow> = rows.iter().filter(|r| r.scene == *s && r.valid).collect();
            let mut builds: Vec<&ResultRow> = Vec::new();
            for r in &srows {
                if !builds.iter().any(|b| method_key(b) == method_key(r)) {
                    builds.push(r);
                }
            }
            let focus = builds.iter().any(|r| r.focus_sah_cost.is_some_and(f64::is_finite));
            let timed: Vec<&ResultRow> = builds.iter().copied().filter(|r| r.build_machine == machine).collect();
            let rays = trace_kind(&srows);
            let traced: Vec<&ResultRow> = srows
                .iter()
                .copied()
                .filter(|r| r.rays_kind == rays && r.trace_seconds.is_some() && !r.machine_mixed && r.machine == machine)
                .collect();
            ScenePick { key: *s, srows, builds, focus, timed, rays, traced }
        })
        .collect();
    let cost_of = |focus: bool, r: &ResultRow| if focus { r.focus_sah_cost } else { Some(r.sah_cost) };
    let mem = |r: &ResultRow| r.total_bytes_per_triangle.unwrap_or(r.bytes_per_triangle);
    let build_fronts = scene_fronts(&picks, |p| &p.timed, |p, r| {
        (total_build_seconds(r), cost_of(p.focus, r).unwrap_or(f64::NAN))
    });
    let trace_fronts = scene_fronts(&picks, |p| &p.traced, |_, r| (mem(r), r.trace_seconds.unwrap_or(f64::NAN)));
    let best_costs = scene_bests(&picks, |p| &p.builds, |p, r| cost_of(p.focus, r), false);
    let fastest_builds = scene_bests(&picks, |p| &p.timed, |_, r| Some(total_build_seconds(r)), false);
    let fastest_traces = scene_bests(&picks, |p| &p.traced, |_, r| r.mrays_per_s, true);
    let smallests = scene_bests(&picks, |p| &p.traced, |_, r| Some(mem(r)), false);
    picks
        .iter()
        .zip(build_fronts.into_iter().zip(trace_fronts))
        .enumerate()
        .map(|(k, (p, (bf, tf)))| {
            let s = p.key;
            let focus = p.focus;
            let build_front = bf.into_iter().map(|i| build_label(p.timed[i]).to_string()).collect();
            let short = short_names(&p.traced);
            let trace_front = tf.into_iter().map(|i| short[i].clone()).collect();
            let named = |b: Option<(usize, f64)>, name: &dyn Fn(usize) -> String| b.map(|(i, value)| Best { name: name(i), value });
            let build_name = |list: &[&ResultRow], i: usize| build_label(list[i]).to_string();
            let short_of = |i: usize| short.get(i).cloned().unwrap_or_default();
            SceneLine {
                scene: p.srows.first().map(|r| r.scene_name.clone()).unwrap_or_else(|| s.to_string()),
                triangles: rows.iter().find(|r| r.scene == *s).map(|r| r.triangles).unwrap_or(0),
                cost_label: if focus { "focus SAH" } else { "SAH" },
                build_front,
                trace_front,
                rays: p.rays.clone().filter(|_| !p.traced.is_empty()),
                best_cost: named(best_costs[k], &|i| build_name(&p.builds, i)),
                fastest_build: named(fastest_builds[k], &|i| build_name(&p.timed, i)),
                fastest_trace: named(fastest_traces[k], &short_of),
                smallest: named(smallests[k], &short_of),
            }
        })
        .collect()
}

fn names(v: &[String]) -> Markup {
    html! {
        @for (i, n) in v.iter().take(SHOWN).enumerate() {
            @if i > 0 { "; " } span.front { (n) }
        }
        @if v.len() > SHOWN { " " span.small { "+" (v.len() - SHOWN) " more" } }
        @if v.is_empty() { span.small { "n/a" } }
    }
}

fn best_cell(b: &Option<Best>, unit: &str) -> Markup {
    html! {
        @match b {
            Some(b) => {
                (b.name) " " span.small {
                    "(" @if unit == " s" { (seconds(b.value)) } @else { (fmt_num(b.value)) (unit) } ")"
                }
            }
            None => span.small { "n/a" },
        }
    }
}

/// The papers line: cells compared, within 3 %, the worst cell.
fn papers(reference: Option<&Result<ReferenceReport, String>>) -> Markup {
    let how = super::reference::HOW_TO_GET_PAPER_NUMBERS;
    match reference {
        None => html! { "no reference tables (../shared/reference absent). " span.small { (how) } },
        Some(Err(e)) => html! { span.warn { "reference tables unreadable: " (e) } },
        Some(Ok(rep)) if rep.comparisons.is_empty() => {
            html! { "no row of this experiment reproduces a paper cell (its scenes are not the papers'). " span.small { (how) } }
        }
        Some(Ok(rep)) => {
            let within = rep.comparisons.iter().filter(|c| c.diff_percent.abs() <= WITHIN_PERCENT).count();
            let worst = rep
                .comparisons
                .iter()
                .filter(|c| c.diff_percent.is_finite())
                .max_by(|a, b| a.diff_percent.abs().total_cmp(&b.diff_percent.abs()));
            html! {
                b { (within) " of " (rep.comparisons.len()) } " cells within " (fmt_num(WITHIN_PERCENT)) " %"
                @if let Some(w) = worst {
                    "; worst: " (w.source) " " (w.metric) ", " (w.abbrev) " on " (w.thesis_scene) ": "
                    b { (format!("{:+.1} %", w.diff_percent)) }
                }
                " " a href="#reference" { "(table)" }
            }
        }
    }
}

pub fn render(lines: &[SceneLine], chips: &[Chip], reference: Option<&Result<ReferenceReport, String>>) -> Markup {
    html! {
        div id="summary" {
            h2 { "Summary" }
            div.chips {
                "Flags: "
                @if chips.is_empty() { span.chip.good { "none: every row valid, no problem, no noisy timing" } }
                @for c in chips { a class={ "chip " (c.class) } href=(c.href) { (c.text) } }
            }
            p { b { "Papers: " } (papers(reference)) }
            table.summary {
                colgroup {
                    col style="width:10%"; col style="width:6%"; col style="width:21%"; col style="width:11%";
                    col style="width:11%"; col style="width:21%"; col style="width:10%"; col style="width:10%";
                }
                tr {
                    th { "scene" } th { "triangles" } th { "front: build time vs SAH" } th { "lowest cost" }
                    th { "fastest build" } th { "front: memory vs trace time" } th { "fastest trace" } th { "fewest bytes/tri" }
                }
                @for l in lines {
                    tr {
                        td { a href="#pareto" { (l.scene) } } td.n { (l.triangles) }
                        td { (names(&l.build_front)) }
                        td { (best_cell(&l.best_cost, &format!(" {}", l.cost_label))) }
                        td { (best_cell(&l.fastest_build, " s")) }
                        td {
                            (names(&l.trace_front))
                            @if let Some(k) = &l.rays { " " span.small { "(" (k) ")" } }
                        }
                        td { (best_cell(&l.fastest_trace, " Mrays/s")) }
                        td { (best_cell(&l.smallest, " B")) }
                    }
                }
            }
            p.small {
                "Fronts: no other method of the scene is both faster and better (build: encode + build + optimize + \
                 compact time against SAH, or focus SAH with a focus box; trace: total bytes per triangle against \
                 trace time of one ray set). Times are medians on one CPU model. Sections below open on click."
            }
        }
    }
}
