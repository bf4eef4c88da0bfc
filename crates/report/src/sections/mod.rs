//! index.html, one writer per section (issue 16). The page is built with maud, which escapes every
//! interpolated string by construction; no pre-escaped strings are passed around (`Section::extra`
//! and `Page::notices` are `Markup`).
//!
//! The page opens with the summary (`summary.rs`, fits one 1400x900 screen); every other section
//! is a `<details>` element, collapsed unless `open`, so the page stays short on screen and in
//! print, and a link to a section opens it (the script at the end).
pub(crate) mod charts;
pub mod heatmaps;
pub(crate) mod layouts;
pub(crate) mod notices;
pub(crate) mod optimization;
pub mod peers;
pub mod reference;
pub mod summary;
pub(crate) mod sweeps;
pub mod tables;

use crate::html::href;
use crate::plots::Plot;
use crate::reference::ReferenceReport;
use bvhlab_pipeline::ResultRow;
use maud::{html, Markup, PreEscaped, DOCTYPE};

pub struct Section {
    pub id: &'static str,
    pub title: String,
    pub intro: String,
    pub plots: Vec<Plot>,
    /// After the plots (tables made by the section's builder).
    pub extra: Markup,
    /// Shown expanded when the page opens (the Pareto fronts); all others start collapsed.
    pub open: bool,
}

impl Section {
    pub fn new(id: &'static str, title: impl Into<String>, intro: impl Into<String>, plots: Vec<Plot>) -> Section {
        Section { id, title: title.into(), intro: intro.into(), plots, extra: html! {}, open: false }
    }
}

pub struct Heatmap {
    pub scene: String,
    pub caption: String,
    pub file: String,
}

pub struct Page<'a> {
    pub experiment: &'a str,
    pub generated: String,
    pub rows: &'a [ResultRow],
    pub summary: Markup,
    pub sections: Vec<Section>,
    pub heatmaps: Vec<Heatmap>,
    pub reference: Option<Result<ReferenceReport, String>>,
    pub reference_plots: Vec<Plot>,
    pub problems: Vec<String>,
    /// Shown near the top: timings from several machines, an incomplete report.
    pub notices: Markup,
}

const CSS: &str = "body{font-family:sans-serif;margin:1em 1.5em;color:#222;max-width:1600px}\
h1{margin:0 0 0.1em;font-size:1.5em}h2{font-size:1.25em;margin:0.2em 0;display:inline}\
.meta{color:#555;margin:0.2em 0}figure{display:inline-block;margin:0.5em;vertical-align:top;max-width:100%}\
figure img{max-width:100%;height:auto;border:1px solid #ddd}figcaption{font-size:0.9em;color:#444}\
table{border-collapse:collapse;font-size:0.85em}th,td{border:1px solid #ccc;padding:2px 6px}\
th{background:#f0f0f0;position:sticky;top:0}td.n{text-align:right;font-variant-numeric:tabular-nums}\
tr.invalid td{background:#fdd}.warn{color:#a00}nav{margin:0.4em 0;display:flex;flex-wrap:wrap;gap:0.2em 1.2em}nav a{white-space:nowrap}\
.invalid-box{border:3px solid #c00;background:#fee;padding:0.2em 1em 1em;margin:1em 0}\
.invalid-box h2{color:#c00}.ok{color:#070;font-weight:bold}h3{margin-top:1.2em}\
details.sec{max-width:100%;overflow-x:auto;border-top:1px solid #ccc;margin:0.3em 0;padding-top:0.3em}details.sec>summary{cursor:pointer}\
details.sec[open]>summary{margin-bottom:0.5em}\
#summary{border:2px solid #446;border-radius:6px;padding:0.4em 0.8em;margin:0.5em 0;font-size:0.88em}\
#summary h2{display:block;font-size:1.15em;margin:0.1em 0 0.3em}#summary table{font-size:1em;width:100%}\
#summary td{vertical-align:top;overflow-wrap:anywhere}table.summary{table-layout:fixed;font-size:0.92em}.chips{margin:0.3em 0}.chip{display:inline-block;border-radius:4px;padding:1px 7px;\
margin:2px 4px 2px 0;border:1px solid #999;text-decoration:none;color:#222}.chip.bad{background:#fdd;border-color:#c00}\
.chip.note{background:#ffe9b8;border-color:#c80}.chip.good{background:#dfd;border-color:#070}\
.front{color:#124}.wide{overflow-x:auto;max-width:100%}.small{font-size:0.85em;color:#555}\
.gallery{display:flex;flex-wrap:wrap;gap:6px}.thumb{margin:0;width:150px;font-size:0.72em}\
.thumb img{width:150px;image-rendering:pixelated;display:block}\
.scale{height:10px;width:150px;background:linear-gradient(to right,#00f,#0ff,#0f0,#ff0,#f00)}\
.scale-labels{display:flex;justify-content:space-between;width:150px;font-size:0.9em;color:#444}\
input.filter{margin:0.3em 0;padding:2px 4px;width:24em}\
table.sortable th{cursor:pointer}table.sortable th[data-dir=asc]::after{content:' \\25B2'}\
table.sortable th[data-dir=desc]::after{content:' \\25BC'}\
@media print{@page{size:A4}details.sec>summary{list-style:none}a{color:#222;text-decoration:none}}";

