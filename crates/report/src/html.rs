//! index.html: one self-contained page (inline CSS, relative links) so it opens from disk.
use crate::analysis::{method_key, Flag};
use crate::plots::{fmt_num, Plot};
use crate::reference::{ReferenceReport, WITHIN_PERCENT};
use bvhlab_pipeline::ResultRow;
use std::fmt::Write;

pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Relative URL from a relative file path: percent-encode what is not URL-safe.
fn href(path: &str) -> String {
    let mut out = String::new();
    for b in path.bytes() {
        if b.is_ascii_alphanumeric() || b"-_./~".contains(&b) {
            out.push(b as char);
        } else {
            let _ = write!(out, "%{b:02X}");
        }
    }
    out
}

pub struct Section {
    pub id: &'static str,
    pub title: String,
    pub intro: String,
    pub plots: Vec<Plot>,
    /// Raw HTML after the plots (tables made by the section's builder).
    pub extra: String,
}

pub struct Heatmap {
    pub caption: String,
    pub file: String,
}

pub struct Page<'a> {
    pub experiment: &'a str,
    pub generated: String,
    pub rows: &'a [ResultRow],
    pub sections: Vec<Section>,
    pub heatmaps: Vec<Heatmap>,
    pub reference: Option<Result<ReferenceReport, String>>,
    pub reference_plots: Vec<Plot>,
    pub problems: Vec<String>,
    /// Raw HTML shown near the top: timings from several machines, an incomplete report.
    pub notices: String,
}

const CSS: &str = "body{font-family:sans-serif;margin:1.5em;color:#222;max-width:1600px}\
h1{margin-bottom:0.2em}h2{border-bottom:1px solid #ccc;padding-bottom:0.2em;margin-top:1.6em}\
.meta{color:#555}figure{display:inline-block;margin:0.5em;vertical-align:top}\
figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:0.9em;color:#444}\
table{border-collapse:collapse;font-size:0.85em}th,td{border:1px solid #ccc;padding:2px 6px}\
th{background:#f0f0f0;position:sticky;top:0}td.n{text-align:right;font-variant-numeric:tabular-nums}\
tr.invalid td{background:#fdd}.warn{color:#a00}.heat img{width:320px;image-rendering:pixelated}\
nav a{margin-right:1em}.invalid-box{border:3px solid #c00;background:#fee;padding:0.2em 1em 1em;margin:1em 0}\
.invalid-box h2{color:#c00;border-bottom-color:#c00;margin-top:0.4em}.ok{color:#070;font-weight:bold}\
h3{margin-top:1.2em}";

pub fn render(p: &Page) -> String {
    let mut h = String::new();
    let title = format!("bvhlab report: {}", p.experiment);
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\
         <style>{CSS}</style></head><body>\n<h1>{}</h1>\n",
        escape(&title),
        escape(&title)
    );
    let _ = writeln!(
        h,
        "<p class=\"meta\">Experiment <b>{}</b>, generated {}, {} result rows. \
         Data: <a href=\"results.csv\">results.csv</a>, <a href=\"results.parquet\">results.parquet</a>.</p>",
        escape(p.experiment),
        escape(&p.generated),
        p.rows.len()
    );
    let invalid = invalid_chains(p.rows);
    h.push_str("<nav>");
    if !invalid.is_empty() {
        let _ = write!(h, "<a href=\"#invalid\" class=\"warn\"><b>{} INVALID</b></a>", invalid.len());
    }
    for s in &p.sections {
        let _ = write!(h, "<a href=\"#{}\">{}</a>", s.id, escape(&s.title));
    }
    h.push_str("<a href=\"#heatmaps\">Heat maps</a><a href=\"#reference\">Reference comparison</a>");
    h.push_str("<a href=\"#results\">Results table</a></nav>\n");

    if p.rows.is_empty() {
        h.push_str("<p class=\"warn\">No results: the experiment produced no rows.</p>\n");
    }
    invalid_box(&mut h, &invalid);
    let precision: std::collections::BTreeSet<&String> =
        p.rows.iter().filter_map(|r| r.precision_warning.as_ref()).collect();
    if !precision.is_empty() {
        h.push_str("<h2>Precision warnings</h2><ul>");
        for w in precision {
            let _ = write!(h, "<li class=\"warn\">{}</li>", escape(w));
        }
        h.push_str("</ul>\n");
    }
    h.push_str(&p.notices);
    if !p.problems.is_empty() {
        h.push_str("<h2>Problems while making this report</h2><ul>");
        for e in &p.problems {
            let _ = write!(h, "<li class=\"warn\">{}</li>", escape(e));
        }
        h.push_str("</ul>\n");
    }

    for s in &p.sections {
        let _ = writeln!(h, "<h2 id=\"{}\">{}</h2>\n<p>{}</p>", s.id, escape(&s.title), escape(&s.intro));
        if s.plots.is_empty() && s.extra.is_empty() {
            h.push_str("<p>No data for this plot.</p>\n");
        }
        for plot in &s.plots {
            figure(&mut h, plot);
        }
        h.push_str(&s.extra);
    }

    h.push_str("<h2 id=\"heatmaps\">Heat maps</h2>\n");
    if p.heatmaps.is_empty() {
        h.push_str("<p>No heat maps (they come with primary ray sets).</p>\n");
    } else {
        h.push_str("<p>Traversal steps per primary ray, blue (0) to red (100 or more).</p>\n");
    }
    for m in &p.heatmaps {
        let _ = writeln!(
            h,
            "<figure class=\"heat\"><a href=\"{0}\"><img src=\"{0}\" alt=\"{1}\"></a><figcaption>{1}</figcaption></figure>",
            href(&m.file),
            escape(&m.caption)
        );
    }

    reference_section(&mut h, p);
    results_table(&mut h, p.rows);
    h.push_str("</body></html>\n");
    h
}

fn figure(h: &mut String, plot: &Plot) {
    let _ = writeln!(
        h,
        "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{} (<a href=\"{}\">SVG</a>)</figcaption></figure>",
        href(&plot.png),
        escape(&plot.title),
        escape(&plot.title),
        href(&plot.svg)
    );
}

fn reference_section(h: &mut String, p: &Page) {
    h.push_str("<h2 id=\"reference\">Reference comparison (Frantal 2019 thesis, Bittner 2013)</h2>\n");
    let rep = match &p.reference {
        None => {
            h.push_str("<p>No reference directory (../shared/reference) given: nothing compared.</p>\n");
            return;
        }
        Some(Err(e)) => {
            let _ = writeln!(h, "<p class=\"warn\">Reference tables could not be read: {}</p>", escape(e));
            return;
        }
        Some(Ok(r)) => r,
    };
    h.push_str(
        "<p>Only scenes that are the same model as a thesis scene (same triangle count) are compared; \
         FSW and BIN map to our chains as listed in crates/report/src/reference.rs. \
         AHQ/ALQ/PL1-3 are matched on our Morton-code rows (encoder morton, bits=auto, scene bounds, no grid); \
         the EMC-64-var rows of table 25 are ratios emc64-var / morton of the same builder and parameters, \
         in percent (build time = encode + build + compaction). \
         BP0/BP1/BP2 = bonsai n=512 / n=512 prune t=0.1 / n=4096 prune t=0.01; INC = incremental + collapse. \
         Tables 38 and 20: sweep-sah leaf=1, binned-sah (BIN), incremental, each + ibo (comb, schedule=thesis, the \
         last tree) + collapse; table 20 \
         divides by the table-10 chain of the same method. Bittner 2013 table 2 (scenes matched by triangle count \
         in thousands): sweep-sah leaf=1 + collapse without optimizer (SAH build) or with ibo random/comb \
         (schedule=bittner), \
         kensler-hc/-sa; cost before, ocost after compaction. \
         Difference = (ours &minus; paper) / paper; flagged when |difference| &gt; 3%.</p>\n",
    );
    if !rep.notes.is_empty() {
        h.push_str("<ul>");
        for n in &rep.notes {
            let _ = write!(h, "<li>{}</li>", escape(n));
        }
        h.push_str("</ul>\n");
    }
    if rep.comparisons.is_empty() {
        h.push_str("<p>No row of this experiment reproduces a thesis table cell.</p>\n");
        return;
    }
    let _ = write!(
        h,
        "<table><tr><th>source</th><th>metric</th><th>scene (ours)</th><th>paper scene</th><th>paper method</th>\
         <th>our chain</th><th>ours</th><th>paper</th><th>difference</th><th>within {w}%</th></tr>\n",
        w = fmt_num(WITHIN_PERCENT)
    );
    for c in &rep.comparisons {
        let diff = if c.diff_percent.is_finite() { format!("{:+.1}%", c.diff_percent) } else { "n/a".into() };
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td>\
             <td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            escape(&c.source),
            escape(&c.metric),
            escape(&c.scene_name),
            escape(&c.thesis_scene),
            escape(&c.abbrev),
            escape(&c.method),
            fmt_num(c.ours),
            fmt_num(c.paper),
            diff,
            crate::optimization::flag(c.diff_percent)
        );
    }
    h.push_str("</table>\n");
    for plot in &p.reference_plots {
        figure(h, plot);
    }
}