/// Sorting and filtering of tables, and opening the section a link points into.
const SCRIPT: &str = "(function(){\
function openTarget(){var h=decodeURIComponent(location.hash.slice(1));if(!h)return;var e=document.getElementById(h);\
while(e){if(e.tagName==='DETAILS'){e.open=true;}e=e.parentElement;}}\
window.addEventListener('hashchange',openTarget);openTarget();\
document.querySelectorAll('input.filter').forEach(function(inp){var t=document.getElementById(inp.getAttribute('data-table'));\
if(!t)return;inp.addEventListener('input',function(){var q=inp.value.toLowerCase();\
Array.prototype.forEach.call(t.tBodies[0].rows,function(tr){tr.style.display=tr.textContent.toLowerCase().indexOf(q)>=0?'':'none';});});});\
document.querySelectorAll('table.sortable th').forEach(function(th){th.addEventListener('click',function(){\
var t=th.closest('table'),b=t.tBodies[0],i=th.cellIndex,asc=th.getAttribute('data-dir')!=='asc';\
t.querySelectorAll('th').forEach(function(o){o.removeAttribute('data-dir');});th.setAttribute('data-dir',asc?'asc':'desc');\
var rows=Array.prototype.slice.call(b.rows);rows.sort(function(x,y){var a=x.cells[i].textContent,c=y.cells[i].textContent,\
na=parseFloat(a),nc=parseFloat(c),r=(!isNaN(na)&&!isNaN(nc))?na-nc:a.localeCompare(c);return asc?r:-r;});\
rows.forEach(function(r){b.appendChild(r);});});});})();";

pub fn figure(plot: &Plot) -> Markup {
    html! {
        figure {
            a href=(href(&plot.svg)) { img src=(href(&plot.png)) alt=(plot.title) loading="lazy"; }
            figcaption { (plot.title) " (" a href=(href(&plot.svg)) { "SVG" } ")" }
        }
    }
}

/// One collapsible section.
pub fn section(id: &str, title: &str, open: bool, body: Markup) -> Markup {
    html! {
        details.sec id=(id) open[open] {
            summary { h2 { (title) } }
            (body)
        }
    }
}

pub fn render(p: &Page) -> String {
    let title = format!("bvhlab report: {}", p.experiment);
    let invalid = tables::invalid_chains(p.rows);
    let precision: std::collections::BTreeSet<&String> =
        p.rows.iter().filter_map(|r| r.precision_warning.as_ref()).collect();
    let page = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                title { (title) }
                style { (PreEscaped(CSS)) }
            }
            body {
                h1 { (title) }
                p.meta {
                    "Experiment " b { (p.experiment) } ", generated " (p.generated) ", " (p.rows.len())
                    " result rows. Data: " a href="results.csv" { "results.csv" } ", "
                    a href="results.parquet" { "results.parquet" } "."
                }
                (p.summary)
                nav {
                    @if !invalid.is_empty() {
                        a.warn href="#invalid" { b { (invalid.len()) " INVALID" } }
                    }
                    @for s in &p.sections { a href={ "#" (s.id) } { (s.title) } }
                    a href="#heatmaps" { "Heat maps" }
                    a href="#reference" { "Reference comparison" }
                    a href="#results" { "Results table" }
                    a href="#methods" { "Methods" }
                }
                @if p.rows.is_empty() {
                    p.warn { "No results: the experiment produced no rows." }
                }
                (tables::invalid_box(&invalid))
                @if !precision.is_empty() {
                    (section("precision", "Precision warnings", true, html! {
                        ul { @for w in &precision { li.warn { (w) } } }
                    }))
                }
                (p.notices)
                @if !p.problems.is_empty() {
                    (section("problems", "Problems while making this report", true, html! {
                        ul { @for e in &p.problems { li.warn { (e) } } }
                    }))
                }
                @for s in &p.sections {
                    (section(s.id, &s.title, s.open, html! {
                        p { (s.intro) }
                        @if s.plots.is_empty() && s.extra.0.is_empty() { p { "No data for this plot." } }
                        @for plot in &s.plots { (figure(plot)) }
                        (s.extra)
                    }))
                }
                (heatmaps::gallery(&p.heatmaps))
                (reference::section(p))
                (tables::results(p.rows))
                (tables::methods(p.rows))
                script { (PreEscaped(SCRIPT)) }
            }
        }
    };
    page.into_string()
}