fn opt(v: Option<f64>) -> String {
    v.map(fmt_num).unwrap_or_default()
}

fn results_table(h: &mut String, rows: &[ResultRow]) {
    h.push_str("<h2 id=\"results\">Results table</h2>\n");
    if rows.is_empty() {
        h.push_str("<p>No results.</p>\n");
        return;
    }
    h.push_str(
        "<p>Selected columns; every column is in results.csv / results.parquet. \
         Times are medians in seconds. Rows failing structural validation are red.</p>\n",
    );
    let head = [
        "scene", "method", "rays", "triangles", "dropped", "SAH cost", "focus SAH", "built SAH", "optimized SAH",
        "encode s", "build s", "optimize s", "passes", "compact s", "total build s", "dup codes",
        "inner SA", "leaf SA", "refs/leaf", "leaves", "depth", "bytes/tri", "steps/ray",
        "isects/ray", "Mrays/s", "valid",
    ];
    h.push_str("<table><tr>");
    for c in head {
        let _ = write!(h, "<th>{}</th>", escape(c));
    }
    h.push_str("</tr>\n");
    for r in rows {
        let cls = if r.valid { "" } else { " class=\"invalid\"" };
        let text = [
            escape(&r.scene_name),
            escape(&r.method),
            escape(r.rays_kind.as_deref().unwrap_or("")),
        ];
        let nums = [
            r.triangles.to_string(),
            r.dropped_triangles.to_string(),
            fmt_num(r.sah_cost),
            opt(r.focus_sah_cost),
            opt(r.build_sah_cost),
            opt(r.optimized_sah_cost),
            opt(r.encode_seconds),
            fmt_num(r.build_seconds),
            opt(r.optimize_seconds),
            r.optimize_passes.map(|p| p.to_string()).unwrap_or_default(),
            fmt_num(r.compact_seconds),
            fmt_num(crate::analysis::total_build_seconds(r)),
            opt(r.duplicate_code_fraction),
            fmt_num(r.inner_sa_ratio),
            fmt_num(r.leaf_sa_ratio),
            fmt_num(r.refs_per_leaf),
            r.leaves.to_string(),
            r.depth.to_string(),
            fmt_num(r.bytes_per_triangle),
            opt(r.traversal_steps_per_ray),
            opt(r.intersections_per_ray),
            opt(r.mrays_per_s),
        ];
        let _ = write!(h, "<tr{cls}>");
        for t in text {
            let _ = write!(h, "<td>{t}</td>");
        }
        for n in nums {
            let _ = write!(h, "<td class=\"n\">{n}</td>");
        }
        let _ = writeln!(h, "<td>{}</td></tr>", if r.valid { "yes" } else { "NO" });
    }
    h.push_str("</table>\n");
}

/// Invalid chains: (first row, number of rows) per scene and method key, in row order.
fn invalid_chains(rows: &[ResultRow]) -> Vec<(&ResultRow, usize)> {
    let mut out: Vec<(&ResultRow, usize)> = Vec::new();
    for r in rows.iter().filter(|r| !r.valid) {
        match out.iter_mut().find(|(q, _)| q.scene == r.scene && method_key(q) == method_key(r)) {
            Some((_, n)) => *n += 1,
            None => out.push((r, 1)),
        }
    }
    out
}

/// A red box at the top of the page: every chain whose BVH failed structural validation. Their
/// numbers are not trustworthy; they stay in every table (red rows) so nothing is hidden.
fn invalid_box(h: &mut String, invalid: &[(&ResultRow, usize)]) {
    if invalid.is_empty() {
        return;
    }
    let _ = writeln!(
        h,
        "<div class=\"invalid-box\"><h2 id=\"invalid\">{} invalid result{}: BVH failed validation</h2>\
         <p>These chains produced a BVH that fails structural validation (every triangle exactly once, \
         children inside parents, leaves around their triangles). Their costs, times and ray counts \
         are not trustworthy; they are red in every table below.</p>",
        invalid.len(),
        if invalid.len() == 1 { "" } else { "s" }
    );
    h.push_str(
        "<table><tr><th>scene</th><th>method</th><th>builder</th><th>build params</th><th>encoder</th>\
         <th>encode params</th><th>compact</th><th>rows</th></tr>\n",
    );
    for (r, n) in invalid {
        let _ = writeln!(
            h,
            "<tr class=\"invalid\"><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td class=\"n\">{}</td></tr>",
            escape(&r.scene_name),
            escape(&r.method),
            escape(&r.builder),
            escape(&r.build_params),
            escape(r.encoder.as_deref().unwrap_or("")),
            escape(r.encode_params.as_deref().unwrap_or("")),
            escape(&r.compact),
            n
        );
    }
    h.push_str("</table></div>\n");
}

/// The flags table (see `analysis::flags`); invalid chains red.
pub fn flags_table(flags: &[Flag]) -> String {
    let mut h = String::new();
    if flags.is_empty() {
        h.push_str("<p class=\"ok\">No method is flagged.</p>\n");
        return h;
    }
    h.push_str(
        "<table><tr><th>scene</th><th>metric</th><th>method</th><th>value</th><th>best</th>\
         <th>best method</th><th>ratio</th><th>valid</th></tr>\n",
    );
    for f in flags {
        let cls = if f.valid { "" } else { " class=\"invalid\"" };
        let ratio = if f.ratio.is_finite() { format!("{}x", fmt_num(f.ratio)) } else { "n/a".into() };
        let _ = writeln!(
            h,
            "<tr{cls}><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
             <td>{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            escape(&f.scene_name),
            f.metric,
            escape(&f.method),
            fmt_num(f.value),
            fmt_num(f.best),
            escape(&f.best_method),
            ratio,
            if f.valid { "yes" } else { "NO" }
        );
    }
    h.push_str("</table>\n");
    h
}

/// `YYYY-MM-DD HH:MM:SS UTC` without a date crate (civil-from-days, Howard Hinnant's algorithm).
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes() {
        assert_eq!(escape("<a href=\"x\">&'</a>"), "&lt;a href=&quot;x&quot;&gt;&amp;&#39;&lt;/a&gt;");
        assert_eq!(href("plots/a b#1.png"), "plots/a%20b%231.png");
    }

    #[test]
    fn utc_format() {
        let s = utc_now();
        assert_eq!(s.len(), 23, "{s}");
        assert!(s.starts_with("20"), "{s}");
    }
}
